"""Figures (matplotlib, Agg): a UV map as a checkerboard on the surface beside its layout
coloured by distortion, untangling start/result pictures with inverted elements marked, and
convergence plots.

Each function saves to a path (atomically, in the format its extension names) or into an open
binary file (then ``format`` is required)."""

from __future__ import annotations

import numpy as np

__all__ = [
    "save_param_figure", "save_layout", "save_untangle_figure", "save_convergence", "checker_colors",
    "INVERTED",
]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


INVERTED = "#d62728"  # red: inverted elements in every picture


def _save(fig, target, format):
    """Save ``fig`` into the open binary file ``target`` or atomically to the path ``target``."""
    if hasattr(target, "write"):
        if format is None:
            from ._errors import ParameterError

            raise ParameterError("saving a figure into an open file needs format= (e.g. 'png')")
        fig.savefig(target, format=format)
        return
    from pathlib import Path

    from .io import atomic_output

    with atomic_output(target, "wb") as fh:
        fig.savefig(fh, format=format or Path(target).suffix[1:].lower())


def _layout(fig, ax, x, F, face_values, title, label, vmin=None, vmax=None):
    if face_values is None:
        ax.triplot(x[:, 0], x[:, 1], F, lw=0.2, color="k")
    else:
        tp = ax.tripcolor(x[:, 0], x[:, 1], F, facecolors=np.asarray(face_values), cmap="viridis",
                          vmin=vmin, vmax=vmax, edgecolors="none")
        fig.colorbar(tp, ax=ax, shrink=0.7, label=label)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(title)


def save_layout(path, x, F, face_values=None, title="", label="distortion", vmin=None, vmax=None, format=None):
    """Draw a 2D map ``x`` (n, 2) with triangles ``F`` (m, 3), faces coloured by ``face_values``."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 7), dpi=120)
    _layout(fig, ax, x, F, face_values, title, label, vmin, vmax)
    fig.tight_layout()
    _save(fig, path, format)
    plt.close(fig)


def checker_colors(uv, F, checks=20):
    """(m, 3) RGB per face: a ``checks`` x ``checks`` checkerboard over the UV map's bounding
    square, sampled at each face's UV centroid (uv (n, 2), F (m, 3))."""
    uv = np.asarray(uv, dtype=np.float64)
    lo, span = uv.min(axis=0), max(float(np.ptp(uv, axis=0).max()), 1e-300)
    c = (uv[F].mean(axis=1) - lo) / span * checks
    odd = (np.floor(c[:, 0]) + np.floor(c[:, 1])) % 2 == 1
    return np.where(odd[:, None], [0.95, 0.62, 0.13], [0.97, 0.97, 0.95])


def _shaded(V, F, rgb, light=(0.3, -0.5, 0.8)):
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    lam = np.abs(n @ (np.asarray(light) / np.linalg.norm(light)))
    return np.clip(rgb * (0.35 + 0.65 * lam[:, None]), 0.0, 1.0)


def _surface(ax, V, F, rgb, alpha=1.0, edge=None):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ax.add_collection3d(Poly3DCollection(V[F], facecolors=np.c_[rgb, np.full(len(F), alpha)],
                                         edgecolors=edge or "none", linewidths=0.2))


def _frame3d(ax, V, title, elev=20, azim=-60):
    lo, hi = V.min(axis=0), V.max(axis=0)
    mid, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(mid[0] - r, mid[0] + r)
    ax.set_ylim(mid[1] - r, mid[1] + r)
    ax.set_zlim(mid[2] - r, mid[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    ax.set_title(title, pad=-8)


def save_param_figure(path, V, F, uv, face_values=None, title="", label="distortion", checks=20, format=None):
    """The UV map ``uv`` (n, 2) of the surface ``V`` (n, 3), ``F`` (m, 3) in two panels: a
    checkerboard texture on the 3D surface (flat-shaded per face; even squares mean low
    distortion) and the UV layout coloured by ``face_values`` (m,)."""
    plt = _plt()
    V, F, uv = np.asarray(V, np.float64), np.asarray(F), np.asarray(uv, np.float64)
    fig = plt.figure(figsize=(13, 6.5), dpi=110)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    _surface(ax3, V, F, _shaded(V, F, checker_colors(uv, F, checks)))
    _frame3d(ax3, V, "checkerboard texture on the surface")
    _layout(fig, fig.add_subplot(1, 2, 2), uv, F, face_values, title or "UV layout", label)
    fig.tight_layout()
    _save(fig, path, format)
    plt.close(fig)


def _boundary_faces(T):
    """(k, 3) faces of the tets ``T`` (m, 4) that belong to one tet only, outward-agnostic."""
    faces = np.concatenate([T[:, [0, 1, 2]], T[:, [0, 1, 3]], T[:, [0, 2, 3]], T[:, [1, 2, 3]]])
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[counts == 1]]


def save_untangle_figure(path, start, result, S, inverted_start, inverted_result, title="", format=None):
    """Start and result maps of an untangling side by side, inverted elements in red.

    Parameters
    ----------
    start, result : (n, d) maps (d = 2: triangles; d = 3: tetrahedra).
    S : (m, d+1) elements.
    inverted_start, inverted_result : (m,) bool, elements not positively oriented.

    Notes
    -----
    2D draws the triangles (inverted ones filled red).  3D draws, for each map, the boundary
    surface (translucent), the surface of the half of the mesh below the median of the first
    coordinate (a cut showing the inside), and every inverted tet in red.
    """
    plt = _plt()
    S = np.asarray(S)
    d = S.shape[1] - 1
    maps = [(np.asarray(start, np.float64), np.asarray(inverted_start, bool), "start"),
            (np.asarray(result, np.float64), np.asarray(inverted_result, bool), "result")]
    fig = plt.figure(figsize=(13, 6.5), dpi=110)
    for k, (x, bad, name) in enumerate(maps):
        label = f"{name}: {int(bad.sum())} of {len(S)} inverted"
        if d == 2:
            ax = fig.add_subplot(1, 2, k + 1)
            ax.triplot(x[:, 0], x[:, 1], S, lw=0.25, color="0.35")
            if bad.any():
                ax.tripcolor(x[:, 0], x[:, 1], S[bad], facecolors=np.ones(int(bad.sum())),
                             cmap=plt.matplotlib.colors.ListedColormap([INVERTED]), edgecolors="none")
            ax.set_aspect("equal")
            ax.set_axis_off()
            ax.set_title(label)
            continue
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        outer = _boundary_faces(S)
        _surface(ax, x, outer, _shaded(x, outer, np.array([0.6, 0.7, 0.85])), alpha=0.12)
        centroid = x[S].mean(axis=1)
        half = S[centroid[:, 0] <= np.median(centroid[:, 0])]
        cut = _boundary_faces(half)
        _surface(ax, x, cut, _shaded(x, cut, np.array([0.55, 0.75, 0.95])), alpha=0.9, edge=(0, 0, 0, 0.15))
        if bad.any():
            red = _boundary_faces(S[bad])
            _surface(ax, x, red, np.tile(plt.matplotlib.colors.to_rgb(INVERTED), (len(red), 1)), alpha=1.0)
        _frame3d(ax, x, label)
    if d == 3:
        title = (title + "\n" if title else "") + "boundary translucent, cut at the median x, inverted tets in red"
    if title:
        fig.suptitle(title, y=0.06, fontsize=9)
    fig.tight_layout()
    _save(fig, path, format)
    plt.close(fig)


def save_convergence(path, series, ylabel="energy - best", title="", format=None):
    """Semilog plot of ``{label: (times, energies)}`` against the best energy over all series."""
    plt = _plt()
    best = min(np.min(e) for _, e in series.values())
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for label, (t, e) in series.items():
        gap = np.maximum((np.asarray(e) - best) / abs(best), 1e-16)
        ax.semilogy(t, gap, marker=".", label=label)
    ax.set_xlabel("seconds")
    ax.set_ylabel("relative " + ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    _save(fig, path, format)
    plt.close(fig)

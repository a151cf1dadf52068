"""Figures (matplotlib, no pyplot state): a UV map as a checkerboard texture on the surface
beside its layout coloured by distortion, untangling start/result pictures with inverted
elements marked, and convergence plots.

Each picture has a ``*_figure`` function returning a :class:`matplotlib.figure.Figure` (shown
inline by Jupyter) and a ``save_*`` function that saves it to a path (atomically, in the
format its extension names: ``.png``, ``.pdf``, ``.svg``) or into an open binary file (then
``format`` is required).
"""

from __future__ import annotations

import numpy as np

from ._compose import SUPERSCRIPT
from ._render import camera_rotation, project, rasterize, render_sphere_checker, render_surface, render_uv_checker

__all__ = [
    "distortion", "param_figure", "save_param_figure", "layout_figure", "save_layout", "untangle_figure",
    "save_untangle_figure", "convergence_figure", "save_convergence", "sphere_figure", "save_sphere_figure",
    "atlas_figure", "save_atlas_figure", "flat_tripcolor",
    "INVERTED",
]

INVERTED = "#d62728"  # red: inverted elements in every picture


def distortion(problem, x) -> dict:
    """Per element of ``problem`` (:class:`~geomopt.Problem`) under the map ``x`` (n, d), from
    the singular values of its Jacobian ``J``: ``"conformal"`` (m,) ``sigma_max / sigma_min``
    (1 for a similarity, inf for a degenerate element) and ``"area"`` (m,) ``det J``, the
    signed ratio of mapped to rest area (volume): 1 where area is preserved, <= 0 inverted
    (for a map onto the sphere, whose ``J`` is 3 x 2, the chord triangle's unsigned ratio)."""
    S, x = problem.simplices, np.asarray(x, np.float64)
    E = np.stack([x[S[:, k]] - x[S[:, 0]] for k in range(1, S.shape[1])], axis=-1)
    J = E @ problem.rest_inv
    s = np.linalg.svd(J, compute_uv=False)
    with np.errstate(divide="ignore"):
        conformal = np.where(s[:, -1] > 0, s[:, 0] / np.where(s[:, -1] > 0, s[:, -1], 1.0), np.inf)
    area = np.linalg.det(J) if J.shape[1] == J.shape[2] else np.prod(s, axis=1)
    return {"conformal": conformal, "area": area}


def _figure(width, height, dpi=100, layout="constrained"):
    """A Figure on an Agg canvas, outside pyplot (nothing global to close; Jupyter shows it).
    ``layout=None`` for figures placed by hand (:func:`_margins`): matplotlib's constrained
    layout measures every tick label at each draw, a cost the hand-placed figures avoid."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=dpi, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _margins(fig, left, right, bottom, top, wspace=0.0):
    """Place the subplots of a ``layout=None`` figure: margins in inches, ``wspace`` as
    matplotlib's (a fraction of the mean panel width)."""
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height,
                        wspace=wspace)


def save_figure(fig, target, format=None):
    """Save ``fig`` into the open binary file ``target`` or atomically to the path ``target``."""
    if hasattr(target, "write"):
        if format is None:
            from .._runtime.errors import ParameterError

            raise ParameterError("saving a figure into an open file needs format= (e.g. 'png')")
        fig.savefig(target, format=format, **_encoder_options(format))
        return
    from pathlib import Path

    from ..io import atomic_output

    format = format or Path(target).suffix[1:].lower()
    with atomic_output(target, "wb") as fh:
        fig.savefig(fh, format=format, **_encoder_options(format))


def _encoder_options(format):
    """``savefig`` keyword arguments for ``format``: PNG at zlib level 1 (the same pixels,
    encoded faster in a somewhat larger file; measurements: benchmarks/README.md, issue 49
    section), nothing for other formats."""
    return {"pil_kwargs": {"compress_level": 1}} if format.lower() == "png" else {}


def flat_tripcolor(ax, x, F, face_values, **kwargs):
    """``ax.tripcolor`` of the per-face ``face_values`` (m,) on the triangles ``F`` (m, 3) of
    the 2D points ``x`` (n, 2), drawn as Gouraud triangles whose three corners have their
    face's value: the same flat colours as ``facecolors=`` in one vectorised Agg call, where a
    polygon collection builds a path per triangle."""
    F = np.asarray(F)
    corners = x[F].reshape(-1, 2)  # (3m, 2): no corner shared, so no colour interpolated
    return ax.tripcolor(corners[:, 0], corners[:, 1], np.arange(corners.shape[0]).reshape(-1, 3),
                        np.repeat(np.asarray(face_values, np.float64), 3), shading="gouraud", **kwargs)


def _layout(fig, ax, x, F, face_values, title, label, vmin=None, vmax=None):
    if face_values is None:
        ax.triplot(x[:, 0], x[:, 1], F, lw=0.2, color="k")
    else:
        tp = flat_tripcolor(ax, x, F, face_values, cmap="viridis", vmin=vmin, vmax=vmax)
        fig.colorbar(tp, ax=ax, shrink=0.8, label=label)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(title, fontsize=11, y=1.0)  # y given: no costly search for tick labels above


def layout_figure(x, F, face_values=None, title="", label="distortion", vmin=None, vmax=None, dpi=100):
    """A 2D map ``x`` (n, 2) with triangles ``F`` (m, 3), faces coloured by ``face_values``
    (m,) (or drawn as a wireframe when None); 7 x 7 inches."""
    fig = _figure(7, 7, dpi)
    _layout(fig, fig.add_subplot(), np.asarray(x, np.float64), np.asarray(F), face_values, title, label,
            vmin, vmax)
    return fig


def save_layout(path, x, F, face_values=None, title="", label="distortion", vmin=None, vmax=None, format=None):
    """Save :func:`layout_figure` to ``path``."""
    save_figure(layout_figure(x, F, face_values, title, label, vmin, vmax, dpi=120), path, format)


def _surface_panels(render, caption, view, dpi, title):
    """A 16 x 7.5 inch figure (``title`` above) with three panels: ``render(pixels, azimuth)`` (an
    RGBA image) seen from ``view`` (large, titled ``caption``) and from the other side (smaller); returns the
    figure, the third (empty) axes and the large panel's pixel size.  The renders have about
    1.5x the pixels the panel is shown at (6 inches), smoothed by imshow's anti-aliased
    downsampling: as smooth as rendering 2 x 2 times larger, at a third of the pixels."""
    size = int(round(9.0 * dpi))
    images = render(size, view[1]), render(size // 2, view[1] + 180.0)
    fig = _figure(16, 7.5, dpi, layout=None)
    front, back, right = fig.subplots(1, 3, width_ratios=[1.0, 0.42, 1.0])
    _margins(fig, 0.1, 0.1, 0.1, 0.75 if title else 0.4, wspace=0.05)
    for ax, image, name in ((front, images[0], caption), (back, images[1], "other side")):
        ax.imshow(image, interpolation="antialiased")
        ax.set_axis_off()
        ax.set_title(name, fontsize=11, y=1.0)
    if title:
        fig.suptitle(title, fontsize=12)
    return fig, right, size


def param_figure(V, F, uv, face_values=None, title="", label="distortion", checks=20, view=(15.0, 30.0),
                 up="y", dpi=100):
    """A UV map ``uv`` (n, 2) of the surface ``V`` (n, 3), ``F`` (m, 3), in two panels.

    Left (large): a ``checks`` x ``checks`` checkerboard texture through the UV map on the
    surface, evaluated per pixel (:func:`geomopt.plot._render.render_uv_checker`; squares that stay
    square mean a conformal map, squares of one size an area-preserving one), seen from
    ``view`` = (elevation, azimuth) in degrees about the world axis ``up``; beside it, smaller,
    the opposite side.  Right: the UV layout, faces coloured by ``face_values`` (m,).  16 x 7.5
    inches; ``title`` above all three.
    """
    V, F, uv = np.asarray(V, np.float64), np.asarray(F), np.asarray(uv, np.float64)
    fig, right, _ = _surface_panels(
        lambda px, azim: render_uv_checker(V, F, uv, size=(px, px), elev=view[0], azim=azim, up=up, checks=checks,
                                           supersample=1),
        f"{checks} x {checks} checkerboard through the UV map", view, dpi, title)
    _layout(fig, right, uv, F, face_values, "UV layout", label)
    return fig


def save_param_figure(path, V, F, uv, face_values=None, title="", label="distortion", checks=20, format=None,
                      view=(15.0, 30.0), up="y"):
    """Save :func:`param_figure` to ``path`` (110 dpi: 1760 x 825 pixels as PNG).  A PNG is
    composed without matplotlib (:func:`geomopt.plot._compose.param_picture`, the same panels) where
    that can draw it; PDF and SVG, and the rest, are drawn by matplotlib."""
    if _is_png(path, format):
        from ._compose import param_picture, save_png

        image = param_picture(V, F, uv, face_values, title, label, checks, view, up, dpi=110)
        if image is not None:
            save_png(image, path, 110)
            return
    save_figure(param_figure(V, F, uv, face_values, title, label, checks, view, up, dpi=110), path, format)


def _is_png(target, format):
    """Whether ``target`` (a path, or an open file with ``format``) is to hold a PNG."""
    if format is not None:
        return format.lower() == "png"
    return not hasattr(target, "write") and str(target).lower().endswith(".png")


def sphere_figure(V, F, x, face_values=None, title="", label="log2 area ratio", checks=12, view=(15.0, 30.0),
                  up="y", dpi=100):
    """A map ``x`` (n, 3) of the closed surface ``V`` (n, 3), ``F`` (m, 3) onto the unit sphere,
    in three panels: the surface textured through the map with a latitude-longitude checkerboard
    (:func:`geomopt.plot._render.render_sphere_checker`), seen from ``view`` = (elevation, azimuth)
    about ``up`` and, smaller, from the other side; and the sphere itself, its triangles coloured
    by ``face_values`` (m,) (default: ``log2`` of each triangle's spherical over its rest area,
    both normalised to total ``4 pi``, :func:`geomopt.objective.distortion.sphere_distortion`) on
    a symmetric scale.  16 x 7.5 inches; ``title`` above all three."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    V, F, x = np.asarray(V, np.float64), np.asarray(F, np.int64), np.asarray(x, np.float64)
    if face_values is None:
        from ..objective.distortion import sphere_distortion

        face_values = np.log2(np.maximum(sphere_distortion(V, F, x)["area_ratio"], 1e-12))
    values = np.asarray(face_values, np.float64)
    top = max(float(np.abs(values).max()), 1e-12)
    mappable = ScalarMappable(Normalize(-top, top), colormaps["coolwarm"])
    fig, right, size = _surface_panels(
        lambda px, azim: render_sphere_checker(V, F, x, size=(px, px), elev=view[0], azim=azim, up=up,
                                               checks=checks, supersample=1),
        "latitude-longitude checks through the map", view, dpi, title)
    y = x / np.linalg.norm(x, axis=1, keepdims=True)
    right.imshow(render_surface(y, F, lambda f, b, hit: mappable.to_rgba(values[f])[:, :3], size=(size, size),
                                elev=view[0], azim=view[1], up=up, supersample=1), interpolation="antialiased")
    right.set_axis_off()
    right.set_title("the sphere", fontsize=11)
    fig.colorbar(mappable, ax=right, shrink=0.8, label=label)
    return fig


def save_sphere_figure(path, V, F, x, face_values=None, title="", label="log2 area ratio", checks=12, format=None,
                       view=(15.0, 30.0), up="y"):
    """Save :func:`sphere_figure` to ``path`` (110 dpi: 1760 x 825 pixels as PNG)."""
    save_figure(sphere_figure(V, F, x, face_values, title, label, checks, view, up, dpi=110), path, format)


def _visible_seams(V, F, seams, rotation, size):
    """(s, 2, 2) pixel segments of the seam edges ``seams`` (s, 2) whose midpoint is not hidden
    behind the surface."""
    xy, depth = project(V, rotation, size)
    face, bary = rasterize(xy, depth, F, size)
    mid_xy = 0.5 * (xy[seams[:, 0]] + xy[seams[:, 1]])
    mid_z = 0.5 * (depth[seams[:, 0]] + depth[seams[:, 1]])
    col = np.clip(mid_xy[:, 0].astype(int), 0, size[0] - 1)
    row = np.clip(mid_xy[:, 1].astype(int), 0, size[1] - 1)
    f = face[row, col]
    front = np.einsum("ij,ij->i", bary[row, col], depth[F[np.maximum(f, 0)]])
    tol = 0.01 * float(np.ptp(depth))
    seen = (f < 0) | (mid_z >= front - tol)
    return np.stack([xy[seams[seen, 0]], xy[seams[seen, 1]]], axis=1)


def atlas_figure(V, F, uv, uv_faces, chart, seams, title="", checks=20, view=(15.0, 30.0), up="y", dpi=100):
    """A texture atlas in two panels: left, a ``checks`` x ``checks`` checkerboard through the
    atlas on the surface (:func:`geomopt.plot._render.render_uv_checker`), seen from ``view``, with
    the visible seams drawn in red; right, the atlas in the unit square, charts coloured.

    Parameters
    ----------
    V : (n, 3) float
        The surface's vertices.
    F : (m, 3) int
        Its triangles.
    uv : (k, 2) float
        One UV per chart corner.
    uv_faces : (m, 3) int
        The UV rows of the face corners.
    chart : (m,) int
        The chart of each face.
    seams : (s, 2) int
        The seams as input vertex pairs.
    """
    from matplotlib.collections import LineCollection

    V, F, uv = np.asarray(V, np.float64), np.asarray(F), np.asarray(uv, np.float64)
    T, seams = np.asarray(uv_faces), np.asarray(seams, dtype=np.int64).reshape(-1, 2)
    vertex = np.zeros(len(uv), dtype=np.int64)
    vertex[T] = F  # the surface point of each UV row
    fig = _figure(15, 7.5, dpi)
    left, right = fig.subplots(1, 2)
    size = int(round(9.0 * dpi))  # 1.5x the pixels shown, as param_figure's
    left.imshow(render_uv_checker(V[vertex], T, uv, size=(size, size), elev=view[0], azim=view[1], up=up,
                                  checks=checks, supersample=1), interpolation="antialiased")
    left.add_collection(LineCollection(_visible_seams(V, F, seams, camera_rotation(view[0], view[1], up),
                                                      (size, size)), colors=INVERTED, linewidths=1.2))
    left.set_axis_off()
    left.set_title(f"{checks} x {checks} checkerboard through the atlas, seams in red", fontsize=11)
    right.tripcolor(uv[:, 0], uv[:, 1], T, facecolors=np.asarray(chart) % 20, cmap="tab20", vmin=0, vmax=19,
                    edgecolors="none")
    right.plot([0, 1, 1, 0, 0], [0, 0, 1, 1, 0], color="k", lw=0.8)
    right.set_aspect("equal")
    right.set_axis_off()
    right.set_title(f"{int(np.max(chart)) + 1} charts in the unit square", fontsize=11)
    if title:
        fig.suptitle(title, fontsize=12)
    return fig


def save_atlas_figure(path, V, F, uv, uv_faces, chart, seams, title="", checks=20, format=None,
                      view=(15.0, 30.0), up="y"):
    """Save :func:`atlas_figure` to ``path`` (110 dpi)."""
    save_figure(atlas_figure(V, F, uv, uv_faces, chart, seams, title, checks, view, up, dpi=110), path, format)


def _boundary_faces(T):
    """(k, 3) faces of the tets ``T`` (m, 4) that belong to one tet only, outward-agnostic."""
    faces = np.concatenate([T[:, [0, 1, 2]], T[:, [0, 1, 3]], T[:, [0, 2, 3]], T[:, [1, 2, 3]]])
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[counts == 1]]


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
    """Equal scales on the three axes with the box fitted to the data (no empty cube around an
    elongated mesh), zoomed to fill the panel."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    span = np.maximum(hi - lo, 1e-3 * (hi - lo).max())
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    ax.set_box_aspect(span, zoom=1.05)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    ax.set_title(title)


def untangle_figure(start, result, S, inverted_start, inverted_result, title="", dpi=100):
    """Start and result maps of an untangling side by side, inverted elements in red.

    Parameters
    ----------
    start, result : (n, d) maps (d = 2: triangles; d = 3: tetrahedra).
    S : (m, d+1) elements.
    inverted_start, inverted_result : (m,) bool, elements not positively oriented.
    title : str, shown above both panels.

    Notes
    -----
    2D draws the triangles (inverted ones filled red).  3D draws, for each map, the boundary
    surface (translucent), the surface of the half of the mesh below the median of the first
    coordinate (a cut showing the inside), and every inverted tet in red.
    """
    from matplotlib.colors import ListedColormap, to_rgb

    S = np.asarray(S)
    d = S.shape[1] - 1
    maps = [(np.asarray(start, np.float64), np.asarray(inverted_start, bool), "start"),
            (np.asarray(result, np.float64), np.asarray(inverted_result, bool), "result")]
    fig = _figure(13, 6.5, dpi)
    for k, (x, bad, name) in enumerate(maps):
        label = f"{name}: {int(bad.sum())} of {len(S)} inverted"
        if d == 2:
            ax = fig.add_subplot(1, 2, k + 1)
            ax.triplot(x[:, 0], x[:, 1], S, lw=0.25, color="0.35")
            if bad.any():
                ax.tripcolor(x[:, 0], x[:, 1], S[bad], facecolors=np.ones(int(bad.sum())),
                             cmap=ListedColormap([INVERTED]), edgecolors="none")
            ax.set_aspect("equal")
            ax.set_axis_off()
            ax.set_title(label)
            continue
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        outer = _boundary_faces(S)
        _surface(ax, x, outer, _shaded(x, outer, np.array([0.6, 0.7, 0.85])), alpha=0.12)
        centroid = x[S].mean(axis=1)
        cut = _boundary_faces(S[centroid[:, 0] <= np.median(centroid[:, 0])])
        _surface(ax, x, cut, _shaded(x, cut, np.array([0.55, 0.75, 0.95])), alpha=0.9, edge=(0, 0, 0, 0.15))
        if bad.any():
            red = _boundary_faces(S[bad])
            _surface(ax, x, red, np.tile(to_rgb(INVERTED), (len(red), 1)), alpha=1.0)
        _frame3d(ax, x, label)
    if d == 3:
        title = (title + "\n" if title else "") + "boundary translucent, cut at the median x, inverted tets in red"
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def save_untangle_figure(path, start, result, S, inverted_start, inverted_result, title="", format=None):
    """Save :func:`untangle_figure` to ``path`` (110 dpi)."""
    save_figure(untangle_figure(start, result, S, inverted_start, inverted_result, title, dpi=110), path, format)


def superscript_powers(label):
    """A log axis's mathtext tick label (``$\\mathdefault{10^{-3}}$``,
    ``$\\mathdefault{2\\times10^{-3}}$``) as plain text with Unicode superscripts (``10⁻³``,
    ``2×10⁻³``), which matplotlib draws without its mathtext parser; other labels unchanged."""
    import re

    m = re.fullmatch(r"\$\\mathdefault\{(?:([0-9.]+)\\times\s*)?([0-9.]+)\^\{([-+]?[0-9]+)\}\}\$", label)
    if m is None:
        return label
    coeff, base, exponent = m.groups()
    return (f"{coeff}\u00d7" if coeff else "") + base + exponent.translate(SUPERSCRIPT)


def _superscript_log_formatter(**kwargs):
    from matplotlib.ticker import LogFormatterSciNotation

    class SuperscriptLogFormatter(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return superscript_powers(super().__call__(x, pos))

    return SuperscriptLogFormatter(**kwargs)


def convergence_figure(series, ylabel="energy", title="", reference=None, dpi=100):
    """Convergence of one or more solves against the iteration.

    Parameters
    ----------
    series : dict label -> ``(times, energies)`` or ``(times, energies, grad_norms)``, arrays
        (k + 1,) over the iterates of one solve (``Result.time_history``,
        ``energy_history``, ``grad_history``).
    ylabel : what the energies are (the gap panel's label says "relative gap in" it).
    reference : the energy gaps are measured to (default: the lowest energy of all series).
        Iterates at or below it have no gap to draw on a log scale and are left out, not
        floored.
    title : str, above the panels.

    Returns
    -------
    Figure with the relative gap ``(E - reference) / |reference|`` (log scale) and, when any
    series has gradient norms, a second panel with them (log scale); 10 x 4 inches.
    """
    grads = any(len(s) > 2 for s in series.values())
    fig = _figure(10 if grads else 6, 4, dpi, layout=None)
    axes = fig.subplots(1, 2 if grads else 1, squeeze=False)[0]
    _margins(fig, 0.85, 0.15, 0.55, 0.75 if title else 0.4, wspace=0.3)
    ref = min(float(np.min(s[1])) for s in series.values()) if reference is None else float(reference)
    for label, s in series.items():
        e = np.asarray(s[1], np.float64)
        gap = (e - ref) / max(abs(ref), 1e-300)
        it = np.arange(len(e))
        keep = gap > 0
        axes[0].semilogy(it[keep], gap[keep], marker=".", ms=3, label=label)
        if grads and len(s) > 2:
            axes[1].semilogy(it, np.asarray(s[2], np.float64), marker=".", ms=3, label=label)
    from matplotlib.ticker import MaxNLocator

    for ax in axes:  # powers of ten as text with superscripts: no mathtext parsing (costly)
        ax.yaxis.set_major_formatter(_superscript_log_formatter())
        ax.yaxis.set_minor_formatter(_superscript_log_formatter(labelOnlyBase=False))
    axes[0].set_ylabel("(E - E_ref) / |E_ref|")
    axes[0].set_title(f"relative gap in {ylabel}, E_ref = {ref:.10g}", fontsize=10, y=1.0)
    if grads:
        axes[1].set_ylabel("gradient norm")
        axes[1].set_title(f"gradient norm of {ylabel}", fontsize=10, y=1.0)
    for ax in axes:
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return fig


def save_convergence(path, series, ylabel="energy", title="", format=None, reference=None):
    """Save :func:`convergence_figure` to ``path`` (120 dpi).  A PNG is composed without
    matplotlib (:func:`geomopt.plot._compose.convergence_picture`) where that can draw it."""
    if _is_png(path, format):
        from ._compose import convergence_picture, save_png

        image = convergence_picture(series, ylabel, title, reference, dpi=120)
        if image is not None:
            save_png(image, path, 120)
            return
    save_figure(convergence_figure(series, ylabel, title, reference, dpi=120), path, format)

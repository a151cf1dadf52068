"""Figures: UV layout coloured by per-face distortion, and convergence plots (matplotlib, Agg).

Each function saves to a path (atomically, in the format its extension names) or into an open
binary file (then ``format`` is required).
"""

from __future__ import annotations

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


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


def save_layout(path, x, F, face_values=None, title="", label="distortion", vmin=None, vmax=None,
                format=None):
    """Draw a 2D map ``x`` (n, 2) with triangles ``F`` (m, 3), faces coloured by ``face_values`` (m,).

    ``path`` is a file path (written atomically; the format from its extension unless
    ``format`` is given) or an open binary file (``format``, e.g. ``"png"``, required).
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 7), dpi=120)
    try:
        if face_values is None:
            ax.triplot(x[:, 0], x[:, 1], F, lw=0.2, color="k")
        else:
            tp = ax.tripcolor(x[:, 0], x[:, 1], F, facecolors=np.asarray(face_values), cmap="viridis",
                              vmin=vmin, vmax=vmax, edgecolors="none")
            fig.colorbar(tp, ax=ax, shrink=0.7, label=label)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(title)
        fig.tight_layout()
        _save(fig, path, format)
    finally:
        plt.close(fig)


def save_convergence(path, series, ylabel="energy - best", title="", format=None):
    """Semilog plot of ``{label: (times, energies)}`` against the best energy over all series.

    ``path`` as in :func:`save_layout`.
    """
    plt = _plt()
    best = min(np.min(e) for _, e in series.values())
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    try:
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
    finally:
        plt.close(fig)

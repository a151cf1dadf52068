"""How a comparison is shown: the convergence figure and the LaTeX table.

Every solver keeps one colour and one marker in every figure (:func:`solver_style`), so that
figures of different meshes, energies or runs can sit side by side in a paper.  Figures are
saved with TrueType (Type 42) fonts in PDF and PostScript (:data:`PAPER_RC`): ACM's and IEEE's
submission checks reject Type 3 fonts, matplotlib's default.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["solver_style", "comparison_figure", "save_figure", "latex_table", "text_table", "STYLES", "LAYOUTS", "PAPER_RC"]

from .options import LAYOUTS, check_font_size  # three panels per mesh, 15 inches wide, or one panel (gap against solve
# seconds) per mesh, a paper column wide (3.4 in: ACM 3.33 in, IEEE 3.5 in)
#: matplotlib settings every comparison figure is saved with: TrueType fonts in PDF / PS
PAPER_RC = {"pdf.fonttype": 42, "ps.fonttype": 42}
_WIDTH = {"wide": 15.0, "column": 3.4}
_FONT = {"wide": 10.0, "column": 8.0}

#: solver name -> (colour, marker); other names get a fixed one from their name's checksum
STYLES = {
    "newton": ("#1f77b4", "o"), "lbfgs": ("#ff7f0e", "s"), "slim": ("#2ca02c", "^"), "aqp": ("#d62728", "v"),
    "cm": ("#9467bd", "D"), "optx-lbfgs": ("#8c564b", "P"), "optx-bfgs": ("#e377c2", "X"),
    "optx-ncg": ("#7f7f7f", "*"),
}
_SPARE = ("#bcbd22", "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd")
_MARKERS = ("h", "p", "<", ">", "d", "8", "H", "1")


def solver_style(name: str) -> tuple:
    """``(colour, marker)`` of a solver, the same in every figure."""
    if name in STYLES:
        return STYLES[name]
    k = zlib.crc32(name.encode())
    return _SPARE[k % len(_SPARE)], _MARKERS[(k // len(_SPARE)) % len(_MARKERS)]


def _font_rc(layout, font_size) -> dict:
    size = _FONT[layout] if font_size is None else float(font_size)
    return {"font.size": size, "axes.titlesize": size, "axes.labelsize": size, "legend.fontsize": size,
            "xtick.labelsize": 0.9 * size, "ytick.labelsize": 0.9 * size}


def comparison_figure(comparisons: dict, log_x: bool = False, dpi: int = 100, layout: str = "wide",
                      font_size: float | None = None):
    """The convergence figure of comparisons (label -> :class:`~geomopt.experiments.comparison.Comparison`).

    ``layout="wide"``: one row of three panels per comparison, 15 inches wide, 4 per row: the
    relative gap to the reference against solve seconds and against iterations (log scale;
    dotted lines at the summary's tolerances; iterates at or below the reference are left out,
    not floored), and the gradient norm against iterations.  ``layout="column"``: the first
    panel alone per comparison, 3.4 inches wide (one paper column), 2.4 per comparison.
    Seconds are on the comparison's clock (``Comparison.clock``).  Solvers keep
    :func:`solver_style` throughout; ``log_x`` puts the seconds and iterations on log scales
    (iterations counted from 1).  ``font_size`` in points (default 10 wide, 8 column).  Save
    it with :func:`save_figure` (TrueType fonts)."""
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    check_font_size(layout, font_size, "comparison_figure")
    panels, height = (3, 4.0) if layout == "wide" else (1, 2.4)
    with rc_context(_font_rc(layout, font_size)):
        fig = Figure(figsize=(_WIDTH[layout], 0.6 + height * len(comparisons)), dpi=dpi, layout="constrained")
        FigureCanvasAgg(fig)
        axes = fig.subplots(len(comparisons), panels, squeeze=False)
        names = []
        for row, (label, c) in zip(axes, comparisons.items()):
            for name, run in c.results.items():
                names += [name] if name not in names else []
                _draw(row, c, name, run, log_x)
            _decorate(row, c, label, log_x)
        handles = [Line2D([], [], color=solver_style(n)[0], marker=solver_style(n)[1], label=n) for n in names]
        fig.legend(handles=handles, loc="outside upper center", frameon=False,
                   ncols=len(names) if layout == "wide" else min(len(names), 3))
    return fig


def save_figure(fig, fh, fmt: str) -> None:
    """``fig.savefig(fh, format=fmt)`` with :data:`PAPER_RC` (TrueType fonts in PDF / PS)."""
    from matplotlib import rc_context

    with rc_context(PAPER_RC):
        fig.savefig(fh, format=fmt)


def _draw(row, comparison, name, run, log_x):
    colour, marker = solver_style(name)
    gap = comparison.gap(name, run)
    it = np.arange(len(gap)) + (1 if log_x else 0)
    keep = gap > 0
    # markers evenly spaced along the drawn curve (a fraction of the axes), on linear and log axes
    style = dict(color=colour, marker=marker, ms=4, lw=1.4, markevery=0.07)
    t = comparison.times(run)
    if log_x:  # the start (t = 0) has no place on a log axis
        keep_t = keep & (t > 0)
    else:
        keep_t = keep
    row[0].plot(t[keep_t], gap[keep_t], **style)
    if len(row) > 1:
        row[1].plot(it[keep], gap[keep], **style)
        row[2].plot(it, run.grad_history, **style)


def _decorate(row, comparison, label, log_x):
    reps = max(len(r) for r in comparison.runs.values())
    clock = "CPU" if comparison.clock == "cpu" else "wall"
    if len(row) == 1:  # a paper column: the caption says the rest
        row[0].set_title(label, loc="left")
        row[0].set_xlabel(f"solve seconds ({clock})")
        row[0].set_ylabel("relative gap")
    else:
        row[0].set_title(f"{label}\n{comparison.describe_reference()}", loc="left")
        row[0].set_xlabel(f"solve seconds ({clock}" + (f"; the run of median time of {reps}" if reps > 1 else "")
                          + "; setup excluded)")
        row[1].set_xlabel("iteration + 1" if log_x else "iteration")
        row[2].set_xlabel("iteration + 1" if log_x else "iteration")
        row[0].set_ylabel("relative gap (E - E_ref) / |E_ref|")
        row[2].set_ylabel("gradient norm |grad E| (free DOFs)")
    for ax in row:
        ax.set_yscale("log")
        if log_x:
            ax.set_xscale("log")
        # opaque greys (the default grid at alpha 0.35 and 0.12 on white): PostScript has no alpha
        ax.grid(True, which="major", color="0.89")
        ax.grid(True, which="minor", color="0.96")
    for ax in row[:2]:
        for tol in comparison.tolerances:
            ax.axhline(tol, color="0.55", lw=0.8, ls=":", zorder=0)
        lo, hi = ax.get_ylim()
        ax.set_ylim(max(lo, 1e-17), hi)


def _tex(text: str) -> str:
    return "".join("\\" + ch if ch in "_%&#$" else ch for ch in str(text))


def _exp(t: float) -> str:
    mant, ex = f"{t:.0e}".split("e")
    return f"10^{{{int(ex)}}}" if mant == "1" else f"{mant}\\cdot 10^{{{int(ex)}}}"


def latex_table(comparisons: dict) -> str:
    """A booktabs LaTeX table (``\\usepackage{booktabs}``) of the comparisons (label ->
    Comparison): per solver the iterations and the solve seconds on the comparisons' clock
    (wall or CPU: ``Comparison.clock``) to each tolerance (medians over repeats; "--" where
    never reached), the final gap and the outcome, one block per mesh."""
    first = next(iter(comparisons.values()))
    tols, clock = first.tolerances, "CPU" if first.clock == "cpu" else "wall"
    cols = 3 + 2 * len(tols)
    lines = [f"% geomopt compare: iterations and solve seconds ({clock} clock, setup excluded) until the",
             "% relative gap (E - E_ref)/|E_ref| first falls to each tolerance; medians over the repeats.",
             f"\\begin{{tabular}}{{l{'r' * (cols - 1)}}}", "\\toprule",
             " & " + " & ".join(f"\\multicolumn{{2}}{{c}}{{gap $\\le {_exp(t)}$}}" for t in tols)
             + " & & \\\\",
             "".join(f"\\cmidrule(lr){{{2 + 2 * k}-{3 + 2 * k}}}" for k in range(len(tols))),
             "solver & " + " & ".join([f"it & {clock} s"] * len(tols)) + " & final gap & outcome \\\\",
             "\\midrule"]
    for label, c in comparisons.items():
        if len(comparisons) > 1:
            lines.append(f"\\multicolumn{{{cols}}}{{l}}{{\\emph{{{_tex(label)}; "
                         f"$E_\\mathrm{{ref}}/A = {c.reference_mean_energy:.10g}$}}}} \\\\")
        for row in c.summary_rows():
            cells = [_tex(row["solver"])]
            for t in tols:
                key = f"{t:.0e}"
                it = row[f"it_to_{key}"]
                seconds = row[f"{'cpu' if c.clock == 'cpu' else 'wall'}_s_to_{key}"]
                cells += ["--"] * 2 if it is None else [str(it), f"{seconds:.2f}"]
            cells += [f"{row['gap']:.1e}", _tex(row["outcome"].replace("_", " "))]
            lines.append(" & ".join(cells) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", ""]
    return "\n".join(lines)


def text_table(rows, tolerances) -> str:
    """Fixed-width text table of summary rows (``mesh`` column when present)."""
    mesh = bool(rows) and "mesh" in rows[0]
    left = (f"{'mesh':>16} " if mesh else "") + f"{'solver':>11} {'outcome':>18} {'iters':>6} {'wall s':>8} " \
                                                f"{'cpu s':>8} {'gap':>8}"
    head = " " * len(left) + "".join(f" | {'to ' + format(t, '.0e'):^21}" for t in tolerances)
    lines = [head, left + " | {:>5} {:>7} {:>7}".format("it", "wall s", "cpu s") * len(tolerances)
             + f" {'setup s':>8} {'flips':>5}"]
    for row in rows:
        line = (f"{row['mesh'][:16]:>16} " if mesh else "") + (
            f"{row['solver']:>11} {row['outcome']:>18} {row['iterations']:>6d} {row['wall_s']:>8.3f} "
            f"{row['cpu_s']:>8.3f} {row['gap']:>8.1e}")
        for t in tolerances:
            key = f"{t:.0e}"
            it = row[f"it_to_{key}"]
            line += (" | {:>5} {:>7} {:>7}".format("never", "-", "-") if it is None else
                     f" | {it:>5d} {row[f'wall_s_to_{key}']:>7.3f} {row[f'cpu_s_to_{key}']:>7.3f}")
        lines.append(line + f" {row['setup_s']:>8.2f} {row['max_flips']:>5d}")
    return "\n".join(lines)

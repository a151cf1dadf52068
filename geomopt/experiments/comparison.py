"""Solver comparison: every solver from the same start map, traced per iteration, measured
against a reference energy, repeated for medians, and recorded with what produced it.

:func:`compare` runs each solver of a list on one problem through the public solver interface
(``init``, then ``terminate`` / ``step`` one iteration at a time), recording after every
iteration the wall and CPU time of the solve, the energy, the gradient norm and the number of
inverted elements by the exact predicate (:mod:`geomopt.exact.predicates`): the point of the
comparison is that every solver stays flip-free.  ``setup`` (``init`` and a first
``terminate``: JIT compilation, sparsity pattern, symbolic analysis) is measured separately and
never counted in the solve time; neither is the bookkeeping done after each step.

**Timing.**  By default (``warmup=True``) each solver first runs :data:`WARMUP_STEPS`
iterations untimed from the same start, through the same loop, and they are discarded: what a
solver compiles lazily during its first steps (AQP's first iterate, the search, the trace) is
then not solve time, at the cost of a few iterations, not a whole solve; ``warmup=False`` times
the first, cold run.  ``clock`` chooses what the
limit ``max_seconds``, the figure's time axis, the LaTeX table and the choice of the median
run use: ``"wall"`` (default; elapsed time, what a user waits and what papers usually report)
or ``"cpu"`` (the process's CPU time, every thread summed: steadier on a loaded, shared machine,
but a solver that runs several threads is charged for all of them).  Both clocks are always
recorded (``history.csv``, ``summary.csv``, the text report).

**Energies.**  ``energy`` is the total ``E = sum_e vol_e psi(J_e)``, ``mean_energy`` is
``E / sum_e vol_e`` (4 at an isometry for symmetric Dirichlet); the relative gap of an iterate
is ``(E - E_ref) / |E_ref|``, the same for both.  The reference ``E_ref`` is, by default
(``reference="auto"``), the energy of a tight projected-Newton solve from the same start
(``rtol=1e-14``; recorded with its outcome), or the lower energy any solver reached if one went
below it; a given mean energy (``reference=7.4464...``), or ``"best"``: the lowest energy any
solver reached (that solver's own gap then ends at 0, which a log plot cannot show).

**Tolerances.**  For each of ``tolerances`` (default 1e-2, 1e-4, 1e-6) the summary gives the
first iteration whose gap is at most the tolerance, and the wall and CPU seconds of the solve
until then; with ``repeat=N`` each solver runs N times and times are medians (iteration
counts are deterministic; the maps and traces kept are those of the median-time run).

Problems: a free-boundary disk surface (Tutte start scaled as in
:func:`~geomopt.parameterize`, or a given start map), a LIM case folder (fixed handles; its
map must be flip-free: untangle a tangled case first), or any :class:`~geomopt.Problem` with
a start map.  :meth:`Comparison.write` writes the traces, the summary, a LaTeX table, a
manifest (every solver's full configuration, the environment, content hashes), one map per
solver and the convergence figure; :class:`ComparisonSet` does the same for several meshes.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from . import manifest as _manifest
from .._runtime.config import options_or_default
from .._runtime.errors import ParameterError
from .._runtime.log import logger
from .._runtime.x64 import float64
from ..energies import energy_spec
from ..objective.objective import Objective
from ..solvers import Newton, Outcome, Progress, iterate
from .options import (CLOCKS, DEFAULT_SOLVERS, FORMATS, HISTORY_COLUMNS, TOLERANCES, WARMUP_STEPS, CompareOptions,
                      summary_columns)

__all__ = ["compare", "compare_meshes", "CompareOptions", "Comparison", "ComparisonSet", "SolverRun", "Reference", "DEFAULT_SOLVERS",
           "TOLERANCES", "HISTORY_COLUMNS", "summary_columns", "exit_status"]

#: the ``reason`` of a solve the time limit stopped (outcome MAX_STEPS)
TIME_LIMIT = "stopped at the time limit (max_seconds)"
#: the reference solve of ``reference="auto"``
REFERENCE_RTOL, REFERENCE_MAX_STEPS = 1e-14, 500


def stopping_rule(solver) -> str:
    """In words, what "converged" means for ``solver`` (it differs between solvers)."""
    inner = getattr(solver, "solver", None)
    if inner is not None and hasattr(inner, "rtol") and hasattr(inner, "atol"):
        return (f"optimistix {type(inner).__name__}'s own test (Cauchy termination: the change in y and "
                f"in f below rtol={inner.rtol:g} / atol={inner.atol:g}); also stops when non-finite, "
                f"diverged or after max_steps={solver.max_steps}")
    return (f"geomopt's test: the decrement -g.d/2 along the solver's own direction d, or a stalled "
            f"energy decrease, at most rtol={solver.rtol:g} x |E|; also stops when non-finite, diverged, "
            f"the line search fails or after max_steps={solver.max_steps}")


@dataclasses.dataclass(frozen=True)
class SolverRun:
    """One solve of one solver in a comparison.

    Attributes
    ----------
    name : the solver's name in the comparison;  solver : the solver object.
    x : (n, d) the final map (problem frame).
    outcome : :class:`~geomopt.solvers.Outcome`;  stopped : ``"max_seconds"`` when the time
        limit ended the solve (``outcome`` is then ``MAX_STEPS``), else None.
    inverted : int, inverted or degenerate elements of ``x`` (exact predicate).
    energy_history : (k + 1,) total energy of every iterate, the start included.
    time_history, cpu_history : (k + 1,) wall and process-CPU seconds of the solve when each
        iterate was reached (setup and bookkeeping excluded).
    grad_history : (k + 1,) Euclidean norm of the total energy's gradient (free DOFs).
    flips_history : (k + 1,) inverted elements of every iterate (exact predicate).
    setup_seconds, setup_cpu_seconds : ``init`` and a first ``terminate`` (compilation...).
    evaluations : energy evaluations the solver counted.
    certificate : :class:`~geomopt.exact.certify.LocalCertificate` of ``x`` (inverted elements, branch
        points, overlapping boundary fans).
    """

    name: str
    solver: Any
    x: np.ndarray
    outcome: Outcome
    stopped: str | None
    inverted: int
    energy_history: np.ndarray
    time_history: np.ndarray
    cpu_history: np.ndarray
    grad_history: np.ndarray
    flips_history: np.ndarray
    setup_seconds: float
    setup_cpu_seconds: float
    evaluations: int
    certificate: Any

    @property
    def iterations(self) -> int:
        return len(self.energy_history) - 1

    @property
    def energy(self) -> float:
        """The final total energy."""
        return float(self.energy_history[-1])

    @property
    def seconds(self) -> float:
        return float(self.time_history[-1])

    @property
    def cpu_seconds(self) -> float:
        return float(self.cpu_history[-1])

    @property
    def status(self) -> str:
        """``"max_seconds"`` for a solve the time limit stopped, else the outcome's value."""
        return self.stopped or self.outcome.value

    @property
    def certified(self) -> bool:
        """No iterate had an inverted or degenerate element and the final map is locally
        injective (exact: :func:`~geomopt.exact.certify.local_certificate`)."""
        return self.certificate.ok and int(self.flips_history.max()) == 0


@dataclasses.dataclass(frozen=True)
class Reference:
    """The energy gaps are measured to: ``energy`` (total), where it came from (``source``:
    ``"auto"``, ``"given"`` or ``"best"``) and ``detail`` (the reference solve's solver,
    outcome, iterations and seconds for ``"auto"``; which solver went lower, if one did)."""

    energy: float
    source: str
    detail: dict


@dataclasses.dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare` on one problem.

    Attributes
    ----------
    runs : dict solver name -> tuple of :class:`SolverRun`, one per repeat, in run order.
    reference : :class:`Reference`, what the gaps are measured to.
    objective : the :class:`~geomopt.Objective` every solver minimised.
    start : (n, d) the start map every solver began from (problem frame).
    mirror : (d,) per-axis signs from the problem frame to the input's (a LIM case given
        clockwise is solved mirrored, :meth:`~geomopt.lim.LimCase.to_problem`); maps are
        written as ``x * mirror``.
    label : str, a short description of the problem for titles.
    tolerances : the gaps the summary reports iterations and seconds to.
    source : dict, where the problem came from (input path and file hash, start map) for the
        manifest.
    clock : ``"wall"`` or ``"cpu"``: the seconds the figure, the LaTeX table and the median run
        use (:meth:`times`); both are recorded.
    warmup : whether each solver ran once untimed before its timed runs.
    """

    runs: dict
    reference: Reference
    objective: Objective
    start: np.ndarray
    mirror: np.ndarray
    label: str = ""
    tolerances: tuple = TOLERANCES
    source: dict = dataclasses.field(default_factory=dict)
    clock: str = "wall"
    warmup: bool = False

    def times(self, run: SolverRun) -> np.ndarray:
        """(iterations + 1,) solve seconds of every iterate of ``run`` on :attr:`clock`."""
        return run.cpu_history if self.clock == "cpu" else run.time_history

    @property
    def results(self) -> dict:
        """Solver name -> the :class:`SolverRun` of median time (on :attr:`clock`) among its
        repeats (its map and traces are the ones written and drawn)."""
        out = {}
        for name, runs in self.runs.items():
            order = np.argsort([self.times(r)[-1] for r in runs], kind="stable")
            out[name] = runs[int(order[(len(runs) - 1) // 2])]
        return out

    @property
    def area(self) -> float:
        """The total rest area (volume) mean energies are divided by."""
        return self.objective.total_volume

    @property
    def reference_mean_energy(self) -> float:
        return self.reference.energy / self.area

    @property
    def best_mean_energy(self) -> float:
        """The lowest mean energy any solver reached (any repeat)."""
        return min(float(np.min(r.energy_history)) for rs in self.runs.values() for r in rs) / self.area

    def outcome(self, name) -> str:
        """``"max_seconds"`` for a solve the time limit stopped, else its outcome's value."""
        return self.results[name].status

    def gap(self, name, run: SolverRun | None = None) -> np.ndarray:
        """(iterations + 1,) relative gap ``(E - E_ref) / |E_ref|`` of every iterate of
        ``name``'s median run (or of ``run``)."""
        e = (run or self.results[name]).energy_history
        return (e - self.reference.energy) / max(abs(self.reference.energy), 1e-300)

    def hits(self, run: SolverRun) -> list:
        """Per tolerance: ``(iteration, wall s, CPU s)`` of the first iterate of ``run``
        whose gap is at most the tolerance, or None."""
        gap = self.gap(run.name, run)
        out = []
        for tol in self.tolerances:
            k = np.flatnonzero(gap <= tol)
            out.append(None if k.size == 0 else (int(k[0]), float(run.time_history[k[0]]),
                                                 float(run.cpu_history[k[0]])))
        return out

    def summary_rows(self) -> list:
        """Rows of ``summary.csv`` (:func:`summary_columns`) as dicts, one per solver; times
        are medians over the repeats, tolerance times medians over the repeats that got there."""
        rows = []
        for name, runs in self.runs.items():
            r = self.results[name]
            row = {"solver": name, "outcome": r.status, "certified": all(x.certified for x in runs),
                   "iterations": r.iterations, "wall_s": _median(x.seconds for x in runs),
                   "cpu_s": _median(x.cpu_seconds for x in runs), "setup_s": runs[0].setup_seconds,
                   "setup_cpu_s": runs[0].setup_cpu_seconds,
                   "s_per_it": _median(self.times(x)[-1] / max(x.iterations, 1) for x in runs), "energy": r.energy,
                   "mean_energy": r.energy / self.area, "gap": float(self.gap(name)[-1]),
                   "max_flips": max(int(x.flips_history.max()) for x in runs), "repeats": len(runs)}
            hits = [self.hits(x) for x in runs]
            for j, tol in enumerate(self.tolerances):
                got = [h[j] for h in hits if h[j] is not None]
                key = f"{tol:.0e}"
                row[f"it_to_{key}"] = int(_median(g[0] for g in got)) if got else None
                row[f"wall_s_to_{key}"] = _median(g[1] for g in got) if got else None
                row[f"cpu_s_to_{key}"] = _median(g[2] for g in got) if got else None
            rows.append(row)
        return rows

    def history_rows(self):
        """Rows of ``history.csv`` (:data:`HISTORY_COLUMNS`): every iterate of every repeat."""
        rows = []
        for name, runs in self.runs.items():
            for rep, r in enumerate(runs):
                gap = self.gap(name, r)
                for k in range(len(r.energy_history)):
                    e = float(r.energy_history[k])
                    rows.append((name, rep, k, float(r.time_history[k]), float(r.cpu_history[k]), e,
                                 e / self.area, float(gap[k]), float(r.grad_history[k]),
                                 int(r.flips_history[k])))
        return rows

    def describe_reference(self) -> str:
        ref, d = self.reference, self.reference.detail
        text = f"reference mean energy {self.reference_mean_energy:.10g}"
        if ref.source == "auto":
            text += (f" (Newton, rtol {d['rtol']:g}: {d['iterations']} iterations, {d['outcome']}"
                     f"{'; ' + d['lower'] + ' went lower' if d.get('lower') else ''})")
        elif ref.source == "given":
            text += " (given)"
        else:
            text += " (the lowest any solver reached)"
        return text

    def report(self) -> str:
        """A plain-text table: per solver the outcome, totals, and iterations / wall / CPU
        seconds to each tolerance (medians over the repeats)."""
        from .report import text_table

        reps = max(len(r) for r in self.runs.values())
        head = (f"{self.label}; {self.describe_reference()}" + (f"; medians of {reps} runs" if reps > 1 else "")
                + f"; {'after an untimed warm-up' if self.warmup else 'cold (no warm-up)'}, {self.clock} clock")
        return head + "\n" + text_table(self.summary_rows(), self.tolerances)

    def manifest(self) -> dict:
        """Everything needed to reproduce or question the numbers: versions, environment,
        problem (hashes), energy, start, reference, settings and every solver's full
        configuration and stopping rule."""
        problem = self.objective.problem
        solvers = {}
        for name, runs in self.runs.items():
            solvers[name] = {"config": _manifest.config(runs[0].solver), "stopping": stopping_rule(runs[0].solver)}
        energy = self.objective.energy
        return {
            "problem": {**self.source, "kind": problem.kind, "dim": problem.dim, "vertices": problem.n_vertices,
                        "elements": problem.n_elements, "fixed_vertices": int(problem.fixed.size),
                        "rest_area": self.area,
                        "mesh_sha256": _manifest.array_hash(problem.rest_vertices, problem.input_simplices)},
            "energy": {"name": energy.name, "params": _manifest.config(dict(self.objective.params())),
                       "convention": "energy = total sum_e vol_e psi(J_e); mean_energy = energy / rest_area"},
            "start_sha256": _manifest.array_hash(self.start),
            "reference": {"energy": self.reference.energy, "mean_energy": self.reference_mean_energy,
                          "source": self.reference.source, **_manifest.config(self.reference.detail)},
            "tolerances": list(self.tolerances), "solvers": solvers,
            "timing": {"clock": self.clock, "warmup": self.warmup,
                       "convention": "solve seconds exclude setup and bookkeeping; clock 'cpu' is the "
                                     "process CPU time (all threads), 'wall' elapsed time"},
        }

    def figure(self, log_x: bool = False, dpi: int = 100, layout: str = "wide", font_size: float | None = None):
        """The convergence figure (:func:`geomopt.experiments.report.comparison_figure`: ``layout``
        ``"wide"`` or ``"column"``, ``font_size`` in points); save it with
        :func:`geomopt.experiments.report.save_figure` for TrueType fonts in PDF."""
        from .report import comparison_figure

        return comparison_figure({self.label: self}, log_x=log_x, dpi=dpi, layout=layout, font_size=font_size)

    def output_names(self, formats=("png",)):
        """The file names :meth:`write` writes."""
        from .writers import output_names

        return output_names(list(self.runs), self.objective.problem.dim, formats)

    def write(self, out, formats=("png",), log_x=False, extra=None, *, layout="wide", font_size=None) -> dict:
        """Write ``history.csv``, ``summary.csv``, ``table.tex``, ``manifest.json``, a map per
        solver and ``convergence.<format>`` per format into the folder ``out`` (created if
        missing, not its parents: :func:`geomopt.io.check_outputs`), each atomically; ``extra``
        is added to the manifest; ``log_x``, ``layout``, ``font_size``: :meth:`figure`.

        Returns
        -------
        dict file kind -> pathlib.Path.
        """
        from .writers import write_comparison

        return write_comparison(self, out, formats, log_x, extra, layout=layout, font_size=font_size)


@dataclasses.dataclass(frozen=True)
class ComparisonSet:
    """Comparisons of the same solvers on several meshes, as one table and one figure.

    Attributes
    ----------
    comparisons : dict mesh name -> :class:`Comparison`, in order.
    """

    comparisons: dict

    def report(self) -> str:
        return "\n\n".join(c.report() for c in self.comparisons.values())

    def summary_rows(self) -> list:
        """Every comparison's :meth:`Comparison.summary_rows`, each with ``mesh`` first."""
        return [{"mesh": key, **row} for key, c in self.comparisons.items() for row in c.summary_rows()]

    def figure(self, log_x: bool = False, dpi: int = 100, layout: str = "wide", font_size: float | None = None):
        """:meth:`Comparison.figure` of every comparison, one row (wide) or panel (column) each."""
        from .report import comparison_figure

        return comparison_figure({c.label: c for c in self.comparisons.values()}, log_x=log_x, dpi=dpi,
                                 layout=layout, font_size=font_size)

    def output_names(self, formats=("png",)):
        """The file names :meth:`write` writes."""
        from .writers import set_output_names

        return set_output_names(self, formats)

    def write(self, out, formats=("png",), log_x=False, extra=None, **figure) -> dict:
        """Each comparison into ``out/<mesh name>/`` (:meth:`Comparison.write`), then
        :meth:`write_combined`; ``figure``: ``layout``, ``font_size``."""
        from .writers import write_set

        return write_set(self, out, formats, log_x, extra, **figure)

    def write_combined(self, out, formats=("png",), log_x=False, extra=None, *, layout="wide",
                       font_size=None) -> dict:
        """Over all comparisons: ``summary.csv`` (with a ``mesh`` column), ``table.tex``,
        ``manifest.json`` and ``convergence.<format>`` (one row of panels per mesh) in ``out``."""
        from .writers import write_combined

        return write_combined(self, out, formats, log_x, extra, layout=layout, font_size=font_size)


def exit_status(comparisons) -> int:
    """The command's exit status over a :class:`Comparison` or :class:`ComparisonSet`: 0 when
    every solver (every repeat) converged and neither an iterate nor its final map had an
    inverted element (exact predicate), else 1."""
    items = comparisons.comparisons.values() if isinstance(comparisons, ComparisonSet) else [comparisons]
    ok = all(r.outcome is Outcome.CONVERGED and r.stopped is None and r.certified
             for c in items for runs in c.runs.values() for r in runs)
    return 0 if ok else 1


def _median(values) -> float:
    return float(np.median(np.fromiter(values, np.float64)))


# ------------------------------------------------------------------------------ running


@float64
def compare(mesh, faces=None, energy="symmetric_dirichlet", solvers=None, *, x0=None,
            options: CompareOptions | None = None, out=None, progress=False) -> Comparison:
    """Run several solvers on one problem from the same start map and trace each iteration.

    Parameters
    ----------
    mesh : what to solve:

        * a mesh file path (OBJ/OFF/PLY/STL, a disk): free-boundary parameterization;
        * a LIM case folder (``input.obj`` + ``handles.txt``, or ``rest.vtk`` + ``init.vtk``):
          fixed handles, the case's map as the start (:meth:`~geomopt.lim.LimCase.to_problem`);
        * an (n, 3) (surface) or (n, 2) (planar) vertex array, with ``faces`` (m, 3):
          free-boundary parameterization;
        * a :class:`~geomopt.Problem` (handles included); ``x0`` is then required unless it
          has no handles and maps to 2D (then the Tutte start).
    faces : (m, 3) int, only with a vertex array.
    energy : energy name or :class:`~geomopt.energies.Energy`, or ``(name, {parameter: value})``
        (:func:`geomopt.energies.energy_spec`).
    solvers : names (``geomopt.solvers.SOLVERS``), solver objects, or a dict name -> solver
        (names become file names: letters, digits, ``_.+-``).  Default
        :data:`DEFAULT_SOLVERS` (without ``cm`` for tets).
    x0 : (n, d) start map, used as given (not rescaled; in the input's frame for a LIM case).
        Default: the free-boundary Tutte start (:func:`~geomopt.param.start_map`, the options'
        ``weights``) or the LIM case's map.  It must be flip-free (exact predicate).
    options : :class:`~geomopt.experiments.options.CompareOptions`: time and iteration limits,
        the reference, repeats and warm-up, the clock, the tolerances and the figure's formats,
        axis and layout (see the module notes, Timing).
    out : folder to :meth:`~Comparison.write` the files into; every output path is checked
        *before* solving (:func:`geomopt.io.check_outputs`: none may replace the input ``mesh``,
        and the folder's parent must exist), the folder is created after solving.
    progress : True: each solve's progress (:class:`~geomopt.solvers.Progress`) and one record
        per run on the ``geomopt`` logger (INFO).

    Returns
    -------
    :class:`Comparison`

    Raises
    ------
    MeshError : invalid mesh or start map, or a start map with inverted elements.
    ParameterError : unknown or duplicate solver, invalid limits, ``cm`` on tets.
    GeomoptError : the output folder or a file in it cannot be written.

    Examples
    --------
    Two solvers on a tent of four triangles, from the same Tutte start (``out=`` would write the
    traces, tables and figures):

    >>> import geomopt
    >>> V = [[0, 0, 0.5], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
    >>> F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]
    >>> comparison = geomopt.compare(V, F, solvers=["newton", "lbfgs"])
    >>> {name: run.outcome.value for name, run in comparison.results.items()}
    {'newton': 'converged', 'lbfgs': 'converged'}
    """
    from . import inputs, writers

    settings = options_or_default(CompareOptions, options, "compare")
    energy, energy_params = energy_spec(energy, where="compare")
    objective, start, mirror, label, source = inputs.comparison_problem(mesh, faces, energy, x0, settings.weights,
                                                                         energy_params)
    problem = objective.problem
    named = inputs.comparison_solvers(solvers, problem, settings.max_steps)
    if out is not None:
        writers.prepare_folder(out, writers.output_names(list(named), problem.dim, settings.formats),
                               writers.input_files([mesh]), create=False)
    label = f"{label}: {problem.n_elements} {'tets' if problem.dim == 3 else 'triangles'}, {objective.energy.name}"
    runs, limit, clock = {}, settings.max_seconds, settings.clock
    for name, solver in named.items():
        if settings.warmup:
            _warm_up(solver, objective, start)
        runs[name] = tuple(_run(name, solver, objective, start, limit, progress,
                                f" [{k + 1}/{settings.repeat}]" if settings.repeat > 1 else "", clock)
                           for k in range(settings.repeat))
    ref = _reference(settings.reference, runs, objective, start, progress)
    comparison = Comparison(runs, ref, objective, start, mirror, label, settings.tolerances, source, clock,
                            settings.warmup)
    if out is not None:
        comparison.write(out, settings.formats, settings.log_x, layout=settings.layout, font_size=settings.font_size)
    return comparison


def compare_meshes(meshes, energy="symmetric_dirichlet", solvers=None, *, options: CompareOptions | None = None,
                   out=None, progress=False) -> ComparisonSet:
    """:func:`compare` on each of several meshes (paths, or a dict name -> mesh) with the same
    ``energy``, ``solvers`` and ``options``; with ``out``, each comparison is written into
    ``out/<name>/`` (its outputs checked before it is solved) and the combined table, manifest
    and figure into ``out``.

    Names are the file names without extension (folder names for LIM cases); they must differ.
    """
    from . import inputs, writers

    options = options_or_default(CompareOptions, options, "compare_meshes")
    energy, energy_params = energy_spec(energy, where="compare_meshes")
    if not isinstance(meshes, dict):
        meshes = {inputs.mesh_key(m): m for m in meshes} if len({inputs.mesh_key(m) for m in meshes}) == len(meshes) else None
        if meshes is None:
            raise ParameterError("compare: two meshes have the same file name; their outputs would share a "
                                 "folder: rename one")
    for key in meshes:
        if not inputs.NAME.fullmatch(str(key)):
            raise ParameterError(f"compare: mesh name {key!r} cannot be a folder name; use letters, digits and _.+-")
    if out is not None:  # created now: each mesh's folder is checked in it before its solves
        out = writers.prepare_folder(out, writers.common_names(options.formats), writers.input_files(meshes.values()))
    comparisons = {key: compare(mesh, energy=(energy, energy_params), solvers=solvers, options=options,
                                out=None if out is None else out / key, progress=progress)
                   for key, mesh in meshes.items()}
    result = ComparisonSet(comparisons)
    if out is not None:
        result.write_combined(out, options.formats, options.log_x, layout=options.layout, font_size=options.font_size)
    return result


def _run(name, solver, objective, x0, max_seconds, progress, tag="", clock="wall") -> SolverRun:
    """One solver through :func:`~geomopt.solvers.iterate`, every iterate observed: its
    inverted elements counted (exact) and the time limit applied (on ``clock``).  Only the solver's calls are
    timed (wall and process CPU); the observer's time is not solve time.  The final map is
    certified there (:class:`~geomopt.solvers.LocalCertificate`): a CONVERGED solve whose map
    is not locally injective ends NOT_INJECTIVE."""
    problem = objective.problem
    report = Progress(prefix=f"{name}{tag} ", total=solver.max_steps, every=50) if progress else None
    flips = [problem.count_inverted(np.asarray(x0))]

    def observe(state, seconds):
        flips.append(problem.count_inverted(objective.unpad_map(np.asarray(state.x))))
        return TIME_LIMIT if max_seconds is not None and seconds >= max_seconds else None

    res = iterate(solver, objective, x0, objective.params(), observe=observe, progress=report, trace=True,
                  clock=clock)
    t, st = res.trace, res.stats
    run = SolverRun(name, solver, res.x, res.outcome, "max_seconds" if res.reason == TIME_LIMIT else None,
                    res.certificate.inverted, t.energy, t.seconds, t.cpu_seconds, t.grad_norm,
                    np.asarray(flips, np.int64), st.setup_seconds, st.setup_cpu_seconds, st.evaluations,
                    res.certificate)
    if progress:
        logger.info(f"{name}{tag}: {run.iterations} it, {run.seconds:.2f} s (cpu {run.cpu_seconds:.2f} s) + setup "
                    f"{run.setup_seconds:.2f} s, mean energy {run.energy / objective.total_volume:.10g}, max flips "
                    f"{int(run.flips_history.max())}, {run.status}")
    return run


def _warm_up(solver, objective, start):
    """:data:`WARMUP_STEPS` untimed, discarded iterations of ``solver`` through the same loop as
    its timed runs (every iterate traced): what it compiles lazily (its step, the search, the
    trace's kernels) is compiled here, not in its timed run."""
    short = dataclasses.replace(solver, max_steps=min(solver.max_steps, WARMUP_STEPS))
    iterate(short, objective, start, objective.params(), progress=False, trace=True, warn=False)


def _reference(reference, runs, objective, start, progress) -> Reference:
    """The energy gaps are measured to (see :func:`compare`'s ``reference``)."""
    finals = {name: float(np.min(r.energy_history[np.isfinite(r.energy_history)], initial=np.inf))
              for name, rs in runs.items() for r in rs}
    best_name = min(finals, key=finals.get)
    if reference == "best":
        return Reference(finals[best_name], "best", {"solver": best_name})
    if reference != "auto":
        return Reference(float(reference) * objective.total_volume, "given", {"mean_energy": float(reference)})
    solver = Newton(rtol=REFERENCE_RTOL, max_steps=REFERENCE_MAX_STEPS)
    run = _run("reference", solver, objective, start, None, progress)
    energy = float(np.min(run.energy_history))
    detail = {"solver": solver, "rtol": REFERENCE_RTOL, "outcome": run.status, "iterations": run.iterations,
              "seconds": run.seconds, "energy": energy, "certified": run.certified}
    if finals[best_name] < energy:  # a solver went lower: the reference is the lowest energy known
        detail["lower"] = best_name
        energy = finals[best_name]
    return Reference(energy, "auto", detail)

"""Solver comparison: every solver from the same start map, with per-iteration traces.

:func:`compare` runs each solver of a list on one problem through the public solver interface
(``init``, then ``terminate`` / ``step`` one iteration at a time), recording after every
iteration the solve time, the energy, the gradient norm and the number of inverted elements
by the exact predicate (:mod:`geomopt.predicates`): the point of the comparison is that every
solver stays flip-free.  ``setup_seconds`` (``init`` and a first ``terminate``: JIT
compilation, sparsity pattern, symbolic analysis) is measured separately and never counted in
the solve time; neither is the bookkeeping (gradient norm, inverted count) done after each
step.  What a solver compiles lazily during its first steps does count as solve time.

Energies in the traces and files are area-weighted means ``E / total rest area`` (4 at an
isometry for symmetric Dirichlet), gradient norms those of the same mean; relative gaps are
``(E - E_best) / |E_best|`` with ``E_best`` the lowest energy any solver reached.

Problems: a free-boundary disk surface (Tutte start scaled as in
:func:`~geomopt.parameterize`, or a given start map), a LIM case folder (fixed handles; its
map must be flip-free: untangle a tangled case first), or any :class:`~geomopt.Problem` with
a start map.  :meth:`Comparison.write` writes ``history.csv``, ``summary.csv``, one map per
solver (``<solver>.obj`` with one ``vt`` per vertex as ``geomopt param`` writes it; ``.vtk``
for tets) and ``convergence.png``, each atomically.
"""

from __future__ import annotations

import csv
import dataclasses
import io as _io
import math
import re
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from . import io
from ._errors import GeomoptError, MeshError, ParameterError
from ._objective import Objective
from .problem import Problem
from .solvers import CM, Outcome, Progress, Result, get_solver

__all__ = ["compare", "Comparison", "DEFAULT_SOLVERS", "HISTORY_COLUMNS", "SUMMARY_COLUMNS"]

#: what ``geomopt compare`` runs when no ``--solvers`` is given (``cm`` is left out in 3D)
DEFAULT_SOLVERS = ("newton", "lbfgs", "slim", "aqp", "cm")
HISTORY_COLUMNS = ("solver", "iteration", "time_s", "energy", "grad_norm", "flips")
SUMMARY_COLUMNS = ("solver", "outcome", "iterations", "solve_s", "compile_s", "s_per_it",
                   "final_energy", "gap", "flips", "max_flips")
GAP_FLOOR = 1e-16  # relative gaps are drawn no lower than this (a log scale has no zero)
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]*")
# optimistix's BFGS keeps a dense (n d) x (n d) inverse Hessian; refuse what cannot fit
_DENSE_SOLVERS = ("optx-bfgs",)
_DENSE_LIMIT_BYTES = 2 << 30


@dataclasses.dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare`.

    Attributes
    ----------
    results : dict solver name -> :class:`~geomopt.Result`, in run order.  Besides the usual
        fields each ``info`` holds ``flips_history`` ((iterations + 1,) int, inverted elements
        of every iterate, start included) and ``stopped`` (``"max_seconds"`` when the time
        limit ended the solve, else None).
    best_energy : float, the lowest total energy any solver reached (``E_best``).
    objective : the :class:`~geomopt.Objective` every solver minimised.
    start : (n, d) the start map every solver began from (problem frame).
    mirror : (d,) per-axis signs from the problem frame to the input's (a LIM case given
        clockwise is solved mirrored, :func:`~geomopt.untangle.lim_problem`); maps are
        written as ``x * mirror``.
    label : str, a short description of the problem for titles.
    """

    results: dict
    best_energy: float
    objective: Objective
    start: np.ndarray
    mirror: np.ndarray
    label: str = ""

    @property
    def area(self) -> float:
        """The total rest area (volume) the mean energies are divided by."""
        return self.objective.total_volume

    @property
    def best_mean_energy(self) -> float:
        return self.best_energy / self.area

    def outcome(self, name) -> str:
        """``"max_seconds"`` for a solve the time limit stopped, else the outcome's value."""
        res = self.results[name]
        return res.info.get("stopped") or res.outcome.value

    def gap(self, name) -> np.ndarray:
        """(iterations + 1,) relative gap ``(E - E_best) / |E_best|`` of every iterate."""
        e = self.results[name].energy_history
        return (e - self.best_energy) / max(abs(self.best_energy), 1e-300)

    def history_rows(self):
        """Rows of ``history.csv`` (:data:`HISTORY_COLUMNS`), one per solver and iterate."""
        rows = []
        for name, r in self.results.items():
            flips = r.info["flips_history"]
            for k in range(len(r.energy_history)):
                rows.append((name, k, float(r.time_history[k]), float(r.energy_history[k]) / self.area,
                             float(r.grad_history[k]) / self.area, int(flips[k])))
        return rows

    def summary_rows(self):
        """Rows of ``summary.csv`` (:data:`SUMMARY_COLUMNS`), one per solver."""
        rows = []
        for name, r in self.results.items():
            rows.append((name, self.outcome(name), r.iterations, r.seconds, r.setup_seconds,
                         r.seconds / max(r.iterations, 1), r.energy / self.area, float(self.gap(name)[-1]),
                         r.inverted, int(np.max(r.info["flips_history"]))))
        return rows

    def report(self) -> str:
        """A plain-text table of :meth:`summary_rows`."""
        lines = [f"{self.label}; best energy {self.best_mean_energy:.10g}",
                 f"{'solver':>11} {'outcome':>18} {'iters':>6} {'solve s':>8} {'compile s':>9} "
                 f"{'s/it':>8} {'energy':>16} {'gap':>8} {'max flips':>9}"]
        for name, outcome, it, solve, setup, spi, e, gap, _, max_flips in self.summary_rows():
            lines.append(f"{name:>11} {outcome:>18} {it:>6d} {solve:>8.3f} {setup:>9.2f} {spi:>8.4f} "
                         f"{e:>16.10g} {gap:>8.1e} {max_flips:>9d}")
        return "\n".join(lines)

    def figure(self, dpi=100):
        """A matplotlib Figure (Agg canvas, no pyplot state; 10 x 4 inches at ``dpi``): the
        relative gap, log scale, against solve seconds (left) and iterations (right), one curve
        per solver."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(10, 4), dpi=dpi)
        FigureCanvasAgg(fig)
        left, right = fig.subplots(1, 2, sharey=True)
        for name, r in self.results.items():
            gap = np.maximum(self.gap(name), GAP_FLOOR)
            left.semilogy(r.time_history, gap, marker=".", ms=3, label=name)
            right.semilogy(np.arange(len(gap)), gap, marker=".", ms=3, label=name)
        left.set_xlabel("solve seconds (setup excluded)")
        right.set_xlabel("iteration")
        left.set_ylabel("(E - E_best) / E_best")
        for ax in (left, right):
            ax.grid(True, which="both", alpha=0.3)
        right.legend(fontsize=8)
        fig.suptitle(f"{self.label}; E_best = {self.best_mean_energy:.10g}", fontsize=10)
        fig.tight_layout()
        return fig

    def output_names(self):
        """The file names :meth:`write` writes."""
        return _output_names(list(self.results), self.objective.problem.dim)

    def write(self, out) -> dict:
        """Write ``history.csv``, ``summary.csv``, a map per solver and ``convergence.png``
        into the folder ``out`` (created if missing), each atomically.

        Returns
        -------
        dict file kind (``"history"``, ``"summary"``, ``"convergence"``, or a solver name) ->
        pathlib.Path.
        """
        out = _prepare_folder(out, self.output_names())
        problem = self.objective.problem
        paths = {"history": out / "history.csv", "summary": out / "summary.csv"}
        _write_csv(paths["history"], HISTORY_COLUMNS, self.history_rows())
        _write_csv(paths["summary"], SUMMARY_COLUMNS, self.summary_rows())
        V = np.asarray(problem.rest_vertices, np.float64)
        for name, r in self.results.items():
            x = np.asarray(r.x) * self.mirror  # negation is exact
            if problem.elements is not None:  # quads (.obj) / hexahedra (.vtk): the cells themselves
                kind = "quad" if problem.elements.shape[1] == 4 else "hexahedron"
                paths[name] = io.write_cells(out / f"{name}{'.obj' if kind == 'quad' else '.vtk'}", x,
                                             problem.elements, kind)
            elif problem.dim == 2:
                V3 = V if V.shape[1] == 3 else np.c_[V, np.zeros(len(V))]
                paths[name] = io.write_obj_with_uv(out / f"{name}.obj", V3, problem.input_simplices, x)
            else:
                paths[name] = io.write_vtk_tets(out / f"{name}.vtk", x, problem.input_simplices)
        buf = _io.BytesIO()
        self.figure().savefig(buf, format="png")
        paths["convergence"] = io.atomic_write(out / "convergence.png", lambda fh: fh.write(buf.getvalue()),
                                               mode="wb")
        return paths


# ------------------------------------------------------------------------------ running


def compare(mesh, faces=None, *, solvers=None, energy="symmetric_dirichlet", x0=None, weights="uniform",
            max_seconds=None, max_steps=None, out=None, progress=False, **energy_params) -> Comparison:
    """Run several solvers on one problem from the same start map and trace each iteration.

    Parameters
    ----------
    mesh : what to solve:

        * a mesh file path (OBJ/OFF/PLY/STL, a disk): free-boundary parameterization;
        * a LIM case folder (``input.obj`` + ``handles.txt``, or ``rest.vtk`` + ``init.vtk``):
          fixed handles, the case's map as the start (:func:`~geomopt.untangle.lim_problem`);
        * an (n, 3) (surface) or (n, 2) (planar) vertex array, with ``faces`` (m, 3):
          free-boundary parameterization;
        * a :class:`~geomopt.Problem` (handles included); ``x0`` is then required unless it
          has no handles and maps to 2D (then the Tutte start).
    faces : (m, 3) int, only with a vertex array.
    solvers : names (``geomopt.solvers.SOLVERS``), solver objects, or a dict name -> solver
        (names become file names: letters, digits, ``_.+-``).  Default
        :data:`DEFAULT_SOLVERS` (without ``cm`` for tets).
    energy : energy name or :class:`~geomopt.energies.Energy`; ``energy_params`` override its
        parameters.
    x0 : (n, d) start map, used as given (not rescaled; in the input's frame for a LIM case).
        Default: the free-boundary Tutte start (:func:`~geomopt.param.start_map`, ``weights``)
        or the LIM case's map.  It must be flip-free (exact predicate).
    max_seconds : float > 0, stop a solver once its solve time (setup excluded) reaches this;
        its outcome is then ``"max_seconds"`` (``Result.outcome`` ``MAX_STEPS``).
    max_steps : int >= 1, iteration limit of every solver (default: each solver's own).
    out : folder to :meth:`~Comparison.write` the files into; it is created and every output
        path checked *before* solving.
    progress : True: per-iteration progress and one line per solver on stderr.

    Returns
    -------
    :class:`Comparison`

    Raises
    ------
    MeshError : invalid mesh or start map, or a start map with inverted elements.
    ParameterError : unknown or duplicate solver, invalid limits, ``cm`` on tets.
    GeomoptError : the output folder or a file in it cannot be written.
    """
    objective, start, mirror, label = _problem(mesh, faces, energy, x0, weights, energy_params)
    problem = objective.problem
    named = _solvers(solvers, problem, max_steps)
    if max_seconds is not None:
        max_seconds = _positive(max_seconds, "max_seconds")
    if out is not None:
        _prepare_folder(out, _output_names(list(named), problem.dim))
    label = f"{label}: {problem.n_elements} {'tets' if problem.dim == 3 else 'triangles'}, " \
            f"{objective.energy.name}"
    results = {}
    for name, solver in named.items():
        results[name] = _run(name, solver, objective, start, max_seconds, progress)
    finals = [np.min(r.energy_history[np.isfinite(r.energy_history)], initial=np.inf)
              for r in results.values()]
    comparison = Comparison(results, float(min(finals)), objective, start, mirror, label)
    if out is not None:
        comparison.write(out)
    return comparison


def _run(name, solver, objective, x0, max_seconds, progress) -> Result:
    """One solver through ``init`` / ``terminate`` / ``step``, timing only those calls."""
    problem = objective.problem
    params = objective.params()
    report = Progress(prefix=f"{name} ", total=solver.max_steps, every=50) if progress else None
    t0 = time.perf_counter()
    state = solver.init(objective, x0, params)
    solver.terminate(state)  # its first call compiles the stopping test's small kernels
    setup = time.perf_counter() - t0
    energies, times, grads = [state.value], [0.0], [_norm(state.grad)]
    flips = [problem.count_inverted(np.asarray(state.x))]
    solve, stopped = 0.0, None
    try:
        while True:
            t0 = time.perf_counter()
            done, outcome = solver.terminate(state)
            solve += time.perf_counter() - t0
            if done:
                break
            if max_seconds is not None and solve >= max_seconds:
                outcome, stopped = Outcome.MAX_STEPS, "max_seconds"
                break
            t0 = time.perf_counter()
            state = solver.step(state)
            solve += time.perf_counter() - t0
            energies.append(state.value)
            times.append(solve)
            grads.append(_norm(state.grad))
            flips.append(problem.count_inverted(np.asarray(state.x)))
            if report:
                report(state, solve, state.value / objective.total_volume)
    finally:
        if report:
            report.close()
    x = np.asarray(state.x)
    if not np.isfinite(x).all():
        outcome, x = Outcome.NONFINITE, np.asarray(x0)
    inverted = problem.count_inverted(x)
    if outcome is Outcome.CONVERGED and inverted:
        outcome = Outcome.NOT_INJECTIVE
    result = Result(x=x, outcome=outcome, inverted=inverted, energy=float(state.value),
                    energy_history=np.asarray(energies, np.float64), iterations=state.iteration,
                    seconds=solve, setup_seconds=setup, time_history=np.asarray(times),
                    grad_history=np.asarray(grads), info={"solver": solver, "stopped": stopped,
                                                          "flips_history": np.asarray(flips, np.int64),
                                                          "evaluations": state.evaluations})
    if progress:
        print(f"{name}: {result.iterations} it, {solve:.2f} s + setup {setup:.2f} s, energy "
              f"{result.energy / objective.total_volume:.10g}, max flips {max(flips)}, "
              f"{stopped or outcome.value}", file=sys.stderr, flush=True)
    return result


def _norm(g) -> float:
    return float(jnp.sqrt(jnp.vdot(g, g))) if g is not None else float("nan")


# ------------------------------------------------------------------------------ inputs


def _problem(mesh, faces, energy, x0, weights, energy_params):
    """``(objective, start map, mirror, label)`` for :func:`compare`'s ``mesh`` argument."""
    from .param import start_map

    mirror, case, given = None, None, x0 is not None
    if isinstance(mesh, (Problem, str, Path)) and faces is not None:
        raise ParameterError("compare: give faces only with a vertex array, not with a path or a Problem")
    if isinstance(mesh, Problem):
        problem, label = mesh, f"{mesh.kind} problem"
    elif isinstance(mesh, (str, Path)):
        path = Path(mesh)
        label = path.name
        if path.is_dir():
            from .lim import LimCase
            from .untangle import lim_problem

            case = path
            problem, case_x0, _, mirror = lim_problem(LimCase.read(path))
            x0 = case_x0 if x0 is None else io.validate_vertices(x0, "start map x0", dim=problem.dim) * mirror
        else:
            problem = Problem.surface(*io.read_mesh(path))
    else:
        if faces is None:
            raise ParameterError("compare: give the faces (m, 3) with a vertex array, or a mesh path, "
                                 "a LIM case folder or a Problem")
        V = io.validate_vertices(mesh, "compare: vertices")
        problem = (Problem.planar if V.shape[1] == 2 else Problem.surface)(V, faces)
        label = "mesh"
    objective = Objective(problem, energy, **energy_params)
    if problem.fixed.size == 0 and problem.dim == 2:
        from .param import check_scale_aware

        check_scale_aware(energy, energy_params)
    if x0 is None:
        if problem.fixed.size or problem.dim != 2 or problem.elements is not None:
            raise ParameterError(f"compare: a {problem.kind} problem with {problem.fixed.size} fixed "
                                 f"vertices needs a start map x0; only free-boundary 2D maps default "
                                 f"to the Tutte start")
        x0, _, _ = start_map(objective, None, weights)
    x0 = problem.check_map(x0, "start map x0")
    inverted = problem.count_inverted(x0)
    if inverted:
        what = "tetrahedra" if problem.dim == 3 else "triangle(s)"
        source = "the start map x0" if given else "the start map"
        if case is not None:
            source = source if given else f"the map of LIM case {case}"
            hint = (f"untangle it first (geomopt untangle {case} -o DIR/input.obj, copy its handles "
                    f"file into DIR, then compare DIR)" if problem.dim == 2 else
                    f"untangle it first (geomopt untangle {case} -o DIR/init.vtk, copy its rest.vtk and "
                    f"handles file into DIR, then compare DIR)")
        else:
            hint = "untangle it first (geomopt.untangle) or give a flip-free x0"
        raise MeshError(f"{source} has {inverted} inverted or degenerate {what}; compare needs a "
                        f"flip-free start map so that every solver can stay flip-free: {hint}")
    return objective, x0, np.ones(problem.dim) if mirror is None else mirror, label


def _solvers(solvers, problem, max_steps) -> dict:
    """``{name: solver}`` with ``max_steps`` applied, checked before anything runs."""
    if solvers is None:
        solvers = [s for s in DEFAULT_SOLVERS if problem.dim == 2 or s != "cm"]
    if isinstance(solvers, str):
        solvers = [s for s in solvers.split(",") if s.strip()]
    items = list(solvers.items()) if isinstance(solvers, dict) else [
        (s.strip().lower().replace("_", "-") if isinstance(s, str) else type(s).__name__.lower(), s)
        for s in solvers]
    if not items:
        raise ParameterError("compare: no solver given; name at least one (e.g. newton,lbfgs)")
    named = {}
    for name, s in items:
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise ParameterError(f"compare: solver name {name!r} cannot be a file name; use letters, "
                                 f"digits and _.+- (starting with a letter or digit)")
        if name in named:
            raise ParameterError(f"compare: solver {name!r} is given twice; name each solver once")
        solver = get_solver(s)
        if max_steps is not None:
            solver = dataclasses.replace(solver, max_steps=max_steps)
        if isinstance(solver, CM) and problem.dim != 2:
            raise ParameterError("compare: cm (composite majorization) is defined for triangles only; "
                                 "leave it out for a tet problem")
        if name in _DENSE_SOLVERS:
            nbytes = 8 * (problem.n_vertices * problem.dim) ** 2
            if nbytes > _DENSE_LIMIT_BYTES:
                raise ParameterError(
                    f"compare: {name} keeps a dense inverse Hessian of {nbytes / 2**30:.1f} GiB for "
                    f"{problem.n_vertices} vertices; use optx-lbfgs or lbfgs on a mesh this size")
        named[name] = solver
    return named


def _positive(value, name) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (v > 0 and math.isfinite(v)):
        raise ParameterError(f"compare: {name} must be a positive number of seconds, got {value!r}")
    return v


# ------------------------------------------------------------------------------ outputs


def _output_names(names, dim):
    ext = ".obj" if dim == 2 else ".vtk"
    return ["history.csv", "summary.csv", "convergence.png"] + [n + ext for n in names]


def _prepare_folder(out, names) -> Path:
    """Create ``out`` (with parents) and check that every file in ``names`` can be written."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise GeomoptError(f"output {out} exists and is not a folder; give a folder path for --out")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise GeomoptError(f"cannot create the output folder {out} ({exc.strerror}); give a folder "
                           f"path you can write") from exc
    for name in names:
        io.check_output_path(out / name)
    return out


def _write_csv(path, columns, rows):
    def write(fh):
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        w.writerows([repr(float(v)) if isinstance(v, float) else v for v in row] for row in rows)

    return io.atomic_write(path, write)

"""Globally bijective free-boundary parameterization with a scaffold (SCAF).

Jiang, Schaefer, Panozzo (2017), "Simplicial complex augmentation framework for bijective
maps": the region between the UV boundary and an enclosing polygon is triangulated (the
*scaffold*), and the mesh and the scaffold are solved as one problem with the injective line
search.  No scaffold triangle can invert, so two parts of the boundary can never cross; the
scaffold's rest shape is reset to its current shape before each solve, and it is re-triangulated
between solves, so it only resists a step that would close a gap.

The scaffold's triangulation (enclosing polygon, pockets, Steiner points, Delaunay flips) is
:mod:`geomopt.mesh.scaffold`.

By default the solve starts without a scaffold and builds it only when the boundary would
otherwise overlap (see :func:`bijective_parameterize`, ``lazy``): the scaffold costs steps in the
early, large-deformation phase, which the boundary of a Tutte start rarely needs.  Both phases run
in the one loop (:func:`geomopt.solvers.iterate`): the scaffold-free phase under a *guard*
(:class:`SimpleBoundary`: shorten a step that would make the boundary overlap), the scaffold's
outer iterations as a *continuation* (:class:`ScaffoldContinuation`).

The enclosing polygon's vertices are free (the scaffold moves and rotates with the mesh); global
injectivity of the result does not rest on that: it is certified at the end, exactly, by
:func:`geomopt.exact.certify.certify_bijective`.
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import numpy as np

from ._runtime.config import Instance, Int, Maybe, Real, options_or_default, validate
from ._runtime.errors import MeshError, ParameterError, SolveError
from .objective.objective import Objective
from ._runtime.x64 import float64
from .energies import energy_spec
from .exact.certify import certify_bijective, polygon_crossings
from .mesh.problem import Problem
from .mesh.scaffold import build_scaffold, delaunay_flips, refine_scaffold, rest_inverse
from .solvers import (AbstractContinuation, AbstractNewton, Decision, Final, Outcome, ParamDetails, Progress,
                      Trace, get_solver, iterate)
from .solvers._iterate import check_progress
from .exact.topology import check_disk
from .mesh.tutte import optimal_scale, scale_to_area, tutte_embedding

__all__ = ["bijective_parameterize", "ScaffoldOptions", "ScaffoldContinuation", "SimpleBoundary"]


def _interior_first(F, loop):
    """A row order (m,) of ``F`` whose first triangle starts with an interior vertex if any.

    The objective pins the first vertex of the first element (translation); when that vertex is
    interior, scaffold flips never change the free-DOF sparsity pattern (else they may, and the
    Hessian kernel recompiles for the new non-zero count: slower, still correct)."""
    on = np.zeros(int(F.max()) + 1, dtype=bool)
    on[loop] = True
    rows = np.flatnonzero(~on[F[:, 0]])
    order = np.arange(len(F))
    if rows.size:
        order[[0, rows[0]]] = order[[rows[0], 0]]
    return order


#: fractions of a scaffold-free step tried when the whole step makes the boundary overlap, and
#: how many shortened steps in a row are taken before the scaffold is built (bunny_cut: 3 free
#: iterations without shortening, 5 with; the scaffold phase then starts nearer the optimum)
_SHORTEN = (0.5, 0.25)
_MAX_CUTS = 2


def _simple(P) -> bool:
    """Whether the polygon ``P`` (k, 2) is finite and simple (exact)."""
    return bool(np.isfinite(P).all()) and len(polygon_crossings(P)) == 0


class SimpleBoundary:
    """A guard for :func:`~geomopt.solvers.iterate`: keep the boundary polygon ``x[loop]``
    simple (exact check, :func:`polygon_crossings`).

    A step after which the boundary overlaps itself is moved back to the first of
    ``fractions`` of it at which the boundary is simple and the energy below the old one (the
    injective line search bounded the whole step, so no triangle inverts on a part of it;
    ``solver.restart(new, x)`` drops a memory of the whole step, e.g. L-BFGS's pairs); after
    ``max_cuts`` shortened steps in a row, or when no fraction helps, the phase ends at the old
    iterate (None)."""

    def __init__(self, loop, fractions=_SHORTEN, max_cuts: int = _MAX_CUTS):
        self.loop, self.fractions, self.max_cuts = loop, tuple(fractions), int(max_cuts)
        self.cuts = 0  # consecutive steps shortened to keep the boundary simple

    def __call__(self, solver, old, new):
        if not new.stats.accepted or new.stats.broken or _simple(np.asarray(new.x)[self.loop]):
            self.cuts = 0
            return new
        if self.cuts >= self.max_cuts:
            return None
        obj, x, dx = old.objective, old.x, new.x - old.x
        for s in self.fractions:
            xs = x + s * dx
            if not _simple(np.asarray(xs)[self.loop]):
                continue
            if float(obj.value(xs, old.params)) < old.value:
                self.cuts += 1
                return solver.restart(new, x=xs).update(step_size=s * new.step_size)
        return None


@dataclasses.dataclass(frozen=True)
class ScaffoldOptions:
    """The scaffold's settings in :func:`bijective_parameterize` (validated).

    Attributes
    ----------
    scaffold_weight : float > 0, the scaffold's share of the energy (its weights sum to
        ``scaffold_weight`` times the mesh area).  Smaller lets the boundary approach itself in
        fewer outer iterations but cuts more Newton steps short where the scaffold is compressed;
        it does not change what is reachable.  On bunny_cut (outer_rtol 1e-5, inner solves
        converged fully) 1e-3 took 61 solver iterations, 1e-4 62 and 1e-2 84.
    ring_scale : float > 1, size of the enclosing polygon relative to the start's convex hull.
    inner_steps : int >= 1 or None, solver iterations per outer iteration; None (default): 10
        for Newton-type solvers (Newton, SLIM, CM), 50 for the others (L-BFGS, AQP, optimistix:
        their memory or acceleration restarts with every new scaffold, so ten steps a round
        left L-BFGS on the spiral strip at 597-1,000+ iterations depending on the Laplacian
        backend's rounding; fifty: 45 iterations whatever the backend).
    max_outer : int >= 1, the outer iteration limit.
    outer_rtol : float > 0 (1e-4: the mesh energy is then within about 1e-4 of the outer
        loop's limit, measured 4e-5 above the 1e-5 result on bunny_cut, for 30 instead of 40
        solver iterations); Newton-type inner solves stop when the decrement is below
        ``0.1 * outer_rtol`` relative (or the solver's own ``rtol``, if larger).
    lazy : start without a scaffold (see :func:`bijective_parameterize`).
    """

    scaffold_weight: float = 1e-3
    ring_scale: float = 3.0
    inner_steps: int | None = None
    max_outer: int = 100
    outer_rtol: float = 1e-4
    lazy: bool = True

    def __post_init__(self):
        validate(self, scaffold_weight=Real(0.0, lo_open=True), ring_scale=Real(1.0, lo_open=True),
                 inner_steps=Maybe(Int(1)), max_outer=Int(1), outer_rtol=Real(0.0, lo_open=True), lazy=Instance(bool))


class FreeRecord(NamedTuple):
    """The scaffold-free phase (``trace.phases[0]`` when lazy): its iterations, the mesh's
    mean energy after it, and its outcome (None: the boundary was about to overlap)."""

    iterations: int
    mean_energy: float
    outcome: Outcome | None

    def line(self, k: int) -> str:
        how = "(boundary about to overlap: scaffold)" if self.outcome is None else self.outcome.value
        return f"free  {self.iterations:4d} iterations  energy {self.mean_energy:.10g}  {how}"


class ScaffoldRecord(NamedTuple):
    """One outer iteration with the scaffold: its number, the mesh's mean energy after it,
    the inner iterations and outcome, and the Delaunay flips that followed."""

    outer: int
    mean_energy: float
    inner: int
    outcome: Outcome | None
    flips: int

    def line(self, k: int) -> str:
        how = self.outcome.value if self.outcome is not None else "stopped"
        return (f"outer {self.outer:3d}  energy {self.mean_energy:.10g}  inner {self.inner:3d} ({how})  "
                f"flips {self.flips:5d}")


class ScaffoldContinuation(AbstractContinuation):
    """The outer loop of the bijective mode as a continuation of :func:`~geomopt.solvers.iterate`.

    The first phase (``lazy``) runs on the mesh alone under :class:`SimpleBoundary`: when it
    ends on its own the result is the plain solve's; when the guard ends it, the scaffold is
    built around the last iterate and each later phase solves mesh + scaffold with ``inner``
    for up to ``inner_steps`` iterations, then re-triangulates the scaffold
    (:func:`delaunay_flips`), until an inner solve converged and the mesh energy fell by less
    than ``outer_rtol`` (relative), or ``max_outer``.  ``finish`` certifies the mesh's map
    exactly (:func:`~geomopt.exact.certify.certify_bijective`).
    """

    def __init__(self, problem, objective, loop, inner, options, start, scale):
        self.problem, self.objective, self.loop, self.inner, self.opts = problem, objective, loop, inner, options
        self.start_map, self.scale = start, scale
        n = problem.n_vertices
        order = _interior_first(problem.simplices, loop)
        self.mesh = problem.simplices[order], problem.rest_inv[order], problem.volumes[order]
        self.X, self.S = start, None  # the last certified-finite map (mesh + scaffold vertices)
        self.energies, self.times = [self._mesh_energy(start)], [0.0]
        self.free = self.flips = self.outer = 0
        self.n, self.weight = n, 0.0
        self.t0 = time.perf_counter()

    def _mesh_energy(self, X) -> float:
        return float(self.objective.value(np.asarray(X)[: self.problem.n_vertices], self.objective.params()))

    def _combined(self, X, S):
        """The planar problem of mesh + scaffold (the scaffold's current shape its rest shape)."""
        rows, inv, vol = self.mesh
        simplices = np.concatenate([rows, S])
        problem = dataclasses.replace(
            self.problem, kind="planar", n_vertices=len(X), simplices=simplices, input_simplices=simplices,
            rest_inv=np.concatenate([inv, rest_inverse(X, S)]),
            volumes=np.concatenate([vol, np.full(len(S), self.weight)]), rest_vertices=X)
        # size buckets: every remesh of the scaffold has another triangle count, and without them
        # each count compiled its own kernels (~2.3 s a size, warm processes too)
        return Objective(problem, self.objective.energy, buckets=True)

    def scaffolded(self, X):
        """``(objective, X)``: the scaffold built around the map ``X`` (n, 2) (refined), the
        combined objective and the map with the scaffold's vertices appended."""
        X = np.asarray(X)[: self.n]
        scaffold = build_scaffold(X[self.loop], self.opts.ring_scale)
        k = len(self.loop)
        Xs, Ts = refine_scaffold(np.concatenate([X[self.loop], scaffold.outer]), scaffold.triangles, k)
        ids = np.concatenate([self.loop, self.n + np.arange(len(Xs) - k)])  # scaffold id -> vertex
        self.S, self.X = ids[Ts], np.concatenate([X, Xs[k:]])
        self.weight = self.opts.scaffold_weight * self.objective.total_volume / len(self.S)
        return self._combined(self.X, self.S), self.X

    def _log(self, X):
        self.energies.append(self._mesh_energy(X))
        self.times.append(time.perf_counter() - self.t0)
        return self.energies[-1] / self.objective.total_volume

    def __call__(self, state, outcome) -> Decision:
        if self.S is None:  # the scaffold-free phase ended
            self.free, self.X = state.iteration, _real_rows(state)
            record = FreeRecord(self.free, self._log(self.X), outcome)
            if outcome is not None:
                return Decision.stop_with(outcome, record=record)
            objective, X = self.scaffolded(self.X)
            return Decision.go(objective=objective, x=X, solver=self.inner, record=record)
        X = _real_rows(state)
        if outcome is Outcome.NONFINITE or not np.isfinite(X).all():
            return Decision.stop_with(Outcome.NONFINITE)
        self.outer += 1
        self.X = X
        self.S, f = delaunay_flips(X, self.S)
        self.flips += f
        record = ScaffoldRecord(self.outer, self._log(X), state.iteration, outcome, f)
        drop = self.energies[-2] - self.energies[-1]
        if outcome is Outcome.CONVERGED and drop <= self.opts.outer_rtol * abs(self.energies[-1]):
            return Decision.stop_with(Outcome.CONVERGED, record=record)
        if self.outer >= self.opts.max_outer:
            return Decision.stop_with(Outcome.MAX_STEPS, f"stopped at the outer-iteration limit (max_outer="
                                      f"{self.opts.max_outer}) before converging", record=record)
        return Decision.go(objective=self._combined(X, self.S), x=X, record=record)

    def finish(self, state, outcome, reason) -> Final:
        x = np.asarray(self.X[: self.n])
        cert = certify_bijective(x, self.problem.simplices, self.loop)
        if outcome is Outcome.CONVERGED and not cert.globally_injective:
            outcome = Outcome.NOT_INJECTIVE
        details = ParamDetails(start=self.start_map, scale=self.scale, free_iterations=self.free,
                               flips=self.flips, scaffold_triangles=0 if self.S is None else len(self.S))
        return Final(x, outcome, cert, reason, problem=self.problem, objective=self.objective,
                     energy=self.energies[-1], volume=self.objective.total_volume, details=details)


def _real_rows(state) -> np.ndarray:
    """A solver state's map without the rows its size-bucketed objective pads it with."""
    return np.asarray(state.objective.unpad_map(np.asarray(state.x)))


def _inner_solver(solver, opts, named):
    """The scaffold phase's solver: ``solver`` with ``max_steps = inner_steps``; a Newton-type
    inner solve need not converge further than the outer loop's own tolerance (a quasi-Newton
    decrement is a poorer estimate: L-BFGS stopped 2.6e-4 high on the spiral); a solver given
    by name gets the search's 0.9 of the flip bound: AQP's and L-BFGS's default stops a quarter
    of the way to the first collapse (keeping real triangles from their barrier), but the
    steps the scaffold blocks are its own air triangles', which the next scaffold replaces (at
    0.25 L-BFGS on the spiral hit max_outer (100), at 0.9 it converged in 59 outer iterations).
    A search passed in a solver object is kept."""
    if not (dataclasses.is_dataclass(solver) and hasattr(solver, "max_steps")):
        raise ParameterError(f"the bijective mode needs a dataclass solver with a max_steps field "
                             f"(e.g. geomopt.Newton()), got {solver!r}")
    rtol = max(solver.rtol, 0.1 * opts.outer_rtol) if isinstance(solver, AbstractNewton) else solver.rtol
    steps = opts.inner_steps if opts.inner_steps is not None else (10 if isinstance(solver, AbstractNewton) else 50)
    inner = dataclasses.replace(solver, max_steps=int(steps), rtol=rtol)
    if named and inner.search.safety < 0.9:
        inner = dataclasses.replace(inner, search=dataclasses.replace(inner.search, safety=0.9))
    return inner


def _bijective_start(problem, objective, x0, weights, loop):
    """``(x0, scale)``: the start map (Tutte onto a circle by default), checked globally
    injective (exact), centred, scaled to the rest area and by :func:`optimal_scale`."""
    if x0 is None:
        x0 = tutte_embedding(problem.rest_vertices, problem.input_simplices, weights, boundary=loop)
    x0 = problem.check_map(x0, "start map x0")
    cert = certify_bijective(x0, problem.simplices, loop)
    if not cert.globally_injective:
        raise MeshError(
            f"the start map x0 is not globally injective ({cert.inverted} inverted triangle(s), "
            f"{len(cert.crossings)} crossing boundary edge pair(s), boundary orientation "
            f"{cert.orientation}); omit x0 for a Tutte start, or untangle it first")
    x0 = x0 - x0.mean(axis=0)
    x0 = scale_to_area(x0, problem.rest_vertices, problem.simplices)
    s = optimal_scale(objective, x0)
    return s * x0, s


@float64
def bijective_parameterize(V, F, energy="symmetric_dirichlet", solver=None, *, weights="uniform", x0=None,
                           options: ScaffoldOptions | None = None, progress=True, throw=False):
    """Flatten a disk-topology surface to the plane with a free boundary, globally bijective.

    Solves the same problem as :func:`~geomopt.param.parameterize` with, around the mesh, a
    scaffold (SCAF, Jiang et al. 2017; see the module docstring) that keeps the boundary from
    touching itself.  The scaffold's triangles take the same energy as the mesh, each weighted by
    ``scaffold_weight * (mesh area) / (number of scaffold triangles)`` (as in SCAF, uniform rather
    than by area, so small gaps resist as much as large ones), with their current shape as rest
    shape (:class:`ScaffoldContinuation`).

    With ``lazy`` (default) the solver first runs on the mesh alone, for as long as every
    iterate's boundary stays simple (:class:`SimpleBoundary`), then the scaffold is built at the
    last iterate; where the free-boundary solve never overlaps, the result is the plain solve's.
    Every accepted iterate is bijective; between two iterates of the scaffold-free phase the
    straight path is not checked, which does not matter for the returned map.  ``lazy=False``
    uses the scaffold from the start (the boundary never crosses itself along the whole path).

    Parameters
    ----------
    V : (n, 3) float rest vertex positions;  F : (m, 3) int triangles of a topological disk.
    energy, solver, weights, throw : as for :func:`~geomopt.param.parameterize` (``energy`` a
        name, an Energy or ``(name, {parameter: value})``); the solver's
        ``max_steps`` is replaced by ``inner_steps`` in the scaffold phase (a solver that is not
        a dataclass with ``max_steps`` is rejected).
    progress : bool, one record per phase on the ``geomopt`` logger (INFO).
    x0 : (n, 2) optional start map; it must be globally injective (the default, Tutte's
        embedding onto a circle, is).
    options : :class:`ScaffoldOptions` (``scaffold_weight``, ``ring_scale``, ``inner_steps``,
        ``max_outer``, ``outer_rtol``, ``lazy``); None: the defaults.

    Returns
    -------
    :class:`~geomopt.solvers.Result` for the mesh alone: ``x`` (n, 2), ``energy`` the mesh
    energy, ``trace.energy`` / ``trace.seconds`` the mesh energy and elapsed seconds at the
    start, after the scaffold-free phase (if ``lazy``) and after each outer iteration;
    ``stats.iterations`` the solver iterations summed, ``stats.outer_iterations`` the scaffold's.
    ``certificate`` is the exact :class:`~geomopt.exact.certify.Certificate` and ``injectivity`` is
    ``"global"`` when it holds; a result that is not globally injective has outcome
    ``NOT_INJECTIVE`` (never expected: the scaffold forbids it), so ``success`` means converged,
    flip-free and bijective.  ``details`` (:class:`~geomopt.solvers.ParamDetails`) holds the
    start and its scale, ``free_iterations``, ``flips`` and ``scaffold_triangles``.

    Raises
    ------
    MeshError : invalid or non-disk mesh, or a start map that is not globally injective.
    ParameterError : unknown energy/solver/weights name or an invalid parameter.
    SolveError : only with ``throw=True``, when the result is not converged and bijective.
    """
    opts = options_or_default(ScaffoldOptions, options, "bijective_parameterize")
    energy, energy_params = energy_spec(energy, where="bijective_parameterize")
    check_progress(progress, "bijective_parameterize")
    t_start = time.perf_counter()
    problem = Problem.surface(V, F)
    objective = Objective(problem, energy, buckets=True, **energy_params)
    named = solver is None or isinstance(solver, str)
    solver = get_solver("newton" if solver is None else solver)
    inner = _inner_solver(solver, opts, named)
    loop = check_disk(problem.input_simplices, problem.n_vertices)
    x0, s = _bijective_start(problem, objective, x0, weights, loop)
    cont = ScaffoldContinuation(problem, objective, loop, inner, opts, x0, s)
    report = Progress(iterations=False) if progress else None
    if opts.lazy:
        first, guard, start = solver, SimpleBoundary(loop), (objective, x0)
    else:
        first, guard, start = inner, None, cont.scaffolded(x0)
    setup = time.perf_counter() - t_start
    result = iterate(first, start[0], start[1], objective.params(), continuation=cont, guard=guard,
                     progress=report, trace=False, label="bijective solve", warn=not throw)
    result = dataclasses.replace(
        result, trace=Trace(np.asarray(cont.energies), np.asarray(cont.times), np.full(len(cont.times), np.nan),
                            None, result.trace.phases),
        stats=dataclasses.replace(result.stats, outer_iterations=cont.outer,
                                  setup_seconds=result.stats.setup_seconds + setup))
    if throw and not result.success:
        raise SolveError(f"bijective solve failed: {result.message}; injectivity {result.injectivity}", result)
    return result

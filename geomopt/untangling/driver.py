"""The untangling driver: :func:`untangle` checks the input, picks the start and the
inner solver, normalises the problem and runs the eps continuation in the one loop."""

from __future__ import annotations

import dataclasses
import time
import warnings

import jax
import numpy as np

from .._runtime.config import options_or_default
from .._runtime.errors import MaxStepsWarning, ParameterError, SolveError
from .._runtime.log import logger
from .._runtime.tracing import is_traced
from .._runtime.x64 import float64
from ..energies import garanzha
from ..exact.predicates import box_scale, differing_rows
from ..mesh.orientation import fixed_total_problem
from ..mesh.problem import Problem
from ..objective.objective import Objective
from ..solvers import (AbstractSolver, LocalCertificate, Outcome, Progress, Result, RunStats, UntangleDetails, iterate,
                       traced_result)
from ..solvers._iterate import check_progress
from .continuation import EpsContinuation, judged
from .implicit import untangle_map
from .inner import default_solver, stiff_solver
from .options import POLISH_UP_TO, UntangleOptions
from .rest import check_rest, equilateral_problem
from .schedule import start_eps
from .start import BOX, choose_start, harmonic_start, hold_free_parts

#: outer iterations at the eps floor without fewer inverted elements after which ``start="auto"``
#: gives up the given map and starts again from the harmonic extension of the handles
STALL_OUTER = 20

__all__ = ["UntangleResult", "untangle", "infeasible"]


#: what :func:`untangle` returns (one result type for every solve; kept as a name)
UntangleResult = Result


@float64
def untangle(problem: Problem, x0, solver="lbfgs", *, options: UntangleOptions | None = None, progress=True,
             throw: bool = False, adjoint: str = "auto") -> Result:
    """Untangle ``x0`` (n, d) with ``problem``'s handles fixed (Garanzha et al. 2021).

    With no handles (a free boundary, e.g. repairing a folded UV map) translation is pinned
    by the objective's gauge and rotation and scale are free; the map must not be mirrored as
    a whole (a positive total signed area/volume): mirror it first (see :func:`~geomopt.param.repair_map`).

    Differentiable: given a traced ``problem`` (rest vertices, handle positions) or a traced
    ``options.theta``, ``result.x`` is the untangled map as a function of them (the optimum of
    the final eps, polished by Newton, differentiated by the implicit function theorem:
    :func:`geomopt.untangling.implicit.untangle_map`), the same map as the plain call's;
    the start and the map's power-of-two scale are constants of the solve.

    Parameters
    ----------
    problem : :class:`~geomopt.mesh.problem.Problem`, with fixed vertices (``with_fixed``) or not.
    x0 : (n, d) start map; its handle rows are replaced by ``problem.fixed_positions``.
    solver : ``"lbfgs"`` (default), ``"newton"`` (see :func:`default_solver`) or a solver object.
        Its line search should not be injective: the start is tangled.
    options : :class:`UntangleOptions` (theta, max_outer, energy_tol, eps0, max_aspect,
        keep_memory, injective_when_untangled, min_sigma, max_sigma, bucket, start); None: the
        defaults.
    progress : True (one record per outer iteration on the ``geomopt`` logger, INFO: see
        :mod:`geomopt._runtime.log`), False, or a callable
        ``(outer, eps, energy, min_det, n_inverted, inner, seconds)``.
    throw : raise :class:`~geomopt.SolveError` (carrying the result) unless ``success``.
    adjoint : the linear solver of the adjoint on traced inputs (see :func:`geomopt.minimize`).

    Returns
    -------
    :class:`~geomopt.solvers.Result`: ``x`` in the input frame, handles bit-identical to
    ``problem.fixed_positions``; ``certificate`` the exact :class:`~geomopt.solvers.LocalCertificate`
    (inverted elements, 2D branch points, moved handles); ``stats.iterations`` the inner
    iterations, ``stats.outer_iterations``, ``stats.inverted_at_start``; ``trace.phases`` one
    :class:`~geomopt.untangling.UntangleRecord` per outer iteration (the last one the final
    polish, see :class:`UntangleOptions`); ``details`` the :class:`UntangleDetails`.
    ``energy`` and ``mean_energy`` are measured in the normalised frame.

    Stars whose every element has all its vertices fixed and that overlap in ``x0``
    (:meth:`~geomopt.Problem.certify_fixed`) are the same in every map with these handles: the
    rest is solved, and a map locally injective everywhere else ends
    ``Outcome.CERTIFIED_EXCEPT_FIXED`` (not ``success``; ``certificate.forced`` lists them).

    Raises
    ------
    MeshError
        The rest mesh of a triangle or tet problem is not locally injective (exact, at set-up).

    Examples
    --------
    A 4 x 4 grid whose interior is rotated by 180 degrees (folded), its boundary fixed:

    >>> from geomopt.mesh import generators
    >>> from geomopt.untangling import untangle
    >>> tangle = generators.rotated_interior(*generators.square_mesh(4), 180.0)
    >>> result = untangle(tangle.problem(), tangle.x0, progress=False)
    >>> tangle.inverted(), result.certificate.inverted, result.success
    (4, 0, True)
    """
    opts = options_or_default(UntangleOptions, options, "untangle")
    if is_traced(problem, x0, opts.theta):  # differentiable: the implicit adjoint at the last eps's optimum
        x = untangle_map(untangle, problem, x0, opts.theta, solver=solver, adjoint=adjoint,
                         options=dataclasses.replace(opts, theta=None))
        return traced_result(x, problem=problem, solver=solver)
    if not isinstance(solver, (str, AbstractSolver)):
        raise ParameterError(f"solver must be 'lbfgs', 'newton' or a solver object, got {solver!r}")
    check_progress(progress, "untangle")
    t_setup = time.perf_counter()
    check_rest(problem)  # exact, before anything is compiled
    x0 = problem.check_map(x0)
    initially = problem.count_inverted(x0)
    why = _refusal(problem, x0, initially, problem.free_mask[problem.simplices].any(axis=1))
    if why:
        return _early_result(problem, x0, initially, t_setup, throw, why)
    forced = problem.certify_fixed(x0)  # stars no free vertex changes (quads/hexahedra: their tangent cones)
    x_start, which = choose_start(problem, x0, opts.start)
    may_fall_back = opts.start == "auto" and which != "harmonic" and len(problem.fixed) > 0
    run = (problem, solver, opts, initially, forced, progress, throw)
    result = _attempt(*run, t_setup, x_start, which, stall=STALL_OUTER if may_fall_back else None)
    if may_fall_back and not (result.success or result.outcome is Outcome.CERTIFIED_EXCEPT_FIXED):
        if result.stats.outer_iterations < opts.max_outer:  # not at the user's limit: the rest of it
            rest = dataclasses.replace(opts, max_outer=opts.max_outer - result.stats.outer_iterations)
            result = _fall_back((problem, solver, rest) + run[3:], x0, x_start, result)
        if result.outcome is Outcome.MAX_STEPS and not throw and result.details.start == which:
            warnings.warn(f"untangling: {result.reason}, after {result.stats.iterations} iterations and "
                          f"{result.stats.seconds:.3g} s; the map returned is not converged (outcome max_steps): "
                          f"raise that limit", MaxStepsWarning, stacklevel=2)  # the first run's, held back
    if throw and not result.success:
        raise SolveError(f"untangling failed: {result.message}", result)
    return result


def _fall_back(run, x0, x_start, first) -> Result:
    """The eps loop again from the harmonic extension of the handles (:func:`harmonic_start`)
    after ``first``, the run from ``x_start``, ended uncertified before the outer-iteration limit
    (``run``'s options hold what is left of it); ``first`` when the extension is undefined or is
    ``x_start``, or when its run ends uncertified with no fewer inverted elements.  The result's
    stats add up both runs."""
    problem, progress = run[0], run[5]
    fallback = harmonic_start(problem, x0)
    if fallback is None or not differing_rows(fallback, x_start).any():
        return first
    if progress is True:
        logger.info(f"untangling: the given map ended uncertified ({first.message}); again from the harmonic "
                    f"extension of the handles")
    result = _attempt(*run, time.perf_counter(), fallback, "harmonic", stall=None)
    if not result.success and result.certificate.inverted >= first.certificate.inverted:
        return first  # the fallback got no further: the first run's map, and its reason, are the answer
    a, b = first.stats, result.stats
    stats = dataclasses.replace(b, setup_seconds=a.setup_seconds + b.setup_seconds, seconds=a.seconds + b.seconds,
                                iterations=a.iterations + b.iterations, evaluations=a.evaluations + b.evaluations,
                                outer_iterations=a.outer_iterations + b.outer_iterations)
    return dataclasses.replace(result, stats=stats, details=dataclasses.replace(result.details,
                                                                                start="given, then harmonic"))


def _attempt(problem, solver, opts, initially, forced, progress, throw, t_setup, x_start, which, stall) -> Result:
    """The eps loop from ``x_start`` (``which`` start, :func:`choose_start`) with the parts
    without a handle held (:func:`hold_free_parts`); ``stall`` as :class:`EpsContinuation`'s."""
    parts = hold_free_parts(problem, x_start)  # parts without a handle: held at a certified map
    held = np.union1d(problem.fixed, parts.held)
    solving = problem.with_fixed(held, parts.x[held]) if len(parts.held) else problem
    active = solving.free_mask[solving.simplices].any(axis=1)
    theta = opts.resolved_theta(problem.dim)
    details = UntangleDetails(theta, theta / (1.0 - theta), 1.0, 1.0, int(active.sum()), which,
                              parts.given + parts.rest + parts.pinned, parts.rest)
    if not active.any():  # nothing left to move: the map is certified as it is
        return _held_result(problem, parts.x, initially, forced, t_setup, details)
    before = time.perf_counter() - t_setup
    result = _solve(problem, solving, parts.x, active, solver, opts, details, initially, forced, progress, throw,
                    stall)
    return dataclasses.replace(result, problem=problem, stats=dataclasses.replace(
        result.stats, setup_seconds=result.stats.setup_seconds + before))


def _solve(problem, solving, x_start, active, solver, opts, details, initially, forced, progress, throw,
           stall=None) -> Result:
    """The eps loop on ``solving`` (``problem`` with its handle-free parts held) from ``x_start``."""
    t_setup = time.perf_counter()
    stiff = None  # the solver a stalling inner solve continues with (default L-BFGS only)
    if isinstance(solver, str):
        corners = problem.elements is not None
        stiff = stiff_solver(solver, problem.dim, corners)
        solver = default_solver(solver, problem.dim, int(active.sum()), corners, initially)
    scaled, sub, xs, k, s = _normalised(solving, x_start, active, opts)
    energy = garanzha.with_params(eps=1.0, lam=details.lam)
    full = Objective(scaled, energy, buckets=opts.bucket)
    obj = Objective(sub, energy, buckets=full.sizes if opts.bucket else False)
    if opts.eps0 is None:
        opts = dataclasses.replace(opts, eps0=start_eps(sub, xs))
    if opts.polish == "auto":
        opts = dataclasses.replace(opts, polish=int(solving.free_mask.sum()) * problem.dim <= POLISH_UP_TO)
    details = dataclasses.replace(details, map_scale=k, rest_scale=s)
    eps = EpsContinuation(solving, scaled, full, obj, k, xs, opts, details, initially, solver, stiff, forced, stall)
    eps.prepare_polish()
    setup = time.perf_counter() - t_setup
    result = iterate(eps.phase_solver, obj, jax.device_put(xs), obj.params(eps=float(opts.eps0)), continuation=eps,
                     progress=_phase_progress(progress), trace=False, throw=False, label="untangling",
                     warn=not throw and stall is None)  # raised by untangle (a stalled run is retried)
    # result.solver: the inner solver, not the final polish's
    return dataclasses.replace(result, solver=eps.solver, stats=dataclasses.replace(
        result.stats, setup_seconds=result.stats.setup_seconds + setup))


def _held_result(problem, x, initially, forced, t_setup, details) -> Result:
    """The result when no vertex is left to move (every part held or fixed): ``x`` certified."""
    t = time.perf_counter()
    outcome, cert, reason = judged(problem, x, Outcome.CONVERGED, "", forced)
    stats = RunStats(setup_seconds=t - t_setup, inverted_at_start=initially, certify_seconds=time.perf_counter() - t)
    return Result(x, outcome, cert, stats, problem=problem, reason=reason, details=details)


def _phase_progress(progress):
    """untangle's ``progress`` as an :func:`~geomopt.solvers.iterate` progress: lines per
    outer iteration, or the user's callable per outer iteration."""
    if progress is True:
        return Progress(iterations=False)
    if callable(progress):
        return _PhaseCallback(progress)
    return None


class _PhaseCallback:
    """A callable ``(outer, eps, energy, min_det, n_inverted, inner, seconds)`` called per
    outer iteration (and never per inner iteration)."""

    iterations = False

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, state, elapsed, mean_energy):
        return None

    def phase(self, index, r, elapsed):
        self.fn(index, r.eps, r.mean_energy, r.min_det, r.inverted, r.inner, elapsed)


def infeasible(problem: Problem, x0) -> str | None:
    """Why no map of ``problem`` with its handles can be injective, decided from the start map
    ``x0`` (n, dim) before any solve (a property of the input: :func:`untangle` returns it as a
    not-injective result), or None: a whole fixed boundary enclosing a non-positive total
    (:func:`geomopt.mesh.orientation.fixed_total_problem`), or an inverted element whose every
    vertex is fixed."""
    x0 = problem.check_map(x0)
    return _refusal(problem, x0, problem.count_inverted(x0), problem.free_mask[problem.simplices].any(axis=1))


def _refusal(problem, x0, initially, active) -> str | None:
    """Why no map with these handles can be injective (checked before solving), or None."""
    why = fixed_total_problem(problem, x0) if initially else None
    if why:
        return f"{why}; mirror the handle positions or free part of the boundary"
    if initially and not active.all():  # elements that cannot move: one inverted = infeasible
        dead = int(np.count_nonzero(_orient_bad(x0, problem.simplices[~active])))
        if dead:
            return (f"{dead} inverted element(s) have every vertex fixed: no map with these handles "
                    f"is injective")
    return None


def _normalised(problem, x0, active, opts):
    """``(scaled, sub, xs, k, s)``: the map scaled by a power of two ``k`` into a box of size
    ~BOX (``xs``), the rest mesh by ``s`` to the map's volume (equilateral rest triangles above
    ``max_aspect`` in 2D), ``sub`` its active elements."""
    d = problem.dim
    k = box_scale(x0, BOX)
    xs = x0 * k
    map_vol = float(problem.signed_volumes(xs).sum())
    rest_vol = float(problem.volumes.sum())
    s = (map_vol / rest_vol) ** (1.0 / d) if map_vol > 0 else k
    scaled = dataclasses.replace(
        problem, rest_inv=problem.rest_inv / s, volumes=problem.volumes * s**d,
        rest_vertices=problem.rest_vertices * s, fixed_positions=problem.fixed_positions * k)
    scaled = equilateral_problem(scaled, opts.max_aspect)
    sub = dataclasses.replace(scaled, simplices=scaled.simplices[active],
                              input_simplices=scaled.input_simplices[active],
                              rest_inv=scaled.rest_inv[active], volumes=scaled.volumes[active])
    return scaled, sub, xs, k, s


def _orient_bad(x, S):
    from ..exact.predicates import simplex_orientations

    return simplex_orientations(x, S) != 1


def _early_result(problem, x0, initially, t_setup, throw, reason):
    result = Result(x0, Outcome.NOT_INJECTIVE, LocalCertificate(initially),
                    RunStats(setup_seconds=time.perf_counter() - t_setup, inverted_at_start=initially),
                    problem=problem, reason=reason)
    if throw:
        raise SolveError(f"untangling failed: {reason}", result)
    return result

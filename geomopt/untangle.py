"""Untangling: Garanzha et al.'s regularised energy with an eps-driving outer loop.

V. Garanzha, I. Kaporin, L. Kudryavtseva, F. Protais, N. Ray, D. Sokolov, "Foldover-free maps
in 50 lines of code", ACM Trans. Graph. 40(4), 2021.

Given a (possibly tangled) map with fixed handles, minimise

    E_eps(x) = sum_e vol_e * ( |J|^2 / chi(det J, eps)^(2/d) + lam (det J^2 + 1) / chi(det J, eps) )

(``geomopt.energies.garanzha``; the paper's code normalises it as ``(1-theta) f + theta g``,
the same up to the factor ``1 - theta``) at fixed ``eps`` with an inner solver, then shrink
``eps`` from the worst determinant ``D-``: with ``sigma = max(1 - E/E_prev, min_sigma)``
(at most ``max_sigma`` while ``D- <= 0``) and ``mu = (1 - sigma) chi(D-, eps)``,
``eps = 2 sqrt(mu (mu - D-))`` when ``D- < mu`` (so that ``chi(D-, eps_new) = mu``), else a
tiny floor (:func:`next_eps`).  Stop when every element
is positively oriented and the energy changed by less than ``1e-5`` (relative) during the last
inner solve.  ``theta`` weighs shape against area, ``lam = theta / (1 - theta)``: 1/128 in 2D
and 1/2 in 3D as in the paper's code, whose initial ``eps`` is 1.

Departures from the paper's code, each measured on the LIM sample and on generated tangles
(see ``benchmarks/untangle.py`` and the issue notes):

* ``sigma`` is at least 0.5 instead of 0.1 (the paper's 0.1 takes 5x more outer iterations,
  64 vs 12 on WeberZorin14_fig19), and at most 0.5 while some element is inverted: without
  that cap a first inner solve that lowers the energy a lot sends ``eps`` to ~0 while
  elements are still folded, after which the loop stalls (``random_interior`` on
  ``disk_mesh(60)``, seed 0, never untangles).  Once nothing is inverted the paper's rule
  applies uncapped (:func:`next_eps`): eps then usually drops to the floor in one step
  (the twisted cube of 48k tets: 3 outer iterations instead of 5);
* the inner L-BFGS uses the M1QN3 diagonal seed, a loose tolerance (``1e-6``) and keeps its
  curvature pairs across outer iterations (2-5x fewer energy evaluations in total);
* the density is evaluated without ``pow`` (not vectorised by XLA on CPU).

Before solving, the map is scaled by a power of two to a box of size ~10 (exact, so scaling
back is exact too) and the rest mesh so that its volume equals the map's: the mean
determinant is then 1 and ``eps0 = 1`` is meaningful whatever the input units.  In 2D, rest
triangles with an aspect ratio above 10 are replaced by equilateral ones, as the paper's code
does.  Elements whose vertices are all fixed are left out of the inner energy (but not of
``D-`` and the stopping test).  The handles are written back from ``problem.fixed_positions``
at the end (bit-exact), and the result is certified with the exact orientation predicate
(:mod:`geomopt.predicates`) and around every vertex and edge (:func:`geomopt.certify.local_certificate`):
a map with every element positive can still wind twice around an interior vertex (2D) or edge
(3D), or overlap itself around a boundary vertex or edge; such a map is ``NOT_INJECTIVE``
(interior failures counted in ``info['branch_vertices']``, the certificate in
``info['local_certificate']``).

``eps`` and ``lam`` are traced parameters of the jitted kernels: the whole outer loop compiles
once per mesh shape.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import sys
import time
from collections.abc import Mapping
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import MeshError, ParameterError, SolveError
from ._tracing import refuse_traced
from ._x64 import float64
from ._programs import jit as programs_jit
from ._geometry import det
from ._objective import Objective, jacobians, total_energy
from .certify import local_certificate
from .energies import garanzha
from .linesearch import InjectiveSearch
from .problem import Problem, fixed_total_problem
from .solvers import LBFGS, AbstractSolver, Newton, Outcome
from .solvers._base import check_progress
from .topology import boundary_vertices

__all__ = ["UntangleResult", "untangle", "untangle_case", "lim_problem", "write_untangle_result",
           "default_solver", "stiff_solver", "next_eps"]

BOX = 10.0  # the map is scaled to about this size (Garanzha et al.'s code uses 10)
EPS_FLOOR = {2: 1e-9, 3: 1e-10}


LAPLACIAN_FROM = 50_000  # active elements from which the default L-BFGS uses the Laplacian seed


#: inner iterations after which the default L-BFGS continues with the Laplacian seed
STIFF_AFTER = 100


def stiff_solver(name: str, dim: int) -> AbstractSolver | None:
    """The solver an inner solve of :func:`default_solver` continues with when it has not
    converged after :data:`STIFF_AFTER` iterations (None: no switch).

    ``"lbfgs"``: the Laplacian seed (Sobolev-preconditioned L-BFGS).  An inner solve that
    needs more than a hundred iterations with the diagonal seed is a stiff, global one (the
    first outer iteration of a large rotation): there the Laplacian seed's iteration count
    does not grow with the mesh (disk 12.7k triangles rotated 180 degrees: 1,474 -> 50 inner
    iterations, 2.2 -> 0.2 s; an irregular Delaunay disk 6,855 -> 1,259), while on local
    tangles (noise) the diagonal seed converges within the probe at a third of the cost per
    iteration and is kept."""
    if str(name).strip().lower() != "lbfgs":
        return None
    return dataclasses.replace(default_solver("lbfgs", dim, LAPLACIAN_FROM), precondition="laplacian")


def default_solver(name: str, dim: int, n_elements: int = 0) -> AbstractSolver:
    """The inner solver :func:`untangle` uses for ``"lbfgs"`` or ``"newton"``.

    ``"lbfgs"``: M1QN3 diagonal seed below ``LAPLACIAN_FROM`` elements, the Laplacian seed
    (:class:`~geomopt.solvers.LBFGS` ``precondition="laplacian"``) from there on.  Measured
    (warm seconds, diagonal -> Laplacian): ~1e5 elements: rotated square 104 -> 58, Tutte
    L / star 27 -> 11 / 19 -> 11, bent rod 43 -> 13, twisted cube 12.6 -> 6.1, noisy disk
    1.3 -> 3.0; the LIM armadillo (24k tets) 0.66 -> 1.04 and 2D cases of ~1e4 triangles
    were slower or even with it (its host solves cost more than the iterations they save)."""
    key = str(name).strip().lower()
    if key == "lbfgs":
        return LBFGS(history=10, rtol=1e-6, gtol=1e-6, max_steps=30000 if dim == 2 else 3000,
                     search=InjectiveSearch(injective=False, c2=0.9),
                     precondition="laplacian" if n_elements >= LAPLACIAN_FROM else "diagonal")
    if key == "newton":
        return Newton(projection="clamp", rtol=1e-7, max_steps=100,
                      search=InjectiveSearch(injective=False))
    raise ParameterError(f"unknown untangling solver {name!r}; valid: 'lbfgs', 'newton' or a solver object")


@dataclasses.dataclass(frozen=True)
class UntangleResult:
    """The outcome of :func:`untangle`.

    Attributes
    ----------
    x : (n, d) ndarray, the map; handles bit-identical to ``problem.fixed_positions``.
    outcome : :class:`~geomopt.solvers.Outcome`.
    inverted : int, elements not positively oriented in ``x`` (exact predicate).
    initially_inverted : int, the same for the start map.
    handles_moved : int, handles whose position differs from the prescribed one in any bit.
    outer_iterations, inner_iterations : int.
    seconds : time of the outer loop;  setup_seconds : scaling, kernels' compilation, solver setup.
    min_det_rel : smallest signed area/volume of ``x`` divided by the mean absolute one.
    energy_history, eps_history, min_det_history, inverted_history : (outer_iterations,) arrays,
        the (scaled-domain) energy, eps used, worst det J and float-inverted count after each
        outer iteration.
    info : dict, extra data (scale factors, theta, solver...).
    """

    x: np.ndarray
    outcome: Outcome
    inverted: int
    initially_inverted: int
    handles_moved: int
    outer_iterations: int
    inner_iterations: int
    seconds: float
    setup_seconds: float
    min_det_rel: float
    energy_history: np.ndarray
    eps_history: np.ndarray
    min_det_history: np.ndarray
    inverted_history: np.ndarray
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def success(self) -> bool:
        """Converged, no inverted element (exact), every handle exactly in place and locally
        injective around every vertex and edge (``info['local_certificate']``)."""
        return self.outcome is Outcome.CONVERGED and self.inverted == 0 and self.handles_moved == 0

    @property
    def message(self) -> str:
        msg = self.info.get("reason") or self.outcome.message
        if self.inverted:
            msg += f"; {self.inverted} inverted element(s)"
        if self.handles_moved:
            msg += f"; {self.handles_moved} handle(s) moved"
        return msg


# --------------------------------------------------------------------- kernels




@partial(programs_jit, static_argnums=0)
def _outer_stats(density, geom, x, params):
    """(energy over all elements, min det J, #elements with det J <= 0), over the elements of
    positive rest volume (``bucket`` padding adds elements of zero volume)."""
    D = det(jacobians(geom, x))
    real = geom[2] > 0
    return total_energy(density, geom, x, params), jnp.min(jnp.where(real, D, jnp.inf)), jnp.sum(real & (D <= 0))


# --------------------------------------------------------------------- helpers


def _aspect_ratio(P):
    """(m,) aspect ratio ``lmax (l1+l2+l3) / (4 sqrt(3) area)`` of triangles P (m, 3, k); 1 = equilateral."""
    l = np.linalg.norm(P[:, [1, 2, 0]] - P, axis=2)
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    if P.shape[2] == 2:
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    else:
        area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return l.max(1) * l.sum(1) / (4.0 * np.sqrt(3.0) * area)


def _equilateral_rest(problem: Problem, max_aspect: float) -> Problem:
    """Replace rest triangles with aspect ratio above ``max_aspect`` by equilateral ones with the
    mean edge length (as Garanzha et al.'s 2D code does).  Triangles only."""
    P = problem.rest_vertices[problem.simplices]
    ar = _aspect_ratio(P)
    bad = ar > max_aspect
    if not bad.any():
        return problem
    a = np.linalg.norm(P[bad][:, [1, 2, 0]] - P[bad], axis=2).mean(1)
    Dm = np.zeros((bad.sum(), 2, 2))
    Dm[:, 0, 0] = a
    Dm[:, 0, 1] = 0.5 * a
    Dm[:, 1, 1] = 0.5 * np.sqrt(3.0) * a
    rest_inv, vol = problem.rest_inv.copy(), problem.volumes.copy()
    rest_inv[bad] = np.linalg.inv(Dm)
    vol[bad] = np.sqrt(3.0) / 4.0 * a * a
    return dataclasses.replace(problem, rest_inv=rest_inv, volumes=vol)


def _chi_scalar(D: float, eps: float) -> float:
    """``geomopt.energies.chi`` for Python floats (cancellation-free for ``D <= 0``)."""
    r = math.sqrt(eps * eps + D * D)
    return 0.5 * (D + r) if D > 0 else eps * eps / (2.0 * (r - D))


def next_eps(eps: float, E: float, E_prev: float, detmin: float, min_sigma: float = 0.5,
             max_sigma: float = 0.5, floor: float = 1e-10) -> float:
    """The eps of the next outer iteration (Garanzha et al. 2021, section 4).

    ``sigma = max(1 - E/E_prev, min_sigma)``, capped at ``max_sigma`` while some element is
    inverted (``detmin <= 0``); ``mu = (1 - sigma) chi(detmin, eps)``; the new eps solves
    ``chi(detmin, eps_new) = mu`` when ``detmin < mu``, else it is ``floor``.  Once nothing is
    inverted the paper's rule applies uncapped: an inner solve that lowered the energy a lot
    (``sigma`` near 1) sends eps to the floor in one step, where the cap took several halvings.

    Parameters
    ----------
    eps : the eps of the inner solve just finished;  E, E_prev : the energy after and before it.
    detmin : the smallest det J after it.
    """
    sigma = max(1.0 - E / E_prev, min_sigma)
    if detmin <= 0:
        sigma = min(sigma, max_sigma)
    mu = (1.0 - sigma) * _chi_scalar(detmin, eps)
    return max(floor, 2.0 * math.sqrt(mu * (mu - detmin))) if detmin < mu else floor


def _power_of_two(v: float) -> float:
    return float(2.0 ** round(math.log2(v))) if v > 0 and math.isfinite(v) else 1.0


def _bits_differ(a, b) -> int:
    a, b = np.ascontiguousarray(a, np.float64), np.ascontiguousarray(b, np.float64)
    return int(np.count_nonzero((a.view(np.uint64) != b.view(np.uint64)).any(axis=-1)))


# --------------------------------------------------------------------- main entry


@float64
def untangle(
    problem: Problem,
    x0,
    solver="lbfgs",
    theta: float | None = None,
    progress=True,
    throw: bool = False,
    max_outer: int = 200,
    energy_tol: float = 1e-5,
    eps0: float = 1.0,
    max_aspect: float | None = 10.0,
    keep_memory: bool = True,
    injective_when_untangled: bool = False,
    min_sigma: float = 0.5,
    max_sigma: float = 0.5,
    bucket: bool = False,
) -> UntangleResult:
    """Untangle ``x0`` (n, d) with ``problem``'s handles fixed (Garanzha et al. 2021).

    With no handles (a free boundary, e.g. repairing a folded UV map) translation is pinned
    by the objective's gauge and rotation and scale are free; the map must not be mirrored as
    a whole (a positive total signed area/volume): mirror it first (see :func:`~geomopt.param.repair_map`).

    Parameters
    ----------
    problem : :class:`~geomopt.problem.Problem`, with fixed vertices (``with_fixed``) or not.
    x0 : (n, d) start map; its handle rows are replaced by ``problem.fixed_positions``.
    solver : ``"lbfgs"`` (default), ``"newton"`` (see :func:`default_solver`) or a solver object
        (``init/step/terminate``; one with a ``run(state)`` method is driven by it).  Its line
        search should not be injective: the start is tangled.
    theta : shape/area balance in ``(0, 1)``; ``lam = theta / (1 - theta)``.
        Default 1/128 in 2D, 1/2 in 3D.
    progress : True (one line per outer iteration on stderr), False, or a callable
        ``(outer, eps, energy, min_det, n_inverted, inner, seconds)``.
    throw : raise :class:`~geomopt.SolveError` (carrying the result) unless ``success``.
    max_outer : outer (eps) iteration limit.
    energy_tol : stop once untangled and ``|E_prev - E| / E`` of an inner solve is below this.
    eps0 : initial eps (the map is normalised so the mean det J is 1).
    max_aspect : 2D only: rest triangles with an aspect ratio above this are replaced by
        equilateral ones (Garanzha et al.'s code uses 10); None keeps the rest mesh.
    keep_memory : keep the L-BFGS curvature pairs across outer iterations, except after one
        that increased the number of inverted elements (measured on square_rot180: it stalled
        with 64 folds under half of 14 exact rotations of its rest mesh when the pairs were
        always kept, and untangled under all 14 with this reset, at the same cost elsewhere).
    injective_when_untangled : once every element is positive, switch the inner line search
        to the injective one (no element can flip back; compiles a second kernel).
    min_sigma, max_sigma : bounds of ``sigma = 1 - E/E_prev``, the fraction by which each outer
        iteration shrinks ``chi(D-, eps)`` (:func:`next_eps`).  The paper uses ``0.1`` and no
        cap; the default halves it every outer iteration while elements are inverted and
        applies no cap once none is (see the module notes).
    bucket : pad the problem to its size bucket (:func:`geomopt.batch.pad_to_bucket`), so that
        meshes of similar sizes share compiled kernels; same certificate, same map up to the
        rounding of sums over elements.

    Returns
    -------
    :class:`UntangleResult`
    """
    refuse_traced("geomopt.untangle.untangle", "for the untangled map as a differentiable function of the problem "
                  "(rest shape, handles) and theta use geomopt.implicit.untangle", problem, x0, theta)
    t_setup = time.perf_counter()
    d = problem.dim
    if theta is None:
        theta = 1.0 / 128.0 if d == 2 else 0.5
    if not 0.0 < theta < 1.0:
        raise ParameterError(f"theta must lie in (0, 1), got {theta}")
    if max_outer < 1:
        raise ParameterError(f"max_outer must be >= 1, got {max_outer}")
    if not (isinstance(energy_tol, numbers.Real) and 0.0 < energy_tol < 1.0):
        raise ParameterError(f"energy_tol must be a number in (0, 1), got {energy_tol!r}")
    if not 0.0 < min_sigma <= max_sigma < 1.0:
        raise ParameterError(f"need 0 < min_sigma <= max_sigma < 1, got {min_sigma}, {max_sigma}")
    if not (isinstance(solver, (str, AbstractSolver))):
        raise ParameterError(f"solver must be 'lbfgs', 'newton' or a solver object, got {solver!r}")
    check_progress(progress, "untangle")
    lam = theta / (1.0 - theta)
    report = _Progress() if progress is True else (progress or None)

    x0 = problem.check_map(x0)
    S = problem.simplices
    initially = problem.count_inverted(x0)
    free = problem.free_mask
    active = free[S].any(axis=1)
    stiff = None  # the solver a stalling inner solve continues with (default L-BFGS only)
    if isinstance(solver, str):
        stiff = stiff_solver(solver, d)
        solver = default_solver(solver, d, int(active.sum()))
    why = fixed_total_problem(problem, x0) if initially else None
    if why:
        return _early_result(problem, x0, initially, t_setup, throw,
                             f"{why}; mirror the handle positions or free part of the boundary")
    if initially and not active.all():  # elements that cannot move: one inverted = infeasible
        dead = int(np.count_nonzero(_orient_bad(x0, S[~active])))
        if dead:
            return _early_result(problem, x0, initially, t_setup, throw,
                                 f"{dead} inverted element(s) have every vertex fixed: no map with "
                                 f"these handles is injective")
    # ---- normalise: map by a power of two into a box of size ~BOX, rest to the map's volume
    span = float(np.max(x0.max(axis=0) - x0.min(axis=0)))
    k = _power_of_two(BOX / span) if span > 0 else 1.0
    xs = x0 * k
    map_vol = float(problem.signed_volumes(xs).sum())
    rest_vol = float(problem.volumes.sum())
    s = (map_vol / rest_vol) ** (1.0 / d) if map_vol > 0 else k
    scaled = dataclasses.replace(
        problem, rest_inv=problem.rest_inv / s, volumes=problem.volumes * s**d,
        rest_vertices=problem.rest_vertices * s, fixed_positions=problem.fixed_positions * k)
    if max_aspect is not None and d == 2:
        scaled = _equilateral_rest(scaled, max_aspect)
    sub = dataclasses.replace(scaled, simplices=scaled.simplices[active],
                              input_simplices=scaled.input_simplices[active],
                              rest_inv=scaled.rest_inv[active], volumes=scaled.volumes[active])
    if bucket:
        from .batch import pad_to_bucket

        scaled, sub, xs = pad_to_bucket(scaled, sub, xs)
    energy = garanzha.with_params(eps=eps0, lam=lam)
    full = Objective(scaled, energy)
    obj = Objective(sub, energy)
    eps = float(eps0)
    params = obj.params(eps=eps)
    x = jax.device_put(xs)  # no per-shape copy program (jnp.asarray compiles one); xs is not written
    # compile (or load) what the loop runs now, so that setup time holds it: L-BFGS's init
    # compiles its two programs (evaluation and loop); other solvers compile their
    # re-parameterisation and inner loop in the next two calls (no-ops for L-BFGS's programs)
    state = solver.init(obj, x, params)
    state = solver.with_params(state, params)
    state = solver.run(state, max_steps=0)
    E, detmin, nneg = (float(v) for v in _outer_stats(energy.density, full.geom, x, params))
    setup = time.perf_counter() - t_setup

    # ---- the outer loop
    t0 = time.perf_counter()
    hist_E, hist_eps, hist_det, hist_inv = [], [], [], []
    inner_total, outcome, reason = 0, Outcome.MAX_STEPS, None
    evaluations_before = 0  # of a solver the loop switched away from
    floor = EPS_FLOOR.get(d, 1e-10)
    injective = False
    outer = 0
    for outer in range(1, max_outer + 1):
        E_prev = E
        it0 = state.iteration
        if stiff is not None and stiff != solver:
            state = solver.run(state, max_steps=STIFF_AFTER)
            if not solver.terminate(state)[0]:  # stalled: the Laplacian seed from here on
                inner_total += state.iteration - it0
                evaluations_before += state.evaluations
                solver = stiff
                state = solver.init(obj, state.x, params)
                it0 = state.iteration
        state = solver.run(state)
        n_inner = state.iteration - it0
        inner_total += n_inner
        x = state.x
        E, detmin, nneg = (float(v) for v in _outer_stats(energy.density, full.geom, x, params))
        nneg = int(nneg)
        hist_E.append(E), hist_eps.append(eps), hist_det.append(detmin), hist_inv.append(nneg)
        if report:
            report(outer, eps, E / full.total_volume, detmin, nneg, n_inner, time.perf_counter() - t0)
        if not (math.isfinite(E) and math.isfinite(detmin)):
            outcome, reason = Outcome.NONFINITE, None
            break
        settled = abs(E_prev - E) / abs(E) < energy_tol
        if detmin > 0 and settled:
            if scaled.count_inverted(np.asarray(x)) == 0:
                outcome = Outcome.CONVERGED
                break
        eps = next_eps(eps, E, E_prev, detmin, min_sigma, max_sigma, floor)
        params = obj.params(eps=eps)
        if injective_when_untangled and not injective and detmin > 0:
            injective = True  # from now on no element may flip back
            solver = dataclasses.replace(solver, search=dataclasses.replace(solver.search, injective=True))
            stiff = None if stiff is None else dataclasses.replace(
                stiff, search=dataclasses.replace(stiff.search, injective=True))
        state = solver.with_params(state, params)
        E = float(_outer_stats(energy.density, full.geom, state.x, params)[0])
        # stale curvature pairs can steer the next solve into more folds: drop them then
        worse = len(hist_inv) > 1 and hist_inv[-1] > hist_inv[-2]
        if not keep_memory or worse:
            state = solver.forget(state)
    if outcome is Outcome.MAX_STEPS:
        reason = f"stopped at the outer-iteration limit (max_outer={max_outer}) before it settled"
    seconds = time.perf_counter() - t0
    t_certify = time.perf_counter()
    evaluations = evaluations_before + state.evaluations

    # ---- back to the input frame: exact (power of two), handles written back bit for bit
    xs_final = np.asarray(state.x, dtype=np.float64)
    if not np.isfinite(xs_final).all():
        outcome, xs_final = Outcome.NONFINITE, xs
    out = xs_final[: problem.n_vertices] / k  # without bucket padding
    out[problem.fixed] = problem.fixed_positions
    cert = local_certificate(out, S)  # exact: orientations, and fans/stars around vertices and edges
    inverted = cert.inverted
    moved = _bits_differ(out[problem.fixed], problem.fixed_positions)
    if outcome is Outcome.CONVERGED and (not cert.ok or moved):
        outcome = Outcome.NOT_INJECTIVE
    branches = len(cert.branch_vertices) + len(cert.branch_edges)
    if not inverted and not cert.ok and outcome is Outcome.NOT_INJECTIVE:
        hint = ("the fixed boundary probably winds more than once or overlaps itself, check the handle "
                "positions" if np.isin(boundary_vertices(S, problem.n_vertices), problem.fixed).all() else
                "flip-free motion cannot remove it; start from a map whose boundary is a simple "
                "polygon (e.g. a Tutte embedding) or fix the boundary while untangling")
        reason = f"no element is inverted, but {cert.message}; {hint}"
    vols = problem.signed_volumes(out)
    result = UntangleResult(
        x=out, outcome=outcome, inverted=inverted, initially_inverted=initially, handles_moved=moved,
        outer_iterations=outer, inner_iterations=inner_total, seconds=seconds, setup_seconds=setup,
        min_det_rel=_min_rel(vols),
        energy_history=np.asarray(hist_E), eps_history=np.asarray(hist_eps),
        min_det_history=np.asarray(hist_det), inverted_history=np.asarray(hist_inv, dtype=np.int64),
        info={"theta": theta, "lam": lam, "map_scale": k, "rest_scale": s, "solver": solver,
              "reason": reason, "evaluations": evaluations, "elements": problem.n_elements,
              "active_elements": int(active.sum()), "branch_vertices": branches,
              "local_certificate": cert, "certify_seconds": time.perf_counter() - t_certify},
    )
    if throw and not result.success:
        raise SolveError(f"untangling failed: {result.message}", result)
    return result


def _min_rel(vols):
    """The smallest signed size over the mean absolute one (nan for an all-degenerate map)."""
    scale = float(np.mean(np.abs(vols)))
    return float(vols.min() / scale) if scale > 0 else float("nan")


def _orient_bad(x, S):
    from .predicates import simplex_orientations

    return simplex_orientations(x, S) != 1


def _early_result(problem, x0, initially, t_setup, throw, reason):
    vols = problem.signed_volumes(x0)
    result = UntangleResult(
        x=x0, outcome=Outcome.NOT_INJECTIVE, inverted=initially, initially_inverted=initially,
        handles_moved=0, outer_iterations=0, inner_iterations=0, seconds=0.0,
        setup_seconds=time.perf_counter() - t_setup, min_det_rel=_min_rel(vols),
        energy_history=np.zeros(0), eps_history=np.zeros(0), min_det_history=np.zeros(0),
        inverted_history=np.zeros(0, np.int64),
        info={"reason": reason, "elements": problem.n_elements},
    )
    if throw:
        raise SolveError(f"untangling failed: {reason}", result)
    return result


class _Progress:
    """One line per outer iteration on ``stream`` (default: the current ``sys.stderr``)."""

    def __init__(self, stream=None):
        self.stream = stream

    def __call__(self, outer, eps, energy, detmin, nneg, inner, seconds):
        print(f"outer {outer:3d}  eps {eps:9.3e}  mean energy {energy:.8g}  min det {detmin:+.3e}  "
              f"inverted {nneg:6d}  inner {inner:5d}  {seconds:7.2f}s",
              file=self.stream or sys.stderr, flush=True)


# --------------------------------------------------------------------- LIM cases


def lim_problem(case):
    """The untangling problem of a LIM case (:class:`geomopt.lim.LimCase`, or a dict with its keys).

    2D: the rest mesh is the ``v`` lines and the start map the ``vt`` lines.  A planar rest
    mesh (``z == 0`` everywhere) is a :meth:`Problem.planar` problem, whose rest triangles must
    all have the same orientation; any other rest mesh is a surface (:meth:`Problem.surface`,
    each triangle flattened to its own frame), whose triangles must be consistently oriented
    as a surface (adjacent faces traverse their shared edge in opposite directions).  Either
    way a map with every triangle positively oriented then has no fold, which is what the
    certificate claims.  A start map whose orientation is opposite to the rest mesh's
    (negative total signed area, counted in the rest orientation) is mirrored (``u -> -u``,
    exact) into the problem's frame.  3D: :meth:`Problem.tets` (an all-negative rest mesh is
    handled there).

    Raises
    ------
    MeshError
        The rest mesh is degenerate or inconsistently oriented (a face listed clockwise among
        counter-clockwise ones), the start map is collapsed (zero total signed area) or, in 3D
        with every boundary vertex a handle, its total signed volume is not positive: no map
        with that boundary can be certified.

    Returns
    -------
    problem : :class:`~geomopt.problem.Problem` (handles at their ``init`` positions, mirrored
        like the map).
    x0 : (n, d) start map, in the problem's frame.
    orientation : +1 or -1, the orientation every element must have in the input's own
        connectivity and frame (what :func:`write_untangle_result` certifies).
    mirror : (d,) the exact per-axis sign taking the problem's frame to the input's.
    """
    H = case["handles"]
    if case["dim"] == 2:
        F, init, rest = case["faces"], case["init"], np.asarray(case["rest"])
        planar = rest.ndim == 2 and (rest.shape[1] == 2 or (rest.shape[1] == 3 and not np.any(rest[:, 2])))
        base = Problem.planar(rest, F) if planar else Problem.surface(rest, F)
        # planar: the rest triangles may all be clockwise (Problem.planar reversed each one)
        rest_sign = 1 if np.array_equal(base.simplices, base.input_simplices) else -1
        P = init[F]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        total = float(np.sum(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])) / 2.0
        if not (total > 0 or total < 0):
            raise MeshError(
                f"{case.get('path', 'the case')}: the start map's total signed area is {total:g}: the "
                f"map is collapsed, so no orientation can be certified; give a start map ('vt' lines) "
                f"whose fixed boundary encloses a nonzero area")
        orientation = -1 if total < 0 else 1  # in the input's connectivity and frame
        mirror = np.array([float(orientation * rest_sign), 1.0])
        problem = base.with_fixed(H, init[H] * mirror)
        return problem, init * mirror, orientation, mirror
    problem = Problem.tets(case["rest"], case["tets"], H, case["init"][H])
    # rest tets all negative in the input order: Problem.tets swapped two vertices of each
    orientation = 1 if np.array_equal(problem.simplices, problem.input_simplices) else -1
    init = np.asarray(case["init"], dtype=np.float64)
    why = fixed_total_problem(problem, init)  # in the rest orientation
    if why:
        raise MeshError(f"{case.get('path', 'the case')}: {why} (Garanzha et al.'s code rejects such input "
                        f"too); check that the rest and initial meshes belong together")
    return problem, init, orientation, np.ones(3)


@float64
def untangle_case(folder, solver="lbfgs", progress=True, **options):
    """Read a LIM case folder (:meth:`geomopt.lim.LimCase.read`) and untangle it
    (:func:`lim_problem`, :func:`untangle`).

    Parameters
    ----------
    folder : a case folder, or a case already read (:class:`~geomopt.lim.LimCase`).
    solver, progress, options : passed to :func:`untangle`.

    Returns
    -------
    case : a dict with the case's keys (:class:`~geomopt.lim.LimCase`) plus ``problem`` and
        ``orientation`` (+1 or -1: the orientation every element of the output must have in
        the input's connectivity), as :func:`write_untangle_result` needs.
    result : :class:`UntangleResult`, its ``x`` in the input's frame.
    """
    from .lim import LimCase

    case = folder if isinstance(folder, Mapping) else LimCase.read(folder)
    problem, x0, orientation, mirror = lim_problem(case)
    result = untangle(problem, x0, solver=solver, progress=progress, **options)
    if (mirror < 0).any():
        result = dataclasses.replace(result, x=result.x * mirror)  # negation is exact
    return {**case, "problem": problem, "orientation": orientation}, result


def write_untangle_result(case, result, path):
    """Write an untangled LIM case and certify the file.

    2D: OBJ with the case's ``v`` lines, one ``vt`` per vertex (the map) and ``f a/a b/b c/c``;
    3D: ASCII VTK with the input connectivity.  Full precision, atomic (:mod:`geomopt.io`).
    The file is read back and checked: handles bit-exact and locally injective (exact
    predicates, in the orientation convention of the case: :func:`~geomopt.certify.local_certificate`).

    Returns
    -------
    dict with ``path``, ``inverted`` (in the file), ``handles_moved`` (in the file),
    ``certified`` (both zero and the map locally injective), ``message`` (why not, or "").
    """
    from .io import read_vtk_tets, write_obj_with_uv, write_vtk_tets

    path = Path(path)
    H = case["handles"]
    if case["dim"] == 2:
        F = case["faces"]
        write_obj_with_uv(path, case["rest"], F, result.x)
        back = _read_obj_uv(path, len(case["rest"]))
        S = F
        handles_ref = case["init"][H]
    else:
        T = case["tets"]
        write_vtk_tets(path, result.x, T)
        back, T2 = read_vtk_tets(path)
        if not np.array_equal(T2, T):
            raise MeshError(f"{path}: connectivity read back differs from the input")
        S = T
        handles_ref = case["init"][H]
    cert = local_certificate(back, S, orientation=case["orientation"])
    moved = _bits_differ(back[H], handles_ref)
    message = "; ".join(filter(None, [cert.message, f"{moved} handle(s) moved" if moved else ""]))
    return {"path": path, "inverted": cert.inverted, "handles_moved": moved,
            "certified": cert.ok and moved == 0, "message": message}


def _read_obj_uv(path, n):
    from .io import read_obj_with_uv

    _, UV, _ = read_obj_with_uv(path)
    if len(UV) != n:
        raise MeshError(f"{path}: read back {len(UV)} vt lines, expected {n}")
    return UV

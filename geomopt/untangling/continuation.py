"""The outer loop of untangling as a continuation of :func:`~geomopt.solvers.iterate`
(:class:`EpsContinuation`), one :class:`UntangleRecord` per outer iteration, and the judgement
of the final map (:func:`judged`)."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple
import dataclasses
import math
import time

import jax.numpy as jnp
import numpy as np

from .._runtime.programs import jit as programs_jit
from .._runtime.threads import AHEAD_FROM, ahead
from ..exact.predicates import differing_rows
from ..mesh.geometry import det
from ..objective.objective import jacobians, total_energy
from ..solvers import AbstractContinuation, Decision, Final, Newton, Outcome, local_certificate
from .inner import PROBE_PROGRESS, STIFF_AFTER, STIFF_AFTER_NEWTON, polish_solver
from .schedule import EPS_FLOOR, final_eps, next_eps

__all__ = ["UntangleRecord", "EpsContinuation", "judged"]


class UntangleRecord(NamedTuple):
    """One outer iteration of :func:`~geomopt.untangling.untangle` (``trace.phases``): the eps used, the energy
    (total, and over the rest volume) of the whole problem after the inner solve, its worst
    ``det J`` and float-inverted count, and the inner iterations."""

    eps: float
    energy: float
    mean_energy: float
    min_det: float
    inverted: int
    inner: int

    def line(self, k: int) -> str:
        return (f"outer {k:3d}  eps {self.eps:9.3e}  mean energy {self.mean_energy:.8g}  min det {self.min_det:+.3e}  "
                f"inverted {self.inverted:6d}  inner {self.inner:5d}")


@partial(programs_jit, static_argnums=0)
def _outer_stats(density, geom, x, params):
    """(energy over all elements, min det J, #elements with det J <= 0), over the elements of
    positive rest volume (``bucket`` padding adds elements of zero volume)."""
    D = det(jacobians(geom, x))
    real = geom[2] > 0
    return total_energy(density, geom, x, params), jnp.min(jnp.where(real, D, jnp.inf)), jnp.sum(real & (D <= 0))


class EpsContinuation(AbstractContinuation):
    """The eps schedule of :func:`~geomopt.untangling.untangle` as a continuation of
    :func:`~geomopt.solvers.iterate`: after each inner solve, measure the energy and worst
    ``det J`` over the whole (normalised) problem; stop when nothing is inverted and the
    energy settled, else shrink eps (:func:`next_eps`) and go on.  Once untangled and settled,
    with ``options.polish``, one more phase polishes the map by Newton
    (:func:`~geomopt.untangling.polish_solver`, injective) at the constant :func:`final_eps`:
    the map returned is then the minimiser of an energy whose parameters do not depend on the
    path (the start, the eps schedule), a smooth function of the rest mesh and the handles
    (:func:`geomopt.untangling.implicit.untangle_map` differentiates it).  ``finish`` maps the last
    iterate back to the input frame, writes the handles back bit for bit and certifies it.

    Parameters
    ----------
    problem : the input :class:`~geomopt.Problem`;  scaled : its normalised copy;  full : the
        objective of ``scaled`` (the outer statistics); objective : the inner one (the active
        elements, padded like ``full``), whose parameters change;  map_scale : the power of two
        the map was scaled by;  xs : the scaled start.
    options : :class:`~geomopt.untangling.UntangleOptions`;  details : :class:`~geomopt.solvers.UntangleDetails` of the result;
    initially : inverted elements of the start map;  solver : the inner solver (its search is
        made injective once nothing is inverted with ``injective_when_untangled``).
    stiff : the solver a stalled inner solve continues with (:func:`~geomopt.untangling.stiff_solver`), or None.
    stall : stop (``Outcome.MAX_STEPS``, "stalled") once eps has been at its floor for this many
        outer iterations with no fewer inverted elements than the best before them; None (the
        default) never stops for that.  The driver sets it when it has another start to try.

    Notes
    -----
    While ``stiff`` is pending the inner solves run :attr:`phase_solver`, the solver capped at
    :data:`STIFF_AFTER` iterations (the same compiled loop), and a solve that reaches the cap
    continues with ``stiff`` for the rest of the solve (from the map it started at after a
    diagonal-seeded probe, from the probe's map otherwise), unless (L-BFGS seeds
    only) the probe made fast progress: it removed inverted elements and energy, fewer than
    :data:`PROBE_PROGRESS` times those at its start are left.  Then the same solver goes on for
    another probe, memory kept.  Local tangles (noise) lose folds and energy fast under the
    diagonal seed, whose iterations cost a third of the Laplacian seed's and take as many;
    global ones (rotations, twists, bends) *gain* folds in their first hundred diagonal
    iterations (disk 12.7k rotated 180 degrees: 270 -> 772, ball 12k rotated: 1,966 -> 3,964,
    twisted cube 48k: 3,905 -> 10,926); a Tutte map onto a star loses folds but its energy
    only slowly (mean 3.24 -> 2.52), and the Laplacian seed smooths it in half the iterations.
    A Delaunay disk of 12k triangles with noise: 5,866 -> 4,035 -> 901 folds and mean energy
    5,358 -> 17.5 -> 3.1 at 100 and 200 iterations: no switch, 0.85 -> 0.63 s.
    """

    def __init__(self, problem, scaled, full, objective, map_scale, xs, options, details, initially, solver,
                 stiff=None, forced=None, stall=None):
        self.stall, self.at_floor = stall, 0  # outer iterations ended with eps at the floor
        self.problem, self.scaled, self.full, self.objective, self.solver = problem, scaled, full, objective, solver
        self.forced = forced  # the input's overlaps that the handles alone make (Problem.certify_fixed)
        self.probe = STIFF_AFTER_NEWTON if isinstance(stiff, Newton) else STIFF_AFTER
        self.stiff = stiff if stiff is not None and solver.max_steps > self.probe else None
        self.probed = 0  # inner iterations of this outer iteration before a switch to ``stiff``
        self.window = (initially, math.inf)  # inverted elements and energy at the probe's start
        self.k, self.xs, self.options, self.details, self.initially = map_scale, xs, options, details, initially
        self.eps = float(options.eps0)
        self.floor = EPS_FLOOR.get(problem.dim, 1e-10)
        self.injective = False
        self.polishing = False
        self._ahead = None  # the thread of prepare_polish
        self.inverted = []
        self.E = math.nan

    def _stats(self, x, params):
        return (float(v) for v in _outer_stats(self.objective.energy.density, self.full.geom, x, params))

    @property
    def phase_solver(self):
        """The solver of the next inner solve: capped at :data:`STIFF_AFTER` iterations
        (:data:`STIFF_AFTER_NEWTON` before Newton) while a switch to ``stiff`` is pending."""
        return self.solver if self.stiff is None else dataclasses.replace(self.solver, max_steps=self.probe)

    def _probe_progressed(self, state) -> bool:
        """Whether the probe that just ended removed enough inverted elements and energy to run
        another (:data:`PROBE_PROGRESS`; never before Newton, never past the solver's own step
        limit)."""
        if isinstance(self.stiff, Newton) or self.probed + state.iteration >= self.solver.max_steps:
            return False
        E, _, now = self._stats(state.x, state.params)
        (folds, energy), start = PROBE_PROGRESS, self.window
        progressed = now < folds * start[0] and E < energy * min(start[1], self.E)
        self.window = (int(now), E)
        return progressed

    def _stalled(self) -> bool:
        """Whether the last :attr:`stall` outer iterations, all at the eps floor, left no fewer
        inverted elements than the best before them (the outer iteration just recorded included)."""
        self.at_floor = self.at_floor + 1 if self.eps <= self.floor else 0
        k = self.stall
        if k is None or self.at_floor < k or len(self.inverted) <= k:
            return False
        return min(self.inverted[-k:]) >= min(self.inverted[:-k])

    def start(self, state):
        self.E = next(iter(self._stats(state.x, state.params)))
        self.x_solve = state.x  # where the current inner solve started

    def __call__(self, state, outcome) -> Decision:
        if self.polishing:
            return self._polished(state, outcome)
        if self.stiff is not None and outcome is Outcome.MAX_STEPS and state.iteration >= self.probe:
            if self._probe_progressed(state):  # still untangling locally: another probe, same solver
                self.probed += state.iteration
                return Decision.go(state.params, solver=self.phase_solver)
            # a stiff, global inner solve: the Laplacian seed from here on, same eps; after a
            # diagonal-seeded probe from the map this inner solve started at (the probe's map,
            # which gained folds, cost the Laplacian seed 1,107 iterations on a 10^6-tet noisy
            # box, against 202 from the start); after a Laplacian-seeded probe, and before
            # Newton (hexahedra's corners), from the probe's map (restarting a Laplacian probe
            # from its start cost rotated 10^5-triangle squares 18-33 % more iterations)
            diagonal = getattr(self.solver, "precondition", None) == "diagonal"
            x = self.x_solve if diagonal and not isinstance(self.stiff, Newton) else state.x
            self.probed, self.solver, self.stiff = self.probed + state.iteration, self.stiff, None
            return Decision.go(state.params, objective=self.objective, x=x, solver=self.solver)
        opts, E_prev = self.options, self.E
        E, detmin, nneg = self._stats(state.x, state.params)
        self.E, nneg = E, int(nneg)
        self.inverted.append(nneg)
        record = UntangleRecord(self.eps, E, E / self.full.total_volume, detmin, nneg, self.probed + state.iteration)
        self.probed, self.window = 0, (nneg, math.inf)
        if not (math.isfinite(E) and math.isfinite(detmin)):
            return Decision.stop_with(Outcome.NONFINITE, record=record)
        settled = abs(E_prev - E) / abs(E) < opts.energy_tol
        folded = self.scaled.count_inverted(self.full.unpad_map(np.asarray(state.x))) if detmin > 0 and settled \
            else None
        if folded == 0:
            return self._polish(state, record) if opts.polish else Decision.stop_with(Outcome.CONVERGED, record=record)
        if folded and self.problem.elements is not None and self.eps <= self.floor:
            # hexahedra folded inside, every corner positive: the energy sees corners only, more
            # iterations cannot help
            return Decision.stop_with(Outcome.NOT_INJECTIVE, f"every corner is positive but {folded} hexahedra "
                                      f"fold inside (det J <= 0 between their corners, exact Bernstein test)", record)
        if self._stalled():
            return Decision.stop_with(Outcome.MAX_STEPS, f"stalled: eps at its floor for {self.stall} outer "
                                      f"iterations and no fewer than {min(self.inverted)} inverted", record)
        if len(self.inverted) >= opts.max_outer:
            return Decision.stop_with(Outcome.MAX_STEPS, f"stopped at the outer-iteration limit (max_outer="
                                      f"{opts.max_outer}) before it settled", record)
        self.eps = next_eps(self.eps, E, E_prev, detmin, opts.min_sigma, opts.max_sigma, self.floor)
        params = self.objective.params(eps=self.eps)
        if opts.injective_when_untangled and not self.injective and detmin > 0:
            self.injective = True  # from now on no element may flip back
            self.solver, self.stiff = (None if s is None else dataclasses.replace(
                s, search=dataclasses.replace(s.search, injective=True)) for s in (self.solver, self.stiff))
        self.E = next(iter(self._stats(state.x, params)))
        # stale curvature pairs can steer the next solve into more folds: drop them then
        worse = len(self.inverted) > 1 and self.inverted[-1] > self.inverted[-2]
        self.x_solve = state.x
        return Decision.go(params, restart=not opts.keep_memory or worse, solver=self.phase_solver, record=record)

    def prepare_polish(self) -> None:
        """Build the polish's Hessian pattern and sparse Cholesky analysis on a thread
        (:func:`~geomopt._runtime.threads.ahead`) while the eps loop runs, for problems of
        :data:`~geomopt._runtime.threads.AHEAD_FROM` free coordinates or more (below, the
        thread costs more than the work) whose polish factors (not CG's); :meth:`_polish`
        waits for it.  Nothing is done without ``options.polish``."""
        newton = polish_solver()
        if (self.options.polish and int(np.count_nonzero(self.objective.free_dofs)) >= AHEAD_FROM
                and not newton.uses_cg(self.objective)):
            self._ahead = ahead(lambda: self.objective.cholesky(newton.linear_solver))

    def _polish(self, state, record) -> Decision:
        """Start the final polish (class notes) from the untangled, settled map (its energy
        is measured when the polish ends, :meth:`_polished`)."""
        if self._ahead is not None:
            self._ahead.join()
        self.polishing, self.eps = True, final_eps(self.problem.dim)
        params = self.objective.params(eps=self.eps)
        return Decision.go(params, objective=self.objective, x=state.x, solver=polish_solver(), record=record)

    def _polished(self, state, outcome) -> Decision:
        """The end of the polish: CONVERGED (the exact certificate in :meth:`finish` judges the map),
        ``details.polished`` whether Newton converged."""
        E, detmin, nneg = self._stats(state.x, state.params)
        self.E = E
        record = UntangleRecord(self.eps, E, E / self.full.total_volume, detmin, int(nneg), state.iteration)
        self.details = dataclasses.replace(self.details, polished=outcome is Outcome.CONVERGED)
        if not (math.isfinite(E) and math.isfinite(detmin)):
            return Decision.stop_with(Outcome.NONFINITE, record=record)
        return Decision.stop_with(Outcome.CONVERGED, record=record)

    def finish(self, state, outcome, reason) -> Final:
        problem, k = self.problem, self.k
        xs_final = np.asarray(state.x, dtype=np.float64)
        if not np.isfinite(xs_final).all():
            outcome, xs_final = Outcome.NONFINITE, self.xs
        out = xs_final[: problem.n_vertices] / k  # without bucket padding
        out[problem.fixed] = problem.fixed_positions
        t_certify = time.perf_counter()
        outcome, cert, reason = judged(problem, out, outcome, reason, self.forced)
        return Final(out, outcome, cert, reason, problem=problem, energy=self.E,
                     volume=self.full.total_volume, details=self.details, inverted_at_start=self.initially,
                     certify_seconds=time.perf_counter() - t_certify)


def judged(problem, x, outcome, reason="", forced=None):
    """``(outcome, certificate, reason)`` of the final map ``x`` (n, d): its exact
    :class:`~geomopt.solvers.LocalCertificate` (``forced``, the input's
    :meth:`~geomopt.Problem.certify_fixed`, attached when it lists an overlap), and CONVERGED
    kept only for a valid map: CERTIFIED_EXCEPT_FIXED when it fails only where ``forced`` says
    the handles alone make it fail, else NOT_INJECTIVE with the first failure a free vertex
    could have removed."""
    moved = int(np.count_nonzero(differing_rows(x[problem.fixed], problem.fixed_positions)))
    cert = local_certificate(problem, x, moved)
    if forced is not None and not forced.ok:
        cert = dataclasses.replace(cert, forced=forced)
    if outcome is not Outcome.CONVERGED or cert.valid:
        return outcome, cert, reason
    if cert.valid_except_forced:
        return Outcome.CERTIFIED_EXCEPT_FIXED, cert, (
            f"converged, but the handles alone make the map overlap at {forced.failures} vertices and edges whose "
            f"elements all have every vertex fixed (a property of the input, the same for every map with these "
            f"handles; first: {forced.message}); everywhere else the map is certified locally injective")
    if not cert.inverted and not cert.ok:
        reason = _local_reason(problem, cert if cert.forced is None else cert.beyond(cert.forced))
    return Outcome.NOT_INJECTIVE, cert, reason


def _local_reason(problem, cert) -> str:
    """Why a map with every element positive is not locally injective, with what to do."""
    if np.isin(problem.boundary_vertices(), problem.fixed).all():
        hint = "the fixed boundary probably winds more than once or overlaps itself, check the handle positions"
    elif problem.dim == 2:
        hint = ("flip-free motion cannot remove it; start from a map whose boundary is a simple "
                "polygon (e.g. a Tutte embedding) or fix the boundary while untangling")
    else:  # a free boundary surface folded over itself
        hint = ("flip-free motion cannot remove it: the free boundary surface folds over itself; start from "
                "a map whose boundary surface does not cross itself (the rest mesh moved rigidly onto the "
                "handles, when they allow it) or fix the whole boundary surface while untangling")
    return f"no element is inverted, but {cert.message}; {hint}"

"""Outcomes, the per-iteration statistics every solver reports, and the one stopping rule.

A solver's step reports *facts* about the iteration it took in a :class:`Stats` (the energy,
the decrease its direction promised, whether its search accepted a step...); whether the
solve stops, and why, is decided in one place only: :class:`Termination`.  The same rule
runs on host floats (:func:`~geomopt.solvers.iterate` between steps) and on traced values
(inside L-BFGS's jitted ``lax.while_loop``).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from .._runtime.config import Int, Real, validate

#: a map whose extent grows by more than this factor over its start (and rest) extent diverged
DIVERGENCE_FACTOR = 1e6

#: status code of a solve that goes on (the :class:`Outcome` codes are 1..6)
RUNNING = 0


class Outcome(enum.Enum):
    """How a solve ended; ``code`` is the integer the stopping rule returns (0 = running)."""

    CONVERGED = "converged"
    MAX_STEPS = "max_steps"
    LINE_SEARCH_FAILED = "line_search_failed"
    NONFINITE = "nonfinite"
    NOT_INJECTIVE = "not_injective"
    DIVERGED = "diverged"
    #: untangling: locally injective wherever a free vertex reaches, but the handles alone make
    #: some star overlap (every element there has all its vertices fixed): a property of the input
    CERTIFIED_EXCEPT_FIXED = "certified_except_fixed"

    @property
    def code(self) -> int:
        return _CODES[self]

    @classmethod
    def of(cls, code) -> "Outcome | None":
        """The outcome of a status code (None for :data:`RUNNING`)."""
        code = int(code)
        return None if code == RUNNING else _OUTCOMES[code]

    @property
    def message(self) -> str:
        return {
            "converged": "converged",
            "max_steps": "stopped at the iteration limit before converging (raise max_steps)",
            "line_search_failed": "the line search found no acceptable step (the problem may be "
            "badly scaled or the energy non-smooth)",
            "nonfinite": "the energy or gradient became NaN/inf (check the input and the start map)",
            "not_injective": "the result is not locally injective (inverted or degenerate elements, "
            "or elements overlapping around a vertex or edge)",
            "diverged": "the solve diverged: the energy fell without bound or below its known "
            "lower bound (check the energy and its parameters, or fix more vertices)",
            "certified_except_fixed": "every element is positive and the map is locally injective wherever "
            "a free vertex reaches, but the handles alone make it overlap where every element has all its "
            "vertices fixed (a property of the input)",
        }[self.value]


_OUTCOMES = dict(enumerate(Outcome, start=1))
_CODES = {o: c for c, o in _OUTCOMES.items()}


class Stats(NamedTuple):
    """What one iteration of a solver reports (host floats, or traced scalars in a kernel).

    Attributes
    ----------
    iteration : iterations taken since the solver started (or was re-parameterised).
    value : the energy ``E(x)`` at the current map.
    past_value : the energy the stall test compares with: ``window`` iterations ago for
        L-BFGS, the previous iteration for the others (inf when there is none).
    decrement : >= 0, the energy decrease the last direction promised (Newton: ``-g.d / 2``
        for the full step; AQP: of the step taken; L-BFGS: ``-g.d / 2``); inf before the first.
    step_size : the step the search accepted (nan before the first, 0 when none).
    grad_norm, grad_norm0 : ``|grad E|`` on the free DOFs, now and at the start.
    extent, extent0 : the largest side of the map's bounding box, now and its reference (the
        larger of the start map's and the rest mesh's).
    accepted : False when the last search accepted no step.
    broken : True when the last iteration could not make a direction (non-finite values, no
        factorization).
    done : True when the descent's own rule says it has converged (an external solver's).
    evaluations : energy (and gradient) evaluations so far.
    floor : the energy magnitude below which relative tests use this instead
        (``1e-12 |E(x0)|``): energies that reach 0.
    lower, lower_tol : the energy's known lower bound times the rest volume (-inf when none)
        and the rounding allowed below it.
    """

    iteration: Any = 0
    value: Any = math.nan
    past_value: Any = math.inf
    decrement: Any = math.inf
    step_size: Any = math.nan
    grad_norm: Any = math.nan
    grad_norm0: Any = math.nan
    extent: Any = math.nan
    extent0: Any = math.inf
    accepted: Any = True
    broken: Any = False
    done: Any = False
    evaluations: Any = 1
    floor: Any = 1e-300
    lower: Any = -math.inf
    lower_tol: Any = 0.0


def _host(stats) -> bool:
    return all(isinstance(v, (bool, int, float, np.number, np.bool_)) for v in stats)


@dataclasses.dataclass(frozen=True)
class Termination:
    """The stopping rule of every solver: :meth:`status` of a :class:`Stats`.

    In this order, with ``S = max(|E|, floor)`` and ``S' = max(|E_past|, |E|, floor)``:

    1. ``E`` not finite, or no direction could be made: NONFINITE;
    2. the search accepted no step: CONVERGED when the direction promised at most
       ``flat * S`` (the start was stationary up to rounding), else LINE_SEARCH_FAILED;
    3. the map grew or shrank by ``DIVERGENCE_FACTOR`` over its reference, or ``E`` fell
       below the energy's lower bound: DIVERGED;
    4. CONVERGED when the descent says so (``done``), or ``|g| <= gtol |g0|`` (``gtol > 0``),
       or ``decrement <= rtol * S`` (``rtol > 0``), or the energy *stalled*: it fell by at
       most ``ftol * S'`` since ``E_past`` while the decrement promises at most ``stall * S'``
       (a stalled energy is rounding only when little more is promised: with a larger
       decrement the search is cutting steps short, e.g. at the injective cap);
    5. ``iteration >= max_steps``: MAX_STEPS (:meth:`__call__` only: a solver's jitted kernel
       takes the limit as a traced argument).

    Attributes
    ----------
    rtol, ftol, stall, gtol, flat : the relative tolerances above (0 turns ``rtol`` /
        ``gtol`` off).  Each solver derives its rule from its own fields
        (``solver.termination``).
    max_steps : iteration limit.
    """

    rtol: float = 1e-10
    ftol: float = 1e-12
    stall: float = 1e-5
    gtol: float = 0.0
    flat: float = 1e-14
    max_steps: int = 200

    def __post_init__(self):
        validate(self, rtol=Real(0.0), ftol=Real(0.0), stall=Real(0.0), gtol=Real(0.0, 1.0, hi_open=True),
                 flat=Real(0.0), max_steps=Int(1))

    def status(self, s: Stats):
        """The status code (:data:`RUNNING` or an :attr:`Outcome.code`) of ``s``, without the
        step limit: a Python int for host values, a traced int32 inside ``jit``."""
        host = _host(s)
        if host:
            with np.errstate(invalid="ignore", over="ignore"):
                return int(self._status(np, s))
        return self._status(jnp, s).astype(jnp.int32)

    def _status(self, xp, s):
        scale = xp.maximum(xp.abs(s.value), s.floor)
        fscale = xp.maximum(xp.maximum(xp.abs(s.past_value), xp.abs(s.value)), s.floor)
        drop = s.past_value - s.value
        stalled = (xp.isfinite(s.past_value) & (drop >= 0) & (drop <= self.ftol * fscale)
                   & (s.decrement <= self.stall * fscale))
        converged = s.done | stalled
        if self.rtol > 0:
            converged = converged | (s.decrement <= self.rtol * scale)
        if self.gtol > 0:
            converged = converged | (s.grad_norm <= self.gtol * s.grad_norm0)
        diverged = ((s.extent > DIVERGENCE_FACTOR * s.extent0) | (s.extent * DIVERGENCE_FACTOR < s.extent0)
                    | (s.value < s.lower - s.lower_tol))
        code = xp.where(converged, Outcome.CONVERGED.code, RUNNING)
        code = xp.where(diverged, Outcome.DIVERGED.code, code)
        flat = s.decrement <= self.flat * scale
        code = xp.where(s.accepted, code, xp.where(flat, Outcome.CONVERGED.code,
                                                   Outcome.LINE_SEARCH_FAILED.code))
        return xp.where(~xp.isfinite(s.value) | s.broken, Outcome.NONFINITE.code, code)

    def __call__(self, s: Stats) -> int:
        """:meth:`status` with the step limit (host values)."""
        code = self.status(s)
        if code == RUNNING and s.iteration >= self.max_steps:
            return Outcome.MAX_STEPS.code
        return code

    @staticmethod
    def reason(s: Stats) -> str | None:
        """Why the solve in ``s`` diverged (the test of rule 3), or None."""
        if s.lower > -math.inf and math.isfinite(s.value) and s.value < s.lower - s.lower_tol:
            return f"the energy {s.value:.6g} is below the energy's lower bound {s.lower:.6g}"
        if math.isfinite(s.extent) and s.extent > DIVERGENCE_FACTOR * s.extent0:
            return (f"the map grew to {s.extent:.3g} across, {s.extent / s.extent0:.3g} times its "
                    f"start and rest size, while the energy fell to {s.value:.6g}")
        if math.isfinite(s.extent) and s.extent * DIVERGENCE_FACTOR < s.extent0:
            return (f"the map collapsed to {s.extent:.3g} across, {s.extent / s.extent0:.3g} times its "
                    "start and rest size (the energy is lowered by shrinking the map: with a free "
                    "boundary it has no minimiser; fix vertices or use a scale-aware energy)")
        return None

"""The solver interface and the state of a solve.

A solver is an immutable configuration object (DESIGN.md §1, in the style of optimistix): a
*descent* (how it makes a direction: projected Newton, L-BFGS, SLIM, AQP, CM, an optimistix
descent) plus the shared :class:`~geomopt.solvers.linesearch.InjectiveSearch` in its ``search``
field (how far it goes).  Every solver has

* ``init(objective, x0, params) -> State``: evaluate the start, build what the descent keeps
  (a factorization's symbolic analysis, curvature pairs...) and compile its kernels;
* ``step(state) -> State``: one iteration; it reports what happened in ``state.stats``
  (:class:`~geomopt.solvers.Stats`) and never decides to stop (its duties:
  :meth:`AbstractSolver.step`, checked after every step by :func:`check_step`);
* ``termination``: its :class:`~geomopt.solvers.Termination` (the one stopping rule, with
  the solver's tolerances);
* ``reparam(state, params) -> State``: the same map under new energy parameters (counters
  restart, memory is kept) and ``restart(state, x=None) -> State``: the memory that depends
  on the path (curvature pairs, momentum) dropped, the map moved to ``x`` when given; what
  continuations and guards of :func:`~geomopt.solvers.iterate` ask for;
* ``advance(state, limit) -> State`` where a solver has a jitted multi-step kernel (L-BFGS):
  iterations in one compiled program until its termination stops or ``state.iteration`` reaches
  ``limit``; ``None`` elsewhere.

:func:`~geomopt.solvers.iterate` owns the loop; a notebook can also drive ``init`` / ``step``
by hand.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import Any, Mapping

import jax
import numpy as np

from .._runtime.x64 import float64_methods
from .._runtime.config import Instance, Int, Real, validate
from .._runtime.errors import ParameterError
from .linesearch import InjectiveSearch
from ._termination import Stats, Termination

_STATS_FIELDS = frozenset(Stats._fields)


@dataclasses.dataclass(frozen=True)
class State:
    """The state of one solve.

    Attributes
    ----------
    objective : the :class:`~geomopt.Objective` being minimised.
    params : dict of the energy parameters (float64 scalars).
    x : (n_padded, d) jax array, the current map (padded like the objective).
    grad : (n_padded, d) jax array, the energy's gradient at ``x``, zero on fixed DOFs.
    stats : :class:`~geomopt.solvers.Stats` of the last iteration.
    memory : what the descent keeps between steps (a typed record of each solver: read it
        through the solver).
    """

    objective: Any
    params: Mapping
    x: Any
    grad: Any
    stats: Stats
    memory: Any = None

    # the statistics most callers read (progress bars, notebooks)
    value = property(lambda self: self.stats.value)
    iteration = property(lambda self: self.stats.iteration)
    step_size = property(lambda self: self.stats.step_size)
    decrement = property(lambda self: self.stats.decrement)
    evaluations = property(lambda self: self.stats.evaluations)

    def update(self, **changes) -> "State":
        """A copy with state fields and :class:`Stats` fields replaced (by name)."""
        stats = {k: changes.pop(k) for k in list(changes) if k in _STATS_FIELDS}
        if stats:
            changes["stats"] = self.stats._replace(**stats)
        return dataclasses.replace(self, **changes)


def map_extent(x) -> float:
    """The largest side of the bounding box of a map (n, d)."""
    x = np.asarray(x)
    return float(np.max(x.max(axis=0) - x.min(axis=0))) if x.size else 0.0


def reference_extent(objective, x0) -> float:
    """max(extent of the start map, extent of the rest mesh, tiny): the divergence test's unit.
    A sphere problem's rest triangles are scaled to the unit sphere's area whatever the input's
    units (:meth:`~geomopt.Problem.sphere`): its rest extent is the sphere's, 2."""
    problem = objective.problem
    rest = 2.0 if problem.kind == "sphere" else map_extent(problem.rest_vertices)
    return max(map_extent(x0), rest, 1e-300)


#: the :class:`Stats` fields set by ``init`` that no step may change (:meth:`AbstractSolver.step`)
_REFERENCES = ("extent0", "floor", "lower", "lower_tol", "grad_norm0")


def _same(a, b) -> bool:
    """``a == b`` for host scalars, NaN equal to NaN (a reference no solver set)."""
    return bool(a == b) or bool(a != a and b != b)


def check_step(solver, old: State, new: State) -> None:
    """The duties of :meth:`AbstractSolver.step` that can be checked for free on ``new``, the
    step of ``old``: one iteration further, the references kept, a moved map with its own
    gradient.  Raises :class:`~geomopt.ParameterError` naming the solver's class and the duty."""
    name = f"{type(solver).__name__}.step"
    if not isinstance(new, State):
        raise ParameterError(f"{name} returned a {type(new).__name__}, not a State (AbstractSolver.step)")
    if new.stats.iteration != old.stats.iteration + 1:
        raise ParameterError(f"{name} must set stats.iteration to {old.stats.iteration + 1} (one more than the "
                             f"state's), got {new.stats.iteration} (AbstractSolver.step)")
    changed = [k for k in _REFERENCES if not _same(getattr(new.stats, k), getattr(old.stats, k))]
    if changed:
        raise ParameterError(f"{name} changed stats.{', '.join(changed)}, which init sets and no step may change "
                             f"(AbstractSolver.step)")
    if new.x is not old.x and new.grad is old.grad:
        raise ParameterError(f"{name} moved x but kept the old grad: set grad, value and extent at the new x "
                             f"(AbstractSolver.step)")


def start_stats(objective, x0, value: float, **fields) -> Stats:
    """The :class:`Stats` of a solve starting at ``x0`` with energy ``value``: the references
    of the relative and divergence tests (energy floor, extent, the energy's lower bound)."""
    lb = getattr(objective.energy, "lower_bound", None)
    lower, tol = -math.inf, 0.0
    if lb is not None:
        vol = objective.total_volume
        lower = lb * vol
        tol = 1e-8 * max(abs(lower), vol)
    return Stats(value=value, extent=map_extent(x0), extent0=reference_extent(objective, x0), floor=max(1e-12 * abs(value), 1e-300),
                 lower=lower, lower_tol=tol, **fields)


class AbstractSolver(abc.ABC):
    """A minimiser of an :class:`~geomopt.objective.objective.Objective`: a descent plus ``search``."""

    max_steps: int
    rtol: float
    search: InjectiveSearch

    #: a jitted multi-step kernel ``advance(state, limit)`` (None: step by step)
    advance = None

    def __init_subclass__(cls, **kwargs):
        # solvers driven by hand (init / step...) run in float64 like minimize (geomopt._runtime.x64)
        super().__init_subclass__(**kwargs)
        float64_methods("init", "step", "advance", "reparam", "restart")(cls)

    def _check(self, **rules):
        """Validate the shared configuration and ``rules`` (every subclass's ``__post_init__``)."""
        validate(self, max_steps=Int(1), rtol=Real(0.0, 1.0, hi_open=True), search=Instance(InjectiveSearch),
                 **rules)

    @property
    def termination(self) -> Termination:
        """The stopping rule with this solver's tolerances: the decrement test at ``rtol``,
        the stall test at ``rtol / 100`` (promise ``sqrt(rtol)``), a failed search converged
        when the decrement is below the rounding of ``E`` (``1e-14`` relative)."""
        return Termination(rtol=self.rtol, ftol=0.01 * self.rtol, stall=math.sqrt(self.rtol), flat=0.5e-14,
                           max_steps=self.max_steps)

    @abc.abstractmethod
    def init(self, objective, x0, params) -> State: ...

    def load_ahead(self, objective):
        """Start loading (or compiling) the kernels :meth:`init` will need for ``objective`` on a
        thread (:func:`geomopt._runtime.threads.ahead`), for a caller with other work before
        :meth:`init` (:func:`geomopt.parameterize` builds its start map meanwhile).  Returns the
        thread, or None when this solver loads nothing ahead (the default)."""
        return None

    @abc.abstractmethod
    def step(self, state: State) -> State:
        """One iteration from ``state``: a new :class:`State` (``state`` itself unchanged).

        May assume: ``self.termination`` judged ``state.stats`` RUNNING, so ``value`` is
        finite, ``accepted`` is True, ``broken`` and ``done`` are False and ``iteration <
        max_steps`` (:func:`~geomopt.solvers.iterate` steps no other state, and a new phase
        starts from :meth:`reparam`, which resets them); ``state.grad`` is the gradient at
        ``state.x`` under ``state.params``, zero on fixed DOFs; ``state.memory`` is what this
        solver's ``init`` / ``step`` / ``reparam`` / ``restart`` left.

        Must set in the returned ``stats`` (the facts :class:`~geomopt.solvers.Termination`
        reads; it decides whether to stop, the step never does):

        * ``iteration``: ``state.iteration + 1``, on every path (a step that leaves it
          would loop until the wall clock);
        * ``broken = True`` when no direction could be made (nothing else is then read);
        * ``accepted = False`` when the search took no step; ``x``, ``value``, ``grad`` and
          ``extent`` are then the state's;
        * when ``x`` moves: ``value`` ``E(x)``, ``grad`` at ``x`` (a new array, zero on fixed
          DOFs), ``extent`` (:func:`map_extent`) and ``evaluations`` (plus those made);
        * ``decrement`` (>= 0, the decrease the direction promised) whenever the
          termination's ``rtol`` is on, also when the search took no step (rule 2 tells a
          stationary start from a failed search by it); left ``inf``, the decrement test is
          off (a descent that reports ``done`` instead: :class:`~geomopt.solvers.optimistix.Optimistix`);
        * ``past_value``: the energy the stall test compares with (the value before the step,
          or ``window`` steps back); left ``inf``, the stall test is off;
        * ``grad_norm`` when the termination's ``gtol > 0`` (L-BFGS);
        * ``done`` when the descent has its own convergence test.

        ``step_size`` (nan when unknown) feeds the progress and trace only.  The references
        set by ``init`` (:func:`start_stats`: ``extent0``, ``floor``, ``lower``, ``lower_tol``,
        and ``grad_norm0``) stay as they are.
        """

    def reparam(self, state: State, params) -> State:
        """``state`` re-evaluated under new energy parameters; counters restart."""
        value, grad = state.objective.value_and_grad(state.x, params)
        stats = state.stats._replace(value=float(value), iteration=0, past_value=math.inf, decrement=math.inf,
                                     step_size=math.nan, accepted=True, broken=False, done=False)
        return dataclasses.replace(state, params=params, grad=grad, stats=stats)

    def restart(self, state: State, x=None) -> State:
        """``state`` without the memory that depends on the path taken (none here), moved to
        ``x`` (re-evaluated there, counters kept) when given."""
        if x is None:
            return state
        return self._moved(state, x)

    def _moved(self, state: State, x) -> State:
        value, grad = state.objective.value_and_grad(x, state.params)
        return state.update(x=x, grad=grad, value=float(value), extent=map_extent(x),
                            evaluations=state.stats.evaluations + 1)

    def _start(self, objective, x0, params, memory=None) -> State:
        """The common start state: value and gradient at ``x0`` (padded to the objective's
        size bucket, see :meth:`~geomopt.Objective.pad_map`)."""
        # a private copy (device_put may share a NumPy buffer on CPU), without the copy
        # program jnp.asarray compiles per shape
        x = jax.device_put(objective.pad_map(np.array(x0, dtype=np.float64)))
        value, grad = objective.value_and_grad(x, params)
        return State(objective, params, x, grad, start_stats(objective, x0, float(value)), memory)

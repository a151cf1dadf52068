"""Solver interface (``init / step / terminate``), outcomes, results and the driver loop.

Solvers are immutable configuration objects (DESIGN.md §1, in the style of optimistix):

* ``init(objective, x0, params) -> State``
* ``step(state) -> State``
* ``terminate(state) -> (bool, Outcome | None)``

:func:`minimize` owns the loop, progress output, history and timings, so a notebook can
also drive ``init`` / ``step`` by hand.
"""

from __future__ import annotations

import abc
import dataclasses
import enum
import sys
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import SolveError


class Outcome(enum.Enum):
    CONVERGED = "converged"
    MAX_STEPS = "max_steps"
    LINE_SEARCH_FAILED = "line_search_failed"
    NONFINITE = "nonfinite"
    NOT_INJECTIVE = "not_injective"
    DIVERGED = "diverged"

    @property
    def message(self) -> str:
        return {
            "converged": "converged",
            "max_steps": "stopped at the iteration limit before converging (raise max_steps)",
            "line_search_failed": "the line search found no acceptable step (the problem may be "
            "badly scaled or the energy non-smooth)",
            "nonfinite": "the energy or gradient became NaN/inf (check the input and the start map)",
            "not_injective": "the result has inverted or degenerate elements",
            "diverged": "the solve diverged: the energy fell without bound or below its known "
            "lower bound (check the energy and its parameters, or fix more vertices)",
        }[self.value]


@dataclasses.dataclass(frozen=True)
class State:
    """The state of one solve: the current map and what the solver keeps between steps."""

    objective: Any
    params: dict
    x: Any  # (n, d) jax array
    value: float
    grad: Any  # (n, d) jax array, zero on fixed vertices
    iteration: int = 0
    step_size: float = float("nan")
    decrement: float = float("inf")  # Newton decrement^2 / 2 or its analogue
    prev_value: float = float("inf")
    failure: Outcome | None = None
    aux: Any = None  # solver-specific (L-BFGS memory, ...)


class AbstractSolver(abc.ABC):
    """A minimiser of an :class:`~geomopt._objective.Objective`."""

    max_steps: int
    rtol: float

    @abc.abstractmethod
    def init(self, objective, x0, params) -> State: ...

    @abc.abstractmethod
    def step(self, state: State) -> State: ...

    def terminate(self, state: State):
        """Stop on failure, on a relative decrement below ``rtol``, or the limit.

        An energy change below ``0.01 rtol`` (relative) also counts as converged when the
        decrement is below ``sqrt(rtol)`` (one more Newton step would reach ``rtol``): that is
        the rounding floor.  With a larger decrement a stalled energy is not convergence (the
        line search is cutting the steps short, e.g. on an energy unbounded below); the solver
        goes on until its line search fails or the iteration limit.
        """
        if state.failure is not None:
            return True, state.failure
        if not np.isfinite(state.value):
            return True, Outcome.NONFINITE
        scale = max(abs(state.value), 1e-300)
        if state.decrement <= self.rtol * scale:
            return True, Outcome.CONVERGED
        if (state.iteration > 0 and 0 <= state.prev_value - state.value <= 0.01 * self.rtol * scale
                and state.decrement <= np.sqrt(self.rtol) * scale):
            return True, Outcome.CONVERGED
        if state.iteration >= self.max_steps:
            return True, Outcome.MAX_STEPS
        return False, None


@dataclasses.dataclass(frozen=True)
class Result:
    """The outcome of a solve.

    Attributes
    ----------
    x : (n, d) ndarray, the map.
    outcome : Outcome;  success : converged and injective (exact predicate).
    inverted : int, elements not positively oriented (exact predicate).
    energy : float, final total energy;  energy_history : per-iteration energies.
    iterations : int;  seconds : solve time;  setup_seconds : pattern + JIT compilation.
    info : dict; ``info["reason"]`` says why a solve ended DIVERGED (also in ``message``).
    """

    x: np.ndarray
    outcome: Outcome
    inverted: int
    energy: float
    energy_history: np.ndarray
    iterations: int
    seconds: float
    setup_seconds: float
    time_history: np.ndarray
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.outcome is Outcome.CONVERGED and self.inverted == 0

    @property
    def message(self) -> str:
        msg = self.outcome.message
        if self.info.get("reason"):
            msg += f" ({self.info['reason']})"
        if self.inverted:
            msg += f"; {self.inverted} inverted element(s)"
        return msg


class Progress:
    """Per-iteration log lines on a stream (None = silent)."""

    def __init__(self, stream=sys.stderr, every: int = 1, prefix: str = ""):
        self.stream, self.every, self.prefix = stream, every, prefix

    def __call__(self, state: State, elapsed: float, mean_energy: float):
        if self.stream is None or state.iteration % self.every:
            return
        print(
            f"{self.prefix}iter {state.iteration:4d}  energy {mean_energy:.10g}  "
            f"step {state.step_size:.3g}  decrement {state.decrement:.3g}  {elapsed:7.2f}s",
            file=self.stream,
            flush=True,
        )


DIVERGENCE_FACTOR = 1e6  # a map this many times wider than its start and its rest mesh diverged


@jax.jit
def _extent(x):
    """Bounding-box diagonal of the points ``x`` (n, d)."""
    return jnp.sqrt(jnp.sum((jnp.max(x, axis=0) - jnp.min(x, axis=0)) ** 2))


def divergence(state: State, reference_extent: float, lower_bound: float | None):
    """Why the solve in ``state`` diverged, or None.

    It diverged when the map's extent (bounding-box diagonal) exceeds ``DIVERGENCE_FACTOR``
    times ``reference_extent`` (the larger of the start map's and the rest mesh's: a
    minimiser of a bounded distortion energy stays at the scale of the data), or when the
    energy is below ``lower_bound`` (the energy's known bound times the rest volume, None if
    unknown), allowing for rounding.  Non-finite values are left to the NONFINITE outcome.
    """
    value = state.value
    if lower_bound is not None and np.isfinite(value):
        if value < lower_bound - 1e-8 * max(abs(lower_bound), state.objective.total_volume):
            return f"the energy {value:.6g} is below the energy's lower bound {lower_bound:.6g}"
    extent = float(_extent(state.x))
    if np.isfinite(extent) and extent > DIVERGENCE_FACTOR * reference_extent:
        return (f"the map grew to {extent:.3g} across, {extent / reference_extent:.3g} times its "
                f"start and rest size, while the energy fell to {value:.6g}")
    return None


def minimize(objective, x0, solver=None, params=None, progress: bool | Callable = True,
             throw: bool = False) -> Result:
    """Minimise ``objective`` from ``x0`` (n, d) with ``solver`` (default: projected Newton).

    Parameters
    ----------
    objective : :class:`~geomopt.Objective`.
    x0 : (n, d) start map.
    solver : a solver object or a name in :data:`~geomopt.solvers.SOLVERS` (``"newton"``,
        ``"lbfgs"``); default :class:`~geomopt.solvers.Newton`.
    params : dict overriding the energy's parameters, validated like the energy's own
        (known names, finite numbers, ``eps > 0``, ``lam >= 0``).
    progress : True (log to stderr), False, or a callable ``(state, elapsed, mean_energy)``.
    throw : raise :class:`~geomopt.SolveError` unless the result is converged and injective.

    Returns
    -------
    :class:`Result`.  A solve whose map grows without bound (``DIVERGENCE_FACTOR`` times its
    start and rest size) or whose energy falls below the energy's known lower bound stops
    with :attr:`Outcome.DIVERGED`, its reason in ``info["reason"]`` and ``message``.
    """
    from . import get_solver
    from .newton import Newton

    solver = Newton() if solver is None else get_solver(solver)
    problem = objective.problem
    x0 = problem.check_map(x0)
    params = objective.params(**(params or {}))
    report = Progress() if progress is True else (progress or None)
    vol = objective.total_volume
    lb = objective.energy.lower_bound
    lower_bound = None if lb is None else lb * vol
    reference = max(float(np.linalg.norm(np.ptp(P, axis=0))) for P in (x0, problem.rest_vertices))

    t0 = time.perf_counter()
    state = solver.init(objective, x0, params)
    _extent(state.x)  # compiled with the solver's kernels, in the setup time
    setup = time.perf_counter() - t0
    history, times = [state.value], [0.0]
    reason = None
    t0 = time.perf_counter()
    while True:
        reason = divergence(state, reference, lower_bound)
        if reason is not None:
            outcome = Outcome.DIVERGED
            break
        done, outcome = solver.terminate(state)
        if done:
            break
        state = solver.step(state)
        history.append(state.value)
        times.append(time.perf_counter() - t0)
        if report:
            report(state, times[-1], state.value / vol)
    seconds = time.perf_counter() - t0
    x = np.asarray(state.x)
    if not np.isfinite(x).all():
        outcome = Outcome.NONFINITE
        x = np.asarray(x0)
    inverted = problem.count_inverted(x)
    if outcome is Outcome.CONVERGED and inverted:
        outcome = Outcome.NOT_INJECTIVE
    result = Result(
        x=x, outcome=outcome, inverted=inverted, energy=float(state.value),
        energy_history=np.asarray(history), iterations=state.iteration, seconds=seconds,
        setup_seconds=setup, time_history=np.asarray(times), info={"reason": reason} if reason else {},
    )
    if throw and not result.success:
        raise SolveError(f"solve failed: {result.message}", result)
    return result

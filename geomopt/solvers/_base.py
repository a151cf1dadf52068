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

import numpy as np

from .._errors import SolveError


class Outcome(enum.Enum):
    CONVERGED = "converged"
    MAX_STEPS = "max_steps"
    LINE_SEARCH_FAILED = "line_search_failed"
    NONFINITE = "nonfinite"
    NOT_INJECTIVE = "not_injective"

    @property
    def message(self) -> str:
        return {
            "converged": "converged",
            "max_steps": "stopped at the iteration limit before converging (raise max_steps)",
            "line_search_failed": "the line search found no acceptable step (the problem may be "
            "badly scaled or the energy non-smooth)",
            "nonfinite": "the energy or gradient became NaN/inf (check the input and the start map)",
            "not_injective": "the result has inverted or degenerate elements",
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
        """Stop on failure, on a relative decrement/energy change below ``rtol``, or the limit."""
        if state.failure is not None:
            return True, state.failure
        if not np.isfinite(state.value):
            return True, Outcome.NONFINITE
        scale = max(abs(state.value), 1e-300)
        if state.decrement <= self.rtol * scale:
            return True, Outcome.CONVERGED
        if state.iteration > 0 and 0 <= state.prev_value - state.value <= 0.01 * self.rtol * scale:
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


def minimize(objective, x0, solver=None, params=None, progress: bool | Callable = True,
             throw: bool = False) -> Result:
    """Minimise ``objective`` from ``x0`` (n, d) with ``solver`` (default: projected Newton).

    ``params`` overrides the energy's parameters; ``progress`` is True (log to stderr),
    False, or a callable ``(state, elapsed, mean_energy)``.  With ``throw=True`` a result
    that is not converged and injective raises :class:`~geomopt.SolveError`.
    """
    from .newton import Newton

    solver = Newton() if solver is None else solver
    problem = objective.problem
    x0 = problem.check_map(x0)
    params = objective.params(**(params or {}))
    report = Progress() if progress is True else (progress or None)
    vol = objective.total_volume

    t0 = time.perf_counter()
    state = solver.init(objective, x0, params)
    setup = time.perf_counter() - t0
    history, times = [state.value], [0.0]
    t0 = time.perf_counter()
    while True:
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
        setup_seconds=setup, time_history=np.asarray(times),
    )
    if throw and not result.success:
        raise SolveError(f"solve failed: {result.message}", result)
    return result

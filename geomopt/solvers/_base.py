"""Solver interface, outcomes, results and the one driver loop.

A solver is an immutable configuration object (DESIGN.md §1, in the style of optimistix): a
*descent* (how it makes a direction: projected Newton, L-BFGS, SLIM, AQP, CM, an optimistix
descent) plus the shared :class:`~geomopt.linesearch.InjectiveSearch` in its ``search``
field (how far it goes).  Every solver has

* ``init(objective, x0, params) -> State``
* ``step(state) -> State``
* ``terminate(state) -> (bool, Outcome | None)``
* ``run(state, max_steps=None) -> State``: iterate until ``terminate`` says stop (one jitted
  ``lax.while_loop`` for solvers that are fully jittable, a host loop otherwise);
* ``with_params(state, params) -> State``: the same point with new energy parameters
  (what continuation loops such as untangling's eps loop need; memory is kept where a solver
  has any).

:func:`minimize` owns the loop, progress, history, timings and ``throw``; a notebook can
also drive ``init`` / ``step`` by hand.
"""

from __future__ import annotations

import abc
import dataclasses
import enum
import math
import sys
import time
from collections.abc import Mapping
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import ParameterError, SolveError
from .._tracing import refuse_traced
from .._x64 import float64, float64_methods
from .._config import Instance, Int, Real, validate
from ..certify import local_certificate
from ..linesearch import InjectiveSearch

#: a map whose extent grows by more than this factor over its start (and rest) extent diverged
DIVERGENCE_FACTOR = 1e6


class Outcome(enum.Enum):
    """How a solve ended; :attr:`message` says it in words.  Only ``CONVERGED`` with no
    inverted element (exact predicate) is a success (:attr:`Result.success`)."""

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
            "not_injective": "the result is not locally injective (inverted or degenerate elements, "
            "or elements overlapping around a vertex or edge)",
            "diverged": "the solve diverged: the energy fell without bound or below its known "
            "lower bound (check the energy and its parameters, or fix more vertices)",
        }[self.value]


@dataclasses.dataclass(frozen=True)
class State:
    """The state of one solve: the current map and what the solver keeps between steps.

    ``aux`` holds the descent's own data (L-BFGS memory, a factorization...): read it only
    through the solver."""

    objective: Any
    params: dict
    x: Any  # (n, d) jax array
    value: float
    grad: Any  # (n, d) jax array, zero on fixed vertices (None: not evaluated yet)
    iteration: int = 0
    step_size: float = float("nan")
    decrement: float = float("inf")  # Newton decrement^2 / 2 or its analogue
    prev_value: float = float("inf")
    failure: Outcome | None = None
    evaluations: int = 1
    extent0: float = float("inf")  # reference size for the divergence test
    energy_floor: float = 1e-300  # |E| below this counts as this (1e-12 |E(x0)|): energies reaching 0
    aux: Any = None


def map_extent(x) -> float:
    """The largest side of the bounding box of a map (n, d)."""
    x = np.asarray(x)
    return float(np.max(x.max(axis=0) - x.min(axis=0))) if x.size else 0.0


def reference_extent(objective, x0) -> float:
    """max(extent of the start map, extent of the rest mesh, tiny): the divergence test's unit."""
    rest = map_extent(objective.problem.rest_vertices)
    return max(map_extent(x0), rest, 1e-300)


def divergence(state: State):
    """Why the solve in ``state`` diverged, or None.

    It diverged when the map's extent exceeds ``DIVERGENCE_FACTOR`` times its reference (the
    larger of the start map's and the rest mesh's: a minimiser of a bounded distortion energy
    stays at the scale of the data) or falls below ``1 / DIVERGENCE_FACTOR`` times it (the map
    collapsed towards a point: e.g. Dirichlet with a free boundary), or when the energy is below the energy's known lower
    bound times the rest volume (allowing for rounding).  Non-finite values are NONFINITE.
    """
    value, obj = state.value, state.objective
    lb = getattr(obj.energy, "lower_bound", None)
    if lb is not None and math.isfinite(value):
        bound = lb * obj.total_volume
        if value < bound - 1e-8 * max(abs(bound), obj.total_volume):
            return f"the energy {value:.6g} is below the energy's lower bound {bound:.6g}"
    extent = map_extent(state.x)
    if math.isfinite(extent) and extent > DIVERGENCE_FACTOR * state.extent0:
        return (f"the map grew to {extent:.3g} across, {extent / state.extent0:.3g} times its "
                f"start and rest size, while the energy fell to {value:.6g}")
    if math.isfinite(extent) and extent * DIVERGENCE_FACTOR < state.extent0:
        return (f"the map collapsed to {extent:.3g} across, {extent / state.extent0:.3g} times its "
                "start and rest size (the energy is lowered by shrinking the map: with a free "
                "boundary it has no minimiser; fix vertices or use a scale-aware energy)")
    return None


def converged(value, prev_value, decrement, rtol, iteration, floor=1e-300):
    """The shared stopping test (host floats or traced arrays): the decrement, or the last
    energy decrease, is below ``rtol`` relative to ``max(|E|, floor)``."""
    host = all(isinstance(v, (int, float, np.number)) for v in (value, prev_value, decrement, iteration, floor))
    xp = np if host else jnp  # host floats: no JAX dispatch (and no compilation) per iteration
    scale = xp.maximum(xp.abs(value), floor)
    drop = prev_value - value
    # a stalled energy is the rounding floor only when one more Newton step would reach rtol;
    # with a larger decrement the search is cutting steps short (e.g. unbounded below)
    stalled = (iteration > 0) & (drop >= 0) & (drop <= 0.01 * rtol * scale) & (decrement <= xp.sqrt(rtol) * scale)
    return (decrement <= rtol * scale) | stalled


class AbstractSolver(abc.ABC):
    """A minimiser of an :class:`~geomopt._objective.Objective`: a descent plus ``search``."""

    max_steps: int
    rtol: float
    search: InjectiveSearch

    def __init_subclass__(cls, **kwargs):
        # solvers driven by hand (init / step) run in float64 like minimize (geomopt._x64)
        super().__init_subclass__(**kwargs)
        float64_methods("init", "step", "run", "with_params", "forget")(cls)

    def _check(self, **rules):
        """Validate the shared configuration and ``rules`` (every subclass's ``__post_init__``)."""
        validate(self, max_steps=Int(1), rtol=Real(0.0, 1.0, hi_open=True), search=Instance(InjectiveSearch),
                 **rules)

    @abc.abstractmethod
    def init(self, objective, x0, params) -> State: ...

    @abc.abstractmethod
    def step(self, state: State) -> State: ...

    def terminate(self, state: State):
        """Stop on failure, non-finite values, divergence, convergence or the step limit."""
        if state.failure is not None:
            return True, state.failure
        if not math.isfinite(state.value):
            return True, Outcome.NONFINITE
        if divergence(state) is not None:
            return True, Outcome.DIVERGED
        if bool(converged(state.value, state.prev_value, state.decrement, self.rtol, state.iteration,
                          state.energy_floor)):
            return True, Outcome.CONVERGED
        if state.iteration >= self.max_steps:
            return True, Outcome.MAX_STEPS
        return False, None

    def run(self, state: State, max_steps: int | None = None) -> State:
        """Iterate until :meth:`terminate` stops (or ``max_steps`` more iterations)."""
        limit = None if max_steps is None else state.iteration + int(max_steps)
        while not self.terminate(state)[0] and (limit is None or state.iteration < limit):
            state = self.step(state)
        return state

    def with_params(self, state: State, params) -> State:
        """``state`` re-evaluated under new energy parameters; counters restart."""
        obj = state.objective
        value, grad = obj.value_and_grad(state.x, params)
        return dataclasses.replace(state, params=params, value=float(value), grad=grad, iteration=0,
                                   failure=None, prev_value=float("inf"), decrement=float("inf"),
                                   step_size=float("nan"))

    def forget(self, state: State) -> State:
        """``state`` with any memory the descent keeps (curvature pairs...) cleared."""
        return state

    def _start(self, objective, x0, params, aux=None) -> State:
        """The common start state: value and gradient at ``x0`` (padded to the objective's
        size bucket, see :meth:`~geomopt.Objective.pad_map`)."""
        # a private copy (device_put may share a NumPy buffer on CPU), without the copy
        # program jnp.asarray compiles per shape
        x = jax.device_put(objective.pad_map(np.array(x0, dtype=np.float64)))
        value, grad = objective.value_and_grad(x, params)
        return State(objective, params, x, float(value), grad, extent0=reference_extent(objective, x0),
                     energy_floor=max(1e-12 * abs(float(value)), 1e-300), aux=aux)


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
    time_history : (iterations + 1,) seconds since the solve started, per iteration.
    grad_history : per-iteration gradient norms (free DOFs).
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
    grad_history: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def success(self) -> bool:
        """Converged and certified locally injective (``minimize`` turns an uncertified
        converged map into ``NOT_INJECTIVE``)."""
        return self.outcome is Outcome.CONVERGED and self.inverted == 0

    @property
    def injectivity(self) -> str:
        """``"global"`` (exact certificate: flip-free and the boundary does not overlap itself),
        ``"local"`` (flip-free) or ``"none"``; global injectivity is certified where the solve
        recorded a certificate (free-boundary parameterization), else at most ``"local"``."""
        local = self.info.get("local_certificate")
        if self.inverted or (local is not None and not local.ok):
            return "none"
        return self.info.get("injectivity", "local")

    @property
    def message(self) -> str:
        msg = self.outcome.message
        if self.info.get("reason"):
            msg += f" ({self.info['reason']})"
        if self.inverted:
            msg += f"; {self.inverted} inverted element(s)"
        return msg


class Progress:
    """Per-iteration progress: a tqdm bar when ``stream`` is a terminal, else one line per
    ``every`` iterations; ``stream=None`` is silent."""

    def __init__(self, stream=None, every: int = 1, prefix: str = "", total: int | None = None):
        self.stream = stream if stream is not None else sys.stderr
        self.every, self.prefix, self.total = every, prefix, total
        self._bar = None
        isatty = getattr(self.stream, "isatty", None)
        if isatty is not None and isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, file=self.stream, desc=prefix or "geomopt", leave=False)

    def __call__(self, state: State, elapsed: float, mean_energy: float):
        if self._bar is not None:
            self._bar.update(1)
            shown = {"step": f"{state.step_size:.2g}"} if math.isfinite(state.step_size) else {}
            self._bar.set_postfix(mean_energy=f"{mean_energy:.8g}", **shown, refresh=False)
            return
        if state.iteration % self.every:
            return
        # a solver that does not report a quantity (optimistix's: step, decrement) leaves it out
        extra = "".join(f"  {name} {value:.3g}" for name, value in
                        (("step", state.step_size), ("decrement", state.decrement)) if math.isfinite(value))
        print(f"{self.prefix}iter {state.iteration:4d}  mean energy {mean_energy:.10g}{extra}  {elapsed:7.2f}s",
              file=self.stream, flush=True)

    def close(self):
        if self._bar is not None:
            self._bar.close()


def _grad_norm(state) -> float:
    return float(np.linalg.norm(np.asarray(state.grad))) if state.grad is not None else float("nan")


def check_progress(progress, where="minimize"):
    """Refuse a ``progress`` argument that is neither a bool nor a callable (it used to fail
    with a bare TypeError at the first report, after the set-up and compilation)."""
    if not (isinstance(progress, (bool, np.bool_)) or progress is None or callable(progress)):
        raise ParameterError(f"{where}: progress must be True, False or a callable (see its "
                             f"docstring), got {progress!r}")


@float64
def minimize(objective, x0, solver=None, params=None, progress: bool | Callable = True,
             throw: bool = False) -> Result:
    """Minimise ``objective`` from ``x0`` (n, d) with ``solver`` (default: projected Newton).

    Parameters
    ----------
    objective : :class:`~geomopt.Objective`.
    x0 : (n, d) start map (handle rows replaced by the handles' positions).
    solver : a solver object or name (``geomopt.solvers.SOLVERS``), default ``"newton"``.
    params : energy parameters overriding the objective's (validated like the energy's own).
    progress : True (a bar on a terminal, lines otherwise, on stderr), False, or a callable
        ``(state, elapsed, mean_energy)``.
    throw : raise :class:`~geomopt.SolveError` unless the result is converged and injective.

    Returns
    -------
    :class:`Result`.  A solve whose map grows without bound (``DIVERGENCE_FACTOR`` times its
    start and rest size) or whose energy falls below the energy's known lower bound stops
    with :attr:`Outcome.DIVERGED`, its reason in ``info["reason"]`` and ``message``.
    """
    from . import get_solver

    refuse_traced("geomopt.minimize", "for a map differentiable in the objective (rest shape, handles, weights) "
                  "and params use geomopt.implicit.minimize", objective, x0, params)
    solver = get_solver("newton" if solver is None else solver)
    check_progress(progress)
    if params is not None and not isinstance(params, Mapping):
        raise ParameterError(f"minimize: params must be a mapping of energy parameter names to values "
                             f"(e.g. {{'lam': 1.0}}) or None, got {type(params).__name__}")
    problem = objective.problem
    x0 = objective.prepare_map(x0)  # (n_padded, d): see geomopt._padding
    params = objective.params(**(params or {}))
    report = Progress(total=solver.max_steps) if progress is True else (progress or None)
    vol = objective.total_volume

    t0 = time.perf_counter()
    state = solver.init(objective, x0, params)
    setup = time.perf_counter() - t0
    history, times, grads = [state.value], [0.0], [_grad_norm(state)]
    t0 = time.perf_counter()
    try:
        while True:
            done, outcome = solver.terminate(state)
            if done:
                break
            state = solver.step(state)
            history.append(state.value)
            times.append(time.perf_counter() - t0)
            grads.append(_grad_norm(state))
            if report:
                report(state, times[-1], state.value / vol)
    finally:
        if isinstance(report, Progress):
            report.close()
    seconds = time.perf_counter() - t0
    x = objective.unpad_map(np.asarray(state.x))
    if not np.isfinite(x).all():
        outcome = Outcome.NONFINITE
        x = objective.unpad_map(np.asarray(x0))
    cert = problem.certify(x)  # exact: orientations (quads/hexahedra inside), fans, stars
    inverted = cert.inverted
    if outcome is Outcome.CONVERGED and not cert.ok:
        outcome = Outcome.NOT_INJECTIVE
    reason = divergence(state) if outcome is Outcome.DIVERGED else None
    if outcome is Outcome.NOT_INJECTIVE and not inverted:
        reason = cert.message
    result = Result(
        x=x, outcome=outcome, inverted=inverted, energy=float(state.value),
        energy_history=np.asarray(history), iterations=state.iteration, seconds=seconds,
        setup_seconds=setup, time_history=np.asarray(times), grad_history=np.asarray(grads),
        info={"solver": solver, "evaluations": state.evaluations, "local_certificate": cert,
              **({"reason": reason} if reason else {})},
    )
    if throw and not result.success:
        raise SolveError(f"solve failed: {result.message}", result)
    return result

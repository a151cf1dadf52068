"""The one loop: :func:`iterate` (in the spirit of optimistix's ``_iterate``), and
:func:`minimize` on top of it.

:func:`iterate` is the only place where a solve steps, stops, reports progress, records its
history and raises.  Between steps it asks the solver's :class:`~geomopt.solvers.Termination`
whether to go on; a solver with a jitted multi-step kernel (``advance``: L-BFGS's
``lax.while_loop``) runs whole stretches in it when nobody needs the iterates one by one.
Outer schemes are handed to it, never loops of their own:

* a **continuation** is called each time the solver stops (a *phase* ends) and returns a
  :class:`Decision`: stop (with an outcome), or go on with new energy parameters, the
  solver's memory dropped, a new objective (a new problem of the same shapes), or another
  solver; its record goes to the trace and the progress lines.  Untangling's eps schedule
  (:class:`geomopt.untangling.EpsContinuation`) and the scaffold's rebuilds
  (:class:`geomopt.bijective.ScaffoldContinuation`) are continuations.  Its ``finish`` maps the
  last state to the :class:`Final` map and certificate (back to the input frame);
* a **guard** is called after every step with ``(solver, old, new)`` and returns the state to
  accept (``new``, or a shortened step, e.g. through ``solver.restart(new, x)``), or None to
  end the phase at ``old`` (the continuation then sees the outcome None).  The scaffold's
  scaffold-free phase keeps the boundary simple with one
  (:class:`geomopt.bijective.SimpleBoundary`);
* an **observer** ``observe(state, seconds)`` sees every iterate and may end the solve by
  returning a reason (a non-empty string; outcome MAX_STEPS).  Its time is not solve time.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import time
import warnings
from collections.abc import Mapping
from typing import Any, Callable, NamedTuple

import numpy as np

from .._runtime.errors import MaxStepsWarning, ParameterError, SolveError
from .._runtime.interrupt import raise_pending
from .._runtime.log import bar_wanted, in_notebook, iteration_logger, logger
from .._runtime.threads import single_blas_thread
from .._runtime.tracing import is_traced
from .._runtime.x64 import float64
from ._base import check_step
from ._registry import get_solver
from ._result import Result, RunStats, Trace, local_certificate, traced_result
from ._termination import RUNNING, Outcome, Termination

__all__ = ["iterate", "minimize", "minimize_map", "Decision", "Final", "AbstractContinuation", "Progress", "check_progress"]


class Decision(NamedTuple):
    """What a continuation decides when a phase ends (build with :meth:`stop_with` or
    :meth:`go`).

    Attributes
    ----------
    stop : end the solve with ``outcome`` (and ``reason``).
    params : new energy parameters (``solver.reparam``: same map; every new phase restarts the
        solver's counters and step limit, at the same parameters when none are given).
    restart : drop the solver's path memory (``solver.restart``).
    objective, x : a new objective (same array shapes) and the map to start it from: the
        solver is initialised anew there (``solver.init``).
    solver : the solver from here on (None: the same).
    record : a NamedTuple for the trace's ``phases`` and the progress line (its ``line(k)``
        method, if any, formats it); without a per-iterate trace its ``energy`` field (else the
        state's energy) is the trace's point for the phase.
    """

    stop: bool = False
    outcome: Outcome | None = None
    reason: str = ""
    params: Mapping | None = None
    restart: bool = False
    objective: Any = None
    x: Any = None
    solver: Any = None
    record: Any = None

    @classmethod
    def stop_with(cls, outcome: Outcome, reason: str = "", record=None) -> "Decision":
        return cls(stop=True, outcome=outcome, reason=reason, record=record)

    @classmethod
    def go(cls, params=None, *, restart=False, objective=None, x=None, solver=None, record=None) -> "Decision":
        return cls(params=params, restart=restart, objective=objective, x=x, solver=solver, record=record)


class Final(NamedTuple):
    """What a solve returns besides its statistics: the map in the input frame, the outcome
    (demoted when the certificate fails), the certificate, and the driver's own data; None
    fields default to the objective's (problem, objective, total volume) and the final state's
    energy."""

    x: np.ndarray
    outcome: Outcome
    certificate: Any
    reason: str = ""
    problem: Any = None
    objective: Any = None
    energy: float | None = None
    volume: float | None = None
    details: Any = None
    inverted_at_start: int | None = None
    certify_seconds: float = 0.0


def certified(objective, state, outcome: Outcome | None, x0) -> Final:
    """The :class:`Final` of a plain solve: the map without padding (the start map ``x0``
    when it is not finite: NONFINITE), its :class:`LocalCertificate`, CONVERGED demoted to
    NOT_INJECTIVE when the map is not certified, and the divergence reason."""
    x = objective.unpad_map(np.asarray(state.x))
    reason = None
    if outcome is None:  # a guard refused the next step and no continuation took over
        outcome, reason = Outcome.LINE_SEARCH_FAILED, "the guard refused the next step"
    if not np.isfinite(x).all():
        outcome, x = Outcome.NONFINITE, objective.unpad_map(np.asarray(x0))
    t_certify = time.perf_counter()
    certificate = local_certificate(objective.problem, x)  # exact: orientations, fans, stars
    if outcome is Outcome.CONVERGED and not certificate.locally_injective:
        outcome = Outcome.NOT_INJECTIVE
        reason = reason or certificate.message  # names the first vertex or edge that fails
    if outcome is Outcome.DIVERGED:
        reason = Termination.reason(state.stats)
    return Final(x, outcome, certificate, reason or "", certify_seconds=time.perf_counter() - t_certify)


class AbstractContinuation:
    """An outer scheme for :func:`iterate` (see the module notes): ``start`` sees the first
    state, ``__call__(state, outcome) -> Decision`` each phase's end, ``finish(state, outcome,
    reason) -> Final`` the last state."""

    def start(self, state) -> None:
        """Called once, after the solver's ``init`` (set-up time)."""

    def __call__(self, state, outcome: Outcome | None) -> Decision:
        raise NotImplementedError

    def finish(self, state, outcome: Outcome, reason: str) -> Final:
        raise NotImplementedError


class Progress:
    """Progress of a solve: per iteration a bar (``tqdm.auto``) on a terminal or in a notebook,
    else nothing unless asked; per outer iteration one line (``phases``).

    Lines go to ``stream`` when one is given (one per ``every`` iterations when no bar is
    drawn), else to the ``geomopt`` logger (:mod:`geomopt._runtime.log`): iterations at DEBUG
    on ``geomopt.iterations``, outer iterations at INFO, which print nothing until the
    application configures logging (the command line does)."""

    def __init__(self, stream=None, every: int = 1, prefix: str = "", total: int | None = None,
                 iterations: bool = True, phases: bool = True):
        self.stream = stream
        self.every, self.prefix, self.total = every, prefix, total
        self.iterations, self.phases = iterations, phases
        self._bar = _bar(self.out, total, prefix) if iterations and bar_wanted(self.out) else None

    @property
    def out(self):
        return self.stream if self.stream is not None else sys.stderr

    def _line(self, text: str, log: logging.Logger, level: int):
        if self.stream is not None:
            print(f"{self.prefix}{text}", file=self.stream, flush=True)
        elif log.isEnabledFor(level):
            log.log(level, f"{self.prefix}{text}")

    def __call__(self, state, elapsed: float, mean_energy: float):
        if not self.iterations:
            return
        if self._bar is not None:
            self._bar.update(1)
            shown = {"step": f"{state.step_size:.2g}"} if math.isfinite(state.step_size) else {}
            self._bar.set_postfix(mean_energy=f"{mean_energy:.8g}", **shown, refresh=False)
            return
        if state.iteration % self.every or (self.stream is None and not iteration_logger.isEnabledFor(logging.DEBUG)):
            return
        # a solver that does not report a quantity (optimistix's: step, decrement) leaves it out
        extra = "".join(f"  {name} {value:.3g}" for name, value in
                        (("step", state.step_size), ("decrement", state.decrement)) if math.isfinite(value))
        self._line(f"iter {state.iteration:4d}  mean energy {mean_energy:.10g}{extra}  {elapsed:7.2f}s",
                   iteration_logger, logging.DEBUG)

    def phase(self, index: int, record, elapsed: float):
        if not self.phases or record is None:
            return
        line = record.line(index) if hasattr(record, "line") else f"outer {index:3d}  " + "  ".join(
            f"{k} {v:.6g}" if isinstance(v, float) else f"{k} {v}" for k, v in record._asdict().items())
        self._line(f"{line}  {elapsed:7.2f}s", logger, logging.INFO)

    def close(self):
        if self._bar is not None:
            self._bar.close()


def _bar(out, total, prefix):
    """A tqdm bar: a widget in a notebook (text when its widgets are not installed), text on
    the terminal ``out``."""
    if in_notebook():
        try:
            from tqdm.auto import tqdm as auto_tqdm

            return auto_tqdm(total=total, desc=prefix or "geomopt", leave=False)
        except ImportError:  # tqdm.notebook without ipywidgets
            pass
    from tqdm import tqdm

    return tqdm(total=total, file=out, desc=prefix or "geomopt", leave=False)


def check_progress(progress, where="minimize"):
    """Refuse a ``progress`` argument that is neither a bool nor a callable (it used to fail
    with a bare TypeError at the first report, after the set-up and compilation)."""
    if not (isinstance(progress, (bool, np.bool_)) or progress is None or callable(progress)):
        raise ParameterError(f"{where}: progress must be True, False or a callable (see its "
                             f"docstring), got {progress!r}")


class _Run:
    """The bookkeeping of one :func:`iterate` call: the solve clock (solver and continuation
    calls only), the traces, the reports and the totals over phases."""

    def __init__(self, objective, trace, progress, observe, clock="wall"):
        self.volume = objective.total_volume
        self.trace, self.report, self.observe, self.observed_clock = trace, progress, observe, clock
        self.energy, self.seconds, self.cpus, self.grads, self.phases = [], [], [], [], []
        self.iterations = self.evaluations = 0
        self.solve = self.cpu = 0.0  # wall and process-CPU seconds of the solve
        self.observed_stop = False  # the observer ended the solve (its caller's own limit)

    @contextlib.contextmanager
    def clock(self):
        t, c = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.solve += time.perf_counter() - t
            self.cpu += time.process_time() - c

    @property
    def stepwise(self) -> bool:
        """Whether every iterate must come back to the host (traced, reported or observed)."""
        return bool(self.trace or self.observe is not None or callable(self.report)
                    and getattr(self.report, "iterations", True))

    def iteration(self, state) -> str:
        """Record and report one iterate; the observer's reason to stop, or ""."""
        if self.trace:
            self.point(state, state.value)
        seconds = self.cpu if self.observed_clock == "cpu" else self.solve
        if self.report is not None:
            self.report(state, seconds, state.value / self.volume)
        return (self.observe(state, seconds) or "") if self.observe is not None else ""

    def phase(self, state, record):
        """Record a phase's end: its record, and without a per-iterate trace its point (the
        record's ``energy`` if it has one, else the state's)."""
        if record is None:
            return
        self.phases.append(record)
        if not self.trace:
            self.point(state, getattr(record, "energy", state.value))
        if hasattr(self.report, "phase"):
            self.report.phase(len(self.phases), record, self.solve)

    def point(self, state, energy):
        self.energy.append(energy)
        self.seconds.append(self.solve)
        self.cpus.append(self.cpu)
        g = state.grad
        self.grads.append(float(np.linalg.norm(np.asarray(g))) if g is not None else math.nan)


def _phase(solver, state, guard, run):
    """Step ``state`` until the solver's termination stops it (or the observer, once the
    termination would go on): ``(state, outcome, reason)``, outcome None when the guard ended
    the phase."""
    rule, why = solver.termination, ""
    while True:
        raise_pending()  # an interrupt swallowed since the last step (in a GC callback) ends the solve
        code = rule(state.stats)
        if code != RUNNING:
            return state, Outcome.of(code), ""
        if why:
            run.observed_stop = True
            return state, Outcome.MAX_STEPS, why
        if guard is None and solver.advance is not None and not run.stepwise:
            with run.clock():
                state = solver.advance(state, rule.max_steps)
            continue
        with run.clock():
            new = solver.step(state)
            check_step(solver, state, new)
            if guard is not None:
                new = guard(solver, state, new)
        if new is None:
            return state, None, ""
        why = run.iteration(new)
        state = new


def _apply(solver, state, decision: Decision, run):
    """The solver and state a continuation's decision asks for."""
    solver = decision.solver or solver
    if decision.objective is not None:
        run.evaluations += state.evaluations
        x = state.x if decision.x is None else decision.x
        return solver, solver.init(decision.objective, x, decision.params or state.params)
    # a new phase restarts the solver's counters (and step limit): a reparam, at the same
    # parameters when none are given
    state = solver.reparam(state, state.params if decision.params is None else decision.params)
    if decision.restart:
        state = solver.restart(state)
    return solver, state


def _loop(solver, state, continuation, guard, run):
    """The phases: ``(solver, state, outcome, reason)`` at the end."""
    while True:
        first = state.iteration
        state, outcome, reason = _phase(solver, state, guard, run)
        run.iterations += state.iteration - first
        if continuation is None:
            return solver, state, outcome, reason
        with run.clock():
            decision = continuation(state, outcome)
        run.phase(state, decision.record)
        if decision.stop:
            return solver, state, decision.outcome, decision.reason
        with run.clock():
            solver, state = _apply(solver, state, decision, run)


def _as_progress(progress, total):
    check_progress(progress, "iterate")
    if progress is True:
        return Progress(total=total)
    return progress or None


@float64
def iterate(solver, objective, x0, params, *, continuation: AbstractContinuation | None = None,
            guard: Callable | None = None, observe: Callable | None = None, progress=False,
            trace: bool = True, throw: bool = False, label: str = "solve", warn: bool = True,
            clock: str = "wall") -> Result:
    """Minimise ``objective`` from ``x0`` with ``solver``: the one loop (see the module notes).

    Parameters
    ----------
    solver : a solver object (:class:`~geomopt.solvers.AbstractSolver`).
    objective : :class:`~geomopt.Objective`;  x0 : (n, d) start map;  params : dict of the
        energy parameters (``objective.params(...)``).
    continuation : an :class:`AbstractContinuation`, or None (one phase).
    guard : ``guard(solver, old, new) -> State | None``, or None.
    observe : ``observe(state, seconds) -> str | None``, or None.
    clock : the solve seconds the observer and the progress see: ``"wall"`` (elapsed, the
        default) or ``"cpu"`` (the process's CPU time, every thread summed); the trace and the
        result's stats hold both.
    progress : True (a :class:`Progress`: a bar on a terminal or in a notebook, records on
        the ``geomopt`` logger), False, a :class:`Progress`, or a callable ``(state, seconds, mean_energy)`` called per iterate.
    trace : record the energy, solve seconds and gradient norm of every iterate (else the
        solver may run whole phases in its jitted kernel).
    throw : raise :class:`~geomopt.SolveError` (carrying the result) unless it ``success``.
    label : what failed, in the exception's message.
    warn : issue a :class:`~geomopt.MaxStepsWarning` when the solve stops at its iteration
        limit (outcome MAX_STEPS) and ``throw`` is False, except when the observer stopped it;
        a driver that raises on the result itself passes its own ``not throw``.

    Returns
    -------
    :class:`~geomopt.solvers.Result`.
    """
    with single_blas_thread():
        return _iterate(solver, objective, x0, params, continuation, guard, observe, progress, trace, throw,
                        label, warn, clock)


def _iterate(solver, objective, x0, params, continuation, guard, observe, progress, trace, throw, label, warn,
             clock) -> Result:
    report = _as_progress(progress, getattr(solver, "max_steps", None))
    t0, c0 = time.perf_counter(), time.process_time()
    state = solver.init(objective, x0, params)
    if continuation is not None:
        continuation.start(state)
    setup, setup_cpu = time.perf_counter() - t0, time.process_time() - c0
    if clock not in ("wall", "cpu"):
        raise ParameterError(f"iterate: clock must be 'wall' or 'cpu', got {clock!r}")
    run = _Run(objective, trace, report, observe, clock)
    if trace:
        run.point(state, state.value)  # the start (not reported, not observed)
    try:
        solver, state, outcome, reason = _loop(solver, state, continuation, guard, run)
    finally:
        if isinstance(report, Progress):
            report.close()
    state.objective.free_factors()  # not reused; the certificate and the result allocate next
    if continuation is not None:
        final = continuation.finish(state, outcome, reason)
    else:
        final = certified(objective, state, outcome, x0)
        final = final._replace(reason=final.reason or reason)
    result = _result(final, solver, objective, state, run, (setup, setup_cpu), throw, label)
    if warn and result.outcome is Outcome.MAX_STEPS and not run.observed_stop:
        warnings.warn(_max_steps_message(result, solver, label), MaxStepsWarning, stacklevel=_caller_level())
    return result


def _max_steps_message(result, solver, label) -> str:
    """What a solve stopped at its iteration limit tells the user: which limit, how far it
    got, and how to raise it."""
    name, st = type(solver).__name__, result.stats
    if result.reason:  # an outer scheme's limit, named with its option
        what, how = result.reason, "raise that limit"
    else:
        what = (f"{name} stopped at its iteration limit (max_steps={getattr(solver, 'max_steps', '?')}) "
                f"before converging")
        how = f"raise it: {name}(max_steps=...), or --max-steps on the command line"
    return (f"{label}: {what}, after {st.iterations} iterations and {st.seconds:.3g} s; the map returned is "
            f"not converged (outcome max_steps): {how}")


def _caller_level() -> int:
    """The ``stacklevel`` of the first frame outside geomopt (where the user called it)."""
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
    frame, level = sys._getframe(1), 1
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level


def _result(final: Final, solver, objective, state, run, setup, throw, label) -> Result:
    stats = RunStats(
        iterations=run.iterations, evaluations=run.evaluations + state.evaluations,
        outer_iterations=len(run.phases), seconds=run.solve, setup_seconds=setup[0],
        cpu_seconds=run.cpu, setup_cpu_seconds=setup[1],
        energy=float(state.value if final.energy is None else final.energy),
        volume=float(objective.total_volume if final.volume is None else final.volume),
        inverted_at_start=final.inverted_at_start, certify_seconds=final.certify_seconds)
    trace = Trace(np.asarray(run.energy, np.float64), np.asarray(run.seconds, np.float64),
                  np.asarray(run.grads, np.float64), None, tuple(run.phases), np.asarray(run.cpus, np.float64))
    result = Result(final.x, final.outcome, final.certificate, stats, trace,
                    problem=final.problem or objective.problem, objective=final.objective or objective,
                    solver=solver, reason=final.reason, details=final.details)
    if throw and not result.success:
        raise SolveError(f"{label} failed: {result.message}", result)
    return result


@float64
def minimize(objective, x0, solver=None, params=None, *, progress: bool | Callable = True,
             throw: bool = False, adjoint: str = "auto") -> Result:
    """Minimise ``objective`` from ``x0`` (n, d) with ``solver`` (default: projected Newton).

    Differentiable: given traced values (an ``objective`` built from traced rest vertices,
    handle positions or element weights, traced ``params``; under ``jax.grad``, ``jvp``,
    ``jacrev``, ``vmap``, ``jit``) the map ``result.x`` is the optimum as a function of them, its
    derivative from the implicit function theorem at the optimum (one sparse solve with the
    exact Hessian; :mod:`geomopt.objective.adjoint`), the result's other fields those of
    :func:`~geomopt.solvers.traced_result`.  ``x0`` has zero derivative.

    Parameters
    ----------
    objective : :class:`~geomopt.Objective`.
    x0 : (n, d) start map (handle rows replaced by the handles' positions).
    solver : a solver object or name (``geomopt.solvers.SOLVERS``), default ``"newton"``.
    params : energy parameters overriding the objective's (validated like the energy's own).
    progress : True (a bar on a terminal or in a notebook, records on the ``geomopt``
        logger: :class:`Progress`), False, or a callable ``(state, elapsed, mean_energy)``.
    throw : raise :class:`~geomopt.SolveError` unless the result is converged and injective.
        Traced inputs always raise then (no map is differentiated that is not certified).
    adjoint : the linear solver of the adjoint on traced inputs: ``"auto"`` (as the forward
        Newton solves), a sparse Cholesky backend name or ``"cg"``.

    Returns
    -------
    :class:`~geomopt.solvers.Result`, certified by exact predicates
    (:class:`~geomopt.solvers.LocalCertificate`): a CONVERGED solve whose map is not locally
    injective ends NOT_INJECTIVE.  A solve whose map grows without bound
    (``DIVERGENCE_FACTOR`` times its start and rest size) or whose energy falls below the
    energy's known lower bound ends DIVERGED, its reason in ``reason`` and ``message``.

    Examples
    --------
    A 3 x 3 grid with its boundary fixed and its middle vertex pushed off centre: the symmetric
    Dirichlet minimum puts it back.

    >>> import geomopt
    >>> from geomopt.mesh import generators
    >>> V, F = generators.square_mesh(3)
    >>> boundary = [0, 1, 2, 3, 5, 6, 7, 8]
    >>> problem = geomopt.Problem.planar(V, F, fixed=boundary, fixed_positions=V[boundary])
    >>> x0 = V.copy()
    >>> x0[4] += [0.2, -0.1]
    >>> result = geomopt.minimize(geomopt.Objective(problem, "symmetric_dirichlet"), x0, progress=False)
    >>> result.success, bool(abs(result.x[4] - [0.5, 0.5]).max() < 1e-6)
    (True, True)
    """
    if is_traced(objective, x0, params):  # differentiable: the implicit adjoint at the optimum
        return traced_result(minimize_map(objective, x0, solver, params, adjoint), objective=objective,
                             solver=solver)
    solver = get_solver("newton" if solver is None else solver)
    check_progress(progress)
    if params is not None and not isinstance(params, Mapping):
        raise ParameterError(f"minimize: params must be a mapping of energy parameter names to values "
                             f"(e.g. {{'lam': 1.0}}) or None, got {type(params).__name__}")
    x0 = objective.prepare_map(x0)  # (n_padded, d): see geomopt._runtime.padding
    params = objective.params(**(params or {}))
    return iterate(solver, objective, x0, params, progress=progress, trace=True, throw=throw)


def minimize_map(objective, x0, solver=None, params=None, adjoint: str = "auto"):
    """:func:`minimize`'s map as a differentiable function of ``objective`` (traced rest
    vertices, handle positions, element weights) and ``params``, by the implicit function
    theorem at the optimum (:func:`geomopt.objective.adjoint.argmin`); ``x0`` has zero
    derivative."""
    import jax.numpy as jnp

    from ..objective.adjoint import argmin, require_success

    def solve(obj, p, start):
        result = minimize(obj, np.asarray(start), solver, p, progress=False)
        require_success(result, "geomopt.minimize")
        return result.x, {"objective": obj}

    return argmin(objective, dict(params or {}), jnp.asarray(x0, jnp.float64), solve, adjoint)


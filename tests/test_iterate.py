"""The one loop (``iterate``), the one stopping rule (``Termination``), the one ``Result`` and
the validated options: each protocol exercised, and the rule checked equal on host and traced
values."""

from __future__ import annotations

import dataclasses
import logging
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import Objective, Outcome, ParameterError, ParamOptions, Problem, minimize
from geomopt.bijective import ScaffoldOptions
from geomopt.mesh import generators as G
from geomopt.solvers import (LBFGS, AbstractContinuation, Decision, Final, Newton, Progress, Result, Stats,
                             Termination, iterate, local_certificate)
from geomopt.solvers._termination import RUNNING
from geomopt.untangling import UntangleOptions, untangle

from conftest import grid


def _objective(energy="symmetric_dirichlet"):
    V, F = G.disk_mesh(4)
    b = G.boundary_vertices(F, len(V))
    target = V.copy()
    target[b] = V[b] * [1.3, 0.8]
    return Objective(Problem.planar(V, F, b, target[b]), energy), V


# ------------------------------------------------------------------ the stopping rule


@pytest.mark.parametrize("seed", range(4))
def test_termination_is_the_same_rule_on_host_and_traced_values(seed):
    """One rule, two evaluations: host floats (between steps) and traced scalars (inside
    L-BFGS's while_loop) give the same code on random statistics, edge cases included."""
    rng = np.random.default_rng(seed)
    rule = Termination(rtol=1e-6, ftol=1e-6, stall=5e-4, gtol=1e-3, flat=1e-12, max_steps=10)
    traced = jax.jit(rule.status)
    pick = [1.0, 0.0, -1.0, 1e-300, 1e-7, math.inf, -math.inf, math.nan, 2.0, 1e8]
    for _ in range(200):
        s = Stats(
            iteration=int(rng.integers(0, 3)), value=float(rng.choice(pick)), past_value=float(rng.choice(pick)),
            decrement=float(rng.choice(pick)), step_size=1.0, grad_norm=float(rng.choice(pick)),
            grad_norm0=float(rng.choice(pick)), extent=float(rng.choice([1.0, 1e7, 1e-7])), extent0=1.0,
            accepted=bool(rng.integers(0, 2)), broken=bool(rng.integers(0, 5) == 0),
            done=bool(rng.integers(0, 5) == 0), evaluations=1, floor=1e-300,
            lower=float(rng.choice([-math.inf, 0.0])), lower_tol=1e-8)
        device = Stats(*(jnp.asarray(v) for v in s))
        assert rule.status(s) == int(traced(device)), s


def test_termination_orders_its_tests():
    rule = Termination(rtol=1e-10, max_steps=5)
    base = Stats(iteration=1, value=1.0, decrement=1.0, extent=1.0, extent0=1.0)
    assert rule(base) == RUNNING
    assert rule(base._replace(iteration=5)) == Outcome.MAX_STEPS.code
    assert rule(base._replace(decrement=1e-11)) == Outcome.CONVERGED.code
    assert rule(base._replace(accepted=False)) == Outcome.LINE_SEARCH_FAILED.code
    assert rule(base._replace(accepted=False, decrement=1e-15)) == Outcome.CONVERGED.code  # flat
    assert rule(base._replace(value=math.nan, accepted=False)) == Outcome.NONFINITE.code
    assert rule(base._replace(extent=1e7)) == Outcome.DIVERGED.code
    assert rule(base._replace(value=-1.0, lower=0.0)) == Outcome.DIVERGED.code
    # a stalled energy is convergence only while little more is promised
    stalled = base._replace(past_value=1.0 + 1e-13)
    assert rule(stalled._replace(decrement=1e-6)) == Outcome.CONVERGED.code
    assert rule(stalled._replace(decrement=1e-3)) == RUNNING


# ------------------------------------------------------------------ the loop's protocols


class _Halving(AbstractContinuation):
    """Three phases of one iteration, a record for each; after the second the solver's
    memory is dropped; the third ends the solve."""

    def __init__(self):
        self.calls = []

    def __call__(self, state, outcome):
        self.calls.append((state.iteration, outcome))
        k = len(self.calls)
        record = _Rec(k, state.value)
        if k == 3:
            return Decision.stop_with(Outcome.CONVERGED, "three phases", record)
        return Decision.go(restart=k == 2, record=record)

    def finish(self, state, outcome, reason):
        x = np.asarray(state.x)
        return Final(x, outcome, local_certificate(state.objective.problem, x), reason)


class _Rec(tuple):
    def __new__(cls, k, energy):
        return tuple.__new__(cls, (k, energy))

    @property
    def energy(self):
        return self[1]

    def line(self, k):
        return f"phase {k} energy {self.energy:.6g}"


def test_a_continuation_gets_each_phase_and_its_records_reach_trace_and_progress(caplog):
    caplog.set_level(logging.INFO, logger="geomopt")
    obj, V = _objective()
    cont = _Halving()
    solver = Newton(max_steps=1)
    res = iterate(solver, obj, obj.prepare_map(V), obj.params(), continuation=cont, trace=False,
                  progress=Progress(iterations=False))
    assert [o for _, o in cont.calls] == [Outcome.MAX_STEPS, Outcome.MAX_STEPS, Outcome.MAX_STEPS]
    assert res.outcome is Outcome.CONVERGED and res.reason == "three phases"
    assert res.stats.outer_iterations == 3 and res.stats.iterations == 3
    assert len(res.trace.phases) == 3 and len(res.trace.energy) == 3
    lines = [r.getMessage() for r in caplog.records if r.name == "geomopt"]
    assert [line.split()[:2] for line in lines] == [["phase", "1"], ["phase", "2"], ["phase", "3"]]


def test_a_guard_shortens_steps_and_can_end_a_phase():
    """The guard sees every step: a shortened state is taken as it is, None ends the phase at
    the old iterate (the continuation, or the result, sees the outcome None)."""
    obj, V = _objective()
    seen = []

    def guard(solver, old, new):
        seen.append(new.iteration)
        if new.iteration == 2:
            return solver.restart(new, x=old.x + 0.5 * (new.x - old.x)).update(step_size=0.5 * new.step_size)
        return None if new.iteration == 4 else new

    res = iterate(Newton(), obj, obj.prepare_map(V), obj.params(), guard=guard, trace=True)
    assert seen == [1, 2, 3, 4]
    assert res.stats.iterations == 3 and res.outcome is Outcome.LINE_SEARCH_FAILED
    assert len(res.trace.energy) == 4 and np.all(np.diff(res.trace.energy) < 0)


def test_an_observer_stops_the_solve_with_its_reason():
    obj, V = _objective()
    res = iterate(LBFGS(), obj, obj.prepare_map(V), obj.params(),
                  observe=lambda state, seconds: "enough" if state.iteration >= 2 else None)
    assert res.outcome is Outcome.MAX_STEPS and res.reason == "enough" and res.stats.iterations == 2


def _blas_threads():
    from threadpoolctl import threadpool_info

    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})


def test_the_solve_loop_runs_blas_on_one_thread_and_restores_the_callers_setting():
    from threadpoolctl import threadpool_limits

    obj, V = _objective()
    seen = []
    with threadpool_limits(limits=2, user_api="blas"):  # as on a machine of 2 cores or more
        iterate(LBFGS(), obj, obj.prepare_map(V), obj.params(),
                observe=lambda state, seconds: seen.append(_blas_threads()))
        assert _blas_threads() == [2]
    assert seen and all(s == [1] for s in seen)


def test_overlapping_solve_loops_restore_blas_threads_when_the_last_one_ends():
    from threadpoolctl import threadpool_limits

    from geomopt._runtime.threads import single_blas_thread

    with threadpool_limits(limits=2, user_api="blas"):
        first, second = single_blas_thread(), single_blas_thread()
        first.__enter__()
        second.__enter__()  # e.g. a solve on another thread
        first.__exit__(None, None, None)
        assert _blas_threads() == [1]  # the second still runs
        second.__exit__(None, None, None)
        assert _blas_threads() == [2]


def test_the_blas_libraries_are_looked_for_again_only_after_an_import(monkeypatch):
    """Scanning the process for BLAS libraries costs 2 ms (a tenth of a small chart's solve):
    it is done once, and again when a module was imported since (which may load a library)."""
    import sys
    import types

    import threadpoolctl

    from geomopt._runtime.threads import single_blas_thread

    made = []
    real = threadpoolctl.ThreadpoolController
    monkeypatch.setattr(threadpoolctl, "ThreadpoolController", lambda: made.append(1) or real())
    with single_blas_thread():
        pass
    made.clear()
    for _ in range(3):
        with single_blas_thread():
            pass
    assert made == []
    monkeypatch.setitem(sys.modules, "geomopt_test_new_module", types.ModuleType("geomopt_test_new_module"))
    with single_blas_thread():
        assert made == [1]
        assert _blas_threads() == [1]  # the libraries found again are limited


def test_lbfgs_advances_in_its_kernel_to_the_same_iterate_as_stepping():
    obj, V = _objective()
    x0 = obj.prepare_map(V)
    stepped = iterate(LBFGS(), obj, x0, obj.params(), trace=True)
    advanced = iterate(LBFGS(), obj, x0, obj.params(), trace=False)
    assert stepped.stats.iterations == advanced.stats.iterations > 3
    assert stepped.stats.evaluations == advanced.stats.evaluations
    np.testing.assert_array_equal(stepped.x, advanced.x)
    assert len(advanced.trace.energy) == 0 and len(stepped.trace.energy) == stepped.stats.iterations + 1


@pytest.mark.parametrize("name", sorted(geomopt.solvers.SOLVERS))
def test_every_solver_step_keeps_the_step_duties(name):
    """Every built-in solver, stepped by the loop (trace=True: no multi-step kernel), passes
    :func:`~geomopt.solvers._base.check_step` on every step (AbstractSolver.step's duties)."""
    obj, V = _objective()
    res = iterate(geomopt.solvers.get_solver(name), obj, obj.prepare_map(V), obj.params(), trace=True)
    assert res.stats.iterations >= 1 and len(res.trace.energy) == res.stats.iterations + 1


@dataclasses.dataclass(frozen=True)
class _Forgetful(Newton):
    """Newton whose step forgets one of its duties (``duty``)."""

    duty: str = "iteration"

    def step(self, state):
        new = super().step(state)
        if self.duty == "iteration":
            return new.update(iteration=state.iteration)
        if self.duty == "floor":
            return new.update(floor=2 * state.stats.floor)
        if self.duty == "grad":
            return dataclasses.replace(new, grad=state.grad)
        return new.stats  # not a State


@pytest.mark.parametrize("duty, message", [
    ("iteration", r"_Forgetful.step must set stats.iteration to 1 \(one more than the state's\), got 0"),
    ("floor", r"_Forgetful.step changed stats.floor, which init sets and no step may change"),
    ("grad", r"_Forgetful.step moved x but kept the old grad"),
    ("type", r"_Forgetful.step returned a Stats, not a State"),
])
def test_a_step_that_forgets_a_duty_is_caught(duty, message):
    """A solver's step that leaves ``iteration`` (the loop would never reach ``max_steps``),
    changes a reference of the stopping rule, or moves ``x`` without its gradient is refused
    at its first step, naming the solver and the duty."""
    obj, V = _objective()
    with pytest.raises(ParameterError, match=message):
        iterate(_Forgetful(duty=duty), obj, obj.prepare_map(V), obj.params())


# ------------------------------------------------------------------ Result


#: the Result aliases deprecated for one release, then removed (issue 32)
REMOVED_ALIASES = ("inverted", "iterations", "inner_iterations", "outer_iterations", "seconds", "setup_seconds",
                   "initially_inverted", "handles_moved", "energy_history", "time_history", "grad_history",
                   "eps_history", "min_det_history", "inverted_history", "info")


def test_result_energies_typed_fields_and_no_aliases():
    obj, V = _objective()
    res = minimize(obj, V, progress=False)
    assert res.energy == pytest.approx(float(obj.value(res.x, obj.params())), rel=1e-12)
    assert res.mean_energy == res.energy / obj.total_volume
    assert res.stats.iterations == len(res.trace.energy) - 1 > 0 and res.details is None
    assert [name for name in REMOVED_ALIASES if hasattr(res, name)] == []
    t = G.rotated_interior(*G.square_mesh(6), 90.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        u = untangle(t.problem(), t.x0, progress=False)
        assert u.success and isinstance(u, geomopt.untangling.UntangleResult)
        assert isinstance(u.details, geomopt.solvers.UntangleDetails)
        assert isinstance(u.details, geomopt.solvers.Details)
        assert len(u.trace.column("eps")) == u.stats.outer_iterations > 0
        assert u.stats.inverted_at_start == t.inverted() > 0
        assert u.injectivity == "local" and u.message == "converged" and u.min_det_rel > 0


# ------------------------------------------------------------------ options


@pytest.mark.parametrize("call, message", [
    (lambda V, F: geomopt.parameterize(V, F, options=ParamOptions(bijective="no"), progress=False),
     "bijective must be True or False"),
    (lambda V, F: geomopt.parameterize(V, F, options=ParamOptions(buckets=1), progress=False),
     "buckets must be True or False"),
    (lambda V, F: geomopt.parameterize(V, F, ("garanzha", {"lam": "1"}), progress=False), "lam='1' must be a number"),
    (lambda V, F: geomopt.parameterize(V, F, options=ParamOptions(bijective=True, scaffold=ScaffoldOptions(lazy="yes")),
                                       progress=False), "lazy must be True or False"),
    (lambda V, F: geomopt.parameterize(V, F, options=ParamOptions(bijective=True,
                                                                  scaffold=ScaffoldOptions(inner_steps=2.5)),
                                       progress=False), "inner_steps must be None or an integer"),
])
def test_parameterize_refuses_mistyped_options(call, message):
    V, F = grid(4)
    V3 = np.c_[V, np.zeros(len(V))]
    with pytest.raises(ParameterError, match=message) as err:
        call(V3, F)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("bad, message", [
    (dict(keep_memory="no"), "keep_memory must be True or False"),
    (dict(max_outer=0), "max_outer must be an integer >= 1"),
    (dict(theta=1.5), "theta must be None or a finite number in"),
    (dict(min_sigma=0.6, max_sigma=0.5), "min_sigma <= max_sigma"),
    (dict(bucket="yes"), "bucket must be True or False"),
])
def test_untangle_options_are_validated(bad, message):
    with pytest.raises(ParameterError, match=message):
        UntangleOptions(**bad)
    with pytest.raises(TypeError, match="unexpected keyword argument 'max_outr'"):
        UntangleOptions(max_outr=3)
    ok = UntangleOptions(max_outer=3.0, theta=None)
    assert ok.max_outer == 3 and isinstance(ok.max_outer, int)
    assert dataclasses.replace(ok, keep_memory=False).keep_memory is False


# ------------------------------------------------------------------ the step limit, said (issue 30 item 8)


def test_a_solve_stopped_at_max_steps_warns_where_the_user_called_it():
    """SLIM ran 1,000 iterations for 25 minutes and returned MAX_STEPS with progress off and no
    word: now one MaxStepsWarning names the solver, the limit and how to raise it."""
    from geomopt import SLIM, MaxStepsWarning

    obj, V = _objective()
    with pytest.warns(MaxStepsWarning) as caught:
        res = minimize(obj, V, solver=SLIM(max_steps=2), progress=False)
    assert res.outcome is Outcome.MAX_STEPS and len(caught) == 1
    message = str(caught[0].message)
    for words in ("SLIM stopped at its iteration limit (max_steps=2)", "after 2 iterations", "SLIM(max_steps=...)",
                  "--max-steps"):
        assert words in message, message
    assert caught[0].filename == __file__  # the user's line, not geomopt's


def test_no_max_steps_warning_on_converged_observed_or_thrown_solves():
    """Silent when the solve converged (its phases may stop at a step limit on the way: a
    continuation took over), when the caller's own observer stopped it, and under throw=True
    (the SolveError says it)."""
    from geomopt import MaxStepsWarning, SolveError

    obj, V = _objective()
    with warnings.catch_warnings():
        warnings.simplefilter("error", MaxStepsWarning)
        assert minimize(obj, V, progress=False).outcome is Outcome.CONVERGED
        phased = iterate(Newton(max_steps=1), obj, obj.prepare_map(V), obj.params(), continuation=_Halving(),
                         trace=False)
        assert phased.outcome is Outcome.CONVERGED
        observed = iterate(LBFGS(), obj, obj.prepare_map(V), obj.params(),
                           observe=lambda state, seconds: "enough" if state.iteration >= 2 else None)
        assert observed.outcome is Outcome.MAX_STEPS
        with pytest.raises(SolveError, match="iteration limit"):
            minimize(obj, V, solver=Newton(max_steps=1), progress=False, throw=True)
        t = G.rotated_interior(*G.square_mesh(6), 120.0)
        with pytest.raises(SolveError, match="outer-iteration limit"):
            untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(max_outer=1), throw=True)
    with pytest.warns(MaxStepsWarning, match=r"untangling: stopped at the outer-iteration limit \(max_outer=1\)"):
        untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(max_outer=1))

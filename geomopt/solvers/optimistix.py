"""optimistix solvers through geomopt, kept flip-free by the injective search.

Any optimistix minimiser whose line search is a ``search`` field (``optx.BFGS``,
``optx.LBFGS``, ``optx.NonlinearCG``, ``optx.GradientDescent``-style solvers built from a
descent and a search) runs with :class:`OptxInjectiveSearch` in place of its own search:
a trial point at which an element that was positively oriented is not (the closed-form first
root of a det along the step) is rejected and the step cut back to ``safety`` times that
root; otherwise Armijo backtracking.  So these solvers stay flip-free also for energies with
no barrier (ARAP, Dirichlet).

:class:`ObjectiveFunction` is an :class:`~geomopt.Objective` as a plain ``fn(y, args)`` (args
= the energy parameters) for people who want optimistix's own loop (``optx.minimise``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._errors import ParameterError
from .._geometry import dets
from .._objective import total_energy
from ..linesearch import InjectiveSearch, injective_step_bound, still_positive
from ._base import AbstractSolver, Outcome, State, reference_extent

__all__ = ["Optimistix", "OptxInjectiveSearch", "ObjectiveFunction", "objective_function"]


class ObjectiveFunction(eqx.Module):
    """``fn(y, params) -> E``: an objective as a function of the whole map ``y`` (n, d); fixed
    vertices are read from ``x_fixed`` whatever ``y`` holds there (their gradient is zero)."""

    density: Callable = eqx.field(static=True)
    geom: tuple
    free: jax.Array
    x_fixed: jax.Array

    def __call__(self, y, args):
        x = jnp.where(self.free > 0, y, self.x_fixed)
        return total_energy(self.density, self.geom, x, args)


def objective_function(objective, x0) -> ObjectiveFunction:
    """The :class:`ObjectiveFunction` of an :class:`~geomopt.Objective`, fixed vertices at ``x0``."""
    x0 = jnp.asarray(objective.prepare_map(x0))
    return ObjectiveFunction(objective.energy.density, objective.geom, objective._free, x0)


class _WithAux(eqx.Module):
    fn: ObjectiveFunction

    def __call__(self, y, args):
        return self.fn(y, args), None


class OptxInjectiveSearch(optx.AbstractSearch):
    """An optimistix search that keeps every positively oriented element positive, then
    backtracks (Armijo) with the constants of a geomopt :class:`InjectiveSearch`."""

    simplices: jax.Array
    config: InjectiveSearch = eqx.field(static=True)

    def init(self, y, f_info_struct):
        return jnp.asarray(1.0, jnp.float64)

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        cfg = self.config
        diff = y_eval - y
        slope = f_info.compute_grad_dot(diff)
        f, fe = f_info.as_min(), f_eval_info.as_min()
        if cfg.injective:
            tmax = injective_step_bound(self.simplices, y, diff)
            pos = (cfg.safety * tmax >= 1.0) & still_positive(self.simplices, y, diff, 1.0,
                                                               dets(self.simplices, y) > 0)
            cut = jnp.minimum(cfg.shrink, cfg.safety * tmax)
        else:
            pos, cut = jnp.bool_(True), jnp.asarray(cfg.shrink)
        armijo = pos & jnp.isfinite(fe) & (slope <= 0) & (fe - f <= cfg.c1 * slope)
        accept = first_step | armijo
        size = jnp.where(accept, 1.0, state * jnp.where(pos, cfg.shrink, cut))
        return size, accept, optx.RESULTS.successful, size


@eqx.filter_jit
def _optx_init(osolver, fn, y, params):
    f_struct = jax.ShapeDtypeStruct((), jnp.float64)
    return osolver.init(fn, y, params, {}, f_struct, None, frozenset())


@eqx.filter_jit
def _optx_step(osolver, fn, y, params, ostate):
    y, ostate, _ = osolver.step(fn, y, params, {}, ostate, frozenset())
    done, result = osolver.terminate(fn, y, params, {}, ostate, frozenset())
    f = ostate.f_info.f if hasattr(ostate, "f_info") else fn(y, params)[0]
    g = getattr(getattr(ostate, "f_info", None), "grad", None)
    return y, ostate, done, result == optx.RESULTS.successful, f, g


@dataclasses.dataclass(frozen=True)
class Optimistix(AbstractSolver):
    """An optimistix minimiser driven by geomopt with the injective search.

    Attributes
    ----------
    solver : an optimistix minimiser with a ``search`` field, e.g.
        ``optx.BFGS(rtol=1e-8, atol=1e-8)``, ``optx.LBFGS(...)``, ``optx.NonlinearCG(...)``,
        ``optx.GradientDescent(learning_rate=..., ...)`` is *not* one (fixed step size: use a
        custom ``optx.AbstractGradientDescent`` subclass with a search).  Its own tolerances
        decide convergence.
    max_steps : iteration limit.
    search : the geomopt :class:`~geomopt.linesearch.InjectiveSearch` whose constants
        (``injective``, ``safety``, ``c1``, ``shrink``) :class:`OptxInjectiveSearch` uses.
    """

    solver: Any = None
    rtol: float = 1e-10
    max_steps: int = 1000
    search: InjectiveSearch = InjectiveSearch()

    def __post_init__(self):
        self._check()
        if not isinstance(self.solver, optx.AbstractMinimiser) or not hasattr(self.solver, "search"):
            raise ParameterError(
                "Optimistix(solver=...) needs an optimistix minimiser with a line search, e.g. "
                f"optimistix.BFGS(rtol=1e-8, atol=1e-8); got {type(self.solver).__name__}")

    def init(self, objective, x0, params) -> State:
        fn = _WithAux(objective_function(objective, x0))
        search = OptxInjectiveSearch(objective.geom[0], self.search)
        osolver = eqx.tree_at(lambda s: s.search, self.solver, search)
        y = jnp.asarray(objective.pad_map(np.asarray(x0, np.float64)))
        ostate = _optx_init(osolver, fn, y, params)
        value, grad = objective.value_and_grad(y, params)
        aux = {"fn": fn, "osolver": osolver, "ostate": ostate, "done": False, "ok": True}
        _optx_step(osolver, fn, y, params, ostate)  # compile now: setup time holds it
        return State(objective, params, y, float(value), grad, extent0=reference_extent(objective, x0),
                     aux=aux)

    def step(self, state: State) -> State:
        a = state.aux
        y, ostate, done, ok, f, g = _optx_step(a["osolver"], a["fn"], state.x, state.params, a["ostate"])
        grad = g * state.objective._free if g is not None else state.grad
        return dataclasses.replace(
            state, x=y, value=float(f), grad=grad, iteration=state.iteration + 1,
            prev_value=state.value, evaluations=state.evaluations + 1,
            failure=None if bool(ok) else Outcome.LINE_SEARCH_FAILED,
            aux=dict(a, ostate=ostate, done=bool(done)))

    def terminate(self, state: State):
        done, outcome = super().terminate(dataclasses.replace(state, decrement=float("inf"),
                                                              prev_value=float("inf")))
        if done:
            return done, outcome
        if state.aux["done"]:
            return True, Outcome.CONVERGED
        return False, None

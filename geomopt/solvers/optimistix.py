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
from typing import Any, Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._runtime.errors import ParameterError
from ..objective.objective import total_energy
from .linesearch import InjectiveSearch
from ._base import AbstractSolver, State, map_extent, start_stats

__all__ = ["Optimistix", "OptxInjectiveSearch", "ObjectiveFunction", "objective_function"]


class ObjectiveFunction(eqx.Module):
    """``fn(y, params) -> E``: an objective as a function of the whole map ``y`` (n, d); fixed
    vertices are read from ``x_fixed`` whatever ``y`` holds there (their gradient is zero).
    Made by :func:`objective_function`.

    Attributes
    ----------
    density : the energy density ``psi(J, params)`` (static).
    geom : the objective's per-element geometry (``Objective.geom``: simplices, inverse rest
        matrices, rest sizes times the element weights; padded to the size bucket).
    free : (n, d) 1 on free coordinates, 0 on fixed ones (``Objective.free_mask``).
    x_fixed : (n, d) the map whose rows the fixed vertices take.
    """

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
    return ObjectiveFunction(objective.energy.density, objective.geom, objective.free_mask, x0)


class _WithAux(eqx.Module):
    fn: ObjectiveFunction

    def __call__(self, y, args):
        return self.fn(y, args), None


class OptxInjectiveSearch(optx.AbstractSearch):
    """An optimistix search that keeps every positively oriented element positive, then
    backtracks (Armijo): the accept and next-trial rules of a geomopt :class:`InjectiveSearch`
    (:meth:`~InjectiveSearch.admissible`, :meth:`~InjectiveSearch.sufficient`,
    :meth:`~InjectiveSearch.next_trial`) applied to optimistix's proposed step.

    Attributes
    ----------
    simplices : (m, d + 1) the elements whose orientation is kept (``Objective.geom[0]``).
    config : the :class:`~geomopt.solvers.linesearch.InjectiveSearch` whose rules apply (static).
    """

    simplices: jax.Array
    config: InjectiveSearch = eqx.field(static=True)

    def init(self, y, f_info_struct):
        return jnp.asarray(1.0, jnp.float64)

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        cfg, S = self.config, self.simplices
        diff = y_eval - y
        slope = f_info.compute_grad_dot(diff)
        f, fe = f_info.as_min(), f_eval_info.as_min()
        cap = cfg.cap(S, y, diff)  # in units of the proposed step
        one = jnp.asarray(1.0, jnp.float64)
        good = cfg.admissible(S, y, diff, one, cfg.positive(S, y), fe, cap)
        armijo = good & (slope <= 0) & cfg.sufficient(f, fe, one, slope)
        accept = first_step | armijo
        cut, _, _ = cfg.next_trial(one, jnp.zeros_like(one), jnp.asarray(jnp.inf, jnp.float64),
                                   jnp.bool_(False), cap)
        size = jnp.where(accept, 1.0, state * cut)
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


class OptxMemory(NamedTuple):
    """The optimistix solver (with :class:`OptxInjectiveSearch`), the function it minimises
    and its state."""

    osolver: Any
    fn: Any
    ostate: Any


@dataclasses.dataclass(frozen=True)
class Optimistix(AbstractSolver):
    """An optimistix minimiser driven by geomopt with the injective search.

    Attributes
    ----------
    solver : an optimistix minimiser with a ``search`` field, e.g.
        ``optx.BFGS(rtol=1e-8, atol=1e-8)``, ``optx.LBFGS(...)``, ``optx.NonlinearCG(...)``,
        ``optx.GradientDescent(learning_rate=..., ...)`` is *not* one (fixed step size: use a
        custom ``optx.AbstractGradientDescent`` subclass with a search).  Its own tolerances
        decide convergence (``Stats.done``); geomopt's :class:`~geomopt.solvers.Termination`
        adds the step limit, non-finite values and divergence.  Required.
    rtol : 1e-10; not used by the stopping rule (``solver``'s own ``rtol`` / ``atol`` decide
        convergence); kept so that every solver has one.
    max_steps : 1000; the iteration limit (a solve that reaches it ends ``MAX_STEPS``).
    search : the geomopt :class:`~geomopt.solvers.linesearch.InjectiveSearch` (default
        ``InjectiveSearch()``) whose rules (``injective``, ``safety``, ``c1``, ``shrink``)
        :class:`OptxInjectiveSearch` applies in place of ``solver``'s own search.

    Examples
    --------
    >>> import optimistix as optx
    >>> import geomopt
    >>> from geomopt.solvers.optimistix import Optimistix
    >>> V = [[0, 0, 0.5], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
    >>> F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]
    >>> solver = Optimistix(optx.BFGS(rtol=1e-8, atol=1e-8))
    >>> geomopt.parameterize(V, F, solver=solver, progress=False).success
    True
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
        _optx_step(osolver, fn, y, params, ostate)  # compile now: setup time holds it
        # optimistix decides convergence: geomopt's decrement and stall tests stay off
        stats = start_stats(objective, x0, float(value))
        return State(objective, params, y, grad, stats, OptxMemory(osolver, fn, ostate))

    def step(self, state: State) -> State:
        m = state.memory
        y, ostate, done, ok, f, g = _optx_step(m.osolver, m.fn, state.x, state.params, m.ostate)
        grad = g * state.objective.free_mask if g is not None else state.grad
        return state.update(x=y, value=float(f), grad=grad, iteration=state.iteration + 1,
                            evaluations=state.evaluations + 1, accepted=bool(ok), done=bool(done),
                            extent=map_extent(y), memory=m._replace(ostate=ostate))

    def restart(self, state: State, x=None) -> State:
        """A fresh optimistix state (its memory dropped) at ``x`` or the current map."""
        m = state.memory
        state = state if x is None else self._moved(state, x)
        return dataclasses.replace(state, memory=m._replace(ostate=_optx_init(m.osolver, m.fn, state.x,
                                                                              state.params)))

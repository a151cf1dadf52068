"""The injective search in JAX's optimiser libraries: an optax line search, and jaxopt's.

An optax loop over a mesh map moves the vertices by whatever step its line search accepts; with
an energy without a barrier (ARAP, Dirichlet) or a first-order method whose trial steps skip
over the barrier, the map folds.  :func:`injective_linesearch` is geomopt's
:class:`~geomopt.linesearch.InjectiveSearch` as an ``optax.GradientTransformationExtraArgs``
closed over the mesh: it caps every step at a fraction of the first root of an element's
``det J`` along the direction (Smith & Schaefer 2015), then Armijo / weak Wolfe, so the loop
stays flip-free::

    import optax
    from geomopt.optax import injective_linesearch, energy_fn

    f = energy_fn(objective)                       # the energy, handles held fixed
    opt = optax.lbfgs(linesearch=injective_linesearch(objective))
    state, x = opt.init(x0), x0
    value_and_grad = optax.value_and_grad_from_state(f)
    for _ in range(100):
        value, grad = value_and_grad(x, state=state)
        updates, state = opt.update(grad, state, x, value=value, grad=grad, value_fn=f)
        x = optax.apply_updates(x, updates)

It chains after any optax transformation that makes a descent direction
(``optax.chain(optax.sgd(1.0), injective_linesearch(obj))`` is flip-free gradient descent).

jaxopt (unmaintained; its solvers moved into optax) gets no adapter: its ``LBFGS`` takes a
line search by name, or an instance of a class that is not part of its public API
(``jaxopt._src.base.IterativeLineSearch``); use optax.

optax is optional: imported when :func:`injective_linesearch` is called (``pip install optax``,
or geomopt's ``[optax]`` extra).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from ._errors import ParameterError
from ._objective import Objective
from ._geometry import dets
from ._x64 import float64
from .linesearch import InjectiveSearch

__all__ = ["injective_linesearch", "energy_fn", "InjectiveLinesearchState", "DET_FLOOR"]

#: the default search: injective cap, weak Wolfe (quasi-Newton directions want curvature)
DEFAULT_SEARCH = InjectiveSearch(c2=0.9)
#: no accepted step leaves an element's det below this times the mean |det| of the map
DET_FLOOR = 1e-12


class InjectiveLinesearchState(NamedTuple):
    """State of :func:`injective_linesearch`: the last step (``learning_rate``), value and
    gradient at the accepted point (read by ``optax.value_and_grad_from_state``), and the
    energy evaluations of the last search (``info``; 0 steps accepted is ``learning_rate`` 0)."""

    learning_rate: jax.Array
    value: jax.Array
    grad: Any
    info: jax.Array


def _import(name):
    try:
        return __import__(name)
    except ImportError:
        raise ParameterError(f"geomopt.optax needs the optional package {name!r}: pip install {name}") from None


def _mesh(objective):
    if not isinstance(objective, Objective):
        raise ParameterError(f"the injective search needs a geomopt.Objective (its mesh), got "
                             f"{type(objective).__name__}")
    n = objective.problem.n_vertices
    return objective.geom[0], objective.free_mask[:n]


def energy_fn(objective: Objective, params=None) -> Callable:
    """``x -> E(x)`` for an (n, d) map, whose gradient is zero on the handles (they stay put
    under any optax transformation); traceable (see :class:`~geomopt.Objective`)."""
    _, free = _mesh(objective)
    p = objective.params(**(params or {}))

    def f(x):
        return objective.value(free * x + (1.0 - free) * jax.lax.stop_gradient(x), p)

    return f


@float64
def injective_linesearch(objective: Objective, search: InjectiveSearch = DEFAULT_SEARCH):
    """geomopt's injective line search as an optax ``GradientTransformationExtraArgs``.

    ``update(updates, state, params, *, value, grad, value_fn, **extra_args)`` searches along
    ``updates`` (the descent direction, zero on the objective's handles) from the map
    ``params`` (n, d) for ``value_fn`` (the loss, e.g. :func:`energy_fn`; its extra arguments
    come from ``extra_args``) and returns ``t * updates``: ``t`` below the first element
    inversion on the way, Armijo (and weak Wolfe when ``search.c2 > 0``), and no element's
    ``det J`` below :data:`DET_FLOOR` times the mean (rounded positions checked).  A search
    that finds no such step returns zero updates (the map stays where it is, flip-free).

    Parameters
    ----------
    objective : :class:`~geomopt.Objective` whose mesh the maps live on (its simplices and
        handles; the energy searched is ``value_fn``).
    search : :class:`~geomopt.linesearch.InjectiveSearch` (``injective`` must be True).
    """
    optax = _import("optax")
    if not (isinstance(search, InjectiveSearch) and search.injective):
        raise ParameterError("injective_linesearch needs an InjectiveSearch with injective=True")
    S, free = _mesh(objective)

    def init(params):
        return InjectiveLinesearchState(jnp.asarray(1.0, params.dtype), jnp.asarray(jnp.inf, params.dtype),
                                        jnp.zeros_like(params), jnp.asarray(0, jnp.int32))

    def update(updates, state, params, *, value, grad, value_fn, **extra_args):
        def value_and_grad(x):
            v, g = jax.value_and_grad(value_fn)(x, **extra_args)
            return v, g * free

        d = updates * free
        t, x_t, f_t, g_t, ok, evals = search.search(value_and_grad, S, params, value, grad * free, d)
        # the search guards the edge matrices; the map itself (rounded positions) must keep every
        # element above a floor too, else elements shrink geometrically to det == 0 under an
        # energy without a barrier, where rounding decides their sign
        D0 = dets(S, params)
        ok = ok & jnp.all(jnp.where(D0 > 0, dets(S, x_t) > DET_FLOOR * jnp.mean(jnp.abs(D0)), True))
        t = jnp.where(ok, t, 0.0)
        state = InjectiveLinesearchState(t, jnp.where(ok, f_t, value), jnp.where(ok, g_t, grad * free),
                                         jnp.asarray(evals, jnp.int32))
        return t * d, state

    return optax.GradientTransformationExtraArgs(init, update)

"""The injective search in JAX's optimiser libraries: an optax line search, and jaxopt's.

An optax loop over a mesh map moves the vertices by whatever step its line search accepts; with
an energy without a barrier (ARAP, Dirichlet) or a first-order method whose trial steps skip
over the barrier, the map folds.  :func:`injective_linesearch` is geomopt's
:class:`~geomopt.solvers.linesearch.InjectiveSearch` as an ``optax.GradientTransformationExtraArgs``
closed over the mesh: it caps every step at a fraction of the first root of an element's
``det J`` along the direction (Smith & Schaefer 2015), then Armijo / weak Wolfe, so the loop
stays flip-free.  :func:`run` is the whole loop in one compiled ``lax.while_loop``::

    import optax
    from geomopt.optax import energy_fn, injective_linesearch, run

    f = energy_fn(objective)                       # the energy, handles held fixed
    opt = optax.lbfgs(linesearch=injective_linesearch(objective))
    x, state, steps = run(opt, f, x0, max_steps=300)

A loop of your own must be jitted too: one step is ::

    value_and_grad = optax.value_and_grad_from_state(f)

    @jax.jit
    def step(x, state):
        value, grad = value_and_grad(x, state=state)
        updates, state = opt.update(grad, state, x, value=value, grad=grad, value_fn=f)
        return optax.apply_updates(x, updates), state

Called eagerly (without ``jax.jit``) each ``opt.update`` traces and compiles the control flow
inside it again, because every call hands ``lax.while_loop`` / ``lax.scan`` / ``lax.cond`` new
closures (the search's loop, L-BFGS's two-loop recursion, ``value_and_grad_from_state``): on the
camel head (22.7k triangles) 0.5 s per step, against 0.01 s jitted (``benchmarks/optax_loop.py``).
Run the loop with JAX's 64-bit mode on (``jax.config.update("jax_enable_x64", True)``), or
through :func:`run`, which switches it on for its duration.

It chains after any optax transformation that makes a descent direction
(``optax.chain(optax.sgd(1.0), injective_linesearch(obj))`` is flip-free gradient descent).

jaxopt (unmaintained; its solvers moved into optax) gets no adapter: its ``LBFGS`` takes a
line search by name, or an instance of a class that is not part of its public API
(``jaxopt._src.base.IterativeLineSearch``); use optax.

optax is optional: imported when :func:`injective_linesearch` is called (``pip install optax``,
or geomopt's ``[optax]`` extra).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._runtime.errors import ParameterError
from .objective.objective import Objective
from .mesh.geometry import dets
from ._runtime.x64 import float64
from .solvers.linesearch import InjectiveSearch

__all__ = ["injective_linesearch", "energy_fn", "run", "InjectiveLinesearchState", "DET_FLOOR"]

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
    under any optax transformation); traceable in JAX's 64-bit mode (see
    :class:`~geomopt.Objective`; called eagerly it switches the mode on itself)."""
    _, free = _mesh(objective)
    p = objective.params(**(params or {}))

    def f(x):
        return objective.value(free * x + (1.0 - free) * jax.lax.stop_gradient(x), p)

    return float64(f)  # float64 when called eagerly; inside a float32 trace, a ParameterError


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
    search : :class:`~geomopt.solvers.linesearch.InjectiveSearch` (``injective`` must be True).
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


@float64
def run(optimizer, value_fn: Callable, x0, max_steps: int = 100, tol: float = 0.0):
    """Run an optax ``optimizer`` on ``value_fn`` from ``x0`` in one compiled ``lax.while_loop``.

    Each iteration is ``optax.value_and_grad_from_state(value_fn)`` (the value and gradient the
    line search left in the state, else computed), ``optimizer.update(grad, state, x, value=,
    grad=, value_fn=)`` and ``optax.apply_updates``; the loop stops after ``max_steps``
    iterations, after an iteration that moved nothing (the injective search found no
    acceptable step, or the gradient is zero), or once ``|grad|_2 <= tol``.

    The loop is compiled once per ``(optimizer, value_fn)`` pair and shape of ``x0``: keep both
    objects and call again with another start or ``max_steps`` (traced) without re-tracing; a
    new ``optax.lbfgs(...)`` or :func:`energy_fn` is a new pair.  Runs in JAX's 64-bit mode.

    Parameters
    ----------
    optimizer : an ``optax.GradientTransformationExtraArgs`` such as
        ``optax.lbfgs(linesearch=injective_linesearch(objective))``.
    value_fn : ``x -> E(x)`` (e.g. :func:`energy_fn`), traceable.
    x0 : (n, d) start map.
    max_steps : int >= 0, iterations at most.
    tol : float >= 0, stop once the gradient's 2-norm is at most this.

    Returns
    -------
    x : (n, d) float64 ndarray, the last map;  state : the optimizer's state there;
    steps : int, iterations run.

    Examples
    --------
    >>> import optax
    >>> from geomopt import Objective, Problem
    >>> from geomopt.mesh import generators
    >>> from geomopt.param import start_map
    >>> V, F = generators.saddle(rings=4)
    >>> obj = Objective(Problem.surface(V, F), "symmetric_dirichlet")
    >>> x0 = start_map(obj)[0]
    >>> f = energy_fn(obj)
    >>> opt = optax.lbfgs(linesearch=injective_linesearch(obj))
    >>> x, state, steps = run(opt, f, x0, max_steps=30)
    >>> bool(obj.problem.count_inverted(x) == 0 and f(x) < f(x0)), steps
    (True, 30)
    """
    _import("optax")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 0:
        raise ParameterError(f"run: max_steps must be an int >= 0, got {max_steps!r}")
    if not (np.isscalar(tol) and np.isfinite(tol) and tol >= 0):
        raise ParameterError(f"run: tol must be a finite float >= 0, got {tol!r}")
    x0 = jnp.asarray(x0, jnp.float64)
    x, state, steps = _run(optimizer, value_fn, x0, jnp.asarray(max_steps, jnp.int32), jnp.asarray(tol, x0.dtype))
    return np.asarray(x), state, int(steps)


@partial(jax.jit, static_argnums=(0, 1))
def _run(optimizer, value_fn, x0, max_steps, tol):
    import optax

    value_and_grad = optax.value_and_grad_from_state(value_fn)

    def step(carry):
        x, state, k, _ = carry
        value, grad = value_and_grad(x, state=state)
        updates, state = optimizer.update(grad, state, x, value=value, grad=grad, value_fn=value_fn)
        moved = jnp.any(updates != 0) & (jnp.sqrt(jnp.vdot(grad, grad)) > tol)
        return optax.apply_updates(x, updates), state, k + 1, moved

    def more(carry):
        return (carry[2] < max_steps) & carry[3]

    carry = (x0, optimizer.init(x0), jnp.asarray(0, jnp.int32), jnp.asarray(True))
    return jax.lax.while_loop(more, step, carry)[:3]

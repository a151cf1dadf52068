"""AQP: accelerated quadratic proxy (Kovalsky, Galun & Lipman 2016, "Accelerated quadratic
proxy for geometric optimization").

The proxy is the rest Dirichlet Laplacian ``K`` (constant: factored once).  Each iteration
first moves along the momentum ``v = x_k - x_{k-1}`` by ``theta`` (capped by the injective
bound along ``v``, dropped when it raises the energy), then takes the proxy step
``d = -K^-1 grad E(y)`` from that point ``y`` with the shared injective search.  Because the
proxy does not change with the mesh's resolution, the iteration count stays nearly flat when
the same shape is refined, as long as the start map converges under refinement too (a
uniform Tutte map does not on irregular meshes: on the saddle its smallest singular value
shrinks by ~30% per subdivision; the mean-value one converges) and the minimum does not get
harder on the finer mesh (the ruffled disk: SLIM's and AQP's counts both grow there, only
Newton's stays flat; ``benchmarks/solvers.py --refine``).

``K`` is the Hessian of the Dirichlet energy ``|J|^2``; the proxy is ``c K`` with ``c`` the
energy's curvature at rest relative to Dirichlet's (:func:`rest_curvature`; 4 for symmetric
Dirichlet), so that the line search's first trial ``t = 1`` is the proxy's minimiser near
the solution instead of a step ``1/c`` too long that Armijo halves ``log2 c`` times in every
iteration.

The search caps the first trial at a quarter of the flip bound (``InjectiveSearch(safety=0.25)``,
not the 0.9 of the other solvers).  The Laplacian proxy does not see the barrier, so the bound
is often what limits its step; at 0.9 the blocking element loses ~90% of its area in one step
and the next gradient is dominated by its barrier, giving alternating tiny steps (measured:
Tutte-started saddle at 1.5k/6k/25k triangles, iterations to 1e-4 of the minimum 9/15/22 at 0.9,
9/9/11 at 0.25; camelhead 704 -> 210, face 911 -> 55; ``benchmarks/solvers.py --refine``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.config import Real
from .linesearch import InjectiveSearch
from ._base import AbstractSolver, State, map_extent
from ._laplacian import RestLaplacian

__all__ = ["AQP", "rest_curvature"]


def rest_curvature(density, params, d) -> float:
    """The curvature of ``density`` at rest relative to the Dirichlet energy ``|J|^2``: the mean
    of ``d^2 psi(diag(sigma)) / d sigma_i^2`` at ``sigma = 1``, over 2 (Dirichlet's), or 1
    where that is not a positive finite number (a density without curvature there)."""
    f = lambda s: density(jnp.diag(s) if d > 1 else s, params)  # noqa: E731
    h = np.asarray(jnp.diagonal(jax.hessian(f)(jnp.ones(d, jnp.float64))))
    c = float(np.mean(h)) / 2.0
    return c if math.isfinite(c) and c > 0 else 1.0


class AQPMemory(NamedTuple):
    """AQP's memory: the previous map (the momentum ``x_k - x_{k-1}``; None after a start or
    restart), the factored rest Laplacian and the proxy's scale ``1 / rest_curvature``."""

    prev_x: Any
    proxy: Any
    scale: float


@dataclasses.dataclass(frozen=True)
class AQP(AbstractSolver):
    """Accelerated quadratic proxy.

    Attributes
    ----------
    condition : 100 (>= 1); the condition number ``kappa`` the acceleration is tuned for:
        ``theta = (1 - 1/sqrt(kappa)) / (1 + 1/sqrt(kappa))`` (Nesterov; Kovalsky et al. 2016).
    rtol : 1e-10; stop when the decrement of the step taken or the energy decrease is below
        ``rtol * |E|`` (:attr:`termination`).
    max_steps : 2000; the iteration limit (a solve that reaches it ends ``MAX_STEPS``).
    search : the :class:`~geomopt.solvers.linesearch.InjectiveSearch`, default ``InjectiveSearch(safety=0.25)``:
        first trial at most a quarter of the flip bound (see the module notes); the momentum move is capped and
        checked by the same search (:meth:`~geomopt.solvers.linesearch.InjectiveSearch.cap`,
        :meth:`~geomopt.solvers.linesearch.InjectiveSearch.admissible`).
    """

    condition: float = 100.0
    rtol: float = 1e-10
    max_steps: int = 2000
    search: InjectiveSearch = InjectiveSearch(safety=0.25)

    def __post_init__(self):
        self._check(condition=Real(1.0))

    @property
    def theta(self) -> float:
        r = 1.0 / math.sqrt(self.condition)
        return (1.0 - r) / (1.0 + r)

    def init(self, objective, x0, params) -> State:
        scale = 1.0 / rest_curvature(objective.energy.density, params, objective.problem.dim)
        state = self._start(objective, x0, params, AQPMemory(None, RestLaplacian(objective), scale))
        self.search(objective, params, state.x, state.value, state.grad, jnp.zeros_like(state.x))
        return state

    def reparam(self, state: State, params) -> State:
        """As :meth:`AbstractSolver.reparam`, the proxy's curvature scale re-derived."""
        state = super().reparam(state, params)
        scale = 1.0 / rest_curvature(state.objective.energy.density, params, state.objective.problem.dim)
        return dataclasses.replace(state, memory=state.memory._replace(scale=scale))

    def restart(self, state: State, x=None) -> State:
        """The momentum dropped; moved to ``x`` when given."""
        state = dataclasses.replace(state, memory=state.memory._replace(prev_x=None))
        return state if x is None else self._moved(state, x)

    def _momentum(self, state):
        """``(y, f(y), grad(y), evaluations)``: the momentum point ``x + theta v`` (``v = x_k -
        x_{k-1}``), ``theta`` capped by the search, when the search admits it and it does not
        raise the energy; else ``x`` itself."""
        obj, x, prev = state.objective, state.x, state.memory.prev_x
        if prev is None:
            return x, state.value, state.grad, 0
        v = x - prev
        th = min(self.theta, self.search.cap_along(obj, x, v))
        if not th > 0:
            return x, state.value, state.grad, 0
        y = x + th * v
        f, g = obj.value_and_grad(y, state.params)
        f = float(f)
        if self.search.admissible_step(obj, x, v, th, f) and f <= state.value:
            return y, f, g, 1
        return x, state.value, state.grad, 1

    def step(self, state: State) -> State:
        obj, params, x = state.objective, state.params, state.x
        y, fy, gy, evals = self._momentum(state)
        d = -state.memory.scale * jnp.asarray(state.memory.proxy.solve(jnp.asarray(gy).__array__()))
        slope = float(jnp.vdot(gy, d))
        t, xn, fn, gn, n = self.search(obj, params, y, fy, gy, d)
        stats = dict(iteration=state.iteration + 1, evaluations=state.evaluations + evals + n)
        memory = state.memory._replace(prev_x=x)
        if t == 0.0:
            if y is not x:  # momentum point accepted, proxy step not: keep the momentum move
                return state.update(x=y, value=fy, grad=gy, step_size=0.0, past_value=state.value,
                                    decrement=-0.5 * slope, memory=memory, extent=map_extent(y), **stats)
            return state.update(step_size=0.0, accepted=False, decrement=-0.5 * slope, **stats)
        return state.update(x=xn, value=fn, grad=gn, step_size=t, past_value=state.value,
                            decrement=-0.5 * t * slope, memory=memory, extent=map_extent(xn), **stats)

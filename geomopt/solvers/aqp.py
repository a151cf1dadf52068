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

import jax
import jax.numpy as jnp
import numpy as np

from .._config import Real
from ..linesearch import InjectiveSearch, max_injective_step
from ._base import AbstractSolver, Outcome, State
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


@dataclasses.dataclass(frozen=True)
class AQP(AbstractSolver):
    """Accelerated quadratic proxy.

    Attributes
    ----------
    condition : the condition number ``kappa`` the acceleration is tuned for:
        ``theta = (1 - 1/sqrt(kappa)) / (1 + 1/sqrt(kappa))`` (Nesterov; Kovalsky et al. 2016).
    rtol, max_steps : as for every solver (relative energy decrease / decrement test).
    search : the :class:`~geomopt.linesearch.InjectiveSearch` (default: first trial at most a
        quarter of the flip bound, see the module notes).
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
        state = self._start(objective, x0, params, aux={"prev_x": None, "proxy": RestLaplacian(objective),
                                                        "scale": scale})
        self.search(objective, params, state.x, state.value, state.grad, jnp.zeros_like(state.x))
        return state

    def with_params(self, state: State, params) -> State:
        """As :meth:`AbstractSolver.with_params`, the proxy's curvature scale re-derived."""
        state = super().with_params(state, params)
        scale = 1.0 / rest_curvature(state.objective.energy.density, params, state.objective.problem.dim)
        return dataclasses.replace(state, aux=dict(state.aux, scale=scale))

    def step(self, state: State) -> State:
        obj, params, x = state.objective, state.params, state.x
        y, fy, gy, evals = x, state.value, state.grad, 0
        prev = state.aux["prev_x"]
        if prev is not None:
            v = x - prev
            th = self.theta
            if self.search.injective:
                th = min(th, self.search.safety * float(max_injective_step(obj.geom[0], x, v)))
            if th > 0:
                y2 = x + th * v
                f2, g2 = obj.value_and_grad(y2, params)
                evals += 1
                if math.isfinite(float(f2)) and float(f2) <= state.value:
                    y, fy, gy = y2, float(f2), g2
        d = -state.aux["scale"] * jnp.asarray(state.aux["proxy"].solve(jnp.asarray(gy).__array__()))
        slope = float(jnp.vdot(gy, d))
        t, xn, fn, gn, n = self.search(obj, params, y, fy, gy, d)
        evals += n
        it = state.iteration + 1
        aux = dict(state.aux, prev_x=x)
        if t == 0.0:
            if y is not x:  # momentum point accepted, proxy step not: keep the momentum move
                return dataclasses.replace(state, x=y, value=fy, grad=gy, iteration=it, step_size=0.0,
                                           prev_value=state.value, decrement=-0.5 * slope, aux=aux,
                                           evaluations=state.evaluations + evals)
            failure = None if -slope <= 1e-14 * max(abs(fy), 1e-300) else Outcome.LINE_SEARCH_FAILED
            return dataclasses.replace(state, iteration=it, step_size=0.0, failure=failure,
                                       decrement=-0.5 * slope, evaluations=state.evaluations + evals)
        return dataclasses.replace(state, x=xn, value=fn, grad=gn, iteration=it, step_size=t,
                                   prev_value=state.value, decrement=-0.5 * t * slope, aux=aux,
                                   evaluations=state.evaluations + evals)

"""Projected Newton with a sparse Cholesky and the injective line search.

Per iteration: per-element Hessians by autodiff, projected to PSD in J-space, assembled
into a fixed CSC pattern, factored (symbolic analysis reused), then the injective
backtracking line search (Teran et al. 2005; Smith & Schaefer 2015).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._config import Instance, Int, OneOf, Real, validate
from .._objective import PROJECTIONS
from ..linesearch import Backtracking
from ..linsolve import BACKENDS, NotPositiveDefinite, SparseCholesky
from ._base import AbstractSolver, Outcome, State


@dataclasses.dataclass(frozen=True)
class Newton(AbstractSolver):
    """Projected Newton.

    Attributes
    ----------
    projection : ``"adaptive"`` (default), ``"clamp"``, ``"abs"`` or ``"none"``.  Projected
        Newton converges only linearly near a minimum because the projection changes the
        Hessian of elements that are indefinite there (symmetric Dirichlet has many), so
        ``adaptive`` clamps while far from the minimum and, once a full step was accepted and
        the decrement is below ``exact_below * |E|``, factors the *unprojected* Hessian: at a
        strict minimum it is positive definite and Newton converges quadratically.  The exact
        Hessian gets a Levenberg-Marquardt shift, relaxed after full steps and stiffened after
        cut ones; if it does not factor (indefinite), clamping resumes for two iterations.
    linear_solver : a :data:`~geomopt.linsolve.BACKENDS` name.
    rtol : stop when the Newton decrement ``-g.d/2`` or the energy decrease is below
        ``rtol * |E|``.
    max_steps : iteration limit.
    regularization : relative diagonal shift added to the Hessian (it is singular for a free
        boundary: rotations); increased automatically when a factorization fails.
    line_search : :class:`~geomopt.linesearch.Backtracking`.
    """

    projection: str = "adaptive"
    exact_below: float = 1e-4
    linear_solver: str = "auto"
    rtol: float = 1e-10
    max_steps: int = 200
    regularization: float = 1e-9
    line_search: Backtracking = Backtracking(expand=3)

    def __post_init__(self):
        validate(self, projection=OneOf(("adaptive",) + PROJECTIONS), exact_below=Real(0.0),
                 linear_solver=OneOf(BACKENDS), rtol=Real(0.0, 1.0, hi_open=True),
                 max_steps=Int(1), regularization=Real(0.0, lo_open=True),
                 line_search=Instance(Backtracking))

    def init(self, objective, x0, params) -> State:
        x = jnp.asarray(x0)
        pat = objective.pattern
        chol = SparseCholesky(pat.indptr, pat.indices, self.linear_solver)
        chol.analyze()
        value, grad = objective.value_and_grad(x, params)
        # compile every kernel the loop uses now, so that setup time holds the compilation
        for projection in ("clamp", "none") if self.projection == "adaptive" else (self.projection,):
            objective.hessian(x, params, projection)
        self.line_search(objective, params, x, float(value), grad, jnp.zeros_like(x))
        aux = {"chol": chol, "cooldown": 0}
        return State(objective, params, x, float(value), grad, aux=aux)

    def _projection(self, state):
        if self.projection != "adaptive":
            return self.projection
        if state is None or state.aux["cooldown"] > 0 or not state.step_size >= 1.0:
            return "clamp"
        return "none" if state.decrement <= self.exact_below * abs(state.value) else "clamp"

    def _direction(self, state, projection, shifts):
        """Newton direction on the free DOFs with the first diagonal shift (relative to the mean
        diagonal) in ``shifts`` that factors; ``(value, grad, g, d, shift)``, d None on failure."""
        obj, pat, chol = state.objective, state.objective.pattern, state.aux["chol"]
        value, grad, data = obj.hessian(state.x, state.params, projection)
        data = np.array(data)
        g = np.asarray(grad).reshape(-1)[pat.free_dofs]
        scale = max(float(np.mean(np.abs(data[pat.diag]))), 1e-300)
        for shift in shifts:
            try:
                d_ = data.copy()
                d_[pat.diag] += shift * scale
                chol.factor(d_)
                return float(value), grad, g, -chol.solve(g), shift
            except NotPositiveDefinite:
                continue
        return float(value), grad, g, None, None

    def step(self, state: State) -> State:
        obj, params, x, pat = state.objective, state.params, state.x, state.objective.pattern
        projection = self._projection(state)
        aux = dict(state.aux, cooldown=max(state.aux["cooldown"] - 1, 0))
        reg = self.regularization
        if projection == "none":
            # Levenberg-Marquardt on the exact Hessian: the smallest shift that factors
            mu = max(aux.get("mu", reg), reg)
            value, grad, g, d_free, used = self._direction(state, "none", [mu, 1e2 * mu])
            exact = d_free is not None
            if not exact:
                aux["cooldown"], aux["mu"] = 2, 1e4 * mu
            else:
                aux["mu"] = used
        if projection != "none" or d_free is None:
            value, grad, g, d_free, _ = self._direction(
                state, "clamp" if projection == "none" else projection, [reg * 100**k for k in range(8)])
        if d_free is None or not np.isfinite(value):
            return dataclasses.replace(state, failure=Outcome.NONFINITE)
        dx = np.zeros(x.size)
        dx[pat.free_dofs] = d_free
        dx = jnp.asarray(dx.reshape(x.shape))
        decrement = 0.5 * float(-g @ d_free)
        t, xn, vn, _ = self.line_search(obj, params, x, value, grad, dx)
        it = state.iteration + 1
        if projection == "none" and exact:
            # trust-region-like damping: relax after a full (or longer) step, stiffen after a cut
            aux["mu"] = max(aux["mu"] / 10, reg) if t >= 1.0 else aux["mu"] * 10
        if t == 0.0:
            if decrement <= self.rtol * max(abs(value), 1e-300) * 100:
                # already at the minimum up to rounding
                return dataclasses.replace(state, iteration=it, decrement=decrement, step_size=0.0)
            return dataclasses.replace(state, iteration=it, failure=Outcome.LINE_SEARCH_FAILED,
                                       decrement=decrement, step_size=0.0)
        return dataclasses.replace(  # the next step's Hessian evaluation brings the gradient
            state, x=xn, value=vn, grad=None, iteration=it, step_size=t,
            decrement=decrement, prev_value=value, aux=aux,
        )

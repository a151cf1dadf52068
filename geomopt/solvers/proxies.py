"""Convex proxies of a density's element Hessian, derived generically from ``psi``.

Each proxy is a hashable object called as ``proxy(density, J, params) -> (d, d, d, d)``: a
PSD J-space block (index order ``[c, j, e, l]`` of ``d^2 psi / dJ[c, j] dJ[e, l]``), used by
:class:`~geomopt.solvers.Newton`-type solvers in place of the projected Hessian.

* :class:`SLIMProxy` — Rabinovich et al. 2017, "Scalable locally injective mappings": the
  reweighted proxy ``|W (J - R)|_F^2`` with ``W = U diag(w) U^T`` (``J = U S V^T``) and
  ``w_i^2 = (d psi / d sigma_i) / (2 (sigma_i - 1))`` (its limit ``psi_ii / 2`` at
  ``sigma_i = 1``), so the proxy's gradient equals the energy's: the global step is
  ``-H_proxy^-1 grad E``.  For symmetric Dirichlet this is the paper's closed form
  ``w_i^2 = (1 + sigma_i^-1 + sigma_i^-2 + sigma_i^-3)``.  Any rotation-invariant density works.
* :class:`CMProxy` — Shtengel et al. 2017, "Geometric optimization via composite
  majorization", 2D: ``psi(J) = h(alpha, beta)`` with ``alpha = |J_conformal|`` and
  ``beta = |J_anticonformal|`` (convex, ``sigma = alpha +- beta``); the block
  ``Dg^T [hess h]_+ Dg + sum_i max(h_i, 0) hess g_i`` is PSD and, where ``h`` is convex,
  majorizes the true Hessian (the terms with ``h_i < 0`` are concave and dropped).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .._eigh import eigh
from .._errors import ParameterError

__all__ = ["SLIMProxy", "CMProxy", "slim_weights", "svd2", "true_hessian_block"]


def _sv_density(density, params, d):
    """``sigma -> psi(diag(sigma))``: the density of a rotation-invariant energy on singular values."""
    return lambda s: density(jnp.diag(s) if d > 1 else s, params)


def svd2(J):
    """Closed-form SVD ``(U, sigma, Vt)`` of one 2x2 ``J``: ``sigma`` (2,) non-negative,
    descending, ``J = U diag(sigma) Vt`` with ``U``, ``Vt`` orthogonal (``U`` a reflection when
    ``det J < 0``).

    ``J = R(phi) diag(alpha + beta, alpha - beta) R(theta)`` with ``alpha``, ``beta`` the norms of
    J's conformal and anticonformal parts (rotations ``R``; e.g. Smith & Schaefer 2015).  The
    small singular value is ``|det J| / sigma_1`` (no cancellation for nearly degenerate J).
    Pure element-wise code: inside ``vmap`` on CPU it fuses into one loop, where
    ``jnp.linalg.svd`` calls LAPACK once per matrix (the SLIM proxy kernel took 3.8x longer
    with it on camelhead).  Not differentiated (the proxies use it for values only).
    """
    a, b, c, e = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    E, F, G, H = 0.5 * (a + e), 0.5 * (a - e), 0.5 * (c + b), 0.5 * (c - b)
    s1 = jnp.hypot(E, H) + jnp.hypot(F, G)
    det = a * e - b * c
    s2 = jnp.abs(det) / jnp.where(s1 > 0, s1, 1.0)
    a1, a2 = jnp.arctan2(G, F), jnp.arctan2(H, E)
    phi, theta = 0.5 * (a2 + a1), 0.5 * (a2 - a1)
    cp, sp_, ct, st = jnp.cos(phi), jnp.sin(phi), jnp.cos(theta), jnp.sin(theta)
    flip = jnp.where(det < 0, -1.0, 1.0)  # R(phi) diag(1, -1) for the unsigned sigma_2
    U = jnp.stack([jnp.stack([cp, -sp_ * flip]), jnp.stack([sp_, cp * flip])])
    Vt = jnp.stack([jnp.stack([ct, -st]), jnp.stack([st, ct])])
    return U, jnp.stack([s1, s2]), Vt


def slim_weights(density, J, params):
    """(d,) SLIM weights ``w_i^2`` and the SVD ``(U, sigma, Vt)`` of one Jacobian ``J`` (d, d)
    (closed form for d = 2: :func:`svd2`)."""
    d = J.shape[-1]
    U, s, Vt = svd2(J) if d == 2 else jnp.linalg.svd(J)
    f = _sv_density(density, params, d)
    g = jax.grad(f)(s)
    h = jnp.diagonal(jax.hessian(f)(s))
    near = jnp.abs(s - 1.0) < 1e-6
    w2 = jnp.where(near, 0.5 * h, g / (2.0 * jnp.where(near, 1.0, s - 1.0)))
    # a density decreasing away from sigma = 1 gives w^2 < 0: keep the proxy convex
    w2 = jnp.maximum(jnp.abs(w2), 1e-8)
    return w2, (U, s, Vt)


@dataclasses.dataclass(frozen=True)
class SLIMProxy:
    """SLIM's reweighted quadratic proxy (see the module notes)."""

    def __call__(self, density, J, params):
        d = J.shape[-1]
        w2, (U, _, _) = slim_weights(density, J, params)
        WtW = (U * w2[None, :]) @ U.T  # W^T W, acting on J's rows (target coordinates)
        return 2.0 * WtW[:, None, :, None] * jnp.eye(d, dtype=J.dtype)[None, :, None, :]


def _alpha_beta(J):
    """(alpha, beta) of a 2x2 J: norms of its conformal and anticonformal parts."""
    a, b, c, e = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    tiny = 1e-300
    alpha = 0.5 * jnp.sqrt((a + e) ** 2 + (c - b) ** 2 + tiny)
    beta = 0.5 * jnp.sqrt((a - e) ** 2 + (b + c) ** 2 + tiny)
    return jnp.stack([alpha, beta])


@dataclasses.dataclass(frozen=True)
class CMProxy:
    """Composite majorization (2D; see the module notes)."""

    def __call__(self, density, J, params):
        if J.shape[-1] != 2:
            raise ParameterError("CM (composite majorization) is defined for 2D problems (triangles); "
                                 "use newton, lbfgs or slim for tetrahedra")

        def h(ab):
            return density(jnp.diag(jnp.stack([ab[0] + ab[1], ab[0] - ab[1]])), params)

        ab = _alpha_beta(J)
        dh = jax.grad(h)(ab)
        Hh = jax.hessian(h)(ab)
        w, Q = eigh(Hh[None])
        Hh = ((Q[0] * jnp.maximum(w[0], 0.0)[None, :]) @ Q[0].T)
        Dg = jax.jacfwd(_alpha_beta)(J).reshape(2, 4)
        Hg = jax.hessian(_alpha_beta)(J).reshape(2, 4, 4)
        H = Dg.T @ Hh @ Dg + jnp.einsum("i,ipq->pq", jnp.maximum(dh, 0.0), Hg)
        return H.reshape(2, 2, 2, 2)


def true_hessian_block(density, J, params):
    """The unprojected J-space Hessian block (for tests and comparisons)."""
    return jax.hessian(density)(J, params)

"""Projections of the element Hessian: how a Newton-type solver makes each element's J-space
block positive semidefinite (or replaces it by a convex proxy).

Every projection is a hashable object (a static argument of the Hessian kernels) whose
:meth:`~AbstractProjection.block` maps the density, one Jacobian ``J`` (d, d), the energy
parameters and the element's rest volume to its ``(d*d, d*d)`` J-space block (index order
``[c, j, e, l]`` of ``d^2 psi / dJ[c, j] dJ[e, l]`` flattened):

* :class:`Clamp` -- eigenvalues clamped at a tiny relative floor (Teran et al. 2005);
* :class:`Abs` -- absolute eigenvalues (Chen et al. 2024, "Stabler Neo-Hookean simulation:
  absolute eigenvalue filtering for projected Newton");
* :class:`Exact` -- the unprojected Hessian (what the implicit function theorem needs; may be
  indefinite);
* :class:`SLIMProxy` -- Rabinovich et al. 2017, "Scalable locally injective mappings": the
  reweighted proxy ``|W (J - R)|_F^2`` with ``W = U diag(w) U^T`` (``J = U S V^T``) and
  ``w_i^2 = (d psi / d sigma_i) / (2 (sigma_i - 1))`` (its limit ``psi_ii / 2`` at
  ``sigma_i = 1``), so the proxy's gradient equals the energy's: the global step is
  ``-H_proxy^-1 grad E``.  For symmetric Dirichlet this is the paper's closed form
  ``w_i^2 = (1 + sigma_i^-1 + sigma_i^-2 + sigma_i^-3)``.  Any rotation-invariant density works;
* :class:`CMProxy` -- Shtengel et al. 2017, "Geometric optimization via composite
  majorization", 2D: ``psi(J) = h(alpha, beta)`` with ``alpha = |J_conformal|`` and
  ``beta = |J_anticonformal|`` (convex, ``sigma = alpha +- beta``); the block
  ``Dg^T [hess h]_+ Dg + sum_i max(h_i, 0) hess g_i`` is PSD and, where ``h`` is convex,
  majorizes the true Hessian (the terms with ``h_i < 0`` are concave and dropped).

:class:`Adaptive` is not a block but a rule choosing one per Newton iteration (clamp far from
the minimum, exact near it).  The names ``"clamp"``, ``"abs"``, ``"none"`` (``"exact"``) and
``"adaptive"`` are accepted wherever a projection is (:func:`as_projection`).

The three eigenvalue filters share one compiled Hessian kernel: :meth:`~AbstractProjection.kernel`
maps each to :class:`EigenFilter` and a traced code (:data:`FILTER_CODES`), so a Newton solve
that clamps far from the minimum and takes the exact Hessian near it (:class:`Adaptive`)
compiles one program, not two (the exact Hessian skips the eigendecomposition by a
``lax.cond`` on the code).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax import lax

from .._runtime.config import Real, validate
from ..linalg.eigh import eigh
from .._runtime.errors import ParameterError

__all__ = ["AbstractProjection", "Clamp", "Abs", "Exact", "SLIMProxy", "CMProxy", "Adaptive", "EigenFilter",
           "as_projection", "project_psd", "filter_eigenvalues", "svd2", "slim_weights", "true_hessian_block",
           "PROJECTION_NAMES", "FILTER_CODES"]

#: the eigenvalue filters as the traced code of :func:`filter_eigenvalues`
FILTER_CODES = {"clamp": 0, "abs": 1, "none": 2}


def project_psd(H, method):
    """Project symmetric blocks ``H`` (..., k, k) to PSD by their eigenvalues.

    ``clamp``: ``max(lambda, floor)`` with a tiny relative floor (Teran et al. 2005);
    ``abs``: ``max(|lambda|, floor)`` (Chen et al. 2024); ``none``: unchanged.
    PSD blocks are returned unchanged up to rounding and the floor.
    """
    if method not in FILTER_CODES:
        raise ParameterError(f"unknown PSD projection {method!r}; valid: 'clamp', 'abs', 'none'")
    return H if method == "none" else _filtered(H, FILTER_CODES[method])


def filter_eigenvalues(H, code):
    """:func:`project_psd` with the method as a traced int ``code`` (:data:`FILTER_CODES`),
    the same for every block: ``code == 2`` returns ``H`` without decomposing it."""
    return lax.cond(code == FILTER_CODES["none"], lambda H: H, lambda H: _filtered(H, code), H)


def _filtered(H, code):
    w, Q = eigh(H)
    floor = 1e-10 * jnp.max(jnp.abs(w), axis=-1, keepdims=True)
    w = jnp.maximum(jnp.where(code == FILTER_CODES["abs"], jnp.abs(w), w), floor)
    Qw = Q * w[..., None, :]
    # sum_l Qw[i, l] Q[j, l] as broadcast products: 1.3x faster on CPU than a batched matmul
    return sum(Qw[..., :, None, l] * Q[..., None, :, l] for l in range(Q.shape[-1]))


class AbstractProjection:
    """A rule for an element's J-space Hessian block (see the module notes).

    Subclasses are frozen dataclasses; ``psd`` says whether every block is PSD (a Newton step
    on it always factors after a diagonal shift), ``proxy`` whether it replaces the Hessian
    by a convex proxy (SLIM, CM) rather than filtering its eigenvalues."""

    psd = True
    proxy = False

    def block(self, density, J, params, vol, code=0):
        """(d*d, d*d) block ``vol * H`` of one element with Jacobian ``J`` (d, d); ``code`` is
        the traced argument of :meth:`kernel` (used by :class:`EigenFilter` only)."""
        d = J.shape[-1]
        return self(density, J, params).reshape(d * d, d * d) * vol

    def kernel(self) -> tuple:
        """``(projection, code)``: the static projection a compiled Hessian kernel is made for
        and the int it is called with; the eigenvalue filters share :class:`EigenFilter`."""
        return self, 0

    def __call__(self, density, J, params):
        """(d, d, d, d) block of one element, before the volume weight."""
        raise NotImplementedError

    def check_dim(self, d: int):
        """Raise ParameterError when the projection is not defined for d x d Jacobians."""

    def kernels(self) -> tuple:
        """The projections whose Hessian kernels a solve with this one runs."""
        return (self,)

    def select(self, stats, cooldown: int) -> "AbstractProjection":
        """The projection of the next Newton iteration (itself, except for :class:`Adaptive`)."""
        return self


@dataclasses.dataclass(frozen=True)
class _Eigen(AbstractProjection):
    """The density's Hessian with its eigenvalues filtered by ``method`` (:func:`project_psd`)."""

    method = "clamp"

    def block(self, density, J, params, vol, code=0):
        d = J.shape[-1]
        return project_psd(jax.hessian(density)(J, params).reshape(d * d, d * d) * vol, self.method)

    def __call__(self, density, J, params):
        d = J.shape[-1]
        return self.block(density, J, params, 1.0).reshape(d, d, d, d)

    def kernel(self) -> tuple:
        return EigenFilter(), FILTER_CODES[self.method]


@dataclasses.dataclass(frozen=True)
class EigenFilter(AbstractProjection):
    """The Hessian kernel's form of :class:`Clamp`, :class:`Abs` and :class:`Exact`: the
    filter is the traced ``code`` of :meth:`block` (:func:`filter_eigenvalues`)."""

    def block(self, density, J, params, vol, code=0):
        d = J.shape[-1]
        return filter_eigenvalues(jax.hessian(density)(J, params).reshape(d * d, d * d) * vol, code)

    def __call__(self, density, J, params):
        raise ParameterError("EigenFilter is the Hessian kernel's form of clamp/abs/exact; use those")


@dataclasses.dataclass(frozen=True)
class Clamp(_Eigen):
    """Negative eigenvalues clamped to a tiny relative floor (Teran et al. 2005)."""

    method = "clamp"


@dataclasses.dataclass(frozen=True)
class Abs(_Eigen):
    """Eigenvalues replaced by their absolute values (Chen et al. 2024)."""

    method = "abs"


@dataclasses.dataclass(frozen=True)
class Exact(_Eigen):
    """The unprojected Hessian (may be indefinite)."""

    method = "none"
    psd = False


@dataclasses.dataclass(frozen=True)
class Adaptive(AbstractProjection):
    """Clamp while far from the minimum; once a full step was accepted and the decrement is
    below ``exact_below * |E|``, the exact Hessian (Newton then converges quadratically at a
    strict minimum, where projected Newton converges only linearly: the projection changes the
    Hessian of elements that are indefinite there, and symmetric Dirichlet has many).  After
    an exact Hessian fails to factor, clamping resumes for the solver's cooldown."""

    exact_below: float = 1e-4

    def __post_init__(self):
        validate(self, exact_below=Real(0.0))

    def block(self, density, J, params, vol, code=0):
        raise ParameterError("Adaptive chooses a projection per iteration (select); it has no block")

    def kernels(self) -> tuple:
        return (Clamp(), Exact())

    def select(self, stats, cooldown: int) -> AbstractProjection:
        if cooldown > 0 or not stats.step_size >= 1.0:
            return Clamp()
        return Exact() if stats.decrement <= self.exact_below * abs(stats.value) else Clamp()


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
class SLIMProxy(AbstractProjection):
    """SLIM's reweighted quadratic proxy (Rabinovich et al. 2017; see the module notes)."""

    proxy = True

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
class CMProxy(AbstractProjection):
    """Composite majorization (Shtengel et al. 2017), 2D (see the module notes)."""

    proxy = True

    def check_dim(self, d):
        if d != 2:
            raise ParameterError("CM (composite majorization) is defined for 2D problems (triangles); "
                                 "use newton, lbfgs or slim for tetrahedra")

    def __call__(self, density, J, params):
        self.check_dim(J.shape[-1])

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


_NAMED = {"clamp": Clamp(), "abs": Abs(), "none": Exact(), "exact": Exact(), "adaptive": Adaptive()}
#: the names :func:`as_projection` accepts
PROJECTION_NAMES = tuple(_NAMED)


def as_projection(projection) -> AbstractProjection:
    """A projection object from a name (:data:`PROJECTION_NAMES`) or the object itself."""
    if isinstance(projection, AbstractProjection):
        return projection
    if isinstance(projection, str) and projection in _NAMED:
        return _NAMED[projection]
    raise ParameterError(f"unknown projection {projection!r}; valid: {', '.join(map(repr, PROJECTION_NAMES))} "
                         f"or a geomopt projection object (Clamp(), SLIMProxy()...)")

"""The sparse linear solve of a fairing method, differentiable in the operator's values, the
right-hand side and the held vertices.

``A p = b`` on the free vertices, the others held at ``x_held``: ``A_FF p_F = b_F - A_FH x_H``.
On concrete arrays it is assembled (:meth:`~geomopt.fairing.operators.Sparse.csr`) and solved
by a sparse Cholesky factorization (:func:`geomopt.linalg.linsolve.spd_solve`: PARDISO, CHOLMOD or
cholespy where installed) when the free block is symmetric (every method's is, up to rounding) and
positive definite, else by SciPy's sparse LU.  On JAX values it is a ``jax.custom_vjp``: the forward solve runs on the host
(a callback), and the backward pass is the implicit function theorem at the solution, one
solve with ``A_FF`` transposed: ``lam = A_FF^-T g_F`` and each input's cotangent is ``-lam``
pulled back through the residual ``r(theta) = (A(theta) p - b(theta))_F`` (a JAX ``vjp`` of the
matrix-free product, so any operator built from :mod:`~geomopt.fairing.operators` differentiates).
"""

from __future__ import annotations

import numpy as np

from .operators import xp_of

__all__ = ["linear_solve"]


#: relative asymmetry (largest ``|K - K^T|`` over largest ``|K|``) up to which a free block counts
#: as symmetric and goes to the Cholesky factorization: products such as ``A^T W A`` are symmetric
#: only up to rounding
SYMMETRY_TOLERANCE = 1e-12


def _is_symmetric(K):
    """Whether the sparse ``K`` (k, k) equals its transpose to :data:`SYMMETRY_TOLERANCE`."""
    if K.nnz == 0:
        return True
    gap = abs(K - K.T)
    return gap.nnz == 0 or gap.max() <= SYMMETRY_TOLERANCE * abs(K).max()


def _factored_solve(K, rhs):
    """``K^-1 rhs`` for the sparse ``K`` (k, k): Cholesky where it is symmetric positive
    definite, else LU."""
    from scipy.sparse.linalg import splu

    from ..linalg.linsolve import NotPositiveDefinite, spd_solve

    if _is_symmetric(K):
        try:
            return spd_solve(K, rhs)
        except NotPositiveDefinite:
            pass  # indefinite or singular to the factorization: LU decides
    return splu(K.tocsc()).solve(rhs)


def _host_solve(A, b, free, x_held, transpose=False):
    """NumPy: the solution (n, d) with the held rows ``x_held``; ``transpose`` solves
    ``A_FF^T lam_F = b_F`` with zero held rows instead."""
    K = A.csr()
    if transpose:
        K = K.T.tocsr()
    F, H = np.flatnonzero(free), np.flatnonzero(~free)
    b = np.asarray(b, dtype=np.float64)
    x = np.zeros_like(b) if transpose else np.array(x_held, dtype=np.float64)
    if len(F) == 0:
        return x
    rhs = b[F] - (0 if transpose or len(H) == 0 else K[F][:, H] @ x[H])
    x[F] = _factored_solve(K[F][:, F].tocsr(), np.ascontiguousarray(rhs))
    return x


def linear_solve(A, b, free, x_held):
    """``p`` (n, d): ``A p = b`` on the ``free`` (n,) bool rows, ``p = x_held`` (n, d) elsewhere.

    ``A`` is an operator of :mod:`geomopt.fairing.operators` whose free block is invertible.
    NumPy in, NumPy out (a direct sparse solve); JAX in, JAX out, differentiable (see the
    module notes)."""
    if xp_of(b, x_held, *A.leaves()) is np:
        return _host_solve(A, b, free, x_held)
    return _traced_solve(A, b, free, x_held)


def _traced_solve(A, b, free, x_held):
    import jax
    import jax.numpy as jnp

    from .._runtime.x64 import pure_callback

    free = np.asarray(free, bool)
    mask = jnp.asarray(free)[:, None]
    shape = jax.ShapeDtypeStruct(tuple(np.shape(b)), jnp.float64)

    def host(leaves, b, x_held, transpose=False):
        op, _ = A.rebuilt([np.asarray(v) for v in leaves])
        return _host_solve(op, np.asarray(b), free, np.asarray(x_held), transpose)

    @jax.custom_vjp
    def solve(leaves, b, x_held):
        return pure_callback(lambda lv, bb, xh: host(lv, bb, xh), shape, leaves, b, x_held)

    def forward(leaves, b, x_held):
        p = solve(leaves, b, x_held)
        return p, (leaves, b, x_held, p)

    def backward(saved, g):
        leaves, b, x_held, p = saved
        lam = pure_callback(lambda lv, gg: host(lv, gg, np.zeros(gg.shape), True), shape, leaves,
                            jnp.where(mask, g, 0.0))

        def residual(leaves, b, x_held):
            q = jnp.where(mask, jax.lax.stop_gradient(p), x_held)
            op, _ = A.rebuilt(leaves)
            return jnp.where(mask, op.matvec(q) - b, 0.0)

        _, pull = jax.vjp(residual, leaves, b, x_held)
        dl, db, dx = pull(-lam)
        return dl, db, dx + jnp.where(mask, 0.0, g)

    solve.defvjp(forward, backward)
    return solve([jnp.asarray(v) for v in A.leaves()], jnp.asarray(b), jnp.asarray(x_held))

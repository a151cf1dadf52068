"""Conjugate gradients on the host (NumPy), for sparse systems whose preconditioner is a
factorization held on the host: Newton's lagged factor (:class:`~geomopt.solvers.Newton`'s
``reuse_factor``) and the float64 refinement of a float32 factorization
(:class:`~geomopt.linalg.pardiso.Refined`).  The device version is
:func:`geomopt.objective.cg.pcg`."""

from __future__ import annotations

import numpy as np

__all__ = ["pcg", "symmetric_product"]


def symmetric_product(L):
    """``p -> A p`` for the symmetric ``A`` whose lower triangle (diagonal included) is the
    sparse matrix ``L``, without assembling ``A``."""
    LT, D = L.T, L.diagonal()

    def matvec(p):
        return L @ p + LT @ p - D * p

    return matvec


def pcg(matvec, b, precondition, rtol, maxiter):
    """Preconditioned conjugate gradients for ``A x = b`` on the host.

    Parameters
    ----------
    matvec : (n,) -> (n,) product with the symmetric matrix A.
    b : (n,) right-hand side.
    precondition : (n,) -> (n,) product with a symmetric positive-definite approximation of
        A^-1 (e.g. the solve of an earlier factorization).
    rtol : stop when ``|b - A x|_2 <= rtol |b|_2``.
    maxiter : iteration limit.

    Returns
    -------
    ``(x, iterations)``; ``x`` None when the limit is reached first or a search direction of
    non-positive curvature (A not positive definite) is met.
    """
    x = np.zeros_like(b)
    r = np.array(b, dtype=np.float64)
    bnorm = float(np.linalg.norm(r))
    if bnorm == 0.0:
        return x, 0
    z = np.asarray(precondition(r), np.float64)  # a float32 factor's solve too
    p, rz = z.copy(), float(r @ z)
    for k in range(1, maxiter + 1):
        Ap = matvec(p)
        curvature = float(p @ Ap)
        if not curvature > 0.0:
            return None, k
        alpha = rz / curvature
        x += alpha * p
        r -= alpha * Ap
        if float(np.linalg.norm(r)) <= rtol * bnorm:
            return x, k
        z = np.asarray(precondition(r), np.float64)
        rz, rz_old = float(r @ z), rz
        p *= rz / rz_old
        p += z
    return None, maxiter

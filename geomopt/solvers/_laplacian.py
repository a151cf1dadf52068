"""The rest Dirichlet Laplacian ``K`` of a problem, factored once: L-BFGS's Sobolev seed and
AQP's proxy (Kovalsky et al. 2016).  Applied on the host (``jax.pure_callback`` from jitted
code, by an integer handle)."""

from __future__ import annotations

import itertools
import weakref

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .._objective import Objective
from ..linsolve import SparseCholesky


_LIVE_PRECONDITIONERS: "weakref.WeakValueDictionary[int, RestLaplacian]" = \
    weakref.WeakValueDictionary()
_NEXT_HANDLE = itertools.count()


def laplacian_solve_host(handle, q):
    """Host side of the preconditioner (``jax.pure_callback``): ``K^-1 q`` on the free DOFs."""
    return _LIVE_PRECONDITIONERS[int(handle)].solve(np.asarray(q))


class RestLaplacian:
    """``K^-1`` for the rest Dirichlet Hessian ``K`` of an objective's problem on its free DOFs,
    assembled by :class:`~geomopt.Objective` and factored by
    :class:`~geomopt.linsolve.SparseCholesky`.

    The Dirichlet Hessian is ``K (x) I_d``: when every vertex is free or fixed as a whole,
    one coordinate's block is factored and applied to each coordinate (d times smaller).
    Jitted kernels refer to it by an integer handle (traced, so new meshes or solves never
    recompile); it lives as long as a solver state holds it."""

    def __init__(self, objective):
        problem, d = objective.problem, objective.problem.dim
        dobj = Objective(problem, "dirichlet")
        pat = dobj.pattern
        H = pat.matrix(np.asarray(dobj.hessian(jnp.asarray(problem.rest_vertices[:, :d] * 0.0), {}, "none")[2]))
        dofs = pat.free_dofs
        free = np.asarray(objective.free_dofs, bool)
        self.per_vertex = bool(np.all(free.all(axis=1) | ~free.any(axis=1)))
        if self.per_vertex:
            sel = np.flatnonzero(dofs % d == 0)
            H, self.rows = H[sel][:, sel], dofs[sel] // d
        else:
            self.rows = dofs
        n = H.shape[0]
        if n:
            # a tiny shift keeps it definite when a component has no fixed vertex
            H = (H + sp.identity(n) * (1e-12 * max(float(H.diagonal().mean()), 1e-300))).tocsc()
            L = sp.tril(H).tocsc()
            L.sort_indices()
            self._chol = SparseCholesky(L.indptr, L.indices)
            self._chol.factor(L.data)
        self.d = d

    def solve(self, q):
        out = np.zeros_like(q)
        if self.rows.size == 0:
            return out
        if self.per_vertex:
            out[self.rows] = np.stack([self._chol.solve(np.ascontiguousarray(q[self.rows, c]))
                                       for c in range(self.d)], axis=1)
        else:
            flat = out.reshape(-1)
            flat[self.rows] = self._chol.solve(q.reshape(-1)[self.rows])
        return out

    @classmethod
    def register(cls, objective):
        pre = cls(objective)
        pre.handle = next(_NEXT_HANDLE) % (2**31 - 1)
        _LIVE_PRECONDITIONERS[pre.handle] = pre
        return pre

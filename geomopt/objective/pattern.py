"""The sparsity pattern of an objective's Hessian: which vertex blocks exist (one d x d block
per pair of vertices sharing an element) and where each element's blocks land in the CSC data
of the free-DOF lower triangle; computed once per mesh from the vertex graph."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.sparse as sp

from ..mesh.problem import Problem

__all__ = ["HessianPattern", "hessian_pattern", "vertex_graph", "block_pairs", "local_pairs", "index_dtype"]


def local_pairs(d):
    """The element-local DOF pairs ``p <= q`` (DOF p = vertex a, coordinate c: p = a*d + c):
    the element Hessian is symmetric, so only these are lifted and assembled."""
    k = (d + 1) * d
    p, q = np.triu_indices(k)
    return p, q


def block_pairs(d):
    """The element-local vertex pairs ``a <= b`` ((d+1)(d+2)/2 of them, row-major upper
    triangle): the d x d blocks of the element Hessian that are assembled."""
    return np.triu_indices(d + 1)


@dataclasses.dataclass(frozen=True, eq=False)
class HessianPattern:
    """CSC pattern of the lower triangle of the Hessian restricted to free DOFs
    (vertex-major numbering: dof = v*d + c).  Sparse Cholesky backends read only the lower
    triangle; :meth:`matrix` gives the full symmetric matrix.

    The Hessian is assembled per *vertex block*: for every pair of vertices ``w <= v`` that
    share an element (the vertex graph, diagonal included), the d x d block ``H[v-dofs,
    w-dofs]``; the CSC data are then gathered from the blocks.

    Attributes
    ----------
    n : number of free DOFs.
    indptr : (n+1,);  indices : (nnz,), row indices sorted per column; int32 (int64 from 2^31
        entries, :func:`index_dtype`): SciPy then takes them as they are (it converts int64
        indices that fit to int32 copies at every matrix built on them).
    free_dofs : (n,) global dof ids of the free DOFs.
    diag : (n,) data positions of the diagonal (one per free DOF used by an element).
    dim : d.
    vertex_ptr, vertex_idx : (n_vertices+1,), (n_blocks,) int64: the vertex graph in CSC
        lower-triangle form (column vertex w: sorted row vertices v >= w, w itself first).
    blocks : (m, (d+1)(d+2)/2) int32, the vertex block of each element block pair
        ``a <= b`` (:func:`block_pairs`).
    swap : (m, (d+1)(d+2)/2) bool, True where the stored block ``H[v-dofs, w-dofs]`` is the
        element block ``(b, a)`` (``S[a] < S[b]``), False where it is ``(a, b)``.
    gather : (nnz,) int32 (int64 from 2^31 block entries, :func:`index_dtype`), position in
        the block data (n_blocks, d, d) flattened of each CSC entry.
    """

    n: int
    indptr: np.ndarray
    indices: np.ndarray
    free_dofs: np.ndarray
    diag: np.ndarray
    dim: int
    vertex_ptr: np.ndarray
    vertex_idx: np.ndarray
    blocks: np.ndarray
    swap: np.ndarray
    gather: np.ndarray

    @property
    def nnz(self) -> int:
        return len(self.indices)

    @property
    def n_blocks(self) -> int:
        return len(self.vertex_idx)

    @functools.cached_property
    def slots(self) -> np.ndarray:
        """(m*P,) data position of each element DOF pair ``p <= q`` (:func:`local_pairs`),
        ``nnz`` where a DOF is fixed: the scalar form of :attr:`blocks` (computed on first use)."""
        d = self.dim
        p, q = local_pairs(d)
        a, c, b, e = p // d, p % d, q // d, q % d
        bi, bj = block_pairs(d)
        which = np.zeros((d + 1, d + 1), np.int64)
        which[bi, bj] = np.arange(len(bi))
        k = self.blocks[:, which[a, b]].astype(np.int64)  # (m, P); a <= b
        # the stored block is H[v-dofs, w-dofs], v > w: its row coordinate is the one on v
        swap = self.swap[:, which[a, b]]
        rc = np.where(a == b, np.maximum(c, e), np.where(swap, e, c))
        cc = np.where(a == b, np.minimum(c, e), np.where(swap, c, e))
        inverse = np.full(self.n_blocks * d * d, self.nnz, np.int64)
        inverse[self.gather] = np.arange(self.nnz)
        return inverse[(k * d + rc) * d + cc].reshape(-1)

    def lower(self, data) -> sp.csc_matrix:
        return sp.csc_matrix((np.asarray(data), self.indices, self.indptr), shape=(self.n, self.n))

    def matrix(self, data) -> sp.csc_matrix:
        L = self.lower(data)
        return (L + L.T - sp.diags(L.diagonal())).tocsc()


def index_dtype(size):
    """int32 for indices into arrays of ``size`` entries when they fit, else int64: the
    assembly maps are the largest arrays a Newton step keeps beside the factor."""
    return np.int32 if size < np.iinfo(np.int32).max else np.int64


def vertex_graph(simplices, n_vertices):
    """The vertex graph of a mesh in CSC lower-triangle form, diagonal included.

    Parameters
    ----------
    simplices : (m, d+1) int vertex ids.
    n_vertices : int.

    Returns
    -------
    ptr : (n_vertices+1,) int64;  idx : (n_blocks,) int64, for each vertex w the sorted
        vertices v >= w sharing an element with it (w itself first when it is used).

    Built by SciPy's COO to CSR conversion (a counting sort by row, then a sort within the
    short rows): O(m), no global sort.
    """
    S = np.asarray(simplices)
    a, b = np.triu_indices(S.shape[1], 1)
    u, v = S[:, a].ravel(), S[:, b].ravel()
    used = np.flatnonzero(np.bincount(S.ravel(), minlength=n_vertices))
    rows = np.concatenate([np.minimum(u, v), used])
    cols = np.concatenate([np.maximum(u, v), used])
    A = sp.csr_matrix((np.ones(len(rows), np.int32), (rows, cols)), shape=(n_vertices, n_vertices))
    A.sum_duplicates()  # canonical: sorted column indices, no duplicates
    return A.indptr.astype(np.int64), A.indices.astype(np.int64)


def hessian_pattern(problem: Problem, free_dofs) -> HessianPattern:
    """The pattern for ``free_dofs`` (n_vertices, d) bool, from the vertex graph.

    Each vertex block of the graph is expanded to its d x d DOF entries in CSC order by
    arithmetic (no sort), the entries of fixed DOFs and the upper half of diagonal blocks are
    dropped, and each off-diagonal element block is located in its row of the graph (SciPy's
    CSR lookup).  O(m) memory and time beyond SciPy's conversions."""
    d = problem.dim
    S = problem.simplices
    nv = problem.n_vertices
    free = np.asarray(free_dofs, bool).reshape(-1)
    red = np.full(nv * d, -1, np.int64)
    red[free] = np.arange(free.sum())
    n = int(free.sum())
    ptr, idx = vertex_graph(S, nv)
    deg = np.diff(ptr)
    # candidate entries in CSC order, generated sequentially: DOF column (w, e) holds, for
    # each block k of vertex column w (rows idx[k] >= w) and each coordinate c, the row
    # (idx[k], c); drop the fixed DOFs and the upper half of the diagonal blocks
    seglen = np.repeat(deg * d, d)  # candidates per DOF column w*d+e
    it = index_dtype(max(d * d * len(idx), nv * d))  # int32 below 2^31 entries: half the scratch
    col = np.repeat(np.arange(nv * d, dtype=it), seglen)
    j = np.arange(len(col), dtype=it) - np.repeat((np.cumsum(seglen) - seglen).astype(it), seglen)
    w, e = np.divmod(col, it(d))
    k, c = np.divmod(j, it(d))
    del j
    k += ptr[w].astype(it)
    v = idx[k].astype(it)
    row = v * it(d) + c
    keep = ((v > w) | (c >= e)) & free[row] & free[col]
    del v, w
    indices = red[row[keep]]
    del row
    cols = red[col[keep]]
    del col
    ct = index_dtype(max(len(indices), n + 1))
    indptr = np.zeros(n + 1, ct)
    np.cumsum(np.bincount(cols, minlength=n), out=indptr[1:])
    diag = np.flatnonzero(indices == cols)
    del cols
    indices = indices.astype(ct, copy=False)
    gather = ((k * it(d) + c) * it(d) + e)[keep]  # position (k, c, e) in the block data
    del k, c, e, keep
    # element blocks: the diagonal ones lead their vertex's row; locate the others
    bi, bj = block_pairs(d)
    sa, sb = S[:, bi], S[:, bj]
    blocks = ptr[sa]
    off = bi != bj
    lookup = sp.csr_matrix((np.arange(len(idx)), idx, ptr), shape=(nv, nv))
    lo, hi = np.minimum(sa[:, off], sb[:, off]), np.maximum(sa[:, off], sb[:, off])
    blocks[:, off] = np.asarray(lookup[lo.ravel(), hi.ravel()]).reshape(lo.shape)
    return HessianPattern(n, indptr, indices, np.flatnonzero(free), diag, d, ptr, idx,
                          blocks.astype(np.int32), sa < sb, gather)

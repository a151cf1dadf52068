"""Laplacians and mass matrices of triangle surfaces and polylines, as sparse operators that
act both on NumPy arrays (assembled for SciPy's sparse solvers) and on JAX arrays (matrix-free,
differentiable in their values).

Conventions: ``L`` is the *negative semi-definite* stiffness matrix, ``(L p)_i = sum_j w_ij
(p_j - p_i)`` with one weight per edge; ``M`` is the lumped (diagonal) mass matrix.

- Triangles: uniform weights ``w_ij = 1``; cotangent weights ``w_ij = (cot a_ij + cot b_ij) / 2``
  (Pinkall & Polthier 1993; Meyer et al. 2003), the angles opposite the edge, each **clamped**
  to ``[0, COT_MAX]``.  Clamping makes every weight non-negative, so a Laplacian step moves a
  vertex towards a convex combination of its neighbours (a discrete maximum principle: no
  overshoot across obtuse triangles, where the plain cotangent weight is negative), and keeps
  weights finite on slivers (a cotangent grows like 1 / angle).  We chose it over the intrinsic
  Delaunay Laplacian (Bobenko & Springborn 2007; Sharp, Soliman & Crane 2019), which also has
  non-negative weights and is consistent, because that one needs intrinsic edge flips: a
  combinatorial step through which the weights are not differentiable in the vertices, and
  another triangulation to carry.  Mass: a third of the incident triangles' areas (barycentric).
- Polylines: uniform weights 1, or the 1D cotangent analogue ``w_e = 1 / |e|`` (the linear
  finite-element stiffness); mass: half the incident edges' lengths.

Every function of vertex positions here takes NumPy or JAX arrays and computes with the same
library (``xp``), so the JAX form is differentiable (the double-``where`` guards keep degenerate
elements from producing NaN gradients).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._runtime.errors import MeshError
from ..exact.topology import unique_pairs

__all__ = ["any_column", "Topology", "Sparse", "Diag", "Sum", "Product", "edge_weights", "masses", "mean_edge_length", "xp_of",
           "COT_MAX", "LAPLACIANS"]

#: the largest cotangent kept (an angle of about 0.57 degrees): slivers get finite weights
COT_MAX = 100.0
LAPLACIANS = ("uniform", "cotangent")


def xp_of(*arrays):
    """``jax.numpy`` when an argument is a JAX array (or tracer), else ``numpy``."""
    import sys

    if "jax" in sys.modules:
        import jax

        if any(isinstance(a, jax.Array) for a in arrays):
            import jax.numpy as jnp

            return jnp
    return np


def segment_sum(xp, values, ids, n):
    """``out[i] = sum of values[k] over ids[k] == i`` (n, ...)."""
    if xp is np:  # a bincount per column: an order of magnitude faster than np.add.at
        values = np.asarray(values, dtype=np.float64)
        if values.ndim == 1:
            return np.bincount(ids, weights=values, minlength=n)
        flat = values.reshape(len(values), -1)
        out = np.stack([np.bincount(ids, weights=flat[:, c], minlength=n) for c in range(flat.shape[1])], axis=1)
        return out.reshape((n,) + values.shape[1:])
    import jax

    return jax.ops.segment_sum(values, ids, num_segments=n)


def any_column(a):
    """(m,) bool: the rows of ``a`` (m, k) with a true (or nonzero) entry: ``a.any(axis=1)``
    by ``k`` column ORs, several times faster for the two or three columns of elements and
    coordinates (NumPy's row reduction is slow on short rows)."""
    a = np.asarray(a)
    out = a[:, 0].astype(bool)
    for c in range(1, a.shape[1]):
        out |= a[:, c].astype(bool, copy=False)
    return out


@dataclasses.dataclass(frozen=True)
class Topology:
    """The connectivity of a triangle surface or a polyline (NumPy, concrete).

    Attributes
    ----------
    elements : (m, 3) triangles or (m, 2) edges, int64.
    n : vertex count.
    edges : (E, 2) unique edges, each sorted.
    element_edges : (m, 3) for triangles: the edge opposite each corner (index into ``edges``);
        (m, 1) for polylines (the element itself).
    boundary : (b,) sorted boundary vertices (the ends of open polylines).
    """

    elements: np.ndarray
    n: int
    edges: np.ndarray
    element_edges: np.ndarray
    boundary: np.ndarray

    @property
    def is_curve(self) -> bool:
        return self.elements.shape[1] == 2

    @classmethod
    def of(cls, S, n) -> "Topology":
        S = np.asarray(S, dtype=np.int64)
        if S.shape[1] == 2:
            edges, inverse, _ = unique_pairs(S, n)
            degree = np.bincount(S.ravel(), minlength=n)
            return cls(S, n, edges, inverse.reshape(-1, 1), np.flatnonzero(degree == 1))
        opposite = np.stack([S[:, [1, 2]], S[:, [2, 0]], S[:, [0, 1]]], axis=1).reshape(-1, 2)
        edges, inverse, counts = unique_pairs(opposite, n)
        if counts.max(initial=0) > 2:
            raise MeshError(f"an edge is shared by {counts.max()} triangles: the surface must be edge-manifold")
        return cls(S, n, edges, inverse.reshape(-1, 3), np.unique(edges[counts == 1]))

    def free_mask(self, boundary: str) -> np.ndarray:
        """(n,) bool: the vertices a method moves (all but the boundary when ``boundary`` is
        ``"fixed"``; vertices in no element never move)."""
        free = np.zeros(self.n, bool)
        free[self.elements] = True
        if boundary == "fixed":
            free[self.boundary] = False
        return free


def _norm(xp, v):
    """|v| along the last axis with a zero-safe gradient (double where)."""
    sq = xp.sum(v * v, axis=-1)
    safe = xp.where(sq > 0, sq, 1.0)
    return xp.where(sq > 0, xp.sqrt(safe), 0.0)


def mean_edge_length(V, topo: Topology):
    """The mean length of the unique edges: a float for NumPy ``V``, a (differentiable) JAX
    scalar for JAX ``V``; 1 without edges."""
    xp = xp_of(V)
    e = topo.edges
    if len(e) == 0:
        return 1.0
    if xp is np:  # coordinate rows gathered one-dimensionally: the same floats as the row form below
        Vt, et = np.ascontiguousarray(np.asarray(V).T), np.ascontiguousarray(e.T)
        d = [x.take(et[1]) - x.take(et[0]) for x in Vt]
        squared = d[0] * d[0]
        for c in range(1, len(d)):
            squared += d[c] * d[c]
        return float(np.mean(np.where(squared > 0, np.sqrt(squared), 0.0)))
    return xp.mean(_norm(xp, V[e[:, 1]] - V[e[:, 0]]))


def edge_weights(V, topo: Topology, laplacian: str):
    """(E,) the weight of each unique edge (see the module notes), NumPy or JAX like ``V``."""
    xp = xp_of(V)
    E = len(topo.edges)
    if laplacian == "uniform":
        return xp.ones(E)
    S = topo.elements
    if topo.is_curve:
        length = _norm(xp, V[S[:, 1]] - V[S[:, 0]])
        tiny = 1e-12 * xp.maximum(xp.max(length), 1e-300)
        return segment_sum(xp, 1.0 / xp.maximum(length, tiny), topo.element_edges[:, 0], E)
    cots = []
    for k in range(3):
        u, v = V[S[:, (k + 1) % 3]] - V[S[:, k]], V[S[:, (k + 2) % 3]] - V[S[:, k]]
        dot, cross = xp.sum(u * v, axis=-1), _norm(xp, xp.cross(u, v))
        scale = xp.sum(u * u, axis=-1) + xp.sum(v * v, axis=-1)
        ok = cross > 1e-12 * scale
        cot = xp.where(ok, dot / xp.where(ok, cross, 1.0), COT_MAX)
        cots.append(0.5 * xp.clip(cot, 0.0, COT_MAX))
    return segment_sum(xp, xp.stack(cots, axis=1).reshape(-1), topo.element_edges.reshape(-1), E)


def masses(V, topo: Topology):
    """(n,) lumped masses: a third of the incident triangles' areas, or half of the incident
    edges' lengths; NumPy or JAX like ``V``."""
    xp = xp_of(V)
    S = topo.elements
    if topo.is_curve:
        size = _norm(xp, V[S[:, 1]] - V[S[:, 0]]) / 2.0
    else:
        size = _norm(xp, xp.cross(V[S[:, 1]] - V[S[:, 0]], V[S[:, 2]] - V[S[:, 0]])) / 6.0
    k = S.shape[1]
    return segment_sum(xp, xp.repeat(size, k), S.reshape(-1), topo.n)


# -- a small algebra of sparse operators: matrix-free on any array library, assembled for SciPy --

@dataclasses.dataclass(frozen=True)
class Sparse:
    """``A[rows[k], cols[k]] += vals[k]`` (n, n); ``vals`` NumPy or JAX."""

    rows: np.ndarray
    cols: np.ndarray
    vals: object
    n: int

    @classmethod
    def laplacian(cls, topo: Topology, w) -> "Sparse":
        """The stiffness matrix ``L`` of edge weights ``w`` (E,) (see the module notes)."""
        xp = xp_of(w)
        i, j = topo.edges[:, 0], topo.edges[:, 1]
        diag = -segment_sum(xp, xp.concatenate([w, w]), np.concatenate([i, j]), topo.n)
        idx = np.arange(topo.n)
        return cls(np.concatenate([i, j, idx]), np.concatenate([j, i, idx]), xp.concatenate([w, w, diag]), topo.n)

    def matvec(self, x):
        xp = xp_of(self.vals, x)
        return segment_sum(xp, self.vals[:, None] * x[self.cols], self.rows, self.n)

    @property
    def T(self):
        return Sparse(self.cols, self.rows, self.vals, self.n)

    def csr(self):
        import scipy.sparse as sp

        return sp.csr_matrix((np.asarray(self.vals, dtype=np.float64), (self.rows, self.cols)), shape=(self.n, self.n))

    def leaves(self):
        return [self.vals]

    def rebuilt(self, leaves):
        return dataclasses.replace(self, vals=leaves[0]), leaves[1:]


@dataclasses.dataclass(frozen=True)
class Diag:
    """``diag(d)``."""

    d: object

    def matvec(self, x):
        return self.d[:, None] * x

    @property
    def T(self):
        return self

    def csr(self):
        import scipy.sparse as sp

        return sp.diags(np.asarray(self.d, dtype=np.float64)).tocsr()

    def leaves(self):
        return [self.d]

    def rebuilt(self, leaves):
        return Diag(leaves[0]), leaves[1:]


@dataclasses.dataclass(frozen=True)
class Sum:
    """``a + b``."""

    a: object
    b: object

    def matvec(self, x):
        return self.a.matvec(x) + self.b.matvec(x)

    @property
    def T(self):
        return Sum(self.a.T, self.b.T)

    def csr(self):
        return (self.a.csr() + self.b.csr()).tocsr()

    def leaves(self):
        return self.a.leaves() + self.b.leaves()

    def rebuilt(self, leaves):
        a, leaves = self.a.rebuilt(leaves)
        b, leaves = self.b.rebuilt(leaves)
        return Sum(a, b), leaves


@dataclasses.dataclass(frozen=True)
class Product(Sum):
    """``a @ b``."""

    def matvec(self, x):
        return self.a.matvec(self.b.matvec(x))

    @property
    def T(self):
        return Product(self.b.T, self.a.T)

    def csr(self):
        return (self.a.csr() @ self.b.csr()).tocsr()

    def rebuilt(self, leaves):
        a, leaves = self.a.rebuilt(leaves)
        b, leaves = self.b.rebuilt(leaves)
        return Product(a, b), leaves

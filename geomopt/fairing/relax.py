"""Tangential relaxation: better triangle shapes with every vertex kept on the input surface.

Each of ``steps`` rounds moves every free vertex by ``lam`` times the tangential part of its
uniform Laplacian (the offset to its neighbours' centroid less its component along the vertex
normal), then projects it back onto the *input* surface (its closest point there,
:func:`geomopt.fairing.surface.closest_points`), so that the vertices never leave it.  Boundary
vertices and those on creases (``crease_angle``) are held, so boundaries and sharp edges stay
where they are.  A vertex whose move would fold a face is not moved that round
(:func:`geomopt.fairing.certificate.safe_step` with whole steps: a fraction of a move between two
surface points would leave the surface).  After Botsch & Kobbelt, "A remeshing approach to
multiresolution modeling", 2004 (tangential smoothing with back-projection).

Host only (NumPy): the projection is piecewise, so this method is not differentiable.
"""

from __future__ import annotations

import numpy as np

from .certificate import safe_step
from .methods import crease_vertices, normalized_laplacian
from .operators import any_column
from .surface import closest_points, face_distances, surface_index

__all__ = ["relax"]


def _vertex_normals(X, F, n):
    """(n, 3) area-weighted vertex normals, unit length (0 where undefined)."""
    fn = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    N = np.zeros((n, 3))
    for k in range(3):
        np.add.at(N, F[:, k], fn)
    length = np.linalg.norm(N, axis=1, keepdims=True)
    return np.where(length > 0, N / np.where(length > 0, length, 1.0), 0.0)


def _flat(V, F, n, tol):
    """(n,) bool: vertices whose input neighbours lie within ``tol`` of the plane through the
    vertex along its normal; the others cannot move without a face leaving the surface by more
    than about ``tol``, and are held (the check of each move's faces stays)."""
    import scipy.sparse as sp

    N = _vertex_normals(V, F, n)
    ring = sp.csr_matrix((np.ones(3 * F.size), (np.repeat(F, 3, axis=1).ravel(), np.tile(F, 3).ravel())), shape=(n, n))
    ring = ring.tocoo()
    off = np.abs(np.sum(N[ring.row] * (V[ring.col] - V[ring.row]), axis=1))
    worst = np.zeros(n)
    np.maximum.at(worst, ring.row, off)
    return (worst <= tol) & (np.linalg.norm(N, axis=1) > 0)


def relax(V, topo, free, o):
    """``(X, moved)``: the relaxed vertices (n, 3), each on the surface ``V, topo.elements``, and
    how many vertex moves were taken over all rounds (see the module notes)."""
    V = np.asarray(V, dtype=np.float64)
    F = topo.elements
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    free = free & ~crease_vertices(V, topo, o.crease_angle) & _flat(V, F, topo.n, o.surface_tolerance * diag)
    X, moved, index = V.copy(), 0, surface_index(V, F)
    for _ in range(o.steps):
        A, _ = normalized_laplacian(X, topo, "uniform")
        d = A.matvec(X)
        N = _vertex_normals(X, F, topo.n)
        d = d - np.sum(d * N, axis=1, keepdims=True) * N
        target = X.copy()
        idx = np.flatnonzero(free)
        if len(idx) == 0:
            break
        target[idx] = closest_points(X[idx] + o.lam * d[idx], V, F, index=index)[0]
        X, t = _close_step(X, target, V, F, free, o.surface_tolerance * diag, index)
        moved += int(np.count_nonzero(t))
    return X, moved


def _close_step(X, target, V, F, free, tol, index):
    """``(Y, t)``: :func:`safe_step` from ``X`` towards ``target`` in whole vertex moves, with the
    moves undone of every vertex of a new face farther than ``tol`` from the surface ``V, F``
    (then the step retaken, until no face is; only faces with a vertex changed since the last
    check are measured again)."""
    target, last = target.copy(), X
    while True:
        Y, t = safe_step(X, target, F, free, halvings=1)  # each vertex all the way or not at all
        changed = np.flatnonzero(any_column(Y != last))
        if len(changed) == 0:
            return Y, t
        near = np.flatnonzero(np.isin(F, changed).any(axis=1))
        far = near[face_distances(Y, F[near], V, F, index=index, enough=tol) > tol]
        if len(far) == 0:
            return Y, t
        undo = np.intersect1d(np.unique(F[far]), np.flatnonzero(t > 0))
        target[undo] = X[undo]
        last = Y

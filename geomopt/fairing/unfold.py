"""Fold removal: the folded faces of a surface unfolded by local smoothing of a growing
neighbourhood, kept only where it folds fewer faces (a monotone count, as untangling's).

The fold-safe step (:func:`geomopt.fairing.certificate.safe_step`) never lets a corner fail that
did not fail before; on densely folded input (heavy noise) that stalls, because a fold is often
undone only by letting a neighbouring corner fail for a while.  Here each round

1. takes the *region*: the free vertices within ``r`` rings of a folded face;
2. smooths it with ``3 r`` Jacobi steps of the uniform Laplacian, ``p <- p + (c - p) / 2``
   (``c`` the neighbours' centroid; the other vertices held);
3. keeps, per connected part of the region, the smoothed positions where fewer faces within
   two rings of that part are folded than before (exact signs,
   :func:`geomopt.exact.normals.corner_signs`), provided the whole surface then has fewer folded
   faces; failing that the whole smoothed region when it has fewer; failing that nothing.

``r`` drops by one after a round that kept something and grows by one after one that did not;
removal stops when no face is folded, ``r`` exceeds :data:`MAX_RINGS`, or after ``max_rounds``.
The count of folded faces strictly falls with every kept round, so it ends, and the output
never has more folded faces than the start.  It is the count that is monotone, not the set (as
in untangling): a face unfolded at the start may end folded while many others unfold.
(Keeping the set monotone as well, as the fold-safe step does, stalls on dense folds.)
:func:`geomopt.fairing.fair` reports such faces (``FairDetails.folds_added``).

The smoothing is the one the lectures start from (uniform Laplacian: it pulls a vertex into
its neighbours' convex hull, which unfolds the star when that hull is convex), in the spirit of
Laplacian-based untangling (Freitag & Plassmann, "Local optimization-based simplicial mesh
untangling and improvement", 2000, start from it too).
"""

from __future__ import annotations

import numpy as np

from .certificate import certify_folds, local_signs
from .operators import any_column

__all__ = ["remove_folds", "MAX_RINGS", "MAX_ROUNDS"]

#: the largest neighbourhood (rings around the folded faces) a round smooths
MAX_RINGS = 16
#: rounds before removal gives up
MAX_ROUNDS = 200


def _averaging(topo):
    """The uniform averaging operator (n, n) CSR: row ``i`` the mean over ``i``'s neighbours."""
    import scipy.sparse as sp

    e, n = topo.edges, topo.n
    W = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    degree = np.asarray(W.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.where(degree > 0, degree, 1.0)) @ W


def _grow(mask, A, rings):
    """``mask`` (n,) bool grown by ``rings`` rings through the edges (the pattern of ``A``, the
    averaging operator: in a triangle surface or a polyline, vertices share an element exactly
    when they share an edge)."""
    mask = mask.copy()
    for _ in range(rings):
        mask |= (A @ mask.astype(np.float64)) > 0
    return mask


def _folded_mask(X, S):
    """(m,) bool: the folded faces of ``X``."""
    out = np.zeros(len(S), bool)
    out[certify_folds(X, S).folded] = True
    return out


def _refolded(Y, S, folded, moved, A):
    """(m,) bool: the folded faces of ``Y``, which differs from the vertices whose folded faces
    are ``folded`` only on ``moved`` (n,) bool: the signs of a face change only when a corner lies
    within one ring of a moved vertex, and those are taken again (exactly, on the faces around
    their corners), the rest kept."""
    affected = any_column(_grow(moved, A, 1)[S])
    corners = np.zeros(len(moved), bool)
    corners[S[affected].ravel()] = True
    sub = any_column(corners[S])  # every face around a corner of an affected face
    out = folded.copy()
    out[affected] = any_column(local_signs(Y, S[sub])[affected[sub]] <= 0)
    return out


def _partwise(X, Y, S, topo, region, folded_x, folded_y):
    """``X`` with the smoothed ``Y`` taken on each connected part of ``region`` that folds fewer
    faces within two rings of it (see the module notes)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    e = topo.edges[region[topo.edges[:, 0]] & region[topo.edges[:, 1]]]
    graph = csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(topo.n, topo.n))
    _, label = connected_components(graph, directed=False)
    label = np.where(region, label, -1)
    owner = np.full(topo.n, -1)
    owner[region] = label[region]
    for _ in range(2):  # spread each part's label two rings out; a vertex reached by two parts: -2
        spread = owner.copy()
        c = S.shape[1]
        T = S[any_column(owner[S] >= 0)]  # (the elements with no labelled corner spread nothing)
        for k in range(c):
            for j in (j for j in range(c) if j != k):
                src, dst = owner[T[:, k]], T[:, j]
                take = (src >= 0) & (spread[dst] == -1)
                spread[dst[take]] = src[take]
                clash = (src >= 0) & (spread[dst] >= 0) & (spread[dst] != src)
                spread[dst[clash]] = -2
        owner = spread
    labels = owner[S]  # the part each element is near (within two rings); -1: none or several
    near = np.where(~any_column(labels != labels[:, :1]), labels[:, 0], -1)
    parts = np.unique(near[near >= 0])
    before = np.bincount(near[near >= 0], weights=folded_x[near >= 0], minlength=parts.max(initial=-1) + 1)
    after = np.bincount(near[near >= 0], weights=folded_y[near >= 0], minlength=parts.max(initial=-1) + 1)
    better = np.flatnonzero(after < before)
    take = region & np.isin(label, better)
    return np.where(take[:, None], Y, X)


def remove_folds(X, topo, free, max_rounds=MAX_ROUNDS, start=None):
    """``(X, rounds)``: ``X`` (n, d) with its folded faces (elements) removed where it can (see
    the module notes), never more of them folded than at the start; ``free`` (n,) bool the
    vertices it may move; ``rounds``: the rounds taken; ``start``: the
    :func:`~geomopt.fairing.certificate.certify_folds` of ``X`` when the caller has it."""
    S = topo.elements
    X = np.asarray(X, dtype=np.float64)
    if start is None:
        folded = _folded_mask(X, S)
    else:
        folded = np.zeros(len(S), bool)
        folded[start.folded] = True
    A = _averaging(topo)
    rings, rounds = 1, 0
    while folded.any() and rings <= MAX_RINGS and rounds < max_rounds:
        seed = np.zeros(topo.n, bool)
        seed[S[folded].ravel()] = True
        region = _grow(seed, A, rings) & free
        idx = np.flatnonzero(region)
        rows, Y = A[idx], X.copy()  # only the region's rows of the operator
        for _ in range(3 * rings):
            Y[idx] = 0.5 * (Y[idx] + rows @ Y)
        folded_y, rounds = _refolded(Y, S, folded, region, A), rounds + 1
        Z = _partwise(X, Y, S, topo, region, folded, folded_y)
        folded_z = _refolded(Z, S, folded, region, A)
        if folded_z.sum() >= folded.sum():
            Z, folded_z = Y, folded_y
        if folded_z.sum() < folded.sum():
            X, folded, rings = Z, folded_z, max(1, rings - 1)
        else:
            rings += 1
    return X, rounds

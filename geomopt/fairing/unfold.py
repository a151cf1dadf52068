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

from ..exact.topology import ranges
from .certificate import Stars, certify_folds, signs_near
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


def _grow(vertices, A, rings):
    """(p,) sorted: the ``vertices`` (sorted int) and those within ``rings`` rings through the
    edges (the pattern of ``A``, the averaging operator: in a triangle surface or a polyline,
    vertices share an element exactly when they share an edge)."""
    for _ in range(rings):
        vertices = np.union1d(vertices, A.indices[ranges(A.indptr, vertices)])
    return vertices


def _folded_mask(X, S):
    """(m,) bool: the folded faces of ``X``."""
    out = np.zeros(len(S), bool)
    out[certify_folds(X, S).folded] = True
    return out


def _refolded(Y, S, folded, moved, stars):
    """(m,) bool: the folded faces of ``Y``, which differs from the vertices whose folded faces
    are ``folded`` only on ``moved`` (p,) int: the signs of a face change only when a corner lies
    within one ring of a moved vertex, and those are taken again (exactly, on the faces around
    their corners), the rest kept."""
    affected, neg = signs_near(Y, S, moved, stars)
    out = folded.copy()
    out[affected] = any_column(neg)
    return out


def _parts(region, A):
    """(r,) a label per vertex of ``region`` (r,) sorted: its connected part through the edges
    between region vertices."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    if len(region) == 0:
        return np.zeros(0, np.int64)
    count = A.indptr[region + 1] - A.indptr[region]
    j = A.indices[ranges(A.indptr, region)]
    i = np.repeat(np.arange(len(region)), count)
    at = np.minimum(np.searchsorted(region, j), len(region) - 1)
    inside = region[at] == j
    graph = csr_matrix((np.ones(np.count_nonzero(inside)), (i[inside], at[inside])), shape=(len(region),) * 2)
    return connected_components(graph, directed=False)[1]


def _partwise(X, Y, S, region, A, stars, folded_x, folded_y):
    """``X`` with the smoothed ``Y`` taken on each connected part of ``region`` (p,) sorted that
    folds fewer faces within two rings of it (see the module notes)."""
    label = _parts(region, A)
    owner = np.full(len(X), -1)
    owner[region] = label
    labelled = region
    for _ in range(2):  # spread each part's label two rings out; a vertex reached by two parts: -2
        spread = owner.copy()
        c = S.shape[1]
        T = S[stars.around(labelled)]  # (the elements with no labelled corner spread nothing)
        for k in range(c):
            for j in (j for j in range(c) if j != k):
                src, dst = owner[T[:, k]], T[:, j]
                take = (src >= 0) & (spread[dst] == -1)
                spread[dst[take]] = src[take]
                clash = (src >= 0) & (spread[dst] >= 0) & (spread[dst] != src)
                spread[dst[clash]] = -2
        owner = spread
        labelled = np.unique(T)
        labelled = labelled[owner[labelled] >= 0]
    faces = stars.around(labelled)  # the others have a corner with no label or several
    labels = owner[S[faces]]  # the part each element is near (within two rings); -1: none or several
    near = np.where(~any_column(labels != labels[:, :1]), labels[:, 0], -1)
    keep = near >= 0
    count = label.max(initial=-1) + 1
    before = np.bincount(near[keep], weights=folded_x[faces[keep]], minlength=count)
    after = np.bincount(near[keep], weights=folded_y[faces[keep]], minlength=count)
    take = region[(after < before)[label]]
    Z = X.copy()
    Z[take] = Y[take]
    return Z


def remove_folds(X, topo, free, max_rounds=MAX_ROUNDS, start=None, stars: Stars | None = None):
    """``(X, rounds)``: ``X`` (n, d) with its folded faces (elements) removed where it can (see
    the module notes), never more of them folded than at the start; ``free`` (n,) bool the
    vertices it may move; ``rounds``: the rounds taken; ``start``: the
    :func:`~geomopt.fairing.certificate.certify_folds` of ``X`` when the caller has it;
    ``stars``: the :class:`~geomopt.fairing.certificate.Stars` of ``topo.elements``, when the
    caller has them.  Each round reads only its region's neighbourhood (through the vertex stars
    and the edges)."""
    S = topo.elements
    X = np.asarray(X, dtype=np.float64)
    if start is None:
        folded = _folded_mask(X, S)
    else:
        folded = np.zeros(len(S), bool)
        folded[start.folded] = True
    A, stars = _averaging(topo), stars or Stars(S, topo.n)
    rings, rounds, count = 1, 0, int(np.count_nonzero(folded))
    while count and rings <= MAX_RINGS and rounds < max_rounds:
        region = _grow(np.unique(S[folded]), A, rings)
        region = region[free[region]]
        rows, Y = A[region], X.copy()  # only the region's rows of the operator
        for _ in range(3 * rings):
            Y[region] = 0.5 * (Y[region] + rows @ Y)
        folded_y, rounds = _refolded(Y, S, folded, region, stars), rounds + 1
        Z = _partwise(X, Y, S, region, A, stars, folded, folded_y)
        folded_z = _refolded(Z, S, folded, region, stars)
        if np.count_nonzero(folded_z) >= count:
            Z, folded_z = Y, folded_y
        if np.count_nonzero(folded_z) < count:
            X, folded, rings, count = Z, folded_z, max(1, rings - 1), int(np.count_nonzero(folded_z))
        else:
            rings += 1
    return X, rounds

"""Nearly developable pieces of a chart, by region growing on face normals.

Where cone cuts stall (a coarse or strongly curved chart whose curvature is spread over many
vertices, not concentrated at a few cones), a chart flattens better in pieces that are each
close to one plane, or more generally whose normals stay in a narrow cone.  In the spirit of
D-Charts (Julius, Kraevoy & Sheffer 2005) and of variational shape approximation (Cohen-Steiner,
Alliez & Desbrun 2004), :func:`normal_regions` grows ``k`` regions over the chart's faces
(Lloyd iterations): every face joins the region whose seed it reaches by the cheapest path of
face steps, a step costing its length times ``compact`` plus the face's normal deviation from
the region's mean normal; each region's mean normal and seed are then updated (the seed to a
face deep inside the region, or the least deviating one).  Crumbs join the neighbour they share
the longest border with, and the regions must be disks.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .charts import face_pairs, patch_is_disk

__all__ = ["normal_regions"]

_CRUMB = 0.02  # a piece under this fraction of the chart's area joins a neighbour


def _dual(V, F):
    """``(a, b, length, step, edge_of)``: the face pairs sharing an edge, that edge's 3D length,
    the distance between the two faces' centroids, and the faces' edge ids."""
    a, b, edge, E, edge_of = face_pairs(F)
    c = V[F].mean(axis=1)
    return a, b, np.linalg.norm(V[E[edge, 1]] - V[E[edge, 0]], axis=1), np.linalg.norm(c[a] - c[b], axis=1), edge_of


def _normals(V, F):
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area2 = np.linalg.norm(n, axis=1)
    return n / np.maximum(area2, 1e-300)[:, None], 0.5 * area2


def _seeds(N, A, k):
    """``k`` faces spread in normal space (farthest-point sampling from the face that deviates
    most from the mean normal)."""
    mean = (A[:, None] * N).sum(axis=0)
    seeds = [int(np.argmin(N @ mean))]
    gap = 1 - N @ N[seeds[0]]
    for _ in range(k - 1):
        seeds.append(int(np.argmax(gap)))
        gap = np.minimum(gap, 1 - N @ N[seeds[-1]])
    return seeds


def _grow(N, a, b, step, seeds, proxies, compact):
    """Each face's region: the seed it reaches by the cheapest path (module doc)."""
    from scipy.sparse.csgraph import dijkstra

    m = len(N)
    dist = np.empty((len(seeds), m))
    for r, (s, p) in enumerate(zip(seeds, proxies)):
        dev = 1 - N @ p
        w = step * (compact + 0.5 * (dev[a] + dev[b])) + 1e-12
        graph = sp.coo_matrix((np.r_[w, w], (np.r_[a, b], np.r_[b, a])), shape=(m, m)).tocsr()
        dist[r] = dijkstra(graph, indices=s)
    return np.argmin(dist, axis=0), dist


def _centres(label, N, a, b, step, proxies, seeds):
    """Each region's new seed: the face that least deviates from the region's mean normal,
    ties (within 0.05 of ``1 - cos``) going to the face farthest inside the region (from faces
    at its border or at the chart's boundary); an empty region keeps its seed in ``seeds``."""
    from scipy.sparse.csgraph import dijkstra

    m = len(N)
    same = label[a] == label[b]
    graph = sp.coo_matrix((np.r_[step[same], step[same]], (np.r_[a[same], b[same]], np.r_[b[same], a[same]])),
                          shape=(m, m)).tocsr()
    inner = np.bincount(np.r_[a[same], b[same]], minlength=m) == 3
    depth = dijkstra(graph, indices=np.flatnonzero(~inner), min_only=True) if (~inner).any() else np.zeros(m)
    out = list(seeds)
    for r, p in enumerate(proxies):
        faces = np.flatnonzero(label == r)
        if not len(faces):
            continue
        dev = 1 - N[faces] @ p
        deep = depth[faces] / max(float(depth[faces].max()), 1e-300)
        out[r] = int(faces[np.argmin(dev + 0.05 * (1 - deep))])
    return out


def _pieces(F, label, a, b):
    """Connected pieces (faces joined across edges inside one region): ``(count, piece)``."""
    from scipy.sparse.csgraph import connected_components

    same = label[a] == label[b]
    m = len(F)
    graph = sp.coo_matrix((np.ones(int(same.sum())), (a[same], b[same])), shape=(m, m)).tocsr()
    return connected_components(graph, directed=False)


def _absorb_crumbs(F, label, A, a, b, length, rounds=4):
    """Relabel every connected piece under ``_CRUMB`` of the area to the neighbouring piece it
    shares the longest border with, again until none is left."""
    for _ in range(rounds):
        count, piece = _pieces(F, label, a, b)
        small = np.bincount(piece, A, minlength=count) < _CRUMB * A.sum()
        if count < 2 or not small.any():
            break
        pa, pb = piece[a], piece[b]
        cross = pa != pb
        border = sp.coo_matrix((np.r_[length[cross], length[cross]], (np.r_[pa[cross], pb[cross]],
                                np.r_[pb[cross], pa[cross]])), shape=(count, count)).toarray()
        border[:, small] *= 1e-6  # prefer joining a piece that stays
        target = np.argmax(border, axis=1)
        first = np.full(count, len(F))
        np.minimum.at(first, piece, np.arange(len(F)))
        new = label[first]
        new[small] = label[first[target[small]]]
        label = new[piece]
    return _pieces(F, label, a, b)[1]


def _all_disks(F, edge_of, piece):
    """Whether every piece (edge-connected faces of a disk) is a disk."""
    nv, ne = int(F.max()) + 1, int(edge_of.max()) + 1
    return all(patch_is_disk(F, edge_of, np.flatnonzero(piece == p), nv, ne) for p in range(piece.max() + 1))


def normal_regions(V, F, k: int, rounds: int = 6, compact: float = 0.1, centred: bool = True):
    """Split a disk chart into about ``k`` nearly developable pieces (module doc).

    Parameters
    ----------
    V : (n, 3) float, the chart's vertices;  F : (m, 3) int, its faces (a disk).
    k : the number of regions grown (crumbs joined, so the pieces may be fewer).
    rounds : Lloyd iterations;  compact : the cost of a face step per unit length (beside the
        normal deviation ``1 - cos``): larger, rounder pieces.
    centred : move each seed to the deepest of its region's least deviating faces
        (:func:`_centres`), else to the least deviating face nearest the old seed (the regions
        then leak a little across creases, which sometimes flattens better).

    Returns
    -------
    (m,) int64 piece of each face (``0 .. count - 1``), or None when a piece is not a disk or
    there is only one piece.
    """
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    if len(F) < 2 * k:
        return None
    N, A = _normals(V, F)
    a, b, length, step, edge_of = _dual(V, F)
    seeds = _seeds(N, A, k)
    proxies = [N[s] for s in seeds]
    for _ in range(rounds):
        label, dist = _grow(N, a, b, step, seeds, proxies, compact)
        for r in range(len(seeds)):
            faces = np.flatnonzero(label == r)
            p = (A[faces, None] * N[faces]).sum(axis=0) if len(faces) else proxies[r]
            proxies[r] = p / max(np.linalg.norm(p), 1e-300)
            if len(faces) and not centred:  # the least deviating face, the nearest of ties
                near = dist[r, faces] / max(dist[r, faces].max(), 1e-300)
                seeds[r] = int(faces[np.argmin(1 - N[faces] @ proxies[r] + 1e-3 * near)])
        if centred:
            seeds = _centres(label, N, a, b, step, proxies, seeds)
    label, _ = _grow(N, a, b, step, seeds, proxies, compact)
    piece = _absorb_crumbs(F, label, A, a, b, length)
    if piece.max() < 1 or not _all_disks(F, edge_of, piece):
        return None
    return piece.astype(np.int64)

"""Distances to a triangle surface, closest points on it, and triangle shape measures (NumPy).

:func:`closest_points` finds, for each query point, the closest point of a triangle mesh: the
faces whose centroid lies within ``d + R`` of the point are candidates (``d`` the distance to the
closest point among the faces of the ``k`` nearest centroids, ``R`` the largest centroid-to-corner
distance of the faces' bucket: :func:`surface_index`), which contain the closest face, and the point-triangle distance is Ericson's
(Real-Time Collision Detection, 2005, 5.1.5).
"""

from __future__ import annotations

import numpy as np

__all__ = ["closest_points", "surface_index", "point_triangle", "triangle_angles", "aspect_ratios", "volume",
           "face_samples", "face_distances"]


def point_triangle(P, A, B, C):
    """(k, 3) the closest points of triangles ``A, B, C`` (k, 3) to the points ``P`` (k, 3)."""
    ab, ac, ap = B - A, C - A, P - A
    d1, d2 = np.sum(ab * ap, 1), np.sum(ac * ap, 1)
    bp, cp = P - B, P - C
    d3, d4 = np.sum(ab * bp, 1), np.sum(ac * bp, 1)
    d5, d6 = np.sum(ab * cp, 1), np.sum(ac * cp, 1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(all="ignore"):
        denom = va + vb + vc
        v, w = vb / denom, vc / denom
        out = A + ab * v[:, None] + ac * w[:, None]  # inside the face
        cases = [  # (where, point), the later ones overriding: edges, then vertices
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), A + ab * (d1 / (d1 - d3))[:, None]),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), A + ac * (d2 / (d2 - d6))[:, None]),
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
             B + (C - B) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
            ((d1 <= 0) & (d2 <= 0), A), ((d3 >= 0) & (d4 <= d3), B), ((d6 >= 0) & (d5 <= d6), C),
        ]
    for where, point in cases:
        out = np.where(where[:, None], point, out)
    bad = ~np.isfinite(out).all(axis=1)  # a degenerate face: its nearest corner
    if bad.any():
        corners = np.stack([A[bad], B[bad], C[bad]], axis=1)
        k = np.argmin(np.sum((corners - P[bad, None]) ** 2, axis=2), axis=1)
        out[bad] = corners[np.arange(len(k)), k]
    return out


def surface_index(V, F):
    """What :func:`closest_points` searches, built once per surface: ``(corners A, B, C (m, 3)
    each, buckets)``; the faces are bucketed by their centroid-to-corner radius (powers of two),
    each bucket a tree of its centroids with its largest radius, so that a few large faces do
    not widen every search."""
    from scipy.spatial import cKDTree

    V = np.asarray(V, dtype=np.float64)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    centroid = (A + B + C) / 3.0
    radius = np.sqrt(np.max(np.sum((np.stack([A, B, C]) - centroid) ** 2, axis=2), axis=0))
    level = np.floor(np.log2(np.maximum(radius, 1e-300))).astype(np.int64)
    buckets = [(cKDTree(centroid[ids]), ids, float(radius[ids].max()))
               for ids in (np.flatnonzero(level == v) for v in np.unique(level))]
    return A, B, C, buckets


#: query points per batch of :func:`closest_points`: its candidate arrays grow with the points
#: times the candidates each, so batches bound its memory (tens of MB, not GB)
CHUNK = 16384


def closest_points(P, V, F, k=8, index=None):
    """``(Q, face)``: the closest points ``Q`` (p, 3) of the surface ``V, F`` to ``P`` (p, 3) and
    the faces (p,) they lie on (exact candidate search, see the module notes); ``index``: the
    surface's :func:`surface_index`, when the caller keeps one.  Points are searched in batches
    of :data:`CHUNK`."""
    P = np.asarray(P, dtype=np.float64)
    index = index or surface_index(V, F)
    if len(P) <= CHUNK:
        return _closest_batch(P, index, k)
    parts = [_closest_batch(P[i:i + CHUNK], index, k) for i in range(0, len(P), CHUNK)]
    return np.concatenate([q for q, _ in parts]), np.concatenate([f for _, f in parts])


def _closest_batch(P, index, k):
    """:func:`closest_points` of one batch of points."""
    A, B, C, buckets = index
    who, faces = [], []
    for tree, ids, _ in buckets:
        _, near = tree.query(P, k=min(k, len(ids)))
        near = ids[near.reshape(len(P), -1)]
        who.append(np.repeat(np.arange(len(P)), near.shape[1]))
        faces.append(near.ravel())
    best = _nearest_of(P, A, B, C, np.concatenate(who), np.concatenate(faces), len(P))[1]
    who, faces = [], []
    for tree, ids, R in buckets:
        lists = tree.query_ball_point(P, np.sqrt(best) * (1 + 1e-12) + R * (1 + 1e-12) + 1e-300)
        who.append(np.repeat(np.arange(len(P)), [len(x) for x in lists]))
        faces.append(ids[np.concatenate([np.asarray(x, np.int64) for x in lists])] if len(who[-1]) else
                     np.zeros(0, np.int64))
    face, _, Q = _nearest_of(P, A, B, C, np.concatenate(who), np.concatenate(faces), len(P))
    return Q, face


def face_samples(order):
    """(s, 3) barycentric coordinates of the points ``(i, j, k) / order``, ``i + j + k = order``:
    the corners, ``order - 1`` points along each edge, and the interior grid."""
    ijk = [(i, j, order - i - j) for i in range(order + 1) for j in range(order + 1 - i)]
    return np.asarray(ijk, dtype=np.float64) / order


def face_distances(X, F, V, G, order=4, index=None):
    """(m,) for each triangle ``F`` (m, 3) of the vertices ``X``: the largest distance of its
    :func:`face_samples` points to the surface ``V, G`` (a lower bound of the face's one-sided
    Hausdorff distance, exact at the samples); ``index``: ``V, G``'s :func:`surface_index`."""
    B = face_samples(order)
    P = np.einsum("sk,mkd->msd", B, np.asarray(X, dtype=np.float64)[F]).reshape(-1, 3)
    Q, _ = closest_points(P, V, G, index=index)
    return np.linalg.norm(Q - P, axis=1).reshape(len(F), len(B)).max(axis=1)


def _nearest_of(P, A, B, C, who, faces, p):
    """For each point the nearest of its candidate ``faces`` (listed with their point ``who``):
    ``(face, squared distance, closest point)``."""
    Q = point_triangle(P[who], A[faces], B[faces], C[faces])
    d = np.sum((Q - P[who]) ** 2, axis=1)
    order = np.lexsort((d, who))
    first = order[np.r_[True, who[order][1:] != who[order][:-1]]]
    face, dist, point = np.zeros(p, np.int64), np.full(p, np.inf), P.copy()
    face[who[first]], dist[who[first]], point[who[first]] = faces[first], d[first], Q[first]
    return face, dist, point


def triangle_angles(V, F) -> np.ndarray:
    """(m, 3) the interior angles (degrees) of each triangle."""
    V = np.asarray(V, dtype=np.float64)
    out = []
    for k in range(3):
        u, v = V[F[:, (k + 1) % 3]] - V[F[:, k]], V[F[:, (k + 2) % 3]] - V[F[:, k]]
        out.append(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.sum(u * v, axis=1))))
    return np.stack(out, axis=1)


def aspect_ratios(V, F) -> np.ndarray:
    """(m,) longest edge over the height on it, divided by that of the equilateral triangle
    (``2 / sqrt(3)``): 1 at best, growing without bound on slivers (inf when degenerate)."""
    V = np.asarray(V, dtype=np.float64)
    e = np.stack([np.linalg.norm(V[F[:, (k + 1) % 3]] - V[F[:, k]], axis=1) for k in range(3)], axis=1)
    area2 = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    longest = e.max(axis=1)
    with np.errstate(divide="ignore"):
        return longest * longest / area2 * (np.sqrt(3.0) / 2.0)


def volume(V, F) -> float:
    """The signed volume enclosed by a closed, outward-oriented triangle surface."""
    V = np.asarray(V, dtype=np.float64)
    return float(np.sum(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]]))) / 6.0)

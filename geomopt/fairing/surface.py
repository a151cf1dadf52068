"""Distances to a triangle surface, closest points on it, and triangle shape measures (NumPy).

:func:`closest_points` finds, for each query point, the closest point of a triangle mesh by an
exact candidate search (an upper bound of the distance from the faces around the nearest vertex,
then every face that can come closer, found among the faces' centroids by radius:
:func:`surface_index`); the point-triangle distance is Ericson's (Real-Time Collision Detection,
2005, 5.1.5).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._runtime.errors import ParameterError
from ..exact.topology import ranges

__all__ = ["closest_points", "surface_index", "SurfaceIndex", "point_triangle", "triangle_angles", "smallest_angles", "aspect_ratios", "volume",
           "shape_measures",
           "face_samples", "face_distances", "largest_face_distance"]


def point_triangle(P, A, B, C):
    """(k, 3) the closest points of triangles ``A, B, C`` (k, 3) to the points ``P`` (k, 3).

    The region tests multiply four coordinate differences: a row where they overflow (differences
    near 1e+77 and above) or all underflow (near 1e-77 and below) is taken again with its
    differences from ``A`` scaled by a power of two (exactly) to magnitude about 1."""
    out, unsafe = _point_triangle(P, A, B, C)
    if unsafe.any():
        A0, diff = A[unsafe], [X[unsafe] - A[unsafe] for X in (P, B, C)]
        size = np.max(np.abs(np.concatenate(diff, axis=1)), axis=1)
        e = np.maximum(np.frexp(size)[1], -1020)[:, None]
        scaled, _ = _point_triangle(*(np.ldexp(X, -e) for X in (diff[0], np.zeros_like(A0), diff[1], diff[2])))
        out[unsafe] = A0 + np.ldexp(scaled, e)
    bad = ~np.isfinite(out).all(axis=1)  # a degenerate face: its nearest corner
    if bad.any():
        corners = np.stack([A[bad], B[bad], C[bad]], axis=1)
        k = np.argmin(np.sum((corners - P[bad, None]) ** 2, axis=2), axis=1)
        out[bad] = corners[np.arange(len(k)), k]
    return out


def _point_triangle(P, A, B, C):
    """``(Q, unsafe)``: Ericson's closest points (non-finite on degenerate faces) and the rows
    (k,) whose products of differences overflowed or all underflowed (not to be trusted)."""
    with np.errstate(all="ignore"):
        ab, ac, ap = B - A, C - A, P - A
        d1, d2 = np.sum(ab * ap, 1), np.sum(ac * ap, 1)
        bp, cp = P - B, P - C
        d3, d4 = np.sum(ab * bp, 1), np.sum(ac * bp, 1)
        d5, d6 = np.sum(ab * cp, 1), np.sum(ac * cp, 1)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        denom = va + vb + vc
        tiny = 2.0 ** -500  # below it, products of two such dot products underflow
        unsafe = ~np.isfinite(denom) | ((np.abs(d1) < tiny) & (np.abs(d2) < tiny) & (np.abs(d3) < tiny)
                                        & (np.abs(d4) < tiny) & (np.abs(d5) < tiny) & (np.abs(d6) < tiny))
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
    return out, unsafe


class SurfaceIndex(NamedTuple):
    """What :func:`closest_points` searches, built once per surface by :func:`surface_index`.

    Attributes
    ----------
    A, B, C : (m, 3) the faces' corners.
    radius : (m,) each face's largest centroid-to-corner distance.
    centroids : (m, 3).
    buckets : ``(tree, ids, R)`` per power of two of the radius: a ``cKDTree`` of the centroids of
        the faces ``ids``, and their largest radius ``R`` (a few large faces do not widen every
        search).
    vertex_tree : a ``cKDTree`` of the vertices ``used`` (those of a face).
    used : (u,) the vertices of ``vertex_tree``.
    ring_start, ring_faces : the faces around vertex ``v``: ``ring_faces[ring_start[v]:ring_start[v + 1]]``.
    size : the largest coordinate magnitude (the scale of rounding errors).
    exponent : the power of two that every array above but ``size`` is divided by (exactly), so
        that their coordinates are below 1 and squared distances neither overflow nor underflow.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    radius: np.ndarray
    centroids: np.ndarray
    buckets: list
    vertex_tree: object
    used: np.ndarray
    ring_start: np.ndarray
    ring_faces: np.ndarray
    size: float
    exponent: int


def surface_index(V, F) -> SurfaceIndex:
    """The :class:`SurfaceIndex` of the triangle surface ``V`` (n, 3), ``F`` (m, 3): at least one
    face, and finite coordinates at the vertices of the faces (else :class:`ParameterError`)."""
    from scipy.spatial import cKDTree

    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    if len(F) == 0 or not np.isfinite(V[F]).all():
        raise ParameterError("the surface to measure distances to needs at least one face and finite "
                             "vertex coordinates; give a mesh without NaN or infinite vertices")
    size = float(np.abs(V[F]).max())
    exponent = int(np.frexp(size)[1])
    V = np.ldexp(V, -exponent)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    centroid = (A + B + C) / 3.0
    radius = np.sqrt(np.max(np.sum((np.stack([A, B, C]) - centroid) ** 2, axis=2), axis=0))
    level = np.floor(np.log2(np.maximum(radius, 1e-300))).astype(np.int64)
    buckets = [(cKDTree(centroid[ids]), ids, float(radius[ids].max()))
               for ids in (np.flatnonzero(level == v) for v in np.unique(level))]
    used = np.unique(F)
    order = np.argsort(F.ravel(), kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(F.ravel(), minlength=len(V)))])
    return SurfaceIndex(A, B, C, radius, centroid, buckets, cKDTree(V[used]), used, start, order // 3,
                        size, exponent)


#: query points per batch of :func:`closest_points`: its candidate arrays grow with the points
#: times the candidates each, so batches bound its memory (tens of MB, not GB)
CHUNK = 16384
#: centroids per bucket that :func:`closest_points` takes from a nearest-neighbour query before
#: it falls back, for the points that have more within reach, to a ball query
NEIGHBOURS = 16


def closest_points(P, V, F, index=None):
    """``(Q, face)``: the closest points ``Q`` (p, 3) of the surface ``V, F`` to ``P`` (p, 3) and
    the faces (p,) they lie on; ``index``: the surface's :func:`surface_index`, when the caller
    keeps one.  Points are searched in batches of :data:`CHUNK`.

    Exact candidate search, in two stages: (1) an upper bound ``d`` of each point's distance,
    from the faces around its nearest vertex; (2) every face whose centroid lies within ``d + R``
    of the point (``R`` the largest centroid-to-corner radius of the face's bucket), kept when
    its centroid is within ``d`` plus its own radius: these contain the closest face.  The
    point-triangle distance is Ericson's (Real-Time Collision Detection, 2005, 5.1.5)."""
    return _batched(P, V, F, index, 0.0)[:2]


def _batched(P, V, F, index, enough):
    """:func:`closest_points` and the distances (p,), where a point found within ``enough`` of the
    surface by the first stage keeps that stage's point (then not necessarily the closest)."""
    index = index or surface_index(V, F)
    P = np.asarray(P, dtype=np.float64)
    if not np.isfinite(P).all():
        raise ParameterError("closest points: the query points must be finite (no NaN or infinity)")
    P, enough = np.ldexp(P, -index.exponent), np.ldexp(enough, -index.exponent)
    parts = [_closest_batch(P[i:i + CHUNK], index, enough) for i in range(0, max(len(P), 1), CHUNK)]
    Q, face = np.concatenate([q for q, _ in parts]), np.concatenate([f for _, f in parts])
    dist = np.sqrt(np.sum((Q - P) ** 2, axis=1))
    return np.ldexp(Q, index.exponent), face, np.ldexp(dist, index.exponent)


def _ring_candidates(P, index):
    """``(who, faces)``: the faces around each point's nearest vertex (p points)."""
    _, j = index.vertex_tree.query(P)
    v = index.used[j]
    who = np.repeat(np.arange(len(P)), index.ring_start[v + 1] - index.ring_start[v])
    return who, index.ring_faces[ranges(index.ring_start, v)]


def _reach_candidates(P, index, reach):
    """``(who, faces)``: for each point, the faces whose centroid lies within ``reach`` (p,) plus
    the face's own radius (every face that can come closer than ``reach``), with a margin for
    the rounding of centroids, radii and distances (relative 1e-12, absolute 1e-13 of the
    coordinates' size)."""
    slack = 1e-13 * (np.abs(P).max(axis=1) + np.ldexp(index.size, -index.exponent)) + 1e-300
    reach = reach * (1 + 1e-12) + slack
    who, faces = [], []
    for tree, ids, R in index.buckets:
        bound = reach + R * (1 + 1e-12)
        k = min(NEIGHBOURS, len(ids))
        dist, near = tree.query(P, k=k, distance_upper_bound=float(bound.max()))
        dist, near = dist.reshape(len(P), k), near.reshape(len(P), k)
        full = np.flatnonzero(dist[:, -1] <= bound) if k < len(ids) else np.zeros(0, np.int64)
        keep = dist <= bound[:, None]
        keep[full] = False  # more than k within reach: a ball query below
        w, c = np.nonzero(keep)
        who.append(w)
        faces.append(ids[near[w, c]])
        if len(full):
            lists = tree.query_ball_point(P[full], bound[full])
            who.append(np.repeat(full, [len(x) for x in lists]))
            faces.append(ids[np.concatenate([np.asarray(x, np.int64) for x in lists])])
    who, faces = np.concatenate(who), np.concatenate(faces)
    gap = np.linalg.norm(P[who] - index.centroids[faces], axis=1) - index.radius[faces] * (1 + 1e-12)
    take = gap <= reach[who]  # (a face farther than its centroid's distance less its radius is farther)
    return who[take], faces[take]


def _closest_batch(P, index, enough=0.0):
    """:func:`_batched` of one batch of points."""
    who, faces = _ring_candidates(P, index)
    face, best, Q = _nearest_of(P, index, who, faces, len(P))
    far = np.flatnonzero(~(best <= enough * enough))  # (nan: searched too)
    if len(far) == 0:
        return Q, face
    keep = np.zeros(len(P), np.int64)
    keep[far] = np.arange(len(far))
    sub = np.isin(who, far) if len(far) < len(P) else np.ones(len(who), bool)
    more_who, more_faces = _reach_candidates(P[far], index, np.sqrt(best[far]))
    face[far], _, Q[far] = _nearest_of(P[far], index, np.concatenate([keep[who[sub]], more_who]),
                                       np.concatenate([faces[sub], more_faces]), len(far))
    return Q, face


def face_samples(order):
    """(s, 3) barycentric coordinates of the points ``(i, j, k) / order``, ``i + j + k = order``:
    the corners, ``order - 1`` points along each edge, and the interior grid."""
    ijk = [(i, j, order - i - j) for i in range(order + 1) for j in range(order + 1 - i)]
    return np.asarray(ijk, dtype=np.float64) / order


def _samples(X, F, order):
    """(m * s, 3) the :func:`face_samples` points of each face, face by face."""
    return np.einsum("sk,mkd->msd", face_samples(order), np.asarray(X, dtype=np.float64)[F]).reshape(-1, 3)


def face_distances(X, F, V, G, order=4, index=None, enough=0.0):
    """(m,) for each triangle ``F`` (m, 3) of the vertices ``X``: the largest distance of its
    :func:`face_samples` points to the surface ``V, G`` (a lower bound of the face's one-sided
    Hausdorff distance, exact at the samples); ``index``: ``V, G``'s :func:`surface_index`.
    ``enough``: a face whose distance is at most ``enough`` may get any value up to ``enough``
    (a point found that near by the first stage of :func:`closest_points` is not searched
    further): ``face_distances(..., enough=tol) > tol`` is exact, and faster."""
    P = _samples(X, F, order)
    return _batched(P, V, G, index, enough)[2].reshape(len(F), -1).max(axis=1)


def largest_face_distance(X, F, V, G, order=4, index=None) -> float:
    """``face_distances(X, F, V, G, order).max()`` (0 without faces), from above and within
    rounding: at least that max and at most ``1e-14`` of the coordinates' size more.

    A face of ``F`` that is the same face of ``G`` (same corners, same positions) lies on the
    surface: its samples' distances are rounding errors, below that margin, and are not searched.
    For the others, the first stage of :func:`closest_points` bounds every sample's distance from
    above; only the samples whose bound exceeds the largest exact distance found so far (by more
    than the margin) are searched exactly, the largest bounds first."""
    X, V, F = np.asarray(X, dtype=np.float64), np.asarray(V, dtype=np.float64), np.asarray(F)
    index = index or surface_index(V, G)
    same = np.zeros(len(F), bool)
    if np.shape(F) == np.shape(G) and np.array_equal(F, G):
        same = (X[F] == V[F]).reshape(len(F), -1).all(axis=1)
    P = _samples(X, F[~same], order)
    margin = 1e-14 * (index.size + float(np.abs(X[F]).max(initial=0.0)))
    bound = np.concatenate([_batched(P, V, G, index, np.inf)[2], [margin] if same.any() else []])
    done, best = np.zeros(len(bound), bool), 0.0
    while True:
        todo = np.flatnonzero(~done & (bound > best + margin))
        if len(todo) == 0:
            return max(best, float(bound.max(initial=0.0)))
        if len(todo) > CHUNK:
            todo = todo[np.argpartition(-bound[todo], CHUNK)[:CHUNK]]
        bound[todo], done[todo] = _batched(P[todo], V, G, index, 0.0)[2], True
        best = max(best, float(bound[todo].max()))


def _nearest_of(P, index, who, faces, p):
    """For each point the nearest of its candidate ``faces`` (listed with their point ``who``):
    ``(face, squared distance, closest point)``."""
    Q = point_triangle(P[who], index.A[faces], index.B[faces], index.C[faces])
    d = np.sum((Q - P[who]) ** 2, axis=1)
    dist = np.full(p, np.inf)
    np.minimum.at(dist, who, d)
    hit = np.flatnonzero(d <= dist[who])  # (the first candidate of the least distance, as a stable sort's)
    first = np.full(p, len(who))
    np.minimum.at(first, who[hit], hit)
    has = first < len(who)
    face, point = np.zeros(p, np.int64), P.copy()
    face[has], point[has] = faces[first[has]], Q[first[has]]
    return face, dist, point


def triangle_angles(V, F) -> np.ndarray:
    """(m, 3) the interior angles (degrees) of each triangle."""
    V = np.asarray(V, dtype=np.float64)
    out = []
    for k in range(3):
        u, v = V[F[:, (k + 1) % 3]] - V[F[:, k]], V[F[:, (k + 2) % 3]] - V[F[:, k]]
        out.append(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.sum(u * v, axis=1))))
    return np.stack(out, axis=1)


def _corners(V, F):
    """(3, 3, m): ``P[k, c]`` the coordinate ``c`` of corner ``k`` of each triangle ``F`` (m, 3)
    on ``V`` (n, 3), coordinate-major (one-dimensional gathers: several times faster than
    ``V[F]``, and every later product runs along contiguous rows)."""
    return _gathered(np.ascontiguousarray(np.asarray(V, dtype=np.float64).T), np.asarray(F, dtype=np.int64))


def _gathered(Vt, F):
    """:func:`_corners` from the coordinate rows ``Vt`` (3, n)."""
    Ft = np.ascontiguousarray(F.T)
    P = np.empty((3, 3, Ft.shape[1]))
    for k in range(3):
        for c in range(3):
            np.take(Vt[c], Ft[k], out=P[k, c])
    return P


def _dot(a, b):
    """(m,) the row dot products of ``a, b`` (3, m), summed as ``np.einsum("ij,ij->i")`` sums
    three terms (first and last, then the middle): the same floats as the row-major forms."""
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


def _cross(a, b):
    """(3, m) the cross products of ``a, b`` (3, m), by ``np.cross``'s formulas."""
    out = np.empty_like(a)
    for c, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.subtract(a[i] * b[j], a[j] * b[i], out=out[c])
    return out


def _length(a):
    """(m,) the lengths of ``a`` (3, m), as ``np.linalg.norm(..., axis=1)`` sums the squares."""
    return np.sqrt((a[0] * a[0] + a[1] * a[1]) + a[2] * a[2])


def _edges(P):
    """``(edges, squared)``: the edge vectors ``P[k + 1] - P[k]`` (3 of (3, m)) of the
    triangles' corners ``P`` (3, 3, m) (:func:`_corners`), and their squared lengths (3 of (m,))."""
    edges = [P[(k + 1) % 3] - P[k] for k in range(3)]
    return edges, [_dot(e, e) for e in edges]


def _smallest_angles_of(P, squared):
    """:func:`smallest_angles` of the corners ``P`` (3, 3, m) with :func:`_edges`' ``squared``."""
    k = np.argmin(np.stack([squared[(c + 1) % 3] for c in range(3)]), axis=0)  # opposite corner c
    m = P.shape[2]
    flat, rows = P.reshape(-1), np.arange(m)

    def at(j):  # (3, m) the coordinates of each triangle's corner j (m,) (P[j[f], :, f])
        base = j * (3 * m) + rows
        return np.stack([flat.take(base + c * m) for c in range(3)])

    corner = at(k)
    u, v = at((k + 1) % 3) - corner, at((k + 2) % 3) - corner
    dot = (u[0] * v[0] + u[1] * v[1]) + u[2] * v[2]
    dot += 0.0  # np.sum's over a row of three, which starts from +0: never -0 (arctan2 tells them apart)
    return np.degrees(np.arctan2(_length(_cross(u, v)), dot))


def _aspect_ratios_of(edges, squared):
    """:func:`aspect_ratios` from :func:`_edges`' ``edges`` and ``squared``."""
    longest2 = np.maximum(np.maximum(squared[0], squared[1]), squared[2])
    area2 = _length(_cross(edges[0], -edges[2]))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(area2 > 0, longest2 / area2 * (np.sqrt(3.0) / 2.0), np.inf)


def _volume_of(P):
    """:func:`volume` of the corners ``P`` (3, 3, m)."""
    return float(np.sum(_dot(P[0], _cross(P[1], P[2]))) / 6.0)


def smallest_angles(V, F) -> np.ndarray:
    """(m,) each triangle's smallest interior angle (degrees): the one opposite its shortest
    edge, by :func:`triangle_angles`' formula at that corner alone (a third of the work)."""
    P = _corners(V, F)
    return _smallest_angles_of(P, _edges(P)[1])


def aspect_ratios(V, F) -> np.ndarray:
    """(m,) longest edge over the height on it, divided by that of the equilateral triangle
    (``2 / sqrt(3)``): 1 at best, growing without bound on slivers (inf when degenerate)."""
    return _aspect_ratios_of(*_edges(_corners(V, F)))


def volume(V, F) -> float:
    """The signed volume enclosed by a closed, outward-oriented triangle surface."""
    return _volume_of(_corners(V, F))


def shape_measures(V, F, closed=True):
    """``(volume, smallest angle, largest aspect ratio)`` of the triangles ``F`` (m, 3) on ``V``
    (n, 3): :func:`volume` (nan unless ``closed``), the least of :func:`smallest_angles` (inf
    without triangles) and the largest of :func:`aspect_ratios` (nan without triangles), the
    same values, from one gather of the corners, in batches of :data:`BATCH` triangles."""
    Vt, F = np.ascontiguousarray(np.asarray(V, dtype=np.float64).T), np.asarray(F, dtype=np.int64)
    volumes, angle, aspect = np.empty(len(F)), [np.inf], []
    for i in range(0, len(F), BATCH):
        P = _gathered(Vt, F[i:i + BATCH])
        edges, squared = _edges(P)
        aspect.append(_aspect_ratios_of(edges, squared).max())
        angle.append(_smallest_angles_of(P, squared).min())
        if closed:
            volumes[i:i + BATCH] = _dot(P[0], _cross(P[1], P[2]))
    return (float(np.sum(volumes) / 6.0) if closed else float("nan"), float(np.min(angle)),
            float(np.max(aspect)) if aspect else float("nan"))


#: triangles per batch of :func:`shape_measures`: its temporaries stay small (cached, and their
#: memory reused instead of newly mapped for each)
BATCH = 1 << 15

"""How exposed a place on a surface is: the ambient visibility of points and edges, by exact ray
casting against the triangles (the "ambient occlusion" of rendering, Zhukov, Iones & Kronin
1998, counted with uniform weights over the hemisphere).

A point's visibility is the fraction of ``rays`` rays over the hemisphere around its normal,
from the point moved off the surface along that normal, that leave the mesh without hitting a
triangle.  The rays are a fixed set: a Fibonacci lattice of ``rays`` directions on the upper
half sphere (equal-area, González 2010) and their mirror images; of each mirrored pair
``±h`` a point shoots the one on its normal's side, so every point shoots exactly ``rays``
rays, spread evenly over its hemisphere, and all the points shooting along ``h`` or ``-h``
share one parallel projection.  Along a direction ``d`` a ray is a point of the plane normal to
``d``: it hits a triangle exactly when it lies in the triangle's projection and the triangle is
ahead of it along ``d``.  The projected triangles are binned in a uniform grid, so each ray
tests only the triangles of its cell (no bounding volume hierarchy, no per-ray traversal): the
triangles' cells are joined to the rays' (only cells that hold a ray are listed), and a triangle
wholly behind a ray's origin is dropped before its edges are tested.
"""

from __future__ import annotations

import numpy as np

__all__ = ["hemisphere_directions", "ambient_visibility", "vertex_normals", "edge_visibility",
           "vertex_visibility", "independent_vertices"]

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))
_MAX_PAIRS = 1 << 22  # ray-triangle candidate pairs tested at once (memory bound)
_MAX_CELLS = 1 << 20  # (triangle, grid cell) entries of a projection's grid, at least (memory bound)


def hemisphere_directions(count: int = 96) -> np.ndarray:
    """(count, 3) unit directions spread evenly over the half sphere ``z > 0`` (a Fibonacci
    lattice: heights evenly spaced in ``(0, 1)``, so each direction stands for equal area)."""
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    z = 1.0 - (np.arange(count) + 0.5) / count
    r = np.sqrt(1.0 - z * z)
    phi = _GOLDEN * np.arange(count)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def _plane_basis(d):
    """(3, 2) an orthonormal basis of the plane normal to the unit vector ``d``."""
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    u = np.cross(d, a)
    u /= np.linalg.norm(u)
    return np.c_[u, np.cross(d, u)]


def _corner_extremes(A):
    """``(lo, hi)``: the least and greatest of each row's three corners of ``A`` (m, 3, ...),
    two elementwise passes (a reduction over the short middle axis is several times slower)."""
    a, b, c = A[:, 0], A[:, 1], A[:, 2]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)


def _grid_join(P, Q, fine):
    """The (triangle, point) pairs whose projections share a cell of a uniform grid, ``fine``
    cells a side of the median triangle's bounding box: ``(tri, first, many, points)``, entry
    ``e`` pairing triangle ``tri[e]`` of the projected triangles ``P`` (m, 3, 2) with the points
    ``points[first[e]:first[e] + many[e]]`` of ``Q`` (p, 2) in one of the cells its bounding
    box meets.  The triangles' cells are joined to the points' (the points sorted by cell, not
    the triangles' cells), and only the cells holding a point are listed."""
    bmin, bmax = _corner_extremes(P)
    lo, hi = bmin.min(axis=0), bmax.max(axis=0)
    extent = float(np.max(hi - lo))
    typical = float(np.median(np.max(bmax - bmin, axis=1)))
    size = int(np.clip(np.ceil(fine * extent / max(typical, 1e-300)), 1, 4096))
    size = min(size, _affordable_side(bmax - bmin, extent))
    h = max(extent / size, 1e-300)
    i0 = np.clip(((bmin - lo) / h).astype(np.int64), 0, size - 1)
    i1 = np.clip(((bmax - lo) / h).astype(np.int64), 0, size - 1)
    q = np.floor((Q - lo) / h).astype(np.int64)
    inside = np.all((q >= 0) & (q < size), axis=1)
    where = np.where(inside, q[:, 0] * size + q[:, 1], size * size)  # outside: a cell of no triangle
    held = np.bincount(where, minlength=size * size + 1)
    span = i1 - i0 + 1
    count = span[:, 0] * span[:, 1]
    tri = np.repeat(np.arange(len(P)), count)
    k = np.arange(len(tri)) - np.repeat(np.cumsum(count) - count, count)
    across, down = np.divmod(k, np.repeat(span[:, 0], count))
    cell = np.repeat(i0[:, 0] * size + i0[:, 1], count) + down * size + across
    many = held[cell]
    some = many > 0
    return tri[some], (np.cumsum(held) - held)[cell[some]], many[some], np.argsort(where, kind="stable")


def _affordable_side(boxes, extent) -> int:
    """The most cells a side of a grid over ``extent`` in which the triangles' bounding boxes
    ``boxes`` (m, 2: widths, heights) cover at most ``_MAX_CELLS`` (or 16 per triangle) cells in
    all: a triangle spanning the grid lists every cell it meets, and where a few long triangles
    sit among many small ones (the sides of a thin capsule, whose caps set the median) a grid
    fine for the small ones made 468 million (triangle, cell) entries.  A box of width ``w``
    meets at most ``w / h + 2`` columns of cells of side ``h``: the count is at most
    ``A / h**2 + 2 B / h + 4 m`` (``A`` the boxes' areas, ``B`` their half-perimeters summed)."""
    m = len(boxes)
    budget = max(16 * m, _MAX_CELLS) - 4 * m
    A = float(np.sum(boxes[:, 0] * boxes[:, 1]))
    B = float(np.sum(boxes[:, 0] + boxes[:, 1]))
    if A > 0:
        inv_h = (-B + np.sqrt(B * B + A * budget)) / A
    else:
        inv_h = budget / max(2 * B, 1e-300)
    return int(max(1, min(4096, np.floor(inv_h * extent))))


def _hits_along(V, F, origins, sign, d, fine=2.0):
    """(p,) bool: whether the ray from each of ``origins`` (p, 3) along ``sign * d`` (sign
    (p,) of +-1, ``d`` a unit vector) hits a triangle of ``V[F]`` at a positive distance."""
    B = _plane_basis(d)
    X = V @ B
    Q, zq = origins @ B, origins @ d
    P, Z = X[F], (V @ d)[F]
    planes = _planes(P, Z)
    reach = np.where(sign > 0, -zq, zq)  # a triangle ahead has sign * depth above sign * zq somewhere
    deep, high = _corner_extremes(Z)
    top = np.c_[high, -deep]  # the most of depth and of -depth on each triangle
    side = (sign < 0).astype(np.int64)
    tri, first, many, points = _grid_join(P, Q, fine)
    ends = np.cumsum(many)
    hit = np.zeros(len(origins), dtype=bool)
    lo_e = 0
    while lo_e < len(tri):  # chunks of at most _MAX_PAIRS candidate pairs
        base = ends[lo_e - 1] if lo_e else 0
        hi_e = max(int(np.searchsorted(ends, base + _MAX_PAIRS, side="right")), lo_e + 1)
        m = many[lo_e:hi_e]
        t = np.repeat(tri[lo_e:hi_e], m)
        pt = points[np.repeat(first[lo_e:hi_e] - (ends[lo_e:hi_e] - base) + m, m) + np.arange(ends[hi_e - 1] - base)]
        ahead = top[t, side[pt]] + reach[pt] > 0  # some of the triangle is ahead of the point: cheap, first
        t, pt = t[ahead], pt[ahead]
        for j in (0, 3, 6, 9):  # the edge tests one at a time, each on the pairs left (most fail early)
            c = planes[t, j:j + 3]
            value = c[:, 0] * Q[pt, 0] + c[:, 1] * Q[pt, 1] + c[:, 2]
            keep = value >= 0 if j < 9 else (value - zq[pt]) * sign[pt] > 0
            t, pt = t[keep], pt[keep]
        hit[pt] = True
        lo_e = hi_e
    return hit


def _planes(P, Z):
    """(m, 12) per projected triangle ``P`` (m, 3, 2) with depths ``Z`` (m, 3): three edge
    functions ``a x + b y + c``, each at least 0 exactly on the triangle's side of its edge
    (the edges included), and its depth plane ``z = a x + b y + c``; a triangle projecting to
    a segment (zero area) gets edge functions that are negative everywhere."""
    A, B, C = P[:, 0], P[:, 1], P[:, 2]
    area = (B[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (B[:, 1] - A[:, 1]) * (C[:, 0] - A[:, 0])
    s = np.sign(area)
    out = np.empty((len(P), 12))
    for i, (a, b) in enumerate(((B, C), (C, A), (A, B))):
        # (b - a) x (q - a) = -(b_y - a_y) q_x + (b_x - a_x) q_y + (b_y - a_y) a_x - (b_x - a_x) a_y
        out[:, 3 * i] = -s * (b[:, 1] - a[:, 1])
        out[:, 3 * i + 1] = s * (b[:, 0] - a[:, 0])
        out[:, 3 * i + 2] = s * ((b[:, 1] - a[:, 1]) * a[:, 0] - (b[:, 0] - a[:, 0]) * a[:, 1])
    out[area == 0, 2] = -1.0  # never inside
    safe = np.where(area != 0, area, 1.0)
    # barycentric weights w_i = (edge function i, unsigned) / area; z = sum w_i Z_i
    for j in range(3):
        out[:, 9 + j] = sum(s * out[:, 3 * i + j] * Z[:, i] for i in range(3)) / safe
    return out


def ambient_visibility(V, F, points, normals, rays: int = 96, offset: float = 1e-5) -> np.ndarray:
    """(p,) the fraction of ``rays`` rays from each point, over the hemisphere around its normal,
    that leave the mesh without hitting it (module doc).

    Parameters
    ----------
    V : (n, 3) float;  F : (m, 3) int triangles (any orientation, any topology).
    points : (p, 3) ray origins on the surface;  normals : (p, 3) unit normals there.
    rays : rays per point;  offset : the origins move this fraction of the bounding box's
        diagonal along their normals first (off the surface they lie on).
    """
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    diagonal = float(np.linalg.norm(np.ptp(V[F.ravel()], axis=0)))
    origins = points + offset * diagonal * normals
    H = hemisphere_directions(rays)
    escaped = np.zeros(len(points))
    for d in H:
        side = normals @ d
        sign = np.where(side >= 0, 1.0, -1.0)
        escaped += ~_hits_along(V, F, origins, sign, d)
    return escaped / rays


def vertex_normals(V, F) -> np.ndarray:
    """(n, 3) unit area-weighted vertex normals (zero at a vertex of no face)."""
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.zeros_like(V)
    for c in range(3):
        np.add.at(out, F[:, c], N)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def edge_visibility(V, F, E, rays: int = 96, offset: float = 1e-5) -> np.ndarray:
    """(k,) :func:`ambient_visibility` of the edges ``E`` (k, 2) of ``V``, ``F``: from each
    edge's midpoint, around the mean of its two vertices' normals (:func:`vertex_normals`)."""
    V, E = np.asarray(V, dtype=np.float64), np.asarray(E, dtype=np.int64)
    N = vertex_normals(V, F)
    n = N[E[:, 0]] + N[E[:, 1]]
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
    return ambient_visibility(V, F, V[E].mean(axis=1), n, rays, offset)


def vertex_visibility(V, F, rays: int = 32, offset: float = 1e-5, sampled: bool = False) -> np.ndarray:
    """(n,) :func:`ambient_visibility` of the vertices of ``V``, ``F`` around their normals
    (:func:`vertex_normals`): the cheaper figure a seam's cost is weighted by (a third as many
    points as edges, and fewer rays).  With ``sampled``, rays are cast from a maximal independent
    set of the vertices only (:func:`independent_vertices`, about a fifth of them on a triangle
    mesh), and every other vertex gets the mean of its sampled neighbours: an approximation of a
    smooth field, for large meshes."""
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    N = vertex_normals(V, F)
    if not sampled:
        return ambient_visibility(V, F, V, N, rays, offset)
    E = np.unique(np.sort(np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1), axis=0)
    chosen = independent_vertices(len(V), E)
    out = np.zeros(len(V))
    out[chosen] = ambient_visibility(V, F, V[chosen], N[chosen], rays, offset)
    a, b = np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]]
    use = chosen[b] & ~chosen[a]
    total = np.bincount(a[use], out[b[use]], minlength=len(V))
    count = np.bincount(a[use], minlength=len(V))
    rest = ~chosen & (count > 0)
    out[rest] = total[rest] / count[rest]
    return out


def independent_vertices(n: int, E) -> np.ndarray:
    """(n,) bool, a maximal independent set of the graph of ``n`` vertices and edges ``E`` (k, 2):
    no two chosen vertices share an edge, and every vertex is chosen or next to a chosen one
    (Luby 1986: in each round a vertex whose fixed pseudo-random priority is below all its open
    neighbours' is chosen and its neighbours closed)."""
    E = np.asarray(E, dtype=np.int64).reshape(-1, 2)
    a, b = np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]]
    priority = np.random.default_rng(0).permutation(n)
    chosen, closed = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    while not closed.all():
        p = np.where(closed, n, priority)
        low = np.full(n, n)
        np.minimum.at(low, a, p[b])
        pick = ~closed & (p < low)
        chosen |= pick
        closed |= pick
        closed[b[pick[a]]] = True
    return chosen

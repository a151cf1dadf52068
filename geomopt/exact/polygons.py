"""Exact tests of closed polygons and edge loops in the plane: pairs of edges that cross or
overlap (:func:`polygon_crossings`, :func:`loop_crossings`: a uniform-grid broad phase, then
:func:`~geomopt.exact.predicates.orient2d`) and the turning sense (:func:`polygon_orientation`).
The global and bijective certificates (:mod:`geomopt.exact.certify`) rest on them."""

from __future__ import annotations

import numpy as np

from .._runtime.errors import MeshError
from .._runtime.validate import validate_vertices
from .predicates import orient2d

__all__ = ["polygon_crossings", "loop_crossings", "polygon_orientation"]


_MAX_CELLS_PER_EDGE = 4.0
_CELL_SCALE = 2.0  # cell size / mean edge box size: 2 measured faster than 1 on long polygons


def _as_polygon(P) -> np.ndarray:
    P = validate_vertices(P, "polygon", dim=2)
    if len(P) < 3:
        raise MeshError(f"a closed polygon needs at least 3 vertices, got {len(P)}")
    return P


def _segments_meet(a, b, c, d) -> np.ndarray:
    """Whether closed segments ``ab`` and ``cd`` (rows of (q, 2) arrays) share a point, given
    that their bounding boxes overlap (touching included).  Exact.

    With overlapping boxes, the segments meet iff each one's endpoints are not strictly on the
    same side of the other's line: collinear segments with overlapping boxes overlap, and a
    collinear endpoint with the other pair straddling is the meeting point."""
    o1, o2 = orient2d(a, b, c), orient2d(a, b, d)
    o3, o4 = orient2d(c, d, a), orient2d(c, d, b)
    return (o1 * o2 <= 0) & (o3 * o4 <= 0)


def _adjacent_overlaps(P, nxt, ex, ey) -> np.ndarray:
    """Indices ``i`` such that edges ``i`` and ``nxt[i]`` share more than their common
    vertex ``P[nxt[i]]``: collinear and not pointing in strictly opposite directions from it (this
    includes a zero-length edge).  ``ex, ey`` (k,) are the edge vectors ``P[nxt[i]] - P[i]``.
    Exact: the sign of a float difference is exact.

    From the shared vertex, edge ``i`` points along ``-e_i`` and edge ``nxt[i]`` along
    ``e_nxt[i]``; these are strictly opposite per axis when ``e_i`` is not zero and has the
    signs of ``e_nxt[i]``, and then the edges cannot overlap."""
    sx = (ex > 0).view(np.int8) - (ex < 0).view(np.int8)
    sy = (ey > 0).view(np.int8) - (ey < 0).view(np.int8)
    opposite = (sx == sx[nxt]) & (sy == sy[nxt]) & ((sx != 0) | (sy != 0))
    rest = np.flatnonzero(~opposite)  # strictly opposite directions never overlap
    flat = orient2d(P[rest], P[nxt[rest]], P[nxt[nxt[rest]]]) == 0
    return rest[flat]


def _grid_candidates(lox, loy, hix, hiy, nxt):
    """Candidate pairs ``(i, j)`` of non-consecutive edges (``j != nxt[i]``, ``i != nxt[j]``) whose bounding boxes
    ``[lox, hix] x [loy, hiy]`` (each (k,), coordinates within [-1, 1]) overlap, touching
    included; each pair once, in no particular order.

    Uniform grid; the cell size starts at ``_CELL_SCALE`` times the mean box size and is doubled
    until there are at most ``_MAX_CELLS_PER_EDGE`` (edge, cell) entries per edge, so that a few
    very long edges cannot blow the grid up.  The entries are sorted as one int64 each, the cell
    id in the high bits and the edge in the low ones (``np.sort`` of integers is several times
    faster than ``argsort`` and leaves nothing to gather), and the pairs of a cell are found by
    comparing every entry with the one ``s`` places on, ``s = 1, 2, ...``, on a shrinking index
    set (work proportional to the entries plus the pairs)."""
    k = lox.size
    ox, oy = lox.min(), loy.min()
    span = max(hix.max() - ox, hiy.max() - oy)
    h = _CELL_SCALE * float(np.mean(np.maximum(hix - lox, hiy - loy)))
    if not h > 0:
        h = span / k if span > 0 else 1.0
    h = max(h, span * 2.0**-24)  # at most 2**24 cells a side: counts fit int64 (and 1 / h is finite)
    bits = max(int(k - 1).bit_length(), 1)  # edge ids take the low bits of an entry
    while True:
        # coordinates >= 0, so truncation is the floor; a rounded product is monotone in its
        # argument, which the de-duplication below relies on
        inv = 1.0 / h
        x0 = ((lox - ox) * inv).astype(np.int64)
        y0 = ((loy - oy) * inv).astype(np.int64)
        wx = ((hix - ox) * inv).astype(np.int64) - x0 + 1
        wy = ((hiy - oy) * inv).astype(np.int64) - y0 + 1
        per = wx * wy
        nx = int((x0 + wx).max()) + 1
        cells = nx * (int((y0 + wy).max()) + 1)
        if (per.sum(dtype=np.float64) <= _MAX_CELLS_PER_EDGE * k and cells.bit_length() + bits <= 62) or h >= span:
            break
        h *= 2.0
    # one entry (cell << bits | edge) per (edge, covered cell); single-cell edges need no expansion
    multi = np.flatnonzero(per > 1)
    cnt = per[multi] - 1  # cells after the first
    edge_m = np.repeat(multi, cnt)
    local = np.arange(edge_m.size) - np.repeat(np.cumsum(cnt) - cnt, cnt) + 1
    w = wx[edge_m]
    key_m = (y0[edge_m] + local // w) * nx + x0[edge_m] + local % w
    entry = np.concatenate([((y0 * nx + x0) << bits) | np.arange(k), (key_m << bits) | edge_m])
    entry.sort()
    key = np.append(entry >> bits, -1)  # a sentinel cell ends the last run
    edge = entry & ((1 << bits) - 1)  # ascending within a cell
    if cells < 2**31:  # halve the memory traffic of the pair search
        key, edge = key.astype(np.int32), edge.astype(np.int32)
    # entry p pairs with p + s while the cell is the same (the keys are sorted); consecutive
    # edges (tested by _adjacent_overlaps) and pairs whose boxes do not overlap are dropped at once
    I, J, K = [], [], []
    p = np.flatnonzero(key[1:] == key[:-1])
    s = 1
    while p.size:
        i, j = edge[p], edge[p + s]
        keep = (nxt[i] != j) & (nxt[j] != i)
        i, j, q = i[keep], j[keep], p[keep]
        keep = (lox[i] <= hix[j]) & (lox[j] <= hix[i]) & (loy[i] <= hiy[j]) & (loy[j] <= hiy[i])
        I.append(i[keep])
        J.append(j[keep])
        K.append(key[q[keep]])
        s += 1
        p = p[key[p + s] == key[p]]
    if not I:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i, j, cell = (np.concatenate(a).astype(np.int64) for a in (I, J, K))
    # keep a pair only in the cell of the lower-left corner of the boxes' intersection
    cx = ((np.maximum(lox[i], lox[j]) - ox) * inv).astype(np.int64)
    cy = ((np.maximum(loy[i], loy[j]) - oy) * inv).astype(np.int64)
    keep = cy * nx + cx == cell
    return i[keep], j[keep]


def polygon_crossings(P) -> np.ndarray:
    """Pairs of edges of a closed polygon that cross, touch or overlap.  Exact.

    Parameters
    ----------
    P : (k, 2) float array, k >= 3
        Polygon vertices in order; edge ``i`` runs from ``P[i]`` to ``P[(i + 1) % k]``.

    Returns
    -------
    pairs : (q, 2) int64 array
        Edge index pairs ``(i, j)``, ``i < j``, sorted, that violate simplicity (see the module
        docstring: non-consecutive edges that share any point; consecutive edges that overlap
        beyond their shared vertex).  Empty iff the polygon is simple.

    Raises
    ------
    MeshError
        ``P`` is not a finite (k, 2) array with k >= 3.
    """
    P = _as_polygon(P)
    return loop_crossings(P, np.roll(np.arange(len(P)), -1))


def loop_crossings(P, nxt) -> np.ndarray:
    """Pairs of edges of a set of closed loops that cross, touch or overlap.  Exact.

    The loops' vertices are the rows of ``P``; edge ``i`` runs from ``P[i]`` to ``P[nxt[i]]``
    (``nxt`` is a permutation whose cycles are the loops, each of at least 3 edges).  Edges
    ``i`` and ``nxt[i]`` are consecutive: they must meet only at ``P[nxt[i]]``; any other two
    edges, of the same loop or of two loops, must not meet at all (the module docstring's rule,
    extended to several loops).  One grid broad phase for all loops.

    Parameters
    ----------
    P : (k, 2) finite float64 array, the loop vertices (a point may appear in several rows).
    nxt : (k,) int array, the next row along each loop.

    Returns
    -------
    pairs : (q, 2) int64 array
        Edge index pairs ``(i, j)``, ``i < j``, sorted, that meet where they must not.
    """
    P = np.asarray(P, dtype=np.float64)
    nxt = np.asarray(nxt, dtype=np.int64)
    k = len(P)
    x, y = P[:, 0].copy(), P[:, 1].copy()
    xn, yn = x[nxt], y[nxt]
    pairs = []
    adj = _adjacent_overlaps(P, nxt, xn - x, yn - y)
    # the broad phase sees the loops scaled by a power of two to a box within [-1, 1]: a
    # monotone map of each coordinate (exact, or rounded for tiny coordinates beside huge ones),
    # which keeps every box overlap, and keeps the grid's arithmetic away from overflow
    # (1 / h for subnormal coordinates) and from underflow; the exact tests see P itself
    top = float(np.max(np.abs(P))) if k else 0.0
    if top > 0:
        x, y, xn, yn = (np.ldexp(a, -int(np.frexp(top)[1])) for a in (x, y, xn, yn))
    if adj.size:
        a, b = adj, nxt[adj]
        pairs.append(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1))
    if k > 3:
        i, j = _grid_candidates(np.minimum(x, xn), np.minimum(y, yn), np.maximum(x, xn), np.maximum(y, yn), nxt)
        hit = _segments_meet(P[i], P[nxt[i]], P[j], P[nxt[j]])
        i, j = i[hit], j[hit]
        pairs.append(np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    out = np.concatenate(pairs).astype(np.int64)
    return np.unique(out, axis=0) if len(out) else out.reshape(0, 2)


def polygon_orientation(P) -> int:
    """Orientation of a simple polygon: ``+1`` counter-clockwise, ``-1`` clockwise.  Exact.

    The turn at the lexicographically smallest vertex (a vertex of the convex hull) has the
    polygon's orientation.  ``0`` means that turn is flat, which a simple polygon cannot have.

    Parameters
    ----------
    P : (k, 2) float array, k >= 3, vertices in order.
    """
    P = _as_polygon(P)
    x = P[:, 0]
    ties = np.flatnonzero(x == x.min())
    v = int(ties[np.argmin(P[ties, 1])])
    k = len(P)
    tri = P[[(v - 1) % k]], P[[v]], P[[(v + 1) % k]]
    return int(orient2d(*tri)[0])

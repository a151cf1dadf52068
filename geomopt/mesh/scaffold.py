"""The scaffold of bijective parameterization (:mod:`geomopt.bijective`) as a 2D mesh: built
around a simple boundary polygon and kept a valid triangulation as the map moves.

Built and maintained without a triangulation library and with exact predicates only (:func:`geomopt.exact.predicates.orient2d`):

* the enclosing polygon is the convex hull of the boundary polygon scaled by ``ring_scale``
  about an interior point; the ring between hull and scaled hull is cut into trapezoids, each
  split into two triangles;
* the pockets between the boundary polygon and its hull are ear-clipped;
* Steiner points are added inside (:func:`refine_scaffold`: longest-edge bisection towards a
  size graded from the local boundary edge length), so that scaffold triangles have free
  vertices and are not long and thin: a scaffold whose every vertex sits on the boundary or the
  enclosing polygon cannot deform on its own, and its thin triangles collapsed within 0.06-0.3
  of a Newton step wherever the boundary slid along itself (bunny_cut);
* every re-triangulation is a round of Lawson edge flips (each flip checked exactly to keep both
  new triangles positive) towards the constrained Delaunay triangulation of the same vertices.
  Flips keep the numbers of vertices, triangles and edges, so the combined problem keeps its
  array shapes and its Hessian's non-zero count: nothing is recompiled between outer iterations.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._runtime.errors import MeshError, ParameterError
from ..exact.predicates import orient2d

__all__ = ["Scaffold", "build_scaffold", "refine_scaffold", "delaunay_flips", "ear_clip", "interior_pairs",
           "rest_inverse"]


_CCW_ERR = (3.0 + 16.0 * 2.0**-53) * 2.0**-53  # Shewchuk's orient2d stage-A bound


def _turn(a, b, c) -> int:
    """Exact sign of ``orient2d(a, b, c)`` for three points given as float pairs (scalar path:
    float determinant with Shewchuk's error bound, the exact predicate when uncertain)."""
    acx, acy, bcx, bcy = a[0] - c[0], a[1] - c[1], b[0] - c[0], b[1] - c[1]
    left, right = acx * bcy, acy * bcx
    det = left - right
    if abs(det) > _CCW_ERR * (abs(left) + abs(right)) and min(
            abs(v) for v in (acx, acy, bcx, bcy) if v != 0) >= 2.0**-300:
        return 1 if det > 0 else -1
    return int(orient2d(np.array([a]), np.array([b]), np.array([c]))[0])


def _hull_positions(P) -> np.ndarray:
    """Positions (indices into ``P``) of the vertices of a simple counter-clockwise polygon
    ``P`` (k, 2) that lie on the boundary of its convex hull, in polygon order.

    Strict hull vertices by Andrew's monotone chain with exact turns; then every polygon vertex
    on a hull edge (exactly collinear with it) is added, so that each pocket between the polygon
    and its hull is bounded by a chain that touches the hull only at its two ends."""
    k = len(P)
    order = np.lexsort((P[:, 1], P[:, 0]))
    pts = P.tolist()
    lower, upper = [], []
    for i in order.tolist():
        while len(lower) >= 2 and _turn(pts[lower[-2]], pts[lower[-1]], pts[i]) <= 0:
            lower.pop()
        lower.append(i)
    for i in order[::-1].tolist():
        while len(upper) >= 2 and _turn(pts[upper[-2]], pts[upper[-1]], pts[i]) <= 0:
            upper.pop()
        upper.append(i)
    strict = np.array(lower[:-1] + upper[:-1], dtype=np.int64)  # counter-clockwise hull
    # hull vertices in polygon order (a simple polygon meets its hull boundary in hull order)
    strict = np.sort(strict)
    # assign every polygon position to the hull edge (strict[e], strict[e + 1]) whose chain holds it
    pos = np.arange(k)
    e = np.searchsorted(strict, pos, side="right") - 1  # -1: before the first hull vertex
    e = np.where(e < 0, len(strict) - 1, e)
    a, b = strict[e], strict[(e + 1) % len(strict)]
    on = orient2d(P[a], P[b], P) == 0
    return np.flatnonzero(on)  # includes the strict hull vertices (orient 0 with their own edge)


def ear_clip(Q) -> list:
    """Triangles (index triples into ``Q``, counter-clockwise) of a simple counter-clockwise
    polygon ``Q`` (p, 2), by ear clipping with exact predicates.

    An ear is a strictly convex vertex whose closed triangle holds no other (reflex or flat)
    vertex; a simple polygon with more than 3 vertices always has one (Meisters 1975)."""
    p = len(Q)
    if p == 3:
        return [(0, 1, 2)]
    pts = Q.tolist()
    prv = [(i - 1) % p for i in range(p)]
    nxt = [(i + 1) % p for i in range(p)]
    alive = np.ones(p, dtype=bool)
    reflex = np.zeros(p, dtype=bool)
    for i in range(p):
        reflex[i] = _turn(pts[prv[i]], pts[i], pts[nxt[i]]) <= 0
    X, Y = Q[:, 0], Q[:, 1]
    tris = []
    i, left, misses = 0, p, 0
    while left > 3:
        a, c = prv[i], nxt[i]
        ear = not reflex[i]
        if ear:
            cand = np.flatnonzero(reflex & alive)
            if cand.size:
                ax, ay, bx, by, cx, cy = pts[a] + pts[i] + pts[c]
                box = ((X[cand] >= min(ax, bx, cx)) & (X[cand] <= max(ax, bx, cx))
                       & (Y[cand] >= min(ay, by, cy)) & (Y[cand] <= max(ay, by, cy)))
                cand = cand[box]
                cand = cand[(cand != a) & (cand != c)]
            pa, pb, pc = pts[a], pts[i], pts[c]
            ear = not any(_turn(pa, pb, pts[r]) >= 0 and _turn(pb, pc, pts[r]) >= 0
                          and _turn(pc, pa, pts[r]) >= 0 for r in cand.tolist())
        if ear:
            tris.append((a, i, c))
            alive[i] = False
            nxt[a], prv[c] = c, a
            left -= 1
            for j in (a, c):
                reflex[j] = _turn(pts[prv[j]], pts[j], pts[nxt[j]]) <= 0
            i, misses = a, 0
        else:
            i = c
            misses += 1
            if misses > left:
                raise MeshError("ear clipping found no ear: the scaffold pocket is not a simple "
                                "polygon (the start map's boundary must not touch itself)")
    i = int(np.flatnonzero(alive)[0])
    tris.append((prv[i], i, nxt[i]))
    return tris


@dataclasses.dataclass(frozen=True, eq=False)
class Scaffold:
    """A triangulation of the ring between a boundary polygon and an enclosing polygon.

    Attributes
    ----------
    outer : (h, 2) float64, positions of the enclosing polygon's vertices (counter-clockwise).
    triangles : (k + h, 3) int64, counter-clockwise; ids ``0 .. k-1`` are the boundary polygon's
        vertices (positions in its loop), ``k .. k+h-1`` the enclosing polygon's.
    """

    outer: np.ndarray
    triangles: np.ndarray


def build_scaffold(P, ring_scale: float = 3.0) -> Scaffold:
    """Triangulate the region between a simple counter-clockwise polygon and an enclosing one.

    Parameters
    ----------
    P : (k, 2) float array, the boundary polygon (simple, counter-clockwise; see
        :func:`geomopt.exact.certify.polygon_crossings`).
    ring_scale : float > 1, the enclosing polygon is the convex hull of ``P`` scaled by this
        factor about the mean of the hull vertices.

    Returns
    -------
    :class:`Scaffold` with ``k + h`` triangles (``h`` hull vertices), every one positively
    oriented (checked exactly), followed by :func:`delaunay_flips`.

    Raises
    ------
    MeshError
        ``P`` is not simple and counter-clockwise (ear clipping finds no ear), or is degenerate.
    """
    if not ring_scale > 1:
        raise ParameterError(f"ring_scale must be > 1, got {ring_scale}")
    P = np.asarray(P, dtype=np.float64)
    k = len(P)
    hull = _hull_positions(P)
    if len(hull) < 3:
        raise MeshError("the boundary polygon is degenerate (its convex hull has no area)")
    centre = P[hull].mean(axis=0)
    outer = centre + ring_scale * (P[hull] - centre)
    h = len(hull)
    tris = []
    # ring: the trapezoid (hull[j], hull[i], outer[i], outer[j]), j = i + 1, counter-clockwise
    # (the hull runs counter-clockwise, the ring lies to its right), split along hull[i]-outer[j]
    i = np.arange(h)
    j = (i + 1) % h
    tris.append(np.stack([hull[i], k + i, k + j], axis=1))
    tris.append(np.stack([hull[j], hull[i], k + j], axis=1))
    # pockets: the chain from hull[t] to hull[t+1] runs with the polygon's inside on its left,
    # so the pocket (on its right) is the reversed chain closed by the hull edge
    for t in range(h):
        a, b = int(hull[t]), int(hull[(t + 1) % h])
        gap = (b - a) % k
        if gap <= 1:
            continue
        chain = (a + np.arange(gap + 1)) % k
        pocket = chain[::-1]
        tris.append(pocket[np.asarray(ear_clip(P[pocket]), dtype=np.int64)])
    T = np.concatenate(tris).astype(np.int64)
    X = np.concatenate([P, outer])
    bad = orient2d(X[T[:, 0]], X[T[:, 1]], X[T[:, 2]]) != 1
    if bad.any() or len(T) != k + h:
        raise MeshError(
            f"could not build a valid scaffold ({int(bad.sum())} non-positive of {len(T)} "
            f"triangles, {k + h} expected): the boundary polygon must be simple and "
            f"counter-clockwise")
    T, _ = delaunay_flips(X, T)
    return Scaffold(outer, T)


def interior_pairs(T):
    """``(h1, h2)``: the two half-edges (``3 f + c`` runs ``T[f, c] -> T[f, c + 1]``) of every
    edge used by exactly two triangles of ``T`` (t, 3), ``h1 < h2``, the edges in the order of
    their vertex pairs ``(min, max)`` (the row order of
    :func:`~geomopt.exact.topology.unique_edges`).  One stable sort of the edge keys: this runs
    once per flip or split round, hundreds of times per scaffold."""
    T = np.asarray(T, dtype=np.int64).reshape(-1, 3)
    if len(T) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    a, b = T.ravel(), T[:, [1, 2, 0]].ravel()
    keys = np.minimum(a, b) * (int(T.max()) + 1) + np.maximum(a, b)
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    same = k[1:] == k[:-1]  # positions i, i + 1 of one edge
    # exactly two: a run of length 2 (neither neighbour pair of the same edge)
    two = same & np.r_[True, ~same[:-1]] & np.r_[~same[1:], True]
    i = np.flatnonzero(two)
    return order[i], order[i + 1]


def _opposite_angles_cot(X, a, b, c):
    """cot of the angle at ``c`` in triangles ``(a, b, c)`` (vectorised)."""
    u, v = X[a] - X[c], X[b] - X[c]
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    dot = u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return dot / cross


def delaunay_flips(X, T, max_rounds: int = 200, tol: float = 1e-9):
    """Lawson flips of the interior edges of a triangulation towards a Delaunay one.

    An edge shared by two triangles of ``T`` is flipped when the angles opposite it sum to more
    than pi (``cot alpha + cot beta < -tol``, evaluated in floats: it only steers quality) and both
    new triangles are positively oriented (exact).  Edges used by one triangle of ``T`` (here the
    mesh boundary and the enclosing polygon) are never flipped: the result is the constrained
    Delaunay triangulation of the same vertices, up to the tolerance.  Each round flips an
    independent set (an edge is flipped when it is the worst edge of both its triangles).

    Parameters
    ----------
    X : (N, 2) float, vertex positions;  T : (t, 3) int, counter-clockwise triangles.
    max_rounds : int;  tol : float.

    Returns
    -------
    T : (t, 3) int64, the new triangles (same count);  flips : int, the number of flips.
    """
    T = np.array(T, dtype=np.int64)
    flips = 0
    for _ in range(max_rounds):
        h1, h2 = interior_pairs(T)  # half-edge 3 f + c runs T[f, c] -> T[f, c+1]; opposite T[f, c+2]
        f1, c1, f2, c2 = h1 // 3, h1 % 3, h2 // 3, h2 % 3
        a, b = T[f1, c1], T[f1, (c1 + 1) % 3]
        c, d = T[f1, (c1 + 2) % 3], T[f2, (c2 + 2) % 3]
        bad = -(_opposite_angles_cot(X, a, b, c) + _opposite_angles_cot(X, b, a, d))
        cand = bad > tol
        if not cand.any():
            break
        idx = np.flatnonzero(cand)
        # exact: both new triangles (c, a, d) and (d, b, c) positive
        ca, cb, cc, cd = X[a[idx]], X[b[idx]], X[c[idx]], X[d[idx]]
        ok = (orient2d(cc, ca, cd) == 1) & (orient2d(cd, cb, cc) == 1)
        idx = idx[ok]
        if idx.size == 0:
            break
        # independent set: each triangle claims its worst candidate edge
        claim = np.full(len(T), -np.inf)
        np.maximum.at(claim, f1[idx], bad[idx])
        np.maximum.at(claim, f2[idx], bad[idx])
        idx = idx[(claim[f1[idx]] == bad[idx]) & (claim[f2[idx]] == bad[idx])]
        # ties: keep one edge per triangle
        _, first = np.unique(np.concatenate([f1[idx], f2[idx]]), return_index=True)
        owner = np.zeros(2 * idx.size, dtype=bool)
        owner[first] = True
        idx = idx[owner[: idx.size] & owner[idx.size:]]
        if idx.size == 0:
            break
        T[f1[idx]] = np.stack([c[idx], a[idx], d[idx]], axis=1)
        T[f2[idx]] = np.stack([d[idx], b[idx], c[idx]], axis=1)
        flips += idx.size
    return T, flips


def _size_field(P, grading):
    """Target edge length at points, (q, 2) -> (q,): the length of the boundary edges at the
    nearest vertex of the closed polygon ``P`` (k, 2), plus ``grading`` times the distance to it."""
    from scipy.spatial import cKDTree

    length = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)  # edge i: P[i] -> P[i + 1]
    local = 0.5 * (length + np.roll(length, 1))
    tree = cKDTree(P)

    def size(Q):
        d, i = tree.query(Q)
        return local[i] + grading * d

    return size


def refine_scaffold(X, T, k, grading=1.0, ratio=1.5, max_points=None, max_rounds=40):
    """Add Steiner points inside a scaffold until its triangles are about as large as the
    boundary edges near them, growing by ``grading`` per unit of distance from the boundary.

    Without interior vertices every scaffold triangle has all its corners on the mesh boundary
    or the enclosing polygon, so it cannot deform on its own: where the boundary slides along
    itself, the long thin triangles of a pocket collapse within a fraction of a step and cap the
    injective line search (0.06-0.3 of a Newton step on bunny_cut).  With interior vertices the
    Newton step extends the boundary's motion elastically into the scaffold.

    Each round splits every triangle whose longest edge exceeds ``ratio`` times the target size
    at its centroid (an independent set of them) at the midpoint of that edge: both triangles
    when the edge is shared (longest-edge bisection), that triangle alone when the edge is on
    the enclosing polygon (which gains a vertex); a triangle whose longest edge is a mesh
    boundary edge is not split.  Every new triangle is checked positive exactly (a split that
    fails the check is skipped).  Each round ends with a few rounds of :func:`delaunay_flips`,
    the refinement with all of them.

    Parameters
    ----------
    X : (N, 2) float, vertex positions, the first ``k`` the boundary polygon's (counter-clockwise).
    T : (t, 3) int, counter-clockwise scaffold triangles.
    k : int, number of boundary polygon vertices;  grading, ratio : float > 0.
    max_points : int, cap on the Steiner points added (default ``4 k``);  max_rounds : int.

    Returns
    -------
    X : (N + s, 2) float64 with the ``s`` Steiner points appended;  T : (t', 3) int64,
    counter-clockwise, ``t + s <= t' <= t + 2 s``.
    """
    X = np.array(X, dtype=np.float64)
    T = np.array(T, dtype=np.int64)
    size = _size_field(X[:k], grading)
    budget = 4 * k if max_points is None else int(max_points)
    added = 0
    for _ in range(max_rounds):
        if added >= budget:
            break
        X, T, new = _split_round(X, T, k, size, ratio, budget - added)
        if not new:
            break
        added += new
        # a few flip rounds between splits keep the shapes good (bunny_cut: 5th percentile of the
        # smallest angle 10.8 degrees, 13 with full flips); all of them only at the end
        T, _ = delaunay_flips(X, T, max_rounds=5)
    T, _ = delaunay_flips(X, T)
    return X, T


def _split_round(X, T, k, size, ratio, budget):
    """One round of :func:`refine_scaffold`: ``(X, T, added)`` after splitting an independent
    set of the (at most ``budget``) triangles most over size at their longest edges."""
    A, B, C = X[T[:, 0]], X[T[:, 1]], X[T[:, 2]]
    L = np.stack([np.linalg.norm(B - A, axis=1), np.linalg.norm(C - B, axis=1),
                  np.linalg.norm(A - C, axis=1)], axis=1)  # edge c runs T[c] -> T[c + 1]
    longest = np.argmax(L, axis=1)
    lmax = L[np.arange(len(T)), longest]
    over = lmax / (ratio * size((A + B + C) / 3.0))
    cand = np.flatnonzero(over > 1.0)
    if cand.size == 0:
        return X, T, 0
    cand = cand[np.argsort(-over[cand], kind="stable")][:budget]
    other = np.full(len(T) * 3, -1, dtype=np.int64)  # twin half-edge, -1 on a constrained edge
    h1, h2 = interior_pairs(T)
    other[h1], other[h2] = h2, h1
    c = longest[cand]
    h = other[3 * cand + c]
    splittable = (h >= 0) | (T[cand, c] >= k) | (T[cand, (c + 1) % 3] >= k)  # not a mesh edge
    cand, c, h = cand[splittable], c[splittable], h[splittable]
    g = np.where(h >= 0, h // 3, 0)
    shared = h >= 0
    a, b, o = T[cand, c], T[cand, (c + 1) % 3], T[cand, (c + 2) % 3]
    q = np.where(shared, T[g, (h % 3 + 2) % 3], o)
    m = 0.5 * (X[a] + X[b])  # midpoint of the longest edge a-b
    ok = (orient2d(X[a], m, X[o]) == 1) & (orient2d(m, X[b], X[o]) == 1)
    ok &= ~shared | ((orient2d(X[b], m, X[q]) == 1) & (orient2d(m, X[a], X[q]) == 1))
    # an independent set: each triangle goes to its highest-priority split
    rank = np.arange(len(cand), 0, -1, dtype=np.float64) * ok
    claim = np.zeros(len(T))
    np.maximum.at(claim, cand, rank)
    np.maximum.at(claim, g[shared], rank[shared])
    take = ok & (claim[cand] == rank) & (~shared | (claim[g] == rank))
    if not take.any():
        return X, T, 0
    f, a, b, o, q, m, g, shared = (v[take] for v in (cand, a, b, o, q, m, g, shared))
    v = len(X) + np.arange(len(f))
    T = T.copy()
    T[f] = np.stack([a, v, o], axis=1)
    gs = g[shared]
    T[gs] = np.stack([b[shared], v[shared], q[shared]], axis=1)
    X = np.concatenate([X, m])
    T = np.concatenate([T, np.stack([v, b, o], axis=1), np.stack([v[shared], a[shared], q[shared]], axis=1)])
    return X, T, len(f)


def rest_inverse(X, T):
    """Inverse edge matrices ``[x1 - x0, x2 - x0]^-1`` (t, 2, 2) of positively oriented
    triangles: the current shape taken as rest shape."""
    D = np.stack([X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]], axis=2)
    return np.linalg.inv(D)

"""Globally bijective free-boundary parameterization with a scaffold (SCAF).

Jiang, Schaefer, Panozzo (2017), "Simplicial complex augmentation framework for bijective
maps": the region between the UV boundary and an enclosing polygon is triangulated (the
*scaffold*), and the mesh and the scaffold are solved as one problem with the injective line
search.  No scaffold triangle can invert, so two parts of the boundary can never cross; the
scaffold's rest shape is reset to its current shape before each solve, and it is re-triangulated
between solves, so it only resists a step that would close a gap.

How this module builds and maintains the scaffold, without a triangulation library and with
exact predicates only (:func:`geomopt.exact.predicates.orient2d`):

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

By default the solve starts without a scaffold and builds it only when the boundary would
otherwise overlap (see :func:`bijective_parameterize`, ``lazy``): the scaffold costs steps in the
early, large-deformation phase, which the boundary of a Tutte start rarely needs.  Both phases run
in the one loop (:func:`geomopt.solvers.iterate`): the scaffold-free phase under a *guard*
(:class:`SimpleBoundary`: shorten a step that would make the boundary overlap), the scaffold's
outer iterations as a *continuation* (:class:`ScaffoldContinuation`).

The enclosing polygon's vertices are free (the scaffold moves and rotates with the mesh); global
injectivity of the result does not rest on that: it is certified at the end, exactly, by
:func:`geomopt.exact.certify.certify_bijective`.
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import numpy as np

from ._runtime.config import Instance, Int, Maybe, Real, validate
from ._runtime.errors import MeshError, ParameterError, SolveError
from .objective.objective import Objective
from ._runtime.x64 import float64
from .exact.certify import certify_bijective, polygon_crossings
from .exact.predicates import orient2d
from .mesh.problem import Problem
from .solvers import (AbstractContinuation, AbstractNewton, Decision, Final, Outcome, ParamDetails, Progress,
                      Trace, get_solver, iterate)
from .solvers._iterate import check_progress
from .exact.topology import check_disk, unique_edges
from .mesh.tutte import optimal_scale, scale_to_area, tutte_embedding

__all__ = ["Scaffold", "build_scaffold", "refine_scaffold", "delaunay_flips", "bijective_parameterize",
           "ScaffoldOptions", "ScaffoldContinuation", "SimpleBoundary"]

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


def _ear_clip(Q) -> list:
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
        tris.append(pocket[np.asarray(_ear_clip(P[pocket]), dtype=np.int64)])
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
        E, count, edge_of = unique_edges(T)
        he = edge_of.ravel()  # half-edge 3 f + c runs T[f, c] -> T[f, c+1]; opposite T[f, c+2]
        shared = count[he] == 2
        hs = np.flatnonzero(shared)
        hs = hs[np.argsort(he[hs], kind="stable")]
        h1, h2 = hs[0::2], hs[1::2]  # the two half-edges of every interior edge
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
    _, count, edge_of = unique_edges(T)
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
    he = edge_of.ravel()
    other = np.full(len(T) * 3, -1, dtype=np.int64)  # twin half-edge, -1 on a constrained edge
    hs = np.flatnonzero(count[he] == 2)
    hs = hs[np.argsort(he[hs], kind="stable")]
    other[hs[0::2]], other[hs[1::2]] = hs[1::2], hs[0::2]
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


def _rest_inverse(X, T):
    """Inverse edge matrices ``[x1 - x0, x2 - x0]^-1`` (t, 2, 2) of positively oriented
    triangles: the current shape taken as rest shape."""
    D = np.stack([X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]], axis=2)
    return np.linalg.inv(D)


def _interior_first(F, loop):
    """A row order (m,) of ``F`` whose first triangle starts with an interior vertex if any.

    The objective pins the first vertex of the first element (translation); when that vertex is
    interior, scaffold flips never change the free-DOF sparsity pattern (else they may, and the
    Hessian kernel recompiles for the new non-zero count: slower, still correct)."""
    on = np.zeros(int(F.max()) + 1, dtype=bool)
    on[loop] = True
    rows = np.flatnonzero(~on[F[:, 0]])
    order = np.arange(len(F))
    if rows.size:
        order[[0, rows[0]]] = order[[rows[0], 0]]
    return order


#: fractions of a scaffold-free step tried when the whole step makes the boundary overlap, and
#: how many shortened steps in a row are taken before the scaffold is built (bunny_cut: 3 free
#: iterations without shortening, 5 with; the scaffold phase then starts nearer the optimum)
_SHORTEN = (0.5, 0.25)
_MAX_CUTS = 2


def _simple(P) -> bool:
    """Whether the polygon ``P`` (k, 2) is finite and simple (exact)."""
    return bool(np.isfinite(P).all()) and len(polygon_crossings(P)) == 0


class SimpleBoundary:
    """A guard for :func:`~geomopt.solvers.iterate`: keep the boundary polygon ``x[loop]``
    simple (exact check, :func:`polygon_crossings`).

    A step after which the boundary overlaps itself is moved back to the first of
    ``fractions`` of it at which the boundary is simple and the energy below the old one (the
    injective line search bounded the whole step, so no triangle inverts on a part of it;
    ``solver.restart(new, x)`` drops a memory of the whole step, e.g. L-BFGS's pairs); after
    ``max_cuts`` shortened steps in a row, or when no fraction helps, the phase ends at the old
    iterate (None)."""

    def __init__(self, loop, fractions=_SHORTEN, max_cuts: int = _MAX_CUTS):
        self.loop, self.fractions, self.max_cuts = loop, tuple(fractions), int(max_cuts)
        self.cuts = 0  # consecutive steps shortened to keep the boundary simple

    def __call__(self, solver, old, new):
        if not new.stats.accepted or new.stats.broken or _simple(np.asarray(new.x)[self.loop]):
            self.cuts = 0
            return new
        if self.cuts >= self.max_cuts:
            return None
        obj, x, dx = old.objective, old.x, new.x - old.x
        for s in self.fractions:
            xs = x + s * dx
            if not _simple(np.asarray(xs)[self.loop]):
                continue
            if float(obj.value(xs, old.params)) < old.value:
                self.cuts += 1
                return solver.restart(new, x=xs).update(step_size=s * new.step_size)
        return None


@dataclasses.dataclass(frozen=True)
class ScaffoldOptions:
    """The scaffold's settings in :func:`bijective_parameterize` (validated).

    Attributes
    ----------
    scaffold_weight : float > 0, the scaffold's share of the energy (its weights sum to
        ``scaffold_weight`` times the mesh area).  Smaller lets the boundary approach itself in
        fewer outer iterations but cuts more Newton steps short where the scaffold is compressed;
        it does not change what is reachable.  On bunny_cut (outer_rtol 1e-5, inner solves
        converged fully) 1e-3 took 61 solver iterations, 1e-4 62 and 1e-2 84.
    ring_scale : float > 1, size of the enclosing polygon relative to the start's convex hull.
    inner_steps : int >= 1 or None, solver iterations per outer iteration; None (default): 10
        for Newton-type solvers (Newton, SLIM, CM), 50 for the others (L-BFGS, AQP, optimistix:
        their memory or acceleration restarts with every new scaffold, so ten steps a round
        left L-BFGS on the spiral strip at 597-1,000+ iterations depending on the Laplacian
        backend's rounding; fifty: 45 iterations whatever the backend).
    max_outer : int >= 1, the outer iteration limit.
    outer_rtol : float > 0 (1e-4: the mesh energy is then within about 1e-4 of the outer
        loop's limit, measured 4e-5 above the 1e-5 result on bunny_cut, for 30 instead of 40
        solver iterations); Newton-type inner solves stop when the decrement is below
        ``0.1 * outer_rtol`` relative (or the solver's own ``rtol``, if larger).
    lazy : start without a scaffold (see :func:`bijective_parameterize`).
    """

    scaffold_weight: float = 1e-3
    ring_scale: float = 3.0
    inner_steps: int | None = None
    max_outer: int = 100
    outer_rtol: float = 1e-4
    lazy: bool = True

    def __post_init__(self):
        validate(self, scaffold_weight=Real(0.0, lo_open=True), ring_scale=Real(1.0, lo_open=True),
                 inner_steps=Maybe(Int(1)), max_outer=Int(1), outer_rtol=Real(0.0, lo_open=True), lazy=Instance(bool))


class FreeRecord(NamedTuple):
    """The scaffold-free phase (``trace.phases[0]`` when lazy): its iterations, the mesh's
    mean energy after it, and its outcome (None: the boundary was about to overlap)."""

    iterations: int
    mean_energy: float
    outcome: Outcome | None

    def line(self, k: int) -> str:
        how = "(boundary about to overlap: scaffold)" if self.outcome is None else self.outcome.value
        return f"free  {self.iterations:4d} iterations  energy {self.mean_energy:.10g}  {how}"


class ScaffoldRecord(NamedTuple):
    """One outer iteration with the scaffold: its number, the mesh's mean energy after it,
    the inner iterations and outcome, and the Delaunay flips that followed."""

    outer: int
    mean_energy: float
    inner: int
    outcome: Outcome | None
    flips: int

    def line(self, k: int) -> str:
        how = self.outcome.value if self.outcome is not None else "stopped"
        return (f"outer {self.outer:3d}  energy {self.mean_energy:.10g}  inner {self.inner:3d} ({how})  "
                f"flips {self.flips:5d}")


class ScaffoldContinuation(AbstractContinuation):
    """The outer loop of the bijective mode as a continuation of :func:`~geomopt.solvers.iterate`.

    The first phase (``lazy``) runs on the mesh alone under :class:`SimpleBoundary`: when it
    ends on its own the result is the plain solve's; when the guard ends it, the scaffold is
    built around the last iterate and each later phase solves mesh + scaffold with ``inner``
    for up to ``inner_steps`` iterations, then re-triangulates the scaffold
    (:func:`delaunay_flips`), until an inner solve converged and the mesh energy fell by less
    than ``outer_rtol`` (relative), or ``max_outer``.  ``finish`` certifies the mesh's map
    exactly (:func:`~geomopt.exact.certify.certify_bijective`).
    """

    def __init__(self, problem, objective, loop, inner, options, start, scale):
        self.problem, self.objective, self.loop, self.inner, self.opts = problem, objective, loop, inner, options
        self.start_map, self.scale = start, scale
        n = problem.n_vertices
        order = _interior_first(problem.simplices, loop)
        self.mesh = problem.simplices[order], problem.rest_inv[order], problem.volumes[order]
        self.X, self.S = start, None  # the last certified-finite map (mesh + scaffold vertices)
        self.energies, self.times = [self._mesh_energy(start)], [0.0]
        self.free = self.flips = self.outer = 0
        self.n, self.weight = n, 0.0
        self.t0 = time.perf_counter()

    def _mesh_energy(self, X) -> float:
        return float(self.objective.value(np.asarray(X)[: self.problem.n_vertices], self.objective.params()))

    def _combined(self, X, S):
        """The planar problem of mesh + scaffold (the scaffold's current shape its rest shape)."""
        rows, inv, vol = self.mesh
        simplices = np.concatenate([rows, S])
        problem = dataclasses.replace(
            self.problem, kind="planar", n_vertices=len(X), simplices=simplices, input_simplices=simplices,
            rest_inv=np.concatenate([inv, _rest_inverse(X, S)]),
            volumes=np.concatenate([vol, np.full(len(S), self.weight)]), rest_vertices=X)
        return Objective(problem, self.objective.energy)

    def scaffolded(self, X):
        """``(objective, X)``: the scaffold built around the map ``X`` (n, 2) (refined), the
        combined objective and the map with the scaffold's vertices appended."""
        X = np.asarray(X)[: self.n]
        scaffold = build_scaffold(X[self.loop], self.opts.ring_scale)
        k = len(self.loop)
        Xs, Ts = refine_scaffold(np.concatenate([X[self.loop], scaffold.outer]), scaffold.triangles, k)
        ids = np.concatenate([self.loop, self.n + np.arange(len(Xs) - k)])  # scaffold id -> vertex
        self.S, self.X = ids[Ts], np.concatenate([X, Xs[k:]])
        self.weight = self.opts.scaffold_weight * self.objective.total_volume / len(self.S)
        return self._combined(self.X, self.S), self.X

    def _log(self, X):
        self.energies.append(self._mesh_energy(X))
        self.times.append(time.perf_counter() - self.t0)
        return self.energies[-1] / self.objective.total_volume

    def __call__(self, state, outcome) -> Decision:
        if self.S is None:  # the scaffold-free phase ended
            self.free, self.X = state.iteration, np.asarray(state.x)
            record = FreeRecord(self.free, self._log(self.X), outcome)
            if outcome is not None:
                return Decision.stop_with(outcome, record=record)
            objective, X = self.scaffolded(self.X)
            return Decision.go(objective=objective, x=X, solver=self.inner, record=record)
        X = np.asarray(state.x)
        if outcome is Outcome.NONFINITE or not np.isfinite(X).all():
            return Decision.stop_with(Outcome.NONFINITE)
        self.outer += 1
        self.X = X
        self.S, f = delaunay_flips(X, self.S)
        self.flips += f
        record = ScaffoldRecord(self.outer, self._log(X), state.iteration, outcome, f)
        drop = self.energies[-2] - self.energies[-1]
        if outcome is Outcome.CONVERGED and drop <= self.opts.outer_rtol * abs(self.energies[-1]):
            return Decision.stop_with(Outcome.CONVERGED, record=record)
        if self.outer >= self.opts.max_outer:
            return Decision.stop_with(Outcome.MAX_STEPS, f"stopped at the outer-iteration limit (max_outer="
                                      f"{self.opts.max_outer}) before converging", record=record)
        return Decision.go(objective=self._combined(X, self.S), x=X, record=record)

    def finish(self, state, outcome, reason) -> Final:
        x = np.asarray(self.X[: self.n])
        cert = certify_bijective(x, self.problem.simplices, self.loop)
        if outcome is Outcome.CONVERGED and not cert.globally_injective:
            outcome = Outcome.NOT_INJECTIVE
        details = ParamDetails(start=self.start_map, scale=self.scale, free_iterations=self.free,
                               flips=self.flips, scaffold_triangles=0 if self.S is None else len(self.S))
        return Final(x, outcome, cert, reason, problem=self.problem, objective=self.objective,
                     energy=self.energies[-1], volume=self.objective.total_volume, details=details)


def _inner_solver(solver, opts, named):
    """The scaffold phase's solver: ``solver`` with ``max_steps = inner_steps``; a Newton-type
    inner solve need not converge further than the outer loop's own tolerance (a quasi-Newton
    decrement is a poorer estimate: L-BFGS stopped 2.6e-4 high on the spiral); a solver given
    by name gets the search's 0.9 of the flip bound: AQP's and L-BFGS's default stops a quarter
    of the way to the first collapse (keeping real triangles from their barrier), but the
    steps the scaffold blocks are its own air triangles', which the next scaffold replaces (at
    0.25 L-BFGS on the spiral hit max_outer (100), at 0.9 it converged in 59 outer iterations).
    A search passed in a solver object is kept."""
    if not (dataclasses.is_dataclass(solver) and hasattr(solver, "max_steps")):
        raise ParameterError(f"the bijective mode needs a dataclass solver with a max_steps field "
                             f"(e.g. geomopt.Newton()), got {solver!r}")
    rtol = max(solver.rtol, 0.1 * opts.outer_rtol) if isinstance(solver, AbstractNewton) else solver.rtol
    steps = opts.inner_steps if opts.inner_steps is not None else (10 if isinstance(solver, AbstractNewton) else 50)
    inner = dataclasses.replace(solver, max_steps=int(steps), rtol=rtol)
    if named and inner.search.safety < 0.9:
        inner = dataclasses.replace(inner, search=dataclasses.replace(inner.search, safety=0.9))
    return inner


def _bijective_start(problem, objective, x0, weights, loop):
    """``(x0, scale)``: the start map (Tutte onto a circle by default), checked globally
    injective (exact), centred, scaled to the rest area and by :func:`optimal_scale`."""
    if x0 is None:
        x0 = tutte_embedding(problem.rest_vertices, problem.input_simplices, weights, boundary=loop)
    x0 = problem.check_map(x0, "start map x0")
    cert = certify_bijective(x0, problem.simplices, loop)
    if not cert.globally_injective:
        raise MeshError(
            f"the start map x0 is not globally injective ({cert.inverted} inverted triangle(s), "
            f"{len(cert.crossings)} crossing boundary edge pair(s), boundary orientation "
            f"{cert.orientation}); omit x0 for a Tutte start, or untangle it first")
    x0 = x0 - x0.mean(axis=0)
    x0 = scale_to_area(x0, problem.rest_vertices, problem.simplices)
    s = optimal_scale(objective, x0)
    return s * x0, s


@float64
def bijective_parameterize(V, F, energy="symmetric_dirichlet", solver=None, weights="uniform",
                           x0=None, progress=True, throw=False, *, options: ScaffoldOptions | None = None,
                           **kwargs):
    """Flatten a disk-topology surface to the plane with a free boundary, globally bijective.

    Solves the same problem as :func:`~geomopt.param.parameterize` with, around the mesh, a
    scaffold (SCAF, Jiang et al. 2017; see the module docstring) that keeps the boundary from
    touching itself.  The scaffold's triangles take the same energy as the mesh, each weighted by
    ``scaffold_weight * (mesh area) / (number of scaffold triangles)`` (as in SCAF, uniform rather
    than by area, so small gaps resist as much as large ones), with their current shape as rest
    shape (:class:`ScaffoldContinuation`).

    With ``lazy`` (default) the solver first runs on the mesh alone, for as long as every
    iterate's boundary stays simple (:class:`SimpleBoundary`), then the scaffold is built at the
    last iterate; where the free-boundary solve never overlaps, the result is the plain solve's.
    Every accepted iterate is bijective; between two iterates of the scaffold-free phase the
    straight path is not checked, which does not matter for the returned map.  ``lazy=False``
    uses the scaffold from the start (the boundary never crosses itself along the whole path).

    Parameters
    ----------
    V : (n, 3) float rest vertex positions;  F : (m, 3) int triangles of a topological disk.
    energy, solver, weights, throw : as for :func:`~geomopt.param.parameterize`; the solver's
        ``max_steps`` is replaced by ``inner_steps`` in the scaffold phase (a solver that is not
        a dataclass with ``max_steps`` is rejected).
    progress : bool, one line per phase on stderr.
    x0 : (n, 2) optional start map; it must be globally injective (the default, Tutte's
        embedding onto a circle, is).
    options : :class:`ScaffoldOptions`; ``kwargs`` naming its fields (``scaffold_weight``,
        ``ring_scale``, ``inner_steps``, ``max_outer``, ``outer_rtol``, ``lazy``) replace them,
        the others are energy parameters.

    Returns
    -------
    :class:`~geomopt.solvers.Result` for the mesh alone: ``x`` (n, 2), ``energy`` the mesh
    energy, ``trace.energy`` / ``trace.seconds`` the mesh energy and elapsed seconds at the
    start, after the scaffold-free phase (if ``lazy``) and after each outer iteration;
    ``stats.iterations`` the solver iterations summed, ``stats.outer_iterations`` the scaffold's.
    ``certificate`` is the exact :class:`~geomopt.exact.certify.Certificate` and ``injectivity`` is
    ``"global"`` when it holds; a result that is not globally injective has outcome
    ``NOT_INJECTIVE`` (never expected: the scaffold forbids it), so ``success`` means converged,
    flip-free and bijective.  ``details`` (:class:`~geomopt.solvers.ParamDetails`) holds the
    start and its scale, ``free_iterations``, ``flips`` and ``scaffold_triangles``.

    Raises
    ------
    MeshError : invalid or non-disk mesh, or a start map that is not globally injective.
    ParameterError : unknown energy/solver/weights name or an invalid parameter.
    SolveError : only with ``throw=True``, when the result is not converged and bijective.
    """
    names = {f.name for f in dataclasses.fields(ScaffoldOptions)}
    opts = dataclasses.replace(options or ScaffoldOptions(), **{k: kwargs.pop(k) for k in list(kwargs) if k in names})
    check_progress(progress, "bijective_parameterize")
    t_start = time.perf_counter()
    problem = Problem.surface(V, F)
    objective = Objective(problem, energy, **kwargs)
    named = solver is None or isinstance(solver, str)
    solver = get_solver("newton" if solver is None else solver)
    inner = _inner_solver(solver, opts, named)
    loop = check_disk(problem.input_simplices, problem.n_vertices)
    x0, s = _bijective_start(problem, objective, x0, weights, loop)
    cont = ScaffoldContinuation(problem, objective, loop, inner, opts, x0, s)
    report = Progress(iterations=False) if progress else None
    if opts.lazy:
        first, guard, start = solver, SimpleBoundary(loop), (objective, x0)
    else:
        first, guard, start = inner, None, cont.scaffolded(x0)
    setup = time.perf_counter() - t_start
    result = iterate(first, start[0], start[1], objective.params(), continuation=cont, guard=guard,
                     progress=report, trace=False, label="bijective solve", warn=not throw)
    result = dataclasses.replace(
        result, trace=Trace(np.asarray(cont.energies), np.asarray(cont.times), np.full(len(cont.times), np.nan),
                            None, result.trace.phases),
        stats=dataclasses.replace(result.stats, outer_iterations=cont.outer,
                                  setup_seconds=result.stats.setup_seconds + setup))
    if throw and not result.success:
        raise SolveError(f"bijective solve failed: {result.message}; injectivity {result.injectivity}", result)
    return result

"""Exact certificate of a texture atlas: every chart flip-free and injective, no two charts
overlapping, every UV inside the unit square.

An atlas is a map ``uv`` (n, 2) of triangles ``uv_faces`` (m, 3), each face carrying a chart id.
Chart ``c``'s *region* is the union of its triangles.  With every triangle positively oriented
(checked exactly), the number of triangles of chart ``c`` covering a point ``p`` off the boundary
equals the winding number about ``p`` of the chart's boundary loops, summed (the degree argument of
:mod:`geomopt.exact.certify`).  The certificate checks, exactly:

1. **inverted**: faces whose orientation (:func:`geomopt.exact.predicates.orient2d`) is not ``+1``.
2. **boundary crossings** (:func:`geomopt.exact.certify.loop_crossings` on all loops of all charts at
   once, one grid broad phase): two boundary edges that are not consecutive on one loop must not
   share any point (a crossing, a T-touch, a collinear overlap, two equal vertices); two
   consecutive ones must meet only at their common vertex.  A pair within one chart makes that
   chart *self-overlapping*, a pair across two charts makes them an *overlapping pair*.
3. **coverage**: with the loops pairwise disjoint and simple, chart ``c``'s coverage is constant
   between loops and changes by a loop's orientation ``s`` (+1 counter-clockwise) across it.
   Let ``W`` be the winding number, summed over the chart's *other* loops, at a vertex of loop
   ``L``: the coverage is ``W`` on one side of ``L`` and ``W + s`` on the other.  The chart is
   injective iff both are 0 or 1 for every loop (every region of the plane's arrangement borders
   some loop, or is the outside, covered 0 times).  A disk chart (one loop) needs ``s = +1``.
4. **containment**: two charts with disjoint boundaries overlap iff some loop of one lies inside
   the other's region (a component of the intersection of the regions is bounded by loops of one
   of them, which then lie inside the other's region, being connected and disjoint from its
   boundary); so one vertex of every loop is tested against every other chart whose bounding box
   holds it: coverage (summed winding) not zero means the pair overlaps.

Windings are exact: a crossing number along the ray ``+x`` from ``p`` with the half-open rule on
``y`` (exact float comparisons) and the side of each straddling edge from ``orient2d`` (D. Sunday,
"Inclusion of a point in a polygon", 2001; a point on an edge has already been reported by 2.).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .._runtime.errors import MeshError
from .._runtime.tracing import refuse_traced
from .._runtime.validate import validate_simplices
from ..exact.certify import loop_crossings
from ..exact.predicates import orient2d
from ..exact.topology import boundary_loops

__all__ = ["AtlasCertificate", "certify_atlas", "chart_boundary_loops"]

_PAIRS_PER_BLOCK = 1 << 22  # (query, edge) pairs held at once by the winding test


@dataclasses.dataclass(frozen=True)
class AtlasCertificate:
    """The outcome of :func:`certify_atlas`.

    Attributes
    ----------
    ok : bool, the atlas is certified: all of the below are empty or zero.
    inverted : (a,) int64, faces whose exact orientation is not positive (folded, mirrored,
        degenerate, or with a non-finite coordinate).
    self_overlapping : (b,) int64, charts that are not injective: a boundary loop crossing or
        touching itself or another loop of the chart, coverage above one or below zero (e.g. a
        clockwise, i.e. mirrored, boundary), no boundary at all, or a non-finite coordinate.
    overlapping_pairs : (c, 2) int64, chart pairs ``(a, b)``, ``a < b``, whose boundaries meet
        or one of which contains part of the other.
    out_of_range : int, rows of ``uv`` outside ``[0, 1]^2`` (or not finite).
    message : str, one line saying what was found.
    seconds : float, time taken.
    """

    ok: bool
    inverted: np.ndarray
    self_overlapping: np.ndarray
    overlapping_pairs: np.ndarray
    out_of_range: int
    message: str
    seconds: float = 0.0

    @property
    def locally_injective(self) -> bool:
        """The whole atlas is certified (as :attr:`ok`): what a :class:`~geomopt.solvers.Result` asks."""
        return bool(self.ok)

    @property
    def injectivity(self) -> str:
        """``"global"`` when certified (the atlas maps the surface one-to-one into the square),
        ``"local"`` when only no face is inverted, else ``"none"``."""
        return "global" if self.ok else ("local" if len(self.inverted) == 0 else "none")


def chart_boundary_loops(uv_faces, chart):
    """Boundary loops of every chart of an atlas.

    An edge is on chart ``c``'s boundary when no other face *of chart c* uses it reversed, so
    charts sharing UV rows still get their own loops.

    Parameters
    ----------
    uv_faces : (m, 3) int array, triangles into the UV rows.
    chart : (m,) int array, chart id of each face.

    Returns
    -------
    loops : list of (k_i,) int64 arrays, UV row ids of each loop, faces to its left
        (:func:`geomopt.exact.topology.boundary_loops`); loops of one chart are consecutive.
    loop_chart : (len(loops),) int64, the chart of each loop, ascending.
    """
    F = np.asarray(uv_faces, dtype=np.int64)
    chart = np.asarray(chart, dtype=np.int64)
    # one vertex per (chart, UV row): a loop never passes from one chart to another
    n = int(F.max()) + 1
    keys, local = np.unique(np.repeat(chart, 3) * n + F.ravel(), return_inverse=True)
    local_loops = boundary_loops(local.reshape(-1, 3))
    owner = np.array([keys[lp[0]] // n for lp in local_loops], dtype=np.int64)
    order = np.argsort(owner, kind="stable")  # largest loop first within a chart
    return [keys[local_loops[i]] % n for i in order], owner[order]


def _check_atlas(uv, uv_faces, chart):
    """The three arrays as float64 (n, 2), int64 (m, 3), int64 (m,), or a MeshError saying what
    is wrong.  Non-finite UVs are accepted: the certificate reports them."""
    uv = np.asarray(uv)
    if uv.ndim != 2 or uv.shape[1] != 2 or uv.dtype.kind not in "fiu" or len(uv) == 0:
        raise MeshError(f"uv must be a non-empty real array of shape (n, 2), got shape {uv.shape} "
                        f"and dtype {uv.dtype}")
    F = validate_simplices(uv_faces, len(uv), 3, name="uv_faces")
    chart = np.asarray(chart)
    if chart.shape != (len(F),) or chart.dtype.kind not in "iu" or (chart < 0).any():
        raise MeshError(f"chart must be one non-negative integer id per face, shape ({len(F)},), got shape "
                        f"{chart.shape} and dtype {chart.dtype}")
    return uv.astype(np.float64, copy=False), F, chart.astype(np.int64, copy=False)


def _loop_arrays(loops):
    """Rows of all loops end to end: ``rows`` (k,) the UV row of each loop vertex, ``nxt`` (k,) the
    next position along its loop, ``loop_of`` (k,) its loop index."""
    lengths = np.array([len(lp) for lp in loops], dtype=np.int64)
    start = np.cumsum(lengths) - lengths
    rows = np.concatenate(loops)
    loop_of = np.repeat(np.arange(len(loops)), lengths)
    pos = np.arange(len(rows))
    nxt = np.where(pos + 1 == (start + lengths)[loop_of], start[loop_of], pos + 1)
    return rows, nxt, loop_of


def _loop_orientations(P, nxt, loop_of, n_loops) -> np.ndarray:
    """(n_loops,) int8: the turn at each loop's lexicographically smallest vertex, which is the
    loop's orientation (+1 counter-clockwise) when the loop is simple.  Exact."""
    order = np.lexsort((P[:, 1], P[:, 0], loop_of))
    first = order[np.searchsorted(loop_of[order], np.arange(n_loops))]
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(len(nxt))
    return orient2d(P[prv[first]], P[first], P[nxt[first]])


def _windings(P, nxt, loop_of, q, edges) -> np.ndarray:
    """Winding numbers about the points ``P[q]`` of the edges ``edges`` (edge ``e`` runs from
    ``P[e]`` to ``P[nxt[e]]``), leaving out, for each point, the edges of its own loop.  Exact
    for points on no edge.  Returns (len(q),) int64."""
    out = np.zeros(len(q), np.int64)
    a, b = P[edges], P[nxt[edges]]
    ax, ay, bx, by = a[:, 0], a[:, 1], b[:, 0], b[:, 1]
    block = max(1, _PAIRS_PER_BLOCK // max(len(edges), 1))
    for s in range(0, len(q), block):
        qs = q[s:s + block]
        px, py = P[qs, 0][:, None], P[qs, 1][:, None]
        up = (ay <= py) & (py < by)
        down = (by <= py) & (py < ay)
        hit = (up | down) & (px <= np.maximum(ax, bx)) & (loop_of[edges] != loop_of[qs][:, None])
        i, e = np.nonzero(hit)
        side = np.ones(len(i), np.int8)  # +1: the edge crosses the ray right of the point
        near = np.flatnonzero(P[qs[i], 0] >= np.minimum(ax[e], bx[e]))
        o = orient2d(a[e[near]], b[e[near]], P[qs[i[near]]])
        side[near] = np.where(up[i[near], e[near]], o > 0, o < 0)
        sign = np.where(up[i, e], 1, -1) * side
        out[s:s + block] = np.bincount(i, weights=sign, minlength=len(qs)).astype(np.int64)
    return out


def _coverage_findings(P, nxt, loop_of, loop_chart):
    """Charts whose coverage is not 0/1 and chart pairs one of which holds a loop of the other
    (items 3 and 4 of the module docstring).  Returns (bad charts set, pairs set)."""
    n_loops = len(loop_chart)
    s = _loop_orientations(P, nxt, loop_of, n_loops).astype(np.int64)
    q = np.searchsorted(loop_of, np.arange(n_loops))  # first vertex of each loop
    edge_chart = loop_chart[loop_of]  # ascending: loops of a chart are consecutive
    charts = np.unique(loop_chart)
    first, last = np.searchsorted(edge_chart, charts), np.searchsorted(edge_chart, charts, side="right")
    lo, hi = np.minimum.reduceat(P, first), np.maximum.reduceat(P, first)
    Q = P[q]
    bad, pairs = set(), set()
    for c, a, b, l, h in zip(charts, first, last, lo, hi):
        edges = np.arange(a, b)
        inside = np.flatnonzero(((Q >= l) & (Q <= h)).all(axis=1))
        w = _windings(P, nxt, loop_of, q[inside], edges)
        own = loop_chart[inside] == c
        W, sl = w[own], s[inside[own]]
        if ((W < 0) | (W > 1) | (W + sl < 0) | (W + sl > 1)).any():
            bad.add(int(c))
        for other in np.unique(loop_chart[inside[~own & (w != 0)]]):
            pairs.add((min(int(c), int(other)), max(int(c), int(other))))
    return bad, pairs


def _message(n_charts, m, inverted, self_overlapping, pairs, out_of_range) -> str:
    if not (len(inverted) or len(self_overlapping) or len(pairs) or out_of_range):
        return (f"atlas certified: {n_charts} charts, {m} faces, every face positively oriented, every chart "
                f"injective, no two charts overlapping, every UV in [0, 1]^2")
    parts = []
    if len(inverted):
        parts.append(f"{len(inverted)} faces not positively oriented (first: face {inverted[0]})")
    if len(self_overlapping):
        parts.append(f"{len(self_overlapping)} charts not injective (first: chart {self_overlapping[0]})")
    if len(pairs):
        parts.append(f"{len(pairs)} overlapping chart pairs (first: {tuple(pairs[0].tolist())})")
    if out_of_range:
        parts.append(f"{out_of_range} UVs outside [0, 1]^2")
    return "atlas NOT certified: " + "; ".join(parts)


def certify_atlas(uv, uv_faces, chart) -> AtlasCertificate:
    """Exact certificate that an atlas is flip-free, its charts injective and disjoint, in range.

    Parameters
    ----------
    uv : (n, 2) float array, corner UVs (one row per chart corner; rows may also be shared).
    uv_faces : (m, 3) int array, triangles into ``uv``, counter-clockwise when valid.
    chart : (m,) int array, the chart id of each face.

    Returns
    -------
    :class:`AtlasCertificate`; ``ok`` iff no face is inverted, every chart is injective, no two
    charts overlap (boundaries disjoint, neither inside the other) and every UV lies in
    ``[0, 1]^2``: then the atlas maps every chart bijectively onto disjoint regions of the square.
    Every decision is exact (see the module docstring).

    Raises
    ------
    MeshError
        Wrong shapes or dtypes, or face indices out of range.
    """
    t0 = time.perf_counter()
    refuse_traced("certify_atlas (exact predicates)", "it certifies concrete atlases", uv)
    uv, F, chart = _check_atlas(uv, uv_faces, chart)
    inverted = np.flatnonzero(orient2d(uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]) != 1)
    out_of_range = int(np.count_nonzero(~((uv >= 0) & (uv <= 1)).all(axis=1)))
    charts = np.unique(chart)
    loops, loop_chart = chart_boundary_loops(F, chart)
    finite = np.isfinite(uv[F]).all(axis=(1, 2))
    unfit = set(np.unique(chart[~finite]).tolist()) | (set(charts.tolist()) - set(loop_chart.tolist()))
    keep = [i for i, c in enumerate(loop_chart) if int(c) not in unfit]
    bad, pairs = set(), set()
    if keep:
        loops, loop_chart = [loops[i] for i in keep], loop_chart[keep]
        rows, nxt, loop_of = _loop_arrays(loops)
        P = uv[rows]
        crossing = loop_crossings(P, nxt)
        ca, cb = loop_chart[loop_of[crossing[:, 0]]], loop_chart[loop_of[crossing[:, 1]]]
        bad = set(ca[ca == cb].tolist())
        pairs = set(zip(np.minimum(ca, cb)[ca != cb].tolist(), np.maximum(ca, cb)[ca != cb].tolist()))
        more_bad, more_pairs = _coverage_findings(P, nxt, loop_of, loop_chart)
        bad |= more_bad
        pairs |= more_pairs
    self_overlapping = np.array(sorted(bad | unfit), dtype=np.int64)
    pairs = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    message = _message(len(charts), len(F), inverted, self_overlapping, pairs, out_of_range)
    ok = not (len(inverted) or len(self_overlapping) or len(pairs) or out_of_range)
    return AtlasCertificate(ok, inverted, self_overlapping, pairs, out_of_range, message, time.perf_counter() - t0)

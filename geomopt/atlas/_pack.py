"""Pack flat charts into the unit square: one common scale, a rotation and a translation each.

A raster packer in the manner of xatlas's (J. Young, https://github.com/jpcy/xatlas, after
B. Lévy et al. 2002's "Tetris" packer), searching for the smallest square:

1. Each chart is turned so that its minimum-area bounding rectangle is axis-aligned (rotating
   calipers over the convex hull: the optimal rectangle has a side on a hull edge, Freeman &
   Shapira 1975), then tried at that angle plus 0, 90, 180 and 270 degrees (90-degree turns are
   exact in floating point, and turn the raster exactly); a chart long enough to decide the
   square's side is also tried at the angle of its smallest bounding square (exactly:
   :func:`smallest_square_angle`; a long chart may fit only diagonally), and a
   chart of over ``_LARGE`` of the total area also every ``90 / _STEPS`` degrees.  Rotations
   only: a chart is never mirrored.
2. At a pixel size chosen from the charts' total area and ``resolution``, each orientation is
   rasterised conservatively (:mod:`geomopt.atlas._raster`) and grown by the margin.
3. The charts are placed into a square of ``S`` pixels, one by one (:mod:`geomopt.atlas._place`:
   free spots on a coarse grid by FFT correlation, then slid down and left on the fine grid), and
   ``S`` is bisected for several strategies (where the bounding square grows least or at the
   lowest top edge; charts by decreasing area or length; with or without the large charts'
   in-between angles), within a budget of packings; the smallest true side wins.
4. The placed charts are scaled so that their bounding square is ``[0, 1]^2``; a packing whose
   margin, after that scaling, fell short (the extent was under-estimated) is redone with a wider
   gap (at most ``_MARGIN_LAYOUTS`` layouts: the gap jumps to where a line through the last two
   layouts' sides says it covers the margin, with coarser pixels where it would pass
   ``_GAP_PIXELS``), and the result is certified exactly (:func:`certify_atlas`): charts disjoint
   and inside the square; a failure is retried at a finer resolution and never returned.

The margin is kept in the max-norm (rasters grown by squares), so ``k`` charts fit only below the
margin :func:`widest_margin`; a wider one is refused before any packing.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial import ConvexHull

from .._runtime.config import Real
from .._runtime.errors import MeshError, ParameterError, SolveError
from .._runtime.validate import validate_simplices, validate_vertices
from ..exact.predicates import orient2d
from ..exact.topology import boundary_half_edges
from ._certify import certify_atlas
from ._place import smallest_square
from ._raster import dilate, rasterize

__all__ = ["MARGIN", "Packing", "pack_charts", "packing_estimate", "smallest_square_angle", "widest_margin"]

_QUARTER_TURNS = [np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([[0.0, -1.0], [1.0, 0.0]]),
                  np.array([[-1.0, 0.0], [0.0, -1.0]]), np.array([[0.0, 1.0], [-1.0, 0.0]])]
_FIRST_GUESS = 0.6  # packing efficiency assumed when choosing the pixel size
_MARGIN_SLACK = 1.1  # margin pixels for a side 10 % above the guess (efficiency down to 0.5): no re-packing
_TRIES = 4
_LARGE, _STEPS = 0.1, 6  # a chart of over this fraction of the area is also tried every 90 / _STEPS degrees
_BUDGET = 24  # square packings per layout (every strategy, bisection steps included)
_LONG_SIDE = 4  # the longest chart spans at most this many times ``resolution`` pixels
_MARGIN_LAYOUTS = 8  # layouts tried for a gap that covers the margin of the packed side
_GAP_PIXELS = 4  # the gap spans at most ``resolution / _GAP_PIXELS`` pixels (coarser pixels beyond)

MARGIN = Real(0.0, 0.25, hi_open=True)  # the margin's range, a fraction of the square's side


def widest_margin(charts: int) -> float:
    """The margin that ``charts`` charts packed by :func:`pack_charts` must stay below:
    ``1 / (ceil(sqrt(charts)) - 1)`` (infinite for one chart).

    The packer keeps charts apart in the max-norm (rasters grown by squares).  Points pairwise at
    least ``m`` apart in the max-norm in the unit square number at most ``(floor(1 / m) + 1)^2``:
    their half-open squares ``[p, p + m)^2`` are disjoint, each meets exactly one of the
    ``floor(1 / m) + 1`` vertical lines ``x = j m`` (``0 <= j m <= 1``), and along each line their
    ``y``-intervals are disjoint, so each line meets at most ``floor(1 / m) + 1`` of them.  With
    ``n = ceil(sqrt(charts))`` that needs ``m <= 1 / (n - 1)``, and equality only for charts of
    no size at the nodes of an ``n x n`` grid."""
    n = math.ceil(math.sqrt(charts))
    return math.inf if n <= 1 else 1.0 / (n - 1)


def _check_margin(margin, charts: int) -> float:
    """``margin`` as a float, or a ParameterError: outside :data:`MARGIN`, or too wide for ``charts``."""
    m = MARGIN(margin)
    if m is None:
        raise ParameterError(f"margin must be {MARGIN} (a fraction of the square's side), got {margin!r}")
    if m >= widest_margin(charts):
        raise ParameterError(f"margin {m!r} cannot keep {charts} charts apart: {charts} charts fit in the unit "
                             f"square only with a margin below {widest_margin(charts):.4g} "
                             f"({math.ceil(math.sqrt(charts)) - 1} gaps across it); use a smaller margin")
    return m


@dataclasses.dataclass(frozen=True)
class Packing:
    """Charts packed into the unit square by :func:`pack_charts`.

    Attributes
    ----------
    uvs : list of (n_i, 2) float64 arrays, the packed charts:
        ``uvs[i] = scale * uvs_in[i] @ R(angles[i]).T + offsets[i]`` (up to rounding), with
        ``R(a) = [[cos a, -sin a], [sin a, cos a]]`` (a rotation: never a mirror).
    scale : float, the common scale of all charts (texel density is kept across charts).
    angles : (k,) float64, each chart's rotation in radians.
    offsets : (k, 2) float64, each chart's translation.
    efficiency : float, total chart area over the area of the charts' bounding square (which is
        the unit square, up to rounding).
    """

    uvs: list
    scale: float
    angles: np.ndarray
    offsets: np.ndarray
    efficiency: float


def _check_charts(uvs, faces):
    if len(uvs) != len(faces) or len(uvs) == 0:
        raise MeshError(f"pack_charts needs one face array per chart and at least one chart, got {len(uvs)} "
                        f"uv arrays and {len(faces)} face arrays")
    U, Fs = [], []
    for i, (u, f) in enumerate(zip(uvs, faces)):
        u = validate_vertices(u, f"chart {i}'s uvs", dim=2)
        f = validate_simplices(f, len(u), 3, name=f"chart {i}'s faces")
        unused = len(u) - len(np.unique(f))
        if unused:
            raise MeshError(f"chart {i} has {unused} uv rows that no face uses; drop them (they would not be packed)")
        bad = np.count_nonzero(orient2d(u[f[:, 0]], u[f[:, 1]], u[f[:, 2]]) != 1)
        if bad:
            raise MeshError(f"chart {i} has {bad} triangles that are not positively oriented; pack flip-free "
                            f"charts (every triangle counter-clockwise)")
        U.append(u)
        Fs.append(f)
    return U, Fs


def _area(u, f) -> float:
    a, b, c = u[f[:, 0]], u[f[:, 1]], u[f[:, 2]]
    return 0.5 * float(np.sum((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])))


def _rotation(c, s) -> np.ndarray:
    return np.array([[c, -s], [s, c]])


def _base_rotations(u, big: bool, steps: int = 1) -> list[tuple[np.ndarray, bool]]:
    """Rotations (2, 2) to try a chart at (each then by quarter turns), each with a flag ``extra``:
    the one making the minimum-area bounding rectangle of the points ``u`` (n, 2) axis-aligned,
    long side along x (rotating calipers: that rectangle has a side on a hull edge, Freeman &
    Shapira 1975); for a ``big`` chart also the one making its bounding square smallest
    (:func:`smallest_square_angle`): a long chart may fit the square only diagonally; and (``extra``) that
    rectangle's at ``steps - 1`` angles between its quarter turns."""
    try:
        hull = u[ConvexHull(u).vertices]
    except Exception:  # noqa: BLE001 -- qhull refuses flat or tiny point sets: keep the chart as it is
        return [(np.eye(2), False)]
    e = np.roll(hull, -1, axis=0) - hull
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    # turning edge direction e onto +x: x' = e . p, y' = e_perp . p (extremes by _support: linear)
    n = np.stack([-e[:, 1], e[:, 0]], 1)
    w = np.einsum("ij,ij->i", e, hull[_support(e, e)] - hull[_support(e, -e)])
    h = np.einsum("ij,ij->i", n, hull[_support(e, n)] - hull[_support(e, -n)])
    k = int(np.argmin(w * h))
    R = _rotation(e[k, 0], -e[k, 1])
    R = R if w[k] >= h[k] else _QUARTER_TURNS[1] @ R
    out = [(R, False)] + [(_rotation(math.cos(a), math.sin(a)) @ R, True)
                          for a in 0.5 * np.pi * np.arange(1, steps) / steps]
    if big:
        a, side = smallest_square_angle(hull)
        if side < 0.98 * max(w[k], h[k]):
            out.append((_rotation(math.cos(a), math.sin(a)), False))
    return out


def _support(e, d) -> np.ndarray:
    """(k,) for each direction ``d`` (k, 2), the vertex of a convex polygon farthest along it,
    from the polygon's unit edge vectors ``e`` (h, 2) (edge ``i`` from vertex ``i`` to ``i + 1``,
    counter-clockwise, as ConvexHull lists them): the vertex where the edges turn from going
    along ``d`` to going against it, i.e. the first edge at or past ``d``'s angle plus a quarter
    turn.  The edges' angles increase around the polygon, so one sort and a binary search per
    direction: O((h + k) log h), where projecting every vertex on every edge's direction (the
    rotating-calipers minimum rectangle over all edges) would be quadratic."""
    angle = np.arctan2(e[:, 1], e[:, 0])
    order = np.argsort(angle, kind="stable")
    target = np.mod(np.arctan2(d[:, 1], d[:, 0]) + 1.5 * np.pi, 2 * np.pi) - np.pi  # + pi/2, in [-pi, pi)
    return order[np.searchsorted(angle[order], target) % len(e)]


def _square_sides(P, a) -> np.ndarray:
    """(len(a),) the side of the axis-aligned bounding square of the points ``P`` (n, 2)
    rotated by each angle of ``a``: ``x' = x cos a - y sin a``, ``y' = x sin a + y cos a``."""
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    return np.maximum(np.ptp(c * P[:, 0] - s * P[:, 1], axis=1), np.ptp(s * P[:, 0] + c * P[:, 1], axis=1))


def smallest_square_angle(hull) -> tuple[float, float]:
    """The rotation angle (radians, in [0, pi / 2)) that makes the axis-aligned bounding square
    of a convex polygon smallest, and that square's side, exactly (up to rounding).

    Between two *critical* angles (where a hull edge turns parallel to an axis) the extreme
    vertices along both axes stay the same, so the width is ``dx cos a - dy sin a`` and the
    height ``ex sin a + ey cos a`` for fixed vertex differences ``d``, ``e``: positive arcs of
    sinusoids, concave there.  The larger of two concave functions is smallest at an end of the
    interval or where they cross (on each side of a crossing one of them is the larger, and a
    concave function is smallest at an end), so the minimum over all angles is at a critical
    angle or at a crossing ``tan a = (dx - ey) / (dy + ex)``; all of them are evaluated.

    Parameters
    ----------
    hull : (n, 2) float, the polygon's vertices (any order; extra points inside do no harm).
    """
    P = np.asarray(hull, dtype=np.float64)
    quarter = 0.5 * np.pi
    e = np.roll(P, -1, axis=0) - P
    e = e[np.hypot(e[:, 0], e[:, 1]) > 0]
    crit = np.unique(np.mod(-np.arctan2(e[:, 1], e[:, 0]), quarter))
    lo, hi = crit, np.r_[crit[1:], crit[0] + quarter]
    mid = 0.5 * (lo + hi)
    c, s = np.cos(mid)[:, None], np.sin(mid)[:, None]
    X, Y = c * P[:, 0] - s * P[:, 1], s * P[:, 0] + c * P[:, 1]
    d = P[np.argmax(X, axis=1)] - P[np.argmin(X, axis=1)]
    f = P[np.argmax(Y, axis=1)] - P[np.argmin(Y, axis=1)]
    cross = np.arctan2(d[:, 0] - f[:, 1], d[:, 1] + f[:, 0])  # w = h there (mod pi)
    cross = lo + np.mod(cross - lo, np.pi)  # the first solution at or after lo
    cand = np.r_[crit, cross[cross <= hi]]
    side = _square_sides(P, cand)
    j = int(np.argmin(side))
    return float(np.mod(cand[j], quarter)), float(side[j])


@dataclasses.dataclass(frozen=True)
class _Shape:
    """One orientation of one chart on the pixel grid: chart point ``u`` lies at pixel
    ``u @ R.T / h - origin`` of ``mask``; ``grown`` is ``mask`` grown by the margin ``r``;
    ``extra``: an angle between the quarter turns of the minimum-area rectangle."""

    R: np.ndarray
    mask: np.ndarray
    grown: np.ndarray
    origin: np.ndarray
    extra: bool = False


def _quarter_turn(mask, origin):
    """The raster of a chart turned by 90 degrees, ``(x, y) -> (-y, x)``, from its raster
    ``mask`` (H, W) at pixel corner ``origin`` = (x0, y0): pixel ``[x0 + j, x0 + j + 1] x
    [y0 + i, y0 + i + 1]`` goes to ``[-(y0 + i + 1), -(y0 + i)] x [x0 + j, x0 + j + 1]``, a pixel
    again (the turn is exact), so the turned raster is as conservative as the first."""
    H = mask.shape[0]
    return np.ascontiguousarray(mask[::-1].T), np.array([-(origin[1] + H), origin[0]], dtype=origin.dtype)


def _shapes(u, B, bases, turns, h, r) -> list[_Shape]:
    """The chart ``u`` (n, 2) with boundary edges ``B`` (s, 2) at each base rotation turned by
    each of ``turns`` (``_QUARTER_TURNS[:len(turns)]``: each the last turned by 90 degrees), on
    pixels of size ``h``, grown by ``r`` pixels."""
    out = []
    for R0, extra in bases:
        mask, origin = rasterize((u @ R0.T) / h, B)
        grown = dilate(mask, r)
        for k, turn in enumerate(turns):
            if k:
                mask, origin = _quarter_turn(mask, origin)
                grown = np.ascontiguousarray(grown[::-1].T)
            out.append(_Shape(turn @ R0, mask, grown, origin, extra))  # exact: a signed permutation
    return out


def _search(U, shapes, h, r, passes):
    """The smallest square found (:func:`smallest_square`) by these strategies: the charts at
    their minimum-area rectangle's quarter turns (and diagonal), by decreasing area, each where
    the bounding square grows least, then each at its lowest top edge; both orders (decreasing
    area, decreasing longest side) with the large charts' in-between angles too, lowest top edge.
    Returns (per chart (rotation, pixel translation), side in pixels)."""
    def placement(placed):
        return [(s.R, np.array([x, y], np.float64) - s.origin) for s, y, x in placed]

    boxes = {}  # per orientation (id), the least and greatest pixel coordinates of its chart, unmoved

    def side(placed):
        """:func:`_side` of the placed charts from their orientations' boxes: adding the
        translation is monotone in floating point, so the box of the moved chart is the moved box."""
        lo, hi = [], []
        for u, (s, y, x) in zip(U, placed):
            if id(s) not in boxes:
                p = (u @ s.R.T) / h
                boxes[id(s)] = (p.min(axis=0), p.max(axis=0))
            t = np.array([x, y], np.float64) - s.origin
            lo.append(boxes[id(s)][0] + t)
            hi.append(boxes[id(s)][1] + t)
        return float(np.max(np.max(hi, axis=0) - np.min(lo, axis=0)))

    by_area = np.argsort([-sh[0].mask.sum() for sh in shapes], kind="stable")
    by_length = np.argsort([-max(max(s.mask.shape) for s in sh) for sh in shapes], kind="stable")
    basic = [[s for s in sh if not s.extra] for sh in shapes]
    strategies = [(basic, "square", by_area), (basic, "bottom", by_area), (basic, "bottom", by_length)]
    if any(s.extra for sh in shapes for s in sh):
        strategies += [(shapes, "bottom", by_area), (shapes, "bottom", by_length)]
    placed, best_side = smallest_square(strategies, r, side, passes)
    return placement(placed), best_side


def _layout(U, Bs, bases, turns, area, margin, resolution, budget=_BUDGET):
    """Pack at a pixel size giving about ``resolution`` pixels a side; returns (rotations (k, 2, 2),
    pixel translations (k, 2), pixel size h).  The gap between charts is widened until it covers
    ``margin`` of the packed side (a finer margin than needed only costs space), in at most
    ``_MARGIN_LAYOUTS`` layouts, else a ParameterError naming the widest margin reached."""
    h = math.sqrt(area / _FIRST_GUESS) / resolution
    # a chart far longer than that square (a thin strip) decides the side: pixels fine enough
    # for the area would make a bitmap of millions of pixels a side (a box 1000 x 1 x 1 hung)
    h = max(h, max(float(np.ptp(u, axis=0).max()) for u in U) / (_LONG_SIDE * resolution))
    r = math.ceil(margin * resolution * _MARGIN_SLACK)
    seen = []  # per layout (gap, side) in chart units
    for _ in range(_MARGIN_LAYOUTS):
        shapes = [_shapes(u, B, base, turns, h, r) for u, B, base in zip(U, Bs, bases)]
        placed, side = _search(U, shapes, h, r, budget)
        if math.ceil(margin * side) <= r:
            return np.array([p[0] for p in placed]), np.array([p[1] for p in placed]), h
        seen.append((r * h, side * h))
        gap = max(_next_gap(seen, margin), (r + 1) * h)
        h = max(h, gap / max(1, resolution // _GAP_PIXELS))  # many pixels of gap: coarser pixels
        r = math.ceil(gap / h)
    widest = max(g / s for g, s in seen)
    raise ParameterError(f"margin {float(margin)!r} could not be kept between {len(U)} charts in {_MARGIN_LAYOUTS} "
                         f"layouts (their side grew with the gap about as fast as the margin does); the widest "
                         f"margin they were packed with is {widest:.4g} ({len(U)} charts fit only below "
                         f"{widest_margin(len(U)):.4g}): use a smaller margin")


def _next_gap(seen, margin) -> float:
    """The gap (chart units) to try next from the layouts so far, ``seen`` = [(gap, side), ...]:
    ``margin`` times the last side, or more where the line through the last two layouts (a
    layout's side grows about linearly with its gap: so many gaps across it) reaches
    ``gap = margin * side`` further on (creeping there one side at a time can take many layouts)."""
    g1, s1 = seen[-1]
    gap = margin * s1
    if len(seen) > 1 and seen[-2][0] != g1:
        g0, s0 = seen[-2]
        slope = (s1 - s0) / (g1 - g0)
        if 0 < margin * slope < 1:
            gap = max(gap, margin * (s1 - slope * g1) / (1 - margin * slope))
    return gap


def _side(P) -> float:
    lo = np.min([p.min(axis=0) for p in P], axis=0)
    hi = np.max([p.max(axis=0) for p in P], axis=0)
    return float(np.max(hi - lo))


def _to_unit_square(U, R, t, h):
    """The charts at pixel positions ``u @ R.T / h + t``, scaled and moved so that their bounding
    square is [0, 1]^2.  Returns (uvs, scale, offsets)."""
    P = [(u @ Ri.T) / h + ti for u, Ri, ti in zip(U, R, t)]
    lo = np.min([p.min(axis=0) for p in P], axis=0)
    side = _side(P)
    scale = 1.0 / (h * side)
    offsets = (t - lo) / side
    uvs = [np.clip(scale * (u @ Ri.T) + o, 0.0, 1.0) for u, Ri, o in zip(U, R, offsets)]  # clip: rounding only
    return uvs, scale, offsets


def _outlines(U, Bs):
    """``(Ub, Bb)``: each chart's boundary vertices ``u[rows]`` and its boundary edges ``B`` in
    them.  A layout needs nothing else: the rasters are drawn from the boundary, and a flip-free
    chart's extremes in any direction lie on its boundary (its interior maps into the interior of
    its image), so its boxes are its boundary's; a layout's work is then in the boundary
    vertices, not in every vertex of every chart at every orientation tried."""
    Ub, Bb = [], []
    for u, B in zip(U, Bs):
        rows, local = np.unique(B, return_inverse=True)
        Ub.append(u[rows])
        Bb.append(local.reshape(B.shape))
    return Ub, Bb


def _prepare(U, Fs, rotate, steps=_STEPS, Bs=None):
    """The charts ``U`` rescaled near 1 by a power of two (``unit``), their total ``area``,
    boundary edges ``Bs`` (found when not given) and the rotations to try (``bases``, ``turns``)."""
    # an exact power-of-two rescaling to sizes near 1 keeps areas and pixel sizes in range
    unit = math.ldexp(1.0, -math.frexp(max(float(np.ptp(u, axis=0).max()) for u in U))[1])
    U = [u * unit for u in U]
    areas = [_area(u, f) for u, f in zip(U, Fs)]
    area = sum(areas)
    Bs = [boundary_half_edges(f) for f in Fs] if Bs is None else [np.asarray(B, dtype=np.int64) for B in Bs]
    bases, turns = [[(np.eye(2), False)]] * len(U), _QUARTER_TURNS[:1]
    if rotate:
        big = 0.6 * math.sqrt(area / _FIRST_GUESS)  # a chart this long may decide the square's side
        bases = [_base_rotations(u[np.unique(B)], np.ptp(u[B[:, 0]], axis=0).max() > big,
                                 steps if a > _LARGE * area else 1) for u, a, B in zip(U, areas, Bs)]
        turns = _QUARTER_TURNS
    return U, unit, area, Bs, bases, turns


def packing_estimate(uvs, faces, *, margin: float = 0.005, rotate: bool = True, resolution: int = 128,
                     budget: int = _BUDGET // 2, boundaries=None) -> float:
    """The packing efficiency :func:`pack_charts` would about reach, cheaply: one layout on a
    coarse bitmap, with fewer square packings and no angles between the quarter turns of a
    chart's minimum-area rectangle, neither checked nor certified (for ranking candidate chart
    sets, e.g. packing splits; the charts are not validated).

    Parameters
    ----------
    uvs, faces, margin, rotate, resolution : as :func:`pack_charts`.
    budget : int, the most square packings.
    boundaries : optional list of (s_i, 2) int arrays, each chart's boundary half-edges
        (:func:`~geomopt.exact.topology.boundary_half_edges` of its faces), when already known.

    Returns
    -------
    float, chart area over the packed bounding square's area.
    """
    U = [np.asarray(u, dtype=np.float64) for u in uvs]
    Fs = [np.asarray(f, dtype=np.int64) for f in faces]
    margin = _check_margin(margin, len(U))
    U, _, area, Bs, bases, turns = _prepare(U, Fs, rotate, steps=1, Bs=boundaries)
    Ub, Bb = _outlines(U, Bs)
    R, t, h = _layout(Ub, Bb, bases, turns, area, margin, max(16, int(resolution)), budget)
    return area / (h * _side([(u @ Ri.T) / h + ti for u, Ri, ti in zip(Ub, R, t)])) ** 2


def pack_charts(uvs, faces, *, margin: float = 0.005, rotate: bool = True, resolution: int = 512,
                certify: bool = True) -> Packing:
    """Pack flat charts into the unit square without overlap, each rotated (never mirrored).

    Parameters
    ----------
    uvs : list of (n_i, 2) float arrays, each chart's flattened coordinates.
    faces : list of (m_i, 3) int arrays, each chart's triangles into its ``uvs``, counter-clockwise.
    margin : float, the least distance between two charts, as a fraction of the square's side.
    rotate : bool, whether charts may turn (to their minimum-area rectangle, then by quarter turns).
    resolution : int, pixels a side of the packing bitmap: higher packs tighter (smaller charts are
        drawn more finely) and takes longer (about quadratically).
    certify : bool, certify the packing (and retry at finer resolutions until it certifies).
        False: the first layout, *not certified* (conservative rasters make it disjoint, but
        nothing checked it exactly): for trial packings whose chosen one the caller certifies
        (as :func:`~geomopt.atlas.make_atlas` certifies its whole atlas), falling back to a
        certified packing when that fails.

    Returns
    -------
    :class:`Packing`; with ``certify``, certified (:func:`certify_atlas`): no two charts meet, all
    inside [0, 1]^2, each chart more than ``margin`` from the others.

    Raises
    ------
    MeshError
        A chart is malformed or has a triangle that is not positively oriented.
    ParameterError
        ``margin`` not in [0, 0.25) (:data:`MARGIN`), not below :func:`widest_margin` of the
        number of charts, or not kept within a bounded number of layouts (the message names the
        widest margin reached); ``resolution`` below 16.
    SolveError
        The packing could not be certified (not expected: the rasters are conservative).
    """
    if int(resolution) < 16:
        raise ParameterError(f"resolution must be at least 16 pixels, got {resolution}")
    U, Fs = _check_charts(uvs, faces)
    margin = _check_margin(margin, len(U))
    U, unit, area, Bs, bases, turns = _prepare(U, Fs, rotate)
    res = int(resolution)
    Ub, Bb = _outlines(U, Bs)
    for _ in range(_TRIES):
        R, t, h = _layout(Ub, Bb, bases, turns, area, margin, res)
        out, scale, offsets = _to_unit_square(U, R, t, h)
        cert = _certify_packed(out, Fs) if certify else None
        if cert is None or cert.ok or not (len(cert.overlapping_pairs) or cert.out_of_range or len(cert.inverted)):
            side = _side(out)
            angles = np.arctan2(R[:, 1, 0], R[:, 0, 0])
            efficiency = sum(_area(u, f) for u, f in zip(out, Fs)) / side**2
            return Packing(out, float(scale) * unit, angles, offsets, float(efficiency))
        res *= 2
    raise SolveError(f"pack_charts could not certify a packing ({cert.message}); report this with the charts",
                     certificate=cert)


def _certify_packed(uvs, faces):
    sizes = np.array([len(u) for u in uvs])
    shift = np.cumsum(sizes) - sizes
    F = np.concatenate([f + s for f, s in zip(faces, shift)])
    chart = np.repeat(np.arange(len(faces)), [len(f) for f in faces])
    return certify_atlas(np.concatenate(uvs), F, chart)

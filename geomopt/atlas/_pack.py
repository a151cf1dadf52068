"""Pack flat charts into the unit square: one common scale, a rotation and a translation each.

The method is xatlas's bitmap packer (J. Young, https://github.com/jpcy/xatlas, after
B. Lévy et al. 2002's "Tetris" packer), vectorised:

1. Each chart is turned so that its minimum-area bounding rectangle is axis-aligned (rotating
   calipers over the convex hull: the optimal rectangle has a side on a hull edge, Freeman &
   Shapira 1975), then tried at that angle plus 0, 90, 180 and 270 degrees (90-degree turns are
   exact in floating point); a chart long enough to decide the square's side is also tried at the
   angle of its smallest bounding square (diagonally).  Rotations only: a chart is never mirrored.
2. At a pixel size chosen from the charts' total area and ``resolution``, each orientation is
   rasterised conservatively (:mod:`geomopt.atlas._raster`) and grown by the margin.
3. Largest first, each chart goes where its grown raster meets no pixel of the charts placed so
   far and the bounding square of everything placed grows least (ties: the smaller bounding
   rectangle, then the lowest and leftmost spot).  All free spots of one orientation come from one
   FFT correlation of the occupancy bitmap with the raster (the occupancy's transform is shared by
   the four orientations); the chosen spot is re-checked exactly on the bitmaps.  Within a budget
   of passes (charts x pixels), a second chart order is tried, then bottom-left packings into
   slightly smaller squares; the smallest square wins.
4. The placed charts are scaled so that their bounding square is ``[0, 1]^2``; a packing whose
   margin, after that scaling, fell short (the extent was under-estimated) is redone with a wider
   margin in pixels, and the result is certified exactly (:func:`certify_atlas`): charts disjoint
   and inside the square; a failure is retried at a finer resolution and never returned.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.fft
from scipy.spatial import ConvexHull

from .._runtime.errors import MeshError, ParameterError, SolveError
from .._runtime.validate import validate_simplices, validate_vertices
from ..exact.predicates import orient2d
from ..exact.topology import boundary_half_edges
from ._certify import certify_atlas
from ._raster import dilate, rasterize

__all__ = ["Packing", "pack_charts"]

_QUARTER_TURNS = [np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([[0.0, -1.0], [1.0, 0.0]]),
                  np.array([[-1.0, 0.0], [0.0, -1.0]]), np.array([[0.0, 1.0], [-1.0, 0.0]])]
_FIRST_GUESS = 0.6  # packing efficiency assumed when choosing the pixel size
_MARGIN_SLACK = 1.1  # margin pixels for a side 10 % above the guess (efficiency down to 0.5): no re-packing
_TRIES = 4
_BAND = 64  # rows of spots per FFT when looking for the lowest spot inside the packed rectangle
_SHRINK = (0.99, 0.97, 0.95)  # squares tried below the greedy packing's, while they fit
_BUDGET = 30 * 512**2 * 2  # charts x pixels x passes: 2 passes for 30 charts at 512, 5 for up to 12


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


def _base_rotations(u, big: bool) -> list[np.ndarray]:
    """Rotations (2, 2) to try a chart at (each then by quarter turns): the one making the
    minimum-area bounding rectangle of the points ``u`` (n, 2) axis-aligned, long side along x
    (rotating calipers: that rectangle has a side on a hull edge, Freeman & Shapira 1975), and for
    a ``big`` chart also the one making its bounding square smallest (sampled every half degree):
    a long chart may fit the square only diagonally."""
    try:
        hull = u[ConvexHull(u).vertices]
    except Exception:  # noqa: BLE001 -- qhull refuses flat or tiny point sets: keep the chart as it is
        return [np.eye(2)]
    e = np.roll(hull, -1, axis=0) - hull
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    # turning edge direction e onto +x: x' = e . p, y' = e_perp . p
    xs, ys = e @ hull.T, np.stack([-e[:, 1], e[:, 0]], 1) @ hull.T
    w, h = np.ptp(xs, axis=1), np.ptp(ys, axis=1)
    k = int(np.argmin(w * h))
    R = _rotation(e[k, 0], -e[k, 1])
    out = [R if w[k] >= h[k] else _QUARTER_TURNS[1] @ R]
    if big:
        a = np.deg2rad(np.arange(0.0, 90.0, 0.5))
        c, s = np.cos(a), np.sin(a)
        side = np.maximum(np.ptp(np.outer(c, hull[:, 0]) - np.outer(s, hull[:, 1]), axis=1),
                          np.ptp(np.outer(s, hull[:, 0]) + np.outer(c, hull[:, 1]), axis=1))
        j = int(np.argmin(side))
        if side[j] < 0.98 * max(w[k], h[k]):
            out.append(_rotation(c[j], s[j]))
    return out


@dataclasses.dataclass(frozen=True)
class _Shape:
    """One orientation of one chart on the pixel grid: chart point ``u`` lies at pixel
    ``u @ R.T / h - origin`` of ``mask``; ``grown`` is ``mask`` grown by the margin ``r``."""

    R: np.ndarray
    mask: np.ndarray
    grown: np.ndarray
    origin: np.ndarray


def _shapes(u, B, bases, turns, h, r) -> list[_Shape]:
    """The chart ``u`` (n, 2) with boundary edges ``B`` (s, 2) at each base rotation turned by
    each of ``turns``, on pixels of size ``h``, grown by ``r`` pixels."""
    out = []
    for R0 in bases:
        for turn in turns:
            R = turn @ R0  # exact products: the turns are signed permutations
            mask, origin = rasterize((u @ R.T) / h, B)
            out.append(_Shape(R, mask, dilate(mask, r), origin))
    return out


def _free_spots(occ_hat, fshape, window, grown) -> np.ndarray:
    """(Hw - dh + 1, Ww - dw + 1) bool: where the grown raster (dh, dw) meets no occupied pixel of
    the window (Hw, Ww), from its FFT ``occ_hat`` (None: nothing placed yet).  A circular
    correlation of size ``fshape`` >= the window is exact on the valid part; counts are
    integers, so ``< 0.5`` is a safe threshold (the chosen spot is re-checked on the bitmaps)."""
    Hw, Ww = window
    dh, dw = grown.shape
    if occ_hat is None:
        return np.ones((Hw - dh + 1, Ww - dw + 1), bool)
    g_hat = scipy.fft.rfft2(grown[::-1, ::-1].astype(np.float32), fshape)
    C = scipy.fft.irfft2(occ_hat * g_hat, fshape)[dh - 1:Hw, dw - 1:Ww]
    return C < 0.5


def _best_spot(occ, extent, shapes, r, bound):
    """The best (key, shape index, y, x) over the orientations of one chart, or None when it does
    not fit; ``extent`` = (rows, cols) occupied so far (pixels from 0); ``bound``: the chart must
    end within ``bound + r`` pixels (None: no bound).  Key: the side of the bounding square of
    everything placed, then the area of its bounding rectangle, then the lowest and leftmost spot."""
    rows, cols = extent
    reach = max(max(s.grown.shape) for s in shapes)
    window = (rows + reach, cols + reach)
    fshape = (scipy.fft.next_fast_len(window[0], True), scipy.fft.next_fast_len(window[1], True))
    occ_hat = scipy.fft.rfft2(occ[:window[0], :window[1]].astype(np.float32), fshape) if rows else None
    best = None
    for k, s in enumerate(shapes):
        free = _free_spots(occ_hat, fshape, window, s.grown)
        ch, cw = s.mask.shape
        dh, dw = s.grown.shape
        if bound is not None:
            free = free[:max(bound - ch + 1, 0), :max(bound - cw + 1, 0)]
        while free.any():
            # the key grows with y and with x: per row the first free column is the row's best
            has = free.any(axis=1)
            ys = np.flatnonzero(has)
            xs = np.argmax(free[ys], axis=1)
            R2 = np.maximum(rows, ys + r + ch) - r
            C2 = np.maximum(cols, xs + r + cw) - r
            j = int(np.argmin((np.maximum(R2, C2) << 32) | (R2 * C2))) if bound is None else 0
            y, x = int(ys[j]), int(xs[j])
            if not (occ[y:y + dh, x:x + dw] & s.grown).any():  # exact re-check of the FFT's answer
                break
            free[y, x] = False
        else:
            continue
        side = max(R2[j], C2[j])
        cand = ((int(side), int(R2[j] * C2[j]), y, x) if bound is None else (y, x), k, y, x)
        best = cand if best is None or cand[0] < best[0] else best
    return best


def _lowest_inside(occ, extent, shapes, r, bound):
    """The lowest, then leftmost, free spot (key, shape index, y, x) that does not grow the
    bounding rectangle of everything placed (or, ``bound`` given, that stays within it), or None.

    Every such spot ties on the greedy key, so the lowest wins; bands of ``_BAND`` rows are searched
    from the bottom, each with FFTs of the band only, and the search stops at the first band with a
    free spot: a small chart late in the packing costs a few band-sized FFTs, not canvas-sized ones."""
    rows, cols = extent
    if bound is None:
        top = [rows - r - s.mask.shape[0] for s in shapes]
        right = [cols - r - s.mask.shape[1] for s in shapes]
    else:  # bottom-left: any spot within the bound, none above the first free row ``rows``
        top = [min(bound - s.mask.shape[0], rows) for s in shapes]
        right = [bound - s.mask.shape[1] for s in shapes]
    live = [k for k in range(len(shapes)) if top[k] >= 0 and right[k] >= 0]
    if not live:
        return None
    dh_max = max(shapes[k].grown.shape[0] for k in live)
    width = max(right[k] + shapes[k].grown.shape[1] for k in live)
    fshape = (scipy.fft.next_fast_len(_BAND + dh_max - 1, True), scipy.fft.next_fast_len(width, True))
    g_hat = {k: scipy.fft.rfft2(shapes[k].grown[::-1, ::-1].astype(np.float32), fshape) for k in live}
    for y0 in range(0, max(top[k] for k in live) + 1, _BAND):
        o_hat = scipy.fft.rfft2(occ[y0:y0 + _BAND + dh_max - 1, :width].astype(np.float32), fshape)
        best = None
        for k in live:
            dh, dw = shapes[k].grown.shape
            n_y = min(_BAND, top[k] - y0 + 1)
            if n_y <= 0:
                continue
            free = scipy.fft.irfft2(o_hat * g_hat[k], fshape)[dh - 1:dh - 1 + n_y, dw - 1:dw + right[k]] < 0.5
            for j in np.flatnonzero(free.ravel()):  # row-major: lowest, then leftmost
                y, x = y0 + j // free.shape[1], j % free.shape[1]
                if not (occ[y:y + dh, x:x + dw] & shapes[k].grown).any():  # exact re-check
                    if best is None or (y, x) < best[2:]:
                        best = (None, k, int(y), int(x))
                    break
        if best is not None:
            return best
    return None


def _place(all_shapes, order, r, bound=None):
    """Place the charts in ``order``; returns per chart (rotation (2, 2), pixel translation (2,)),
    or None when a chart does not fit within ``bound``.  Unbounded, each chart goes where the
    bounding square grows least; bounded, at the lowest and leftmost free spot."""
    cap = 2 * sum(max(s.grown.shape) for s in (sh[0] for sh in all_shapes)) + 1
    occ = np.zeros((64, 64), bool)
    rows = cols = filled = 0
    placed = [None] * len(all_shapes)
    for i in order:
        shapes = all_shapes[i]
        reach = max(max(s.grown.shape) for s in shapes)
        need = (rows + reach, cols + reach)
        if need[0] > occ.shape[0] or need[1] > occ.shape[1]:
            grow = min(cap, 2 * max(need + occ.shape))
            occ = np.pad(occ, ((0, grow - occ.shape[0]), (0, grow - occ.shape[1])))
        # a chart needing over half the free pixels of the rectangle rarely fits inside: go direct
        roomy = rows and shapes[0].mask.sum() < 0.5 * ((rows - r) * (cols - r) - filled)
        spot = _lowest_inside(occ, (rows, cols), shapes, r, bound) if roomy else None
        if spot is None:
            spot = _best_spot(occ, (rows, cols), shapes, r, bound)
        if spot is None:
            return None
        _, k, y, x = spot
        s = shapes[k]
        ch, cw = s.mask.shape
        occ[y + r:y + r + ch, x + r:x + r + cw] |= s.mask
        filled += int(s.mask.sum())
        rows, cols = max(rows, y + r + ch), max(cols, x + r + cw)
        placed[i] = (s.R, np.array([x + r, y + r], np.float64) - s.origin)
    return placed


def _search(U, shapes, h, r, passes):
    """Up to ``passes`` packings; returns the best (placed, side in pixels).  First the greedy
    packing with the charts by decreasing longest side, then by decreasing area; then, in the
    better order, bottom-left packings into squares 1, 3, 5, ... percent smaller than the greedy
    one's while they fit."""
    def side(placed):
        return _side([(u @ R.T) / h + t for u, (R, t) in zip(U, placed)])

    orders = [np.argsort([-max(max(s.mask.shape) for s in sh) for sh in shapes], kind="stable"),
              np.argsort([-sh[0].mask.sum() for sh in shapes], kind="stable")]
    found = []
    for order in orders[:passes]:
        placed = _place(shapes, order, r)
        found.append((side(placed), placed, order))
    greedy, best, order = min(found, key=lambda f: f[0])
    best_side = greedy
    for shrink in _SHRINK[:max(passes - len(orders), 0)]:
        placed = _place(shapes, order, r, bound=int(greedy * shrink))
        if placed is None:
            break
        best_side, best = min((best_side, best), (side(placed), placed), key=lambda f: f[0])
    return best, best_side


def _layout(U, Bs, bases, turns, area, margin, resolution):
    """Pack at a pixel size giving about ``resolution`` pixels a side; returns (rotations (k, 2, 2),
    pixel translations (k, 2), pixel size h).  The margin in pixels is re-chosen until it covers
    ``margin`` of the packed side (a finer margin than needed only costs space)."""
    h = math.sqrt(area / _FIRST_GUESS) / resolution
    r = math.ceil(margin * resolution * _MARGIN_SLACK)
    tried = set()
    while True:
        tried.add(r)
        shapes = [_shapes(u, B, base, turns, h, r) for u, B, base in zip(U, Bs, bases)]
        passes = int(np.clip(_BUDGET / (len(U) * resolution**2), 1, 2 + len(_SHRINK)))
        placed, side = _search(U, shapes, h, r, passes)
        want = math.ceil(margin * side)
        if want <= r:
            return np.array([p[0] for p in placed]), np.array([p[1] for p in placed]), h
        r = max(tried) + 1 if want in tried else want


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


def pack_charts(uvs, faces, *, margin: float = 0.005, rotate: bool = True, resolution: int = 512) -> Packing:
    """Pack flat charts into the unit square without overlap, each rotated (never mirrored).

    Parameters
    ----------
    uvs : list of (n_i, 2) float arrays, each chart's flattened coordinates.
    faces : list of (m_i, 3) int arrays, each chart's triangles into its ``uvs``, counter-clockwise.
    margin : float, the least distance between two charts, as a fraction of the square's side.
    rotate : bool, whether charts may turn (to their minimum-area rectangle, then by quarter turns).
    resolution : int, pixels a side of the packing bitmap: higher packs tighter (smaller charts are
        drawn more finely) and takes longer (about quadratically).

    Returns
    -------
    :class:`Packing`; certified (:func:`certify_atlas`): no two charts meet, all inside [0, 1]^2,
    each chart more than ``margin`` from the others.

    Raises
    ------
    MeshError
        A chart is malformed or has a triangle that is not positively oriented.
    ParameterError
        ``margin`` not in [0, 0.25) or ``resolution`` below 16.
    SolveError
        The packing could not be certified (not expected: the rasters are conservative).
    """
    if not 0 <= margin < 0.25:
        raise ParameterError(f"margin must be a fraction of the square in [0, 0.25), got {margin}")
    if int(resolution) < 16:
        raise ParameterError(f"resolution must be at least 16 pixels, got {resolution}")
    U, Fs = _check_charts(uvs, faces)
    # an exact power-of-two rescaling to sizes near 1 keeps areas and pixel sizes in range
    unit = math.ldexp(1.0, -math.frexp(max(float(np.ptp(u, axis=0).max()) for u in U))[1])
    U = [u * unit for u in U]
    area = sum(_area(u, f) for u, f in zip(U, Fs))
    Bs = [boundary_half_edges(f) for f in Fs]
    bases, turns = [[np.eye(2)]] * len(U), _QUARTER_TURNS[:1]
    if rotate:
        big = 0.6 * math.sqrt(area / _FIRST_GUESS)  # a chart this long may decide the square's side
        bases = [_base_rotations(u[np.unique(B)], np.ptp(u[B[:, 0]], axis=0).max() > big) for u, B in zip(U, Bs)]
        turns = _QUARTER_TURNS
    res = int(resolution)
    for _ in range(_TRIES):
        R, t, h = _layout(U, Bs, bases, turns, area, margin, res)
        out, scale, offsets = _to_unit_square(U, R, t, h)
        cert = _certify_packed(out, Fs)
        if cert.ok or not (len(cert.overlapping_pairs) or cert.out_of_range or len(cert.inverted)):
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

"""Place rasterised charts into a square of pixels: bottom-left, coarse to fine.

Charts are given as bitmaps (:mod:`geomopt.atlas._raster`): ``mask`` (the chart) and ``grown``
(the mask grown by the margin ``r`` pixels, offset by ``r``).  A chart may go at spot ``(y, x)``
(``grown``'s first row and column on the canvas) when ``grown`` there meets no pixel of the masks
placed so far; the mask then covers rows ``y + r .. y + r + h - 1``.  :func:`pack_square` puts the
charts, in a given order, each at its best free spot over its orientations inside an ``S x S``
square (by a rule: the lowest top edge, or the least growth of the bounding square);
:func:`smallest_square` finds the smallest ``S`` that holds them all by bisection, over several
such strategies.

Where to look is decided on a *coarse* grid (blocks of ``c x c`` pixels; a block is set when any
of its pixels is): a spot free on the coarse grid is free on the fine one, and all coarse spots of
one orientation come from one FFT correlation, ``c**2`` times smaller than on the fine grid.  The
chart is then slid down and left on the fine grid while it stays free (exact bitmap tests), into
the gaps narrower than a block that the coarse grid hides.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft

__all__ = ["coarse_factor", "pack_square", "smallest_square"]

_COARSE_SIDE = 128  # pixels a side of the coarse grid
_REACH = 0.1  # after the first strategy, bisections start this fraction below the best square so far
_WORDS = {2: np.uint16, 4: np.uint32, 8: np.uint64}  # c bools (bytes 0 or 1) read as one word: nonzero = any
_TOLERANCE = 0.01  # bisection stops when the bracket is this fraction of the side (or 1 pixel)


def coarse_factor(side: int) -> int:
    """Block size for a square of ``side`` fine pixels: a coarse grid of about ``_COARSE_SIDE``."""
    return max(1, round(side / _COARSE_SIDE))


def pool(mask, c: int) -> np.ndarray:
    """(ceil(H / c), ceil(W / c)) bool: the blocks of ``c x c`` pixels of ``mask`` (H, W) holding
    a set pixel (``mask`` itself for ``c = 1``)."""
    if c == 1:
        return np.asarray(mask, bool)
    H, W = mask.shape
    Hc, Wc = -(-H // c), -(-W // c)
    padded = np.zeros((Hc * c, Wc * c), bool)
    padded[:H, :W] = mask
    if c not in _WORDS:
        return padded.reshape(Hc, c, Wc, c).any(axis=(1, 3))
    words = padded.view(_WORDS[c]).reshape(Hc, c, Wc)  # a block row's c pixels as one word
    return np.bitwise_or.reduce(words, axis=1) != 0


def _padded(a, shape) -> np.ndarray:
    """``a`` (h, w) as float32 in the corner of zeros of ``shape``, cut to it: a kernel larger
    than the FFT is larger than the square, and its (cut) correlation is never read."""
    out = np.zeros(shape, np.float32)
    h, w = min(a.shape[0], shape[0]), min(a.shape[1], shape[1])
    out[:h, :w] = a[:h, :w]
    return out


class _Canvas:
    """The fine occupancy (masks placed) of an ``S x S`` square grown by ``r`` on every side, its
    coarse blocks, and the FFTs of the charts' coarse kernels (cached per chart orientation)."""

    def __init__(self, S: int, r: int, c: int, cache: dict, fft_side: int = 0):
        self.S, self.r, self.c = S, r, c
        n = S + 2 * r
        self.occ = np.zeros((-(-n // c) * c,) * 2, bool)
        self.coarse = np.zeros((-(-n // c),) * 2, bool)
        # at least ``fft_side``: the smaller squares of one bisection share it, and the kernels' FFTs
        self.fshape = (scipy.fft.next_fast_len(max(self.coarse.shape[0], fft_side), True),) * 2
        self.cache = cache
        self.occ_hat = None

    def _kernels(self, shapes):
        """The coarse kernels of the orientations ``shapes`` and their stacked FFTs (cached)."""
        key = (tuple(id(s) for s in shapes), self.c, self.fshape)
        if key not in self.cache:
            coarse = [pool(s.grown, self.c) for s in shapes]
            hats = scipy.fft.rfft2(np.stack([_padded(k[::-1, ::-1], self.fshape) for k in coarse]), axes=(-2, -1))
            self.cache[key] = (coarse, hats)
        return self.cache[key]

    def free(self, shapes):
        """Per orientation of ``shapes``: the (bool) coarse spots (Y, X) where it is free and
        inside the square, or None when it cannot fit the square at all.  One FFT correlation
        for all orientations (counts are integers: ``< 0.5`` is safe; the spot taken is re-checked)."""
        out, H = [None] * len(shapes), self.coarse.shape[0]
        limits = [((self.S - s.mask.shape[0]) // self.c, (self.S - s.mask.shape[1]) // self.c) for s in shapes]
        if not self.coarse.any():
            return [np.ones((t + 1, q + 1), bool) if min(t, q) >= 0 else None for t, q in limits]
        if self.occ_hat is None:
            self.occ_hat = scipy.fft.rfft2(self.coarse.astype(np.float32), self.fshape)
        kernels, hats = self._kernels(shapes)
        fit = [k for k, (top, right) in enumerate(limits) if min(top, right) >= 0]
        if not fit:
            return out
        # the inverse 2D FFT in two passes, the second over the rows of the spots only (of
        # every orientation at once: one call over the rows any of them needs)
        cols = scipy.fft.ifft(self.occ_hat * hats[fit], axis=-2)
        rows = [(kernels[k].shape[0] - 1, min(H, kernels[k].shape[0] + limits[k][0])) for k in fit]
        first, last = min(r[0] for r in rows), max(r[1] for r in rows)
        counts = scipy.fft.irfft(cols[:, first:last], self.fshape[1], axis=-1)
        for j, (k, (a, b)) in enumerate(zip(fit, rows)):
            w, right = kernels[k].shape[1], limits[k][1]
            out[k] = counts[j, a - first:b - first, w - 1:H][:, :right + 1] < 0.5
        return out

    def _free(self, g, y: int, x: int) -> bool:
        return y >= 0 and x >= 0 and not (self.occ[y:y + g.shape[0], x:x + g.shape[1]] & g).any()

    def refine(self, shape, Y: int, X: int):
        """The fine spot (y, x) reached from the coarse spot ``(Y, X)`` (free on the fine grid too)
        by sliding down, then left, one pixel at a time while the chart stays free, until it
        moves no more: it closes the gaps narrower than a block that the coarse grid hides."""
        g = shape.grown
        y, x = self.c * Y, self.c * X
        if not self._free(g, y, x):
            raise AssertionError("a free coarse spot is not free on the fine grid")  # pragma: no cover
        moved = self.c > 1
        while moved:
            moved = False
            while self._free(g, y - 1, x):
                y, moved = y - 1, True
            while self._free(g, y, x - 1):
                x, moved = x - 1, True
        return y, x

    def put(self, shape, y: int, x: int):
        h, w = shape.mask.shape
        r, c = self.r, self.c
        self.occ[y + r:y + r + h, x + r:x + r + w] |= shape.mask
        Y0, X0 = (y + r) // c, (x + r) // c
        Y1, X1 = -(-(y + r + h) // c), -(-(x + r + w) // c)
        self.coarse[Y0:Y1, X0:X1] = pool(self.occ[Y0 * c:Y1 * c, X0 * c:X1 * c], c)
        self.occ_hat = None


def _choose(free, shape, c: int, r: int, extent, rule: str):
    """The best coarse spot (key, Y, X) of ``free`` for ``shape`` by ``rule``, or None: "bottom"
    the lowest top edge, then leftmost; "square" the least growth of the bounding square of
    everything placed (``extent`` = its (rows, cols) in fine pixels), then of its area, then the
    lowest and leftmost.  Both keys grow with X along a row: each row's first free spot is its best."""
    ys = np.flatnonzero(free.any(axis=1))
    if not len(ys):
        return None
    h, w = shape.mask.shape
    if rule == "bottom":
        Y = int(ys[0])
        X = int(np.argmax(free[Y]))
        return (c * Y + h, c * X), Y, X
    xs = np.argmax(free[ys], axis=1)
    R2 = np.maximum(extent[0], c * ys + r + h)
    C2 = np.maximum(extent[1], c * xs + r + w)
    j = int(np.argmin((np.maximum(R2, C2) << 32) | (R2 * C2)))
    return (int(max(R2[j], C2[j])), int(R2[j] * C2[j]), int(ys[j]), int(xs[j])), int(ys[j]), int(xs[j])


def _best_spot(canvas, shapes, extent, rule: str):
    """The best orientation of ``shapes`` and its coarse spot, ``(shape, Y, X)``, by ``rule``
    (:func:`_choose`), or None when no orientation fits; ties go to the first orientation."""
    best = None
    for s, free in zip(shapes, canvas.free(shapes)):
        spot = None if free is None else _choose(free, s, canvas.c, canvas.r, extent, rule)
        if spot is not None and (best is None or spot[0] < best[0]):
            best = (spot[0], s, spot[1], spot[2])
    return None if best is None else best[1:]


def _holds(canvas, shape, Y: int, X: int) -> bool:
    """Whether the coarse spot ``(Y, X)`` of ``shape`` is one that :meth:`_Canvas.free` offers
    in this canvas: inside the square, its coarse kernel inside the coarse grid."""
    (h, w), (kh, kw) = shape.mask.shape, shape.grown.shape
    H, c = canvas.coarse.shape[0], canvas.c
    return (Y <= (canvas.S - h) // c and X <= (canvas.S - w) // c
            and Y + -(-kh // c) <= H and X + -(-kw // c) <= H)


def _pack_traced(shapes, order, r: int, S: int, c: int, cache: dict, rule: str, fft_side: int, known=()):
    """:func:`pack_square`'s packing (or None) and its *trace*: per chart placed, in ``order``,
    ``(shape, Y, X, y, x)`` (coarse and fine spot).  ``known``: the trace of the same charts,
    order and rule in a square at least as large; its charts are placed alike here while their
    coarse spots are offered here too (:func:`_holds`), with no search: a smaller square's free
    spots are a subset of the larger's (the same charts placed before), and a best spot of a set
    that lies in a subset is that subset's best (the keys order all spots; ties alike), so the
    packing is the one a search would find."""
    canvas = _Canvas(S, r, c, cache, fft_side)
    placed, trace, extent = [None] * len(shapes), [], (0, 0)
    for k, i in enumerate(order):
        if k < len(known) and _holds(canvas, *known[k][:3]):
            s, Y, X, y, x = known[k]
        else:
            known = ()
            best = _best_spot(canvas, shapes[i], extent, rule)
            if best is None:
                return None, trace
            s, Y, X = best
            y, x = canvas.refine(s, Y, X)
        canvas.put(s, y, x)
        trace.append((s, Y, X, y, x))
        extent = (max(extent[0], y + r + s.mask.shape[0]), max(extent[1], x + r + s.mask.shape[1]))
        placed[i] = (s, y + r, x + r)
    return placed, trace


def pack_square(shapes, order, r: int, S: int, c: int, cache: dict, rule: str = "bottom", fft_side: int = 0):
    """Each chart in ``order`` at its best free spot by ``rule`` (:func:`_choose`) over its
    orientations ``shapes[i]`` (each with ``mask``, ``grown``), inside an ``S x S`` square of
    fine pixels (coarse blocks of ``c``).  Returns per chart (orientation, y, x) of the mask's
    first pixel (margin offset included), or None when a chart does not fit.  ``cache`` keeps
    the charts' kernel FFTs between calls with the same ``c`` and FFT size (at least ``fft_side``)."""
    return _pack_traced(shapes, order, r, S, c, cache, rule, fft_side)[0]


def smallest_square(strategies, r: int, side_of, budget: int):
    """The packing (per chart (orientation, y, x)) of the smallest square side found, and that
    side (``side_of`` gives a packing's true side in pixels, at most the square's).

    Each *strategy* ``(shapes, rule, order)`` is :func:`pack_square`'s charts (per chart a list
    of orientations), rule and order.  The first starts from a square of the charts' total area
    (at an efficiency of 0.8) and grows it by 10 % until the charts fit; then each strategy
    bisects between a side too small for the area and the smallest square that fitted so far
    (whether a strategy fits is not monotone in the side, so every one bisects from below: the
    first from the area's bound, the others from ``_REACH`` below the best so far).
    At most ``budget`` square packings in all."""
    shapes = strategies[0][0]
    area = sum(min(int(s.mask.sum()) for s in sh) for sh in shapes)
    least = max(min(max(s.mask.shape) for s in sh) for sh in shapes)
    lo = max(int(math.sqrt(area)), least) - 1  # no square of this side holds them
    # blocks for the squares to be tried: their side is at least the longest chart's (a strip
    # thousands of pixels long and one wide has almost no area: a grid from the area alone was
    # the fine one, an FFT of millions of cells per chart placed)
    c = coarse_factor(max(int(math.sqrt(area / 0.6)), least))
    cache, best, tries, fft_side = {}, None, 0, 0
    traces = {}  # per distinct strategy, {S: trace} of its packings so far

    def fits(S, strategy):
        nonlocal best, tries
        shapes_, rule, order = strategy
        done = traces.setdefault((id(shapes_), rule, np.asarray(order).tobytes()), {})
        larger = [q for q in done if q >= S]
        known = done[min(larger)] if larger else ()
        placed, done[S] = _pack_traced(shapes_, order, r, S, c, cache, rule, fft_side, known)
        tries += 1
        if placed is not None:
            side = side_of(placed)
            if best is None or side < best[1]:
                best = (placed, side)
        return placed is not None

    ok = max(lo + 1, int(math.sqrt(area / 0.8)))
    while not fits(ok, strategies[0]):
        ok = max(ok + 1, int(ok * 1.1))
    fft_side = -(-(ok + 2 * r) // c)  # every later square is smaller: one FFT size
    for k, strategy in enumerate(strategies):
        fail = lo if k == 0 else max(lo, int(ok * (1 - _REACH)))
        while ok - fail > max(1, _TOLERANCE * ok) and tries < budget:
            mid = (ok + fail) // 2
            if fits(mid, strategy):
                ok = mid
            else:
                fail = mid
    return best

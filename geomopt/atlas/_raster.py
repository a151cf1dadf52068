"""Conservative rasterisation of a flat chart onto a pixel grid, for the packer.

A chart (positively oriented triangles) is drawn as the set of unit pixels ``[j, j + 1] x [i, i + 1]``
(row ``i``, column ``j``) that its closed region meets, *conservatively*: every closed pixel that
holds a point of the chart is set (a pixel may be set that only comes within ``_EPS`` of it).
Two ways a closed pixel can meet the region: a boundary edge passes through it (the *supercover*
of the boundary: every pixel in an edge's bounding box is tested against the edge's line by the
separating-axis rule, with the tolerance ``_EPS``), or it lies wholly inside, and then its centre
is inside: winding number not zero (the non-zero rule: with positive triangles the boundary
winds about a point as often as triangles cover it), found by scanning the pixel-centre rows.

Then two charts whose rasters, one grown by ``r`` pixels in the max-norm (:func:`dilate`), share
no pixel are more than ``r`` pixels apart: a point ``b`` within ``r`` of a point ``a`` lies in a
closed pixel at most ``r`` pixels from ``a``'s, and both pixels are set.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["dilate", "rasterize"]

_EPS = 1e-7  # pixels; far above the rounding of coordinates below 2**20 pixels (2**-32)


def _expand(count):
    """(owner, k): for each item i, ``count[i]`` entries ``(i, 0 .. count[i] - 1)``."""
    owner = np.repeat(np.arange(len(count)), count)
    return owner, np.arange(owner.size) - np.repeat(np.cumsum(count) - count, count)


def _supercover(a, b, shape) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) of every pixel that the closed segments ``a -> b`` (each (s, 2), pixel units)
    meet or come within ``_EPS`` of, clipped to ``shape``.  Each segment is walked column by
    column (the rows its y-range spans within the column, widened by ``_EPS``): work in the
    pixels it crosses, not in its bounding box (a long diagonal edge of a thin chart spans
    millions of pixels' box)."""
    lo = np.floor(np.minimum(a, b) - _EPS).astype(np.int64)
    hi = np.floor(np.maximum(a, b) + _EPS).astype(np.int64)
    seg, k = _expand(hi[:, 0] - lo[:, 0] + 1)
    col = lo[seg, 0] + k
    ax, ay, bx, by = a[seg, 0], a[seg, 1], b[seg, 0], b[seg, 1]
    x0 = np.maximum(np.minimum(ax, bx), col - _EPS)  # the part of the segment over this column
    x1 = np.minimum(np.maximum(ax, bx), col + 1 + _EPS)
    dx = bx - ax
    flat = np.abs(dx) > 0
    slope = np.where(flat, (by - ay) / np.where(flat, dx, 1.0), 0.0)
    y0, y1 = ay + (x0 - ax) * slope, ay + (x1 - ax) * slope
    ymin, ymax = np.minimum(ay, by), np.maximum(ay, by)
    ylo = np.where(flat, np.clip(np.minimum(y0, y1), ymin, ymax), ymin)
    yhi = np.where(flat, np.clip(np.maximum(y0, y1), ymin, ymax), ymax)
    r0 = np.floor(ylo - _EPS).astype(np.int64)
    cell, j = _expand(np.floor(yhi + _EPS).astype(np.int64) - r0 + 1)
    row, col = r0[cell] + j, col[cell]
    keep = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    return row[keep], col[keep]


def _nonzero_fill(a, b, shape) -> np.ndarray:
    """(H, W) bool: pixels whose centre has a non-zero winding number with respect to the
    directed edges ``a -> b`` (each (s, 2), pixel units).  Scan lines through the centres; half-open
    rule on ``y``, so a vertex on a scan line is counted once."""
    H, W = shape
    ya, yb = a[:, 1], b[:, 1]
    lo, hi = np.minimum(ya, yb), np.maximum(ya, yb)
    r0 = np.maximum(np.ceil(lo - 0.5).astype(np.int64), 0)
    r1 = np.minimum(np.ceil(hi - 0.5).astype(np.int64), H)  # rows r0 .. r1 - 1 have lo <= yc < hi
    seg, k = _expand(np.maximum(r1 - r0, 0))
    row = r0[seg] + k
    yc = row + 0.5
    t = (yc - ya[seg]) / (yb[seg] - ya[seg])
    x = a[seg, 0] + t * (b[seg, 0] - a[seg, 0])
    up = np.where(yb[seg] > ya[seg], 1, -1)
    order = np.lexsort((x, row))
    row, x, up = row[order], x[order], up[order]
    wind = np.cumsum(up)  # per row the total returns to zero (each loop crosses a line evenly)
    inside = np.flatnonzero(wind[:-1] != 0) if len(wind) else np.zeros(0, np.int64)
    start = np.clip(np.ceil(x[inside] - 0.5).astype(np.int64), 0, W)
    stop = np.clip(np.ceil(x[inside + 1] - 0.5).astype(np.int64), 0, W)
    diff = np.zeros((H, W + 1), np.int32)
    np.add.at(diff, (row[inside], start), 1)
    np.add.at(diff, (row[inside], stop), -1)
    return np.cumsum(diff, axis=1)[:, :W] > 0


def rasterize(q, boundary) -> tuple[np.ndarray, np.ndarray]:
    """Conservative raster of one chart.

    Parameters
    ----------
    q : (n, 2) float array, the chart's vertices in pixel units.
    boundary : (s, 2) int array, the chart's boundary edges, directed with the chart to their
        left (:func:`geomopt.exact.topology.boundary_half_edges` of positively oriented triangles).

    Returns
    -------
    mask : (H, W) bool, row ``i`` column ``j`` is the pixel ``[x0 + j, x0 + j + 1] x [y0 + i, y0 + i + 1]``.
    origin : (2,) int64, ``(x0, y0)``, the pixel corner where the mask starts.
    """
    a, b = q[boundary[:, 0]], q[boundary[:, 1]]
    origin = np.floor(a.min(axis=0) - _EPS).astype(np.int64)  # the region's extremes are on its boundary
    top = np.floor(a.max(axis=0) + _EPS).astype(np.int64)
    shape = (int(top[1] - origin[1]) + 1, int(top[0] - origin[0]) + 1)
    a, b = a - origin, b - origin
    mask = _nonzero_fill(a, b, shape)
    mask[_supercover(a, b, shape)] = True
    return mask, origin


def dilate(mask, r: int) -> np.ndarray:
    """``mask`` (H, W) grown by ``r`` pixels in the max-norm: (H + 2 r, W + 2 r), the mask at offset ``r``."""
    if r <= 0:
        return mask.copy()
    padded = np.pad(mask, r)
    return ndimage.maximum_filter(padded, size=2 * r + 1, mode="constant", cval=0)

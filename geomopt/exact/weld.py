"""Points with bit-identical coordinates made one: the STL reader's corners welded into vertices,
and an atlas's input vertices at one position (an unwelded export) joined.  Equality is exact
(-0.0 = +0.0): a 64-bit hash of the coordinates' bits groups them, with a fallback to the bits
themselves should two different points share a hash."""

from __future__ import annotations

import numpy as np

__all__ = ["equal_points", "weld"]


def equal_points(P):
    """``(first, group)`` of the points ``P`` (n, d) float64: each group's first (smallest) point
    index, in no particular order, and each point's group."""
    P = np.ascontiguousarray(P, dtype=np.float64)
    bits = (P + 0.0).view(np.uint64)  # -0.0 + 0.0 = +0.0: equal points weld
    key = np.zeros(len(bits), dtype=np.uint64)
    for j in range(bits.shape[1]):
        key = _mix(key ^ bits[:, j])
    first, group = _groups(key)
    if (bits != bits[first[group]]).any():
        first, group = _groups(np.unique(bits, axis=0, return_inverse=True)[1].ravel())
    return first, group


def weld(corners):
    """Merge corners with equal coordinates (-0.0 = +0.0): ``(V (n, 3), F (m, 3))``, vertices in
    first-seen order with the first corner's exact bits."""
    corners = np.ascontiguousarray(corners, dtype=np.float64)
    first, inverse = equal_points(corners)
    rank = np.empty_like(first)
    rank[np.argsort(first)] = np.arange(first.size)  # groups numbered by their first corner
    return corners[np.sort(first)], rank[inverse].reshape(-1, 3).astype(np.int64)


def _groups(key):
    """``(first, group)``: the first index of each distinct value of ``key`` and the group of every
    entry (one unstable sort: the first of a group is its smallest index)."""
    order = np.argsort(key)
    ordered = key[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    group = np.empty(len(key), dtype=np.int64)
    group[order] = np.cumsum(np.r_[True, ordered[1:] != ordered[:-1]]) - 1
    return np.minimum.reduceat(order, starts), group


def _mix(z):
    """SplitMix64's finaliser: every output bit depends on every input bit."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))

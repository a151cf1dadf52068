"""Exact validity of trilinear hexahedra: is ``det J > 0`` over the whole element?

A hexahedron with vertices ``P`` (8, 3) in VTK order (bottom face ``0 1 2 3`` counter-clockwise
seen from above, top face ``4 5 6 7`` above it) is the image of the unit cube under the
trilinear map ``x(u, v, w)``.  Its Jacobian determinant is a polynomial of degree 2 in each of
``u, v, w``: it has 27 Bernstein coefficients of degree (2, 2, 2), its values at the 8 corners
are the corner coefficients (the orientations of the 8 corner tetrahedra), and it lies between
its smallest and largest coefficient (Johnen, Remacle & Geuzaine, "Geometrical validity of
curvilinear finite elements", J. Comput. Phys. 233, 2013).  Hence:

* a corner coefficient ``<= 0`` is a point where ``det J <= 0``: invalid ("corners" when a
  corner of the element itself, else found inside after subdivision);
* all 27 coefficients ``> 0``: ``det J > 0`` everywhere: valid ("bernstein");
* otherwise the box is split at its midpoint along every axis (de Casteljau, 8 children) and
  each child is tested the same way ("subdivision").

Corner positivity alone is necessary, not sufficient: a hexahedron whose 8 corner tetrahedra
are positive can still fold inside (``corner_valid & ~valid``).

Exactness.  The corner signs come from the exact :func:`geomopt.exact.predicates.orient3d`.  The
coefficients are first computed in float64 together with an a-priori error bound (the same
expression evaluated on absolute values, times a constant covering the depth of the
expression tree: the filter of Shewchuk's predicates); every decision is taken only where the
bound certifies the sign.  An element the float stage cannot decide (a coefficient within its
error bound of a sign change at a corner, tiny or huge coordinates, too many boxes) is redone
with Python integers: each element's coordinates scaled by one power of two are integers, the
corner-to-midpoint averages are scaled by 2, the value-to-Bernstein transform by 2 per axis and
each subdivision by 4 per axis, so every coefficient is an exact integer multiple (a positive
one) of the true value.  An element that still has undecided boxes after ``EXACT_LEVELS``
subdivisions (``det J`` touches 0 without crossing it) is reported ``undecided`` and is not
certified valid.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._runtime.errors import MeshError
from .predicates import orient3d

__all__ = ["HexValidity", "TESTS", "HEX_CORNERS", "hex_validity", "jacobian_bernstein", "jacobian_det",
           "hex_volumes"]

#: The corner tetrahedra of a VTK hexahedron: corner ``c`` then its three edge neighbours,
#: ordered so that the unit cube's corner tetrahedra are positive.
HEX_CORNERS = np.array([[0, 1, 3, 4], [1, 2, 0, 5], [2, 3, 1, 6], [3, 0, 2, 7],
                        [4, 7, 5, 0], [5, 4, 6, 1], [6, 5, 7, 2], [7, 6, 4, 3]], dtype=np.int64)

#: The test that decided each element (:attr:`HexValidity.test` indexes this tuple).
TESTS = ("corners", "bernstein", "subdivision", "exact", "undecided")
CORNERS, BERNSTEIN, SUBDIVISION, EXACT, UNDECIDED = range(5)

# vertex id of the trilinear control point (a, b, c) along (u, v, w)
_VTK = np.array([[[0, 4], [3, 7]], [[1, 5], [2, 6]]])
_EPS = 2.0**-53
FLOAT_LEVELS = 6  # float subdivisions before an element is redone exactly
EXACT_LEVELS = 12  # exact subdivisions before an element is called undecided
MAX_BOXES = 2048  # boxes per element and level before it goes to the next stage
# coordinate differences outside [2^-250, 2^250] (nonzero) skip the float stage: products of
# three stay far from under- and overflow within it
_TINY, _HUGE = 2.0**-250, 2.0**250


@dataclasses.dataclass(frozen=True)
class HexValidity:
    """The outcome of :func:`hex_validity` for ``m`` hexahedra.

    Attributes
    ----------
    valid : (m,) bool, ``det J > 0`` over the whole element (proved exactly).
    corner_valid : (m,) bool, the 8 corner tetrahedra are positive (exact).
    test : (m,) int8, index into :data:`TESTS` of the test that decided the element.
    witness : (m, 3) float, for an invalid element a point ``(u, v, w)`` of the unit cube where
        ``det J <= 0`` (exact dyadic coordinates); NaN elsewhere.
    """

    valid: np.ndarray
    corner_valid: np.ndarray
    test: np.ndarray
    witness: np.ndarray

    @property
    def tests(self) -> dict:
        """How many elements each test decided: ``{name: count}`` over :data:`TESTS`."""
        counts = np.bincount(self.test.astype(np.int64), minlength=len(TESTS))
        return {name: int(c) for name, c in zip(TESTS, counts)}


# ------------------------------------------------------------------ coefficients


def _control_points(X, H):
    """(m, 2, 2, 2, 3) control points ``P[e, a, b, c]`` of the trilinear maps."""
    return np.asarray(X)[np.asarray(H)[:, _VTK]]


def _interp(E, half):
    """Edge vectors ``E`` (m, 2, 2, 3) at the parameters (0, 1/2, 1) of their two axes:
    (m, 3, 3, 3); ``half(a, b)`` is the midpoint rule (a scaled one in the exact stage)."""
    def along(A, axis):
        a0, a1 = np.take(A, 0, axis=axis), np.take(A, 1, axis=axis)
        return np.stack([half(a0, a0), half(a0, a1), half(a1, a1)], axis=axis)

    return along(along(E, 1), 2)


def _triple(a, b, c, absolute=False):
    """``a . (b x c)`` over the last axis (broadcast), or its permanent with ``absolute``."""
    if absolute:
        return (a[..., 0] * (b[..., 1] * c[..., 2] + b[..., 2] * c[..., 1])
                + a[..., 1] * (b[..., 2] * c[..., 0] + b[..., 0] * c[..., 2])
                + a[..., 2] * (b[..., 0] * c[..., 1] + b[..., 1] * c[..., 0]))
    return (a[..., 0] * (b[..., 1] * c[..., 2] - b[..., 2] * c[..., 1])
            + a[..., 1] * (b[..., 2] * c[..., 0] - b[..., 0] * c[..., 2])
            + a[..., 2] * (b[..., 0] * c[..., 1] - b[..., 1] * c[..., 0]))


def _grid_values(P, half, absolute=False):
    """``det J`` at the 27 points ``{0, 1/2, 1}^3``: (m, 3, 3, 3) indexed ``[i(u), j(v), k(w)]``.

    ``J = [x_u, x_v, x_w]``; ``x_u`` is bilinear in ``(v, w)`` between the four u-edges, etc.
    With ``absolute`` the edge vectors are replaced by their absolute values (times
    ``1 + 2^-52``: they are rounded differences) and the product by its permanent."""
    Eu, Ev, Ew = P[:, 1] - P[:, 0], P[:, :, 1] - P[:, :, 0], P[:, :, :, 1] - P[:, :, :, 0]
    if absolute:
        Eu, Ev, Ew = (np.abs(E) * (1.0 + 2 * _EPS) for E in (Eu, Ev, Ew))
    U, V, W = _interp(Eu, half), _interp(Ev, half), _interp(Ew, half)  # [j,k], [i,k], [i,j]
    return _triple(U[:, None], V[:, :, None], W[:, :, :, None], absolute)


def _to_bernstein(p, exact, absolute=False):
    """Values at ``{0, 1/2, 1}`` to degree-2 Bernstein coefficients along the last three axes:
    ``b1 = 2 p(1/2) - (p(0) + p(1)) / 2`` (times 2 per axis in the exact stage)."""
    for axis in (1, 2, 3):
        p0, p1, p2 = (np.take(p, i, axis=axis) for i in range(3))
        if exact:
            mid = 4 * p1 - p0 - p2
            p = np.stack([2 * p0, mid, 2 * p2], axis=axis)
        else:
            mid = 2.0 * p1 + 0.5 * (p0 + p2) if absolute else 2.0 * p1 - 0.5 * (p0 + p2)
            p = np.stack([p0, mid, p2], axis=axis)
    return p


def jacobian_bernstein(X, H) -> np.ndarray:
    """Bernstein coefficients (float64) of ``det J`` of each hexahedron.

    Parameters
    ----------
    X : (n, 3) vertex positions;  H : (m, 8) hexahedra (VTK order).

    Returns
    -------
    (m, 3, 3, 3) coefficients of degree (2, 2, 2) in ``(u, v, w)``; ``[0, 0, 0]`` is the
    determinant at vertex 0 (the corner tetrahedron's edge determinant).
    """
    P = _control_points(np.asarray(X, dtype=np.float64), H)
    with np.errstate(all="ignore"):
        return _to_bernstein(_grid_values(P, lambda a, b: 0.5 * (a + b)), exact=False)


def jacobian_det(X, H, uvw) -> np.ndarray:
    """``det J`` of each hexahedron at parameter points (float64, for sampling).

    Parameters
    ----------
    X : (n, 3);  H : (m, 8);  uvw : (q, 3) points of the unit cube.

    Returns
    -------
    (m, q) determinants.
    """
    P = _control_points(np.asarray(X, dtype=np.float64), H)  # (m, 2, 2, 2, 3)
    u, v, w = (np.asarray(uvw, dtype=np.float64)[:, i] for i in range(3))
    Eu, Ev, Ew = P[:, 1] - P[:, 0], P[:, :, 1] - P[:, :, 0], P[:, :, :, 1] - P[:, :, :, 0]

    def bilinear(E, s, t):  # E (m, 2, 2, 3) -> (m, q, 3)
        weights = np.stack([(1 - s) * (1 - t), (1 - s) * t, s * (1 - t), s * t], axis=1)  # (q, 4)
        return weights @ E.reshape(len(E), 4, 3)

    return _triple(bilinear(Eu, v, w), bilinear(Ev, u, w), bilinear(Ew, u, v))


def hex_volumes(X, H) -> np.ndarray:
    """(m,) signed volume of each trilinear hexahedron: the integral of ``det J`` over the unit
    cube, which is the mean of its 27 Bernstein coefficients (each basis function integrates to
    1/27).  Float64."""
    return jacobian_bernstein(X, H).reshape(len(H), -1).mean(axis=1)


# ------------------------------------------------------------------ subdivision


def _split(B, axis, exact):
    """De Casteljau at 1/2 along ``axis`` of degree-2 coefficients: (left, right)."""
    b0, b1, b2 = (np.take(B, i, axis=axis) for i in range(3))
    if exact:  # scaled by 4: stays integer
        mid = b0 + 2 * b1 + b2
        return (np.stack([4 * b0, 2 * (b0 + b1), mid], axis=axis),
                np.stack([mid, 2 * (b1 + b2), 4 * b2], axis=axis))
    mid = 0.25 * (b0 + 2.0 * b1 + b2)
    return (np.stack([b0, 0.5 * (b0 + b1), mid], axis=axis),
            np.stack([mid, 0.5 * (b1 + b2), b2], axis=axis))


def _children(arrays, exact):
    """The 8 children of every box: each array in ``arrays`` (nb, 3, 3, 3) split along the three
    axes; returns the arrays (8 nb, 3, 3, 3) and the child offsets (8 nb, 3) in {0, 1}."""
    out = list(arrays)
    offs = np.zeros((len(out[0]), 0), np.int64)
    for axis in (1, 2, 3):
        halves = [_split(A, axis, exact) for A in out]
        out = [np.concatenate([lo, hi]) for lo, hi in halves]
        nb = len(offs)
        offs = np.concatenate([np.column_stack([offs, np.zeros(nb, np.int64)]),
                               np.column_stack([offs, np.ones(nb, np.int64)])])
    return out, offs


def _boxes(B, R, exact, levels, state, ids):
    """Decide elements ``ids`` from their coefficients ``B`` (k, 3, 3, 3) by subdivision.

    ``R`` (k, 3, 3, 3) are the permanents bounding the float rounding (None when exact).
    Updates ``state`` (dict of per-element arrays) in place; returns the element ids left to
    the next stage (undecided here)."""
    if not len(B):
        return np.zeros(0, np.int64)
    owner = np.arange(len(B))
    lo = np.zeros((len(B), 3))
    size = 1.0
    left = []
    for level in range(levels + 1):
        err = 0.0 if exact else (64 + 16 * level) * _EPS * R
        corner = (slice(None), slice(None, None, 2), slice(None, None, 2), slice(None, None, 2))
        c, ce = B[corner], (0 if exact else err[corner])
        neg = (c <= 0) if exact else (c + ce < 0)  # a point where det J <= 0
        unsure = np.zeros(len(B), bool) if exact else (np.abs(c) <= ce).reshape(len(B), -1).any(1)
        neg_box = neg.reshape(len(B), -1).any(1)
        ok = ((B > 0) if exact else (B - err > 0)).reshape(len(B), -1).all(1)
        bad = np.unique(owner[neg_box])
        _mark_invalid(state, ids, bad, owner, neg, neg_box, lo, size)
        dead = np.zeros(len(ids), bool)
        dead[bad] = True
        push = np.unique(owner[unsure & ~neg_box])
        dead[push] = True
        keep = ~ok & ~dead[owner]
        counts = np.bincount(owner[keep], minlength=len(ids))
        crowded = np.flatnonzero(counts * 8 > MAX_BOXES)
        stop = np.union1d(push, crowded if level < levels else np.unique(owner[keep]))
        stop = stop[~np.isin(stop, bad)]
        left.append(stop)
        dead[stop] = True
        keep &= ~dead[owner]
        if not keep.any():
            break
        state["level"][ids[np.unique(owner[keep])]] = level + 1
        arrays = [B[keep]] + ([] if exact else [R[keep]])
        arrays, offs = _children(arrays, exact)
        B, R = arrays[0], (None if exact else arrays[1])
        owner = np.tile(owner[keep], 8)
        size *= 0.5
        lo = np.tile(lo[keep], (8, 1)) + size * offs
    return np.unique(np.concatenate(left)) if left else np.zeros(0, np.int64)


def _mark_invalid(state, ids, bad, owner, neg, neg_box, lo, size):
    """Record invalid elements and a witness point (the first negative box corner) for each."""
    if not bad.size:
        return
    boxes = np.flatnonzero(neg_box)
    first = boxes[np.unique(owner[boxes], return_index=True)[1]]
    corner = np.array(np.unravel_index(np.argmax(neg[first].reshape(len(first), -1), axis=1), (2, 2, 2))).T
    el = ids[owner[first]]
    state["failed"][el] = True
    state["witness"][el] = lo[first] + size * corner


def _integer_points(P):
    """Float coordinates (k, ...) as Python integers, one power-of-two scale per row: exact."""
    k = len(P)
    mant, expo = np.frexp(P)
    M = np.ldexp(mant, 53).astype(np.int64)
    E = expo.astype(np.int64) - 53
    big = np.iinfo(np.int64).max
    emin = np.where(M == 0, big, E).reshape(k, -1).min(axis=1)
    emin = np.where(emin == big, 0, emin)
    shift = np.where(M == 0, 0, E - emin.reshape((k,) + (1,) * (P.ndim - 1)))
    return M.astype(object) << shift.astype(object)


def _float_safe(P):
    """(k,) rows whose coordinate differences stay in the float stage's range."""
    D = np.concatenate([(P[:, 1] - P[:, 0]).reshape(len(P), 12), (P[:, :, 1] - P[:, :, 0]).reshape(len(P), 12),
                        (P[:, :, :, 1] - P[:, :, :, 0]).reshape(len(P), 12)], axis=1)
    a = np.abs(D)
    return ((a == 0) | ((a >= _TINY) & (a <= _HUGE))).all(axis=1)


def hex_validity(X, H) -> HexValidity:
    """Exact certificate that each trilinear hexahedron has ``det J > 0`` everywhere.

    Parameters
    ----------
    X : (n, 3) float vertex positions (a map);  H : (m, 8) int hexahedra in VTK order.

    Returns
    -------
    :class:`HexValidity`.  An element with a non-finite coordinate is invalid (test
    ``corners``, as the exact orientation predicate gives it no orientation).

    Raises
    ------
    MeshError
        ``X`` is not (n, 3) or ``H`` not (m, 8) with indices into ``X``.
    """
    X = np.asarray(X, dtype=np.float64)
    H = np.asarray(H)
    if X.ndim != 2 or X.shape[1] != 3:
        raise MeshError(f"hexahedron vertices must have shape (n, 3), got {X.shape}")
    if H.ndim != 2 or H.shape[1] != 8 or H.dtype.kind not in "iu" or (H.size and (H.min() < 0 or H.max() >= len(X))):
        raise MeshError(f"hexahedra must be an integer array of shape (m, 8) indexing {len(X)} vertices")
    m = len(H)
    C = H[:, HEX_CORNERS].reshape(-1, 4)
    signs = orient3d(*(X[C[:, i]] for i in range(4))).reshape(m, 8)
    corner_valid = (signs == 1).all(axis=1)
    state = {"failed": ~corner_valid, "witness": np.full((m, 3), np.nan), "level": np.zeros(m, np.int64),
             "test": np.full(m, CORNERS, np.int8)}
    bad_corner = np.flatnonzero(~corner_valid)
    first = np.argmax(signs[bad_corner] != 1, axis=1)
    state["witness"][bad_corner] = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                                             [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)[first]
    todo = np.flatnonzero(corner_valid)
    P = _control_points(X, H[todo])
    safe = _float_safe(P)
    ids = todo[safe]
    with np.errstate(all="ignore"):
        half = lambda a, b: 0.5 * (a + b)  # noqa: E731
        B = _to_bernstein(_grid_values(P[safe], half), exact=False)
        R = _to_bernstein(_grid_values(P[safe], half, absolute=True), exact=False, absolute=True)
    later = _boxes(B, R, False, FLOAT_LEVELS, state, ids)
    exact_ids = np.union1d(todo[~safe], ids[later])
    state["test"][ids] = np.where(state["level"][ids] > 0, SUBDIVISION, BERNSTEIN)
    if exact_ids.size:
        state["failed"][exact_ids] = False
        Q = _integer_points(_control_points(X, H[exact_ids]))
        Bx = _to_bernstein(_grid_values(Q, lambda a, b: a + b), exact=True)
        undecided = exact_ids[_boxes(Bx, None, True, EXACT_LEVELS, state, exact_ids)]
        state["test"][exact_ids] = EXACT
        state["test"][undecided] = UNDECIDED
        state["failed"][undecided] = True  # not certified
    return HexValidity(corner_valid & ~state["failed"], corner_valid, state["test"], state["witness"])

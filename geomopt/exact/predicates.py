"""Exact orientation predicates for triangles and tetrahedra, vectorised.

Each determinant is first evaluated in float64 with Shewchuk's a-priori error
bound (stage A of J. R. Shewchuk, "Adaptive Precision Floating-Point Arithmetic
and Fast Robust Geometric Predicates", Discrete Comput. Geom. 18, 1997).  Elements
whose sign the bound does not certify -- near-degenerate ones, and those whose
products could underflow or overflow -- are recomputed exactly with Python
integers: every float64 is ``M * 2**E`` with an integer ``M``, so after scaling all
coordinates of one element by a common power of two the determinant is an integer.

Results are ``int8`` arrays of ``+1`` (positive orientation), ``0`` (degenerate) or
``-1``.  Inputs are converted to float64 (exact for float32 and small integers).
An element with a NaN or infinite coordinate has no orientation and gets ``0``, so
:func:`count_inverted` counts it (a diverged map is reported, not raised on).
"""

from __future__ import annotations

import math

import numpy as np

from .._runtime.errors import MeshError, ParameterError
from .._runtime.tracing import refuse_traced

__all__ = ["orient2d", "orient3d", "normal_signs", "simplex_orientations", "count_inverted", "cone_orientations",
           "differing_rows", "box_scale"]

_EPS = 2.0**-53  # half an ulp of 1.0: the relative rounding error of one operation
CCW_ERRBOUND_A = (3.0 + 16.0 * _EPS) * _EPS
O3D_ERRBOUND_A = (7.0 + 56.0 * _EPS) * _EPS
# Coordinate differences at least this large (or exactly zero) keep every product of
# up to three of them out of the subnormal range, where the relative bound fails.  Then a
# zero bound is an exact zero too: every product in it has an exactly-zero factor (a float
# difference is zero only when the operands are equal), so every term of the determinant is
# zero -- the common case of axis-aligned faces, certified without the exact path.
_TINY = 2.0**-300
_PLANES = ((0, 1), (1, 2), (2, 0))  # projections whose orient2d are a normal's z, x, y


def _as_points(p, d: int, name: str) -> np.ndarray:
    p = np.asarray(p)
    if p.ndim != 2 or p.shape[1] != d:
        raise MeshError(f"{name} must be an array of shape (m, {d}), got shape {p.shape}")
    if p.dtype.kind not in "fiub":
        raise MeshError(f"{name} must hold real coordinates, got dtype {p.dtype}")
    return p.astype(np.float64, copy=False)


def _same_length(*arrays):
    lengths = {a.shape[0] for a in arrays}
    if len(lengths) != 1:
        raise MeshError(f"point arrays must have the same number of rows, got {sorted(lengths)}")


def _no_tiny(*diffs) -> np.ndarray:
    """True where every difference is zero or at least ``_TINY`` in magnitude."""
    ok = np.ones(diffs[0].shape, dtype=bool)
    for x in diffs:
        ok &= (x == 0) | (np.abs(x) >= _TINY)
    return ok


def _exact_needed(*pts) -> np.ndarray:
    """Which uncertified elements need the exact evaluation, ``(k,)`` bool.

    Not those with a non-finite coordinate (no orientation: reported as 0) nor
    those with two coincident points (exactly 0).  A certified element never has a
    non-finite coordinate: inf or NaN differences make the error bound inf or NaN.
    """
    finite = np.ones(pts[0].shape[0], dtype=bool)
    for p in pts:
        finite &= np.isfinite(p).all(axis=1)
    need = finite
    for i in range(len(pts)):
        for j in range(i + 1, len(pts)):
            need &= ~(pts[i] == pts[j]).all(axis=1)
    return need


def _sign(x) -> np.ndarray:
    return (x > 0).view(np.int8) - (x < 0).view(np.int8)


def _exact_integer_coordinates(P: np.ndarray) -> np.ndarray:
    """Integer coordinates of each row of points, up to one positive factor per row.

    Parameters
    ----------
    P : (k, p, d) float64 array, finite

    Returns
    -------
    Q : (k, p, d) object array of Python ints
        ``Q[r] = P[r] * 2**s_r`` exactly, for some integer ``s_r`` per row.
    """
    k = P.shape[0]
    mant, expo = np.frexp(P)
    M = np.ldexp(mant, 53).astype(np.int64)  # exact: |M| < 2**53
    E = expo.astype(np.int64) - 53  # P = M * 2**E
    big = np.iinfo(np.int32).max  # ignore zeros when taking each row's smallest exponent
    emin = np.where(M == 0, big, E).reshape(k, -1).min(axis=1)
    emin = np.where(emin == big, 0, emin)  # all-zero rows
    shift = np.where(M == 0, 0, E - emin[:, None, None])
    return M.astype(object) << shift.astype(object)


def _exact_orient2d(a, b, c) -> np.ndarray:
    Q = _exact_integer_coordinates(np.stack([a, b, c], axis=1))
    u, v = Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0]
    det = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    return (det > 0).astype(np.int8) - (det < 0).astype(np.int8)


def _exact_orient3d(a, b, c, d) -> np.ndarray:
    Q = _exact_integer_coordinates(np.stack([a, b, c, d], axis=1))
    u, v, w = Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0], Q[:, 3] - Q[:, 0]
    det = (
        u[:, 0] * (v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1])
        - u[:, 1] * (v[:, 0] * w[:, 2] - v[:, 2] * w[:, 0])
        + u[:, 2] * (v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0])
    )
    return (det > 0).astype(np.int8) - (det < 0).astype(np.int8)


def orient2d(a, b, c) -> np.ndarray:
    """Exact sign of ``det[b - a, c - a]`` for many triangles.

    Parameters
    ----------
    a, b, c : (m, 2) float arrays
        Corners of ``m`` triangles.

    Returns
    -------
    s : (m,) int8 array
        ``+1`` if ``a, b, c`` run counter-clockwise, ``-1`` clockwise, ``0`` collinear
        (or a coordinate is NaN or inf).
    """
    a, b, c = (_as_points(p, 2, name) for p, name in ((a, "a"), (b, "b"), (c, "c")))
    _same_length(a, b, c)
    # Shewchuk's orient2dfast: det[a - c, b - c], same sign as det[b - a, c - a].
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        acx, acy = a[:, 0] - c[:, 0], a[:, 1] - c[:, 1]
        bcx, bcy = b[:, 0] - c[:, 0], b[:, 1] - c[:, 1]
        left, right = acx * bcy, acy * bcx
        det = left - right
        errbound = CCW_ERRBOUND_A * (np.abs(left) + np.abs(right))
    sure = ((np.abs(det) > errbound) | (errbound == 0)) & _no_tiny(acx, acy, bcx, bcy)
    out = _sign(np.where(sure, det, 0.0))
    todo = np.flatnonzero(~sure)
    todo = todo[_exact_needed(a[todo], b[todo], c[todo])]
    if todo.size:
        out[todo] = _exact_orient2d(a[todo], b[todo], c[todo])
    return out


def orient3d(a, b, c, d) -> np.ndarray:
    """Exact sign of ``det[b - a, c - a, d - a]`` for many tetrahedra.

    Parameters
    ----------
    a, b, c, d : (m, 3) float arrays
        Corners of ``m`` tetrahedra.

    Returns
    -------
    s : (m,) int8 array
        ``+1`` if ``d`` lies on the side of plane ``a, b, c`` towards which
        ``(b - a) x (c - a)`` points, ``-1`` on the other side, ``0`` coplanar
        (or a coordinate is NaN or inf).
        (This is minus Shewchuk's ``orient3d``.)
    """
    a, b, c, d = (
        _as_points(p, 3, name) for p, name in ((a, "a"), (b, "b"), (c, "c"), (d, "d"))
    )
    _same_length(a, b, c, d)
    # Shewchuk's orient3dfast: det[a - d, b - d, c - d] = -det[b - a, c - a, d - a].
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        adx, ady, adz = (a - d).T
        bdx, bdy, bdz = (b - d).T
        cdx, cdy, cdz = (c - d).T
        bdxcdy, cdxbdy = bdx * cdy, cdx * bdy
        cdxady, adxcdy = cdx * ady, adx * cdy
        adxbdy, bdxady = adx * bdy, bdx * ady
        det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady)
        permanent = (
            (np.abs(bdxcdy) + np.abs(cdxbdy)) * np.abs(adz)
            + (np.abs(cdxady) + np.abs(adxcdy)) * np.abs(bdz)
            + (np.abs(adxbdy) + np.abs(bdxady)) * np.abs(cdz)
        )
        errbound = O3D_ERRBOUND_A * permanent
    sure = ((np.abs(det) > errbound) | (errbound == 0)) & _no_tiny(
        adx, ady, adz, bdx, bdy, bdz, cdx, cdy, cdz)
    out = -_sign(np.where(sure, det, 0.0))
    todo = np.flatnonzero(~sure)
    todo = todo[_exact_needed(a[todo], b[todo], c[todo], d[todo])]
    if todo.size:
        out[todo] = _exact_orient3d(a[todo], b[todo], c[todo], d[todo])
    return out


def normal_signs(a, b, c) -> np.ndarray:
    """Exact signs of the components of the normal ``(b - a) x (c - a)`` of many 3D triangles.

    Component ``z``, ``x`` and ``y`` of the normal is :func:`orient2d` of the triangle projected
    onto the ``xy``, ``yz`` and ``zx`` plane; the three are filtered together (one set of
    differences) and only uncertain ones are recomputed exactly.

    Parameters
    ----------
    a, b, c : (m, 3) float arrays

    Returns
    -------
    s : (m, 3) int8 array, the signs of ``n_z, n_x, n_y`` (in that order); all three are zero
        exactly when the triangle is degenerate (or has a non-finite coordinate).
    """
    a, b, c = (_as_points(p, 3, name) for p, name in ((a, "a"), (b, "b"), (c, "c")))
    _same_length(a, b, c)
    out = np.empty((3, a.shape[0]), np.int8)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        ac, bc = (a - c).T.copy(), (b - c).T.copy()  # (3, m): contiguous coordinate rows
        small = (ac != 0) & (np.abs(ac) < _TINY) | (bc != 0) & (np.abs(bc) < _TINY)
        for col, (p, q) in enumerate(_PLANES):
            left, right = ac[p] * bc[q], ac[q] * bc[p]
            det = left - right
            errbound = CCW_ERRBOUND_A * (np.abs(left) + np.abs(right))
            sure = ((np.abs(det) > errbound) | (errbound == 0)) & ~small[p] & ~small[q]
            out[col] = _sign(np.where(sure, det, 0.0))
            todo = np.flatnonzero(~sure)
            if todo.size:
                pq = [p, q]
                out[col, todo] = orient2d(a[todo][:, pq], b[todo][:, pq], c[todo][:, pq])
    return out.T


def simplex_orientations(X, S) -> np.ndarray:
    """Exact orientation of every triangle (2D) or tetrahedron (3D).

    Parameters
    ----------
    X : (n, 2) or (n, 3) float array
        Vertex positions.
    S : (m, 3) int array for ``X`` of shape (n, 2), (m, 4) for (n, 3)
        Elements, as vertex indices.

    Returns
    -------
    s : (m,) int8 array
        ``orient2d(X[S[:, 0]], X[S[:, 1]], X[S[:, 2]])`` or the ``orient3d`` analogue.
    """
    X, S = _as_mesh(X, S)
    d = X.shape[1]
    corners = [X[S[:, i]] for i in range(d + 1)]
    return orient2d(*corners) if d == 2 else orient3d(*corners)


def cone_orientations(X, F) -> np.ndarray:
    """Exact orientation of every triangle of a map onto the sphere about its centre.

    Parameters
    ----------
    X : (n, 3) float array
        Vertex positions (directions from the centre; their lengths do not matter).
    F : (m, 3) int array
        Triangles.

    Returns
    -------
    s : (m,) int8 array
        ``orient3d(0, X[a], X[b], X[c])``, the sign of ``det[X[a], X[b], X[c]]``: ``+1`` when
        the triangle turns counter-clockwise seen from outside the sphere.
    """
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"the triangles must have shape (m, 3), got shape {F.shape}")
    # checked as the tets (a, a, b, c): shapes, dtypes and index range
    X, T = _as_mesh(X, F[:, [0, 0, 1, 2]], dims=(3,))
    return orient3d(np.zeros((len(T), 3)), X[T[:, 1]], X[T[:, 2]], X[T[:, 3]])


def _as_mesh(X, S, dims=(2, 3)):
    """``(X (n, d) float64, S (m, d+1))`` checked (shapes, dtypes, index range), ``d`` in
    ``dims``; concrete values only.  Raises MeshError."""
    refuse_traced("exact orientation predicates", "they certify concrete maps; inside a trace use Objective.dets(x) (float determinants)", X)
    X = np.asarray(X)
    if X.ndim != 2 or X.shape[1] not in dims:
        shapes = " or ".join(f"(n, {d})" for d in dims)
        raise MeshError(f"X must be an array of shape {shapes}, got shape {X.shape}")
    d = X.shape[1]
    X = _as_points(X, d, "X")
    S = np.asarray(S)
    if S.ndim != 2 or S.shape[1] != d + 1:
        raise MeshError(
            f"with {d}D vertices the elements must have shape (m, {d + 1}), got shape {S.shape}"
        )
    if S.dtype.kind not in "iu":
        raise MeshError(f"elements must hold integer vertex indices, got dtype {S.dtype}")
    if S.size and (S.min() < 0 or S.max() >= X.shape[0]):
        raise MeshError(
            f"element vertex indices must lie in [0, {X.shape[0]}), "
            f"got range [{S.min()}, {S.max()}]"
        )
    return X, S


def count_inverted(X, S, orientation: int = 1) -> int:
    """Number of elements whose exact orientation is not ``orientation``.

    Degenerate (zero-area / zero-volume) elements count as inverted.

    Parameters
    ----------
    X : (n, 2) or (n, 3) float array
    S : (m, 3) or (m, 4) int array
        See :func:`simplex_orientations`.
    orientation : {+1, -1}
        The orientation every element should have.

    Returns
    -------
    count : int
    """
    if isinstance(orientation, (bool, np.bool_)) or orientation not in (1, -1):
        raise ParameterError(f"orientation must be +1 or -1, got {orientation!r}")
    return int(np.count_nonzero(simplex_orientations(X, S) != orientation))


def vertex_windings(X, F) -> np.ndarray:
    """How many times the triangles around each vertex wind around it, exactly.

    For a map with every triangle positively oriented, an interior vertex whose fan winds
    ``k > 1`` times is a branch point (angle sum ``2 pi k``): no triangle is inverted, yet the
    map is not locally injective there (the fan covers a neighbourhood ``k`` times).

    Each corner ``(v, a, b)`` of a counter-clockwise triangle is counted when its angular
    sector ``[a - v, b - v)`` contains the direction ``+x``, that is when ``a_y <= v_y < b_y``
    (exact float comparisons; valid for positively oriented triangles only).

    Parameters
    ----------
    X : (n, 2) float array, the map.
    F : (m, 3) int array, triangles positively oriented under ``X``.

    Returns
    -------
    windings : (n,) int64; 1 at every interior vertex of a locally injective map.
    """
    X, F = _as_mesh(X, F, dims=(2,))
    out = np.zeros(len(X), dtype=np.int64)
    y = X[:, 1]
    for k in range(3):
        v, a, b = F[:, k], F[:, (k + 1) % 3], F[:, (k + 2) % 3]
        hit = (y[a] <= y[v]) & (y[v] < y[b])
        np.add.at(out, v[hit], 1)
    return out


def branch_vertices(X, F) -> np.ndarray:
    """Interior vertices of a 2D map with every triangle positive whose fan winds around them
    more than once (:func:`vertex_windings` != 1): where the map is not locally injective.

    Parameters
    ----------
    X : (n, 2) float array;  F : (m, 3) int array, positively oriented under ``X``.

    Returns
    -------
    (k,) int64 vertex ids, sorted.
    """
    from .topology import boundary_vertices

    X, F = _as_mesh(X, F, dims=(2,))
    interior = np.ones(len(X), dtype=bool)
    interior[boundary_vertices(F, len(X))] = False
    return np.flatnonzero(interior & (vertex_windings(X, F) != 1))


def differing_rows(a, b) -> np.ndarray:
    """Which rows of ``a`` and ``b`` (k, d) differ as numbers, exactly: the test of a handle
    kept in place.  ``-0.0`` equals ``0.0`` (the same point: meshes made by mirroring or
    trigonometry carry both, and arithmetic may turn one into the other); NaN equals nothing.

    Returns
    -------
    (k,) bool.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return (a != b).any(axis=-1)


def box_scale(x, box: float = 1.0) -> float:
    """The power of two ``k`` with ``x * k`` (x (n, d)) spanning about ``box``; 1.0 for an
    empty, flat or non-finite ``x``.  Multiplying by ``k`` and dividing back are exact in
    float64 (away from overflow and subnormals), so sizes, energies and float tests computed
    on ``x * k`` are those of ``x`` without overflowing at 1e200 or underflowing at 1e-150."""
    x = np.asarray(x, dtype=np.float64)
    span = float(np.max(x.max(axis=0) - x.min(axis=0))) if x.size else 0.0
    v = box / span if span > 0 else 0.0
    return float(2.0 ** round(math.log2(v))) if v > 0 and math.isfinite(v) else 1.0

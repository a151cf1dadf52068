"""Exact signs of each element's direction against its corners' vertex directions: the fold
test of a surface (or a curve) that has no map to the plane.

For a triangle surface, the normal of face ``f`` is ``n_f = (b - a) x (c - a)`` (twice its area
times its unit normal) and the normal of vertex ``v`` is ``N_v = sum over the faces g around v of
n_g``: the area-weighted mean of the incident faces' unit normals, up to a positive factor.  Face
``f`` is *unfolded* at its corner ``v`` when ``n_f . N_v > 0``.  For a polyline, the direction of
edge ``e = (a, b)`` is ``d_e = b - a`` and the tangent of vertex ``v`` is ``D_v = sum over the edges
around v of d_e`` (the length-weighted mean of unit tangents); edge ``e`` is unfolded at its end
``v`` when ``d_e . D_v > 0``.

Each sign is first evaluated in float64 with an a-priori error bound (a static filter in the
manner of Shewchuk, "Adaptive precision floating-point arithmetic and fast robust geometric
predicates", 1997); those the bound does not certify (degenerate elements among them) are
recomputed exactly with Python integers (every float64 is ``M * 2**E``; after scaling all the
coordinates involved by one power of two they are integers, and so is the dot product).

The bound (``eps = 2**-53``, ``gamma_k = k eps / (1 - k eps)``, Higham's notation; the
coordinates are first scaled by an exact power of two to span about 1, so nothing overflows).
A triangle's normal component ``u_i v_j - u_j v_i`` is computed from rounded differences
``u = fl(b - a)`` (one rounding each), two rounded products and one rounded subtraction: its
error is at most ``gamma_4 (|u_i v_j| + |u_j v_i|)``, the *magnitude* ``mag`` of the component.
A vertex sum of ``deg`` such components adds ``gamma_{deg - 1}`` times the sum of their
magnitudes, and the dot product of three terms ``gamma_3`` of the sum of the products'
magnitudes.  So ``|fl(n_f . N_v) - n_f . N_v| <= gamma_{deg + 10} sum_d mag_f[d] MAG_v[d]``
(``MAG_v`` the vertex sum of the magnitudes) up to second order terms.  The filter bounds every
component's magnitude of a face by one number, ``m_f = 2 max_i |u_i| max_j |v_j|`` (one pass
instead of three products per component, and one vertex sum ``M_v`` of them instead of three),
which only loosens the bound: ``sum_d mag_f[d] MAG_v[d] <= 3 m_f M_v``; it uses twice the first
order factor, ``2 (deg + 10) eps``, which covers the second order terms and the rounding of the
bound's own evaluation (a few relative ``eps``).  Edges (degree 2) are the same with fewer
roundings and ``m_e = max_i |d_i|`` (times the dimension ``d`` in place of 3).  That model holds while no intermediate result underflows; below the
normal range each of the few hundred roundings loses at most ``2**-1075`` absolutely, which the
absolute allowance ``2**-900`` covers.  A sign is taken from float64 only where ``|value|``
exceeds the bound (and ``value`` is finite); ``normal_agreement`` likewise with ``32 eps``
(two normals of ``gamma_4`` each and a dot product of ``gamma_3``) times ``3 m_f(X) m_f(Y)``.  tests/test_normals_filter.py
checks every reported sign against rational arithmetic on inputs that float64 alone gets wrong.
"""

from __future__ import annotations

import numpy as np

from .._runtime.errors import MeshError
from .._runtime.tracing import refuse_traced
from .predicates import box_scale

__all__ = ["corner_signs", "normal_agreement", "signs_and_agreement"]

_EPS = 2.0**-53
#: an absolute allowance for underflow: each of the few hundred roundings of a value may lose up to
#: 2**-1074 below the normal range, where the relative bound alone fails
_UNDERFLOW = 2.0**-900


def _checked(X, S):
    refuse_traced("exact fold signs", "they certify concrete vertices", X)
    X, S = np.asarray(X), np.asarray(S)
    if X.ndim != 2 or X.shape[1] not in (2, 3) or X.dtype.kind not in "fiub":
        raise MeshError(f"vertices must be a real array of shape (n, 2) or (n, 3), got {X.dtype} {X.shape}")
    if S.ndim != 2 or S.shape[1] not in (2, 3) or S.dtype.kind not in "iu":
        raise MeshError(f"elements must be integer edges (m, 2) or triangles (m, 3), got {S.dtype} {S.shape}")
    if S.shape[1] == 3 and X.shape[1] != 3:
        raise MeshError(f"triangles need 3D vertices, got shape {X.shape}")
    if S.size and (S.min() < 0 or S.max() >= len(X)):
        raise MeshError(f"element vertex indices must lie in [0, {len(X)}), got [{S.min()}, {S.max()}]")
    X = X.astype(np.float64)
    return X * box_scale(X) if np.isfinite(X).all() else X, S.astype(np.int64)


def _directions(X, S):
    """``(dirs, mag)``: each element's direction (d, m) (the triangle normal or the edge vector),
    coordinate-major, and a bound (m,) of every component's magnitude (see the module notes:
    ``2 max_i |u_i| max_j |v_j|`` for a triangle, ``max_i |d_i|`` for an edge).  Every gather is
    one-dimensional (a coordinate row taken at a row of corner indices): several times faster
    than NumPy's gathers of rows of a 2-D array."""
    Xt, St = np.ascontiguousarray(X.T), np.ascontiguousarray(S.T)  # (d, n), (k, m)
    if S.shape[1] == 2:
        d = np.stack([x.take(St[1]) - x.take(St[0]) for x in Xt])
        return d, _largest(d)
    u, v = np.empty((3, len(S))), np.empty((3, len(S)))
    for x, ui, vi in zip(Xt, u, v):
        a = x.take(St[0])
        np.subtract(x.take(St[1]), a, out=ui)
        np.subtract(x.take(St[2]), a, out=vi)
    cols, other = np.empty_like(u), np.empty(len(S))
    for c, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(u[i], v[j], out=cols[c])
        np.multiply(u[j], v[i], out=other)
        cols[c] -= other
    mag = _largest(u)
    mag *= _largest(v)
    mag *= 2.0
    return cols, mag


def _largest(a):
    """(m,) the largest magnitude in each column of ``a`` (d, m)."""
    out = np.abs(a[0])
    for row in a[1:]:
        np.maximum(out, np.abs(row), out=out)
    return out


def _vertex_sums(values, S, n):
    """(d, n) the sum over the elements around each vertex of ``values`` (d, m) (a bincount per
    coordinate: the same float sums as ``np.add.at`` up to order, an order of magnitude faster)."""
    ids = S.T.ravel()
    return np.stack([np.bincount(ids, weights=np.tile(row, S.shape[1]), minlength=n) for row in values])


def _corner_dots(dirs, sums, St):
    """(k, m) ``dirs[:, f] . sums[:, St[c, f]]``: each element's direction (d, m) against the
    vertex sums (d, n) at its corners ``St`` (k, m) (corner-major, so every product runs along
    contiguous rows)."""
    out = dirs[0] * sums[0].take(St)
    for c in range(1, len(dirs)):
        out += dirs[c] * sums[c].take(St)
    return out


def corner_signs(X, S) -> np.ndarray:
    """Exact sign of each element's direction against the vertex direction at each corner.

    Parameters
    ----------
    X : (n, 3) vertices of a triangle surface, or (n, 2) / (n, 3) vertices of a polyline.
    S : (m, 3) triangles, or (m, 2) edges.

    Returns
    -------
    (m, k) int8, ``k`` = 3 (triangles) or 2 (edges): the sign of ``n_f . N_{S[f, c]}`` (see the
    module notes); 0 where it vanishes or a coordinate is not finite.  A surface or curve is
    fold-free exactly when every sign is +1.
    """
    X, S = _checked(X, S)
    if len(S) == 0:
        return np.zeros((0, S.shape[1]), np.int8)
    with np.errstate(all="ignore"):
        return _corner_signs(X, S, _directions(X, S))


def signs_and_agreement(X, Y, F):
    """``(corner_signs(X, F), normal_agreement(X, Y, F))``, the same exact signs, with the
    float directions of ``X`` computed once for both (the fold-safe step's first check)."""
    X, S = _checked(X, F)
    Y, _ = _checked(Y, F)
    if S.shape[1] != 3:
        raise MeshError(f"normal_agreement needs triangles (m, 3), got shape {S.shape}")
    if len(S) == 0:
        return np.zeros((0, 3), np.int8), np.zeros(0, np.int8)
    with np.errstate(all="ignore"):
        dirs = _directions(X, S)
        return _corner_signs(X, S, dirs), _agreement(X, Y, S, dirs, _directions(Y, S))


def _corner_signs(X, S, directions):
    """:func:`corner_signs` of the scaled ``X`` (:func:`_checked`) from its ``directions``
    (:func:`_directions`)."""
    n = len(X)
    dirs, mag = directions
    sums, sum_mag = _vertex_sums(dirs, S, n), _vertex_sums(mag[None], S, n)[0]
    St = np.ascontiguousarray(S.T)
    # (n,) per vertex: its magnitude sum times 2 (deg + 10) eps, times the dimension
    factor = (2.0 * _EPS * len(dirs)) * (np.bincount(St.ravel(), minlength=n) + 10.0) * sum_mag
    value = _corner_dots(dirs, sums, St)
    bound = factor.take(St)
    bound *= mag
    bound += _UNDERFLOW
    sure = np.abs(value) > bound
    sure &= np.isfinite(value)
    out = np.ascontiguousarray(_signs(value, sure).T)
    if sure.all():
        return out
    sure = sure.T
    finite = np.isfinite(X).all(axis=1)
    ok_corner = finite[S].all(axis=1, keepdims=True) & np.isfinite(sums).all(axis=0)[S]
    todo = np.argwhere(~sure & ok_corner & _finite_stars(finite, S, n)[S])
    if len(todo):
        out[todo[:, 0], todo[:, 1]] = _exact(X, S, todo)
    return out


def _finite_stars(finite, S, n):
    """(n,) bool: every element around the vertex has finite corners."""
    bad = np.zeros(n, bool)
    for k in range(S.shape[1]):
        bad[S[:, k]] |= ~finite[S].all(axis=1)
    return ~bad


def _integers(X):
    """``X`` (p, d) finite float64 as Python integers times one common power of two."""
    mant, expo = np.frexp(X)
    M = np.ldexp(mant, 53).astype(np.int64)
    E = expo.astype(np.int64) - 53
    nonzero = M != 0
    emin = int(E[nonzero].min()) if nonzero.any() else 0
    shift = np.where(nonzero, E - emin, 0)
    return M.astype(object) << shift.astype(object)


def _exact(X, S, todo) -> np.ndarray:
    """The exact signs at the corners ``todo`` (k, 2) (element, corner) with Python integers."""
    centres = np.unique(S[todo[:, 0], todo[:, 1]])
    near = np.isin(S, centres).any(axis=1)
    near[todo[:, 0]] = True
    elements = np.flatnonzero(near)
    used = np.unique(S[elements])
    Q = np.zeros((len(X), X.shape[1]), dtype=object)
    Q[used] = _integers(X[used])
    sub = S[elements]
    if S.shape[1] == 2:
        dirs = Q[sub[:, 1]] - Q[sub[:, 0]]
    else:
        u, v = Q[sub[:, 1]] - Q[sub[:, 0]], Q[sub[:, 2]] - Q[sub[:, 0]]
        dirs = np.stack([u[:, i] * v[:, j] - u[:, j] * v[:, i] for i, j in ((1, 2), (2, 0), (0, 1))], axis=1)
    sums = np.zeros((len(X), dirs.shape[1]), dtype=object)
    for k in range(S.shape[1]):
        np.add.at(sums, sub[:, k], dirs)
    row = np.full(len(S), -1, np.int64)
    row[elements] = np.arange(len(elements))
    d, s = dirs[row[todo[:, 0]]], sums[S[todo[:, 0], todo[:, 1]]]
    value = (d * s).sum(axis=1)
    return np.array([(v > 0) - (v < 0) for v in value], dtype=np.int8)


def _signs(value, sure):
    """int8 like ``value``: its sign where ``sure``, 0 elsewhere."""
    out = np.zeros(value.shape, np.int8)
    out[sure & (value > 0)] = 1
    out[sure & (value < 0)] = -1
    return out


def normal_agreement(X, Y, F) -> np.ndarray:
    """Exact sign of ``n_f(X) . n_f(Y)`` for each triangle: whether its normal on ``X`` is within
    90 degrees of its normal on ``Y`` (both (n, 3); ``F`` (m, 3)).

    Returns
    -------
    (m,) int8: +1 within 90 degrees, -1 beyond, 0 at exactly 90 degrees, on a degenerate
    triangle or a non-finite coordinate.
    """
    X, S = _checked(X, F)
    Y, _ = _checked(Y, F)
    if S.shape[1] != 3:
        raise MeshError(f"normal_agreement needs triangles (m, 3), got shape {S.shape}")
    with np.errstate(all="ignore"):
        return _agreement(X, Y, S, _directions(X, S), _directions(Y, S))


def _agreement(X, Y, S, x_directions, y_directions):
    """:func:`normal_agreement` of the scaled ``X, Y`` from their :func:`_directions`."""
    (nx, mx), (ny, my) = x_directions, y_directions
    value = nx[0] * ny[0] + nx[1] * ny[1] + nx[2] * ny[2]
    bound = mx * my * (3 * 32.0 * _EPS) + _UNDERFLOW
    sure = (np.abs(value) > bound) & np.isfinite(value)
    out = _signs(value, sure)
    if sure.all():
        return out
    finite = np.isfinite(X).all(axis=1) & np.isfinite(Y).all(axis=1)
    todo = np.flatnonzero(~sure & finite[S].all(axis=1))
    if len(todo):
        corners = np.concatenate([X[S[todo]], Y[S[todo]]], axis=1).reshape(-1, 3)
        Q = _integers(corners).reshape(len(todo), 6, 3)  # one common power of two: signs kept
        out[todo] = [_exact_normal_dot(q) for q in Q]
    return out


def _exact_normal_dot(q) -> int:
    """The sign of ``n(q0, q1, q2) . n(q3, q4, q5)`` for integer points ``q`` (6, 3)."""
    def normal(a, b, c):
        u, v = b - a, c - a
        return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]

    d = sum(x * y for x, y in zip(normal(*q[:3]), normal(*q[3:])))
    return (d > 0) - (d < 0)

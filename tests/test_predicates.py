"""Tests for geomopt.exact.predicates: exact orientation signs, checked against Fractions."""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geomopt import MeshError, ParameterError
from geomopt.exact.predicates import count_inverted, orient2d, orient3d, simplex_orientations

ULP = 2.0**-53  # ulp of numbers in [0.5, 1)


def sign(x):
    return (x > 0) - (x < 0)


def ref2d(a, b, c):
    """Exact sign of det[b - a, c - a] with Fractions, one triangle at a time."""
    out = []
    for p, q, r in zip(a, b, c):
        p, q, r = ([Fraction(float(t)) for t in x] for x in (p, q, r))
        out.append(sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])))
    return np.array(out, dtype=np.int8)


def ref3d(a, b, c, d):
    out = []
    for p, q, r, s in zip(a, b, c, d):
        p, q, r, s = ([Fraction(float(t)) for t in x] for x in (p, q, r, s))
        u = [q[i] - p[i] for i in range(3)]
        v = [r[i] - p[i] for i in range(3)]
        w = [s[i] - p[i] for i in range(3)]
        det = (
            u[0] * (v[1] * w[2] - v[2] * w[1])
            - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0])
        )
        out.append(sign(det))
    return np.array(out, dtype=np.int8)


def float2d(a, b, c):
    u, v = b - a, c - a
    return np.sign(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).astype(np.int8)


def float3d(a, b, c, d):
    return np.sign(np.linalg.det(np.stack([b - a, c - a, d - a], axis=1))).astype(np.int8)


# ---------------------------------------------------------------- agreement with floats


def test_orient2d_agrees_with_float_when_well_conditioned():
    rng = np.random.default_rng(0)
    a, b, c = rng.normal(size=(3, 20000, 2))
    u, v = b - a, c - a
    det = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    ok = np.abs(det) > 1e-8
    s = orient2d(a, b, c)
    assert s.dtype == np.int8 and s.shape == (20000,)
    np.testing.assert_array_equal(s[ok], np.sign(det[ok]))


def test_orient3d_agrees_with_float_when_well_conditioned():
    rng = np.random.default_rng(1)
    a, b, c, d = rng.normal(size=(4, 20000, 3))
    det = np.linalg.det(np.stack([b - a, c - a, d - a], axis=1))
    ok = np.abs(det) > 1e-8
    s = orient3d(a, b, c, d)
    assert s.dtype == np.int8 and s.shape == (20000,)
    np.testing.assert_array_equal(s[ok], np.sign(det[ok]))


def test_unit_simplices():
    assert orient2d([[0.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]])[0] == 1
    assert orient2d([[0.0, 0.0]], [[0.0, 1.0]], [[1.0, 0.0]])[0] == -1
    e = np.eye(3)
    assert orient3d([[0.0, 0, 0]], e[[0]], e[[1]], e[[2]])[0] == 1
    assert orient3d([[0.0, 0, 0]], e[[1]], e[[0]], e[[2]])[0] == -1


# ---------------------------------------------------------------- near-degenerate cases


def test_shewchuk_orient2d_example():
    # Shewchuk (1997), Fig. 1: a = (0.5 + x u, 0.5 + y u) against b = (12, 12), c = (24, 24).
    x, y = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    x, y = x.ravel(), y.ravel()
    a = np.stack([0.5 + x * ULP, 0.5 + y * ULP], axis=1)
    b = np.full_like(a, 12.0)
    c = np.full_like(a, 24.0)
    exact = np.sign(y - x)  # det[b - a, c - a] = 12 (a_y - a_x)
    assert (float2d(a, b, c) != exact).sum() > 1000  # plain floats get many wrong
    np.testing.assert_array_equal(orient2d(a, b, c), exact)


def test_one_ulp_off_a_line():
    rng = np.random.default_rng(2)
    m = 5000
    p, q = rng.uniform(-100, 100, size=(2, m))
    t = rng.uniform(-1000, 1000, size=m)
    a, b = np.stack([p, p], 1), np.stack([q, q], 1)
    step = rng.choice([-1, 0, 1], size=m)
    cy = np.where(step > 0, np.nextafter(t, np.inf), np.where(step < 0, np.nextafter(t, -np.inf), t))
    c = np.stack([t, cy], 1)
    exact = np.sign(q - p).astype(int) * step  # det = (q - p) (c_y - c_x)
    np.testing.assert_array_equal(orient2d(a, b, c), exact)
    np.testing.assert_array_equal(exact[:300], ref2d(a[:300], b[:300], c[:300]))


def test_general_line_perturbed_by_ulps_matches_fractions():
    rng = np.random.default_rng(3)
    m = 3000
    a, b = rng.uniform(-1, 1, size=(2, m, 2))
    t = rng.uniform(-3, 3, size=(m, 1))
    c = a + t * (b - a)  # on the line up to rounding
    k = rng.integers(-2, 3, size=(m, 2))
    c = c + k * np.spacing(c)
    np.testing.assert_array_equal(orient2d(a, b, c), ref2d(a, b, c))
    d3 = np.column_stack([c, rng.uniform(-1, 1, m)])
    a3 = np.column_stack([a, np.zeros(m)])
    b3 = np.column_stack([b, np.zeros(m)])
    # plane through a3, b3 and the z axis direction: d3 near it after the ulp nudges
    c3 = a3 + [0.0, 0.0, 1.0]
    np.testing.assert_array_equal(orient3d(a3, b3, c3, d3), ref3d(a3, b3, c3, d3))


def test_near_coplanar_3d_matches_fractions():
    rng = np.random.default_rng(4)
    m = 3000
    a, b, c = rng.uniform(-1, 1, size=(3, m, 3))
    s, t = rng.uniform(-2, 2, size=(2, m, 1))
    d = a + s * (b - a) + t * (c - a)
    d = d + rng.integers(-1, 2, size=(m, 3)) * np.spacing(d)
    got = orient3d(a, b, c, d)
    np.testing.assert_array_equal(got, ref3d(a, b, c, d))
    assert (got != float3d(a, b, c, d)).any()  # floats alone are not enough here


@pytest.mark.parametrize("scale", [2.0**-1000, 2.0**-540, 2.0**500, 2.0**1000])
def test_extreme_scales(scale):
    # products underflow or overflow in float64; the sign must still be exact
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]) * scale
    assert orient2d(tri[[0]], tri[[1]], tri[[2]])[0] == 1
    assert orient2d(tri[[0]], tri[[2]], tri[[1]])[0] == -1
    tet = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) * scale
    assert orient3d(*tet[:, None, :])[0] == 1
    assert orient3d(*tet[[1, 0, 2, 3], None, :])[0] == -1


# ---------------------------------------------------------------- exact zeros


def test_exactly_collinear_is_zero():
    rng = np.random.default_rng(5)
    m = 2000
    p = rng.integers(-1000, 1000, size=(m, 2)) * 2.0**-20
    d = rng.integers(-1000, 1000, size=(m, 2)) * 2.0**-30
    k = rng.integers(-50, 50, size=(3, m, 1))
    a, b, c = p + k[0] * d, p + k[1] * d, p + k[2] * d  # exact dyadic arithmetic
    np.testing.assert_array_equal(orient2d(a, b, c), 0)
    np.testing.assert_array_equal(orient2d(a, a, c), 0)  # repeated point


def test_exactly_coplanar_is_zero():
    rng = np.random.default_rng(6)
    m = 2000
    xy = rng.integers(-(2**20), 2**20, size=(4, m, 2)).astype(float)
    z = 2.0 * xy[..., 0] - 3.0 * xy[..., 1] + 5.0  # plane z = 2x - 3y + 5
    P = np.concatenate([xy, z[..., None]], axis=-1) * 2.0**-40
    np.testing.assert_array_equal(orient3d(*P), 0)
    assert (float3d(*P) != 0).any()  # float determinants are not exactly 0 here
    np.testing.assert_array_equal(orient3d(P[0], P[1], P[1], P[3]), 0)


# ---------------------------------------------------------------- symmetry, property tests

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
coords = st.one_of(finite, st.floats(-4.0, 4.0), st.integers(-3, 3).map(float))


def near_line_points():
    """Three points, the third on the line of the first two up to a few ulps."""
    base = st.floats(-1e3, 1e3)

    def build(v):
        ax, ay, bx, by, t, kx, ky = v
        cx = ax + t * (bx - ax)
        cy = ay + t * (by - ay)
        cx += kx * np.spacing(cx)
        cy += ky * np.spacing(cy)
        return [(ax, ay), (bx, by), (cx, cy)]

    ints = st.integers(-3, 3)
    return st.tuples(base, base, base, base, st.floats(-4, 4), ints, ints).map(build)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.lists(st.tuples(coords, coords), min_size=3, max_size=3), near_line_points()))
def test_orient2d_matches_fractions_and_is_antisymmetric(pts):
    a, b, c = (np.array([p], dtype=float) for p in pts)
    s = orient2d(a, b, c)[0]
    assert s == ref2d(a, b, c)[0]
    assert orient2d(b, a, c)[0] == -s
    assert orient2d(a, c, b)[0] == -s
    assert orient2d(c, b, a)[0] == -s
    assert orient2d(b, c, a)[0] == s  # cyclic shift keeps the sign


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(coords, coords, coords), min_size=4, max_size=4))
def test_orient3d_matches_fractions_and_is_antisymmetric(pts):
    a, b, c, d = (np.array([p], dtype=float) for p in pts)
    s = orient3d(a, b, c, d)[0]
    assert s == ref3d(a, b, c, d)[0]
    assert orient3d(b, a, c, d)[0] == -s
    assert orient3d(a, b, d, c)[0] == -s
    assert orient3d(d, b, c, a)[0] == -s
    assert orient3d(b, c, a, d)[0] == s  # even permutation


def test_antisymmetry_vectorised():
    rng = np.random.default_rng(7)
    a, b, c, d = rng.normal(size=(4, 10000, 3))
    # make a third of them exactly degenerate and a third nearly so
    c[::3] = a[::3]
    d[1::3] = a[1::3] + 0.5 * (b[1::3] - a[1::3]) + np.spacing(a[1::3])
    s = orient3d(a, b, c, d)
    np.testing.assert_array_equal(orient3d(b, a, c, d), -s)
    np.testing.assert_array_equal(orient3d(a, c, b, d), -s)
    np.testing.assert_array_equal(orient3d(a, b, d, c), -s)
    s2 = orient2d(a[:, :2], b[:, :2], d[:, :2])
    np.testing.assert_array_equal(orient2d(d[:, :2], b[:, :2], a[:, :2]), -s2)


# ---------------------------------------------------------------- mesh-level functions


def test_simplex_orientations_triangles_and_tets():
    X2 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 0.0]])
    S2 = np.array([[0, 1, 2], [0, 2, 1], [0, 1, 3]])
    np.testing.assert_array_equal(simplex_orientations(X2, S2), [1, -1, 0])
    X3 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]])
    S3 = np.array([[0, 1, 2, 3], [1, 0, 2, 3], [0, 1, 2, 4]])
    np.testing.assert_array_equal(simplex_orientations(X3, S3), [1, -1, 0])
    X_int = np.array([[0, 0], [1, 0], [0, 1]])  # integer coordinates are accepted
    assert simplex_orientations(X_int, np.array([[0, 1, 2]]))[0] == 1


def test_count_inverted():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 0.0]])
    S = np.array([[0, 1, 2], [0, 2, 1], [0, 1, 3], [1, 2, 0]])
    assert count_inverted(X, S) == 2  # one flipped, one degenerate
    assert count_inverted(X, S, orientation=-1) == 3
    assert isinstance(count_inverted(X, S), int)
    with pytest.raises(ParameterError, match=r"\+1 or -1"):
        count_inverted(X, S, orientation=0)


@pytest.mark.parametrize(
    "X, S, match",
    [
        (np.zeros((4, 4)), np.array([[0, 1, 2]]), r"\(n, 2\) or \(n, 3\)"),
        (np.zeros((4, 2)), np.array([[0, 1, 2, 3]]), r"\(m, 3\)"),
        (np.zeros((4, 3)), np.array([[0, 1, 2]]), r"\(m, 4\)"),
        (np.zeros((4, 2)), np.array([[0, 1, 4]]), r"\[0, 4\)"),
        (np.zeros((4, 2)), np.array([[0, -1, 2]]), r"\[0, 4\)"),
        (np.zeros((4, 2)), np.array([[0.0, 1.0, 2.0]]), "integer"),
    ],
)
def test_simplex_orientations_bad_input(X, S, match):
    with pytest.raises(MeshError, match=match):
        simplex_orientations(X, S)


def test_orient_bad_shapes():
    with pytest.raises(MeshError, match=r"\(m, 2\)"):
        orient2d(np.zeros((3, 3)), np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(MeshError, match="same number of rows"):
        orient2d(np.zeros((3, 2)), np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(MeshError, match=r"\(m, 3\)"):
        orient3d(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 2)), np.zeros((3, 3)))


def test_non_finite_coordinates_give_zero():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [np.nan, 0.0], [np.inf, 1.0], [np.inf, 2.0]])
    S = np.array([[0, 1, 2], [0, 1, 3], [0, 4, 2], [4, 5, 0], [2, 1, 0]])
    with np.errstate(all="raise"):  # and no floating-point warnings
        np.testing.assert_array_equal(simplex_orientations(X, S), [1, 0, 0, 0, -1])
        assert count_inverted(X, S) == 4
    X3 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [np.inf, np.inf, np.inf]])
    S3 = np.array([[0, 1, 2, 3], [0, 1, 2, 4], [4, 1, 2, 4]])
    np.testing.assert_array_equal(simplex_orientations(X3, S3), [1, 0, 0])

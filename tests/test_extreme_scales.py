"""Every exact routine is exact for every finite float input (issue 19 item 3).

Fuzzed against brute-force oracles in exact rational arithmetic, at scales from the subnormal
range (1e-310 and below) to 1e300 and above: the orientation predicates, polygon simplicity
(``polygon_crossings``: its grid broad phase once overflowed ``1 / h`` on subnormal
coordinates and missed crossings), ``certify_bijective`` and the local certificate.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geomopt.exact.certify import certify_bijective, local_certificate, polygon_crossings, polygon_orientation
from geomopt.exact.predicates import normal_signs, orient2d, orient3d
from geomopt import ParamOptions

# powers of two: exact scalings of small-integer data, from the deepest subnormals to near overflow
EXPONENTS = [-1074, -1070, -1060, -1040, -1030, -1022, -1000, -600, 0, 600, 1000, 1012]
# scales as the issue states them (not powers of two: the data are rounded, then exact)
SCALES = [1e-320, 1e-310, 1e-300, 1e-30, 1.0, 1e30, 1e300, 1e307]


def _sgn(x) -> int:
    return (x > 0) - (x < 0)


def _det2(a, b, c) -> int:
    a, b, c = ([Fraction(float(t)) for t in p] for p in (a, b, c))
    return _sgn((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _det3(a, b, c, d) -> int:
    a, b, c, d = ([Fraction(float(t)) for t in p] for p in (a, b, c, d))
    u, v, w = ([p[i] - a[i] for i in range(3)] for p in (b, c, d))
    return _sgn(u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
                + u[2] * (v[0] * w[1] - v[1] * w[0]))


finite = st.floats(allow_nan=False, allow_infinity=False)
# coordinates from a few magnitudes (mixed within one point set), often repeated or on a line
magnitude = st.sampled_from([0.0, 5e-324, 1e-310, 2.0**-1022, 1e-300, 1e-200, 1.0, 3.0, 1e200, 1e300, 1.7e308])
mixed = st.one_of(finite, st.builds(lambda m, k, s: s * m * k, magnitude, st.integers(0, 9),
                                   st.sampled_from([1, -1])).filter(math.isfinite))


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(mixed, mixed), min_size=3, max_size=3))
def test_orient2d_is_exact_for_any_finite_input(pts):
    a, b, c = (np.array([p]) for p in pts)
    assert orient2d(a, b, c)[0] == _det2(*pts)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(mixed, mixed, mixed), min_size=4, max_size=4))
def test_orient3d_is_exact_for_any_finite_input(pts):
    a, b, c, d = (np.array([p]) for p in pts)
    assert orient3d(a, b, c, d)[0] == _det3(*pts)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(mixed, mixed, mixed), min_size=3, max_size=3))
def test_normal_signs_are_exact(pts):
    a, b, c = (np.array([p]) for p in pts)
    proj = [(0, 1), (1, 2), (2, 0)]
    want = [_det2(*[(p[i], p[j]) for p in pts]) for i, j in proj]
    assert normal_signs(a, b, c)[0].tolist() == want


@pytest.mark.parametrize("e", EXPONENTS)
def test_predicates_scale_invariant_vectorised(e):
    """Many random small-integer triangles and tets (lots of exact zeros) scaled by 2**e."""
    rng = np.random.default_rng(e & 0xFFFF)
    P2 = rng.integers(-3, 4, (500, 3, 2)).astype(float)
    P3 = rng.integers(-2, 3, (500, 4, 3)).astype(float)
    want2 = orient2d(P2[:, 0], P2[:, 1], P2[:, 2])
    want3 = orient3d(P3[:, 0], P3[:, 1], P3[:, 2], P3[:, 3])
    s = 2.0**e
    np.testing.assert_array_equal(orient2d(*(P2[:, i] * s for i in range(3))), want2)
    np.testing.assert_array_equal(orient3d(*(P3[:, i] * s for i in range(4))), want3)
    # oracle on a sample (Fractions are slow)
    for r in range(0, 500, 25):
        assert want2[r] == _det2(*P2[r]) and want3[r] == _det3(*P3[r])


# ------------------------------------------------------------------------- polygons


def _segments_meet_exact(a, b, c, d) -> bool:
    o1, o2, o3, o4 = _det2(a, b, c), _det2(a, b, d), _det2(c, d, a), _det2(c, d, b)
    if o1 * o2 > 0 or o3 * o4 > 0:
        return False
    if o1 == o2 == o3 == o4 == 0:  # collinear: the boxes must overlap
        return all(max(min(a[i], b[i]), min(c[i], d[i])) <= min(max(a[i], b[i]), max(c[i], d[i]))
                   for i in range(2))
    return True


def brute_force_crossings(P):
    """The docstring's semantics, pair by pair, in rational arithmetic."""
    k = len(P)
    out = set()
    for i in range(k):
        a, b = P[i], P[(i + 1) % k]
        c = P[(i + 2) % k]
        # edges i and i + 1 overlap beyond their shared vertex b: collinear, not strictly opposite
        if _det2(a, b, c) == 0:
            da = [Fraction(float(a[t])) - Fraction(float(b[t])) for t in range(2)]
            dc = [Fraction(float(c[t])) - Fraction(float(b[t])) for t in range(2)]
            if not (da[0] * dc[0] + da[1] * dc[1] < 0):
                out.add(tuple(sorted((i, (i + 1) % k))))
    for i in range(k):
        for j in range(i + 1, k):
            if j == i + 1 or (i == 0 and j == k - 1):
                continue
            if _segments_meet_exact(P[i], P[(i + 1) % k], P[j], P[(j + 1) % k]):
                out.add((i, j))
    return sorted(out)


def _random_polygons(seed, count=60):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        k = int(rng.integers(3, 12))
        yield rng.integers(-4, 5, (k, 2)).astype(float)  # small grid: touching, collinear, repeated


@pytest.mark.parametrize("e", EXPONENTS)
def test_polygon_crossings_match_brute_force_at_every_scale(e):
    for P in _random_polygons(e & 0xFFFF):
        want = brute_force_crossings(P)
        got = polygon_crossings(P * 2.0**e).tolist()
        assert [tuple(p) for p in got] == want, (e, P.tolist())


@pytest.mark.parametrize("scale", SCALES)
def test_polygon_crossings_on_rounded_scaled_data(scale):
    """Data rounded at the scale (not a power of two): compared with the oracle on the rounded data."""
    for P in _random_polygons(17, 40):
        Q = P * scale + scale * np.random.default_rng(1).uniform(0, 0.5, P.shape)
        if not np.isfinite(Q).all():
            continue
        assert [tuple(p) for p in polygon_crossings(Q).tolist()] == brute_force_crossings(Q)


def test_polygon_mixing_magnitudes():
    """One long edge next to many subnormal-sized ones (a grid cell size far below the span)."""
    k = 40
    t = np.arange(k, dtype=float)
    P = np.c_[t * 5e-324, (t % 2) * 5e-324]  # a subnormal zigzag...
    P = np.vstack([P, [[1e300, 1e300], [-1e300, 1e300]]])  # ...closed through huge vertices
    want = brute_force_crossings(P)
    assert [tuple(p) for p in polygon_crossings(P).tolist()] == want


def test_certify_bijective_at_subnormal_scale_finds_the_crossing():
    """Issue 19 item 3: an overlapping disk map scaled to 1e-310 was certified global."""
    from geomopt.mesh import generators as G

    V, F = G.disk_mesh(3)
    loop = None
    cert = certify_bijective(V, F)
    assert cert.injectivity == "global"
    loop = cert.loop
    X = V.copy()
    X[loop[0]] = 3.0 * X[loop[len(loop) // 2]]  # pull a boundary vertex across the disk
    want = certify_bijective(X, F)
    assert want.injectivity != "global"
    for e in (-1060, -1040, -1030, 1000):
        got = certify_bijective(X * 2.0**e, F)
        assert got.injectivity == want.injectivity
        np.testing.assert_array_equal(got.crossings, want.crossings)
    for s in (1e-310, 1e300):
        assert certify_bijective(X * s, F).injectivity != "global"
        assert certify_bijective(V * s, F).injectivity == "global"


@pytest.mark.parametrize("e", [-1070, -1040, 0, 1000])
def test_polygon_orientation_scale_invariant(e):
    P = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)
    assert polygon_orientation(P * 2.0**e) == 1 and polygon_orientation(P[::-1] * 2.0**e) == -1


def test_local_certificate_scale_invariant():
    """The local certificate of exact small-integer maps (valid, branched, overlapping) is the
    same after any exact scaling."""
    from test_local_injectivity import exact_fan, wrapped_cylinder

    from geomopt.mesh import generators as G

    cases = [exact_fan(1.5, 12), exact_fan(0.75, 12), G.square_mesh(4), G.box_mesh(2, 2, 2)]
    V, T, X, _ = wrapped_cylinder(2.0, sectors=8, levels=2)
    cases.append((np.round(X * 8), T))  # integer data (rounded: still every tet positive?)
    for X, S in cases:
        X = np.asarray(X, float) * (4 if X.shape[1] == 2 else 1)
        want = local_certificate(X, S)
        for e in (-1060, -1030, 600, 1000):
            got = local_certificate(X * 2.0**e, S)
            assert (got.ok, got.inverted, got.message) == (want.ok, want.inverted, want.message), e


@pytest.mark.parametrize("scale", [1e300, 1e-310, 2.0**-1060])
def test_bijective_start_at_extreme_scales(scale, tmp_path):
    """Issue 19: ``--bijective`` with a start map scaled by 1e300 or 1e-310 failed ('the map's total
    signed area is nan / 0') where the plain run succeeded: the start's area overflowed or
    underflowed before it was scaled to the rest area."""
    from geomopt import cli
    from geomopt.mesh import generators as G
    from geomopt.io import read_obj_with_uv, write_obj_with_uv
    from geomopt.param import parameterize
    from geomopt.mesh.tutte import tutte_embedding

    V, F = G.ruffled_disk(6)
    x0 = tutte_embedding(V, F) * scale
    for bijective in (False, True):
        res = parameterize(V, F, x0=x0, options=ParamOptions(bijective=bijective), progress=False)
        assert res.success and res.injectivity == "global", (bijective, res.message)
    src, out = tmp_path / "in.obj", tmp_path / "out.obj"
    write_obj_with_uv(src, V, F, x0)
    assert cli.main(["param", str(src), "-o", str(out), "--init", "uv", "--bijective", "--quiet"]) == 0
    assert np.isfinite(read_obj_with_uv(out)[1]).all()


@pytest.mark.parametrize("scale", [1e-150, 1e200, 1e300])
@pytest.mark.parametrize("dim", [2, 3])
def test_untangle_a_start_map_at_extreme_scales(scale, dim):
    """The whole-boundary orientation test before untangling once summed the map's signed
    sizes in float: at 1e200 they overflowed (``ValueError: -inf + inf in fsum``), and a tet
    map at 1e-150 underflowed to a "collapsed" map and was refused.  Signs and ratios are
    scale-free, so these solve as at scale 1, with the handles bit-identical."""
    from geomopt.mesh import generators as G
    from geomopt.mesh.orientation import check_initial_orientation
    from geomopt.untangling import untangle

    tg = (G.rotated_interior(*G.square_mesh(6), 120.0) if dim == 2
          else G.rotated_interior(*G.box_mesh(2, 3, 2), 100.0))
    x0 = tg.x0 * scale
    problem = tg.problem().with_fixed(tg.fixed, x0[tg.fixed])
    check_initial_orientation(problem, x0)  # raised MeshError ("collapsed") at 1e-150 in 3D
    res = untangle(problem, x0, progress=False)
    assert res.success and res.certificate.inverted == 0
    assert np.array_equal(res.x[tg.fixed].view(np.uint64), x0[tg.fixed].view(np.uint64))

"""Global injectivity: the exact certificate, the scaffold, and the bijective mode."""

from fractions import Fraction

import numpy as np
import pytest

import geomopt
from geomopt.mesh import generators as g
from geomopt._runtime.errors import MeshError, ParameterError
from geomopt.exact.certify import certify_bijective, polygon_crossings, polygon_orientation
from geomopt.exact.predicates import count_inverted, orient2d
from geomopt.mesh.scaffold import build_scaffold, delaunay_flips, ear_clip, interior_pairs, refine_scaffold
from geomopt.bijective import ScaffoldOptions, SimpleBoundary, bijective_parameterize
from geomopt.exact.topology import check_disk, unique_edges
from geomopt.mesh.tutte import tutte_embedding

# ------------------------------------------------------------------ brute-force reference


def _sign(v):
    return (v > 0) - (v < 0)


def _orient(a, b, c):
    return _sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _on_segment(a, b, p):
    return min(a[0], b[0]) <= p[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])


def brute_crossings(P):
    """All violating edge pairs by the textbook case analysis in exact rational arithmetic."""
    Q = [(Fraction(float(x)), Fraction(float(y))) for x, y in P]
    k = len(Q)
    out = []
    for i in range(k):
        for j in range(i + 1, k):
            a, b, c, d = Q[i], Q[(i + 1) % k], Q[j], Q[(j + 1) % k]
            if j == i + 1 or (i == 0 and j == k - 1):
                u, v, w = (a, b, d) if j == i + 1 else (c, a, b)  # v: the shared vertex
                du, dw = (u[0] - v[0], u[1] - v[1]), (w[0] - v[0], w[1] - v[1])
                if _orient(u, v, w) == 0 and (du == (0, 0) or dw == (0, 0)
                                              or du[0] * dw[0] + du[1] * dw[1] > 0):
                    out.append((i, j))
                continue
            o1, o2, o3, o4 = _orient(a, b, c), _orient(a, b, d), _orient(c, d, a), _orient(c, d, b)
            if (o1 * o2 < 0 and o3 * o4 < 0) or (o1 == 0 and _on_segment(a, b, c)) or (
                    o2 == 0 and _on_segment(a, b, d)) or (o3 == 0 and _on_segment(c, d, a)) or (
                    o4 == 0 and _on_segment(c, d, b)):
                out.append((i, j))
    return out


def random_layout(rng, kind):
    k = int(rng.integers(3, 12))
    if kind == "grid":  # many collinear, touching and repeated points
        return rng.integers(0, 4, (k, 2)).astype(np.float64)
    if kind == "tenths":  # collinear in exact arithmetic only up to rounding: exact fallback
        return rng.integers(0, 4, (k, 2)) * 0.1
    t = np.sort(rng.random(k)) * 2 * np.pi  # star-shaped (simple), half of them with two
    P = np.stack([np.cos(t), np.sin(t)], 1) * (1 + 0.8 * rng.random((k, 1)))  # vertices swapped
    if rng.random() < 0.5:
        i, j = rng.choice(k, 2, replace=False)
        P[[i, j]] = P[[j, i]]
    return P


# ------------------------------------------------------------------ the certificate


@pytest.mark.parametrize("kind", ["grid", "tenths", "star"])
def test_crossings_match_brute_force_on_random_layouts(kind):
    rng = np.random.default_rng({"grid": 1, "tenths": 2, "star": 3}[kind])
    found = 0
    for _ in range(300):
        P = random_layout(rng, kind)
        got = [tuple(p) for p in polygon_crossings(P)]
        assert got == brute_crossings(P), P.tolist()
        found += bool(got)
    assert 20 < found < 280  # the layouts exercise both simple and self-crossing polygons


def test_crossing_definitions():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    assert polygon_crossings(square).shape == (0, 2)
    # a vertex touching a non-adjacent edge
    touch = np.array([[0, 0], [2, 0], [2, 2], [1, 0], [0, 2]], dtype=float)  # P3 on edge 0
    assert [tuple(p) for p in polygon_crossings(touch)] == [(0, 2), (0, 3)]
    # a straight (180 degree) vertex is fine; doubling back along the same line is not
    straight = np.array([[0, 0], [1, 0], [2, 0], [2, 1], [0, 1]], dtype=float)
    assert len(polygon_crossings(straight)) == 0
    back = np.array([[0, 0], [2, 0], [1, 0], [1, 1]], dtype=float)
    assert (0, 1) in map(tuple, polygon_crossings(back))
    # a zero-length edge fails with its neighbours
    dup = np.array([[0, 0], [1, 0], [1, 0], [1, 1]], dtype=float)
    assert {(0, 1), (1, 2)} <= set(map(tuple, polygon_crossings(dup)))
    # a bow tie: edges 0 and 2 cross properly
    eight = np.array([[0, 0], [1, 1], [1, 0], [0, 1]], dtype=float)
    assert [tuple(p) for p in polygon_crossings(eight)] == [(0, 2)]


def test_crossings_with_a_coarsened_grid():
    # two edges as long as the polygon among 2000 short ones: the grid gets coarser, and stays exact
    t = np.linspace(0.0, np.pi, 2000)
    P = np.concatenate([np.stack([np.cos(t), np.sin(t)], 1), [[-1.0, -1e-3]]])
    assert len(polygon_crossings(P)) == 0
    P[-1] = [0.0, 0.5]  # the closing edges run inside the half disk, touching nothing
    assert len(polygon_crossings(P)) == 0
    P[-1] = [0.0, 2.0]  # the closing edges cross the arc
    assert len(polygon_crossings(P)) == 2


def test_polygon_orientation():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    assert polygon_orientation(square) == 1
    assert polygon_orientation(square[::-1]) == -1


def test_certificate_levels():
    V, F = g.disk_mesh(4)
    x = tutte_embedding(V, F)
    cert = certify_bijective(x, F)
    assert cert.globally_injective and cert.injectivity == "global"
    mirrored = x * [-1.0, 1.0]  # every triangle inverted, boundary clockwise
    cert = certify_bijective(mirrored, F)
    assert cert.injectivity == "none" and cert.orientation == -1
    # a planar band wider than its spiral's spacing: locally injective, overlapping
    V, F = g.spiral_strip(turns=2.0, spacing=0.2, width=0.3, lift=0.0, n_across=2)
    cert = certify_bijective(V[:, :2], F)
    assert cert.inverted == 0 and len(cert.crossings) > 0 and cert.injectivity == "local"
    # the same band with a gap between its turns is bijective
    V, F = g.spiral_strip(turns=2.0, spacing=0.5, width=0.3, lift=0.0, n_across=2)
    assert certify_bijective(V[:, :2], F).injectivity == "global"


def test_certificate_rejects_bad_input():
    V, F = g.disk_mesh(2)
    with pytest.raises(MeshError):
        certify_bijective(V[:, :1], F)
    with pytest.raises(MeshError):
        polygon_crossings(np.zeros((2, 2)))
    with pytest.raises(MeshError):
        polygon_crossings(np.array([[0, 0], [1, np.nan], [0, 1]]))
    x = tutte_embedding(V, F)
    for loop in ([0, 0, 1], [0, 1], [0, 1, len(V)]):
        with pytest.raises(MeshError):
            certify_bijective(x, F, loop=np.array(loop))
    x[0] = np.nan
    assert certify_bijective(x, F).injectivity == "none"


# ------------------------------------------------------------------ the scaffold


def _spiral_polygon(turns=2.5, n=400):
    V, F = g.spiral_strip(turns=turns, spacing=0.5, width=0.3, lift=0.0, n_across=1)
    return V[check_disk(F, len(V)), :2]


@pytest.mark.parametrize("shape", ["spiral", "star", "L", "crescent"])
def test_scaffold_closes_a_bijective_disk(shape):
    P = _spiral_polygon() if shape == "spiral" else g.polygon(shape)
    if shape == "L":  # collinear vertices on the hull and in the pocket
        P = np.concatenate([np.linspace(P[i], P[(i + 1) % len(P)], 3, endpoint=False) for i in range(len(P))])
    sc = build_scaffold(P)
    k, h = len(P), len(sc.outer)
    X = np.concatenate([P, sc.outer])
    assert len(sc.triangles) == k + h
    assert count_inverted(X, sc.triangles) == 0
    # scaffold + the polygon's own ear-clipped inside = a disk bounded by the enclosing polygon
    inside = np.asarray(ear_clip(P), dtype=np.int64)
    cert = certify_bijective(X, np.concatenate([inside, sc.triangles]))
    assert cert.globally_injective
    assert set(cert.loop.tolist()) == set(range(k, k + h))


def _min_angles(X, T):
    A, B, C = X[T[:, 0]], X[T[:, 1]], X[T[:, 2]]

    def angle(u, v):
        cos = (u * v).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    return np.minimum(np.minimum(angle(B - A, C - A), angle(A - B, C - B)), angle(A - C, B - C))


@pytest.mark.parametrize("shape", ["spiral", "star"])
def test_refined_scaffold_is_a_graded_conforming_triangulation(shape):
    P = _spiral_polygon() if shape == "spiral" else g.polygon(shape)
    if shape == "star":  # fine boundary edges: the scaffold must grade from them
        P = np.concatenate([np.linspace(P[i], P[(i + 1) % len(P)], 8, endpoint=False) for i in range(len(P))])
    k = len(P)
    sc = build_scaffold(P)
    X0 = np.concatenate([P, sc.outer])
    X, T = refine_scaffold(X0, sc.triangles, k)
    assert np.array_equal(X[: len(X0)], X0) and len(X) > len(X0)  # Steiner points appended
    assert count_inverted(X, T) == 0
    # still a disk around the polygon: no hanging vertex, the mesh boundary edges unsplit, and the
    # outer loop is the enclosing polygon with (only) midpoints added
    inside = np.asarray(ear_clip(P), dtype=np.int64)
    cert = certify_bijective(X, np.concatenate([inside, T]))
    assert cert.globally_injective
    assert set(range(k, len(X0))) <= set(cert.loop.tolist()) and min(cert.loop) >= k
    # much better shaped than the unrefined scaffold, whose triangles are long and thin
    before, after = _min_angles(X0, sc.triangles), _min_angles(X, T)
    assert np.percentile(after, 5) > 3 * np.percentile(before, 5)
    assert np.percentile(after, 5) > 10.0 and np.median(after) > 30.0
    # graded: triangles at the boundary are about as large as its edges, far ones much larger
    edge = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).max()
    L = np.linalg.norm(X[T] - X[np.roll(T, -1, axis=1)], axis=2).max(axis=1)
    touching = (T < k).any(axis=1)
    assert L[touching].max() <= 4 * edge and L[~touching].max() > 10 * edge


def test_interior_pairs_are_the_twin_half_edges_of_edges_with_two_triangles():
    # a grid's triangles shuffled (boundary edges: one triangle), plus a fin on an interior edge
    # (three triangles: not an interior pair) and a repeated triangle (its edges: more than two)
    rng = np.random.default_rng(3)
    T = np.asarray(g.square_mesh(5)[1])
    T = T[rng.permutation(len(T))]
    n = int(T.max()) + 1
    e = T[0, :2]
    T = np.concatenate([T, [[e[1], e[0], n]], T[[5]]])
    h1, h2 = interior_pairs(T)
    E, count, edge_of = unique_edges(T)  # the reference: one edge's half-edges by edge row
    he = edge_of.ravel()
    hs = np.flatnonzero(count[he] == 2)
    hs = hs[np.argsort(he[hs], kind="stable")]
    assert np.array_equal(h1, hs[0::2]) and np.array_equal(h2, hs[1::2])
    assert np.all(h1 < h2) and len(h1) > 10
    H = T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert np.array_equal(H[h1], H[h2][:, ::-1])  # twins run the other way
    fin = {tuple(sorted(H[h])) for h in np.r_[h1, h2]}
    assert tuple(sorted(e)) not in fin and tuple(sorted(T[5, :2])) not in fin  # three or four triangles
    assert len(interior_pairs(np.zeros((0, 3), dtype=np.int64))[0]) == 0


def test_scaffold_rejects_a_clockwise_polygon():
    with pytest.raises(MeshError):
        build_scaffold(_spiral_polygon()[::-1])


def _locally_delaunay(X, T, tol=1e-9):
    E, count, edge_of = unique_edges(T)
    he = edge_of.ravel()
    hs = np.flatnonzero(count[he] == 2)
    hs = hs[np.argsort(he[hs], kind="stable")]
    f1, c1, f2, c2 = hs[0::2] // 3, hs[0::2] % 3, hs[1::2] // 3, hs[1::2] % 3
    a, b, c, d = T[f1, c1], T[f1, (c1 + 1) % 3], T[f1, (c1 + 2) % 3], T[f2, (c2 + 2) % 3]

    def cot(p, q, r):
        u, v = X[p] - X[r], X[q] - X[r]
        return (u * v).sum(1) / (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])

    bad = -(cot(a, b, c) + cot(b, a, d)) > tol
    convex = (orient2d(X[c], X[a], X[d]) == 1) & (orient2d(X[d], X[b], X[c]) == 1)
    return not (bad & convex).any()


def test_delaunay_flips_reach_a_delaunay_triangulation():
    rng = np.random.default_rng(0)
    t = (np.arange(40) + 0.5 * rng.random(40)) * 2 * np.pi / 40
    X = np.stack([np.cos(t), np.sin(t)], 1) * (1 + 0.02 * rng.random((40, 1)))
    X = np.concatenate([X, [[0.3, 0.1]]])  # an off-centre vertex fanned to the boundary
    T = np.stack([np.full(40, 40), np.arange(40), (np.arange(40) + 1) % 40], 1)
    assert count_inverted(X, T) == 0
    T2, flips = delaunay_flips(X, T)
    assert flips > 0
    assert len(T2) == len(T) and count_inverted(X, T2) == 0
    assert _locally_delaunay(X, T2) and not _locally_delaunay(X, T)
    # the float angle test only steers: a flip that would invert a triangle is refused even
    # when the angle test asks for every flip (tol = -inf); here the quad is reflex at vertex 1
    Xr = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.0], [5.0, -0.1]])
    Tr = np.array([[0, 1, 2], [1, 0, 3]])
    assert orient2d(Xr[[3]], Xr[[1]], Xr[[2]])[0] == -1  # the flipped triangle (3, 1, 2)
    Tr2, flips = delaunay_flips(Xr, Tr, tol=-np.inf)
    assert flips == 0 and np.array_equal(Tr2, Tr)
    # same triangulated region: boundary edges unchanged
    E1, c1, _ = unique_edges(T)
    E2, c2, _ = unique_edges(T2)
    assert {tuple(e) for e in E1[c1 == 1]} == {tuple(e) for e in E2[c2 == 1]}


# ------------------------------------------------------------------ the bijective mode


@pytest.fixture(scope="module")
def spiral():
    """A lifted spiral strip whose plain free-boundary optimum overlaps itself."""
    V, F = g.spiral_strip(turns=2.5, spacing=0.5, width=0.3, lift=1.5, n_across=2)
    return V, F, V[:, :2].copy()


def test_plain_solve_overlaps_and_bijective_does_not(spiral):
    V, F, x0 = spiral
    plain = geomopt.parameterize(V, F, x0=x0, progress=False)
    assert plain.success and plain.certificate.inverted == 0
    assert len(certify_bijective(plain.x, F).crossings) > 0  # locally injective, overlapping
    res = bijective_parameterize(V, F, x0=x0, progress=False)
    assert res.success, res.message
    assert res.stats.outer_iterations > 0 and res.details.scaffold_triangles > 0
    cert = certify_bijective(res.x, F)  # independently of the solver's own certificate
    assert cert.globally_injective and res.injectivity == "global"
    assert res.certificate.inverted == 0 and len(res.certificate.crossings) == 0
    # the bijective optimum costs energy, but not much: the strip only has to stop at contact
    assert plain.energy <= res.energy <= 1.01 * plain.energy
    assert np.all(np.diff(res.trace.energy) <= 1e-12 * res.trace.energy[0])


def test_a_scaffold_free_step_that_would_overlap_is_shortened(spiral):
    """The lazy phase's guard halves (then quarters) a step whose end has an overlapping
    boundary, and gives up (None: build the scaffold) when neither fraction keeps the boundary
    simple; it passes simple steps through."""
    from geomopt.param import start_map

    V, F, x0 = spiral
    problem = geomopt.Problem.surface(V, F)
    objective = geomopt.Objective(problem, "symmetric_dirichlet")
    loop = check_disk(F, len(V))
    x0, _, _ = start_map(objective, x0)
    solver = geomopt.Newton()
    state = solver.init(objective, x0, objective.params())
    guard = SimpleBoundary(loop, (0.5, 0.25), max_cuts=10**6)
    fractions = []
    for _ in range(30):
        new = solver.step(state)
        short = guard(solver, state, new)
        if len(polygon_crossings(np.asarray(new.x)[loop])):
            if short is None:
                break
            s = short.step_size / new.step_size
            fractions.append(s)
            np.testing.assert_allclose(np.asarray(short.x), np.asarray(state.x + s * (new.x - state.x)))
            assert len(polygon_crossings(np.asarray(short.x)[loop])) == 0 and short.value < state.value
            assert short.value == pytest.approx(float(objective.value(short.x, objective.params())))
        assert short is not None
        state = short
    else:
        pytest.fail("the spiral's boundary never came to overlap")
    assert fractions == [0.5, 0.25]


def test_bijective_with_a_quasi_newton_solver(spiral):
    """L-BFGS keeps a memory of whole steps: after a shortened scaffold-free step it restarts
    (else its pairs describe a step not taken), and its inner solves keep its own tolerance."""
    V, F, x0 = spiral
    res = bijective_parameterize(V, F, x0=x0, progress=False, solver="lbfgs")
    assert res.success and res.injectivity == "global", res.message
    newton = bijective_parameterize(V, F, x0=x0, progress=False)
    assert abs(res.energy - newton.energy) <= 1e-3 * newton.energy  # L-BFGS: 2.5e-4 above


def test_bijective_matches_plain_where_plain_does_not_overlap():
    V, F = g.saddle(8, order=3, amplitude=2.0)
    plain = geomopt.parameterize(V, F, progress=False)
    assert certify_bijective(plain.x, F).globally_injective
    # lazy (default): no step overlaps, so no scaffold and exactly the plain solve
    res = bijective_parameterize(V, F, progress=False)
    assert res.success and res.injectivity == "global"
    assert res.stats.outer_iterations == 0 and res.details.scaffold_triangles == 0
    # (the start is normalised like parameterize's up to rounding)
    assert res.stats.iterations == plain.stats.iterations and abs(res.energy - plain.energy) <= 1e-9 * plain.energy
    # with the scaffold from the start: the same optimum
    res = bijective_parameterize(V, F, options=ScaffoldOptions(lazy=False), progress=False)
    assert res.success and res.injectivity == "global" and res.stats.outer_iterations > 0
    assert abs(res.energy - plain.energy) <= 1e-5 * plain.energy


def test_bijective_input_errors(spiral):
    V, F, _ = spiral
    Vo, Fo = g.spiral_strip(turns=2.0, spacing=0.2, width=0.3, lift=0.5, n_across=2)
    with pytest.raises(MeshError, match="not globally injective"):
        bijective_parameterize(Vo, Fo, x0=Vo[:, :2], progress=False)
    for bad in (dict(scaffold_weight=0.0), dict(scaffold_weight=np.nan), dict(inner_steps=0),
                dict(max_outer=True), dict(outer_rtol=-1.0), dict(ring_scale=1.0), dict(lazy=1)):
        with pytest.raises(ParameterError, match=f"ScaffoldOptions: {next(iter(bad))} must be"):
            ScaffoldOptions(**bad)
    with pytest.raises(ParameterError, match="options must be a ScaffoldOptions or None, got dict"):
        bijective_parameterize(V, F, x0=V[:, :2], options={"lazy": False}, progress=False)
    with pytest.raises(TypeError, match="unexpected keyword argument 'lazy'"):
        bijective_parameterize(V, F, x0=V[:, :2], progress=False, lazy=False)


def test_generators_validate_and_give_injective_projections():
    for make in (lambda: g.spiral_strip(width=0.0), lambda: g.spiral_strip(n_across=0),
                 lambda: g.ruffled_disk(4, waves=0), lambda: g.saddle(4, order=1)):
        with pytest.raises(ParameterError):
            make()
    for V, F in (g.spiral_strip(turns=1.5), g.ruffled_disk(6), g.saddle(6)):
        assert V.shape[1] == 3
        assert certify_bijective(V[:, :2], F).globally_injective


def test_parameterize_reports_injectivity_and_the_cli_flag(spiral, tmp_path, capsys):
    """The plain result says it is only locally injective, and `geomopt param` says so even with
    --quiet, pointing to --bijective; --bijective gives a global map and no warning."""
    import json

    import geomopt.cli
    from geomopt.io import read_obj_uv, write_obj_with_uv

    V, F, x0 = spiral
    plain = geomopt.parameterize(V, F, x0=x0, progress=False)
    assert plain.injectivity == "local" and plain.certificate.crossings.size
    src = tmp_path / "spiral.obj"
    write_obj_with_uv(src, V, F, x0)
    out = tmp_path / "plain.obj"
    capsys.readouterr()
    assert geomopt.cli.main(["param", str(src), "-o", str(out), "--init", "uv", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "only locally injective" in err and "--bijective" in err
    assert geomopt.cli.main(["param", str(src), "-o", str(out), "--init", "uv", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["injectivity"] == "local" and summary["boundary_crossings"] > 0
    out = tmp_path / "bij.obj"
    assert geomopt.cli.main(["param", str(src), "-o", str(out), "--init", "uv", "--bijective", "--json"]) == 0
    cap = capsys.readouterr()
    summary = json.loads(cap.out)
    assert summary["injectivity"] == "global" and summary["boundary_crossings"] == 0
    assert "only locally injective" not in cap.err
    _, _, uv = read_obj_uv(out)
    assert certify_bijective(uv, F).globally_injective

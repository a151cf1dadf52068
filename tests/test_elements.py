"""Quads and hexahedra as corner simplices (issue 18): the corner-simplex energy, the exact
validity certificates (quads by corners, hexahedra by Bernstein coefficients), rest checks,
untangling and smoothing."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

import geomopt
from geomopt.mesh import generators as G
from geomopt import CompareOptions, Outcome, UntangleOptions, smooth
from geomopt.smoothing import SmoothOptions
from geomopt.exact import hexvalid
from geomopt._runtime.errors import MeshError, ParameterError
from geomopt.objective.objective import Objective
from geomopt.mesh.elements import (certify_elements, corner_edges, count_invalid, quality, scaled_jacobian,
    valid_elements)
from geomopt.exact.hexvalid import HEX_CORNERS, hex_validity, hex_volumes, jacobian_bernstein, jacobian_det
from geomopt.mesh.problem import Problem
from geomopt.untangling import STIFF_AFTER_NEWTON, choose_start, harmonic_start, untangle

CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)


def _jittered_quads(n=6, jitter=0.02, seed=0):
    V, Q = G.quad_mesh(n, n)
    rng = np.random.default_rng(seed)
    inner = (V > 0).all(1) & (V < 1).all(1)
    V[inner] += jitter * rng.standard_normal((inner.sum(), 2))
    return V, Q


def _random_hexes(m, seed=0):
    """m separate hexahedra: the unit cube with its vertices moved by noise of random size."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0.05, 0.6, m)[:, None, None]
    X = (CUBE[None] + noise * rng.standard_normal((m, 8, 3))).reshape(-1, 3)
    return X, np.arange(8 * m).reshape(m, 8)


def _exact_det(P, uvw):
    """det J of the trilinear map with control points P (8, 3) (VTK order) at a rational point."""
    P = [[Fraction(float(c)) for c in p] for p in P]
    u, v, w = (Fraction(float(t)) for t in uvw)
    lin = {0: lambda t: 1 - t, 1: lambda t: t}
    idx = {(a, b, c): i for i, (a, b, c) in enumerate(CUBE.astype(int).tolist())}

    def deriv(axis, s, t):
        others = [k for k in range(3) if k != axis]
        out = [Fraction(0)] * 3
        for p in (0, 1):
            for q in (0, 1):
                lo = [0, 0, 0]
                lo[others[0]], lo[others[1]] = p, q
                hi = list(lo)
                hi[axis] = 1
                wgt = lin[p](s) * lin[q](t)
                for k in range(3):
                    out[k] += wgt * (P[idx[tuple(hi)]][k] - P[idx[tuple(lo)]][k])
        return out

    a, b, c = deriv(0, v, w), deriv(1, u, w), deriv(2, u, v)
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))


# ----------------------------------------------------------------------------- corner energy


@pytest.mark.parametrize("energy", ["symmetric_dirichlet", "winslow", "arap", "mips", "dirichlet"])
def test_quad_energy_is_the_triangle_energy_of_its_corner_triangles(energy):
    """The four corner triangles of each quad are the two diagonal triangulations: the quad
    path's energy, gradient and Hessian equal the triangle path's sums to rounding."""
    V, Q = _jittered_quads()
    b = Problem.quads(V, Q).boundary_vertices()
    x = V + 0.01 * np.random.default_rng(1).standard_normal(V.shape)
    quad = Problem.quads(V, Q, b, V[b])
    tri = [Problem.planar(V, np.concatenate([Q[:, [0, 1, 3]], Q[:, [2, 3, 1]]]), b, V[b]),
           Problem.planar(V, np.concatenate([Q[:, [1, 2, 0]], Q[:, [3, 0, 2]]]), b, V[b])]
    oq = Objective(quad, energy)
    params = oq.params()
    vq, gq = oq.value_and_grad(x, params)
    assert np.isfinite(float(vq))
    parts = [Objective(p, energy).value_and_grad(x, params) for p in tri]
    assert abs(float(vq) - sum(float(v) for v, _ in parts)) <= 1e-12 * abs(float(vq))
    assert np.abs(np.asarray(gq) - sum(np.asarray(g) for _, g in parts)).max() <= 1e-12 * np.abs(gq).max()
    if energy == "symmetric_dirichlet":
        Hq = oq.pattern.matrix(oq.hessian(x, params, "none")[2]).toarray()
        Ht = sum(o.pattern.matrix(o.hessian(x, params, "none")[2]).toarray()
                 for o in (Objective(p, energy) for p in tri))
        assert np.abs(Hq - Ht).max() <= 1e-12 * np.abs(Hq).max()


def test_corner_jacobians_are_the_element_derivatives_at_the_corners():
    X, H = _random_hexes(50)
    corners = CUBE  # the corner c of the unit cube is vertex c
    D = jacobian_det(X, H, corners)  # (m, 8)
    E = np.linalg.det(corner_edges(X, H)).reshape(len(H), 8)
    assert np.allclose(D, E, rtol=1e-12, atol=1e-12)
    B = jacobian_bernstein(X, H)
    assert np.allclose(B[:, ::2, ::2, ::2].reshape(len(H), 8)[:, [0, 4, 6, 2, 1, 5, 7, 3]], D)
    # at rest every corner Jacobian is the identity and the weights are the corner sizes
    V, Q = _jittered_quads()
    p = Problem.quads(V, Q)
    J = np.swapaxes(V[p.simplices[:, 1:]] - V[p.simplices[:, :1]], 1, 2) @ p.rest_inv
    assert np.allclose(J, np.eye(2))
    area = 0.5 * np.abs(np.sum(V[Q][:, :, 0] * np.roll(V[Q][:, :, 1], -1, 1) - np.roll(V[Q][:, :, 0], -1, 1) * V[Q][:, :, 1], 1))
    assert np.allclose(p.volumes.reshape(-1, 4).sum(1), 2 * area)  # the corners cover a quad twice


def test_hex_volume_and_weights():
    # a parallelepiped: corner tetrahedra are each 1/6 of it, together 4/3
    A = np.array([[2.0, 0.3, 0.1], [0.2, 1.5, 0.0], [0.1, -0.4, 0.7]])
    P = CUBE @ A.T
    p = Problem.hexes(P, np.arange(8)[None])
    vol = abs(np.linalg.det(A))
    assert np.isclose(hex_volumes(P, np.arange(8)[None])[0], vol)
    assert np.allclose(p.volumes, vol / 6) and np.isclose(p.volumes.sum(), 4 / 3 * vol)
    # a trilinear hexahedron: the mean of the Bernstein coefficients is the integral of det J
    X, H = _random_hexes(20, seed=3)
    g = (np.array([-1, 1]) / np.sqrt(3) + 1) / 2
    gauss = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    assert np.allclose(hex_volumes(X, H), jacobian_det(X, H, gauss).mean(1), rtol=1e-12, atol=1e-12)


def test_scaled_jacobian():
    V, Q = G.quad_mesh(2, 2)
    assert np.allclose(scaled_jacobian(V, Q), 1.0)
    S = V @ np.array([[1.0, 0.5], [0.0, 1.0]]).T  # shear: every corner angle 90 +- 26.57 degrees
    assert np.allclose(scaled_jacobian(S, Q), np.sin(np.arctan2(1, 0.5)))
    W = V.copy()
    W[4] = [1.6, 1.6]  # centre vertex pushed past the far corner of quad 0 and others
    sj = scaled_jacobian(W, Q)
    q = quality(W, Q)
    assert q.min == sj.min() < 0 and q.below_0 == np.count_nonzero(sj < 0) and q.below_0_2 >= q.below_0
    V3, H = G.hex_mesh(2, 2, 2)
    assert np.allclose(scaled_jacobian(V3, H), 1.0)


# ----------------------------------------------------------------------------- validity


def test_quad_corners_decide_validity_everywhere():
    """A bilinear quad's det J is affine in u and in v, its corner values its coefficients:
    corners positive <=> positive on a dense grid (random quads, valid and not)."""
    rng = np.random.default_rng(0)
    m = 4000
    ref = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    X = (ref[None] + rng.uniform(0.05, 0.7, m)[:, None, None] * rng.standard_normal((m, 4, 2))).reshape(-1, 2)
    Q = np.arange(4 * m).reshape(m, 4)
    ok = valid_elements(X, Q)
    t = np.linspace(0, 1, 21)
    u, v = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
    P = X[Q]
    xu = (1 - v)[None, :, None] * (P[:, 1] - P[:, 0])[:, None] + v[None, :, None] * (P[:, 2] - P[:, 3])[:, None]
    xv = (1 - u)[None, :, None] * (P[:, 3] - P[:, 0])[:, None] + u[None, :, None] * (P[:, 2] - P[:, 1])[:, None]
    D = xu[..., 0] * xv[..., 1] - xu[..., 1] * xv[..., 0]
    assert 0 < ok.sum() < m
    assert ((D.min(1) > 0) == ok).all()


@pytest.fixture(scope="module")
def random_hexes():
    X, H = _random_hexes(10_000)
    return X, H, hex_validity(X, H)


def test_hex_certificate_matches_a_dense_sampling_oracle(random_hexes):
    """10^4 random hexahedra: certified valid => det J > 0 at all 17^3 samples; invalid => an
    exact witness point where det J <= 0, and the sampling agrees but for elements whose
    negative region slips between the samples (each confirmed by its exact witness)."""
    X, H, r = random_hexes
    g = np.linspace(0, 1, 17)
    uvw = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    smin = np.concatenate([jacobian_det(X, H[i:i + 200], uvw).min(1) for i in range(0, len(H), 200)])
    assert (smin[r.valid] > 0).all()
    assert r.corner_valid.sum() > 4000 and (r.corner_valid & ~r.valid).sum() >= 30  # folded inside
    assert (~r.valid & (smin > 0)).sum() <= 3  # missed by the sampling
    for e in np.flatnonzero(~r.valid & r.corner_valid):
        assert _exact_det(X[H[e]], r.witness[e]) <= 0
    assert set(r.tests) == set(hexvalid.TESTS) and r.tests["subdivision"] > 0


def test_hex_certificate_float_stage_agrees_with_the_exact_one(random_hexes, monkeypatch):
    X, H, r = random_hexes
    monkeypatch.setattr(hexvalid, "_float_safe", lambda P: np.zeros(len(P), bool))
    sub = slice(0, 3000)
    rx = hex_validity(X, H[sub])
    assert np.array_equal(rx.valid, r.valid[sub])
    assert rx.tests["exact"] == rx.corner_valid.sum()


def test_hex_certificate_is_exact_at_the_boundary_of_validity():
    # top face turned by 180 degrees: det J = 0 along the vertical mid-edge, > 0 elsewhere
    def twisted(deg):
        a = np.deg2rad(deg)
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        R = np.diag([-1.0, -1.0, 1.0]) if deg == 180 else R  # exactly
        P = CUBE.copy()
        P[4:] = (CUBE[4:] - [0.5, 0.5, 0]) @ R.T + [0.5, 0.5, 0]
        return P

    H = np.arange(8)[None]
    r = hex_validity(twisted(180), H)
    assert r.corner_valid[0] and not r.valid[0] and _exact_det(twisted(180), r.witness[0]) == 0
    assert hex_validity(twisted(170), H).valid[0]
    # scale and translation do not change any decision (tiny, huge, far from the origin)
    X, H2 = _random_hexes(500, seed=5)
    base = hex_validity(X, H2).valid
    for Y in (X * 2.0**-600, X * 2.0**500, X + 1e6):
        assert np.array_equal(hex_validity(Y, H2).valid, base)
    bad = X.copy()
    bad[3, 1] = np.nan
    assert not hex_validity(bad, H2).valid[0]


# ----------------------------------------------------------------------------- rest checks


def _grid_hexes():
    return G.hex_mesh(2, 2, 2)


@pytest.mark.parametrize("case", ["non-convex", "bow tie", "against", "repeated", "non-manifold", "z",
                                  "surface twist", "hex twist", "hex against", "hex duplicate", "rest"])
def test_bad_rest_elements_get_one_line_errors(case):
    V, Q = G.quad_mesh(3, 3)
    V3, H = _grid_hexes()
    if case == "non-convex":
        W = V.copy()
        W[5] = [0.6, 0.6]  # vertex (1, 1) pushed inside quad 4's far corner: a reflex corner
        make = lambda: Problem.quads(W, Q)  # noqa: E731
    elif case == "bow tie":
        make = lambda: Problem.quads(V, np.concatenate([Q[:1, [0, 1, 3, 2]], Q[1:]]))  # noqa: E731
    elif case == "against":
        make = lambda: Problem.quads(V, np.concatenate([Q[:1, ::-1], Q[1:]]))  # noqa: E731
    elif case == "repeated":
        make = lambda: Problem.quads(V, np.concatenate([Q[:1, [0, 1, 1, 3]], Q[1:]]))  # noqa: E731
    elif case == "non-manifold":
        W = np.vstack([V, [[0, -1], [1 / 3, -1], [0, -2], [1 / 3, -2]]])  # two quads below edge 0-1
        make = lambda: Problem.quads(W, np.concatenate([Q, [[1, 0, 16, 17], [1, 0, 18, 19]]]))  # noqa: E731
    elif case == "z":
        make = lambda: Problem.quads(np.column_stack([V, V[:, 0] ** 2]), Q)  # noqa: E731
    elif case == "surface twist":
        W = np.column_stack([V, np.zeros(len(V))])
        make = lambda: Problem.quad_surface(W, np.concatenate([Q[:1, [0, 1, 3, 2]], Q[1:]]))  # noqa: E731
    elif case == "hex twist":
        W = V3.copy()
        make = lambda: Problem.hexes(W, np.concatenate([H[:1, [0, 1, 2, 3, 6, 7, 4, 5]], H[1:]]))  # noqa: E731
    elif case == "hex against":
        make = lambda: Problem.hexes(V3, np.concatenate([H[:1, [0, 3, 2, 1, 4, 7, 6, 5]], H[1:]]))  # noqa: E731
    elif case == "hex duplicate":
        make = lambda: Problem.hexes(V3, np.concatenate([H, H[:1]]))  # noqa: E731
    else:
        make = lambda: Problem.quads(V, Q, rest="square")  # noqa: E731
    with pytest.raises(ParameterError if case == "rest" else MeshError) as info:
        make()
    msg = str(info.value)
    assert "\n" not in msg and len(msg) > 40
    assert ("repeat another's vertices (first: hexahedron 8 repeats hexahedron 0)" in msg) == (case == "hex duplicate")


def test_clockwise_and_mirrored_meshes_are_reoriented():
    V, Q = G.quad_mesh(3, 2)
    p = Problem.quads(V, Q[:, ::-1])
    assert np.array_equal(p.elements, Q[:, ::-1][:, [0, 3, 2, 1]]) and count_invalid(V, p.elements) == 0
    V3, H = _grid_hexes()
    p = Problem.hexes(V3, H[:, [0, 3, 2, 1, 4, 7, 6, 5]])
    assert np.array_equal(p.elements, H)


def test_boundary_vertices_are_the_elements_not_their_corners():
    V, Q = G.quad_mesh(4, 3)
    p = Problem.quads(V, Q)
    onb = (V[:, 0] == 0) | (V[:, 0] == 1) | (V[:, 1] == 0) | (V[:, 1] == 1)
    assert np.array_equal(p.boundary_vertices(), np.flatnonzero(onb))
    V3, H = G.hex_mesh(3, 3, 3)
    onb = ((V3 == 0) | (V3 == 1)).any(1)
    assert np.array_equal(Problem.hexes(V3, H).boundary_vertices(), np.flatnonzero(onb))


def test_certificate_reports_tests_and_quality():
    V3, H = G.hex_mesh(2, 2, 2)
    c = certify_elements(V3, H)
    assert c.certified and c.tests["bernstein"] == 8 and c.quality.min == pytest.approx(1.0)
    W = V3.copy()
    W[13] = [0.5, 0.5, 0.5] + np.array([0.1, -0.12, 0.1])  # inside, but not enough to invert a corner
    assert certify_elements(W, H).certified
    W[13] = [2.5, 2.5, 2.5]
    c = certify_elements(W, H)
    assert not c.certified and c.tests["corners"] == c.invalid > 0 and c.summary()["invalid"] == c.invalid


# ----------------------------------------------------------------------------- untangling


def _untangled(tangle, start="given"):
    """Untangled and certified; from the tangled map itself by default (the eps loop's test: with
    the boundary at rest the harmonic start of ``"auto"`` is the rest mesh)."""
    p = tangle.problem()
    assert tangle.inverted() > 0
    r = untangle(p, tangle.x0, progress=False, options=UntangleOptions(start=start))
    assert r.success, (tangle.name, r.message)
    assert r.details.start == ("given" if start == "given" else "harmonic")
    c = certify_elements(r.x, p.elements)
    assert c.certified and r.certificate.inverted == 0
    assert np.array_equal(r.x[tangle.fixed], tangle.x0[tangle.fixed])
    return r, c


@pytest.mark.parametrize("family", ["rot120", "noise", "random", "squash"])
def test_quad_families_untangle(family):
    V, Q = G.quad_mesh(16, 16)
    t = {"rot120": lambda: G.rotated_interior(V, Q, 120), "noise": lambda: G.noisy_interior(V, Q, 2.0),
         "random": lambda: G.random_interior(V, Q), "squash": lambda: G.squashed_boundary(V, Q, 0.7)}[family]()
    _untangled(t)


@pytest.mark.parametrize("family", ["noise", "squash", "twist", "bend"])
def test_hex_families_untangle(family):
    V, H = G.hex_mesh(6, 6, 6)
    t = {"noise": lambda: G.noisy_interior(V, H, 1.0), "squash": lambda: G.squashed_boundary(V, H, 0.6),
         "twist": lambda: G.twisted_box(3, 24, 0.5, hexes=True),
         "bend": lambda: G.bent_box(4, 48, 180.0, hexes=True)}[family]()
    r, c = _untangled(t)
    assert c.tests["bernstein"] + c.tests["subdivision"] + c.tests["exact"] == len(c.valid)
    if family == "bend":  # stiff: Newton after the L-BFGS probe (L-BFGS alone took 3,014)
        assert STIFF_AFTER_NEWTON < r.stats.iterations < STIFF_AFTER_NEWTON + 200


@pytest.mark.parametrize("kind", ["quad", "hex"])
def test_harmonic_start_reproduces_an_affine_boundary(kind):
    """The rest Laplacian of the corner simplices has linear precision on a grid: the harmonic
    extension of an affine image of the boundary is that affine map, whatever the interior was."""
    V, E = G.quad_mesh(5, 7) if kind == "quad" else G.hex_mesh(3, 4, 5)
    p0 = Problem.quads(V, E) if kind == "quad" else Problem.hexes(V, E)
    b = p0.boundary_vertices()
    A = np.array([[1.3, 0.4], [-0.2, 0.9]]) if kind == "quad" else np.array(
        [[1.3, 0.4, 0.1], [-0.2, 0.9, 0.3], [0.1, -0.3, 1.1]])
    target = V @ A.T + 0.7
    p = Problem.quads(V, E, b, target[b]) if kind == "quad" else Problem.hexes(V, E, b, target[b])
    x0 = G.noisy_interior(V, E, 2.0, seed=3).x0
    x0[b] = target[b]
    x = harmonic_start(p, x0)
    assert np.abs(x - target).max() < 1e-12 and np.array_equal(x[b], target[b])


def test_auto_start_untangles_a_bent_hex_rod_from_the_harmonic_extension():
    """The bend that needs Newton after a 1,000-iteration L-BFGS probe from its tangled map (the
    family test above) takes a few iterations from the harmonic extension of its boundary."""
    t = G.bent_box(4, 48, 180.0, hexes=True)
    x, which = choose_start(t.problem(), t.x0)
    assert which == "harmonic" and t.problem().count_inverted(x) < t.inverted()
    r, c = _untangled(t, "auto")
    assert r.stats.iterations < 50 and r.stats.inverted_at_start == t.inverted()
    for scale in (1e-150, 1e200):  # the corner counts are taken on an exactly rescaled copy
        p = Problem.hexes(t.rest, t.problem().elements, t.fixed, t.x0[t.fixed] * scale)
        assert choose_start(p, t.x0 * scale)[1] == "harmonic", scale


def test_auto_start_keeps_the_given_map(monkeypatch):
    import geomopt.untangling.start as S

    V, Q = G.quad_mesh(6, 6)
    t = G.rotated_interior(V, Q, 120)
    p = t.problem()
    assert choose_start(p, V)[1] == "given"  # nothing inverted: the extension is not even made
    assert choose_start(p, t.x0, "given")[1] == "given"
    assert choose_start(p, t.x0)[1] == "harmonic"
    # simplices keep their map under auto (the rest of untangling is measured on it)
    Vt, T = G.box_mesh(2, 2, 8)
    tt = G.bent_box(2, 8, 180.0)
    assert choose_start(tt.problem(), tt.x0)[1] == "given" and choose_start(tt.problem(), tt.x0, "harmonic")[1] == \
        "harmonic"
    # no handle: the extension is undefined
    free = Problem.quads(V, Q)
    assert choose_start(free, t.x0)[1] == "given"
    with pytest.raises(ParameterError, match="needs a handle"):
        choose_start(free, t.x0, "harmonic")
    # an extension with as many inverted corners as the map is not taken
    monkeypatch.setattr(S, "harmonic_start", lambda problem, x0: x0.copy())
    assert choose_start(p, t.x0)[1] == "given"


def test_harmonic_start_needs_a_handle_in_some_part():
    V, Q = G.quad_mesh(3, 3)
    two = np.concatenate([Q, Q + len(V)])
    W = np.concatenate([V, V + [2.0, 0.0]])
    b = Problem.quads(V, Q).boundary_vertices()
    assert harmonic_start(Problem.quads(W, two), W) is None  # no handle anywhere
    p = Problem.quads(W, two, b, W[b])  # handles on the first copy only: the second keeps its map
    x0 = W + 0.1 * np.random.default_rng(0).standard_normal(W.shape)
    xh = harmonic_start(p, x0)
    assert np.abs(xh[: len(V)] - W[: len(V)]).max() < 1e-12 and np.array_equal(xh[len(V):], x0[len(V):])
    p2 = Problem.quads(W, two, np.concatenate([b, b + len(V)]), np.concatenate([W[b], W[b + len(V)]]))
    assert np.abs(harmonic_start(p2, W) - W).max() < 1e-12


# ----------------------------------------------------------------------------- smoothing


def test_smooth_raises_the_worst_element_of_a_perturbed_non_box_hex_mesh():
    V, H = G.sector_mesh(3, 6, 3, perturb=0.4, seed=1)
    before = quality(V, H)
    r = smooth(V, H)
    d = r.details
    assert r.success and d.elements.certified and d.improved and r.stats.outer_iterations == 1 and not len(d.held)
    assert d.after.min > before.min + 0.3 and d.after.mean > before.mean
    assert np.array_equal(r.x[Problem.hexes(V, H).boundary_vertices()], V[Problem.hexes(V, H).boundary_vertices()])


def test_smooth_never_lowers_the_minimum_scaled_jacobian():
    """A needle in the boundary: the Winslow minimum squeezes the quads at its base below the
    input's worst; smooth holds their vertices and solves again, keeping the rest smooth."""
    n = 12
    V, Q = G.quad_mesh(n, n)
    s, t = V[:, 0], V[:, 1]
    needle = np.where(np.isclose(s, 0.5), 0.7, 0.0)
    X0 = np.stack([s, needle + t * (1.0 - needle)], 1)
    before = quality(X0, Q)
    r = smooth(X0, Q)
    d = r.details
    assert r.success and d.elements.certified and d.after.min >= before.min and d.improved
    assert r.stats.outer_iterations > 1 and 0 < len(d.held) < 20 and d.after.below_0_2 < before.below_0_2
    worst = smooth(X0, Q, options=SmoothOptions(max_rounds=1))  # the one solve allowed makes the worst element worse: the input
    assert worst.outcome is Outcome.MAX_STEPS and not worst.success and not worst.details.improved
    assert np.array_equal(worst.x, X0) and "input is returned" in worst.message and not len(worst.details.held)
    assert worst.details.after == before and worst.certificate.locally_injective
    with pytest.raises(MeshError, match="untangle it first"):
        smooth(G.rotated_interior(*G.quad_mesh(4, 4), 90).x0, G.quad_mesh(4, 4)[1])


def test_every_solver_and_compare_take_quads_and_hexahedra(tmp_path):
    import geomopt
    from geomopt import io

    V, Q = G.sector_mesh(3, 6, perturb=0.3, seed=2)
    p = Problem.quads(V, Q, rest="reference")
    p = p.with_fixed(p.boundary_vertices(), V[p.boundary_vertices()])
    cmp = geomopt.compare(p, x0=V, solvers=["newton", "lbfgs", "slim", "aqp", "cm"], options=CompareOptions(max_steps=30),
                          out=tmp_path / "q")
    for name, r in cmp.results.items():
        assert r.certificate.inverted == 0 and certify_elements(r.x, p.elements).certified, name
        assert r.energy < r.energy_history[0]
        P, Q2, _ = io.read_cells(tmp_path / "q" / f"{name}.obj")
        assert np.array_equal(Q2, Q) and np.array_equal(P[:, :2], np.asarray(r.x))
    V3, H = G.sector_mesh(2, 3, 2, perturb=0.3, seed=2)
    p3 = Problem.hexes(V3, H, rest="reference")
    p3 = p3.with_fixed(p3.boundary_vertices(), V3[p3.boundary_vertices()])
    cmp = geomopt.compare(p3, x0=V3, solvers=["newton", "lbfgs"], options=CompareOptions(max_steps=30),
                          out=tmp_path / "h")
    for name, r in cmp.results.items():
        assert r.certificate.inverted == 0 and io.read_cells(tmp_path / "h" / f"{name}.vtk")[2] == "hexahedron"


def test_quad_surface_is_the_surface_path_of_its_corner_triangles():
    """A curved quad patch flattened corner by corner: energy and gradient equal those of
    Problem.surface on its two diagonal triangulations; parameterizing it keeps every quad valid."""
    from geomopt.solvers import minimize

    V, Q = G.quad_mesh(6, 5)
    V3 = np.column_stack([V, 0.3 * np.sin(2.0 * V[:, 0]) * V[:, 1]])
    p = Problem.quad_surface(V3, Q)
    tri = [Problem.surface(V3, np.concatenate([Q[:, [0, 1, 3]], Q[:, [2, 3, 1]]])),
           Problem.surface(V3, np.concatenate([Q[:, [1, 2, 0]], Q[:, [3, 0, 2]]]))]
    b = p.boundary_vertices()
    x = V + 0.01 * np.random.default_rng(4).standard_normal(V.shape)
    obj = Objective(p.with_fixed(b, x[b]), "symmetric_dirichlet")
    vq, gq = obj.value_and_grad(x, obj.params())
    parts = [Objective(t.with_fixed(b, x[b]), "symmetric_dirichlet").value_and_grad(x, obj.params()) for t in tri]
    assert abs(float(vq) - sum(float(v) for v, _ in parts)) <= 1e-12 * float(vq)
    assert np.abs(np.asarray(gq) - sum(np.asarray(g) for _, g in parts)).max() <= 1e-12 * np.abs(gq).max()
    r = minimize(obj, x, progress=False)
    assert r.success and certify_elements(r.x, p.elements).certified


def test_untangling_stops_when_only_hexahedra_interiors_fold(monkeypatch):
    """The energy sees corners only: when every corner is positive but the exact test finds
    hexahedra folded inside, more eps iterations cannot help; untangle says so and stops."""
    import geomopt.mesh.elements as elements_module

    t = G.noisy_interior(*G.hex_mesh(3, 3, 3), 0.5)
    monkeypatch.setattr(elements_module, "count_invalid", lambda X, E: 1)
    r = untangle(t.problem(), t.x0, progress=False)
    assert not r.success and "fold inside" in r.message and r.stats.outer_iterations < 20


# ----------------------------------------------------------------------------- local certificate


def _fan(k, turn):
    """k quads around vertex 0 turning ``turn`` radians in all: (V (2k+1, 2), Q (k, 4))."""
    a = np.arange(k) * turn / k
    V = np.zeros((2 * k + 1, 2))
    V[1:k + 1] = np.c_[np.cos(a), np.sin(a)]
    V[k + 1:] = 1.25 * np.c_[np.cos(a + turn / k / 2), np.sin(a + turn / k / 2)]
    return V, np.array([[0, 1 + j, k + 1 + j, 1 + (j + 1) % k] for j in range(k)])


def _extrude(V, Q):
    n = len(V)
    return np.r_[np.c_[V, np.zeros(n)], np.c_[V, np.ones(n)]], np.c_[Q, Q + n]


def test_element_certificate_finds_branch_points_the_corners_cannot_see():
    """Eight valid quads winding twice around their centre (every corner positive) are not
    locally injective: the certificate names the branch vertex; extruded to hexahedra, the
    axis edge and its ends.  The same certificate passes the once-wound fan, which the
    overlapping corner simplices taken as one mesh would fail."""
    from geomopt.exact.certify import local_certificate
    from geomopt.mesh.elements import corner_simplices, element_local_certificate

    V, Q = _fan(8, 2 * np.pi)
    X, _ = _fan(8, 4 * np.pi)
    assert valid_elements(X, Q).all()
    assert element_local_certificate(V, Q).ok and not local_certificate(V, corner_simplices(Q)).ok
    c = Problem.quads(V, Q).certify(X)
    assert not c.ok and c.inverted == 0 and c.branch_vertices.tolist() == [0] and "branch point" in c.message
    P, H = _extrude(V, Q)
    P2, _ = _extrude(X, Q)
    assert element_local_certificate(P, H).ok and not local_certificate(P, corner_simplices(H)).ok
    c = Problem.hexes(P, H).certify(P2)
    assert not c.ok and c.branch_edges.tolist() == [[0, len(V)]] and "hexahedra around interior edge" in c.message
    V3, H3 = G.hex_mesh(4, 3, 3)
    assert Problem.hexes(V3, H3).certify(V3 + 0.02 * np.sin(7 * V3)).ok


def test_element_certificate_finds_a_free_boundary_overlapping_itself():
    """Six quads of an open fan (a boundary vertex) turned by 1.4 full turns: every quad valid,
    the boundary overlaps at the centre."""
    from geomopt.mesh.elements import element_local_certificate

    k, turn = 6, 1.4 * 2 * np.pi
    a = np.arange(k + 1) * turn / k
    V = np.zeros((2 * k + 2, 2))
    V[1:k + 2] = np.c_[np.cos(a), np.sin(a)]
    V[k + 2:] = 1.25 * np.c_[np.cos(a[:-1] + turn / k / 2), np.sin(a[:-1] + turn / k / 2)]
    Q = np.array([[0, 1 + j, k + 2 + j, 2 + j] for j in range(k)])
    assert valid_elements(V, Q).all()
    c = element_local_certificate(V, Q)
    assert not c.ok and 0 in c.boundary_overlaps.tolist()
    half = V.copy()  # the same fan turned 0.7 turns: fine
    a = np.arange(k + 1) * 0.7 * 2 * np.pi / k
    half[1:k + 2] = np.c_[np.cos(a), np.sin(a)]
    half[k + 2:] = 1.25 * np.c_[np.cos(a[:-1] + 0.7 * np.pi / k), np.sin(a[:-1] + 0.7 * np.pi / k)]
    assert element_local_certificate(half, Q).ok


def _open_fan(k, turn):
    """An open fan of ``k`` quads about vertex 0 turning ``turn`` radians: (V, Q)."""
    a = np.arange(k + 1) * turn / k
    V = np.zeros((2 * k + 2, 2))
    V[1:k + 2] = np.c_[np.cos(a), np.sin(a)]
    V[k + 2:] = 1.25 * np.c_[np.cos(a[:-1] + turn / k / 2), np.sin(a[:-1] + turn / k / 2)]
    return V, np.array([[0, 1 + j, k + 2 + j, 2 + j] for j in range(k)])


@pytest.mark.parametrize("turns", [1.4, 2.2])
def test_hex_certificate_finds_a_boundary_edge_overlapping_itself(turns):
    """The open quad fan extruded to hexahedra: every hexahedron valid, the free boundary
    wraps round the axis edge (0, n) more than a full turn, so the stars of its ends overlap
    and the axis edge's wedges do too; turned 0.7 turns it is locally injective.  The
    certificate skips the boundary tests at the link copies of its stars (they cannot fail),
    never at the apexes."""
    from geomopt.mesh.elements import element_local_certificate

    V, Q = _open_fan(6, turns * 2 * np.pi)
    P, H = _extrude(V, Q)
    assert valid_elements(P, H).all()
    c = element_local_certificate(P, H)
    n = len(V)
    assert not c.ok and c.inverted == 0 and not len(c.branch_vertices) and not len(c.branch_edges)
    assert c.boundary_edge_overlaps.tolist() == [[0, n]] and c.boundary_overlaps.tolist() == [0, n]
    assert element_local_certificate(*_extrude(*_open_fan(6, 0.7 * 2 * np.pi))).ok


def test_fixed_stars_are_judged_on_the_elements_tangent_cones():
    """A hex slab one element thick has every vertex on the boundary: with all of them fixed
    the plain fixed-star check on the overlapping corner tetrahedra would refuse it; judged on
    the tangent cones it passes.  A fixed quad fan winding twice is
    solved and reported as forced by the handles."""
    from geomopt.exact.certify import fixed_star_certificate
    from geomopt.mesh.elements import corner_simplices

    V, H = G.hex_mesh(3, 3, 1)
    p = Problem.hexes(V, H)
    p = p.with_fixed(np.arange(len(V)), V)
    assert not fixed_star_certificate(V, corner_simplices(p.elements), p.fixed).ok
    assert p.certify_fixed(V).ok and p.certify(V).ok
    V2, Q = _fan(8, 2 * np.pi)
    X, _ = _fan(8, 4 * np.pi)
    q = Problem.quads(V2, Q).with_fixed(np.arange(len(V2)), X)
    c = q.certify_fixed(X)
    assert not c.ok and c.branch_vertices.tolist() == [0]
    r = untangle(q, X, progress=False)  # forced by the handles: reported, not refused (issue 30 item 5)
    assert r.outcome == Outcome.CERTIFIED_EXCEPT_FIXED and not r.success
    assert r.certificate.forced.branch_vertices.tolist() == [0]


def test_each_element_kind_is_one_table_row_that_the_library_reads():
    """Issue 32 item 6: dimension, corner arity, validity test, problem constructor and map file
    come from the kind's row (:data:`geomopt.mesh.elements.ELEMENT_KINDS`), and an unknown
    vertex count is one clear error."""
    from geomopt.mesh import elements
    from geomopt.mesh.generators import square_mesh

    for k, kind in elements.ELEMENT_KINDS.items():
        assert kind.n_vertices == k and kind.corners.shape == (k, kind.dim + 1)
        assert hasattr(geomopt.Problem, kind.constructor) and kind.map_file in (".obj", ".vtk")
    V, F = square_mesh(3)
    Q = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]])
    assert elements.corner_simplices(Q).shape == (16, 3)
    problem = geomopt.Problem.cells(V, Q)
    assert problem.dim == 2 and problem.elements.shape == (4, 4) and problem.kind == "quad"
    X = V * [-1.0, 1.0]  # mirrored: every quad reversed
    X[0] = V[0]  # ... and the first one also non-convex at a corner
    valid, corner_valid, tests = elements.ELEMENT_KINDS[4].validity(X, Q)
    assert not valid.any() and (valid == corner_valid).all() and tests["corners"] == 4
    assert elements.count_invalid(X, Q) == 4 and elements.count_invalid(V, Q) == 0
    assert elements.ELEMENT_KINDS[4].validity(V, Q)[0].all()
    unknown = max(elements.ELEMENT_KINDS) + 1  # a count no row has (a new row is not an error here)
    with pytest.raises(geomopt.MeshError, match="no known kind: quads have 4 vertices, hexahedra have 8"):
        elements.kind_of(np.zeros((2, unknown), int))


def test_element_kinds_agree_with_the_file_tables_and_what_is_derived_from_them():
    """Issue 49 item 2: an element kind's row names its cell in the files (io name, node count,
    dimension, words, VTK cell type) and its problems' kind; the case reader's kinds, the map
    files ``geomopt.save`` writes and the viewer's cell types are derived from the rows, never
    listed beside them (a new kind used to touch eight files)."""
    from geomopt import io
    from geomopt._runtime.formats import extensions
    from geomopt.io._cells import VTK_CELLS
    from geomopt.mesh import cells, elements
    from geomopt.plot import _save, _view

    for n, kind in elements.ELEMENT_KINDS.items():
        assert io.CELL_KINDS[kind.word] == (n, kind.dim)
        assert VTK_CELLS[kind.vtk][0] == kind.word and VTK_CELLS[kind.vtk][2] == n
        Q = np.arange(n)[None]
        assert geomopt.Problem.cells(kind.reference, Q).kind == kind.problem_kind
        assert elements.kind_named(kind.problem_kind) is kind
        assert _save.MAP_FILES[kind.problem_kind] == extensions(kind.word, writable=True)
        assert kind.dim == 2 or _view._vtk_type(Q) == kind.vtk  # the volume cells the viewer draws
        assert kind.word in cells.SMOOTH_KINDS and kind.word in cells.UNTANGLE_KINDS
    assert elements.kind_named("tet") is None and _view._vtk_type(np.zeros((1, 4), int)) == 10
    assert len(cells.SMOOTH_KINDS) == len(elements.ELEMENT_KINDS)
    dims = [3 if k == "tetra" else elements.ELEMENT_KINDS[io.CELL_KINDS[k][0]].dim for k in cells.UNTANGLE_KINDS]
    assert dims == sorted(dims, reverse=True) and "tetra" in cells.UNTANGLE_KINDS  # volume cells before quads
    assert cells.UNTANGLE_KINDS.index("hexahedron") < cells.UNTANGLE_KINDS.index("tetra")  # hexes by priority

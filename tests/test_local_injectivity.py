"""Exact local injectivity around vertices and edges (geomopt.exact.stars, certify.local_certificate).

Positive elements are not local injectivity: a fan can wind twice around an interior vertex
(2D) or edge (3D), and a fan around a boundary vertex or edge can turn a full turn or more.
Hand-made maps of each kind, float oracles on random ones, exact scalings, and the call sites
(minimize, untangle, the written file, the CLI) that must refuse them (issue 19).
"""

from __future__ import annotations

import numpy as np
import pytest

from geomopt import Outcome, Problem
from geomopt.exact.certify import LocalCertificate, certify_bijective, local_certificate
from geomopt.exact.predicates import count_inverted
from geomopt.exact.stars import fan_overlaps_2d, star_overlaps_3d

# ------------------------------------------------------------------------------ builders


def fan_2d(angles, radii=None):
    """An open fan around vertex 0 at the origin: triangles (0, i, i + 1) through the given
    angles (increasing); vertex 0 is a boundary vertex turning ``angles[-1] - angles[0]``."""
    radii = np.ones(len(angles)) if radii is None else np.asarray(radii, float)
    W = np.c_[radii * np.cos(angles), radii * np.sin(angles)]
    X = np.vstack([[0.0, 0.0], W])
    F = np.array([[0, i + 1, i + 2] for i in range(len(angles) - 1)])
    return X, F


def exact_fan(turns, k):
    """A fan of ``k`` triangles turning exactly ``turns`` (a multiple of 1/4) turns: the ray
    directions are axis directions or exact integer diagonals, so "exactly one turn" is exact."""
    dirs = np.array([[1, 0], [2, 1], [1, 1], [1, 2], [0, 1], [-1, 2], [-1, 1], [-2, 1],
                     [-1, 0], [-2, -1], [-1, -1], [-1, -2], [0, -1], [1, -2], [1, -1], [2, -1]], float)
    steps = int(round(turns * 16))
    idx = np.round(np.linspace(0, steps, k + 1)).astype(int)
    W = dirs[idx % 16] * (1.0 + 0.25 * (idx // 16))[:, None]  # later turns further out
    X = np.vstack([[0.0, 0.0], W])
    return X, np.array([[0, i + 1, i + 2] for i in range(k)])


def orient_tets(X, T):
    """Swap two vertices of every negatively oriented tet."""
    T = np.array(T, dtype=np.int64)
    P = X[T]
    neg = np.linalg.det(P[:, 1:] - P[:, :1]) < 0
    T[neg] = T[neg][:, [0, 2, 1, 3]]
    return T


def edge_star(turns, k, closed):
    """Tets around the edge (0, 1) on the z axis through a ring of points turning ``turns``
    times (closed: the ring closes up, the edge is interior)."""
    th = np.linspace(0, 2 * np.pi * turns, k + 1)
    if closed:
        th = th[:-1]
    R = np.c_[np.cos(th), np.sin(th), 0.1 * np.sin(3 * th)]
    X = np.vstack([[0, 0, -1.0], [0, 0, 1.0], R])
    nr = len(R)
    T = [[0, 1, 2 + i, 2 + (i + 1) % nr] for i in range(k)]
    return X, orient_tets(X, T)


def cylinder(sectors=12, levels=3, span=2 * np.pi):
    """A tet mesh of a cylinder (or, ``span`` < 2 pi, a sector of one) around the z axis: axis
    vertices and one ring per level, prisms split consistently (diagonal from the lower id).

    Returns rest vertices (n, 3), tets (m, 4) positive, the axis vertex ids (levels + 1,) and
    each vertex's azimuth (n,)."""
    closed = span >= 2 * np.pi
    n_ring = sectors if closed else sectors + 1
    th = np.arange(n_ring) * span / sectors
    V, azim, axis, rings = [], [], [], []
    for z in range(levels + 1):
        axis.append(len(V))
        V.append([0.0, 0.0, float(z)]), azim.append(0.0)
        rings.append(list(range(len(V), len(V) + n_ring)))
        for t in th:
            V.append([np.cos(t), np.sin(t), float(z)]), azim.append(t)
    V = np.array(V)
    T = []
    for z in range(levels):
        for i in range(sectors):
            bottom = [axis[z], rings[z][i], rings[z][(i + 1) % n_ring]]
            up = dict(zip(bottom, [axis[z + 1], rings[z + 1][i], rings[z + 1][(i + 1) % n_ring]]))
            p, q, r = sorted(bottom)
            T += [[p, q, r, up[r]], [p, q, up[q], up[r]], [p, up[p], up[q], up[r]]]
    return V, orient_tets(V, T), np.array(axis), np.array(azim)


def wrapped_cylinder(factor=2.0, sectors=12, levels=3, span=2 * np.pi):
    """The cylinder with every vertex's azimuth multiplied by ``factor`` (a ball whose boundary
    wraps ``factor`` times around its axis): every tet stays positive."""
    V, T, axis, azim = cylinder(sectors, levels, span)
    r = np.hypot(V[:, 0], V[:, 1])
    X = np.c_[r * np.cos(factor * azim), r * np.sin(factor * azim), V[:, 2]]
    return V, T, X, axis


def sphere_link(k=8, rings=3):
    """A UV sphere (k azimuth sectors, ``rings`` latitude rings, two poles): points (p, 3) on
    the unit sphere and triangles (f, 3) oriented outwards."""
    lat = np.linspace(0, np.pi, rings + 2)[1:-1]
    pts = [[0, 0, 1.0]]
    for a in lat:
        for j in range(k):
            t = 2 * np.pi * j / k
            pts.append([np.sin(a) * np.cos(t), np.sin(a) * np.sin(t), np.cos(a)])
    pts.append([0, 0, -1.0])
    P = np.array(pts)
    south = len(P) - 1
    ring = lambda r, j: 1 + r * k + j % k  # noqa: E731
    F = [[0, ring(0, j), ring(0, j + 1)] for j in range(k)]
    for r in range(rings - 1):
        for j in range(k):
            F += [[ring(r, j), ring(r + 1, j), ring(r + 1, j + 1)], [ring(r, j), ring(r + 1, j + 1), ring(r, j + 1)]]
    F += [[south, ring(rings - 1, j + 1), ring(rings - 1, j)] for j in range(k)]
    return P, np.array(F)


def star_of(link_points, link_faces, center=(0.0, 0.0, 0.0)):
    """The star of a vertex (id 0 at ``center``) over a link: tets (0, a, b, c), positive."""
    X = np.vstack([center, link_points])
    T = np.c_[np.zeros(len(link_faces), np.int64), link_faces + 1]
    return X, orient_tets(X, T)


# ------------------------------------------------------------------------------ 2D fans


@pytest.mark.parametrize("turns, bad", [(0.75, False), (15 / 16, False), (1.0, True), (1.25, True),
                                        (1.5, True), (2.0, True)])
def test_boundary_fan_of_a_full_turn_or_more_overlaps(turns, bad):
    X, F = exact_fan(turns, 12)
    assert count_inverted(X, F) == 0
    branch, overlaps = fan_overlaps_2d(X, F)
    assert len(branch) == 0
    assert (0 in overlaps) == bad
    assert set(overlaps.tolist()) <= {0}
    cert = local_certificate(X, F)
    assert cert.ok == (not bad)
    if bad:
        assert "boundary vertex 0" in cert.message


def test_boundary_fan_at_extreme_scales_is_the_same():
    """Powers of two scale the map exactly: the verdict must not change (subnormal, huge)."""
    for turns in (0.75, 1.0, 1.5):
        X, F = exact_fan(turns, 12)
        want = fan_overlaps_2d(X, F)[1].tolist()
        for e in (-1070, -1040, -600, 600, 1000):
            got = fan_overlaps_2d(X * 2.0**e, F)[1].tolist()
            assert got == want, (turns, e)


def test_bowtie_vertex_two_fans():
    """A non-manifold (bow-tie) boundary vertex: two fans at one vertex are fine while disjoint,
    not when one reaches into the other."""
    def bowtie(second):
        X1, F1 = fan_2d(np.linspace(0.0, 2.0, 4))
        X2, F2 = fan_2d(second)
        X = np.vstack([X1, X2[1:]])
        F = np.vstack([F1, np.where(F2 == 0, 0, F2 + len(X1) - 1)])
        return X, F

    X, F = bowtie(np.linspace(3.0, 5.0, 4))
    assert local_certificate(X, F).ok
    X, F = bowtie(np.linspace(1.5, 3.5, 4))  # starts inside the first fan
    assert local_certificate(X, F).boundary_overlaps.tolist() == [0]
    X, F = bowtie(np.linspace(-0.5, 1.0, 4))  # ends inside the first fan
    assert local_certificate(X, F).boundary_overlaps.tolist() == [0]


def test_2d_fans_match_a_float_angle_oracle():
    """Random fans, interior (closed) and boundary (open), against the angle sum in floats
    (cases within 1e-9 of a whole turn skipped)."""
    rng = np.random.default_rng(3)
    checked = 0
    for trial in range(400):
        closed = trial % 2 == 0
        k = int(rng.integers(3, 14))
        steps = rng.uniform(0.05, 0.95, k) * np.pi * rng.choice([0.4, 1.0, 1.6])
        steps = np.minimum(steps, 0.99 * np.pi)
        ang = np.concatenate([[0.0], np.cumsum(steps)])
        total = ang[-1]
        if closed:
            turns = total / (2 * np.pi)
            if abs(turns - round(turns)) > 1e-3 or round(turns) < 1:
                continue
            ang = ang[:-1]
            X, F = fan_2d(ang, rng.uniform(0.5, 2.0, len(ang)))
            F = np.vstack([F, [[0, len(ang), 1]]])  # close the fan: vertex 0 is interior
            if count_inverted(X, F):
                continue
            P = X[F]
            a1 = np.arctan2(P[:, 1, 1], P[:, 1, 0])
            a2 = np.arctan2(P[:, 2, 1], P[:, 2, 0])
            w = round(np.sum((a2 - a1) % (2 * np.pi)) / (2 * np.pi))
            branch, _ = fan_overlaps_2d(X, F)
            assert (0 in branch) == (w != 1)
        else:
            if abs(total - 2 * np.pi) < 1e-9 or abs(total - 4 * np.pi) < 1e-9:
                continue
            X, F = fan_2d(ang, rng.uniform(0.5, 2.0, len(ang)))
            _, overlaps = fan_overlaps_2d(X, F)
            assert (0 in overlaps) == (total > 2 * np.pi)
        checked += 1
    assert checked > 150


# ------------------------------------------------------------------------------ 3D edges


@pytest.mark.parametrize("turns, closed, edges, kind", [
    (1, True, [], None), (2, True, [[0, 1]], "branch"), (3, True, [[0, 1]], "branch"),
    (0.9, False, [], None), (1.5, False, [[0, 1]], "boundary")])
def test_tets_around_an_edge(turns, closed, edges, kind):
    X, T = edge_star(turns, 15, closed)
    assert count_inverted(X, T) == 0
    branch_edges, _, boundary_edges, _ = star_overlaps_3d(X, T)
    assert branch_edges.tolist() == (edges if kind == "branch" else [])
    assert boundary_edges.tolist() == (edges if kind == "boundary" else [])
    cert = local_certificate(X, T)
    assert cert.ok == (kind is None)
    if kind == "branch":
        assert "interior edge (0, 1)" in cert.message


def test_3d_edges_match_a_float_dihedral_oracle():
    rng = np.random.default_rng(7)
    checked = 0
    for trial in range(300):
        closed = trial % 2 == 0
        k = int(rng.integers(3, 12))
        steps = np.minimum(rng.uniform(0.1, 1.0, k) * np.pi * rng.choice([0.5, 1.0, 1.5]), 0.95 * np.pi)
        th = np.concatenate([[0.0], np.cumsum(steps)])
        total = th[-1]
        if closed:
            turns = total / (2 * np.pi)
            if abs(turns - round(turns)) > 1e-3 or round(turns) < 1:
                continue
            th = th[:-1]
        elif abs(total - 2 * np.pi) < 1e-9:
            continue
        r = rng.uniform(0.5, 2.0, len(th))
        R = np.c_[r * np.cos(th), r * np.sin(th), rng.uniform(-2, 2, len(th))]
        X = np.vstack([[0, 0, -1.0], [0, 0, 1.0], R])
        nr = len(R)
        T = orient_tets(X, [[0, 1, 2 + i, 2 + (i + 1) % nr] for i in range(nr if closed else nr - 1)])
        if count_inverted(X, T):
            continue
        branch_edges, _, boundary_edges, _ = star_overlaps_3d(X, T)
        if closed:
            assert (len(branch_edges) > 0) == (round(total / (2 * np.pi)) != 1)
        else:
            assert (len(boundary_edges) > 0) == (total > 2 * np.pi)
        checked += 1
    assert checked > 100


# ------------------------------------------------------------------------------ 3D vertices


def _solid_angle_turns(X, T, v):
    """Sum of the solid angles of the tets at ``v`` over 4 pi (float; Van Oosterom-Strackee)."""
    total = 0.0
    for t in T[(T == v).any(axis=1)]:
        a, b, c = (X[u] - X[v] for u in t if u != v)
        num = abs(np.dot(a, np.cross(b, c)))
        la, lb, lc = (np.linalg.norm(p) for p in (a, b, c))
        den = la * lb * lc + np.dot(a, b) * lc + np.dot(a, c) * lb + np.dot(b, c) * la
        total += 2 * np.arctan2(num, den)
    return total / (4 * np.pi)


def test_interior_vertex_star_covering_twice_fails_at_its_polar_edges():
    """The star over a sphere link mapped with degree 2 (azimuth doubled): every tet positive,
    the vertex's neighbourhood covered twice; the certificate names the polar edges, where
    the covering branches.  (Edges winding once at every edge of an interior vertex imply its
    star covers once: the link is then a covering of the sphere, which is simply connected.)"""
    P, F = sphere_link(k=10, rings=3)
    th = np.arctan2(P[:, 1], P[:, 0])
    r = np.hypot(P[:, 0], P[:, 1])
    P2 = np.c_[r * np.cos(2 * th), r * np.sin(2 * th), P[:, 2]]
    X, T = star_of(P2, F)
    assert count_inverted(X, T) == 0 and _solid_angle_turns(X, T, 0) == pytest.approx(2.0)
    cert = local_certificate(X, T)
    assert not cert.ok
    poles = {1, len(P)}  # ids in X
    assert {tuple(e) for e in cert.branch_edges.tolist()} == {(0, p) for p in poles}
    X, T = star_of(P, F)
    assert local_certificate(X, T).ok and _solid_angle_turns(X, T, 0) == pytest.approx(1.0)


def test_edges_suffice_at_interior_vertices_random_links():
    """Random maps of a sphere link: whenever every tet is positive and every edge winds once,
    the solid angle sums to exactly 4 pi (the star covers once) and the certificate passes."""
    P, F = sphere_link(k=6, rings=2)
    T = star_of(P, F)[1]  # oriented at rest; a map must keep every tet positive
    rng = np.random.default_rng(11)
    seen = {True: 0, False: 0}
    for _ in range(400):
        th = np.arctan2(P[:, 1], P[:, 0]) * rng.choice([1, 2, 3])  # wrap the link 1-3 times
        r = np.hypot(P[:, 0], P[:, 1])
        Q = np.c_[r * np.cos(th), r * np.sin(th), P[:, 2]] + rng.normal(0, rng.uniform(0.02, 0.3), P.shape)
        X = np.vstack([[0, 0, 0.0], Q])
        if count_inverted(X, T):
            continue
        branch_edges, branch_vertices, _, _ = star_overlaps_3d(X, T)
        turns = _solid_angle_turns(X, T, 0)
        if len(branch_edges) == 0:
            assert turns == pytest.approx(1.0) and len(branch_vertices) == 0
        seen[len(branch_edges) == 0] += 1
        assert local_certificate(X, T).ok == (turns == pytest.approx(1.0))
    assert seen[True] > 20 and seen[False] > 5


def test_two_balls_pinched_at_a_vertex_cover_it_twice():
    """Two stars sharing only their centre (a non-manifold vertex), each a ball around it: every
    edge is fine, the vertex is covered twice.  Moved apart as a bow-tie they are fine."""
    P, F = sphere_link(k=6, rings=2)
    Q = 2.0 * P @ np.array([[0.8, -0.6, 0], [0.6, 0.8, 0], [0, 0, 1]])
    X = np.vstack([[0, 0, 0.0], P, Q])
    T = orient_tets(X, np.vstack([np.c_[np.zeros(len(F), int), F + 1],
                                  np.c_[np.zeros(len(F), int), F + 1 + len(P)]]))
    cert = local_certificate(X, T)
    assert cert.branch_vertices.tolist() == [0] and len(cert.branch_edges) == 0
    assert "interior vertex 0" in cert.message
    # two half balls (upper / lower hemispheres of the link) touching at the centre: fine
    up, down = F[(P[F][:, :, 2] >= 0).all(axis=1)], F[(P[F][:, :, 2] <= 0).all(axis=1)]
    X = np.vstack([[0, 0, 0.0], P, Q * [1, 1, 1]])
    T = orient_tets(X, np.vstack([np.c_[np.zeros(len(up), int), up + 1],
                                  np.c_[np.zeros(len(down), int), down + 1 + len(P)]]))
    assert local_certificate(X, T).ok
    # the second half ball turned upwards: nested in the first, overlapping it
    X2 = X.copy()
    X2[1 + len(P):] *= [1, 1, -1]
    T2 = orient_tets(X2, T)
    cert = local_certificate(X2, T2)
    assert 0 in cert.boundary_overlaps and not cert.ok


def strip_star(turns, k=24, r2=1.0, dz=0.0):
    """A boundary vertex at the origin whose link is a band (two latitude rows) turning
    ``turns`` times around the z axis: edges all fine; for more than one turn the band lies
    over itself (its second turn at radius ``r2`` and raised by ``dz``)."""
    th = np.linspace(0, 2 * np.pi * turns, k + 1)
    late = th > 2 * np.pi - 1e-9
    rad = np.where(late, r2, 1.0)
    lo = np.c_[rad * np.cos(th), rad * np.sin(th), -0.3 + dz * late]
    up = np.c_[rad * np.cos(th), rad * np.sin(th), 0.3 + dz * late]
    X = np.vstack([[0, 0, 0.0], lo, up])
    L, U = 1 + np.arange(k + 1), 2 + k + np.arange(k + 1)
    T = [[0, L[i], L[i + 1], U[i + 1]] for i in range(k)] + [[0, L[i], U[i + 1], U[i]] for i in range(k)]
    return X, orient_tets(X, T)


@pytest.mark.parametrize("turns, r2, dz, bad", [
    (0.9, 1.0, 0.0, False), (1.5, 1.0, 0.0, True), (1.5, 1.5, 0.0, True), (1.5, 1.5, 0.05, True),
    (1.2, 1.3, 0.1, True), (1.2, 1.0, 0.7, False)])
def test_boundary_vertex_star_lying_over_itself(turns, r2, dz, bad):
    """Only the vertex fails (its link boundary meets itself: exactly along a shared great circle,
    touching, or crossing); the last case's second turn is above the first (no overlap)."""
    X, T = strip_star(turns, r2=r2, dz=dz)
    assert count_inverted(X, T) == 0
    branch_edges, branch_vertices, boundary_edges, overlaps = star_overlaps_3d(X, T)
    assert len(branch_edges) == len(branch_vertices) == len(boundary_edges) == 0
    assert overlaps.tolist() == ([0] if bad else [])
    for e in (-1000, 1000):  # exact scalings (the data stay normal floats) keep the verdict
        assert star_overlaps_3d(X * 2.0**e, T)[3].tolist() == overlaps.tolist()


# ------------------------------------------------------------------------------ meshes


def test_meshes_certify_and_wrapped_balls_do_not():
    """A cylinder ball certifies; with its azimuth doubled (the boundary wraps twice around the
    axis) every tet is still positive but the axis edges are branch edges; a 3/4 sector turned
    into 1.5 turns overlaps around its boundary axis edges."""
    V, T, axis = cylinder()[:3]
    assert local_certificate(V, T).ok
    _, T, X, axis = wrapped_cylinder(2.0)
    cert = local_certificate(X, T)
    assert cert.inverted == 0 and not cert.ok
    axis_edges = {(int(a), int(b)) for a, b in zip(axis[:-1], axis[1:])}
    assert {tuple(e) for e in cert.branch_edges.tolist()} == axis_edges
    _, T, X, axis = wrapped_cylinder(2.0, span=1.5 * np.pi)
    cert = local_certificate(X, T)
    assert cert.inverted == 0 and len(cert.branch_edges) == 0
    axis_edges = {(int(a), int(b)) for a, b in zip(axis[:-1], axis[1:])}
    assert {tuple(e) for e in cert.boundary_edge_overlaps.tolist()} == axis_edges
    assert "boundary edge" in cert.message


def test_non_finite_or_inverted_maps_are_not_certified():
    V, T = cylinder()[:2]
    X = V.copy()
    X[3] = np.nan
    cert = local_certificate(X, T)
    assert not cert.ok and cert.inverted > 0 and "element" in cert.message
    cert = local_certificate(V, T[:, [1, 0, 2, 3]])
    assert cert.inverted == len(T) and cert.first_inverted == 0
    assert local_certificate(V, T[:, [1, 0, 2, 3]], orientation=-1).ok
    assert isinstance(cert, LocalCertificate)


def test_global_certificate_is_not_global_with_an_overlapping_fan():
    """certify_bijective's local part is the local certificate: a disk map with a boundary fan
    of 1.5 turns is neither global nor local."""
    X, F = exact_fan(1.5, 12)
    cert = certify_bijective(X, F)
    assert cert.inverted == 0 and cert.injectivity == "none"
    assert not cert.locally_injective and not cert.globally_injective


# ------------------------------------------------------------------------------ call sites


def test_minimize_refuses_a_positive_but_overlapping_result():
    """Every vertex fixed: minimize returns the start, a fan turning 1.5 times (issue 19 item 2:
    it passed as a success)."""
    from geomopt import Objective, minimize
    from geomopt.solvers import Outcome

    X, F = exact_fan(1.5, 12)
    rest, _ = exact_fan(0.75, 12)
    problem = Problem.planar(rest, F, np.arange(len(X)), X)
    res = minimize(Objective(problem, "symmetric_dirichlet"), X, "newton", progress=False)
    assert res.certificate.inverted == 0 and res.outcome is Outcome.NOT_INJECTIVE and not res.success
    assert "boundary vertex 0" in res.message and res.injectivity == "none"


def test_untangle_refuses_a_ball_wound_twice_and_writes_nothing(tmp_path):
    """Issue 19 item 1: a ball whose fixed boundary wraps twice around its axis, every tet
    positive, was certified by untangle and by the CLI (exit 0, file written)."""
    from geomopt import cli
    from geomopt.mesh import generators
    from geomopt.lim import LimCase
    from geomopt.solvers import Outcome
    from geomopt.untangling import untangle

    V, T, X, axis = wrapped_cylinder(2.0, levels=3)
    bnd = np.setdiff1d(np.arange(len(V)), axis[1:-1])
    res = untangle(Problem.tets(V, T, bnd, X[bnd]), X, progress=False)
    assert res.certificate.inverted == 0 and res.outcome is Outcome.NOT_INJECTIVE and not res.success
    assert "interior edge" in res.message and len(res.certificate.branch_edges) >= 1
    tangle = generators.Tangle("wound", V, T, X, bnd)
    folder = LimCase.from_tangle(tangle).write(tmp_path / "wound")
    out = tmp_path / "out.vtk"
    assert cli.main(["untangle", str(folder), "-o", str(out), "--quiet"]) == 1
    assert not out.exists()


def test_written_file_certificate_names_the_overlap(tmp_path):
    """LimCase.write_certified certifies the file read back with the local certificate, and
    leaves nothing when it fails."""
    from geomopt._runtime.errors import SolveError
    from geomopt.lim import LimCase

    V, T, X, axis = wrapped_cylinder(2.0)
    case = LimCase(dim=3, rest=V, init=X, simplices=T, handles=np.arange(3))
    with pytest.raises(SolveError, match="interior edge"):
        case.write_certified(X, tmp_path / "w.vtk")
    with pytest.raises(SolveError, match=f"{len(T)} element"):
        case.write_certified(X * [-1.0, 1.0, 1.0], tmp_path / "w2.vtk")
    assert not any(tmp_path.iterdir())


def _pinched(parts):
    """Stars sharing their centre (id 0): ``parts`` is a list of (points (p, 3), faces (f, 3))."""
    X, T, off = [np.zeros((1, 3))], [], 1
    for P, F in parts:
        X.append(P)
        T.append(np.c_[np.zeros(len(F), np.int64), F + off])
        off += len(P)
    X = np.vstack(X)
    return X, orient_tets(X, np.vstack(T))


def _cap(P, F, direction, cos_limit):
    """The faces of a link all of whose corners lie within the cap ``P . direction > cos_limit``."""
    return F[(P[F] @ np.asarray(direction, float) > cos_limit).all(axis=1)]


def test_nested_half_balls_away_from_the_generic_direction():
    """A non-manifold boundary vertex: a small half ball nested inside a big one, both around +x
    (so the generic direction, near +z, sees neither overlap) with disjoint boundaries.  Only
    the count just inside each boundary cycle finds the double cover."""
    P, F = sphere_link(k=12, rings=7)
    Px = P[:, [2, 0, 1]]  # the poles on the x axis
    big, small = _cap(Px, F, [1, 0, 0], -0.2), _cap(Px, F, [1, 0, 0], 0.6)
    X, T = _pinched([(Px, big), (2.0 * Px, small)])
    cert = local_certificate(X, T)
    assert cert.inverted == 0 and cert.boundary_overlaps.tolist() == [0], cert.message
    assert len(cert.branch_edges) == len(cert.boundary_edge_overlaps) == 0
    X, T = _pinched([(Px, big), (2.0 * Px * [-1, 1, 1], small)])  # the small one on the other side
    assert local_certificate(X, T).ok


def test_ball_and_half_ball_pinched_at_a_vertex():
    """A whole ball and a half ball (around +x) sharing their centre: the generic direction is
    covered once (by the ball alone), yet the half ball lies over the ball."""
    P, F = sphere_link(k=12, rings=5)
    Px = P[:, [2, 0, 1]]
    X, T = _pinched([(Px, F), (2.0 * Px, _cap(Px, F, [1, 0, 0], 0.0))])
    cert = local_certificate(X, T)
    assert cert.inverted == 0 and cert.boundary_overlaps.tolist() == [0], cert.message
    # a boundary vertex whose half ball holds both +-u and covers once: fine (the count runs)
    X, T = _pinched([(Px, _cap(Px, F, [1, 0, 0], -0.3))])
    assert local_certificate(X, T).ok


# ------------------------------------------------------------------------------ adversarial


def test_bowtie_fans_touching_along_a_ray_overlap():
    """Two fans at one vertex, the second starting exactly where the first ends (same ray,
    exact directions): their boundary edges overlap near the vertex."""
    X = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 2], [-1, 1], [-1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 5], [0, 5, 6]])
    assert count_inverted(X, F) == 0
    assert local_certificate(X, F).boundary_overlaps.tolist() == [0]
    X[4] = [-0.5, 2]  # the second fan starts just past the first one's end: disjoint
    assert local_certificate(X, F).ok


def test_3d_boundary_edge_exactly_a_full_turn():
    """A slit cylinder: the tets around the axis edge turn exactly once between two boundary
    faces lying on the same half-plane (the slit's two sides, exact coordinates)."""
    R = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [2, 0]], float)
    for last, bad in (([2, 0], True), ([1, 0], True), ([2, -1e-9], False)):
        R[-1] = last
        X = np.vstack([[0, 0, 0], [0, 0, 1], np.c_[R, np.full(len(R), 0.5)]])
        T = orient_tets(X, [[0, 1, 2 + i, 3 + i] for i in range(len(R) - 1)])
        assert count_inverted(X, T) == 0
        assert (local_certificate(X, T).boundary_edge_overlaps.tolist() == [[0, 1]]) == bad, last


def test_non_manifold_edge_with_two_fans():
    """Two fans of tets around one edge (their faces are all distinct, so a Problem accepts the
    mesh): fine while the fans are disjoint, not when one reaches into the other."""
    def two_fans(second):
        first = np.radians([0, 40, 80])
        th = np.concatenate([first, np.radians(second)])
        R = np.c_[np.cos(th), np.sin(th), np.zeros(len(th))]
        X = np.vstack([[0, 0, -1.0], [0, 0, 1.0], R])
        T = [[0, 1, 2, 3], [0, 1, 3, 4], [0, 1, 5, 6], [0, 1, 6, 7]]
        return X, orient_tets(X, T)

    X, T = two_fans([180, 220, 260])
    assert local_certificate(X, T).ok
    X, T = two_fans([60, 120, 160])  # starts inside the first fan
    assert local_certificate(X, T).boundary_edge_overlaps.tolist() == [[0, 1]]
    X, T = two_fans([300, 340, 380])  # ends inside the first fan
    assert local_certificate(X, T).boundary_edge_overlaps.tolist() == [[0, 1]]


def test_near_degenerate_wrapped_ball():
    """The wrapped ball with its rings squeezed towards the axis (tets within a few ulps of flat)
    and at huge and tiny exact scales: the verdict follows the exact orientations."""
    V, T, X, axis = wrapped_cylinder(2.0, sectors=10, levels=2)
    for squeeze in (1e-6, 1e-12):
        Y = X.copy()
        Y[:, :2] *= squeeze
        Y[axis, :2] = 0.0
        cert = local_certificate(Y, T)
        assert cert.inverted == 0 and len(cert.branch_edges) == len(axis) - 1
        for e in (-1000, 900):
            got = local_certificate(Y * 2.0**e, T)
            assert (got.inverted, len(got.branch_edges)) == (0, len(axis) - 1)


def test_parameterize_repairs_a_start_whose_boundary_fan_overlaps():
    """A flip-free start map whose free boundary turns 1.5 times around a vertex is not a valid
    start (it is not locally injective); param repairs it like a folded one, and the result
    certifies."""
    from geomopt.param import parameterize

    rest, F = exact_fan(0.75, 12)
    V = np.c_[rest, np.zeros(len(rest))]
    X, _ = exact_fan(1.5, 12)
    assert count_inverted(X, F) == 0 and not local_certificate(X, F).ok
    res = parameterize(V, F, x0=X, progress=False)
    assert res.details.repair is not None
    assert res.success and res.injectivity == "global" and local_certificate(res.x, F).ok


def test_compare_refuses_positive_but_overlapping_results():
    """geomopt.compare certified with the orientation test alone: every vertex fixed on a fan
    turning 1.5 times, each solver 'converged' on it."""
    from geomopt.experiments.comparison import compare

    X, F = exact_fan(1.5, 12)
    rest, _ = exact_fan(0.75, 12)
    problem = Problem.planar(rest, F, np.arange(len(X)), X)
    comp = compare(problem, x0=X, solvers=["newton", "lbfgs"])
    for name, run in comp.runs.items():
        run = run[0] if isinstance(run, tuple) else run
        assert run.inverted == 0 and not run.certified and run.outcome is not Outcome.CONVERGED, name
        assert "boundary vertex 0" in run.certificate.message


def _max_cover(X, T, v, directions):
    """Largest number of tets at ``v`` whose cone contains one of the ``directions`` (float)."""
    best = 0
    star = T[(T == v).any(axis=1)]
    count = np.zeros(len(directions), int)
    for t in star:
        a, b, c = (X[u] - X[v] for u in t if u != v)
        M = np.array([a, b, c]).T
        if np.linalg.det(M) < 0:
            M = M[:, [1, 0, 2]]
        coef = np.linalg.solve(M, directions.T)
        count += (coef > 1e-9).all(axis=0)
    best = max(best, int(count.max()))
    return best


def test_boundary_stars_match_a_sampled_direction_oracle():
    """Random maps of half-ball stars (a disk link wrapped up to twice around an axis, with
    noise): wherever sampled directions are covered twice the certificate fails the vertex, and
    where it passes no sampled direction is covered twice."""
    P, F = sphere_link(k=10, rings=5)
    cap = _cap(P, F, [0, 0, 1], -0.45)
    X0, T = star_of(P, cap)
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(4000, 3))
    seen = {True: 0, False: 0}
    for _ in range(200):
        th = np.arctan2(P[:, 1], P[:, 0]) * rng.uniform(1.0, 2.2)
        r = np.hypot(P[:, 0], P[:, 1])
        Q = np.c_[r * np.cos(th), r * np.sin(th), P[:, 2]] + rng.normal(0, rng.uniform(0.0, 0.15), P.shape)
        X = np.vstack([[0, 0, 0.0], Q])
        if count_inverted(X, T):
            continue
        cert = local_certificate(X, T)
        covered = _max_cover(X, T, 0, dirs)
        if covered >= 2:
            assert not cert.ok
        if cert.ok:
            assert covered <= 1
        seen[cert.ok] += 1
    assert seen[True] > 10 and seen[False] > 10, seen


def test_a_map_certified_again_unchanged_is_not_recomputed_and_a_changed_one_is(monkeypatch):
    """local_certificate remembers its last answers by the content of its inputs: the same bytes
    (the untangled map, then the file written from it and read back) are not certified twice,
    while the same array changed in place, or another orientation, is certified anew."""
    import collections

    import geomopt.exact.certify as C

    monkeypatch.setattr(C, "_RECENT", collections.OrderedDict())  # nothing remembered from other tests
    V, T = cylinder()[:2]
    _, _, X, _ = wrapped_cylinder(2.0)  # positive tets, branch edges on the axis
    calls = []
    real = C.star_overlaps_3d
    monkeypatch.setattr(C, "star_overlaps_3d", lambda *a: calls.append(1) or real(*a))
    first = local_certificate(X, T)
    again = local_certificate(X.copy(), T.copy())  # equal bytes, other arrays
    assert len(calls) == 1 and not again.ok
    assert np.array_equal(again.branch_edges, first.branch_edges) and again.message == first.message
    again.branch_edges[:] = -1  # the copy handed out is the caller's own
    assert (local_certificate(X, T).branch_edges >= 0).all()
    Y = X.copy()
    local_certificate(Y, T)
    Y[:] = V  # the same array object, now the rest mesh: certified, not the remembered answer
    assert local_certificate(Y, T).ok and len(calls) == 2
    assert local_certificate(V, T[:, [1, 0, 2, 3]], orientation=-1).ok  # another key
    assert local_certificate(V, T[:, [1, 0, 2, 3]]).inverted == len(T)

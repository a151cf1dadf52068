"""Spherical maps of closed genus-0 meshes (geomopt.sphere_map): the certified start, the
optimised map, the exact certificate (flips and double covers rejected), refused inputs, the
energy's gradient and the command line."""

import json
import logging
import subprocess
import sys

import jax
import numpy as np
import pytest

import geomopt
from geomopt import MeshError, ParameterError
from geomopt.exact.certify import certify_sphere
from geomopt.io import read_mesh
from geomopt.mesh.problem import Problem
from geomopt.sphere import sphere_distortion, sphere_start, stereographic
from geomopt.solvers import Outcome


def hull(points):
    """The convex hull of ``points`` (k, 3) as an outward-oriented closed genus-0 mesh."""
    from scipy.spatial import ConvexHull

    h = ConvexHull(points)
    F = h.simplices.copy()
    centre = points[h.vertices].mean(axis=0)
    P = points[F]
    out = np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), P[:, 0] - centre) < 0
    F[out] = F[out][:, [0, 2, 1]]
    used = np.unique(F)
    new = np.full(len(points), -1)
    new[used] = np.arange(len(used))
    return points[used], new[F]


def random_hull(seed, n=60):
    rng = np.random.default_rng(seed)
    return hull(rng.normal(size=(n, 3)) * [1.0, 0.7, 0.4])


def dented(seed=3):
    """A non-convex genus-0 mesh: a subdivided ellipsoid hull with a deep dent pushed in."""
    import trimesh

    m = trimesh.creation.icosphere(2)
    V = m.vertices * [1.3, 0.8, 0.6]
    V = V * (1.0 - 0.7 * np.exp(-8.0 * np.sum((m.vertices - [0, 0, 1]) ** 2, axis=1)))[:, None]
    return V, np.asarray(m.faces)


def tube(rings, sections=12):
    """A closed genus-0 tube: ``rings`` rings of ``sections`` vertices on a unit cylinder, each
    ring turned by half a section, one apex closing each end (a long limb, by connectivity)."""
    h = 2 * np.pi / sections
    t = h * (np.arange(rings)[:, None] * 0.5 + np.arange(sections)[None, :])
    V = np.stack([np.repeat(np.arange(rings) * h, sections), np.cos(t).ravel(), np.sin(t).ravel()], axis=1)
    V = np.vstack([V, [[-h, 0.0, 0.0], [rings * h, 0.0, 0.0]]])
    i, j = np.meshgrid(np.arange(rings - 1), np.arange(sections), indexing="ij")
    p, q = (i * sections + j).ravel(), (i * sections + (j + 1) % sections).ravel()
    a, b, j = len(V) - 2, len(V) - 1, np.arange(sections)
    last = (rings - 1) * sections
    F = np.vstack([np.stack([p, q + sections, q], 1), np.stack([p, p + sections, q + sections], 1),
                   np.stack([np.full(sections, a), j, (j + 1) % sections], 1),
                   np.stack([np.full(sections, b), last + (j + 1) % sections, last + j], 1)])
    return V, F


def test_the_start_spreads_what_a_harmonic_map_crowds(monkeypatch):
    # Tutte's map crowds the far end of a long tube exponentially (start energy ~1e7 here); the
    # reweighted rounds bring it down by orders of magnitude, still certified
    import geomopt.sphere as sphere

    V, F = tube(30)
    x, details = sphere_start(V, F)
    assert certify_sphere(x, F).ok and details.balance_round > 0
    monkeypatch.setattr(sphere, "BALANCE_ROUNDS", 0)
    monkeypatch.setattr(sphere, "BALANCE_ROUNDS_CROWDED", 0)  # the plain Tutte map, however crowded
    plain, plain_details = sphere_start(V, F)
    assert plain_details.balance_round == 0
    balanced_sd = sphere_distortion(V, F, x)["symmetric_dirichlet"]
    plain_sd = sphere_distortion(V, F, plain)["symmetric_dirichlet"]
    assert plain_sd > 1e6 and balanced_sd < 1e-4 * plain_sd


def test_a_long_limb_maps_onto_the_sphere(caplog):
    caplog.set_level(logging.DEBUG, logger="geomopt")
    # tangent steps lengthen the vertices they move: without putting the map back on the sphere
    # this solve ended DIVERGED (vertices 10^6 long) at a mean energy of 18
    V, F = tube(60)
    res = geomopt.sphere_map(V, F, progress=True)
    assert res.success and certify_sphere(res.x, F).ok
    assert res.mean_energy < 25.0
    # each return to the sphere is a progress line (the iterations count from 1 again after it)
    err = "\n".join(r.getMessage() for r in caplog.records)
    phases = [line for line in err.splitlines() if "back on the sphere" in line]
    assert phases and len(phases) == err.count("iter    1 ") - 1, err[-3000:]


@pytest.mark.parametrize("seed", range(6))
def test_start_is_certified_on_random_hulls(seed):
    V, F = random_hull(seed)
    x, details = sphere_start(V, F)
    cert = certify_sphere(x, F)
    assert cert.ok and cert.inverted == 0 and cert.degree == 1
    assert np.allclose(np.linalg.norm(x, axis=1), 1.0)
    assert details.start_certificate.ok


def test_start_is_certified_on_a_non_convex_mesh():
    V, F = dented()
    x, _ = sphere_start(V, F)
    assert certify_sphere(x, F).ok


def test_optimised_map_is_certified_and_lowers_the_energy():
    V, F = dented()
    res = geomopt.sphere_map(V, F, progress=False)
    assert res.success and res.outcome is Outcome.CONVERGED and res.injectivity == "global"
    assert res.x.shape == V.shape and np.allclose(np.linalg.norm(res.x, axis=1), 1.0, atol=1e-14)
    assert certify_sphere(res.x, F).ok
    start = sphere_distortion(V, F, res.details.start)["symmetric_dirichlet"]
    end = sphere_distortion(V, F, res.x)["symmetric_dirichlet"]
    assert end < start and abs(end - res.mean_energy) < 1e-9 * end
    assert 4.0 <= end < 5.0


@pytest.mark.parametrize("scale", [1e-9, 1e9])
def test_the_map_does_not_depend_on_the_inputs_units(scale):
    """The rest triangles are scaled to the sphere's area: a mesh in other units gives the same
    map (a mesh 1e6 times larger once failed the divergence test: its rest extent was taken
    as the unit of a map on the unit sphere)."""
    V, F = dented()
    unit = geomopt.sphere_map(V, F, progress=False)
    res = geomopt.sphere_map(V * scale, F, progress=False)
    assert res.success and certify_sphere(res.x, F).ok
    assert abs(res.mean_energy - unit.mean_energy) < 1e-6 * unit.mean_energy


def test_certificate_rejects_a_flipped_triangle():
    V, F = random_hull(0)
    x, _ = sphere_start(V, F)
    v = F[0, 0]
    others = np.unique(F[np.any(F == v, axis=1)])
    x = x.copy()
    x[v] = -x[others[others != v]].mean(axis=0)  # dragged across the sphere: its fan folds
    cert = certify_sphere(x, F)
    assert cert.inverted >= 1 and not cert.ok and not cert.locally_injective
    assert "inverted" in cert.message


def test_a_given_start_must_certify():
    V, F = random_hull(5, 40)
    x, _ = sphere_start(V, F)
    R = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    R = R * np.sign(np.linalg.det(R))  # a rotation keeps the certificate
    res = geomopt.sphere_map(V, F, x0=2.0 * x @ R.T, progress=False)
    assert res.success and np.allclose(res.details.start, x @ R.T)
    x[F[0, 0]] = -x[F[0, 0]]  # folded
    with pytest.raises(MeshError, match="start map x0 is not a bijection"):
        geomopt.sphere_map(V, F, x0=x, progress=False)


def double_cover(k=10, rings=8):
    """A latitude-longitude sphere mesh (poles of degree ``k``) and its image under ``z -> z^2``
    (stereographic coordinates): every triangle positive, the sphere covered twice."""
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, k, endpoint=False)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    V = np.concatenate([[[0, 0, 1]], np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
                        .reshape(-1, 3), [[0, 0, -1]]])
    ring = lambda i, j: 1 + i * k + j % k  # noqa: E731
    F = [[0, ring(0, j), ring(0, j + 1)] for j in range(k)]
    for i in range(rings - 2):
        for j in range(k):
            F += [[ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)], [ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]]
    F += [[len(V) - 1, ring(rings - 2, j + 1), ring(rings - 2, j)] for j in range(k)]
    F = np.asarray(F)
    # z -> z^2 on the Riemann sphere: latitude angle t -> 2 atan(tan(t/2)^2), longitude doubled
    t = np.arccos(np.clip(V[:, 2], -1, 1))
    t2 = 2 * np.arctan(np.tan(t / 2) ** 2)
    p2 = 2 * np.arctan2(V[:, 1], V[:, 0])
    X = np.stack([np.sin(t2) * np.cos(p2), np.sin(t2) * np.sin(p2), np.cos(t2)], -1)
    return V, F, X


def test_certificate_rejects_a_double_cover():
    V, F, X = double_cover()
    assert certify_sphere(V, F).ok  # the mesh itself, on the sphere
    cert = certify_sphere(X, F)
    assert cert.inverted == 0  # every triangle positive ...
    assert cert.degree == 2 and not cert.ok and "2 times" in cert.message  # ... yet the sphere covered twice
    assert abs(cert.area - 8 * np.pi) < 1e-9


def test_stereographic_orientation():
    """Counter-clockwise planar triangles turn counter-clockwise seen from outside."""
    from geomopt.exact.predicates import cone_orientations

    p = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
    assert cone_orientations(stereographic(p), np.array([[0, 1, 2]]))[0] == 1


@pytest.mark.parametrize("case", ["torus", "boundary", "nonmanifold", "zero_area", "two_spheres", "pillow"])
def test_refuses_anything_but_a_closed_genus0_manifold(case):
    import trimesh

    s = trimesh.creation.icosphere(1)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    if case == "torus":
        t = trimesh.creation.torus(1.0, 0.4, major_sections=12, minor_sections=8)
        V, F = np.asarray(t.vertices), np.asarray(t.faces)
    elif case == "boundary":
        F = F[1:]
    elif case == "nonmanifold":
        V = np.vstack([V, [[2.0, 2.0, 2.0]]])
        F = np.vstack([F, [[F[0, 0], F[0, 1], len(V) - 1]]])
    elif case == "zero_area":
        V = V.copy()
        a, b, c = F[0]
        V[c] = 0.5 * (V[a] + V[b])
    elif case == "pillow":  # closed, genus 0, but two triangles on three vertices
        V, F = np.eye(3), np.array([[0, 1, 2], [0, 2, 1]])
    else:
        V, F = np.vstack([V, V + 3.0]), np.vstack([F, F + len(V)])
    with pytest.raises(MeshError) as info:
        geomopt.sphere_map(V, F, progress=False)
    assert "\n" not in str(info.value)
    words = {"torus": "genus 1", "boundary": "boundary", "nonmanifold": "non-manifold", "zero_area": "zero size",
             "two_spheres": "components", "pillow": "only 3 vertices"}
    assert words[case] in str(info.value)


def test_refuses_a_hessian_solver_and_a_collapsing_energy():
    V, F = random_hull(1, 20)
    with pytest.raises(ParameterError, match="L-BFGS"):
        geomopt.sphere_map(V, F, solver="newton", progress=False)
    with pytest.raises(ParameterError, match="shrinks"):
        geomopt.sphere_map(V, F, energy="dirichlet", progress=False)
    obj = geomopt.Objective(Problem.sphere(V, F), "symmetric_dirichlet")  # by hand: the objective says it too
    with pytest.raises(ParameterError, match="no assembled Hessian"):
        geomopt.minimize(obj, sphere_start(V, F)[0], "newton", progress=False)


def test_energy_gradient_matches_finite_differences():
    from geomopt import Objective

    V, F = random_hull(2, 30)
    x, _ = sphere_start(V, F)
    rng = np.random.default_rng(0)
    x = x * rng.uniform(0.8, 1.3, size=(len(x), 1))  # off the sphere: lengths must not matter
    obj = Objective(Problem.sphere(V, F), "symmetric_dirichlet")
    with jax.enable_x64(True):
        _, g = obj.value_and_grad(x)
        g = np.asarray(g) * obj.free_dofs
        d = rng.normal(size=x.shape) * obj.free_dofs
        h = 1e-6
        fd = (float(obj.value(x + h * d)) - float(obj.value(x - h * d))) / (2 * h)
        assert abs(fd - np.sum(g * d)) <= 1e-6 * abs(fd)
        # scale invariance: the gradient is tangent (orthogonal to each vertex's direction)
        assert np.abs(np.einsum("ij,ij->i", g, x)).max() <= 1e-8 * np.abs(g).max()
        assert abs(float(obj.value(x)) - float(obj.value(x / np.linalg.norm(x, axis=1, keepdims=True)))) < 1e-9 * float(
            obj.value(x))


def test_cli_writes_the_sphere_obj(tmp_path):
    V, F = dented()
    src, out = tmp_path / "dent.off", tmp_path / "dent_sphere.obj"
    with open(src, "w") as fh:
        fh.write(f"OFF\n{len(V)} {len(F)} 0\n")
        np.savetxt(fh, V, fmt="%.17g")
        np.savetxt(fh, np.column_stack([np.full(len(F), 3), F]), fmt="%d")
    run = subprocess.run([sys.executable, "-m", "geomopt", "param", str(src), "--sphere", "-o", str(out), "--quiet",
                          "--json"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert {"cache_dir", "cache_hits", "cache_misses"} <= set(summary)  # as a disk's: what compiled
    timing = summary["timing"]  # the map's own phases, not "other"
    assert timing["solve"] > 0 and timing["setup"] > 0 and timing["other"] < 0.5 * timing["total"]
    X, G = read_mesh(out)
    assert np.array_equal(G, F) and np.allclose(np.linalg.norm(X, axis=1), 1.0, atol=1e-14)
    assert certify_sphere(X, G).ok


def test_sphere_figure_draws_the_map():
    from geomopt import plot

    V, F = random_hull(4, 40)
    x, _ = sphere_start(V, F)
    fig = plot.sphere_figure(V, F, x, dpi=20)
    image = np.asarray(fig.axes[2].images[0].get_array())  # the sphere, coloured by area ratio
    covered = image[..., 3] > 0.99
    hue = image[..., 0][covered] - image[..., 2][covered]  # coolwarm: red above 1, blue below (grey: 0)
    assert len(fig.axes) == 4 and covered.sum() > 1000 and hue.max() > 0.1 and hue.min() < -0.1


def test_cli_refuses_a_torus_with_one_line(tmp_path):
    import trimesh

    t = trimesh.creation.torus(1.0, 0.4, major_sections=12, minor_sections=8)
    src, out = tmp_path / "torus.obj", tmp_path / "out.obj"
    t.export(src)
    run = subprocess.run([sys.executable, "-m", "geomopt", "param", str(src), "--sphere", "-o", str(out), "--quiet"],
                         capture_output=True, text=True)
    assert run.returncode == 2 and not out.exists()
    assert run.stderr.strip().count("\n") == 0 and "genus 1" in run.stderr


def test_cli_refuses_options_a_sphere_map_cannot_take(tmp_path, cli):
    import trimesh

    src, out = tmp_path / "ball.obj", tmp_path / "out.obj"
    trimesh.creation.icosphere(1).export(src)
    for extra in (["--atlas"], ["--bijective"], ["--uv-range", "unit"]):
        code, _, err = cli("param", src, "--sphere", "-o", out, "--quiet", *extra)
        assert code == 2 and not out.exists() and extra[0] in err and err.strip().count("\n") == 0

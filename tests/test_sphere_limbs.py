"""Sphere maps of long-limbed bodies and the sphere certificate's failure paths (issue 48 items
4 and 10).

A harmonic (Tutte) map crowds a limb exponentially in its length over its girth; on a body
with four long limbs and a head the crowding passes float64, and the start used to collapse
the map onto a point, shrink every weight by ~1e-75 a round until they underflowed and end in
an internal error ("sparse pattern: column 0 is empty").
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

import geomopt
import geomopt.cli
import geomopt.sphere as sphere
from geomopt import MeshError, Outcome, ParameterError
from geomopt.exact.certify import certify_sphere
from geomopt.exact.topology import boundary_loops, check_sphere
from geomopt.sphere import candidate_poles, sphere_start


def limbed_body(limbs, subdivisions=3, rings=60, torso=(1.0, 0.6, 1.6)):
    """A closed genus-0 body: an ellipsoidal torso (an icosphere) with a tube extruded from a
    cap for each limb ``(direction (3,), cap angle in degrees, length, girth)``: ``rings`` rings
    out to ``length``, narrowing to ``girth`` times the cap's radius, the cap moved to the end.
    Returns V (n, 3), F (m, 3), outward oriented."""
    m = trimesh.creation.icosphere(subdivisions)
    V, F, unit = m.vertices * np.asarray(torso), m.faces.copy(), m.vertices.copy()
    for direction, angle, length, girth in limbs:
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        centres = unit[F].mean(axis=1)
        cap = centres @ d > np.linalg.norm(centres, axis=1) * np.cos(np.radians(angle))
        (B,) = boundary_loops(F[cap])  # the cap is a disk: one loop, in its faces' direction
        base, k = V[B].mean(axis=0), len(B)
        ring_ids, new = [B], []
        for j in range(1, rings + 1):
            t = j / rings
            new.append(base + (V[B] - base) * (1 - (1 - girth) * min(1.0, 4 * t)) + length * t * d)
            ring_ids.append(len(V) + k * (j - 1) + np.arange(k))
        inner = np.setdiff1d(np.unique(F[cap]), B)
        V = np.concatenate([V] + new)
        V[inner] = base + (V[inner] - base) * girth + length * d
        unit = np.concatenate([unit, np.repeat(d[None], len(V) - len(unit), axis=0)])
        remap = np.arange(len(V))
        remap[B] = ring_ids[-1]
        sides = [np.concatenate([np.stack([lo, np.roll(lo, -1), np.roll(hi, -1)], 1),
                                 np.stack([lo, np.roll(hi, -1), hi], 1)]) for lo, hi in zip(ring_ids, ring_ids[1:])]
        F = np.concatenate([F[~cap], remap[F[cap]]] + sides)
    return V, F


def body(length=10.0, rings=90, girth=0.5, cap=14, subdivisions=3, spread=0.3):
    """Two arms (0.8 ``length``), two legs and a short head on a torso: SMPL-like, longer."""
    limbs = [((1, 0, 0.1), cap, 0.8 * length, girth), ((-1, 0, 0.1), cap, 0.8 * length, girth),
             ((spread, 0, -1), cap, length, girth), ((-spread, 0, -1), cap, length, girth), ((0, 0, 1), 20, 1.2, 0.9)]
    return limbed_body(limbs, subdivisions, rings)


def test_the_generated_body_is_a_closed_genus0_surface_with_long_limbs():
    V, F = body()
    check_sphere(F, len(V))
    mesh = trimesh.Trimesh(V, F, process=False)
    assert 5_000 <= len(F) <= 15_000 and mesh.is_watertight and mesh.volume > 0
    assert np.ptp(V[:, 2]) > 10.0 and np.ptp(V[:, 0]) > 15.0


# ------------------------------------------------------------------ the start of long limbs


def test_a_long_limbed_body_gets_a_certified_start():
    """14,240 triangles: the harmonic map flattens 1,000+ triangles of the limbs' ends to
    rounding in the plane; it was an internal error (ValueError), now a certified start."""
    V, F = body()
    x, details = sphere_start(V, F)
    assert certify_sphere(x, F).ok and details.start_certificate.ok and details.balance_round > 0


def test_a_long_limbed_body_maps_onto_the_sphere():
    """A coarser body past the same limit (4,320 triangles; an internal error before): the start
    certifies and L-BFGS lowers the energy, every iterate a certified bijection."""
    V, F = body(length=6.0, rings=40, cap=24, subdivisions=2, spread=0.5)
    with pytest.warns(Warning, match="iteration limit"):
        res = geomopt.sphere_map(V, F, solver=geomopt.LBFGS(gtol=0.0, rtol=1e-6, window=20, max_steps=150),
                                 progress=False)
    assert res.outcome in (Outcome.CONVERGED, Outcome.MAX_STEPS) and res.certificate.ok
    start = sphere.sphere_distortion(V, F, res.details.start)["symmetric_dirichlet"]
    assert res.mean_energy < 0.5 * start


def test_a_start_collapsed_onto_a_point_stops_with_a_clear_error(monkeypatch):
    """The stereographic scale forced to 1e-200 (the mesh shrunk onto the north pole, as a
    float-degenerate triangle once made it): every estimate is infinite, so the rounds stop
    after BALANCE_PATIENCE of them; the weights are renormalised (their largest 1, never
    underflowing to 0); no pole certifies, and the error says so in one line."""
    V, F = body(length=2.0, rings=8, cap=24, subdivisions=2, spread=0.5)
    sphere_start(V, F)  # certifies at its own scale
    largest, calls = [], []
    real = sphere.weighted_embedding
    monkeypatch.setattr(sphere, "_stereo_scale", lambda P, rest, share: 1e-200)
    monkeypatch.setattr(sphere, "MAX_HALVINGS", 2)

    def recording(W, loop, circle):
        largest.append(float(W.max()))
        calls.append(1)
        return real(W, loop, circle)

    monkeypatch.setattr(sphere, "weighted_embedding", recording)
    with pytest.raises(MeshError, match="no certified start map onto the sphere from poles") as err:
        sphere_start(V, F)
    assert "\n" not in str(err.value)
    poles = len(candidate_poles(F, len(V)))
    assert len(calls) == poles * (sphere.BALANCE_PATIENCE + 1)  # each pole: round 0 and PATIENCE more
    assert min(largest) == 1.0  # renormalised: round 0's uniform weights are 1 too


def test_the_cap_bound_leaves_out_triangles_flat_in_the_plane():
    P = np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 0.5], [0.25, 0.25], [0.5, 0.5]])
    good = np.array([[0, 1, 2]])
    flat = np.array([[1, 3, 2]])  # (0.5, 0), (0.25, 0.25), (0, 0.5): collinear
    bound = sphere._cap_bound(P, good)
    assert np.isfinite(bound) and sphere._cap_bound(P, np.r_[good, flat]) == bound
    assert sphere._flat_in_plane(P, np.r_[good, flat]) == 1 and sphere._flat_in_plane(P, good) == 0


# ------------------------------------------------------------------ poles


def test_candidate_poles_start_at_the_highest_degree_then_the_middle_then_spread():
    V, F = body(length=6.0, rings=40, cap=24, subdivisions=2, spread=0.5)
    poles = candidate_poles(F, len(V))
    degree = np.bincount(F.ravel())
    assert len(poles) == len(set(poles)) == sphere.POLE_TRIES and degree[poles[0]] == degree.max()
    assert np.abs(V[poles[1]]).max() < 2.0  # the middle of the longest path: on the torso
    assert max(np.abs(V[p]).max() for p in poles[2:]) > 4.0  # the ends of limbs


def test_another_pole_is_tried_when_the_first_start_does_not_certify(monkeypatch):
    V, F = body(length=2.0, rings=8, cap=24, subdivisions=2, spread=0.5)
    first, second = candidate_poles(F, len(V))[:2]
    real = sphere._start_at
    monkeypatch.setattr(sphere, "_start_at", lambda V, F, n, pole, w: None if pole == first else real(V, F, n, pole, w))
    x, details = sphere_start(V, F)
    assert details.pole == second and certify_sphere(x, F).ok
    with pytest.raises(MeshError, match=f"from pole {first} .*try another pole"):
        sphere_start(V, F, pole=first)  # a pole the user chose is the only one tried


@pytest.mark.parametrize("pole", [-1, 10**6, 1.5, "3"])
def test_a_pole_that_is_not_a_vertex_id_is_refused(pole):
    V, F = body(length=2.0, rings=8, cap=24, subdivisions=2, spread=0.5)
    with pytest.raises(ParameterError, match="pole"):
        geomopt.sphere_map(V, F, options=sphere.SphereOptions(pole=pole), progress=False)


def _write_body(path):
    V, F = body(length=2.0, rings=8, cap=24, subdivisions=2, spread=0.5)
    trimesh.Trimesh(V, F, process=False).export(path)
    return V, F


def test_cli_pole_puts_that_vertex_at_the_south_pole(tmp_path, capsys):
    V, F = _write_body(tmp_path / "body.obj")
    out = tmp_path / "sphere.obj"
    code = geomopt.cli.main(["param", str(tmp_path / "body.obj"), "--sphere", "--pole", "7", "-o", str(out),
                             "--quiet", "--json", "--max-steps", "20"])
    summary = json.loads(capsys.readouterr().out)
    assert summary["pole"] == 7 and code in (0, 1)
    default = sphere_start(V, F)[1].pole
    assert default != 7


@pytest.mark.parametrize("argv, message", [
    (["--sphere", "--pole", "100000"], "--pole 100000: .* has \\d+ vertices, 0-based ids 0 to"),
    (["--sphere", "--pole", "-1"], "must be a 0-based vertex id"),
    (["--sphere", "--pole", "x"], "must be a 0-based vertex id"),
    (["--pole", "3"], "--pole goes with --sphere"),
])
def test_cli_refuses_a_bad_pole_with_one_line(tmp_path, capsys, argv, message):
    import re

    _write_body(tmp_path / "body.obj")
    out = tmp_path / "out.obj"
    try:
        code = geomopt.cli.main(["param", str(tmp_path / "body.obj"), "-o", str(out), "--quiet"] + argv)
    except SystemExit as usage:  # argparse's own errors
        code = usage.code
    err = capsys.readouterr().err
    assert code == 2 and re.search(message, err), err
    assert not out.exists()


# ------------------------------------------------------------------ the certificate's failure paths


def _octahedron_split(p):
    """The unit octahedron with face (0, 1, 2) split at a vertex 6 placed at ``p`` (3,)."""
    V = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1], p], float)
    F = np.array([[0, 1, 6], [1, 2, 6], [2, 0, 6], [0, 2, 3], [0, 3, 4], [0, 4, 1], [5, 2, 1], [5, 3, 2],
                  [5, 4, 3], [5, 1, 4]])
    return V, F


def test_a_triangle_flat_on_a_great_circle_fails_the_sphere_certificate():
    V, F = _octahedron_split(np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0))
    assert certify_sphere(V, F).ok  # inside the face: a bijection
    V, F = _octahedron_split(np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0))  # on the arc of edge 0-1: y = 0 exactly
    cert = certify_sphere(V, F)
    assert abs(cert.area - 4 * np.pi) < 1e-12  # the areas alone still cover the sphere once
    assert not cert.ok and cert.inverted == 1 and cert.first_inverted == 0


def test_sphere_map_is_not_a_success_when_its_final_certificate_fails(monkeypatch):
    """The certificate of the final map forced to fail (the start's is real): CONVERGED is
    demoted to NOT_INJECTIVE with the certificate's message, and throw raises."""
    import dataclasses

    V, F = _octahedron_split(np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0))
    armed = []
    real_certify, real_start = sphere.certify_sphere, sphere.sphere_start

    def certify(x, F):
        cert = real_certify(x, F)
        return dataclasses.replace(cert, inverted=1, first_inverted=0, degree=0) if armed else cert

    def start(*args, **kwargs):
        found = real_start(*args, **kwargs)
        armed.append(True)
        return found

    monkeypatch.setattr(sphere, "certify_sphere", certify)
    monkeypatch.setattr(sphere, "sphere_start", start)
    res = geomopt.sphere_map(V, F, progress=False)
    assert res.outcome is Outcome.NOT_INJECTIVE and not res.success and "inverted" in res.message
    armed.clear()
    with pytest.raises(geomopt.SolveError):
        geomopt.sphere_map(V, F, progress=False, throw=True)


def test_a_tail_crowded_past_float64_gets_more_rounds():
    """One limb 130 times longer than thick (7,520 triangles): with mean-value weights every one
    of BALANCE_ROUNDS bounded rounds still leaves triangles flat in the plane; up to
    BALANCE_ROUNDS_CROWDED rounds spread it into a certified start."""
    V, F = limbed_body([((0, 0, -1), 14, 40.0, 0.3)], subdivisions=3, rings=260)
    x, details = sphere_start(V, F, weights="mean_value")
    assert certify_sphere(x, F).ok and details.balance_round > sphere.BALANCE_ROUNDS


def test_a_start_far_from_balanced_gets_more_rounds():
    """A tail 100 times longer than thick (6,080 triangles): after BALANCE_ROUNDS rounds its
    certified start had a mean symmetric Dirichlet of 2.7e22 and L-BFGS failed its first line
    search; rounds go on while the estimate is above CROWDED_ESTIMATE."""
    V, F = limbed_body([((0, 0, -1), 14, 30.0, 0.3)], subdivisions=3, rings=200)
    x, details = sphere_start(V, F)
    assert details.balance_round > sphere.BALANCE_ROUNDS
    assert sphere.sphere_distortion(V, F, x)["symmetric_dirichlet"] < 1e10

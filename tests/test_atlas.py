"""Atlases of surfaces that are not disks (issue 31): every chart a disk, the seams exactly the
cut edges, the packed atlas certified with no mirrored chart, the OBJ keeping the input's ``v``
lines and face order, bad input refused with one line, a disk kept as one chart."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from geomopt import MeshError
from geomopt.atlas import AtlasOptions, make_atlas
from geomopt.mesh.generators import disk_mesh, holed_plate
from geomopt.exact.topology import boundary_half_edges, check_disk, unique_edges


def torus():
    t = trimesh.creation.torus(1.0, 0.4, major_sections=16, minor_sections=8)
    return np.asarray(t.vertices), np.asarray(t.faces)


def genus2():
    """The 2-hole plate, subdivided and smoothed: a rounded genus-2 surface."""
    V, F = holed_plate(2, cells=1)
    V, F = trimesh.remesh.subdivide_loop(V, F, iterations=1)
    m = trimesh.Trimesh(V, F, process=False)
    trimesh.smoothing.filter_taubin(m, iterations=10)
    return np.asarray(m.vertices), np.asarray(m.faces)


def sphere():
    s = trimesh.creation.icosphere(2)
    return np.asarray(s.vertices) * [1.0, 1.3, 0.8], np.asarray(s.faces)


def three_loops():
    """A sphere with the faces around three vertices removed: three boundary loops."""
    V, F = sphere()
    F = F[~np.isin(F, [0, 5, 9]).any(axis=1)]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def two_components():
    (V1, F1), (V2, F2) = sphere(), torus()
    return np.r_[V1, V2 + [4.0, 0.0, 0.0]], np.r_[F1, F2 + len(V1)]


def tetrahedron():
    """The smallest closed surface: every vertex pair is an edge, so no cut path has two edges."""
    return np.eye(4, 3, -1), np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


CASES = {"tetrahedron": tetrahedron, "torus": torus, "genus2": genus2, "sphere": sphere, "three_loops": three_loops,
         "two_components": two_components}


@pytest.fixture(scope="module", params=list(CASES))
def made(request):
    V, F = CASES[request.param]()
    r = make_atlas(V, F, progress=False)
    return V, F, r


def test_every_chart_is_a_disk_and_the_atlas_is_certified(made):
    V, F, a = made
    assert a.success and a.certificate.ok, a.message
    assert a.details.metrics.mirrored_charts == 0
    assert np.all((a.x >= 0) & (a.x <= 1))
    assert np.array_equal(a.details.vertex[a.details.uv_faces], F)  # every UV row maps back to its input vertex
    for c in range(a.details.metrics.charts):
        rows, local = np.unique(a.details.uv_faces[a.details.chart == c], return_inverse=True)
        check_disk(local.reshape(-1, 3), len(rows))  # raises unless a disk
        Q = a.x[a.details.uv_faces[a.details.chart == c]]
        signed = (Q[:, 1, 0] - Q[:, 0, 0]) * (Q[:, 2, 1] - Q[:, 0, 1]) - (Q[:, 1, 1] - Q[:, 0, 1]) * (Q[:, 2, 0] - Q[:, 0, 0])
        assert np.all(signed > 0)


def test_the_seams_are_exactly_the_cut_edges(made):
    V, F, a = made
    uv_of = {}  # (face, input vertex) -> UV row
    for f in range(len(F)):
        for k in range(3):
            uv_of[f, F[f, k]] = a.details.uv_faces[f, k]
    faces_of = {}
    for f in range(len(F)):
        for k in range(3):
            faces_of.setdefault(tuple(sorted((F[f, k], F[f, (k + 1) % 3]))), []).append(f)
    cut = {e for e, fs in faces_of.items() if len(fs) == 2
           and any(uv_of[fs[0], v] != uv_of[fs[1], v] for v in e)}
    assert cut == {tuple(e) for e in a.details.seams.tolist()}
    # a seam separates the UVs of both its ends, and is a chart boundary edge on both sides
    T = a.details.uv_faces
    open_edges = {tuple(sorted(e)) for e in a.details.vertex[boundary_half_edges(T)].tolist()}
    input_boundary = {tuple(sorted(e)) for e in boundary_half_edges(F).tolist()}
    assert open_edges == cut | input_boundary
    assert a.details.metrics.seam_length == pytest.approx(sum(np.linalg.norm(V[i] - V[j]) for i, j in cut))


def test_a_reversed_surface_still_has_no_mirrored_chart():
    V, F = torus()
    a = make_atlas(V, F[:, ::-1], progress=False)
    assert a.success and a.details.metrics.mirrored_charts == 0


def test_bad_input_is_refused_with_one_line(cli, tmp_path):
    V, F = sphere()
    nonmanifold = np.r_[F, [[F[0, 0], F[0, 1], len(V)]]]
    a, b = sorted(F[0, :2])
    with pytest.raises(MeshError, match=f"non-manifold edge.*first: the edge of vertices {a} and {b}, in 3 faces"):
        make_atlas(np.r_[V, [[5.0, 5.0, 5.0]]], nonmanifold, progress=False)
    with pytest.raises(MeshError, match=f"non-manifold edge.*; 1 face\\(s\\) repeat another's vertices \\(first: "
                                        f"face {len(F)} repeats face 4\\)"):
        make_atlas(V, np.r_[F, F[4:5, ::-1]], progress=False)  # a face repeated, reversed (a pillow)
    flat = V.copy()
    flat[F[3, 2]] = 0.5 * (flat[F[3, 0]] + flat[F[3, 1]])  # a triangle collapsed to a segment
    with pytest.raises(MeshError, match="zero area"):
        make_atlas(flat, F, progress=False)
    for name, (W, G) in {"nm": (np.r_[V, [[5.0, 5.0, 5.0]]], nonmanifold), "flat": (flat, F)}.items():
        mesh = _write_obj(tmp_path / f"{name}.off.obj", W, G)
        code, _, err = cli("param", mesh, "-o", tmp_path / f"{name}.obj", "--quiet")
        assert code == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("geomopt: error: "), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flat.off.obj", "nm.off.obj"]  # nothing written


def _write_obj(path, V, F):
    """An OBJ of ``V``, ``F`` with every bit of the coordinates."""
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in np.asarray(V).tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in np.asarray(F).tolist()))
    return path


def read_obj_corners(path):
    """``(v (n, 3), vt (t, 2), f (m, k, 2))``: an OBJ's vertices, texture coordinates and each face's
    (vertex, vt) per corner, as written (no checks: the tests read what geomopt wrote)."""
    v, vt, f = [], [], []
    for line in path.read_text().splitlines():
        t = line.split()
        if t and t[0] in ("v", "vt"):
            (v if t[0] == "v" else vt).append([float(x) for x in t[1:]])
        elif t and t[0] == "f":
            f.append([[int(i) - 1 for i in c.split("/")] for c in t[1:]])
    return np.array(v), np.array(vt), np.array(f)


def test_the_obj_keeps_the_v_lines_and_the_face_order(cli, tmp_path):
    V, F = torus()
    mesh = _write_obj(tmp_path / "torus.obj", V, F)
    code, out, _ = cli("param", mesh, "-o", tmp_path / "atlas.obj", "--json", "--quiet")
    summary = json.loads(out)
    assert code == 0 and summary["atlas"] is True
    assert {"cache_dir", "cache_hits", "cache_misses"} <= set(summary)  # as a disk's: what compiled
    # the atlas's stages in the timing split: they add up to its own seconds
    stages = [summary["timing"][k] for k in ("cut", "flatten", "pack")]
    assert all(x > 0 for x in stages) and summary["timing"]["write"] > 0
    assert abs(sum(stages) - summary["seconds"]) < 0.05 * summary["seconds"] + 0.05
    v, vt, f = read_obj_corners(tmp_path / "atlas.obj")
    assert np.array_equal(v, V) and np.array_equal(f[:, :, 0], F)
    assert len(vt) > len(V) and np.all((vt >= 0) & (vt <= 1))  # a closed surface needs seams
    a = make_atlas(V, F, progress=False)
    assert np.array_equal(vt, a.x) and np.array_equal(f[:, :, 1], a.details.uv_faces)


def test_a_disk_keeps_one_chart_unless_atlas_is_asked(cli, tmp_path):
    V2, F = disk_mesh(4)
    V = np.c_[V2, 0.2 * V2[:, 0] ** 2]
    mesh = _write_obj(tmp_path / "disk.obj", V, F)
    code, out, _ = cli("param", mesh, "-o", tmp_path / "one.obj", "--json", "--quiet")
    assert code == 0 and "atlas" not in json.loads(out)
    v, vt, f = read_obj_corners(tmp_path / "one.obj")
    assert len(vt) == len(V) and np.array_equal(f[:, :, 1], f[:, :, 0])  # one vt per vertex: one chart
    code, out, _ = cli("param", mesh, "-o", tmp_path / "atlas.obj", "--atlas", "--margin", "0.02", "--json", "--quiet")
    summary = json.loads(out)
    assert code == 0 and summary["atlas"] is True and summary["certified"] is True
    _, vt, _ = read_obj_corners(tmp_path / "atlas.obj")
    assert np.all((vt >= 0.0) & (vt <= 1.0))


def test_options_are_validated():
    with pytest.raises(Exception, match="max_distortion"):
        AtlasOptions(max_distortion=3.0)
    with pytest.raises(Exception, match="options must be"):
        make_atlas(*torus(), options={"margin": 0.1}, progress=False)


def test_a_split_made_for_the_packing_is_reported():
    """A chart split to pack better changes the chart count after the flattening stage said it:
    the progress says so (the command's log showed one chart flattened, then two packed)."""
    from geomopt.mesh import generators

    V, F = generators.holed_plate(2, cells=3)
    events = []
    atlas = make_atlas(V, F, progress=lambda stage, info: events.append((stage, info)))
    stages = [s for s, _ in events]
    charts = int(atlas.details.chart.max()) + 1
    flattened = [info["charts"] for s, info in events if s == "flattened"]
    assert atlas.success and flattened and flattened[-1] < charts  # this plate is split to pack
    assert stages.index("split to pack") == len(stages) - 2 and events[-2][1]["charts"] == charts

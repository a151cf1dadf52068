"""``geomopt.save(result, path, png=None)`` and its forward ``Result.save`` (issue 33 item 5, issue
49: the writers live above the results): the map file the command line would write,
read back bit for bit, the picture beside it, both or neither, never an input replaced."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import geomopt
from geomopt import GeomoptError, ParameterError, Problem, io
from geomopt.mesh import generators as G
from geomopt.untangling import untangle


@pytest.fixture(scope="module")
def surface():
    V, F = G.disk_mesh(3)
    V = np.c_[V, 0.3 * V[:, 0] ** 2]
    return V, F, geomopt.parameterize(V, F, progress=False)


def test_a_surface_map_is_its_mesh_with_uvs_and_its_picture(surface, tmp_path):
    V, F, res = surface
    written = geomopt.save(res, tmp_path / "m.obj", png=tmp_path / "m.png")
    assert written == (tmp_path / "m.obj", tmp_path / "m.png")
    V2, F2, uv = io.read_obj_uv(tmp_path / "m.obj")
    assert np.array_equal(V2, V) and np.array_equal(F2, F) and np.array_equal(uv, res.x)
    assert (tmp_path / "m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert res.save(tmp_path / "m.ply") == (tmp_path / "m.ply",)
    assert (tmp_path / "m.ply").read_bytes().startswith(b"ply")


def test_planar_tet_and_hex_maps_are_written_as_the_command_line_writes_them(tmp_path):
    t = G.rotated_interior(*G.square_mesh(5), 90.0)
    res = untangle(t.problem(), t.x0, progress=False)
    res.save(tmp_path / "planar.obj")
    rest, uv, F = io.read_obj_with_uv(tmp_path / "planar.obj")
    assert np.array_equal(rest[:, :2], t.rest) and not rest[:, 2].any()
    assert np.array_equal(uv, res.x) and np.array_equal(F, t.simplices)
    tets, hexes = G.twisted_box(2, 3, 0.2), G.twisted_box(2, 3, 0.2, hexes=True)
    flipped = tets.simplices[:, [0, 2, 1, 3]]  # every tet negative at rest: the file keeps the input's order
    for problem, cells, x0, kind, ext in (
            (Problem.tets(tets.rest, flipped, tets.fixed, tets.x0[tets.fixed]), flipped, tets.x0, "tetra", ".vtu"),
            (hexes.problem(), hexes.simplices, hexes.x0, "hexahedron", ".msh")):
        res = untangle(problem, x0, progress=False)
        res.save(tmp_path / f"{kind}{ext}")
        P, C, read = io.read_cells(tmp_path / f"{kind}{ext}", (kind,))
        assert read == kind and np.array_equal(P, res.x) and np.array_equal(C, cells)


def test_what_save_cannot_write_is_refused_before_anything_is_written(surface, tmp_path):
    V, F, res = surface
    tangle = G.twisted_box(2, 3, 0.2)
    tets = untangle(tangle.problem(), tangle.x0, progress=False)
    (tmp_path / "mesh.obj").write_text("keep")
    cases = [
        (dataclasses.replace(res, problem=None), ("a.obj",), {}, ParameterError, "does not know its mesh"),
        (tets, ("a.vtk",), {"png": "a.png"}, ParameterError, "draws triangle and sphere maps only"),
        (res, ("a.vtk",), {}, GeomoptError, ".obj"),
        (res, ("a.obj",), {"png": "a.jpg"}, GeomoptError, ".png"),
        (res, ("mesh.obj",), {"inputs": [tmp_path / "mesh.obj"]}, GeomoptError, "is the input file"),
        (res, ("a.obj",), {"png": "a.obj"}, GeomoptError, "a.obj"),
    ]
    for result, args, kwargs, error, words in cases:
        args = tuple(str(tmp_path / a) for a in args)
        kwargs = {k: (str(tmp_path / v) if isinstance(v, str) else v) for k, v in kwargs.items()}
        with pytest.raises(error, match=words.replace(".", r"\.")):
            result.save(*args, **kwargs)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.obj"]
    assert (tmp_path / "mesh.obj").read_text() == "keep"


def test_a_picture_that_fails_leaves_no_map_either(surface, tmp_path, monkeypatch):
    from geomopt.plot import _figures

    V, F, res = surface

    def broken(*args, **kwargs):
        raise RuntimeError("drawing failed")

    monkeypatch.setattr(_figures, "save_param_figure", broken)
    with pytest.raises(RuntimeError, match="drawing failed"):
        res.save(tmp_path / "m.obj", png=tmp_path / "m.png")
    assert list(tmp_path.iterdir()) == []


def test_result_save_is_a_forward_to_geomopt_save(surface, tmp_path, monkeypatch):
    """``Result.save`` hands everything to ``geomopt.save`` (the one writer, on the output floor)."""
    V, F, res = surface
    calls = []
    monkeypatch.setattr(geomopt, "save", lambda *a, **k: calls.append((a, k)) or ("written",))
    assert res.save(tmp_path / "m.obj", tmp_path / "m.png", inputs=["mesh.obj"]) == ("written",)
    assert calls == [((res, tmp_path / "m.obj", tmp_path / "m.png"), {"inputs": ["mesh.obj"]})]
    assert list(tmp_path.iterdir()) == []

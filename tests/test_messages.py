"""Messages and exit statuses of bad input (issue 48, items 5 and 7): each refusal names what
is wrong in the user's own terms (the option's object, the file's 1-based numbers) and exits 2
when it is decided before solving."""

from __future__ import annotations

import json

import numpy as np
import pytest

import geomopt
from geomopt import io
from geomopt.mesh import generators as G

from conftest import cube_tets, grid
from test_cli import one_error_line


def bowl(n=5):
    V2, F = grid(n)
    return np.c_[V2, 0.1 * V2[:, 0] ** 2], F


def test_make_atlas_sends_an_atlas_setting_to_atlas_options():
    V, F = bowl()
    with pytest.raises(geomopt.ParameterError, match=r"margin is an AtlasOptions field: pass "
                                                     r"options=AtlasOptions\(margin=0.01\)"):
        geomopt.make_atlas(V, F, margin=0.01, progress=False)


def test_param_sphere_refuses_margin(tmp_path, cli):
    import trimesh

    src, out = tmp_path / "ball.obj", tmp_path / "out.obj"
    trimesh.creation.icosphere(1).export(src)
    code, _, err = cli("param", src, "--sphere", "--margin", "0.01", "-o", out, "--quiet")
    assert code == 2 and not out.exists()
    one_error_line(err, "--margin")


def test_result_save_refuses_an_unknown_extension_as_a_value_error(tmp_path):
    V, F = bowl()
    res = geomopt.parameterize(V, F, progress=False)
    with pytest.raises(geomopt.ParameterError, match=r"\.stl"):
        res.save(tmp_path / "x.stl")
    assert issubclass(geomopt.ParameterError, ValueError) and list(tmp_path.iterdir()) == []


def tangled_tets(tmp_path):
    V, T = cube_tets(3)
    t = G.noisy_interior(V, T, 2.0, seed=1)
    return V, T, t, io.write_cells(tmp_path / "tangled.vtu", t.x0, T, "tetra")


def test_untangle_with_every_vertex_fixed_is_refused_before_solving(tmp_path, cli):
    V, T, t, tangled = tangled_tets(tmp_path)
    rest = io.write_cells(tmp_path / "rest.msh", V, T, "tetra")
    (tmp_path / "all.txt").write_text("".join(f"{i}\n" for i in range(len(V))))
    code, out, err = cli("untangle", tangled, "--rest", rest, "--handles", tmp_path / "all.txt",
                         "-o", tmp_path / "out.vtk", "--quiet", "--json")
    assert code == 2 and not (tmp_path / "out.vtk").exists()
    line = one_error_line(err, f"{t.inverted()} inverted element(s) have every vertex fixed")
    assert line.count("inverted element(s)") == 1, line
    assert json.loads(out)["exit_status"] == 2


@pytest.mark.parametrize("kind", ["tetra", "hexahedron"])
def test_untangle_refuses_a_mirrored_rest_mesh(tmp_path, cli, kind):
    if kind == "tetra":
        V, S, t, tangled = tangled_tets(tmp_path)
    else:
        V, S = G.hex_mesh(3, 3, 3)
        t = G.rotated_interior(V, S, 60)
        tangled = io.write_cells(tmp_path / "tangled.vtk", t.x0, S, kind)
    rest = io.write_cells(tmp_path / "rest.vtk", V * [-1.0, 1.0, 1.0], S, kind)  # a mirror image
    code, _, err = cli("untangle", tangled, "--rest", rest, "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 2 and not (tmp_path / "out.vtk").exists(), err
    one_error_line(err, f"the rest mesh's {len(S)} elements are negatively oriented")

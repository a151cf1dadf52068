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


def test_make_atlas_takes_no_loose_keywords():
    """An atlas setting or an energy parameter given as a keyword is an error (they go into
    AtlasOptions and energy=(name, {...})), never read as something else."""
    V, F = bowl()
    for loose in ({"margin": 0.01}, {"eps": 0.1}, {"colour": "red"}):
        with pytest.raises(TypeError, match=f"unexpected keyword argument '{next(iter(loose))}'"):
            geomopt.make_atlas(V, F, progress=False, **loose)


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


def pinched_obj(path):
    """A closed surface pinched at one vertex: two octahedra sharing their vertex 1 (file's
    numbering), edge-manifold everywhere, non-manifold at that vertex."""
    import trimesh

    a = trimesh.creation.icosphere(0)
    V1, F1 = np.asarray(a.vertices), np.asarray(a.faces)
    top = int(np.argmax(V1[:, 2]))
    order = np.r_[top, np.delete(np.arange(len(V1)), top)]  # the shared vertex first (file's vertex 1)
    V1, F1 = V1[order], np.argsort(order)[F1]
    V2 = 2 * V1[0] - V1  # the point reflection through vertex 0: meets the first there only
    F2 = np.where(F1 == 0, 0, F1 + len(V1) - 1)[:, [0, 2, 1]]
    V = np.r_[V1, V2[1:]]
    F = np.r_[F1, F2]
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))
    return V, F


def test_a_pinched_vertex_split_by_an_atlas_is_said(tmp_path, cli):
    V, F = pinched_obj(tmp_path / "pinched.obj")
    atlas = geomopt.make_atlas(V, F, progress=False)
    assert atlas.success and atlas.details.pinched.tolist() == [0]
    code, _, err = cli("param", tmp_path / "pinched.obj", "-o", tmp_path / "out.obj", "--quiet")
    assert code == 0, err
    lines = [l for l in err.splitlines() if "pinched" in l]
    assert len(lines) == 1 and "1 pinched" in lines[0] and "vertex 1 " in lines[0] + " ", err


def test_a_mixed_tet_and_hex_file_is_refused_as_mixed(tmp_path, cli):
    pts = "".join(f"{x} {y} {z}\n" for x, y, z in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 0, 1),
                                                   (1, 0, 1), (0, 1, 1), (1, 1, 1), (0, 0, 2)])
    (tmp_path / "mixed.vtk").write_text(
        f"# vtk DataFile Version 2.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 9 double\n{pts}"
        f"CELLS 3 19\n8 0 1 3 2 4 5 7 6\n4 4 5 6 8\n4 5 7 6 8\nCELL_TYPES 3\n12\n10\n10\n")
    code, _, err = cli("untangle", tmp_path / "mixed.vtk", "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 2 and not (tmp_path / "out.vtk").exists()
    line = one_error_line(err, "2 tetrahedra and 1 hexahedron", "one kind of element")
    assert "only meshes of linear hexahedra" not in line


def test_a_tet_mesh_whose_free_boundary_folds_gets_3d_advice(tmp_path, cli):
    """One handle leaves the boundary free: the tets all turn positive but the boundary surface
    folds over an interior edge, which no flip-free motion undoes (with no handle at all the part
    is held at the rest mesh, certified).  The advice is about surfaces, not polygons."""
    V, T, t, tangled = tangled_tets(tmp_path)
    rest = io.write_cells(tmp_path / "rest.msh", V, T, "tetra")
    (tmp_path / "one.txt").write_text(f"{t.fixed[0]}\n")
    code, _, err = cli("untangle", tangled, "--rest", rest, "--handles", tmp_path / "one.txt",
                       "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 1, err
    line = one_error_line(err, "boundary surface")
    assert "polygon" not in line and "Tutte" not in line
    (tmp_path / "none.txt").write_text("")
    code, _, err = cli("untangle", tangled, "--rest", rest, "--handles", tmp_path / "none.txt",
                       "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 0, err


def _text_outside(fig) -> list:
    """The titles, axis labels and legends of ``fig`` that reach outside it once drawn."""
    fig.canvas.draw()
    r, W, H = fig.canvas.get_renderer(), fig.bbox.width, fig.bbox.height
    arts = [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label) if t.get_text()]
    arts += list(fig.legends)
    return [a for a in arts if (lambda b: b.x0 < -1 or b.y0 < -1 or b.x1 > W + 1 or b.y1 > H + 1)(a.get_window_extent(r))]


def test_compare_font_sizes_are_bounded_where_the_figure_fits(tmp_path, cli):
    from geomopt.experiments.comparison import compare_meshes
    from geomopt.experiments.options import MAX_FONT_SIZE, CompareOptions

    V, F = bowl()
    mesh = io.write_obj(tmp_path / "camelhead.obj", V, F)
    code, out, err = cli("compare", mesh, "-o", tmp_path / "o", "--font-size", "72", "--layout", "column", "--quiet")
    assert code == 2 and not (tmp_path / "o").exists()
    one_error_line(err, "font_size", f"at most {MAX_FONT_SIZE['column']:g}")
    with pytest.raises(geomopt.ParameterError, match="at most"):
        CompareOptions(layout="wide", font_size=MAX_FONT_SIZE["wide"] + 1)
    six = ["newton", "lbfgs", "aqp", "slim", "optx-ncg", "cm"]  # the legend of many solvers, two meshes
    res = compare_meshes({"camelhead": mesh, "b": io.write_obj(tmp_path / "b.obj", 2 * V, F)}, solvers=six,
                         options=CompareOptions(warmup=False, max_steps=20))
    for layout, size in MAX_FONT_SIZE.items():
        assert _text_outside(res.figure(layout=layout, font_size=size)) == [], (layout, size)
        with pytest.raises(geomopt.ParameterError, match="at most"):
            res.figure(layout=layout, font_size=size + 1)


def test_a_non_manifold_edge_is_named_in_the_files_own_terms(tmp_path, cli):
    """Three fans of faces on one edge that only fan-triangulation made: the diagonal (1, 3) of
    the quad on line 7 is also a side of two triangles: the file's own vertices (1-based) and
    face lines are named, and that the edge is a diagonal the file does not have."""
    text = ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 0.5 1\nv 0.5 0.5 -1\n"
            "f 1 2 3 4\n"  # fanned into (1 2 3) (1 3 4): the diagonal 1-3
            "f 1 3 5\n")   # a third face on 1-3
    (tmp_path / "m.obj").write_text(text)
    code, _, err = cli("param", tmp_path / "m.obj", "-o", tmp_path / "out.obj", "--quiet")
    assert code == 2 and not (tmp_path / "out.obj").exists()
    line = one_error_line(err, "vertices 1 and 3", "lines 7 and 8", "diagonal")
    assert "vertices 0 and 2" not in line

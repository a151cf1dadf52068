"""Quad and hex meshes in files and on the command line (issue 18 items 3-4): every format read
back bit for bit or refused with one line, `geomopt smooth` and `geomopt untangle` on quad/hex
cases writing only certified files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geomopt import MeshError, MeshFormatError, io
from geomopt._runtime.formats import extensions
from geomopt.mesh import generators as G
from geomopt.mesh.cells import CELL_EXTENSIONS, case_inputs, output_extensions
from geomopt.mesh.elements import certify_elements, quality
from geomopt.mesh.problem import Problem

from test_cli import one_error_line

def _meshes():
    V, Q = G.sector_mesh(3, 5, perturb=0.3, seed=3)
    V3, H = G.sector_mesh(2, 4, 2, perturb=0.3, seed=3)
    return {"quad": (V, Q), "hexahedron": (V3, H)}


@pytest.mark.parametrize("kind", ["quad", "hexahedron"])
@pytest.mark.parametrize("ext", extensions(writable=True))  # every writable format of the table
def test_cells_round_trip_bit_for_bit(tmp_path, kind, ext):
    if ext not in extensions(kind, writable=True):  # .obj: quads only
        with pytest.raises(MeshFormatError, match="extension"):
            io.write_cells(tmp_path / "h.obj", *_meshes()[kind], kind)
        return
    P, C = _meshes()[kind]
    path = io.write_cells(tmp_path / f"m{ext}", P, C, kind)
    back, C2, kind2 = io.read_cells(path)
    assert kind2 == kind and np.array_equal(C2, C)
    assert np.array_equal(back[:, : P.shape[1]], P) and (back.shape[1] == P.shape[1] or not back[:, 2:].any())


def _refused(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises((MeshFormatError, MeshError)) as info:
        io.read_cells(path)
    return str(info.value)


def test_mixed_and_wrong_cells_are_refused(tmp_path):
    pts = "".join(f"{x} {y} 0\n" for y in range(3) for x in range(3))
    # legacy VTK with a quad and a triangle
    vtk = (f"# vtk DataFile Version 2.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 9 double\n{pts}"
           f"CELLS 2 9\n4 0 1 4 3\n3 1 2 5\nCELL_TYPES 2\n9\n5\n")
    assert "cells other than quads (triangle)" in _refused(tmp_path, "mixed.vtk", vtk)
    # OBJ: a triangle among quads
    obj = "".join(f"v {x} {y} 0\n" for y in range(3) for x in range(3)) + "f 1 2 5 4\nf 2 3 6\n"
    msg = _refused(tmp_path, "mixed.obj", obj)
    assert "line 11" in msg and "3 corners" in msg and "\n" not in msg
    # Medit: hexahedra beside tetrahedra
    P3, H = _meshes()["hexahedron"]
    io.write_cells(tmp_path / "h.mesh", P3, H, "hexahedron")
    text = (tmp_path / "h.mesh").read_text().replace("End", "Tetrahedra\n1\n1 2 3 4 0\nEnd")
    assert "mixes 1 tetrahedron and 16 hexahedra; geomopt maps one kind" in _refused(tmp_path, "mixed.mesh", text)
    # a quad repeating a vertex; a count that does not match
    assert "more than once" in _refused(tmp_path, "rep.obj", obj.replace("f 2 3 6\n", "f 2 3 3 6\n"))
    bad = vtk.replace("CELLS 2 9\n4 0 1 4 3\n3 1 2 5\nCELL_TYPES 2\n9\n5\n", "CELLS 1 5\n4 0 1 4 3\nCELL_TYPES 2\n9\n9\n")
    assert "CELLS declares 1 cells but CELL_TYPES declares 2" in _refused(tmp_path, "count.vtk", bad)
    # hexahedra are not tetrahedra
    with pytest.raises(MeshFormatError, match="contains non-tetrahedral volume cells .hexahedron"):
        io.read_tets(tmp_path / "h.mesh")


def test_a_tet_mesh_needs_its_rest_mesh_and_smooth_refuses_it(tmp_path):
    from geomopt.mesh.cells import SMOOTH_KINDS, read_cell_case
    from geomopt.io import write_vtk_tets

    V, T = G.box_mesh(2, 2, 2)
    write_vtk_tets(tmp_path / "tets.vtk", V, T)
    with pytest.raises(MeshError, match="tetrahedral mesh: .* needs the rest mesh: give it with --rest REST"):
        read_cell_case(tmp_path / "tets.vtk")
    with pytest.raises(MeshFormatError, match="is a tetrahedral mesh; smoothing takes quad and hex meshes"):
        read_cell_case(tmp_path / "tets.vtk", kinds=SMOOTH_KINDS)
    P3, H = _meshes()["hexahedron"]  # a mixed mesh keeps its own message
    io.write_cells(tmp_path / "h.mesh", P3, H, "hexahedron")
    text = (tmp_path / "h.mesh").read_text().replace("End", "Tetrahedra\n1\n1 2 3 4 0\nEnd")
    (tmp_path / "mixed.mesh").write_text(text)
    for kinds in ({}, {"kinds": SMOOTH_KINDS}):
        with pytest.raises(MeshFormatError, match=r"mixes 1 tetrahedron and \d+ hexahedra"):
            read_cell_case(tmp_path / "mixed.mesh", **kinds)


def _tangled_tets(tmp_path, flip=False):
    """A tangled tet cube as two files in two formats (rest.msh, tangled.vtu) and its Tangle;
    ``flip``: every tet listed negatively oriented (as the LIM armadillo's)."""
    from conftest import cube_tets

    V, T = cube_tets(3)
    t = G.noisy_interior(V, T, 2.0, seed=1)
    T = T[:, [0, 2, 1, 3]] if flip else T
    rest = io.write_cells(tmp_path / "rest.msh", V, T, "tetra")
    tangled = io.write_cells(tmp_path / "tangled.vtu", t.x0, T, "tetra")
    return rest, tangled, t, T


@pytest.mark.parametrize("flip", [False, True])
def test_untangle_command_on_a_tet_mesh_file_with_its_rest_mesh(cli, tmp_path, flip):
    from geomopt.exact.certify import local_certificate

    rest, tangled, t, T = _tangled_tets(tmp_path, flip)
    assert t.inverted() > 0
    code, out, err = cli("untangle", tangled, "--rest", rest, "-o", tmp_path / "out.mesh", "--quiet", "--json")
    assert code == 0, err
    report = json.loads(out)  # the keys of the folder mode, and the kind
    assert report["kind"] == "tetra" and report["dim"] == 3 and report["elements"] == len(T)
    assert report["inverted_before"] == t.inverted() > report["inverted"] == 0
    assert report["certified"] and report["outcome"] == "converged" and report["forced_overlaps"] == 0
    assert report["handles_moved"] == 0 and report["min_scaled_jacobian"] > 0 and report["min_det_rel"] > 0
    assert report["fixed_vertices"] == len(t.fixed)  # the boundary by default
    P, T2, kind = io.read_cells(tmp_path / "out.mesh", ("tetra",))
    assert kind == "tetra" and np.array_equal(T2, T)
    assert local_certificate(P, T, orientation=-1 if flip else 1).ok
    assert np.array_equal(P[t.fixed], t.x0[t.fixed])


def test_untangle_command_takes_the_handles_of_a_handles_file(cli, tmp_path):
    rest, tangled, t, T = _tangled_tets(tmp_path)
    chosen = t.fixed[::3]
    (tmp_path / "handles.txt").write_text("".join(f"{i}\n" for i in chosen))
    code, out, err = cli("untangle", tangled, "--rest", rest, "--handles", tmp_path / "handles.txt",
                         "-o", tmp_path / "out.vtk", "--quiet", "--json")
    assert code == 0, err
    assert json.loads(out)["fixed_vertices"] == len(chosen)
    P, _, _ = io.read_cells(tmp_path / "out.vtk", ("tetra",))
    assert np.array_equal(P[chosen], t.x0[chosen])
    # a quad mesh with a rest mesh of its own (not reference squares) and handles from a file
    V, Q = G.quad_mesh(6, 6)
    tq = G.rotated_interior(V, Q, 120)
    io.write_cells(tmp_path / "qrest.vtk", V, Q, "quad")
    io.write_cells(tmp_path / "qtangled.obj", tq.x0, Q, "quad")
    np.savetxt(tmp_path / "qhandles.txt", tq.fixed, fmt="%d")
    code, out, err = cli("untangle", tmp_path / "qtangled.obj", "--rest", tmp_path / "qrest.vtk", "--handles",
                         tmp_path / "qhandles.txt", "-o", tmp_path / "q.vtu", "--quiet", "--json")
    assert code == 0, err
    assert json.loads(out)["kind"] == "quad" and json.loads(out)["fixed_vertices"] == len(tq.fixed)
    P, _, _ = io.read_cells(tmp_path / "q.vtu")
    assert certify_elements(P[:, :2], Q).certified


def _rest_variants(tmp_path, rest, T):
    """Rest meshes that do not belong to the tangled file: one (unused) vertex more; the same
    tetrahedra in another order."""
    V, _ = io.read_tets(rest)
    extra = io.write_cells(tmp_path / "extra.vtk", np.vstack([V, V[:1] + 5.0]), T, "tetra")
    swapped = io.write_cells(tmp_path / "swapped.vtk", V, T[::-1], "tetra")
    return extra, swapped


@pytest.mark.parametrize("make,words", [
    (lambda d, r, t, e, s: ["--rest", s], ["different cells", "first difference at cell 0"]),
    (lambda d, r, t, e, s: ["--rest", e], ["vertices but", "same count and order"]),
    (lambda d, r, t, e, s: [], ["needs the rest mesh", "--rest REST"]),
    (lambda d, r, t, e, s: ["--rest", r, "--handles", d / "bad.txt"], ["handles has 1 indices outside 0..63"]),
    (lambda d, r, t, e, s: ["--rest", r, "-o", r], ["is the input file"]),
    (lambda d, r, t, e, s: ["--rest", r, "--png", d / "pic.png", "-o", d / "out.obj"], [".obj"]),
])
def test_untangle_refuses_mismatched_files_in_one_line(cli, tmp_path, make, words):
    rest, tangled, t, T = _tangled_tets(tmp_path)
    extra, swapped = _rest_variants(tmp_path, rest, T)
    (tmp_path / "bad.txt").write_text(f"0\n{len(t.rest)}\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    argv = make(tmp_path, rest, tangled, extra, swapped)
    argv = argv if "-o" in argv else argv + ["-o", tmp_path / "out.vtk"]
    code, _, err = cli("untangle", tangled, *argv, "--quiet")
    assert code == 2
    one_error_line(err, *words)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # nothing written, no input replaced


def test_rest_and_handles_options_are_for_one_mesh_file(cli, tmp_path):
    from geomopt.lim import LimCase

    case = LimCase.from_tangle(G.noisy_interior(*G.box_mesh(2, 2, 2), 1.0)).write(tmp_path / "case")
    code, _, err = cli("untangle", case, "--rest", case / "rest.vtk", "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 2 and "go with one mesh file" in one_error_line(err)
    assert not (tmp_path / "out.vtk").exists()


def test_gmsh_made_hex_meshes_are_read_exactly(tmp_path):
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addBox(0, 0, 0, 1, 2, 1)
        gmsh.model.occ.synchronize()
        for _, c in gmsh.model.getEntities(1):
            gmsh.model.mesh.setTransfiniteCurve(c, 4)
        for _, s in gmsh.model.getEntities(2):
            gmsh.model.mesh.setTransfiniteSurface(s)
            gmsh.model.mesh.setRecombine(2, s)
        gmsh.model.mesh.setTransfiniteVolume(1)
        gmsh.model.mesh.generate(3)
        for version in (2.2, 4.1):
            gmsh.option.setNumber("Mesh.MshFileVersion", version)
            gmsh.option.setNumber("Mesh.SaveAll", 1)  # boundary quads, lines and points beside the hexes
            gmsh.write(str(tmp_path / f"box{version}.msh"))
        n_hex = len(gmsh.model.mesh.getElementsByType(5)[0])
    finally:
        gmsh.finalize()
    for version in (2.2, 4.1):
        P, H, kind = io.read_cells(tmp_path / f"box{version}.msh")
        assert kind == "hexahedron" and len(H) == n_hex == 27
        assert certify_elements(P, Problem.hexes(P, H).elements).certified


# ----------------------------------------------------------------------------- command line


def test_smooth_command_writes_a_certified_better_mesh(cli, tmp_path):
    V, H = G.sector_mesh(2, 5, 2, perturb=0.4, seed=1)
    src = io.write_cells(tmp_path / "in.vtk", V, H, "hexahedron")
    code, out, err = cli("smooth", src, "-o", tmp_path / "out.vtu", "--quiet", "--json")
    assert code == 0, err
    P, H2, _ = io.read_cells(tmp_path / "out.vtu")
    E = Problem.hexes(V, H).elements
    assert np.array_equal(H2, H) and certify_elements(P, E).certified
    assert quality(P, H).min >= quality(V, H).min + 0.2
    b = Problem.hexes(V, H).boundary_vertices()
    assert np.array_equal(P[b], V[b])
    assert '"improved": true' in out
    assert {"import", "read", "solve", "write", "total"} <= set(json.loads(out)["timing"])


def test_untangle_command_on_quad_and_hex_cases(cli, tmp_path):
    V, Q = G.quad_mesh(10, 10)
    t = G.rotated_interior(V, Q, 120)
    src = io.write_cells(tmp_path / "tangled.obj", t.x0, Q, "quad")
    code, out, err = cli("untangle", src, "-o", tmp_path / "out.msh", "--quiet", "--json")
    assert code == 0, err
    report = json.loads(out)  # the keys README promises for every `untangle --json`
    assert report["dim"] == 2 and report["vertices"] == len(V) and report["inverted_before"] == t.inverted()
    assert report["inverted"] == 0 and report["handles_moved"] == 0 and report["outcome"] == "converged"
    assert report["inner_iterations"] >= report["outer_iterations"] >= 1
    assert report["start"] == "harmonic"  # auto: the boundary's harmonic extension has no inverted corner
    code, out, err = cli("untangle", src, "-o", tmp_path / "given.msh", "--quiet", "--json", "--start", "given")
    assert code == 0, err
    assert json.loads(out)["start"] == "given" and json.loads(out)["inner_iterations"] > 1
    assert {"import", "read", "compile", "setup", "solve", "certify", "write", "total"} <= set(report["timing"])
    P, Q2, _ = io.read_cells(tmp_path / "out.msh")
    assert certify_elements(P[:, :2], Q).certified and np.array_equal(P[t.fixed, :2], t.x0[t.fixed])
    # a LIM-style hex case folder: rest.vtk, init.vtk, handles.txt (its own handles, not the boundary)
    V3, H = G.hex_mesh(4, 4, 4)
    th = G.noisy_interior(V3, H, 1.0)
    case = tmp_path / "hexcase"
    case.mkdir()
    io.write_cells(case / "rest.vtk", V3, H, "hexahedron")
    io.write_cells(case / "init.vtk", th.x0, H, "hexahedron")
    np.savetxt(case / "handles.txt", th.fixed[::2], fmt="%d")
    code, _, err = cli("untangle", case, "-o", tmp_path / "hex.vtk", "--quiet")
    assert code == 0, err
    P3, _, _ = io.read_cells(tmp_path / "hex.vtk")
    assert certify_elements(P3, H).certified and np.array_equal(P3[th.fixed[::2]], th.x0[th.fixed[::2]])


def _bad_cases(tmp):
    V, Q = G.quad_mesh(3, 3)
    V3 = np.column_stack([V, V[:, 0] * V[:, 1]])
    twisted = np.concatenate([Q[:1, [0, 1, 3, 2]], Q[1:]])
    against = np.concatenate([Q[:1, ::-1], Q[1:]])
    repeated = "".join(f"v {x} {y} 0\n" for x, y in V) + "".join(f"f {a + 1} {b + 1} {b + 1} {d + 1}\n"
                                                                  for a, b, c, d in Q)
    mixed = "".join(f"v {x} {y} 0\n" for x, y in V) + "f 1 2 6 5\nf 2 3 7\n"
    files = {"non-planar": (V3, Q), "twisted": (V, twisted), "orientation": (V, against)}
    out = {}
    for name, (P, C) in files.items():
        out[name] = io.write_cells(tmp / f"{name}.vtk", P, C, "quad")
    for name, text in (("repeated", repeated), ("mixed", mixed)):
        out[name] = tmp / f"{name}.obj"
        out[name].write_text(text)
    return out


@pytest.mark.parametrize("name,words", [
    ("non-planar", ["not in the plane z = 0"]), ("twisted", ["inconsistent orientation"]),
    ("orientation", ["inconsistent orientation"]), ("repeated", ["use a vertex more than once"]),
    ("mixed", ["3 corners", "mixed meshes are not supported"]),
])
@pytest.mark.parametrize("command", ["smooth", "untangle"])
def test_bad_quad_input_is_one_line_exit_2(cli, tmp_path, name, words, command):
    path = _bad_cases(tmp_path)[name]
    code, _, err = cli(command, path, "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 2
    one_error_line(err, *words)
    assert not (tmp_path / "out.vtk").exists()


def test_smooth_refuses_an_invalid_mesh_and_its_own_input(cli, tmp_path):
    V, H = G.hex_mesh(3, 3, 3)
    bad = io.write_cells(tmp_path / "bad.vtk", G.noisy_interior(V, H, 1.0).x0, H, "hexahedron")
    code, _, err = cli("smooth", bad, "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 2 and "untangle it first" in one_error_line(err)
    code, _, err = cli("smooth", bad, "-o", bad, "--quiet")
    assert code == 2 and "is the input file" in one_error_line(err)


def test_what_a_cell_case_reads_and_may_be_written_to(tmp_path):
    """The inputs no output may be (a mesh file, or every file of a case folder, then --rest and
    --handles) and the extensions an output may have (.obj for quads only)."""
    assert output_extensions("quad") == CELL_EXTENSIONS
    for kind in ("tetra", "hexahedron"):
        assert output_extensions(kind) == tuple(e for e in CELL_EXTENSIONS if e != ".obj")
    folder = tmp_path / "case"
    folder.mkdir()
    for name in ("rest.vtk", "init.vtk", "handles.txt"):
        (folder / name).write_text("")
    assert sorted(case_inputs(folder)) == sorted(str(folder / n) for n in ("rest.vtk", "init.vtk", "handles.txt"))
    mesh, rest, handles = (tmp_path / n for n in ("tangled.vtk", "rest.vtk", "ids.txt"))
    assert case_inputs(mesh) == [str(mesh)]
    assert case_inputs(mesh, rest, handles) == [str(mesh), str(rest), str(handles)]
    assert case_inputs(mesh, handles=handles) == [str(mesh), str(handles)]

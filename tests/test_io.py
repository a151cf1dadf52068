"""Tests of geomopt.io: readers, writers, validators, atomic output, LIM cases."""

from __future__ import annotations

import csv
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geomopt._runtime.errors import MeshError, MeshFormatError, ParameterError
from geomopt.io import (
    atomic_output,
    atomic_write,
    read_mesh,
    read_vtk_tets,
    validate_indices,
    validate_simplices,
    validate_vertices,
    write_obj_with_uv,
    write_vtk_tets,
)
from geomopt.lim import LimCase

SHARED = Path(__file__).resolve().parents[1].parent / "shared/data"
from conftest import LIM_ROOT  # noqa: E402
MESH_DIR = SHARED / "meshes"

TET_VTK = (
    "# vtk DataFile Version 2.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\n"
    "POINTS 4 double\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
)
TET_CELLS = "CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n"


def write(path, content):
    """Write str or bytes to ``path`` and return it."""
    path = Path(path)
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


def obj_v_lines(path):
    """Vertex positions of an OBJ's ``v`` lines, in file order, shape (n, 3)."""
    with open(path) as fh:
        return np.array([[float(x) for x in line.split()[1:4]] for line in fh if line.startswith("v ")])


def lim2d_folder(folder, obj, handles="0\n"):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write(folder / "input.obj", obj)
    if handles is not None:
        write(folder / "handles.txt", handles)
    return folder


SQUARE_OBJ = (
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
)


# ------------------------------------------------------------------ atomic output


def test_atomic_output_writes_on_success(tmp_path):
    target = tmp_path / "out.txt"
    with atomic_output(target) as fh:
        fh.write("hello\n")
    assert target.read_text() == "hello\n"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_atomic_output_leaves_nothing_when_writer_raises(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError):
        with atomic_output(target) as fh:
            fh.write("partial data\n" * 1000)
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []


def test_atomic_write_keeps_existing_file_when_writer_raises(tmp_path):
    target = write(tmp_path / "out.bin", b"old")

    def bad_writer(fh):
        fh.write(b"new partial")
        raise KeyError("midway")

    with pytest.raises(KeyError):
        atomic_write(target, bad_writer, mode="wb")
    assert target.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["out.bin"]
    atomic_write(target, lambda fh: fh.write(b"new"), mode="wb")
    assert target.read_bytes() == b"new"


def test_atomic_output_permissions_follow_umask(tmp_path):
    target = tmp_path / "out.txt"
    with atomic_output(target) as fh:
        fh.write("x")
    mask = os.umask(0)
    os.umask(mask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~mask)


def test_atomic_output_bad_mode(tmp_path):
    with pytest.raises(ParameterError, match="mode"):
        with atomic_output(tmp_path / "x", mode="a"):
            pass


def test_writers_are_atomic_on_invalid_input(tmp_path):
    target = write(tmp_path / "m.vtk", "old")
    with pytest.raises(MeshError):
        write_vtk_tets(target, np.zeros((4, 3)), np.array([[0, 1, 2, 9]]))
    assert target.read_text() == "old"


# --------------------------------------------------------------------- validators


def test_validate_vertices_ok_and_errors():
    V = validate_vertices([[0, 0, 0], [1, 2, 3]], "V", dim=3)
    assert V.dtype == np.float64 and V.shape == (2, 3)
    assert validate_vertices(np.zeros((5, 2)), "UV").shape == (5, 2)
    with pytest.raises(MeshError, match="shape"):
        validate_vertices(np.zeros((5, 2)), "V", dim=3)
    with pytest.raises(MeshError, match="shape"):
        validate_vertices(np.zeros(6), "V")
    with pytest.raises(MeshError, match="no vertices"):
        validate_vertices(np.zeros((0, 3)), "V")
    with pytest.raises(MeshError, match="real numbers"):
        validate_vertices(np.zeros((2, 3), dtype=complex), "V")
    with pytest.raises(MeshError, match="rectangular"):
        validate_vertices([[0, 0, 0], [1, 2]], "V")
    bad = np.zeros((6, 3))
    bad[2, 1] = np.nan
    bad[4, 0] = np.inf
    with pytest.raises(MeshError, match=r"2 vertices with NaN.*first: vertex 2"):
        validate_vertices(bad, "V")


def test_validate_simplices_ok_and_errors():
    F = validate_simplices(np.array([[0, 1, 2]], dtype=np.uint32), 3, 3, "F")
    assert F.dtype == np.int64
    with pytest.raises(MeshError, match="integer dtype"):
        validate_simplices(np.array([[0.0, 1.0, 2.0]]), 3, 3, "F")
    with pytest.raises(MeshError, match=r"shape \(m, 4\)"):
        validate_simplices(np.array([[0, 1, 2]]), 3, 4, "T")
    with pytest.raises(MeshError, match="no triangles"):
        validate_simplices(np.zeros((0, 3), dtype=int), 3, 3, "F")
    with pytest.raises(MeshError, match=r"outside 0\.\.2.*first: triangle 1"):
        validate_simplices(np.array([[0, 1, 2], [0, 1, 3], [-1, 0, 1]]), 3, 3, "F")
    with pytest.raises(MeshError, match=r"1 tetrahedra that use a vertex more than once.*tetrahedron 1"):
        validate_simplices(np.array([[0, 1, 2, 3], [0, 1, 2, 1]]), 4, 4, "T")


def test_validate_simplices_finds_a_repeat_in_any_block_of_rows():
    """Repeats are looked for a block of rows at a time: one far down a large array is found too."""
    T = np.arange(4 * 100000).reshape(-1, 4)
    T[70001, 3] = T[70001, 1]
    with pytest.raises(MeshError, match=r"1 tetrahedra that use a vertex more than once.*tetrahedron 70001"):
        validate_simplices(T, T.size, 4, "T")


def test_validate_indices():
    assert validate_indices([], 3).shape == (0,)
    assert validate_indices(np.array([2, 0]), 3).tolist() == [2, 0]
    with pytest.raises(MeshError, match="outside"):
        validate_indices([0, 3], 3)
    with pytest.raises(MeshError, match="more than once"):
        validate_indices([1, 0, 1], 3)
    with pytest.raises(MeshError, match="integer"):
        validate_indices([1.0], 3)
    with pytest.raises(MeshError, match="1-D"):
        validate_indices([[1]], 3)


# ---------------------------------------------------------------------- read_mesh


def test_read_mesh_keeps_duplicate_and_unreferenced_vertices_in_order(tmp_path):
    text = (
        "v 5 5 5\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 0\nv 1 0 0\n"
        "vt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\n"
        "vn 0 0 1\nvn 0 0 -1\n"
        "f 2/1/1 3/2/1 4/3/1\nf 5/4/2 6/2/2 4/3/2\n"
    )
    V, F = read_mesh(write(tmp_path / "dup.obj", text))
    np.testing.assert_array_equal(V, obj_v_lines(tmp_path / "dup.obj"))
    assert F.tolist() == [[1, 2, 3], [4, 5, 3]]
    assert V.dtype == np.float64 and F.dtype == np.int64


@pytest.mark.parametrize("name", ["bunny_cut.obj", "face.obj", "armadillo_cut_low.obj"])
def test_read_mesh_shared_objs_match_v_lines(name):
    path = MESH_DIR / name
    if not path.exists():
        pytest.skip(f"shared mesh {path} not present")
    V, F = read_mesh(path)
    np.testing.assert_array_equal(V, obj_v_lines(path))
    with open(path) as fh:
        assert F.shape[0] == sum(line.startswith("f ") for line in fh)


def test_read_mesh_off_ply_stl(tmp_path):
    V, F = read_mesh(write(tmp_path / "a.off", "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n"))
    assert V.shape == (4, 3) and F.tolist() == [[0, 1, 2], [0, 2, 3]]
    ply = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    V, F = read_mesh(write(tmp_path / "a.PLY", ply))
    assert V.shape == (3, 3) and F.tolist() == [[0, 1, 2]]
    stl = (
        "solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
        "endloop\nendfacet\nendsolid a\n"
    )
    V, F = read_mesh(write(tmp_path / "a.stl", stl))
    assert V.shape == (3, 3) and F.shape == (1, 3)


def test_read_mesh_latin1_obj(tmp_path):
    text = "# Cr\xe9\xe9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    V, F = read_mesh(write(tmp_path / "l.obj", text.encode("latin-1")))
    assert V.shape == (3, 3) and F.tolist() == [[0, 1, 2]]


def test_read_mesh_merges_material_groups(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 2 4 3\n"
    V, F = read_mesh(write(tmp_path / "mtl.obj", text))
    assert V.shape == (4, 3)
    assert sorted(map(tuple, F.tolist())) == [(0, 1, 2), (1, 3, 2)]


@pytest.mark.parametrize(
    "name, content, word",
    [
        ("empty.obj", "", "empty"),
        ("garbage.obj", b"\x00\x01\xff\xfe garbage \x00", "binary file"),
        ("garbage.ply", b"\x00\x01\xff\xfe garbage \x00", "does not start with the line 'ply'"),
        ("text.obj", "hello world\n", "line 1: unknown OBJ statement 'hello'"),
        ("comments.obj", "# only a comment\n\n", "contains no mesh"),
        ("points.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\n", "no triangle faces"),
        ("lines.obj", "v 0 0 0\nv 1 0 0\nl 1 2\n", "no triangle faces"),
        ("points.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
         "property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n", "no triangle faces"),
        ("short.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n", "declares 3 vertices and 1 faces, but the file ends"),
        ("mesh.xyz", "0 0 0\n", ".obj, .off, .ply, .stl"),
        ("mesh", "v 0 0 0\n", "unsupported extension"),
    ],
)
def test_read_mesh_format_errors(tmp_path, name, content, word):
    with pytest.raises(MeshFormatError, match=word):
        read_mesh(write(tmp_path / name, content))


def test_read_mesh_missing_directory_and_multi_mesh(tmp_path):
    with pytest.raises(MeshFormatError, match="does not exist"):
        read_mesh(tmp_path / "nope.obj")
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(MeshFormatError, match="directory"):
        read_mesh(tmp_path / "dir.obj")
    facet = "facet normal 0 0 1\nouter loop\nvertex 0 0 {z}\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n"
    two = f"solid a\n{facet.format(z=0)}endsolid a\nsolid b\n{facet.format(z=5)}endsolid b\n"
    with pytest.raises(MeshFormatError, match="2 separate meshes"):
        read_mesh(write(tmp_path / "two.stl", two))


def test_binary_stl_with_a_solid_header_and_a_wrong_count_is_described_truly(tmp_path):
    """Its header starts with 'solid' (common); the refusal said it did not."""
    record = np.zeros(1, [("n", "<f4", 3), ("c", "<f4", (3, 3)), ("a", "<u2")])
    record["c"] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    header = b"solid exported by some CAD".ljust(80, b" ")
    for count in (2, 0):  # declares 2 (or 0) triangles, holds 1
        data = header + np.uint32(count).tobytes() + record.tobytes()
        with pytest.raises(MeshFormatError, match="starts with 'solid' but holds binary bytes"):
            read_mesh(write(tmp_path / "wrong.stl", data))
    with pytest.raises(MeshFormatError, match="does not start with 'solid'"):
        read_mesh(write(tmp_path / "wrong.stl", b"x" * 80 + np.uint32(2).tobytes() + record.tobytes()))
    with pytest.raises(MeshFormatError, match="too short.*starts with 'solid' but holds binary"):
        read_mesh(write(tmp_path / "short.stl", b"solid \x00\x01"))


@pytest.mark.parametrize(
    "text, word",
    [
        ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\nf 1 2 3\n", "more than once"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "line 4: face corner '7' refers to a vertex beyond the file's 3"),
    ],
)
def test_read_mesh_content_errors(tmp_path, text, word):
    with pytest.raises(MeshError, match=word) as info:
        read_mesh(write(tmp_path / "bad.obj", text))
    assert not isinstance(info.value, MeshFormatError)


def test_read_mesh_ply_index_out_of_range(tmp_path):
    ply = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n"
    )
    with pytest.raises(MeshError, match="outside"):
        read_mesh(write(tmp_path / "oob.ply", ply))


# --------------------------------------------------------------- OBJ with UV / 2D


def test_write_obj_with_uv_round_trip_exact(tmp_path):
    rng = np.random.default_rng(0)
    n = 30
    V = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-200, 200, size=(n, 3))
    V[0] = [-0.0, 1e-310, 0.1]
    UV = rng.normal(size=(n, 2)) / 3.0
    F = np.array([rng.permutation(n)[:3] for _ in range(40)])
    folder = tmp_path / "case"
    folder.mkdir()
    write_obj_with_uv(folder / "input.obj", V, F, UV)
    write(folder / "handles.txt", "3\n1")
    lines = (folder / "input.obj").read_text().splitlines()
    assert [line.split()[0] for line in lines] == ["v"] * n + ["vt"] * n + ["f"] * 40
    assert lines[2 * n] == "f {0}/{0} {1}/{1} {2}/{2}".format(*(F[0] + 1))
    case = LimCase.read(folder)
    np.testing.assert_array_equal(case.rest, V)
    np.testing.assert_array_equal(case.init, UV)
    np.testing.assert_array_equal(case.simplices, F)
    assert case.handles.tolist() == [3, 1]
    V2, F2 = read_mesh(folder / "input.obj")
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(F2, F)


def test_write_obj_with_uv_rejects_bad_input(tmp_path):
    with pytest.raises(MeshError, match="one UV per vertex"):
        write_obj_with_uv(tmp_path / "a.obj", np.zeros((3, 3)), [[0, 1, 2]], np.zeros((2, 2)))
    assert not (tmp_path / "a.obj").exists()


def test_read_lim2d_forms_and_empty_handles(tmp_path):
    obj = "# c\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\ng x\nf 1 2/2 3/3/1\n"
    case = LimCase.read(lim2d_folder(tmp_path, obj, handles=""))
    assert case.simplices.tolist() == [[0, 1, 2]]
    assert case.handles.shape == (0,) and case.handles.dtype == np.int64
    case = LimCase.read(lim2d_folder(tmp_path, obj.replace("\n", "\r\n"), handles="0\r\n2"))
    assert case.handles.tolist() == [0, 2]


@pytest.mark.parametrize(
    "obj, handles, error, word",
    [
        (SQUARE_OBJ.replace("vt 0 1\n", ""), "0", MeshFormatError, "one 'vt'"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f 1/1 3/3 4/2"), "0", MeshFormatError, "texture index"),
        (SQUARE_OBJ.replace("v 1 1 0", "v 1 x 0"), "0", MeshFormatError, "line 3"),
        (SQUARE_OBJ.replace("vt 1 0\n", "vt 1\n"), "0", MeshFormatError, "line 6"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f 1/1 3/3 4/4 2/2"), "0", MeshFormatError, "only triangles"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f -5 -2 -1"), "0", MeshFormatError, "before the first vertex"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f -4/-4 -2/-2 -1/-1"), "0", MeshFormatError, "relative"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f 1 3 x"), "0", MeshFormatError, "line 10"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f 1 3 9"), "0", MeshError, "line 10: face corner '9' refers to a vertex beyond"),
        (SQUARE_OBJ.replace("f 1/1 3/3 4/4", "f 1 3 3"), "0", MeshError, "more than once"),
        (SQUARE_OBJ.replace("vt 1 1", "vt inf 1"), "0", MeshError, "infinite"),
        (SQUARE_OBJ, "0\n4\n", MeshError, "outside"),
        (SQUARE_OBJ, "0\n1\n0\n", MeshError, "more than once"),
        (SQUARE_OBJ, "0\n1.5\n", MeshFormatError, "line 2"),
        ("", "0", MeshFormatError, "empty"),
        ("# nothing\n", "0", MeshFormatError, "no 'v' lines"),
        ("v 0 0 0\nvt 0 0\n", "0", MeshFormatError, "no 'f' lines"),
    ],
)
def test_read_lim2d_errors(tmp_path, obj, handles, error, word):
    with pytest.raises(error, match=word):
        LimCase.read(lim2d_folder(tmp_path, obj, handles))


def test_read_lim2d_missing_files(tmp_path):
    with pytest.raises(MeshFormatError, match="input.obj"):
        LimCase.read(tmp_path)
    with pytest.raises(MeshFormatError, match="handles.txt"):
        LimCase.read(lim2d_folder(tmp_path, SQUARE_OBJ, handles=None))


# --------------------------------------------------------------------------- VTK


def test_vtk_round_trip_exact(tmp_path):
    rng = np.random.default_rng(1)
    P = rng.normal(size=(20, 3)) * 10.0 ** rng.integers(-100, 100, size=(20, 3))
    P[0] = [-0.0, 1 / 3, 1e-308]
    T = np.array([rng.permutation(20)[:4] for _ in range(15)])
    path = write_vtk_tets(tmp_path / "m.vtk", P, T)
    P2, T2 = read_vtk_tets(path)
    np.testing.assert_array_equal(P2, P)
    np.testing.assert_array_equal(T2, T)
    assert P2.dtype == np.float64 and T2.dtype == np.int64
    assert "POINTS 20 double" in path.read_text()


@pytest.mark.parametrize(
    "content, word",
    [
        (TET_VTK + "CELLS 2 9\n4 0 1 2 3\n3 0 1 2\nCELL_TYPES 2\n10\n5\n", "triangle"),
        (TET_VTK, "expected 'CELLS' after the points, found the end of the file"),
        (TET_VTK.replace("1 0 0\n0 1 0", "1 x 0\n0 1 0") + TET_CELLS, "cannot read 'x' as a number"),
        ("# vtk DataFile Version 2.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 0 double\n"
         "CELLS 0 0\nCELL_TYPES 0\n", "no points"),
        (TET_VTK + "CELLS 0 0\nCELL_TYPES 0\n", "no cells"),
        ("", "empty"),
        (b"\x00\xff\x13 not vtk", "does not start with '# vtk DataFile Version"),
    ],
)
def test_read_vtk_tets_format_errors(tmp_path, content, word):
    with pytest.raises(MeshFormatError, match=word):
        read_vtk_tets(write(tmp_path / "bad.vtk", content))


def test_read_vtk_tets_content_errors(tmp_path):
    with pytest.raises(MeshError, match="outside"):
        read_vtk_tets(write(tmp_path / "oob.vtk", TET_VTK + TET_CELLS.replace("4 0 1 2 3", "4 0 1 2 9")))
    with pytest.raises(MeshFormatError, match="does not exist"):
        read_vtk_tets(tmp_path / "missing.vtk")


def lim3d_folder(folder, rest_points=None, init_points=None, handles="0\n"):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    T = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    write_vtk_tets(folder / "rest.vtk", P if rest_points is None else rest_points, T)
    write_vtk_tets(folder / "init.vtk", 2 * P if init_points is None else init_points, T)
    if handles is not None:
        write(folder / "handles.txt", handles)
    return folder, P, T


def test_read_lim3d_and_handles_fallback(tmp_path):
    folder, P, T = lim3d_folder(tmp_path / "c", handles="4\n0\n")
    case = LimCase.read(folder)
    np.testing.assert_array_equal(case.rest, P)
    np.testing.assert_array_equal(case.init, 2 * P)
    np.testing.assert_array_equal(case.simplices, T)
    assert case.handles.tolist() == [4, 0]
    (folder / "handles.txt").unlink()
    write(folder / "handles_derived_boundary.txt", "1\n2\n")
    assert LimCase.read(folder).handles.tolist() == [1, 2]
    (folder / "handles_derived_boundary.txt").unlink()
    with pytest.raises(MeshFormatError, match="handles"):
        LimCase.read(folder)


def test_read_lim3d_mismatch_errors(tmp_path):
    folder, P, T = lim3d_folder(tmp_path / "a")
    write_vtk_tets(folder / "init.vtk", np.vstack([P, P[:1]]), T)
    with pytest.raises(MeshError, match="points"):
        LimCase.read(folder)
    write_vtk_tets(folder / "init.vtk", P, T[:, [1, 0, 2, 3]])
    with pytest.raises(MeshError, match="connectivity"):
        LimCase.read(folder)
    (folder / "init.vtk").unlink()
    with pytest.raises(MeshFormatError, match="init.vtk"):
        LimCase.read(folder)


# ------------------------------------------------------------------- LIM cases


def test_read_lim_case_dispatch_and_lim_cases(tmp_path):
    d2 = lim2d_folder(tmp_path / "root/2D/sq", SQUARE_OBJ)
    d3, _, _ = lim3d_folder(tmp_path / "root/3D/tet")
    (tmp_path / "root/other").mkdir()
    assert LimCase.cases(tmp_path / "root") == [d2, d3]
    assert LimCase.read(d2).dim == 2
    case = LimCase.read(d3)
    assert case.dim == 3 and case.simplices.shape == (2, 4)
    with pytest.raises(MeshFormatError, match="not a LIM case"):
        LimCase.read(tmp_path / "root/other")
    with pytest.raises(MeshFormatError, match="does not exist"):
        LimCase.read(tmp_path / "nowhere")
    with pytest.raises(MeshFormatError, match="does not exist"):
        LimCase.cases(tmp_path / "nowhere")
    write(d2 / "rest.vtk", "x")
    with pytest.raises(MeshFormatError, match="both"):
        LimCase.read(d2)


def test_lim_case_write_reads_back_bit_for_bit(tmp_path):
    """LimCase.write then LimCase.read gives the same typed fields (2D with a planar rest, 3D)."""
    from geomopt.mesh import generators

    for tangle in (generators.rotated_interior(*generators.square_mesh(5), 90.0),
                   generators.twisted_box(2, 3)):
        case = LimCase.from_tangle(tangle)
        folder = case.write(tmp_path / f"deep/{tangle.dim}d")
        back = LimCase.read(folder)
        assert (back.dim, back.path, back.handles_file) == (tangle.dim, folder, folder / "handles.txt")
        rest = np.c_[tangle.rest, np.zeros(len(tangle.rest))] if tangle.dim == 2 else tangle.rest
        for got, want in ((back.rest, rest), (back.init, tangle.x0), (back.simplices, tangle.simplices),
                          (back.handles, tangle.fixed)):
            np.testing.assert_array_equal(got, want)
        assert LimCase.cases(tmp_path) == sorted([folder] + ([tmp_path / "deep/2d"] if tangle.dim == 3 else []))


def test_lim_case_reads_like_the_old_dict(tmp_path):
    """Code written against read_lim_case's dict keeps working (keys, ** and dict(...))."""
    case = LimCase.read(lim2d_folder(tmp_path / "sq", SQUARE_OBJ))
    assert list(case) == ["dim", "path", "rest", "init", "faces", "handles", "handles_file"]
    assert case["faces"] is case.simplices and case.get("tets") is None and "faces" in case
    assert {**case, "x": 1}["handles"] is case.handles
    d3, _, _ = lim3d_folder(tmp_path / "t")
    assert LimCase.read(d3)["tets"].shape == (2, 4)
    with pytest.raises(MeshError, match="init must have shape"):
        LimCase(dim=2, rest=case.rest, init=case.init[:2], simplices=case.simplices, handles=case.handles)
    with pytest.raises(MeshError, match="2D or 3D"):
        LimCase(dim=4, rest=case.rest, init=case.init, simplices=case.simplices, handles=case.handles)


def signed_contents(X, E):
    """Signed areas (2D, E (m,3)) or 6x volumes (3D, E (m,4)) of the elements."""
    D = X[E[:, 1:]] - X[E[:, :1]]
    if X.shape[1] == 2:
        return D[:, 0, 0] * D[:, 1, 1] - D[:, 0, 1] * D[:, 1, 0]
    return np.linalg.det(D)


def test_shared_lim_cases_match_manifest():
    if not (LIM_ROOT / "manifest.tsv").exists():
        pytest.skip(f"LIM sample data not found at {LIM_ROOT}")
    with open(LIM_ROOT / "manifest.tsv") as fh:
        rows = {row["path"]: row for row in csv.DictReader(fh, delimiter="\t")}
    cases = LimCase.cases(LIM_ROOT)
    assert sorted(str(c.relative_to(LIM_ROOT)) for c in cases) == sorted(rows)
    for folder in cases:
        row = rows[str(folder.relative_to(LIM_ROOT))]
        case = LimCase.read(folder)
        elements = case.simplices
        assert case.dim == int(row["dim"])
        assert case.rest.shape[0] == int(row["n_vertices"]) == case.init.shape[0]
        assert elements.shape[0] == int(row["n_elements"])
        assert case.handles.size == int(row["n_fixed"])
        orient = case.init if case.dim == 2 else case.rest
        s = np.sign(signed_contents(orient, elements).sum())
        inverted = (s * signed_contents(case.init, elements) <= 0).sum()
        assert inverted == int(row["n_inverted_init"])


# ------------------------------------------------------------------------ fuzzing

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-5, 10).map(str),
    st.sampled_from(["x", "1e999", "-0", "", "1/2", "nan", "99999999999999999999999"]),
)
index = st.one_of(
    st.integers(-3, 8).map(str),
    st.tuples(st.integers(-2, 8), st.integers(-2, 8)).map(lambda t: f"{t[0]}/{t[1]}"),
    st.sampled_from(["1//1", "2/2/2", "/1", "a", "", "1/1/1/1", "99999999999999999999999"]),
)
obj_line = st.one_of(
    st.lists(number, max_size=4).map(lambda xs: " ".join(["v", *xs])),
    st.lists(number, max_size=3).map(lambda xs: " ".join(["vt", *xs])),
    st.lists(index, max_size=5).map(lambda xs: " ".join(["f", *xs])),
    st.sampled_from(["# c", "usemtl m", "o obj", "g grp", "vn 0 0 1", "l 1 2", "s off", ""]),
    st.text(max_size=12),
)
obj_text = st.lists(obj_line, max_size=14).map("\n".join)
handles_text = st.lists(st.one_of(st.integers(-2, 8).map(str), st.sampled_from(["x", "1.0", ""])), max_size=5)


def expect_clean(fn, *args):
    """Call ``fn``; only geomopt mesh errors are allowed to escape."""
    try:
        fn(*args)
    except MeshError:
        pass


@FUZZ
@given(data=st.one_of(st.binary(max_size=300), obj_text.map(str.encode)),
       ext=st.sampled_from([".obj", ".off", ".ply", ".stl", ".vtk"]))
def test_fuzz_read_mesh_and_vtk(data, ext):
    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp) / f"m{ext}", data)
        expect_clean(read_vtk_tets if ext == ".vtk" else read_mesh, path)


@FUZZ
@given(obj=st.one_of(obj_text, st.binary(max_size=200)), handles=handles_text)
def test_fuzz_read_lim2d(obj, handles):
    with tempfile.TemporaryDirectory() as tmp:
        expect_clean(LimCase.read, lim2d_folder(tmp, obj, "\n".join(handles)))

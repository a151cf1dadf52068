"""Mesh files are read exactly as they say, or refused with a message naming the real problem.

Issue 10, class 3: every reader (OBJ, OFF, PLY ascii/binary, STL ascii/binary, LIM input.obj,
handles.txt, legacy VTK) against header-count mismatches, byte-order marks, CRLF line ends,
malformed numbers and indices.  The files are written here by hand (independently of
geomopt's writers); a property test runs random small meshes through every format.
"""

from __future__ import annotations

import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from geomopt._runtime.errors import MeshError, MeshFormatError
from geomopt.io import read_mesh, read_vtk_tets, write_ply_with_uv
from geomopt.lim import LimCase

BOM = b"\xef\xbb\xbf"
SQUARE_V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def put(path, data):
    path = Path(path)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


# ------------------------------------------------------------- independent writers


def r(x):
    return repr(float(x))


def obj_bytes(V, F, corner="{a}"):
    """OBJ text; ``corner`` formats one corner from its 1-based index ``a``."""
    lines = [f"v {r(x)} {r(y)} {r(z)}" for x, y, z in V]
    lines += ["f " + " ".join(corner.format(a=a + 1) for a in f) for f in F]
    return ("\n".join(lines) + "\n").encode()


def off_bytes(V, F, nv=None, nf=None):
    lines = ["OFF", f"{len(V) if nv is None else nv} {len(F) if nf is None else nf} 0"]
    lines += [f"{r(x)} {r(y)} {r(z)}" for x, y, z in V]
    lines += [f"{len(f)} " + " ".join(map(str, f)) for f in F]
    return ("\n".join(lines) + "\n").encode()


def ply_header(fmt, nv, nf, vtype="double"):
    return (f"ply\nformat {fmt} 1.0\ncomment by hand\nelement vertex {nv}\nproperty {vtype} x\n"
            f"property {vtype} y\nproperty {vtype} z\nelement face {nf}\n"
            f"property list uchar int vertex_indices\nend_header\n").encode()


def ply_ascii_bytes(V, F, nv=None, nf=None):
    body = "".join(f"{r(x)} {r(y)} {r(z)}\n" for x, y, z in V)
    body += "".join(f"{len(f)} " + " ".join(map(str, f)) + "\n" for f in F)
    return ply_header("ascii", len(V) if nv is None else nv, len(F) if nf is None else nf) + body.encode()


def ply_binary_bytes(V, F, order="<", nv=None, nf=None):
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    body = b"".join(struct.pack(order + "3d", *v) for v in V)
    body += b"".join(struct.pack(order + "B3i", len(f), *f) for f in F)
    return ply_header(fmt, len(V) if nv is None else nv, len(F) if nf is None else nf) + body


def stl_ascii_bytes(V, F):
    out = ["solid test"]
    for f in F:
        out += ["  facet normal 0 0 1", "    outer loop"]
        out += [f"      vertex {r(x)} {r(y)} {r(z)}" for x, y, z in V[f]]
        out += ["    endloop", "  endfacet"]
    return ("\n".join(out + ["endsolid test"]) + "\n").encode()


def stl_binary_bytes(V, F, count=None):
    body = b"".join(struct.pack("<12fH", 0, 0, 1, *V[f].ravel(), 0) for f in F)
    return b"binary stl".ljust(80, b" ") + struct.pack("<I", len(F) if count is None else count) + body


def vtk_bytes(P, T, binary=False, version="2.0", n_points=None, n_cells=None, n_types=None):
    """Legacy VTK; version '5.1' writes OFFSETS/CONNECTIVITY."""
    n, m = len(P), len(T)
    head = f"# vtk DataFile Version {version}\nhand\n{'BINARY' if binary else 'ASCII'}\nDATASET UNSTRUCTURED_GRID\n"
    out = [head.encode(), f"POINTS {n if n_points is None else n_points} double\n".encode()]

    def block(values, code):
        if binary:
            return np.asarray(values, dtype=">" + code).tobytes() + b"\n"
        return (" ".join(r(v) if code == "f8" else str(int(v)) for v in np.ravel(values)) + "\n").encode()

    out.append(block(P, "f8"))
    mc = m if n_cells is None else n_cells
    if version == "5.1":
        out.append(f"CELLS {mc + 1} {4 * m}\nOFFSETS vtktypeint64\n".encode())
        out.append(block(np.arange(m + 1) * 4, "i8"))
        out.append(b"CONNECTIVITY vtktypeint64\n")
        out.append(block(T, "i8"))
    else:
        out.append(f"CELLS {mc} {5 * m}\n".encode())
        out.append(block(np.c_[np.full(m, 4), T], "i4"))
    out.append(f"CELL_TYPES {m if n_types is None else n_types}\n".encode())
    out.append(block(np.full(m, 10), "i4"))
    return b"".join(out)


def crlf(data):
    return data.replace(b"\n", b"\r\n")


# ------------------------------------------------------------------ issue examples


def test_off_header_declaring_fewer_faces_is_refused(tmp_path):
    data = off_bytes(SQUARE_V, SQUARE_F, nf=1)
    with pytest.raises(MeshFormatError, match=r"declares 4 vertices and 1 faces, but the file holds more \(line 8\)"):
        read_mesh(put(tmp_path / "m.off", data))
    with pytest.raises(MeshFormatError, match="declares 5 vertices and 2 faces, but the file ends"):
        read_mesh(put(tmp_path / "m.off", off_bytes(SQUARE_V, SQUARE_F, nv=5)))


def test_bom_at_the_start_is_skipped_and_the_file_read_exactly(tmp_path):
    for name, data in [("m.obj", obj_bytes(SQUARE_V, SQUARE_F)), ("m.off", off_bytes(SQUARE_V, SQUARE_F)),
                       ("m.ply", ply_ascii_bytes(SQUARE_V, SQUARE_F)),
                       ("b.ply", ply_binary_bytes(SQUARE_V, SQUARE_F)),
                       ("m.stl", stl_ascii_bytes(SQUARE_V, SQUARE_F))]:
        V, F = read_mesh(put(tmp_path / name, BOM + data))
        np.testing.assert_array_equal(V, SQUARE_V, err_msg=name)
        np.testing.assert_array_equal(F, SQUARE_F, err_msg=name)


@pytest.mark.parametrize("prefix, word", [(b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"),
                                          (b"\xff\xfe\x00\x00", "UTF-32")])
def test_utf16_and_utf32_text_is_refused_by_name(tmp_path, prefix, word):
    with pytest.raises(MeshFormatError, match=f"{word} text"):
        read_mesh(put(tmp_path / "m.obj", prefix + obj_bytes(SQUARE_V, SQUARE_F)))


def test_bom_in_the_middle_is_refused_with_its_line(tmp_path):
    data = obj_bytes(SQUARE_V, SQUARE_F).replace(b"v 1.0 1.0", BOM + b"v 1.0 1.0")
    with pytest.raises(MeshFormatError, match="line 3: a byte-order mark"):
        read_mesh(put(tmp_path / "m.obj", data))


@pytest.mark.parametrize("token", ["1_0", "+1", "\u0661", " \u0661", "1e3", "0x10", "1.0", "١٠", "--1", "1-"])
def test_handles_accept_only_plain_decimal_integers(tmp_path, token):
    folder = tmp_path / "case"
    folder.mkdir()
    put(folder / "input.obj", obj_bytes(SQUARE_V, SQUARE_F, corner="{a}/{a}").replace(
        b"f ", b"vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf ", 1))
    put(folder / "handles.txt", "0\n")
    assert LimCase.read(folder).handles.tolist() == [0]
    put(folder / "handles.txt", f"0\n{token}\n")
    with pytest.raises(MeshFormatError, match="line 2: cannot read .* as an integer"):
        LimCase.read(folder)
    put(folder / "handles.txt", BOM + b"3\r\n1\r\n")
    assert LimCase.read(folder).handles.tolist() == [3, 1]


def test_obj_relative_indices_count_back_from_the_face(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nf -4 -3 -1\nf 1/1 -2//1 -1/1/1\n"
    V, F = read_mesh(put(tmp_path / "m.obj", text))
    assert F.tolist() == [[0, 1, 2], [0, 1, 3], [0, 2, 3]]
    with pytest.raises(MeshFormatError, match="line 2: .* before the first vertex"):
        read_mesh(put(tmp_path / "m.obj", "v 0 0 0\nf -1 -2 -3\nv 1 0 0\nv 0 1 0\n"))


def test_polygons_are_fan_triangulated_exactly_in_every_format(tmp_path):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 1, 0], [1, 2, 0], [0, 1, 0]])
    fan = [[0, 1, 2], [0, 2, 3], [0, 3, 4]]
    files = {
        "p.obj": b"".join(f"v {r(x)} {r(y)} {r(z)}\n".encode() for x, y, z in V) + b"f 1 2 3 4 5\n",
        "p.off": b"OFF\n5 1 0\n" + b"".join(f"{x} {y} {z}\n".encode() for x, y, z in V) + b"5 0 1 2 3 4\n",
        "p.ply": ply_header("ascii", 5, 1) + b"".join(f"{x} {y} {z}\n".encode() for x, y, z in V)
        + b"5 0 1 2 3 4\n",
        "b.ply": ply_header("binary_big_endian", 5, 2) + b"".join(struct.pack(">3d", *v) for v in V)
        + struct.pack(">B5i", 5, 0, 1, 2, 3, 4) + struct.pack(">B3i", 3, 4, 3, 1),
    }
    for name, data in files.items():
        _, F = read_mesh(put(tmp_path / name, data))
        assert F.tolist()[:3] == fan, name
    assert F.tolist()[3] == [4, 3, 1]
    with pytest.raises(MeshFormatError, match="face has 2 corner"):
        read_mesh(put(tmp_path / "two.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n"))


def test_a_polygon_whose_fan_folds_is_refused_in_every_format(tmp_path):
    """A concave pentagon: its fan from the first corner has a triangle facing backwards, so the
    triangles would not tile it (a folded rest mesh); convex polygons and quads still read."""
    V = np.array([[0.0, 0, 0], [2, 0, 0], [2, 2, 0], [1, 0.5, 0], [0, 2, 0]])
    files = {
        "p.obj": b"".join(f"v {x} {y} {z}\n".encode() for x, y, z in V) + b"f 1 2 3 4 5\n",
        "p.off": b"OFF\n5 1 0\n" + b"".join(f"{x} {y} {z}\n".encode() for x, y, z in V) + b"5 0 1 2 3 4\n",
        "p.ply": ply_header("ascii", 5, 1) + b"".join(f"{x} {y} {z}\n".encode() for x, y, z in V)
        + b"5 0 1 2 3 4\n",
    }
    for name, data in files.items():
        with pytest.raises(MeshFormatError, match="face 1 is a polygon of 5 corners that is not convex"):
            read_mesh(put(tmp_path / name, data))
    _, F = read_mesh(put(tmp_path / "q.obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0.3\nv 0 1 0\nf 1 2 3 4\n"))  # skew quad
    assert F.tolist() == [[0, 1, 2], [0, 2, 3]]


@pytest.mark.parametrize("text, error, word", [
    ("v 0 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormatError, "line 1: 'v' line has 4 numbers|line 1: cannot read 'x'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 x\n", MeshFormatError, "line 4: cannot read face corner 'x'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/\n", MeshFormatError, "line 4: cannot read face corner '3/'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", MeshFormatError, "line 4: .*index 0"),
    ("v 0 0 0\nv 1 0 0 7 7\nv 0 1 0\nf 1 2 3\n", MeshFormatError, "line 2: 'v' line has 5 numbers"),
    ("v 0 0 0\nv 1.0.0 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormatError, "line 2: cannot read '1.0.0' as a number"),
    ("v 0 0 0\nv 0x10 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormatError, "line 2: cannot read '0x10'"),
    ("v 0 0 0\nv 1_0 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormatError, "underscores"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1_0\n", MeshFormatError, "line 4: cannot read face corner '1_0'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 +3\n", MeshFormatError, "line 4: cannot read face corner '\\+3'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\ncurv 0 1 1 2\n", MeshFormatError, "line 4: free-form geometry"),
    ("v 0 0 0\nV 1 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormatError, "line 2: unknown OBJ statement 'V'"),
    ("v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r", MeshFormatError, "carriage return"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", MeshError, "line 4: face corner '4' refers to a vertex beyond"),
    ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", MeshError, "NaN"),
])
def test_obj_malformed_lines_are_refused_by_line(tmp_path, text, error, word):
    with pytest.raises(error, match=word):
        read_mesh(put(tmp_path / "m.obj", text))


def test_obj_accepted_variants_read_exactly(tmp_path):
    text = ("# comment\nv 0 0 0 1.0\nv 1 0 0 0.5 0.5 0.5 # trailing comment\nv 0 1 \\\n 0\nvn 0 0 1\n"
            "vt 0 0\ng part\ns off\nusemtl m\nf 1/1/1 2//1 3/1\nl 1 2\n")
    V, F = read_mesh(put(tmp_path / "m.obj", text))
    np.testing.assert_array_equal(V, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert F.tolist() == [[0, 1, 2]]


def test_obj_slash_corners_read_as_the_general_corner_parser_reads_them(tmp_path, monkeypatch):
    """The fast path for corners of one form ('a/t' ...) gives what the general corner grammar
    gives, or defers to it."""
    import geomopt.io._obj as obj
    from geomopt.io import read_obj_with_uv

    head = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"
    faces = ["f 1/1 2/2 3/3\nf 2/2 4/4 3/3\n", "f -4/-4 -3/-3 -2/-2\nf 2/2 4/4 3/3\n",
             "f 1/1 2/2/1 3/3\nf 2/2 4/4 3/3\n", "f 1/1 2/2 3/3\nf 2/2 4/4 3//1\n", "f 1/1 2/2 3/\nf 2/2 4/4 3/3\n",
             "f 1/1 2/2 3/3/\nf 2/2 4/4 3/3\n", "f 1/1 2/0 3/3\nf 2/2 4/4 3/3\n", "f 1/1 2/2 3/+3\nf 2/2 4/4 3/3\n",
             "f 1/1 2/2 3/3\nf 2/2 4/4 3\n", "f 1/1 2/2 3/3\nf 2/2 4/5 3/3\n", "f 1/1 2/2/2 3\nf 2/2 4/4 3/3\n",
             "f 1//1 2//1 3//1\nf 2//1 4//1 3//1\n", "f 1//1 2/0/1 3//1\nf 2//1 4//1 3//1\n",
             "f 1/1/1 2/2/2 3/3/3\nf 2/2/2 4/4/4 3/3/3\n", "f 1/1/1 2//2 3/3/3\nf 2/2/2 4/4/4 3/3/3\n"]

    def outcome(path):
        try:
            return [a.tolist() for a in read_obj_with_uv(path)]
        except (MeshError, MeshFormatError) as exc:
            return type(exc).__name__, str(exc)

    for i, text in enumerate(faces):
        path = put(tmp_path / f"m{i}.obj", head + text)
        fast = outcome(path)
        with monkeypatch.context() as m:
            m.setattr(obj, "_regular_corners", lambda text, count: None)
            assert outcome(path) == fast, text


def test_obj_vt_w_is_read_only_when_zero(tmp_path):
    """'vt u v w' maps are planar only with w = 0: any other w is refused, not dropped."""
    from geomopt.io import read_obj_with_uv

    head = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    faces = "f 1/1 2/2 3/3\n"
    _, uv, _ = read_obj_with_uv(put(tmp_path / "w0.obj", head + "vt 0 0 0\nvt 1 0\nvt 0 1 -0.0\n" + faces))
    np.testing.assert_array_equal(uv, [[0, 0], [1, 0], [0, 1]])
    with pytest.raises(MeshFormatError, match=r"line 6: 'vt' line has a third coordinate w = '0.5'"):
        read_obj_with_uv(put(tmp_path / "w.obj", head + "vt 0 0\nvt 1 0 0\nvt 0 1 0.5\n" + faces))


def test_off_faces_written_across_lines_are_read_as_geomview_defines(tmp_path):
    # libigl-tutorial-data's inspired_mesh_quads_*.off write "4 a\nb\nc\nd\n": OFF is free format,
    # a face's colour runs to the end of the line of its last index
    head = "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n"
    V, F = read_mesh(put(tmp_path / "q.off", head + "4 0\n1\n2\n3\n\n3 0\n2 1 0.5 0.5 0.5\n"))
    assert F.tolist() == [[0, 1, 2], [0, 2, 3], [0, 2, 1]]
    np.testing.assert_array_equal(V[:, :2], [[0, 0], [1, 0], [1, 1], [0, 1]])
    for body, word in [("4 0\n1\n2\n3\n3 0 2 1\n3 0 1 2\n", "declares 4 vertices and 2 faces, but the file holds more"),
                       ("4 0\n1\n2\n3 1 2 3 4 5\n3 0 2 1\n", "holds more"),  # 5 colour numbers: not a face
                       ("4 0\n1\n2\n3\n3 0 2\n", "holds more"),  # a face cut short by the end of the file
                       ("2 0\n1\n3 0 1 2\n", "holds more")]:
        with pytest.raises(MeshFormatError, match=word):
            read_mesh(put(tmp_path / "bad.off", head + body))


def test_off_variants_and_errors(tmp_path):
    ok = "COFF\n# c\n3 1 3\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2 1 0 0\n"
    V, F = read_mesh(put(tmp_path / "c.off", ok))
    np.testing.assert_array_equal(V, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert F.tolist() == [[0, 1, 2]]
    V, F = read_mesh(put(tmp_path / "inline.off", "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"))
    assert F.tolist() == [[0, 1, 2]]
    for text, word in [
        ("OFF\n3 1 0\n0 0 0 9\n1 0 0\n0 1 0\n3 0 1 2\n", "line 3: vertex line has 4 numbers"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", "line 6: face line declares 4 vertices"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 x\n", "line 6 \\(face colour\\): cannot read 'x'"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1_0\n", "line 6: cannot read '1_0' as an integer"),
        ("OFF\n3 1\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", "declares 3 vertices and 1 faces, but the file holds more"),
        ("COFF\n3 1 0\n0 0 0 1 0 x 1\n1 0 0 1 0 0 1\n0 1 0 1 0 0 1\n3 0 1 2\n", "line 3: cannot read 'x'"),
        ("OFF BINARY\n", "binary OFF"),
        ("4OFF\n3 1 0\n", "not supported"),
        ("MESH\n3 1 0\n", "must start with the keyword 'OFF'"),
    ]:
        with pytest.raises(MeshFormatError, match=word):
            read_mesh(put(tmp_path / "bad.off", text))


def test_ply_header_and_body_checks(tmp_path):
    good = ply_ascii_bytes(SQUARE_V, SQUARE_F)
    cases = [
        (good.replace(b"end_header\n", b""), "no 'end_header' line"),
        (good[:40], "no 'end_header' line"),
        (good.replace(b"element face 2", b"element face 1"), "line 16: the PLY body holds more lines"),
        (good.replace(b"element face 2", b"element face 3"), "declares 3 element 'face' lines but the body ends"),
        (good.replace(b"element vertex 4", b"element vertex 3"), "line 14: element 'vertex' line has 1 values|"
                                                                  "list 'vertex_indices'"),
        (good.replace(b"property double y", b"property doubel y"), "line 6: malformed or unsupported property"),
        (good.replace(b"list uchar int", b"list float int"), "a list count must be an integer type"),
        (good.replace(b"format ascii 1.0", b"format ascii 2.0"), "unsupported PLY format line"),
        (good.replace(b"comment by hand", b"hello"), "line 3: unknown PLY header line"),
        (good.replace(b"3 0 2 3", b"3 0 2 3.0"), "line 16: cannot read '3.0' as an integer"),
        (good.replace(b"3 0 2 3", b"300 0 2 3"), "declares 300 items|does not fit"),
        (good.replace(b"1.0 1.0 0.0", b"1.0 1.0 0.0 9"), "line 13: element 'vertex' line has 4 values"),
        (ply_header("ascii", 4, 2, vtype="float") + b"1e39 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n",
         "does not fit the declared type float32"),
        (ply_binary_bytes(SQUARE_V, SQUARE_F)[:-1], "ends inside element 'face'"),
        (ply_binary_bytes(SQUARE_V, SQUARE_F) + b"\n", "1 bytes longer than the header"),
        (ply_binary_bytes(SQUARE_V, SQUARE_F, nf=1), "bytes longer than the header"),
        (ply_binary_bytes(SQUARE_V, SQUARE_F, nv=5), "do not match the body"),
    ]
    for data, word in cases:
        with pytest.raises(MeshFormatError, match=word):
            read_mesh(put(tmp_path / "bad.ply", data))


def test_ply_float_properties_are_float32_as_declared(tmp_path):
    data = ply_header("ascii", 3, 1, vtype="float") + b"0.1 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    V, _ = read_mesh(put(tmp_path / "f.ply", data))
    assert V[0, 0] == np.float64(np.float32(0.1))
    binary = ply_header("binary_little_endian", 3, 1, vtype="float") + np.array(
        [0.1, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + struct.pack("<B3i", 3, 0, 1, 2)
    V2, _ = read_mesh(put(tmp_path / "b.ply", binary))
    np.testing.assert_array_equal(V2, V)


def test_write_ply_with_uv_round_trips_every_bit(tmp_path):
    rng = np.random.default_rng(3)
    V = rng.normal(size=(7, 3)) * 10.0 ** rng.integers(-300, 300, size=(7, 3))
    V[0] = [-0.0, 5e-324, 1 / 3]
    UV = rng.normal(size=(7, 2))
    F = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]])
    path = write_ply_with_uv(tmp_path / "m.ply", V, F, UV)
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    assert b"format binary_little_endian 1.0" in head and b"property double u\nproperty double v\n" in head
    vert = np.frombuffer(body, np.dtype([(c, "<f8") for c in "xyzuv"]), 7)
    faces = np.frombuffer(body, np.dtype([("n", "u1"), ("i", "<i4", (3,))]), 3, vert.nbytes)
    assert np.array_equal(np.c_[vert["x"], vert["y"], vert["z"]].view(np.int64), V.view(np.int64))
    assert np.array_equal(np.c_[vert["u"], vert["v"]].view(np.int64), UV.view(np.int64))
    assert (faces["n"] == 3).all() and np.array_equal(faces["i"], F)
    V2, F2 = read_mesh(path)
    assert np.array_equal(V2.view(np.int64), V.view(np.int64)) and np.array_equal(F2, F)


def test_stl_corners_are_welded_by_bit_identical_coordinates(tmp_path):
    V = SQUARE_V.astype(np.float32).astype(np.float64)
    for data in (stl_ascii_bytes(V, SQUARE_F), stl_binary_bytes(V, SQUARE_F), crlf(stl_ascii_bytes(V, SQUARE_F))):
        V2, F2 = read_mesh(put(tmp_path / "m.stl", data))
        np.testing.assert_array_equal(V2, V)
        np.testing.assert_array_equal(F2, SQUARE_F)
    minus = stl_ascii_bytes(V, SQUARE_F).replace(b"vertex 0.0 0.0 0.0", b"vertex -0.0 0.0 0.0", 1)
    assert minus != stl_ascii_bytes(V, SQUARE_F)
    V3, F3 = read_mesh(put(tmp_path / "m.stl", minus))  # -0.0 == 0.0: welded (a mirrored export)
    np.testing.assert_array_equal(V3, V)
    np.testing.assert_array_equal(F3, SQUARE_F)


def test_stl_errors(tmp_path):
    good = stl_binary_bytes(SQUARE_V, SQUARE_F)
    for data, word in [
        (good[:-1], r"declares 2 triangles = 184 bytes, but the file has 183"),
        (stl_binary_bytes(SQUARE_V, SQUARE_F, count=3), "declares 3 triangles"),
        (stl_ascii_bytes(SQUARE_V, SQUARE_F).replace(b"endsolid test\n", b""), "no 'endsolid'"),
        (stl_ascii_bytes(SQUARE_V, SQUARE_F) + b"junk\n", "data after 'endsolid'"),
        (stl_ascii_bytes(SQUARE_V, SQUARE_F).replace(b"outer loop", b"outer lop", 1), "line 3: expected 'outer loop'"),
        (stl_ascii_bytes(SQUARE_V, SQUARE_F).replace(b"vertex 1.0 0.0 0.0", b"vertex 1.0 0.0", 1),
         "expected 'vertex x y z'"),
        (stl_ascii_bytes(SQUARE_V, SQUARE_F).replace(b"vertex 1.0 0.0 0.0", b"vertex 1_0 0.0 0.0", 1),
         "underscores"),
        (stl_ascii_bytes(SQUARE_V, SQUARE_F) * 2, "2 separate meshes"),
    ]:
        with pytest.raises(MeshFormatError, match=word):
            read_mesh(put(tmp_path / "bad.stl", data))


TET_P = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
TET_T = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("version", ["2.0", "5.1"])
def test_vtk_versions_and_encodings_read_exactly(tmp_path, binary, version):
    data = vtk_bytes(TET_P, TET_T, binary=binary, version=version)
    P, T = read_vtk_tets(put(tmp_path / "m.vtk", data))
    np.testing.assert_array_equal(P, TET_P)
    np.testing.assert_array_equal(T, TET_T)
    extra = b"POINT_DATA 5\nSCALARS s double 1\nLOOKUP_TABLE default\n1 2 3 4 5\n"
    field = b"FIELD FieldData 1\nTIME 1 1 double\n" + (struct.pack(">d", 0.5) if binary else b"0.5") + b"\n"
    data = data.replace(b"POINTS", field + b"POINTS", 1) + extra
    P, T = read_vtk_tets(put(tmp_path / "m.vtk", BOM + data))
    np.testing.assert_array_equal(P, TET_P)
    np.testing.assert_array_equal(T, TET_T)


@pytest.mark.parametrize("kwargs, word", [
    (dict(n_types=1), "CELLS declares 2 cells but CELL_TYPES declares 1"),
    (dict(n_cells=1), "cells use 5|CELLS declares 1 cells"),
    (dict(n_points=4), "more values follow the POINTS section"),
    (dict(n_points=6), "the POINTS section declares 18 values but 'CELLS' follows after 15"),
])
def test_vtk_count_mismatches_are_refused(tmp_path, kwargs, word):
    with pytest.raises(MeshFormatError, match=word):
        read_vtk_tets(put(tmp_path / "m.vtk", vtk_bytes(TET_P, TET_T, **kwargs)))


def test_vtk_trailing_garbage_and_bad_numbers(tmp_path):
    good = vtk_bytes(TET_P, TET_T)
    for data, word in [(good + b"garbage 1 2\n", "unexpected 'garbage 1 2' after the cell types"),
                       (good + b"10\n", "more values follow the CELL_TYPES section"),
                       (good.replace(b"1.0 0.0 0.0", b"1_0 0.0 0.0", 1), "underscores"),
                       (good.replace(b"DATASET UNSTRUCTURED_GRID", b"DATASET POLYDATA"), "UNSTRUCTURED_GRID"),
                       (vtk_bytes(TET_P, TET_T, binary=True)[:-30], "truncated")]:
        with pytest.raises(MeshFormatError, match=word):
            read_vtk_tets(put(tmp_path / "m.vtk", data))


@pytest.mark.parametrize("old, new, word", [
    (b"POINTS 5 double", b"POINTS 5", "expected 'POINTS n type', found 'POINTS 5'"),
    (b"CELLS 2 10", b"CELLS 2", "expected 'CELLS' after the points, found 'CELLS 2'"),
    (b"CELL_TYPES", b"CELL_KINDS", "expected 'CELL_TYPES' after the cells"),
    (b"CELL_TYPES 2\n10 ", b"CELL_TYPES 2\n4294967306 ", "CELL_TYPES section: a value does not fit the declared type int32"),
])
def test_vtk_section_lines_not_as_declared_are_refused(tmp_path, old, new, word):
    data = vtk_bytes(TET_P, TET_T)
    assert old in data
    with pytest.raises(MeshFormatError, match=word):
        read_vtk_tets(put(tmp_path / "m.vtk", data.replace(old, new)))


def test_readers_restore_the_garbage_collector(tmp_path):
    """The parsers pause the cyclic GC (speed); it must come back on, also after a refusal."""
    import gc

    good, bad = put(tmp_path / "m.off", off_bytes(SQUARE_V, SQUARE_F)), put(tmp_path / "b.off", b"OFF\n")
    read_mesh(good)
    with pytest.raises(MeshFormatError):
        read_mesh(bad)
    assert gc.isenabled()
    gc.disable()
    try:
        read_mesh(good)
        assert not gc.isenabled()  # and a caller's choice to keep it off is kept
    finally:
        gc.enable()


def test_each_reader_failure_names_its_own_problem(tmp_path):
    """Class 7: no generic 'a face probably refers to a vertex that does not exist' for everything."""
    messages = []
    for name, data in [("trunc.ply", ply_ascii_bytes(SQUARE_V, SQUARE_F)[:30]),
                       ("mid_bom.obj", b"v 0 0 0\n" + BOM + b"v 1 0 0\nv 0 1 0\nf 1 2 3\n"),
                       ("count.off", off_bytes(SQUARE_V, SQUARE_F, nf=1)),
                       ("utf16.off", "OFF\n".encode("utf-16"))]:
        with pytest.raises(MeshFormatError) as info:
            read_mesh(put(tmp_path / name, data))
        messages.append(str(info.value))
    assert "end_header" in messages[0]
    assert "byte-order mark" in messages[1]
    assert "declares 4 vertices and 1 faces" in messages[2]
    assert "UTF-16" in messages[3]
    assert not any("does not exist" in m for m in messages)


# ------------------------------------------------------------------ property test

@st.composite
def small_meshes(draw, k=3, width=64):
    """(V (n, 3) distinct float64 rows, representable in ``width`` bits; F (m, k) distinct indices per row)."""
    n = draw(st.integers(k, 9))
    coordinate = st.floats(allow_nan=False, allow_infinity=False, width=width)
    V = np.array(draw(st.lists(st.tuples(coordinate, coordinate, coordinate), min_size=n, max_size=n,
                               unique=True)), dtype=np.float64).reshape(n, 3)
    F = np.array(draw(st.lists(st.permutations(range(n)).map(lambda p: p[:k]), min_size=1, max_size=8)),
                 dtype=np.int64).reshape(-1, k)
    return V, F


def expected_stl(V, F):
    """Corners welded in order of first appearance (an independent, dict-based weld)."""
    corners = V[F].reshape(-1, 3)
    ids, verts = {}, []
    for c in corners:
        key = c.tobytes()
        if key not in ids:
            ids[key] = len(verts)
            verts.append(c)
    return np.array(verts), np.array([ids[c.tobytes()] for c in corners]).reshape(-1, 3)


def same_bits(A, B):
    A, B = np.asarray(A, np.float64), np.asarray(B, np.float64)
    return A.shape == B.shape and np.array_equal(A.view(np.int64), B.view(np.int64))


FORMATS = ["obj", "obj_slash", "obj_negative", "off", "ply_ascii", "ply_le", "ply_be", "stl_ascii",
           "stl_binary", "lim2d", "vtk", "vtk_binary", "vtk51"]


def make_file(folder, fmt, V, F, mismatch):
    """Write one mesh in ``fmt``; ``mismatch`` (+1/-1/0) shifts a declared count (or corrupts an OBJ)."""
    d = mismatch
    if fmt.startswith("obj"):
        corner = {"obj": "{a}", "obj_slash": "{a}/{a}", "obj_negative": "-{neg}"}[fmt]
        lines = [f"v {r(x)} {r(y)} {r(z)}" for x, y, z in V]
        lines += ["f " + " ".join(corner.format(a=a + 1, neg=len(V) - a) for a in f) for f in F]
        if d:
            lines[0] += " junk" if d > 0 else " 1 2"  # 5 numbers: neither w nor r g b
        return put(folder / "m.obj", ("\n".join(lines) + "\n").encode())
    if fmt == "off":
        return put(folder / "m.off", off_bytes(V, F, nf=len(F) + d))
    if fmt == "ply_ascii":
        return put(folder / "m.ply", ply_ascii_bytes(V, F, nf=len(F) + d))
    if fmt in ("ply_le", "ply_be"):
        return put(folder / "m.ply", ply_binary_bytes(V, F, "<" if fmt == "ply_le" else ">", nv=len(V) + d))
    if fmt == "stl_ascii":
        data = stl_ascii_bytes(V, F)
        return put(folder / "m.stl", data if not d else data.replace(b"endfacet\n", b"", 1))
    if fmt == "stl_binary":
        return put(folder / "m.stl", stl_binary_bytes(V, F, count=len(F) + d))
    if fmt == "lim2d":
        lines = [f"v {r(x)} {r(y)} {r(z)}" for x, y, z in V]
        lines += [f"vt {r(x)} {r(y)}" for x, y, _ in V[: len(V) + min(d, 0)]]
        lines += ["f " + " ".join(f"{a + 1}/{a + 1}" for a in f) for f in F]
        put(folder / "handles.txt", "\n".join(map(str, range(0, len(V), 2))) + ("\n1_0" if d > 0 else ""))
        return put(folder / "input.obj", ("\n".join(lines) + "\n").encode())
    binary, version = fmt == "vtk_binary", "5.1" if fmt == "vtk51" else "2.0"
    return put(folder / "m.vtk", vtk_bytes(V, F, binary=binary, version=version, n_types=len(F) + d))


def read_back(fmt, path):
    if fmt == "lim2d":
        case = LimCase.read(path.parent)
        return case["rest"], case["faces"], case
    if fmt.startswith("vtk"):
        return (*read_vtk_tets(path), None)
    return (*read_mesh(path), None)


TEXT = {"obj", "obj_slash", "obj_negative", "off", "ply_ascii", "stl_ascii", "lim2d", "vtk", "vtk51"}


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), fmt=st.sampled_from(FORMATS), bom=st.booleans(), line_ends=st.booleans(),
       mismatch=st.sampled_from([0, 0, 1, -1]))
def test_every_format_reads_exactly_what_was_written_or_refuses(data, fmt, bom, line_ends, mismatch):
    V, F = data.draw(small_meshes(k=4 if fmt.startswith("vtk") else 3, width=32 if fmt == "stl_binary" else 64))
    if fmt.startswith("stl"):  # distinct rows as bits (-0.0 and 0.0 compare equal but are not welded)
        assume(len({v.tobytes() for v in V}) == len({tuple(v) for v in V.tolist()}))
    with tempfile.TemporaryDirectory() as tmp:
        path = make_file(Path(tmp), fmt, V, F, mismatch)
        raw = path.read_bytes()
        if line_ends and (fmt in TEXT or fmt.startswith("ply")):
            head, sep, body = raw.partition(b"end_header\n")
            raw = crlf(raw) if fmt in TEXT else crlf(head + sep) + body  # binary PLY: the header only
        if bom and fmt != "stl_binary":
            raw = BOM + raw
        path.write_bytes(raw)
        if mismatch:
            with pytest.raises(MeshFormatError):
                read_back(fmt, path)
            return
        V2, F2, case = read_back(fmt, path)
    if fmt.startswith("stl"):
        V, F = expected_stl(V, F)
    assert same_bits(V2, V), (fmt, V2, V)
    assert np.array_equal(F2, F), (fmt, F2, F)
    if case is not None:
        assert same_bits(case["init"], V[:, :2]) and case["handles"].tolist() == list(range(0, len(V), 2))


MUTANTS_V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]])
MUTANTS_F = np.array([[0, 1, 2], [0, 2, 3], [1, 2, 4]])
MUTANTS_T = np.array([[0, 1, 2, 4], [0, 2, 3, 4]])
MUTANTS = {
    "m.obj": obj_bytes(MUTANTS_V, MUTANTS_F, "{a}/{a}/{a}"), "m.off": off_bytes(MUTANTS_V, MUTANTS_F),
    "a.ply": ply_ascii_bytes(MUTANTS_V, MUTANTS_F), "l.ply": ply_binary_bytes(MUTANTS_V, MUTANTS_F),
    "b.ply": ply_binary_bytes(MUTANTS_V, MUTANTS_F, ">"), "a.stl": stl_ascii_bytes(MUTANTS_V, MUTANTS_F),
    "b.stl": stl_binary_bytes(MUTANTS_V, MUTANTS_F), "a.vtk": vtk_bytes(MUTANTS_V, MUTANTS_T),
    "b.vtk": vtk_bytes(MUTANTS_V, MUTANTS_T, binary=True),
    "c.vtk": vtk_bytes(MUTANTS_V, MUTANTS_T, binary=True, version="5.1"),
}
edit = st.tuples(st.sampled_from(["flip", "delete", "insert", "truncate", "repeat"]), st.integers(0, 10**6),
                 st.binary(min_size=1, max_size=4))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(sorted(MUTANTS)), edits=st.lists(edit, min_size=1, max_size=3))
def test_damaged_files_are_read_or_refused_with_a_mesh_error(name, edits):
    """Valid files with a few bytes flipped, deleted, inserted or repeated, or truncated: never another exception."""
    b = bytearray(MUTANTS[name])
    for op, pos, blob in edits:
        p = pos % max(len(b), 1)
        if op == "flip" and b:
            b[p] ^= blob[0] or 1
        elif op == "delete":
            del b[p:p + len(blob)]
        elif op == "insert":
            b[p:p] = blob
        elif op == "truncate":
            del b[p:]
        else:
            b[p:p] = b[p:p + 8]
    with tempfile.TemporaryDirectory() as tmp:
        path = put(Path(tmp) / name, bytes(b))
        try:
            (read_vtk_tets if name.endswith(".vtk") else read_mesh)(path)
        except MeshError:
            pass


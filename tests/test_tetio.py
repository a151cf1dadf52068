"""Tet-mesh formats (geomopt.io.read_tets / write_tets): each advertised format read exactly or
refused, written so it reads back exactly."""

import numpy as np
import pytest

import geomopt
from geomopt import io
from geomopt._runtime import formats

from conftest import cube_tets

# one cube of 6 tets in Gmsh 2.2 / 4.1 and Medit (vertices 1-based)
_P1, _T1 = cube_tets(1)


def _msh22(tags=range(1, 9)):
    """The cube in MSH 2.2 ASCII; node i gets tag ``tags[i]``."""
    tags = list(tags)
    nodes = "".join(f"{tags[i]} {x!r} {y!r} {z!r}\n" for i, (x, y, z) in enumerate(_P1.tolist()))
    elems = "".join(f"{k + 1} 4 2 0 1 {' '.join(str(tags[v]) for v in t)}\n" for k, t in enumerate(_T1))
    return (f"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n8\n{nodes}$EndNodes\n"
            f"$Elements\n6\n{elems}$EndElements\n")


def _msh41(tags=range(1, 9)):
    """The cube in MSH 4.1 ASCII (one node block, one element block); node i gets tag ``tags[i]``."""
    tags = list(tags)
    return (f"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 8 {min(tags)} {max(tags)}\n3 1 0 8\n"
            + "".join(f"{t}\n" for t in tags) + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in _P1.tolist())
            + "$EndNodes\n$Elements\n1 6 1 6\n3 1 4 6\n"
            + "".join(f"{k + 1} {' '.join(str(tags[v]) for v in t)}\n" for k, t in enumerate(_T1))
            + "$EndElements\n")


MSH22, MSH41 = _msh22(), _msh41()
MEDIT = ("MeshVersionFormatted 2\nDimension 3\nVertices\n8\n"
         + "".join(f"{x!r} {y!r} {z!r} 0\n" for x, y, z in _P1.tolist())
         + "Tetrahedra\n6\n" + "".join(f"{' '.join(str(v + 1) for v in t)} 1\n" for t in _T1) + "End\n")


def _jittered(n=2):
    V, T = cube_tets(n)
    return V + np.pi * 1e-3 * np.arange(len(V))[:, None], T  # digits that a short float format would lose


@pytest.mark.parametrize("ext", formats.extensions("tetra", writable=True))  # every writable row of the table
def test_every_format_round_trips_bit_exactly_and_creates_only_the_file(tmp_path, ext):
    V, T = _jittered()
    path = io.write_tets(tmp_path / f"cube{ext}", V, T)
    assert [p.name for p in tmp_path.iterdir()] == [f"cube{ext}"]
    P2, T2 = io.read_tets(path)
    np.testing.assert_array_equal(P2, V)
    np.testing.assert_array_equal(T2, T)
    assert P2.dtype == np.float64 and T2.dtype == np.int64
    if ext == ".msh":
        assert path.read_text().startswith("$MeshFormat\n4.1 0 8\n")  # ASCII, checkable on reading


def test_gmsh_22_and_41_and_medit_text_read_exactly(tmp_path):
    for name, text in (("a.msh", MSH22), ("b.msh", MSH41), ("c.mesh", MEDIT)):
        (tmp_path / name).write_text(text)
        P, T = io.read_tets(tmp_path / name)
        np.testing.assert_array_equal(P, _P1)
        np.testing.assert_array_equal(T, _T1)


def test_gmsh_22_written_by_meshio_reads_exactly(tmp_path):
    import meshio

    V, T = _jittered()
    meshio.gmsh.write(str(tmp_path / "c.msh"), meshio.Mesh(V, [("tetra", T)]), fmt_version="2.2", binary=False)
    P2, T2 = io.read_tets(tmp_path / "c.msh")
    np.testing.assert_array_equal(P2, V)
    np.testing.assert_array_equal(T2, T)


def test_gmsh_node_tags_need_not_be_contiguous(tmp_path):
    tags = [7, 3, 100, 42, 5, 9, 11, 2]  # legal: unique, any order, gaps
    (tmp_path / "a.msh").write_text(_msh22(tags))
    (tmp_path / "b.msh").write_text(_msh41(tags))
    for name in ("a.msh", "b.msh"):
        P, T = io.read_tets(tmp_path / name)
        np.testing.assert_array_equal(P, _P1)  # file order
        np.testing.assert_array_equal(T, _T1)  # tags mapped to those rows


def test_gmsh_boundary_faces_beside_the_tets_are_ignored_other_volume_cells_refused(tmp_path):
    text = MSH22.replace("$Elements\n6\n", "$Elements\n7\n").replace("$EndElements", "7 2 2 0 1 1 2 3\n$EndElements")
    (tmp_path / "a.msh").write_text(text)
    np.testing.assert_array_equal(io.read_tets(tmp_path / "a.msh")[1], _T1)
    text = MSH22.replace("$Elements\n6\n", "$Elements\n7\n").replace(
        "$EndElements", "7 5 2 0 1 1 2 3 4 5 6 7 8\n$EndElements")
    (tmp_path / "b.msh").write_text(text)
    with pytest.raises(geomopt.MeshFormatError, match="mixes 6 tetrahedra and 1 hexahedron"):
        io.read_tets(tmp_path / "b.msh")


_ELEM_LINE = "$Elements\n6\n"
_FIRST41 = MSH41.split("3 1 4 6\n")[1].split("\n")[0]  # the first element line of MSH41
MALFORMED = {
    # Gmsh 2.2
    "msh_fewer_elems": ("msh", MSH22.replace(_ELEM_LINE, "$Elements\n5\n"), r"\$Elements .* declares 5 entries but holds 6"),
    "msh_more_elems": ("msh", MSH22.replace(_ELEM_LINE, "$Elements\n7\n"), r"declares 7 entries but holds 6; the file is truncated"),
    "msh_fewer_nodes": ("msh", MSH22.replace("$Nodes\n8\n", "$Nodes\n7\n"), r"\$Nodes .* declares 7 entries but holds 8"),
    "msh_no_end_elements": ("msh", MSH22.replace("$EndElements\n", ""), r"\$Elements .* not closed by \$EndElements"),
    "msh_no_end_nodes": ("msh", MSH22.replace("$EndNodes\n", ""), r"\$Nodes .* not closed by \$EndNodes"),
    "msh_undefined_node": ("msh", MSH22.replace("\n8 1.0 1.0 1.0\n", "\n100 1.0 1.0 1.0\n"),
                           "an element refers to node tag 8, which \\$Nodes does not define"),
    "msh_triangle_undefined_node": ("msh", MSH22.replace("$Elements\n6\n", "$Elements\n7\n").replace(
        "$EndElements", "7 2 2 0 1 1 2 99\n$EndElements"), "an element refers to node tag 99"),
    "msh41_undefined_node": ("msh", MSH41.replace(f"3 1 4 6\n{_FIRST41}\n", f"3 1 4 6\n{_FIRST41[:-1]}9\n"),
                             "an element refers to node tag 9"),
    "msh_bad_coordinate": ("msh", MSH22.replace("\n2 0.0 0.0 1.0\n", "\n2 0.0 0,0 1.0\n"),
                           r"line 7: expected a number \(\$Nodes\), found '0,0'"),
    "msh41_bad_coordinate": ("msh", MSH41.replace("\n0.0 0.0 1.0\n", "\n0.0 1.0x 1.0\n"), "found '1.0x'"),
    "mesh_bad_coordinate": ("mesh", MEDIT.replace("\n0.0 0.0 1.0 0\n", "\n0.0 0x10 1.0 0\n"),
                            r"line 6: expected a number \(Vertices\), found '0x10'"),
    "msh_short_element": ("msh", MSH22.replace("\n1 4 2 0 1 ", "\n1 4 2 0 ", 1), "needs 9 values, found 8"),
    "msh_binary": ("msh", MSH22.replace("2.2 0 8", "2.2 1 8"), "binary Gmsh file; only ASCII"),
    "msh_version_40": ("msh", MSH22.replace("2.2 0 8", "4 0 8"), "version '4' is not supported"),
    "msh_duplicate_tag": ("msh", MSH22.replace("\n2 0.0", "\n1 0.0", 1), "node tag is defined twice"),
    "msh_junk": ("msh", "$MeshFormat\nnot a mesh\n", "version 'not' is not supported"),
    "msh_stray_text": ("msh", MSH22 + "hello\n", "'hello' outside a section"),
    "msh_stray_text_between": ("msh", MSH22.replace("$EndMeshFormat\n", "$EndMeshFormat\nhello 1\n"),
                               "line 4: 'hello 1' outside a section"),
    # Gmsh 4.1
    "msh41_node_count": ("msh", MSH41.replace("1 8 1 8\n", "1 9 1 9\n"), r"\$Nodes .* declares 9 nodes"),
    "msh41_tag_range": ("msh", MSH41.replace("1 8 1 8\n", "1 8 1 9\n"), r"node tags 1\.\.8 but its header says 1\.\.9"),
    "msh41_block_count": ("msh", MSH41.replace("3 1 4 6\n", "3 1 4 5\n"), r"\$Elements \(line 24\) holds more blocks than the 1 it declares"),
    "msh41_elements_short": ("msh", MSH41.replace("\n6 1 ", "\n6 ", 1), "type-4 element entry has 4 values, expected 5"),
    # Medit
    "mesh_fewer": ("mesh", MEDIT.replace("Tetrahedra\n6\n", "Tetrahedra\n5\n"), "Tetrahedra .* declares 5 entries but more follow"),
    "mesh_more": ("mesh", MEDIT.replace("Tetrahedra\n6\n", "Tetrahedra\n7\n"), "Tetrahedra .* declares 7 entries but holds 6"),
    "mesh_vfew": ("mesh", MEDIT.replace("Vertices\n8\n", "Vertices\n7\n"), "Vertices .* declares 7 entries but more follow"),
    "mesh_noend": ("mesh", MEDIT.replace("End\n", ""), "has no End keyword"),
    "mesh_after_end": ("mesh", MEDIT + "Triangles\n0\n", "text after End"),
    "mesh_idx0": ("mesh", MEDIT.replace("\nTetrahedra\n6\n1 ", "\nTetrahedra\n6\n0 "), "refers to vertex 0; Medit vertices are numbered 1..8"),
    "mesh_idx9": ("mesh", MEDIT.replace("\nTetrahedra\n6\n1 ", "\nTetrahedra\n6\n9 "), "refers to vertex 9"),
    "mesh_float_index": ("mesh", MEDIT.replace("\nTetrahedra\n6\n1 ", "\nTetrahedra\n6\n1.5 "), r"line 15: expected an integer \(Tetrahedra entry\), found '1.5'"),
    "mesh_plus_index": ("mesh", MEDIT.replace("\nTetrahedra\n6\n1 ", "\nTetrahedra\n6\n+1 "), "found '\\+1'"),
    "mesh_width": ("mesh", MEDIT.replace(" 0\n", "\n", 1), "the Vertices entry has 3 values, expected 4"),
    "mesh_dim2": ("mesh", MEDIT.replace("Dimension 3", "Dimension 2"), "needs Dimension 3"),
    "mesh_unknown_section": ("mesh", MEDIT.replace("End\n", "Foo\n0\nEnd\n"), "unsupported Medit section 'Foo'"),
    # legacy VTK (through geomopt.io's reader)
    "vtk_celltypes_short": ("vtk", None, "CELL_TYPES section declares 6 values but the file ends after 5"),
    "vtk_two_points": ("vtk", None, "expected 'CELLS' after the points, found 'POINTS"),
    # VTK XML
    "vtu_truncated": ("vtu", None, "malformed XML .* truncated"),
}


def _malformed_text(name, tmp_path):
    ext, text, _ = MALFORMED[name]
    if text is not None:
        return text
    if ext == "vtk":
        geomopt.io.write_vtk_tets(tmp_path / "ok.vtk", _P1, _T1)
        good = (tmp_path / "ok.vtk").read_text()
        if name == "vtk_celltypes_short":
            return good.rsplit("10\n", 1)[0]
        points = good[good.index("POINTS"):good.index("CELLS")]
        return good.replace("CELLS", points + "CELLS")
    io.write_tets(tmp_path / "ok.vtu", _P1, _T1)
    good = (tmp_path / "ok.vtu").read_text()
    return good[: len(good) // 2]


@pytest.mark.parametrize("name", list(MALFORMED))
def test_malformed_files_are_refused_with_a_message_saying_what_is_wrong(tmp_path, capfd, name):
    ext, _, message = MALFORMED[name]
    path = tmp_path / f"{name}.{ext}"
    path.write_text(_malformed_text(name, tmp_path))
    with pytest.raises(geomopt.MeshFormatError, match=message) as info:
        io.read_tets(path)
    assert str(path) in str(info.value)
    assert capfd.readouterr() == ("", "")  # meshio's own messages are not printed


def test_vtk_keywords_are_case_insensitive_as_in_vtk_itself(tmp_path):
    geomopt.io.write_vtk_tets(tmp_path / "up.vtk", _P1, _T1)
    text = (tmp_path / "up.vtk").read_text()
    (tmp_path / "low.vtk").write_text(text.replace("POINTS", "points").replace("CELLS", "cells")
                                      .replace("CELL_TYPES", "cell_types").replace("double", "DOUBLE"))
    for read in (geomopt.io.read_vtk_tets, io.read_tets):
        P, T = read(tmp_path / "low.vtk")
        np.testing.assert_array_equal(P, _P1)
        np.testing.assert_array_equal(T, _T1)


# extensions of other meshes and formats, less those the table reads tets from
_UNSUPPORTED = [e for e in (".stl", ".off", ".ply", ".obj", ".ugrid", ".xdmf", ".med", ".h5m", ".inp", "")
                if e not in formats.extensions("tetra")]


@pytest.mark.parametrize("ext", _UNSUPPORTED)
def test_unsupported_extensions_are_refused_on_write_and_read_creating_nothing(tmp_path, ext):
    V, T = _jittered(1)
    with pytest.raises(geomopt.MeshFormatError, match=r"supported tet-mesh formats: \.vtk .*\.vtu .*\.msh .*\.mesh"):
        io.write_tets(tmp_path / f"cube{ext}", V, T)
    assert not any(tmp_path.iterdir())
    (tmp_path / f"cube{ext}").write_text(MSH22)
    with pytest.raises(geomopt.MeshFormatError, match="supported tet-mesh formats"):
        io.read_tets(tmp_path / f"cube{ext}")


def test_meshio_warnings_are_not_printed(tmp_path, capfd):
    # meshio warns (on stderr, through rich) about Medit sections it skips; the read is still exact
    (tmp_path / "a.mesh").write_text(MEDIT.replace("End\n", "RequiredVertices\n2\n1\n2\nEnd\n"))
    P, T = io.read_tets(tmp_path / "a.mesh")
    np.testing.assert_array_equal(T, _T1)
    V, T = _jittered(1)
    for ext in (".msh", ".mesh", ".vtu"):
        io.write_tets(tmp_path / f"w{ext}", V, T)
    assert capfd.readouterr() == ("", "")


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    import meshio

    V, T = _jittered(1)
    target = tmp_path / "c.vtu"
    target.write_text("old")

    def broken(filename, *args, **kwargs):
        with open(filename, "w") as fh:
            fh.write("<VTKFile half")  # a partial file, then a failure
        raise meshio.WriteError("disk on fire")

    monkeypatch.setattr(meshio.vtu, "write", broken)
    with pytest.raises(geomopt.GeomoptError, match="could not write .*c.vtu.*disk on fire.*nothing was written"):
        io.write_tets(target, V, T)
    assert [p.name for p in tmp_path.iterdir()] == ["c.vtu"] and target.read_text() == "old"


def test_invalid_arrays_and_contents_are_mesh_errors(tmp_path):
    import meshio

    V, T = cube_tets(1)
    with pytest.raises(geomopt.MeshError):
        io.write_tets(tmp_path / "bad.vtu", V, T + 100)  # index out of range
    assert not any(tmp_path.iterdir())
    meshio.vtu.write(str(tmp_path / "tris.vtu"), meshio.Mesh(V, [("triangle", T[:, :3])]))
    with pytest.raises(geomopt.MeshFormatError, match="no tetrahedra"):
        io.read_tets(tmp_path / "tris.vtu")
    bad = V.copy()
    bad[0, 0] = np.nan
    meshio.vtu.write(str(tmp_path / "nan.vtu"), meshio.Mesh(bad, [("tetra", T)]))
    with pytest.raises(geomopt.MeshError):
        io.read_tets(tmp_path / "nan.vtu")
    with pytest.raises(geomopt.MeshFormatError, match="does not exist"):
        io.read_tets(tmp_path / "missing.msh")
    (tmp_path / "empty.mesh").write_text("")
    with pytest.raises(geomopt.MeshFormatError, match="empty"):
        io.read_tets(tmp_path / "empty.mesh")


# ------------------------------------------------------------------ issue 19: read exactly or refuse

import base64  # noqa: E402
import re  # noqa: E402
import zlib  # noqa: E402

_VTU_TYPES = {"f8": "Float64", "f4": "Float32", "i8": "Int64", "i4": "Int32", "u1": "UInt8", "i1": "Int8",
              "u4": "UInt32", "u8": "UInt64", "i2": "Int16"}


def _vtu(pieces, fmt="ascii", header="UInt32", compressor=None, order="<", version="1.0", blocks=2):
    """A VTU file written here, independently of the reader: ``pieces`` is a list of
    ``(points, connectivity, offsets, types)``; ``fmt`` ascii | binary | raw | base64 (appended)."""
    hdt = np.dtype(order + {"UInt32": "u4", "UInt64": "u8"}[header])
    appended, parts = bytearray(), []

    def encode(values, code):
        values = np.asarray(values, dtype=order + code)
        if fmt == "ascii":
            return 'format="ascii">' + " ".join(repr(v) if code[0] == "f" else str(v) for v in values.tolist()) + \
                "</DataArray>"
        raw = values.tobytes()
        if compressor:
            size = max(1, -(-len(raw) // blocks))
            chunks = [raw[i:i + size] for i in range(0, len(raw), size)]
            comp = [zlib.compress(c) for c in chunks]
            head = np.array([len(chunks), size, len(chunks[-1]) if chunks else 0] + [len(c) for c in comp], hdt)
            pieces_ = [head.tobytes(), b"".join(comp)]
        else:
            pieces_ = [np.array([len(raw)], hdt).tobytes(), raw]
        if fmt == "binary":
            return 'format="binary">' + "".join(base64.b64encode(p).decode() for p in pieces_) + "</DataArray>"
        at = len(appended)
        appended.extend(b"".join(pieces_) if fmt == "raw" else b"".join(base64.b64encode(p) for p in pieces_))
        return f'format="appended" offset="{at}"/>'

    def array(name, values, code, comps=1):
        return f'<DataArray type="{_VTU_TYPES[code]}" Name="{name}" NumberOfComponents="{comps}" ' + \
            encode(np.ravel(values), code)

    for points, conn, offsets, types in pieces:
        parts.append(f'<Piece NumberOfPoints="{len(points)}" NumberOfCells="{len(types)}">'
                     f'<Points>{array("Points", points, "f8" if np.asarray(points).dtype != np.float32 else "f4", 3)}'
                     f'</Points><Cells>{array("connectivity", conn, "i8")}{array("offsets", offsets, "i4")}'
                     f'{array("types", types, "u1")}</Cells></Piece>')
    attrs = f'type="UnstructuredGrid" version="{version}" byte_order="{"LittleEndian" if order == "<" else "BigEndian"}" ' \
            f'header_type="{header}"' + (' compressor="vtkZLibDataCompressor"' if compressor else "")
    text = (f'<?xml version="1.0"?>\n<VTKFile {attrs}>\n<UnstructuredGrid>' + "".join(parts) + "</UnstructuredGrid>\n")
    tail = b"</VTKFile>\n"
    if fmt in ("raw", "base64"):
        return text.encode() + f'<AppendedData encoding="{fmt}">\n_'.encode() + bytes(appended) + \
            b"\n</AppendedData>\n" + tail
    return text.encode() + tail


def _cube_vtu(**kw):
    return _vtu([(_P1, _T1.ravel(), 4 * np.arange(1, 7), [10] * 6)], **kw)


@pytest.mark.parametrize("kw", [dict(), dict(fmt="binary"), dict(fmt="binary", compressor="zlib"),
                                dict(fmt="raw"), dict(fmt="raw", compressor="zlib", header="UInt64"),
                                dict(fmt="base64"), dict(fmt="base64", compressor="zlib", blocks=3),
                                dict(fmt="binary", order=">", header="UInt64"), dict(version="0.1")])
def test_vtu_every_encoding_reads_exactly(tmp_path, kw):
    (tmp_path / "c.vtu").write_bytes(_cube_vtu(**kw))
    P, T = io.read_tets(tmp_path / "c.vtu")
    np.testing.assert_array_equal(P, _P1)
    np.testing.assert_array_equal(T, _T1)


def test_vtu_pieces_and_boundary_cells_read_in_file_order(tmp_path):
    """Two pieces (indices local to each), triangles and a vertex cell beside the tets are skipped."""
    tri = [0, 1, 2]
    pieces = [(_P1, np.r_[_T1[:2].ravel(), tri], [4, 8, 11], [10, 10, 5]),
              (_P1, np.r_[[5], _T1[2:].ravel()], [1, 5, 9, 13, 17], [1, 10, 10, 10, 10])]
    (tmp_path / "p.vtu").write_bytes(_vtu(pieces, fmt="raw", compressor="zlib"))
    P, T = io.read_tets(tmp_path / "p.vtu")
    np.testing.assert_array_equal(P, np.vstack([_P1, _P1]))
    np.testing.assert_array_equal(T, np.vstack([_T1[:2], _T1[2:] + 8]))


_BAD_VTU = {
    "unknown cell type": ([99] * 6, None, None, "unknown VTK cell type 99"),
    "voxel": ([10] * 5 + [11], np.r_[_T1.ravel(), [0, 1, 2, 3]], np.r_[4 * np.arange(1, 6), 28],
              "non-tetrahedral volume cells \\(voxel\\)"),
    "Lagrange tetrahedron": ([71] + [10] * 5, None, None, "non-tetrahedral volume cells \\(Lagrange tetrahedron\\)"),
    "Bezier hexahedron": ([79] + [10] * 5, None, None, "Bezier hexahedron"),
    "duplicated offset": ([10] * 6, None, [4, 8, 8, 12, 16, 20], "cell 2 has no points"),
    "extra connectivity": ([10] * 6, np.r_[_T1.ravel(), 7], None, "connectivity holds 25 values but the offsets use 24"),
    "short tet": ([10] * 6, _T1.ravel()[:-1], [4, 8, 12, 16, 20, 23], "cell 5 is a tetra with 3 points, expected 4"),
    "offsets count": ([10] * 6, None, 4 * np.arange(1, 6), "offsets holds 5 values, expected 6"),
    "index range": ([10] * 6, np.r_[_T1.ravel()[:-1], 8], None, "point index 8.*0..7"),
    "falling offsets": ([10] * 6, None, [4, 12, 8, 16, 20, 24], "cell 2 has no points|must rise"),
}


@pytest.mark.parametrize("name", list(_BAD_VTU))
def test_vtu_cells_not_as_declared_are_refused(tmp_path, capfd, name):
    types, conn, offsets, words = _BAD_VTU[name]
    conn = _T1.ravel() if conn is None else conn
    offsets = 4 * np.arange(1, 7) if offsets is None else offsets
    for fmt in ("ascii", "binary"):
        path = tmp_path / f"bad-{fmt}.vtu"
        path.write_bytes(_vtu([(_P1, conn, offsets, types)], fmt=fmt))
        with pytest.raises(geomopt.MeshFormatError, match=words) as info:
            io.read_tets(path)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
    assert capfd.readouterr() == ("", "")


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace(b'NumberOfPoints="8"', b'NumberOfPoints="9"'), "Points holds 24 values, expected 27"),
    (lambda t: t.replace(b"UnstructuredGrid", b"PolyData"), "not an unstructured grid"),
    (lambda t: t[:len(t) // 2], "malformed XML"),
    (lambda t: t.replace(b'type="Float64"', b'type="Float128"'), "data type 'Float128'"),
    (lambda t: t.replace(b'NumberOfComponents="3"', b'NumberOfComponents="2"'), "3 components"),
    (lambda t: t.replace(b"<Cells>", b"<Cells><Foo/>"), "unexpected <Foo>"),
])
def test_vtu_structure_not_as_declared_is_refused(tmp_path, edit, words):
    path = tmp_path / "bad.vtu"
    path.write_bytes(edit(_cube_vtu(fmt="binary", compressor="zlib")))
    with pytest.raises(geomopt.MeshFormatError, match=words):
        io.read_tets(path)


def test_vtu_truncated_binary_data_is_refused(tmp_path):
    good = _cube_vtu(fmt="raw")
    at = good.index(b"</AppendedData>")
    (tmp_path / "t.vtu").write_bytes(good[:at - 20] + good[at:])
    with pytest.raises(geomopt.MeshFormatError, match="ends inside|truncated"):
        io.read_tets(tmp_path / "t.vtu")


def test_vtu_ascii_integers_beyond_their_declared_type_are_refused(tmp_path):
    good = _cube_vtu()
    assert b'"UInt8" Name="types" NumberOfComponents="1" format="ascii">10 ' in good
    (tmp_path / "t.vtu").write_bytes(good.replace(b'format="ascii">10 ', b'format="ascii">266 ', 1))
    with pytest.raises(geomopt.MeshFormatError, match="types: a value does not fit the declared type uint8"):
        io.read_tets(tmp_path / "t.vtu")


@pytest.mark.parametrize("fmt", ["raw", "base64"])
def test_vtu_data_ending_inside_an_array_header_is_refused(tmp_path, fmt):
    """Compressed appended data cut inside the last array's 4-byte header (raw: 2 bytes, base64: 3) is refused
    as truncated."""
    good = _cube_vtu(fmt=fmt, compressor="zlib")
    start = good.index(b'">\n_') + 4
    last = int(re.findall(rb'offset="([0-9]+)"', good)[-1])
    cut = good[:start + last + (2 if fmt == "raw" else 4)]
    (tmp_path / "t.vtu").write_bytes(cut + b"\n</AppendedData>\n</VTKFile>\n")
    with pytest.raises(geomopt.MeshFormatError, match="types: the (appended|binary) data ends inside this array's"):
        io.read_tets(tmp_path / "t.vtu")


@pytest.mark.parametrize("make", [_msh22, _msh41])
@pytest.mark.parametrize("bad", [0, -3])
def test_gmsh_node_tag_zero_or_negative_is_refused_with_its_line(tmp_path, make, bad):
    """A 0-based export (tag 0) was read as another mesh: meshio maps tag 0 to the largest tag."""
    tags = [bad] + list(range(2, 9))
    (tmp_path / "z.msh").write_text(make(tags))
    with pytest.raises(geomopt.MeshFormatError, match=rf"line \d+: node tag {bad}; Gmsh node tags start at 1"):
        io.read_tets(tmp_path / "z.msh")


def test_valid_files_meshio_refused_are_read(tmp_path):
    """MSH 2.2 with mixed tag counts, MSH 4.1 with an empty element block, a BOM, VTK 5.1 int32 offsets."""
    mixed = MSH22.replace("\n2 4 2 0 1 ", "\n2 4 3 0 1 7 ", 1).replace("\n3 4 2 0 1 ", "\n3 4 0 ", 1)
    empty_block = MSH41.replace("$Elements\n1 6 1 6\n", "$Elements\n2 6 1 6\n2 1 2 0\n")
    for name, text in (("mixed.msh", mixed), ("empty.msh", empty_block), ("bom.msh", "\ufeff" + MSH22),
                       ("bom.mesh", "\ufeff" + MEDIT)):
        (tmp_path / name).write_text(text, encoding="utf-8")
        P, T = io.read_tets(tmp_path / name)
        np.testing.assert_array_equal(P, _P1)
        np.testing.assert_array_equal(T, _T1)
    points = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in _P1.tolist())
    for kind in ("vtktypeint32", "vtktypeint64"):
        text = ("# vtk DataFile Version 5.1\nc\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 8 double\n" + points
                + f"CELLS 7 24\nOFFSETS {kind}\n" + " ".join(str(4 * i) for i in range(7))
                + f"\nCONNECTIVITY {kind}\n" + " ".join(map(str, _T1.ravel())) + "\nCELL_TYPES 6\n" + "10\n" * 6)
        (tmp_path / f"{kind}.vtk").write_text(text)
        P, T = io.read_tets(tmp_path / f"{kind}.vtk")
        np.testing.assert_array_equal(T, _T1)
    (tmp_path / "bom.vtu").write_bytes(b"\xef\xbb\xbf" + _cube_vtu())
    np.testing.assert_array_equal(io.read_tets(tmp_path / "bom.vtu")[1], _T1)


def test_medit_version_1_coordinates_are_read_as_written(tmp_path):
    """MeshVersionFormatted 1 means single precision in binary Medit; an ASCII file's decimals are
    read as written (float64), not rounded to float32 as meshio did."""
    P = _P1 + 0.1
    text = MEDIT.replace("MeshVersionFormatted 2", "MeshVersionFormatted 1")
    text = text.split("Vertices\n8\n")[0] + "Vertices\n8\n" + "".join(f"{x!r} {y!r} {z!r} 0\n" for x, y, z in P.tolist()) \
        + "Tetrahedra" + text.split("Tetrahedra", 1)[1]
    (tmp_path / "v1.mesh").write_text(text)
    got, T = io.read_tets(tmp_path / "v1.mesh")
    np.testing.assert_array_equal(got, P)
    assert (got.astype(np.float32) != got).any()


# ------------------------------------------------------------------ adversarial pass (issue 19, own)


def test_vtu_an_array_given_twice_is_refused_not_picked(tmp_path):
    """Two 'connectivity' arrays: which one a reader takes is a guess; refused."""
    good = _cube_vtu().decode()
    second = '<DataArray type="Int64" Name="connectivity" NumberOfComponents="1" format="ascii">' + \
        " ".join(map(str, _T1[:, ::-1].ravel())) + "</DataArray>"
    (tmp_path / "d.vtu").write_text(good.replace("</Cells>", second + "</Cells>"))
    with pytest.raises(geomopt.MeshFormatError, match="two DataArrays named 'connectivity'"):
        io.read_tets(tmp_path / "d.vtu")


def test_vtu_integer_points_read_exactly_or_refused(tmp_path):
    """Integer coordinates are exact in float64 up to 2**53; beyond that they would be rounded."""
    for scale, ok in ((2**52, True), (2**60 + 1, False)):
        pts = (_P1 * scale).astype(np.int64) + (1 if not ok else 0)
        text = _cube_vtu().decode()
        body = " ".join(map(str, pts.ravel()))
        start = text.index('<DataArray type="Float64" Name="Points"')
        end = text.index("</DataArray>", start)
        text = text[:start] + '<DataArray type="Int64" Name="Points" NumberOfComponents="3" format="ascii">' + \
            body + text[end:]
        (tmp_path / "i.vtu").write_text(text)
        if ok:
            np.testing.assert_array_equal(io.read_tets(tmp_path / "i.vtu")[0], pts.astype(np.float64))
        else:
            with pytest.raises(geomopt.MeshFormatError, match="beyond 2\\*\\*53"):
                io.read_tets(tmp_path / "i.vtu")


def test_vtu_empty_cells_are_legal_and_skipped(tmp_path):
    """VTK_EMPTY_CELL (type 0) has no points: equal offsets there are not a duplicated offset."""
    (tmp_path / "e.vtu").write_bytes(_vtu([(_P1, _T1.ravel(), np.r_[4 * np.arange(1, 4), 12, 4 * np.arange(4, 7)],
                                             [10, 10, 10, 0, 10, 10, 10])]))
    np.testing.assert_array_equal(io.read_tets(tmp_path / "e.vtu")[1], _T1)


@pytest.mark.parametrize("section, extra", [("Vertices", "Vertices\n8\n" + "9 9 9 0\n" * 8),
                                            ("Tetrahedra", "Tetrahedra\n1\n1 2 3 5 0\n")])
def test_medit_a_section_given_twice_is_refused(tmp_path, section, extra):
    """A second Vertices section silently replaced the first (Medit's own reader keeps only one)."""
    (tmp_path / "two.mesh").write_text(MEDIT.replace("End\n", extra + "End\n"))
    with pytest.raises(geomopt.MeshFormatError, match=f"second {section} section"):
        io.read_tets(tmp_path / "two.mesh")


def test_fuzz_found_crashes_are_one_line_refusals(tmp_path):
    """Found by mutating valid files: a number where a Medit section keyword belongs (TypeError) and
    a non-numeric NumberOfComponents (ValueError) escaped as internal errors."""
    (tmp_path / "n.mesh").write_text(MEDIT.replace("Dimension 3\n", "Dimension 3\n7\n"))
    with pytest.raises(geomopt.MeshFormatError, match="line 3: expected a section keyword"):
        io.read_tets(tmp_path / "n.mesh")
    (tmp_path / "c.vtu").write_bytes(_cube_vtu().replace(b'NumberOfComponents="3"', b'NumberOfComponents="3x"'))
    with pytest.raises(geomopt.MeshFormatError, match="expected 3 components"):
        io.read_tets(tmp_path / "c.vtu")


def test_a_format_is_one_row_of_the_table_and_a_read_only_one_is_never_written(tmp_path, monkeypatch):
    """Formats are one table (geomopt._runtime.formats): a row added there is read by every
    reader, listed by the help and the output checks; without a writer it is refused on
    writing (it used to be written as VTU under its own extension), creating nothing."""
    from geomopt._runtime import formats
    from geomopt.mesh.cells import is_cell_case, output_extensions

    monkeypatch.setitem(formats.CELL_FORMATS, ".vtkr", formats.CellFormat(
        "legacy VTK, read-only", "geomopt.io._vtk:parse_vtk", None, mapped=True, one_kind=True))
    V, T = _jittered(1)
    src = io.write_tets(tmp_path / "cube.vtk", V, T)
    copy = tmp_path / "cube.vtkr"
    copy.write_bytes(src.read_bytes())
    P, C = io.read_tets(copy)
    np.testing.assert_array_equal(P, V)
    np.testing.assert_array_equal(C, T)
    assert is_cell_case(copy) and ".vtkr" in formats.listing()
    assert ".vtkr" not in output_extensions("tetra") and ".vtk" in output_extensions("tetra")
    out = tmp_path / "out.vtkr"
    with pytest.raises(geomopt.MeshFormatError, match=r"\.vtkr \(legacy VTK, read-only\), which geomopt reads but "
                                                      r"does not write; supported tet-mesh formats: \.vtk"):
        io.write_tets(out, V, T)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["cube.vtk", "cube.vtkr"]

"""The command line: exit status 0 only for a certified result that was written, 1 for a solve
that did not certify (nothing written), 2 for bad input (one line, no traceback unless --debug).

Most tests call :func:`geomopt.cli.main` in this process (the JIT-compiled kernels are reused
between them); two run ``python -m geomopt`` to check the real entry point.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import geomopt.cli
from geomopt import MeshFormatError, io
from geomopt.exact.predicates import count_inverted

from conftest import cube_tets, grid

V2, F = grid(4)  # 16 vertices, 18 triangles; vertices 5, 6, 9, 10 are interior
V3 = np.c_[V2, 0.3 * np.sin(3.0 * V2[:, 0]) * V2[:, 1]]
BOUNDARY = np.flatnonzero(((V2 == 0) | (V2 == 1)).any(axis=1))


def write_obj(path, V, faces, extra=""):
    with open(path, "w") as fh:
        fh.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in np.asarray(V, float).tolist())
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in np.asarray(faces).tolist())
        fh.write(extra)
    return path


def one_error_line(err, *words):
    """stderr is exactly one ``geomopt: error:`` line holding every word (no traceback)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("geomopt: error: "), err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def read_uv_obj(path):
    v, vt, f = [], [], []
    for line in Path(path).read_text().splitlines():
        t = line.split()
        if t[0] == "v":
            v.append([float(x) for x in t[1:]])
        elif t[0] == "vt":
            vt.append([float(x) for x in t[1:]])
        elif t[0] == "f":
            f.append([int(c.split("/")[0]) - 1 for c in t[1:]])
    return np.array(v), np.array(vt), np.array(f)


# ------------------------------------------------------------------ param: success


def test_param_writes_a_certified_map_quietly_and_deterministically(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    code, out, err = cli("param", mesh, "-o", tmp_path / "a.obj", "--quiet")
    assert (code, out, err) == (0, "", "")
    v, vt, f = read_uv_obj(tmp_path / "a.obj")
    assert np.array_equal(v, V3) and np.array_equal(f, F) and vt.shape == (16, 2)
    assert np.isfinite(vt).all() and count_inverted(vt, F) == 0
    assert cli("param", mesh, "-o", tmp_path / "b.obj", "--quiet")[0] == 0
    assert (tmp_path / "a.obj").read_bytes() == (tmp_path / "b.obj").read_bytes()
    assert sorted(os.listdir(tmp_path)) == ["a.obj", "b.obj", "m.obj"]  # no temporary files


# ------------------------------------------------------------------ param: bad input -> 2


def _bad_meshes(tmp):
    d = tmp / "folder.obj"
    d.mkdir()
    V = V3.copy()
    V[5] = (V[1] + V[6]) / 2  # triangle 3 = [1, 6, 5] becomes flat
    nan = V3.copy()
    nan[3, 1] = np.nan
    return {
        "missing": (tmp / "nope.obj", ["does not exist"]),
        "empty": (tmp / "empty.obj", ["is empty"]),
        "directory": (d, ["is a directory"]),
        "not a mesh": (tmp / "text.obj", ["line 1: unknown OBJ statement 'hello'"]),
        "extension": (tmp / "mesh.xyz", ["unsupported extension '.xyz'", ".obj, .off, .ply, .stl"]),
        "nan": (write_obj(tmp / "nan.obj", nan, F), ["1 vertices with NaN or infinite", "vertex 3"]),
        "index": (write_obj(tmp / "oob.obj", V3, np.r_[F, [[0, 1, 40]]]),
                  ["line 35: face corner '41' refers to a vertex beyond the file's 16 'v' lines"]),
        "repeated": (write_obj(tmp / "rep.obj", V3, np.r_[F, [[0, 0, 1]]]), ["use a vertex more than once"]),
        "zero area": (write_obj(tmp / "flat.obj", V, F), ["1 rest triangle(s) have (near-)zero size", "[3]"]),
        "non-manifold": (write_obj(tmp / "nm.obj", np.r_[V3, [[0.5, -0.5, 1.0], [0.5, -0.5, -1.0]]],
                                   np.r_[F, [[1, 0, 16], [1, 0, 17]]]), ["1 non-manifold edges"]),
        # closed surfaces and several components are no longer refused: param makes an atlas (test_atlas.py)
    }


def test_param_bad_input_is_one_line_exit_2_and_writes_nothing(cli, tmp_path):
    (tmp_path / "empty.obj").write_bytes(b"")
    (tmp_path / "text.obj").write_text("hello\nthis is not a mesh\n")
    (tmp_path / "mesh.xyz").write_text("0 0 0\n")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    for case, (path, words) in _bad_meshes(tmp_path).items():
        code, out, err = cli("param", path, "-o", out_dir / "uv.obj", "--quiet")
        assert code == 2, case
        one_error_line(err, *words)
        assert os.listdir(out_dir) == [], case


def test_param_unreadable_file(cli, tmp_path, monkeypatch):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    real = Path.read_bytes

    def deny(self):
        if self.name == "m.obj":
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", deny)  # chmod does not stop root
    code, _, err = cli("param", mesh, "-o", tmp_path / "uv.obj", "--quiet")
    assert code == 2
    one_error_line(err, "cannot read OBJ file", "Permission denied", "check its permissions")
    assert not (tmp_path / "uv.obj").exists()


def test_param_unknown_names_and_invalid_values(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    code, _, err = cli("param", mesh, "-o", tmp_path / "uv.obj", "--energy", "sym_dir", "--quiet")
    assert code == 2
    one_error_line(err, "unknown energy 'sym_dir'", "valid energies: arap, dirichlet, garanzha, mips")
    code, _, err = cli("param", mesh, "-o", tmp_path / "uv.obj", "--solver", "bfgs", "--quiet")
    assert code == 2
    one_error_line(err, "unknown solver 'bfgs'", "valid solvers:", "newton")
    for bad in ("0", "-3", "ten"):
        with pytest.raises(SystemExit) as info:
            geomopt.cli.main(["param", str(mesh), "-o", str(tmp_path / "uv.obj"), "--max-steps", bad])
        assert info.value.code == 2
    assert os.listdir(tmp_path) == ["m.obj"]


def test_an_output_that_is_an_input_file_is_refused_before_reading(cli, tmp_path, no_work):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    (tmp_path / "alias.obj").hardlink_to(mesh)
    case = lim2d(tmp_path / "case", folded_2d(), BOUNDARY)
    original = {p: p.read_bytes() for p in [mesh, case / "input.obj", case / "handles.txt"]}
    for argv, words in [
        (["param", mesh, "-o", mesh], ["-o output", "is the input file", "give the output another name"]),
        (["param", mesh, "-o", tmp_path / "alias.obj"], ["is the input file"]),  # same file, other name
        (["untangle", case, "-o", case / "input.obj"], ["is the input file", "input.obj"]),
    ]:
        code, _, err = cli(*argv, "--quiet")
        assert code == 2, argv
        one_error_line(err, *words)
    assert {p: p.read_bytes() for p in original} == original
    with pytest.raises(pytest.fail.Exception):  # a distinct output passes the check and reaches reading
        cli("param", tmp_path / "alias.obj", "-o", tmp_path / "uv.obj", "--quiet")


def test_param_output_that_cannot_be_written_fails_before_solving(cli, tmp_path, monkeypatch):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    monkeypatch.setattr("geomopt.param.parameterize", lambda *a, **k: pytest.fail("solved anyway"))
    code, _, err = cli("param", mesh, "-o", tmp_path / "no" / "uv.obj", "--quiet")
    assert code == 2
    one_error_line(err, "the folder", "does not exist; create it first")
    code, _, err = cli("param", mesh, "-o", tmp_path, "--quiet")
    assert code == 2
    one_error_line(err, "is a directory")
    code, _, err = cli("param", mesh, "-o", mesh / "uv.obj", "--quiet")  # parent is a file
    assert code == 2
    one_error_line(err, "is not a directory")
    assert os.listdir(tmp_path) == ["m.obj"]


def test_param_write_failure_after_solving_leaves_nothing(cli, tmp_path, monkeypatch):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    from geomopt.io import _obj

    real = _obj.write_rows

    def disk_full(fh, prefix, A):
        real(fh, prefix, A)  # part of the file is written...
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(_obj, "write_rows", disk_full)
    code, _, err = cli("param", mesh, "-o", tmp_path / "uv.obj", "--quiet")
    assert code == 2
    one_error_line(err, "could not write", "No space left on device", "nothing was written")
    assert os.listdir(tmp_path) == ["m.obj"]  # neither the output nor a temporary file


def test_param_debug_shows_the_exception(tmp_path):
    with pytest.raises(MeshFormatError, match="does not exist"):
        geomopt.cli.main(["param", str(tmp_path / "nope.obj"), "-o", str(tmp_path / "x.obj"), "--debug"])


def test_demo_output_that_is_a_file(cli, tmp_path):
    (tmp_path / "out").write_text("a file\n")
    code, _, err = cli("demo", "-o", tmp_path / "out", "--quiet")
    assert code == 2
    one_error_line(err, "cannot create the output folder")
    assert (tmp_path / "out").read_text() == "a file\n"


# ------------------------------------------------------------------ outputs (issue 10, classes 1, 5, 6)


@pytest.fixture
def no_work(monkeypatch):
    """Reading or solving anything fails the test: output checks must come first."""
    fail = lambda *a, **k: pytest.fail("read or solved before checking the outputs")  # noqa: E731
    monkeypatch.setattr("geomopt.io.read_mesh", fail)
    monkeypatch.setattr("geomopt.lim.LimCase.read", fail)
    monkeypatch.setattr("geomopt.param.parameterize", fail)
    monkeypatch.setattr("geomopt.lim.untangle_case", fail)


def test_outputs_that_are_not_regular_files_are_refused_before_reading(cli, tmp_path, no_work):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    fifo = tmp_path / "pipe.obj"
    os.mkfifo(fifo)
    png_fifo = tmp_path / "pipe.png"
    os.mkfifo(png_fifo)
    (tmp_path / "conv_convergence.png").mkdir()
    (tmp_path / "link.obj").symlink_to("/dev/null")
    case = lim2d(tmp_path / "case", folded_2d(), BOUNDARY)
    before = sorted(os.listdir(tmp_path))
    for argv, words in [
        (["param", mesh, "-o", "/dev/full"], ["output /dev/full is a character device, not a regular file"]),
        (["param", mesh, "-o", "/dev/null"], ["output /dev/null is a character device"]),
        (["param", mesh, "-o", fifo], ["is a named pipe (FIFO), not a regular file"]),
        (["param", mesh, "-o", tmp_path / "link.obj"], ["is a symbolic link"]),
        (["param", mesh, "-o", tmp_path / "uv.obj", "--png", png_fifo], ["--png picture", "named pipe"]),
        (["param", mesh, "-o", tmp_path / "uv.obj", "--png", "/dev/full"], ["--png picture", "character device"]),
        (["param", mesh, "-o", tmp_path / "uv.obj", "--png", tmp_path / "conv.png"],
         ["convergence picture", "conv_convergence.png is a directory"]),
        (["untangle", case, "-o", tmp_path / "pipe.obj"], ["named pipe"]),
        (["untangle", case, "-o", "/dev/null"], ["2D case: the output must be a .obj file"]),
    ]:
        code, out, err = cli(*argv, "--quiet")
        assert code == 2, argv
        one_error_line(err, *words)
    assert sorted(os.listdir(tmp_path)) == before
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode) and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and stat.S_ISFIFO(os.stat(png_fifo).st_mode)


def test_output_names_and_formats_are_checked_before_reading(cli, tmp_path, no_work):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    long_name = "n" * 246 + ".png"  # fits; its _convergence sibling (258 bytes) does not
    for argv, words in [
        (["-o", tmp_path / "uv.stl"], ["output", "uv.stl has extension '.stl'; supported: .obj, .ply"]),
        (["-o", tmp_path / "uv.txt"], ["extension '.txt'"]),
        (["-o", tmp_path / "uv"], ["has no extension; supported: .obj, .ply"]),
        (["-o", tmp_path / ("u" * 300 + ".obj")], ["name too long for the file system"]),
        (["-o", tmp_path / "uv.obj", "--png", tmp_path / "uv.gif"],
         ["--png picture", "extension '.gif'; supported: .png, .pdf, .svg"]),
        (["-o", tmp_path / "uv.obj", "--png", tmp_path / "uv.obj"], ["--png picture", "is the same file as the -o output"]),
        (["-o", tmp_path / "uv.obj", "--png", tmp_path / long_name],
         ["convergence picture", "name too long for the file system"]),
        (["-o", tmp_path / "uv.obj", "--png", tmp_path / "pic"], ["--png picture", "has no extension"]),
    ]:
        code, _, err = cli("param", mesh, *argv, "--quiet")
        assert code == 2, argv
        one_error_line(err, *words)
    assert os.listdir(tmp_path) == ["m.obj"]


def read_ply_uv(path):
    """x y z u v and faces of a binary PLY written by geomopt (parsed here with numpy)."""
    head, body = Path(path).read_bytes().split(b"end_header\n", 1)
    n = int(head.split(b"element vertex ")[1].split()[0])
    m = int(head.split(b"element face ")[1].split()[0])
    vert = np.frombuffer(body, np.dtype([(c, "<f8") for c in "xyzuv"]), n)
    face = np.frombuffer(body, np.dtype([("n", "u1"), ("i", "<i4", (3,))]), m, vert.nbytes)
    assert len(body) == vert.nbytes + face.nbytes and (face["n"] == 3).all()
    return np.c_[vert["x"], vert["y"], vert["z"]], np.c_[vert["u"], vert["v"]], face["i"]


def test_param_writes_the_format_the_extension_names_and_pictures_atomically(cli, tmp_path, monkeypatch):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    code, out, err = cli("param", mesh, "-o", tmp_path / "uv.PLY", "--png", tmp_path / "pic.png", "--quiet",
                         "--json")
    assert (code, err) == (0, "")
    timing = json.loads(out)["timing"]  # the pictures are a phase of their own, apart from writing the map
    assert timing["figures"] > 0 and timing["write"] > 0 and timing["figures"] + timing["write"] <= timing["total"]
    v, uv, f = read_ply_uv(tmp_path / "uv.PLY")
    assert np.array_equal(v, V3) and np.array_equal(f, F) and count_inverted(uv, F) == 0
    assert cli("param", mesh, "-o", tmp_path / "uv.obj", "--quiet")[0] == 0
    assert np.array_equal(read_uv_obj(tmp_path / "uv.obj")[1], uv)  # the same map, every bit
    for name in ("pic.png", "pic_convergence.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(os.listdir(tmp_path)) == ["m.obj", "pic.png", "pic_convergence.png", "uv.PLY", "uv.obj"]

    # the disk fills up while the second picture is written: no picture, no output, no temporary file
    for name in ("pic.png", "pic_convergence.png", "uv.PLY"):
        (tmp_path / name).write_text("old\n")
    import geomopt.plot

    real = geomopt.plot.save_convergence

    def disk_full(path, *a, **k):
        real(path, *a, **k)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(geomopt.plot, "save_convergence", disk_full)
    code, _, err = cli("param", mesh, "-o", tmp_path / "uv.PLY", "--png", tmp_path / "pic.png", "--quiet")
    assert code == 2
    one_error_line(err, "could not write", "No space left on device", "nothing was written")
    for name in ("pic.png", "pic_convergence.png", "uv.PLY"):
        assert (tmp_path / name).read_text() == "old\n"
    assert sorted(os.listdir(tmp_path)) == ["m.obj", "pic.png", "pic_convergence.png", "uv.PLY", "uv.obj"]


def test_stl_input_is_welded_and_says_so(cli, tmp_path, monkeypatch):
    corners = V3[F].astype(np.float32)
    stl = tmp_path / "m.stl"
    stl.write_bytes(b"x" * 80 + np.uint32(len(F)).tobytes() + b"".join(
        np.zeros(3, np.float32).tobytes() + c.tobytes() + b"\0\0" for c in corners))
    seen = {}

    def stop(V, F, **kwargs):
        seen.update(V=V, F=F)
        raise MeshFormatError("stopped before solving")

    monkeypatch.setattr("geomopt.param.parameterize", stop)
    code, _, err = cli("param", stl, "-o", tmp_path / "uv.obj")
    assert code == 2 and "stopped before solving" in err
    assert "welded the 54 corners with bit-identical coordinates into 16 vertices" in err
    order = list(dict.fromkeys(F.ravel().tolist()))  # vertices numbered by first appearance
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    assert np.array_equal(seen["V"], V3[order].astype(np.float32).astype(np.float64))
    assert np.array_equal(seen["F"], rank[F])


# ------------------------------------------------------------------ param: failed solve -> 1


def test_param_solve_that_does_not_certify_exits_1_and_writes_nothing(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    old = tmp_path / "uv.obj"
    old.write_text("previous result\n")
    code, _, err = cli("param", mesh, "-o", old, "--max-steps", "1", "--quiet")
    assert code == 1
    one_error_line(err, "not certified", "iteration limit", "nothing written")
    assert old.read_text() == "previous result\n"
    assert sorted(os.listdir(tmp_path)) == ["m.obj", "uv.obj"]


# ------------------------------------------------------------------ untangle


def lim2d(folder, init, handles, faces=F, rest=None):
    folder.mkdir(parents=True, exist_ok=True)
    rest = np.c_[V2, np.zeros(len(V2))] if rest is None else rest
    io.write_obj_with_uv(folder / "input.obj", rest, faces, init)
    (folder / "handles.txt").write_text("".join(f"{int(h)}\n" for h in handles))
    return folder


def lim3d(folder, init=None, handles=None, tets=None, init_tets=None):
    P, T = cube_tets(2)  # 27 vertices, vertex 13 is the only interior one
    folder.mkdir(parents=True, exist_ok=True)
    io.write_vtk_tets(folder / "rest.vtk", P, T if tets is None else tets)
    io.write_vtk_tets(folder / "init.vtk", P if init is None else init, T if init_tets is None else init_tets)
    handles = [i for i in range(27) if i != 13] if handles is None else handles
    (folder / "handles.txt").write_text("".join(f"{h}\n" for h in handles))
    return folder


def folded_2d():
    x = V2.copy()
    x[5] = [0.9, 0.9]  # interior vertex thrown across: several triangles inverted
    return x


def test_untangle_2d_success_writes_a_certified_obj(cli, tmp_path):
    case = lim2d(tmp_path / "case", folded_2d(), BOUNDARY)
    code, out, err = cli("untangle", case, "-o", tmp_path / "out.obj", "--quiet")
    assert (code, err) == (0, "")
    v, vt, f = read_uv_obj(tmp_path / "out.obj")
    assert count_inverted(vt, f) == 0 and np.array_equal(vt[BOUNDARY], V2[BOUNDARY])
    assert cli("untangle", case, "-o", tmp_path / "again.obj", "--quiet")[0] == 0
    assert (tmp_path / "out.obj").read_bytes() == (tmp_path / "again.obj").read_bytes()


def test_untangle_3d_success_writes_a_certified_vtk(cli, tmp_path):
    P, T = cube_tets(2)
    init = P.copy()
    init[13] = [0.9, 0.9, 0.9]
    case = lim3d(tmp_path / "case", init=init)
    code, out, err = cli("untangle", case, "-o", tmp_path / "out.vtk", "--quiet")
    assert (code, err) == (0, "")
    Q, T2 = io.read_vtk_tets(tmp_path / "out.vtk")
    assert np.array_equal(T2, T) and count_inverted(Q, T) == 0


def test_untangle_that_cannot_certify_exits_1_and_writes_nothing(cli, tmp_path):
    case = lim2d(tmp_path / "case", folded_2d(), np.arange(16))  # the folded vertex is fixed too
    code, _, err = cli("untangle", case, "-o", tmp_path / "out.obj", "--quiet")
    assert code == 1
    one_error_line(err, "not certified", "nothing written")
    assert not (tmp_path / "out.obj").exists()


def _bad_cases(tmp):
    P, T = cube_tets(2)
    ok = folded_2d()
    no_handles = lim2d(tmp / "no_handles", ok, BOUNDARY)
    (no_handles / "handles.txt").unlink()
    vt_short = lim2d(tmp / "vt_short", ok, BOUNDARY)
    text = (vt_short / "input.obj").read_text().splitlines(keepends=True)
    (vt_short / "input.obj").write_text("".join(line for i, line in enumerate(text) if i != 20))  # one vt less
    non_tet = lim3d(tmp / "non_tet")
    (non_tet / "init.vtk").write_text(
        "# vtk DataFile Version 2.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 3 double\n"
        "0 0 0\n1 0 0\n0 1 0\nCELLS 1 4\n3 0 1 2\nCELL_TYPES 1\n5\n")
    (tmp / "empty").mkdir()
    return {
        "missing folder": (tmp / "nope", ".obj", ["does not exist"]),
        "not a case": (tmp / "empty", ".obj", ["not a LIM case folder"]),
        "no handles": (no_handles, ".obj", ["has no handles.txt"]),
        "handles out of range": (lim2d(tmp / "oob", ok, [0, 1, 99]), ".obj", ["indices outside 0..15", "99"]),
        "vt count": (vt_short, ".obj", ["16 'v' lines but 15 'vt' lines"]),
        "point count": (lim3d(tmp / "points", init=P[:-1], init_tets=T[:-6]), ".vtk",
                        ["rest.vtk has 27 points but init.vtk has 26"]),
        "connectivity": (lim3d(tmp / "conn", init_tets=T[:, [0, 2, 1, 3]]), ".vtk", ["different connectivity"]),
        "non-tet cells": (non_tet, ".vtk", ["non-tetrahedral cells (triangle)"]),
        "collapsed 2D": (lim2d(tmp / "flat", np.zeros((16, 2)), BOUNDARY), ".obj",
                         ["total signed area", "collapsed"]),
        "mirrored 3D": (lim3d(tmp / "mirror", init=P * [-1.0, 1.0, 1.0]), ".vtk",
                        ["total signed volume", "mirrored"]),
        "wrong extension": (lim2d(tmp / "ext", ok, BOUNDARY), ".vtk", ["2D case", "must be a .obj file"]),
    }


@pytest.mark.parametrize("name", [
    "missing folder", "not a case", "no handles", "handles out of range", "vt count", "point count",
    "connectivity", "non-tet cells", "collapsed 2D", "mirrored 3D", "wrong extension",
])
def test_untangle_bad_input_is_one_line_exit_2(cli, tmp_path, name):
    folder, ext, words = _bad_cases(tmp_path)[name]
    out = tmp_path / "out" / f"result{ext}"
    out.parent.mkdir()
    code, _, err = cli("untangle", folder, "-o", out, "--quiet")
    assert code == 2
    one_error_line(err, *words)
    assert os.listdir(out.parent) == []


def test_untangle_unwritable_output_fails_before_solving(cli, tmp_path, monkeypatch):
    case = lim2d(tmp_path / "case", folded_2d(), BOUNDARY)
    monkeypatch.setattr("geomopt.lim.untangle_case", lambda *a, **k: pytest.fail("solved anyway"))
    code, _, err = cli("untangle", case, "-o", tmp_path / "no" / "out.obj", "--quiet")
    assert code == 2
    one_error_line(err, "does not exist; create it first")
    with pytest.raises(SystemExit) as info:
        geomopt.cli.main(["untangle", str(case), "-o", str(tmp_path / "x.obj"), "--solver", "slim"])
    assert info.value.code == 2


def test_untangle_empty_handles_says_what_the_cli_user_can_do(cli, tmp_path, monkeypatch):
    case = lim2d(tmp_path / "case", folded_2d(), [])
    monkeypatch.setattr("geomopt.lim.untangle_case", lambda *a, **k: pytest.fail("solved anyway"))
    code, _, err = cli("untangle", case, "-o", tmp_path / "out.obj", "--quiet")
    assert code == 2
    line = one_error_line(err, "handles.txt is empty", "needs a fixed boundary", "0-based ids")
    assert "with_fixed" not in line and "Problem" not in line
    assert not (tmp_path / "out.obj").exists()


def test_untangle_output_that_does_not_certify_never_replaces_the_old_file(cli, tmp_path, monkeypatch):
    case = lim2d(tmp_path / "case", folded_2d(), BOUNDARY)
    out = tmp_path / "out.obj"
    out.write_text("previous result\n")
    from geomopt.lim import LimCase

    real = LimCase._written

    def broken(case, x, path):
        back = real(case, x, path)
        assert Path(path) != out and Path(path).read_bytes().startswith(b"v ")  # written beside, not over
        back[case.simplices[0, :2]] = back[case.simplices[0, 1::-1]]  # swap two corners: inverted
        return back

    monkeypatch.setattr(LimCase, "_written", broken)
    code, _, err = cli("untangle", case, "-o", out, "--quiet")
    assert code == 1
    one_error_line(err, "the written file did not certify: 1 element(s) inverted", "nothing written")
    assert out.read_text() == "previous result\n" and sorted(os.listdir(tmp_path)) == ["case", "out.obj"]


def test_param_inverted_tutte_start_is_reworded_for_the_cli(cli, tmp_path, monkeypatch):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    import geomopt.param

    real = geomopt.param.tutte_embedding

    def folded(*a, **k):
        x = np.array(real(*a, **k))
        x[5] = 2 * x[10] - x[5]  # an interior vertex reflected through another: inverted triangles
        assert count_inverted(x, F) > 0
        return x

    monkeypatch.setattr(geomopt.param, "tutte_embedding", folded)
    code, _, err = cli("param", mesh, "-o", tmp_path / "uv.obj", "--weights", "mean_value", "--quiet")
    assert code == 2
    line = one_error_line(err, "the mean_value Tutte start map of", "inverted or degenerate triangle(s)",
                          "try --weights uniform")
    assert "x0" not in line
    assert os.listdir(tmp_path) == ["m.obj"]


# ------------------------------------------------------------------ the real entry point


@pytest.mark.parametrize("command", ["param", "untangle"])
def test_python_m_geomopt_bad_input_has_no_traceback(tmp_path, command):
    env = {**os.environ, "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-m", "geomopt", command, str(tmp_path / "missing.obj"),
                           "-o", str(tmp_path / "out.obj")], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode == 2
    one_error_line(proc.stderr, "does not exist")
    assert not (tmp_path / "out.obj").exists()


def test_entry_ends_the_process_with_mains_exit_status_unless_a_thread_still_works(monkeypatch):
    import threading

    exits = []

    class Ended(Exception):
        pass

    def fake_exit(code):
        exits.append(code)
        raise Ended

    observed = geomopt.cli.run._observed
    monkeypatch.setattr(geomopt.cli.run, "_observed", lambda: False)  # even if this test runs under coverage
    monkeypatch.setattr(geomopt.cli.run, "main", lambda: 3)
    monkeypatch.setattr(geomopt.cli.run.os, "_exit", fake_exit)
    with pytest.raises(Ended):
        geomopt.cli.entry()
    assert exits == [3]
    release = threading.Event()
    worker = threading.Thread(target=release.wait)  # a non-daemon thread: the normal exit waits for it
    worker.start()
    try:
        with pytest.raises(SystemExit) as info:
            geomopt.cli.entry()
        assert info.value.code == 3 and exits == [3]
    finally:
        release.set()
        worker.join()
    monkeypatch.setattr(geomopt.cli.run, "_observed", observed)
    monkeypatch.setattr(geomopt.cli.run.sys, "getprofile", lambda: object())  # a profiler reports at exit
    with pytest.raises(SystemExit):
        geomopt.cli.entry()
    assert exits == [3]


# ------------------------------------------------------------------ issue 19: exit codes and messages


def test_usage_error_json_and_one_line(capsys):
    for argv, command in [(["param", "m.obj", "-o", "x.obj", "--max-steps", "0"], "param"),
                          (["compare", "m.obj", "--solvers"], "compare"),
                          (["untangle", "case"], "untangle"), (["frobnicate"], "frobnicate")]:
        with pytest.raises(SystemExit) as info:
            geomopt.cli.main(argv + ["--json"])
        assert info.value.code == 2
        out, err = capsys.readouterr()
        summary = json.loads(out)
        assert summary["command"] == command and summary["success"] is False and summary["exit_status"] == 2
        assert summary["error"].startswith("usage: ")
        assert len(err.strip().splitlines()) == 1 and "error:" in err and "--help" in err, err
        with pytest.raises(SystemExit):
            geomopt.cli.main(argv)  # without --json: stdout stays empty
        assert capsys.readouterr().out == ""


WARNS = """
import sys
import numpy as np
import geomopt, geomopt.cli, geomopt.param

def warns(*a, **k):
    np.exp(np.array([1e300])) / np.zeros(1)  # RuntimeWarning: overflow, then inf/0
    raise geomopt.MeshError("the mesh is hopeless")

geomopt.param.parameterize = warns
sys.exit(geomopt.cli.main(sys.argv[1:]))
"""


def test_numpy_warnings_never_reach_stderr(tmp_path):
    """An overflow or 0/0 warning inside a command is not printed: errors are one line (--debug shows them)."""
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]),
           "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-c", WARNS, "param", str(mesh), "-o", str(tmp_path / "uv.obj"),
                           "--quiet"], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    one_error_line(proc.stderr, "the mesh is hopeless")


def test_bijective_with_a_start_it_cannot_take_is_one_line_in_command_line_words(cli, tmp_path):
    """--bijective needs a globally injective start: --init projection is refused before the mesh
    is read, and a folded --init uv map with the options to use (not the API's "x0")."""
    from geomopt.mesh import generators as G

    t = G.rotated_interior(*G.disk_mesh(4), 150.0)
    src = tmp_path / "folded.obj"
    src.write_text("".join(f"v {x!r} {y!r} 0\n" for x, y in t.rest.tolist())
                   + "".join(f"vt {u!r} {v!r}\n" for u, v in t.x0.tolist())
                   + "".join("f {0}/{0} {1}/{1} {2}/{2}\n".format(*(f + 1)) for f in t.simplices))
    code, _, err = cli("param", src, "-o", tmp_path / "out.obj", "--init", "projection", "--bijective", "--quiet")
    assert code == 2
    one_error_line(err, "--bijective", "--init projection")
    code, _, err = cli("param", src, "-o", tmp_path / "out.obj", "--init", "uv", "--bijective", "--quiet")
    assert code == 2
    line = one_error_line(err, "--init uv", "inverted triangle(s)", "drop --bijective")
    assert "x0" not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folded.obj"]


def test_param_releases_the_factorizations_before_writing(cli, tmp_path, monkeypatch):
    """Once solved, ``param`` lets the mesh's Cholesky factorizations go before it writes (at
    10^6 triangles PARDISO's 1.5 GB were held under the writing, the process's peak); the
    objective then analyzes afresh when asked."""
    from geomopt import io
    from geomopt.objective.objective import Objective

    events, release, write = [], Objective.release_factorizations, io.write_mesh_with_uv

    def released(obj):
        before = obj.cholesky("superlu")
        release(obj)
        events.append(obj.cholesky("superlu") is not before)

    monkeypatch.setattr(Objective, "release_factorizations", released)
    monkeypatch.setattr(io, "write_mesh_with_uv", lambda *a, **k: (events.append("write"), write(*a, **k))[1])
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    assert cli("param", mesh, "-o", tmp_path / "a.obj", "--quiet")[0] == 0
    assert events == [True, "write"]

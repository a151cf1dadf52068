"""Output paths: only regular files (or new names) are ever replaced, checks create nothing, and an
interrupted write leaves no temporary file (issue 10, classes 1 and 6, library level; the command
line is tested in tests/test_cli.py)."""

from __future__ import annotations

import os
import signal
import socket
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import grid
from geomopt._runtime.errors import GeomoptError
from geomopt.io import atomic_output, atomic_path, atomic_write, check_output_path, write_mesh_with_uv

REPO = Path(__file__).resolve().parents[1]


def snapshot(folder):
    """Names and the folder's own mtime: creating and deleting a file changes the latter."""
    return sorted(os.listdir(folder)), os.stat(folder).st_mtime_ns


def special_files(tmp_path):
    fifo = tmp_path / "pipe.obj"
    os.mkfifo(fifo)
    link = tmp_path / "link.obj"
    link.symlink_to(tmp_path / "target.obj")
    (tmp_path / "target.obj").write_text("target\n")
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "s.obj"))
    sock.close()
    return {
        "FIFO": (fifo, r"named pipe \(FIFO\)"),
        "/dev/null": (Path("/dev/null"), "character device"),
        "/dev/full": (Path("/dev/full"), "character device"),
        "symlink": (link, "symbolic link"),
        "socket": (tmp_path / "s.obj", "socket"),
        "directory": (tmp_path, "is a directory"),
    }


def test_check_output_path_refuses_what_is_not_a_regular_file_and_creates_nothing(tmp_path):
    cases = special_files(tmp_path)
    before = snapshot(tmp_path)
    for name, (path, words) in cases.items():
        with pytest.raises(GeomoptError, match=words):
            check_output_path(path)
        with pytest.raises(GeomoptError, match=words):  # the writers check too, and write nothing
            atomic_write(path, lambda fh: fh.write("x"))
    assert snapshot(tmp_path) == before
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode) and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert stat.S_ISFIFO(os.lstat(tmp_path / "pipe.obj").st_mode)
    assert (tmp_path / "target.obj").read_text() == "target\n" and (tmp_path / "link.obj").is_symlink()
    check_output_path(tmp_path / "new.obj")
    check_output_path(tmp_path / "target.obj")
    assert snapshot(tmp_path) == before  # the checks of good paths create nothing either


def test_a_folder_given_as_output_gets_an_example_name_of_the_right_kind(tmp_path):
    """The suggested file name has an allowed extension (it said 'out.obj' for a picture)."""
    (tmp_path / "pics.png").mkdir()
    for path, example in ((tmp_path / "pics.png", "pics.png/out.png"), (f"{tmp_path}/", "/out.png")):
        with pytest.raises(GeomoptError) as info:
            check_output_path(path, (".png", ".pdf", ".svg"), what="--png picture")
        assert example in str(info.value) and "out.obj" not in str(info.value)
    with pytest.raises(GeomoptError, match=r"pics\.png/out\.png"):  # no list: the path's own extension
        check_output_path(tmp_path / "pics.png")


def test_check_output_path_names_and_extensions(tmp_path):
    with pytest.raises(GeomoptError, match="name too long for the file system"):
        check_output_path(tmp_path / ("x" * 300 + ".obj"))
    with pytest.raises(GeomoptError, match="names a folder"):
        check_output_path(str(tmp_path) + "/")
    with pytest.raises(GeomoptError, match=r"extension '\.stl'; supported: \.obj, \.ply"):
        check_output_path(tmp_path / "a.stl", (".obj", ".ply"))
    with pytest.raises(GeomoptError, match="has no extension"):
        check_output_path(tmp_path / "a", (".obj",))
    assert check_output_path(tmp_path / "A.PLY", (".obj", ".ply")) == tmp_path / "A.PLY"
    long_utf8 = tmp_path / ("\u00e9" * 120 + ".obj")  # 244 bytes: fits, and so must its temporary name
    atomic_write(long_utf8, lambda fh: fh.write("ok\n"))
    assert long_utf8.read_text() == "ok\n" and os.listdir(tmp_path) == [long_utf8.name]


def test_atomic_path_replaces_only_on_success(tmp_path):
    target = tmp_path / "out.obj"
    target.write_text("old\n")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("new\n")
            raise RuntimeError("not certified")
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["out.obj"]
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".out.obj.")
        tmp.write_text("new\n")
    assert target.read_text() == "new\n" and os.listdir(tmp_path) == ["out.obj"]


def test_atomic_output_refuses_a_target_that_became_special_while_writing(tmp_path):
    target = tmp_path / "out.obj"
    with pytest.raises(GeomoptError, match="named pipe"):
        with atomic_output(target) as fh:
            fh.write("data\n")
            os.mkfifo(target)
    assert stat.S_ISFIFO(os.lstat(target).st_mode) and os.listdir(tmp_path) == ["out.obj"]


def test_write_mesh_with_uv_picks_the_format_by_extension(tmp_path):
    V2, F = grid(3)
    V = np.c_[V2, np.zeros(len(V2))]
    write_mesh_with_uv(tmp_path / "a.obj", V, F, V2)
    write_mesh_with_uv(tmp_path / "a.PLY", V, F, V2)
    assert (tmp_path / "a.obj").read_bytes().startswith(b"v ")
    assert (tmp_path / "a.PLY").read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    with pytest.raises(GeomoptError, match="supported: .obj, .ply"):
        write_mesh_with_uv(tmp_path / "a.off", V, F, V2)
    assert sorted(os.listdir(tmp_path)) == ["a.PLY", "a.obj"]


SLOW_WRITE = """
import sys, time
sys.path.insert(0, {tests!r})
import numpy as np
from types import SimpleNamespace
from conftest import grid
import geomopt.io, geomopt.param, geomopt.cli

V2, F = grid(4)
real = geomopt.io._obj.write_rows

def slow(fh, prefix, A):
    real(fh, prefix, A)
    fh.flush()
    print("writing", flush=True)
    time.sleep(60)

geomopt.io._obj.write_rows = slow
geomopt.param.parameterize = lambda V, F, **k: SimpleNamespace(
    energy=1.0, mean_energy=1.0, stats=SimpleNamespace(iterations=1, seconds=0.0, setup_seconds=0.0),
    certificate=SimpleNamespace(inverted=0), details=None, outcome=SimpleNamespace(value="converged"),
    success=True, x=V2, injectivity="local", message="converged", objective=None)
sys.exit(geomopt.cli.main(["param", sys.argv[1], "-o", sys.argv[2], "--quiet"]))
"""


def slow_write(tmp_path, mesh, out):
    """``geomopt param mesh -o out`` in a process that stops (60 s) after writing part of the file."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    script = textwrap.dedent(SLOW_WRITE.format(tests=str(REPO / "tests")))
    return subprocess.Popen([sys.executable, "-c", script, str(mesh), str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_signal_during_the_write_leaves_no_temporary_file(tmp_path, signum):
    """The command line turns SIGTERM/SIGHUP (and SIGINT) into an exception: the temporary file goes."""
    V2, F = grid(4)
    mesh = tmp_path / "m.obj"
    mesh.write_text("".join(f"v {x!r} {y!r} 0.0\n" for x, y in V2.tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))
    out = tmp_path / "uv.obj"
    out.write_text("previous result\n")
    proc = slow_write(tmp_path, mesh, out)
    try:
        assert proc.stdout.readline() == "writing\n"
        assert any(name.startswith(".uv.obj.") for name in os.listdir(tmp_path))  # mid-write
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signum, err
    assert f"interrupted by {signal.Signals(signum).name}" in err and "Traceback" not in err
    assert sorted(os.listdir(tmp_path)) == ["cache", "m.obj", "uv.obj"]
    assert out.read_text() == "previous result\n"


# ------------------------------------------------------- a command's outputs (issue 19, item 4)

from geomopt.io import check_outputs, create_output_folder  # noqa: E402


def tree(folder):
    """Every file and folder under ``folder`` with its bytes (None for a folder)."""
    return {p.relative_to(folder): (None if p.is_dir() else p.read_bytes()) for p in sorted(Path(folder).rglob("*"))}


def flat_obj(path):
    V, F = grid(4)
    path.write_text("".join(f"v {x!r} {y!r} 0.0\n" for x, y in V.tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))
    return path


def lim2d(folder):
    """A small flip-free 2D LIM case (identity map, boundary fixed)."""
    from geomopt.lim import LimCase
    from geomopt.exact.topology import boundary_vertices

    V, F = grid(4)
    return LimCase(dim=2, rest=np.c_[V, np.zeros(len(V))], init=V, simplices=F,
                   handles=boundary_vertices(F, len(V))).write(folder)


def test_check_outputs_refuses_an_input_by_identity_not_by_name(tmp_path):
    """Same file under another spelling, a symbolic link to it, a hard link: all are the input."""
    mesh = flat_obj(tmp_path / "newton.obj")
    os.link(mesh, tmp_path / "hard.obj")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "soft.obj").symlink_to(mesh)
    before = tree(tmp_path)
    for out, inputs in [(tmp_path / "." / "newton.obj", [mesh]), (tmp_path / "hard.obj", [mesh]),
                        (mesh, [tmp_path / "sub" / "soft.obj"]), (tmp_path / "newton.obj", [tmp_path])]:
        with pytest.raises(GeomoptError, match="is the input file .* would replace your input"):
            check_outputs([("map", out)], inputs)
    assert check_outputs([tmp_path / "other.obj", ("map", tmp_path / "b.ply", (".ply",))], [mesh]) == \
        [tmp_path / "other.obj", tmp_path / "b.ply"]
    with pytest.raises(GeomoptError, match="picture .* is the same file as the map"):
        check_outputs([("map", tmp_path / "a.obj"), ("picture", tmp_path / "sub" / ".." / "a.obj")])
    assert tree(tmp_path) == before


def test_output_folders_one_rule_created_without_parents_never_a_case_or_an_input(tmp_path):
    case = lim2d(tmp_path / "case")
    (tmp_path / "file").write_text("x")
    before = tree(tmp_path)
    for folder, inputs, words in [
        (case, [], "is a LIM case folder .* replace a case's input"),
        (tmp_path / "in", [tmp_path / "in"], "is the input folder"),
        (tmp_path / "a" / "b" / "c", [], "parent .* does not exist; create it first"),
        (tmp_path / "file" / "c", [], "parent .* is not a folder"),
        (tmp_path / "file", [], "exists and is not a folder"),
    ]:
        if inputs:
            (tmp_path / "in").mkdir(exist_ok=True)
            before = tree(tmp_path)
        with pytest.raises(GeomoptError, match=words):
            check_outputs([Path(folder) / "summary.csv"], inputs, folder=folder)
    assert tree(tmp_path) == before
    new = tmp_path / "new"
    assert check_outputs([("summary", new / "s.csv", (".csv",))], folder=new) == [new / "s.csv"]  # to be created
    with pytest.raises(GeomoptError, match="has extension '.txt'"):
        check_outputs([("summary", new / "s.txt", (".csv",))], folder=new)
    with pytest.raises(GeomoptError, match="name too long"):
        check_outputs([new / ("x" * 260 + ".obj")], folder=new)
    assert not new.exists()
    assert create_output_folder(new) == new and new.is_dir()
    with pytest.raises(GeomoptError, match="cannot create the output folder"):
        create_output_folder(tmp_path / "a" / "b")


def test_compare_never_replaces_its_input_nor_writes_into_a_case(cli, tmp_path, monkeypatch):
    """``compare newton.obj --out . --solvers newton`` rewrote newton.obj; a case folder as --out
    got the outputs; --out a/b/c created a and b.  All refused before solving, nothing created."""
    import geomopt

    monkeypatch.setattr("geomopt.experiments.comparison._run", lambda *a, **k: pytest.fail("solved anyway"))
    mesh = flat_obj(tmp_path / "newton.obj")
    case = lim2d(tmp_path / "case")
    before = tree(tmp_path)
    for argv, words in [
        ([mesh, "--out", tmp_path], ["is the input file", "newton.obj"]),
        ([case, "--out", case], ["is the input folder"]),
        ([mesh, "--out", case], ["is a LIM case folder"]),
        ([mesh, "--out", tmp_path / "a" / "b" / "c"], ["does not exist; create it first"]),
    ]:
        code, _, err = cli("compare", *argv, "--solvers", "newton", "--quiet")
        assert code == 2, argv
        assert err.startswith("geomopt: error: ") and len(err.splitlines()) == 1 and all(w in err for w in words), err
    with pytest.raises(GeomoptError, match="is the input file"):
        geomopt.compare(mesh, solvers=["newton"], out=tmp_path)
    assert tree(tmp_path) == before


def test_every_command_refuses_a_missing_parent_and_creates_nothing(cli, tmp_path, monkeypatch):
    """One rule: an output file's folder, or an output folder's parent, must exist."""
    for target in ("geomopt.param.parameterize", "geomopt.lim.untangle_case", "geomopt.experiments.batch.solve_case"):
        monkeypatch.setattr(target, lambda *a, **k: pytest.fail("solved anyway"))
    mesh = flat_obj(tmp_path / "m.obj")
    case = lim2d(tmp_path / "cases" / "sq")
    before = tree(tmp_path)
    for argv in (["param", mesh, "-o", tmp_path / "a" / "uv.obj"], ["demo", "-o", tmp_path / "a" / "b"],
                 ["untangle", case, "-o", tmp_path / "a" / "sq.obj"],
                 ["untangle", tmp_path / "cases", "-o", tmp_path / "a" / "b", "--workers", "1"]):
        code, _, err = cli(*argv, "--quiet")
        assert code == 2 and "does not exist" in err, (argv, err)
    code, _, err = cli("untangle", tmp_path / "cases", "-o", case, "--workers", "1", "--quiet")
    assert code == 2 and "is the input folder" in err, err
    assert tree(tmp_path) == before


# ------------------------------------------------------- stale temporaries (issue 19, exit codes)


def test_a_sigkill_leaves_a_temporary_that_the_next_write_of_that_output_removes(tmp_path):
    """SIGKILL cannot be caught: the temporary stays; the next write of the same output removes it
    (it is not locked by a live writer any more), and leaves other outputs' temporaries alone."""
    V2, F = grid(4)
    mesh = flat_obj(tmp_path / "m.obj")
    out = tmp_path / "uv.obj"
    proc = slow_write(tmp_path, mesh, out)
    try:
        assert proc.stdout.readline() == "writing\n"
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        proc.kill()
    left = [n for n in os.listdir(tmp_path) if n.startswith(".uv.obj.")]
    assert len(left) == 1 and not out.exists()
    other = tmp_path / ".other.obj.0123456789ab.tmp"
    other.write_text("another output's\n")
    write_mesh_with_uv(out, np.c_[V2, np.zeros(len(V2))], F, V2)
    assert sorted(os.listdir(tmp_path)) == sorted(["cache", "m.obj", "uv.obj", other.name])


def test_a_temporary_held_by_a_live_writer_is_kept(tmp_path):
    import fcntl

    live = tmp_path / ".out.txt.aaaaaaaaaaaa.tmp"
    live.write_text("")
    with open(live) as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        atomic_write(tmp_path / "out.txt", lambda f: f.write("done\n"))
        assert live.exists() and (tmp_path / "out.txt").read_text() == "done\n"


def test_a_fifo_or_folder_named_like_a_temporary_is_left_alone_without_hanging(tmp_path):
    """Opening a FIFO for reading blocks until a writer comes: the cleanup must not hang on one."""
    fifo = tmp_path / ".out.txt.0123456789ab.tmp"
    os.mkfifo(fifo)
    (tmp_path / ".out.txt.aaaaaaaaaaaa.tmp").mkdir()
    proc = subprocess.run([sys.executable, "-c", "import sys; from geomopt.io import atomic_write; "
                           "atomic_write(sys.argv[1], lambda fh: fh.write('x'))", str(tmp_path / "out.txt")],
                          env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=60, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and (tmp_path / ".out.txt.aaaaaaaaaaaa.tmp").is_dir()

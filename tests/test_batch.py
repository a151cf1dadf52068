"""Batches of untangling cases (issue 9, parts 3-4): size buckets, summary rows, Dask.

Every padded case here falls in the smallest buckets (2D: 160 vertices / 256 triangles, 3D:
96 / 256), like the CLI tests' cases, so the suite compiles each bucket once.
"""

from __future__ import annotations

import csv
import dataclasses
import os

import numpy as np
import pytest

import geomopt.cli
from geomopt.mesh import generators as G
from geomopt import ParameterError, UntangleOptions, io
from geomopt._runtime.padding import MAXIMUM_ELEMENTS, bucket_sizes
from geomopt.experiments.batch import EXCEPT_FIXED, SUMMARY_COLUMNS, batch_cases, default_workers, run_batch, tally
from geomopt.lim import LimCase, output_suffix
from geomopt.exact.predicates import count_inverted
from geomopt.untangling import untangle
from geomopt.untangling.continuation import _outer_stats


def tangles():
    return {
        "square": G.rotated_interior(*G.square_mesh(8), 90.0, name="square"),
        "star": G.tutte_nonconvex(6, "star", arms=5, depth=0.6, name="star"),
        "disk": G.noisy_interior(*G.disk_mesh(5), 1.5, seed=3, name="disk"),
        "cube": G.rotated_interior(*G.box_mesh(3, 3, 3), 90.0, name="cube"),
    }


# ------------------------------------------------------------------ buckets and padding


def test_bucket_sizes():
    assert bucket_sizes(64, 98, 2) == (160, 256)
    assert bucket_sizes(64, 162, 3) == (96, 256)
    assert bucket_sizes(300, 257, 2) == (320, 512)  # next element bucket
    assert bucket_sizes(200, 250, 2) == (320, 256)  # more vertices than the share: next vertex bucket
    assert bucket_sizes(160, 256, 2) == (160, 256)
    assert bucket_sizes(161, 256, 2) == (320, 256)
    assert bucket_sizes(10, MAXIMUM_ELEMENTS, 3) == (6144, MAXIMUM_ELEMENTS)
    assert bucket_sizes(10, MAXIMUM_ELEMENTS + 1, 3) is None


@pytest.mark.parametrize("name", ["square", "star", "cube"])
def test_padding_gives_the_same_map_up_to_the_rounding_of_sums(name):
    """Padded and unpadded solves take the same outer and inner iterations to the same map:
    bit for bit where XLA happens to split the longer sums alike, else within 1e-12 of the
    map's size (the energy and the solver's dot products sum over more, zero, terms)."""
    t = tangles()[name]
    assert t.inverted() > 0
    plain = untangle(t.problem(), t.x0, progress=False)
    padded = untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(bucket=True))
    assert plain.success and padded.success, (plain.message, padded.message)
    assert padded.x.shape == plain.x.shape
    assert (padded.stats.outer_iterations, padded.stats.iterations) == (plain.stats.outer_iterations, plain.stats.iterations)
    assert padded.stats.inverted_at_start == plain.stats.inverted_at_start == t.inverted()
    np.testing.assert_allclose(padded.x, plain.x, rtol=0, atol=1e-12 * np.ptp(t.x0))
    np.testing.assert_allclose(padded.trace.column("min_det"), plain.trace.column("min_det"), rtol=1e-9)
    assert count_inverted(padded.x, t.simplices) == 0
    assert np.array_equal(padded.x[t.fixed].view(np.uint64), t.x0[t.fixed].view(np.uint64))


def test_cases_of_one_bucket_share_the_compiled_kernels():
    from geomopt.solvers import lbfgs

    ts = tangles()
    untangle(ts["square"].problem(), ts["square"].x0, progress=False, options=UntangleOptions(bucket=True))
    kernels = [lbfgs._run_kernel, lbfgs._reparam_kernel, _outer_stats]
    before = [k._cache_size() for k in kernels]
    for name in ("star", "disk"):  # other shapes, the same bucket
        assert untangle(ts[name].problem(), ts[name].x0, progress=False, options=UntangleOptions(bucket=True)).success
    assert [k._cache_size() for k in kernels] == before


def test_padding_is_fixed_and_weightless():
    """Padded elements are zero-volume copies of elements 0, 1, ... (cycling: copies of one
    element would serialise the gradient's scatter-add on its vertices), padded vertices fixed
    copies of vertex 0: energy, gradient (real rows), Newton Hessian and extent are the
    unpadded ones, and a sub-problem padded like its whole shares its bucket."""
    from geomopt import Objective
    from geomopt.energies import garanzha

    t = tangles()["star"]
    p = t.problem()
    plain, padded = Objective(p, garanzha), Objective(p, garanzha, buckets=True)
    n, m = p.n_vertices, p.n_elements
    sz = padded.sizes
    assert (sz.n_padded, sz.m_padded) == bucket_sizes(n, m, 2) and sz.padded
    S, Minv, vol = (np.asarray(a) for a in padded.geom)
    cycled = np.arange(sz.m_padded - m) % m
    assert np.array_equal(S[:m], p.simplices) and np.array_equal(S[m:], p.simplices[cycled]) and np.all(vol[m:] == 0)
    assert np.array_equal(Minv[m:], Minv[cycled])
    assert np.all(np.asarray(padded.free_mask)[n:] == 0)
    x = padded.pad_map(t.x0)
    assert np.array_equal(x[:n], t.x0) and np.all(x[n:] == t.x0[0])
    params = plain.params(eps=0.1, lam=0.01)
    v0, g0 = plain.value_and_grad(t.x0, params)
    v1, g1 = padded.value_and_grad(x, params)
    assert float(v1) == pytest.approx(float(v0), rel=1e-14)
    np.testing.assert_allclose(np.asarray(g1)[:n], np.asarray(g0), rtol=0, atol=1e-12 * float(np.abs(g0).max()))
    H0, H1 = (np.asarray(o.hessian(t.x0, params)[2]) for o in (plain, padded))
    assert abs(H1 - H0).max() <= 1e-12 * abs(H0).max()
    half = slice(0, m // 2)  # a sub-problem on the same vertices (as untangle's active elements)
    sub = dataclasses.replace(p, simplices=p.simplices[half], input_simplices=p.input_simplices[half],
                              rest_inv=p.rest_inv[half], volumes=p.volumes[half])
    assert Objective(sub, garanzha, buckets=sz).sizes == dataclasses.replace(sz, m=m // 2)
    with pytest.raises(ParameterError, match="do not hold"):
        Objective(p, garanzha, buckets=dataclasses.replace(sz, m_padded=m - 1))
    with pytest.raises(ParameterError, match="buckets must be"):
        Objective(p, garanzha, buckets="yes")


def test_untangling_stats_ignore_the_padding():
    """The worst det J and the inverted count of the outer loop see only real elements (the
    padded copies of real elements would count them again)."""
    from geomopt import Objective
    from geomopt.energies import garanzha

    t = tangles()["square"]
    p = t.problem()
    obj = Objective(p, garanzha, buckets=True)
    assert obj.sizes.padded
    x = obj.pad_map(2.0 * t.rest)  # every real det J = 4
    _, worst, inverted = _outer_stats(garanzha.density, obj.geom, x, obj.params(eps=1.0, lam=0.01))
    assert float(worst) == pytest.approx(4.0) and int(inverted) == 0
    x0 = t.x0.copy()
    a, b = p.simplices[0, :2]
    x0[[a, b]] = x0[[b, a]]  # element 0 inverted: its padded copies are too, but not counted
    assert count_inverted(x0, p.simplices[:1]) == 1
    x = obj.pad_map(x0)
    _, worst, inverted = _outer_stats(garanzha.density, obj.geom, x, obj.params(eps=1.0, lam=0.01))
    assert int(inverted) == count_inverted(x0, p.simplices) and float(worst) < 0


# ------------------------------------------------------------------ batches


def make_cases(root, names=("square", "star", "disk", "cube")):
    ts = tangles()
    root.mkdir(parents=True)
    for name in names:
        LimCase.from_tangle(ts[name]).write(root / name)
    (root / "no_handles").mkdir()
    io.write_obj_with_uv(root / "no_handles" / "input.obj", np.c_[ts["square"].rest, np.zeros(64)],
                         ts["square"].simplices, ts["square"].x0)
    (root / "garbage").mkdir()
    (root / "garbage" / "input.obj").write_text("v 0 0 0\nvt 0 0\nf 1 1 x\n")
    (root / "garbage" / "handles.txt").write_text("0\n")
    stuck = G.Tangle("stuck", ts["square"].rest, ts["square"].simplices, ts["square"].x0,
                     np.arange(64))  # every vertex fixed, folded: cannot certify
    LimCase.from_tangle(stuck).write(root / "stuck")
    return root


BAD = {"no_handles": "has no handles.txt", "garbage": "line 3", "stuck": "not certified"}


def read_summary(path):
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == SUMMARY_COLUMNS
        return list(reader)


def test_a_batch_reports_bad_cases_and_certifies_the_rest(tmp_path):
    cases = batch_cases([make_cases(tmp_path / "cases")])
    assert [c.name for c in cases] == sorted(["square", "star", "disk", "cube", "no_handles", "garbage", "stuck"])
    seen = []
    rows = run_batch(cases, tmp_path / "out", report=lambda row, done, total: seen.append((row["case"], done, total)))
    assert seen == [(c.name, i + 1, len(cases)) for i, c in enumerate(cases)]
    by_case = {r["case"]: r for r in rows}
    for name, words in BAD.items():
        assert by_case[name]["certified"] == "no" and words in by_case[name]["message"], by_case[name]
        assert not any(p.name.startswith(name) for p in (tmp_path / "out").iterdir())
    ts = tangles()
    for name in ("square", "star", "disk", "cube"):
        row, t = by_case[name], ts[name]
        assert row["certified"] == "yes" and row["message"] == "" and row["inverted_after"] == 0
        assert (row["dim"], row["elements"], row["inverted_before"]) == (t.dim, t.n_elements, t.inverted())
        if t.dim == 2:
            V, UV, F = io.read_obj_with_uv(tmp_path / "out" / f"{name}.obj")
        else:
            UV, F = io.read_vtk_tets(tmp_path / "out" / f"{name}.vtk")
        assert count_inverted(UV, F) == 0 and np.array_equal(UV[t.fixed], t.x0[t.fixed])
    assert read_summary(tmp_path / "out" / "summary.csv") == [{k: str(v) for k, v in r.items()} for r in rows]
    assert not [p for p in os.listdir(tmp_path / "out") if p.startswith(".")]  # no temporary left


@pytest.fixture
def own_cache(tmp_path):
    """A fresh persistent compilation cache folder for this test (the previous one restored)."""
    from geomopt._runtime import cache as _cache

    before = _cache.cache_dir()
    yield _cache.set_cache_dir(tmp_path / "jax-cache")
    _cache.set_cache_dir(before)


def test_the_dask_path_on_a_local_cluster_equals_the_serial_path(tmp_path, own_cache):
    """Same rows and bytes as the serial path; the workers compile into (and load from) the
    client's persistent cache folder, whatever their own environment says."""
    cases = batch_cases([make_cases(tmp_path / "cases", names=("square", "star", "disk"))])
    dask = run_batch(cases, tmp_path / "dask", workers=2, chunk=1)
    kept = os.listdir(own_cache) + os.listdir(os.path.join(own_cache, "programs"))  # JAX's cache, geomopt's programs
    assert any("_run_kernel" in name for name in kept)  # written by the workers
    serial = run_batch(cases, tmp_path / "serial")
    assert [{**r, "seconds": ""} for r in dask] == [{**r, "seconds": ""} for r in serial]
    assert sorted(os.listdir(tmp_path / "dask")) == sorted(os.listdir(tmp_path / "serial"))
    for r in serial:
        if r["output"]:
            assert (tmp_path / "dask" / r["output"]).read_bytes() == (tmp_path / "serial" / r["output"]).read_bytes()
    assert sum(r["certified"] == "yes" for r in serial) == 3


def test_an_existing_scheduler_runs_the_batch(tmp_path):
    """``scheduler=ADDRESS`` sends the cases to that cluster's workers (here cases that fail
    while being read, so nothing compiles)."""
    from distributed import LocalCluster

    root = make_cases(tmp_path / "cases", names=())
    cases = [root / "garbage", root / "no_handles"]
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        rows = run_batch(cases, tmp_path / "out", scheduler=cluster.scheduler_address)
    assert [(r["case"], r["certified"]) for r in rows] == [("garbage", "no"), ("no_handles", "no")]
    assert BAD["garbage"] in rows[0]["message"] and BAD["no_handles"] in rows[1]["message"]
    assert [r["case"] for r in read_summary(tmp_path / "out" / "summary.csv")] == ["garbage", "no_handles"]


# ------------------------------------------------------------------ the command line


def test_cli_batch_exit_status_and_outputs(cli, tmp_path):
    ts = tangles()
    good = tmp_path / "good"
    for name in ("square", "cube"):
        LimCase.from_tangle(ts[name]).write(good / name)
    code, _, err = cli("untangle", good, "-o", tmp_path / "out", "--workers", "1", "--quiet")
    assert (code, err) == (0, "")
    assert sorted(os.listdir(tmp_path / "out")) == ["cube.vtk", "square.obj", "summary.csv"]
    # one case to one file gives the same bytes as the batch
    assert cli("untangle", good / "square", "-o", tmp_path / "one.obj", "--quiet")[0] == 0
    assert (tmp_path / "one.obj").read_bytes() == (tmp_path / "out" / "square.obj").read_bytes()
    # some cases fail: exit 1, the others written, one line even with --quiet
    mixed = make_cases(tmp_path / "mixed", names=("star",))
    code, _, err = cli("untangle", mixed, good / "square", "-o", tmp_path / "out2", "--workers", "1", "--quiet")
    assert code == 1 and err.startswith("geomopt: 3 of 5 case(s) not certified") and len(err.splitlines()) == 1
    assert sorted(os.listdir(tmp_path / "out2")) == ["square.obj", "star.obj", "summary.csv"]
    rows = read_summary(tmp_path / "out2" / "summary.csv")
    assert [r["case"] for r in rows] == ["garbage", "no_handles", "star", "stuck", "square"]


def test_a_batch_takes_quad_and_hex_case_folders(cli, tmp_path):
    """The hex case folder README documents (rest.vtk + init.vtk of hexahedra, handles.txt) was
    refused in a batch ("only tetrahedral meshes"); it is solved as the one-case command solves
    it, beside a tet case, and written to <name>.vtk with the same bytes."""
    root = tmp_path / "root"
    for name, t in (("hexes", G.noisy_interior(*G.hex_mesh(3, 3, 2), 1.0, seed=3)),
                    ("quads", G.rotated_interior(*G.quad_mesh(5, 4), 110.0))):
        kind = "hexahedron" if t.dim == 3 else "quad"
        (root / name).mkdir(parents=True)
        io.write_cells(root / name / "rest.vtk", t.rest, t.simplices, kind)
        io.write_cells(root / name / "init.vtk", t.x0, t.simplices, kind)
        np.savetxt(root / name / "handles.txt", t.fixed, fmt="%d")
    LimCase.from_tangle(tangles()["cube"]).write(root / "cube")
    code, _, err = cli("untangle", root, "-o", tmp_path / "out", "--workers", "1", "--quiet")
    assert (code, err) == (0, "")
    rows = read_summary(tmp_path / "out" / "summary.csv")
    assert [(r["case"], r["dim"], r["certified"]) for r in rows] == [
        ("cube", "3", "yes"), ("hexes", "3", "yes"), ("quads", "2", "yes")]
    assert cli("untangle", root / "hexes", "-o", tmp_path / "one.vtk", "--quiet")[0] == 0
    assert (tmp_path / "one.vtk").read_bytes() == (tmp_path / "out" / "hexes.vtk").read_bytes()
    # --start reaches every case of a batch: the same bytes as the one-case command with it
    code, _, err = cli("untangle", root, "-o", tmp_path / "given", "--workers", "1", "--quiet", "--start", "given")
    assert (code, err) == (0, "")
    assert cli("untangle", root / "hexes", "-o", tmp_path / "one_given.vtk", "--quiet", "--start", "given")[0] == 0
    given = (tmp_path / "given" / "hexes.vtk").read_bytes()
    assert given == (tmp_path / "one_given.vtk").read_bytes()
    # the polished maps agree whatever the start (the minimum of one energy); the paths do not
    inner = {r["case"]: r["inner_iterations"] for r in rows}
    inner_given = {r["case"]: r["inner_iterations"] for r in read_summary(tmp_path / "given" / "summary.csv")}
    assert inner_given["hexes"] != inner["hexes"]


def test_cli_batch_bad_usage_exits_2_before_solving(cli, tmp_path, monkeypatch):
    monkeypatch.setattr("geomopt.experiments.batch.solve_case", lambda *a, **k: pytest.fail("solved anyway"))
    ts = tangles()
    LimCase.from_tangle(ts["square"]).write(tmp_path / "a" / "square")
    LimCase.from_tangle(ts["star"]).write(tmp_path / "b" / "square")
    (tmp_path / "empty").mkdir()
    for argv, words in [
        ([tmp_path / "a", tmp_path / "nope"], ["nope is not a folder"]),
        ([tmp_path / "a", tmp_path / "empty"], ["empty holds no LIM case folder"]),
        ([tmp_path / "a", tmp_path / "b"], ["have the same folder name"]),
        ([tmp_path / "a" / "square", tmp_path / "b" / "square", "-o", tmp_path / "x.obj"],
         ["2 case folders need an output folder"]),
    ]:
        if "-o" not in argv:
            argv = argv + ["-o", tmp_path / "out"]
        code, _, err = cli("untangle", *argv, "--quiet")
        assert code == 2, argv
        assert err.startswith("geomopt: error: ") and all(w in err for w in words), err
    (tmp_path / "file").write_text("")
    code, _, err = cli("untangle", tmp_path / "a", "-o", tmp_path / "file" / "sub", "--quiet")
    assert code == 2 and "cannot create the output folder" in err


def test_a_batch_never_writes_over_a_case_input(cli, tmp_path, monkeypatch):
    """A case folder named ``input`` inside case ``R``, output folder ``R/``: ``R/input.obj``
    would be written over case R's own input.  Refused before anything is solved or written."""
    monkeypatch.setattr("geomopt.experiments.batch.solve_case", lambda *a, **k: pytest.fail("solved anyway"))
    ts = tangles()
    LimCase.from_tangle(ts["square"]).write(tmp_path / "R")
    LimCase.from_tangle(ts["star"]).write(tmp_path / "R" / "input")
    before = {p: p.read_bytes() for p in (tmp_path / "R").rglob("*") if p.is_file()}
    code, _, err = cli("untangle", tmp_path / "R" / "input", "-o", str(tmp_path / "R") + "/", "--quiet")
    assert code == 2 and "is a LIM case folder" in err and "replace a case's input" in err, err
    assert {p: p.read_bytes() for p in (tmp_path / "R").rglob("*") if p.is_file()} == before


# ------------------------------------------------------------------ issue 19: exit codes and messages

import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import textwrap  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]

SLOW_BATCH = """
import sys, time
import geomopt.experiments.batch, geomopt.cli

real = geomopt.experiments.batch.solve_case

def slow(folder, outdir, *a, **k):
    if not str(folder).endswith("a"):
        print("solving", flush=True)
        time.sleep(120)
    row = real(folder, outdir, *a, **k)
    print("finished", row["case"], flush=True)
    return row

geomopt.experiments.batch.solve_case = slow
sys.exit(geomopt.cli.main(["untangle", sys.argv[1], "-o", sys.argv[2], "--workers", "1", "--quiet"]))
"""


def test_a_batch_stopped_by_sigterm_writes_the_summary_of_what_finished(tmp_path):
    ts = tangles()
    for name, t in (("a", "square"), ("b", "square"), ("c", "star")):
        LimCase.from_tangle(ts[t]).write(tmp_path / "cases" / name)
    env = {**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(SLOW_BATCH), str(tmp_path / "cases"),
                             str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    try:
        assert proc.stdout.readline() == "finished a\n"
        assert proc.stdout.readline() == "solving\n"  # interrupt b before it is written
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM and "interrupted by SIGTERM" in err, err
    assert sorted(os.listdir(tmp_path / "out")) == ["a.obj", "summary.csv"]
    rows = read_summary(tmp_path / "out" / "summary.csv")
    assert [(r["case"], r["certified"]) for r in rows] == [("a", "yes"), ("b", "no"), ("c", "no")]
    assert all("interrupted" in r["message"] and "summary incomplete" in r["message"] for r in rows[1:])


WRITTEN_THEN_SLOW = """
import sys, time
import geomopt.experiments.batch, geomopt.cli

real = geomopt.experiments.batch.solve_case

def written_then_slow(folder, outdir, *a, **k):
    row = real(folder, outdir, *a, **k)
    if str(folder).endswith("b"):  # as a Dask worker whose row has not reached the client yet
        print("written", flush=True)
        time.sleep(120)
    return row

geomopt.experiments.batch.solve_case = written_then_slow
sys.exit(geomopt.cli.main(["untangle", sys.argv[1], "-o", sys.argv[2], "--workers", "1", "--quiet"]))
"""


def test_an_interrupted_batch_says_which_outputs_it_wrote_before_their_rows_arrived(tmp_path):
    ts = tangles()
    for name in ("a", "b", "c"):
        LimCase.from_tangle(ts["square"]).write(tmp_path / "cases" / name)
    out = tmp_path / "out"
    out.mkdir()
    (out / "c.obj").write_text("an older batch's output\n")  # not written by this batch
    os.utime(out / "c.obj", (0, 0))
    env = {**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(WRITTEN_THEN_SLOW), str(tmp_path / "cases"),
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline() == "written\n"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    rows = read_summary(out / "summary.csv")
    assert [(r["case"], r["certified"], r["output"]) for r in rows] == [("a", "yes", "a.obj"), ("b", "yes", "b.obj"),
                                                                          ("c", "no", "")]
    assert "statistics were lost" in rows[1]["message"] and "not solved" in rows[2]["message"]


def test_a_scheduler_that_is_not_an_address_is_bad_usage_and_creates_nothing(cli, tmp_path, monkeypatch):
    monkeypatch.setattr("geomopt.experiments.batch.solve_case", lambda *a, **k: pytest.fail("solved anyway"))
    LimCase.from_tangle(tangles()["square"]).write(tmp_path / "cases" / "sq")
    code, _, err = cli("untangle", tmp_path / "cases", "-o", tmp_path / "out", "--scheduler", "not a url",
                       "--quiet")
    assert code == 2 and err.startswith("geomopt: error: cannot reach the Dask scheduler at not a url")
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_the_batch_helpers_the_command_line_calls(monkeypatch):
    """How many workers a batch gets by default (one per usable core, at most one per case), how its
    rows are tallied (certified, certified except where the handles fix them, not certified) and
    where a solved LIM case is written (2D: .obj, 3D: .vtk)."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    assert (default_workers(2), default_workers(9)) == (2, 4)
    rows = [{"certified": c} for c in ("yes", EXCEPT_FIXED, "no", "yes", "", EXCEPT_FIXED, "yes")]
    assert tally(rows) == (3, 2, 2) and tally([]) == (0, 0, 0)
    assert (output_suffix(2), output_suffix(3)) == (".obj", ".vtk")


def test_without_dask_a_batch_runs_in_this_process_or_names_the_extra(cli, tmp_path, monkeypatch):
    """Dask distributed is the [batch] extra: without it the command's default batch solves the
    cases in its own process (one line on stderr says so), while asking for workers or a
    scheduler is refused with one line naming the extra, before anything is created."""
    import geomopt.experiments.batch

    monkeypatch.setattr(geomopt.experiments.batch, "dask_available", lambda: False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    good = tmp_path / "good"
    for name in ("square", "cube"):
        LimCase.from_tangle(tangles()[name]).write(good / name)
    code, _, err = cli("untangle", good, "-o", tmp_path / "out", "--quiet")
    assert code == 0 and "Dask is not installed" in err and 'geomopt[batch]' in err
    assert len(err.splitlines()) == 1
    assert sorted(os.listdir(tmp_path / "out")) == ["cube.vtk", "square.obj", "summary.csv"]
    for args in (("--workers", "2"), ("--scheduler", "tcp://127.0.0.1:1")):
        code, _, err = cli("untangle", good, "-o", tmp_path / "refused", "--quiet", *args)
        assert code == 2 and 'geomopt[batch]' in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "refused").exists()


def test_a_case_whose_handles_force_an_overlap_is_written_and_said(cli, tmp_path):
    """Issue 30: the tets around an edge turn 1.5 times with every vertex fixed; the batch writes
    it beside a certified case, marks it except_fixed (not yes) with the overlap, and exits 3."""
    from test_fixed_stars import edge_case

    X, T, rest, fixed = edge_case(1.5, 0.75, 10, False)
    LimCase.from_tangle(G.Tangle("forced", rest, T, X, fixed)).write(tmp_path / "in" / "forced")
    LimCase.from_tangle(tangles()["cube"]).write(tmp_path / "in" / "cube")
    code, out, err = cli("untangle", tmp_path / "in", "-o", tmp_path / "out", "--workers", "1", "--quiet")
    assert code == 3 and len(err.splitlines()) == 1 and "1 of 2 case(s) written but not certified everywhere" in err
    assert sorted(os.listdir(tmp_path / "out")) == ["cube.vtk", "forced.vtk", "summary.csv"]
    rows = {r["case"]: r for r in read_summary(tmp_path / "out" / "summary.csv")}
    assert (rows["cube"]["certified"], rows["cube"]["outcome"]) == ("yes", "converged")
    forced = rows["forced"]
    assert (forced["certified"], forced["outcome"], forced["output"]) == ("except_fixed", "certified_except_fixed",
                                                                            "forced.vtk")
    assert "handles alone" in forced["message"] and "(0, 1)" in forced["message"]

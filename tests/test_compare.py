"""``geomopt compare`` and :func:`geomopt.compare`: the four kinds of output files, the API
agreeing with them bit for bit, fixed-boundary (LIM) cases, refusals before any solve, limits."""

from __future__ import annotations

import csv
import importlib
import os

import numpy as np
import pytest

import geomopt
import geomopt.cli
from geomopt import MeshError, ParameterError, Problem, io
from geomopt._compare import HISTORY_COLUMNS, SUMMARY_COLUMNS, TIME_LIMIT, Comparison
from geomopt.generators import boundary_vertices, box_mesh, rotated_interior, square_mesh
from geomopt.linesearch import InjectiveSearch
from geomopt.predicates import count_inverted
from geomopt.solvers import LBFGS

from conftest import grid
from test_cli import one_error_line, read_uv_obj, write_obj

# geomopt.compare is the function (re-exported by geomopt); the module is this:
compare_module = importlib.import_module("geomopt._compare")
V2, F = grid(4)  # test_cli's mesh (16 vertices, 18 triangles): kernels compiled once per session
V3 = np.c_[V2, 0.3 * np.sin(3.0 * V2[:, 0]) * V2[:, 1]]  # a curved disk
FAST = "newton,aqp,lbfgs"  # quick to compile; newton's kernels are test_cli's


def read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def lim_case(folder, V, F, x, handles):
    """A 2D LIM case folder: input.obj (v = rest, vt = map) and handles.txt."""
    folder.mkdir()
    io.write_obj_with_uv(folder / "input.obj", np.c_[V, np.zeros(len(V))], F, x)
    (folder / "handles.txt").write_text("".join(f"{h}\n" for h in handles))
    return folder


def affine_case(folder, mirrored=False):
    """Fixed boundary at an affine image of a square grid, interior jittered (flip-free); with
    ``mirrored`` the map is clockwise (u -> -u), as LIM cases may be."""
    V, S = square_mesh(4)
    A = np.array([[1.3, 0.2], [-0.1, 0.8]])
    x = V @ A.T
    b = boundary_vertices(S, len(V))
    inner = np.setdiff1d(np.arange(len(V)), b)
    x[inner] += 0.02 * np.random.default_rng(0).standard_normal((inner.size, 2))
    if mirrored:
        x[:, 0] = -x[:, 0]
    return lim_case(folder, V, S, x, b), V, S, x, b


def png_size(data):
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


# ------------------------------------------------------------------ CLI: the files


def test_cli_writes_history_summary_maps_and_a_plot(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    out = tmp_path / "cmp"
    code, stdout, err = cli("compare", mesh, "--out", out, "--solvers", FAST, "--quiet")
    assert (code, stdout, err) == (0, "", "")
    names = FAST.split(",")
    assert sorted(os.listdir(out)) == sorted(["history.csv", "summary.csv", "convergence.png"] +
                                             [n + ".obj" for n in names])

    head, rows = read_csv(out / "history.csv")
    assert tuple(head) == HISTORY_COLUMNS
    assert [r[0] for r in rows if r[1] == "0"] == names  # every solver starts at iteration 0
    starts = {r[3] for r in rows if r[1] == "0"}
    assert len(starts) == 1  # ... from the same start map
    shead, summary = read_csv(out / "summary.csv")
    assert tuple(shead) == SUMMARY_COLUMNS
    assert [s[0] for s in summary] == names
    best = min(float(s[6]) for s in summary)
    for s in summary:
        mine = [r for r in rows if r[0] == s[0]]
        assert [int(r[1]) for r in mine] == list(range(int(s[2]) + 1))
        t = np.array([float(r[2]) for r in mine])
        e = np.array([float(r[3]) for r in mine])
        assert t[0] == 0 and np.all(np.diff(t) >= 0) and np.all(np.diff(e) <= 0)
        assert all(r[5] == "0" for r in mine) and s[8] == s[9] == "0"
        assert s[1] == "converged" and float(s[4]) > 0
        assert float(s[7]) == pytest.approx((float(s[6]) - best) / best, abs=1e-15)
        assert float(s[7]) < 1e-6  # a tiny disk: every fast solver converges
        v, vt, f = read_uv_obj(out / f"{s[0]}.obj")
        assert np.array_equal(v, V3) and np.array_equal(f, F) and vt.shape == (len(V3), 2)
        assert count_inverted(vt, F) == 0

    data = (out / "convergence.png").read_bytes()
    assert png_size(data) == (1000, 400)
    import matplotlib.image

    img = matplotlib.image.imread(out / "convergence.png")[..., :3]
    colours = {tuple(np.round(c * 255).astype(int)) for c in img.reshape(-1, 3)}
    # one curve per solver, in matplotlib's default cycle (blue, orange, green)
    for rgb in [(31, 119, 180), (255, 127, 14), (44, 160, 44)]:
        assert rgb in colours, rgb


def test_api_result_agrees_with_the_files(tmp_path):
    res = geomopt.compare(V3, F, solvers=["newton", "aqp"], out=tmp_path / "o")
    assert isinstance(res, Comparison) and list(res.results) == ["newton", "aqp"]
    area = res.area
    assert area == pytest.approx(Problem.surface(V3, F).volumes.sum())
    _, rows = read_csv(tmp_path / "o" / "history.csv")
    for name, r in res.results.items():
        mine = [row for row in rows if row[0] == name]
        assert len(mine) == r.stats.iterations + 1 == len(r.trace.energy)
        assert [float(x[2]) for x in mine] == list(r.trace.seconds)
        assert [float(x[3]) for x in mine] == list(r.trace.energy / area)
        assert [float(x[4]) for x in mine] == list(r.trace.grad_norm / area)
        assert [int(x[5]) for x in mine] == list(r.trace.flips)
        assert r.stats.seconds >= r.trace.seconds[-1] and r.energy == r.trace.energy[-1]
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    assert res.best_energy == min(r.energy for r in res.results.values())
    for s in summary:
        r = res.results[s[0]]
        assert s[1] == r.outcome.value == "converged"
        assert (int(s[2]), float(s[3]), float(s[4])) == (r.stats.iterations, r.stats.seconds, r.stats.setup_seconds)
        assert float(s[6]) == r.energy / area and float(s[7]) == res.gap(s[0])[-1]
    _, vt, _ = read_uv_obj(tmp_path / "o" / "aqp.obj")
    assert np.array_equal(vt, res.results["aqp"].x)


# ------------------------------------------------------------------ fixed boundary


@pytest.mark.parametrize("mirrored", [False, True], ids=["ccw", "clockwise"])
def test_lim_case_with_handles(cli, tmp_path, mirrored):
    case, V, S, x, b = affine_case(tmp_path / "case", mirrored)
    code, _, err = cli("compare", case, "--out", tmp_path / "o", "--solvers", "aqp,lbfgs", "--quiet")
    assert (code, err) == (0, "")
    A = np.array([[1.3, 0.2], [-0.1, 0.8]])
    target = V @ A.T * ([-1, 1] if mirrored else [1, 1])
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    for s in summary:
        _, vt, f = read_uv_obj(tmp_path / "o" / f"{s[0]}.obj")
        assert np.array_equal(f, S)
        assert np.array_equal(vt[b], x[b])  # handles bit-exact, in the input's frame
        np.testing.assert_allclose(vt, target, atol=1e-4)  # the affine map is the minimum
        assert count_inverted(vt, S, orientation=-1 if mirrored else 1) == 0
        assert s[1] == "converged" and float(s[6]) == pytest.approx(float(summary[0][6]), rel=1e-8)


def test_api_fixed_problem_with_start_map_and_tets(tmp_path):
    V, T = box_mesh(2, 2, 2)  # test_solvers' tet mesh: kernels compiled once per session
    b = boundary_vertices(T, len(V))
    inner = np.setdiff1d(np.arange(len(V)), b)
    A = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.1], [0.1, 0.0, 1.1]])
    x0 = V @ A.T
    x0[inner] += 0.05  # interior off its affine position
    problem = Problem.tets(V, T, b, x0[b])
    with pytest.raises(ParameterError, match="needs a start map x0"):
        geomopt.compare(problem, solvers=["newton"])
    with pytest.raises(ParameterError, match="triangles only"):
        geomopt.compare(problem, x0=x0, solvers=["cm"])
    res = geomopt.compare(problem, x0=x0, solvers={"accel": geomopt.AQP()}, out=tmp_path)
    assert res.results["accel"].success
    P, T2 = io.read_vtk_tets(tmp_path / "accel.vtk")
    assert np.array_equal(T2, T) and np.array_equal(P, res.results["accel"].x)
    np.testing.assert_allclose(P, V @ A.T, atol=1e-4)


def test_flips_of_every_iterate_are_recorded_and_exit_1(cli, tmp_path, monkeypatch):
    """A solver without the injective bound folds the Dirichlet (harmonic) map onto a notched
    boundary: the flips column shows it and the command exits 1, files written."""
    V, S = square_mesh(5)
    x = V.copy()
    x[:, 1] *= np.where(np.isclose(V[:, 0], 0.5), 0.15, 1.0)  # a deep notch from the top
    b = boundary_vertices(S, len(V))
    case = lim_case(tmp_path / "notch", V, S, x, b)
    folding = LBFGS(search=InjectiveSearch(injective=False, c2=0.9))
    real = compare_module.get_solver
    monkeypatch.setattr(compare_module, "get_solver", lambda s: folding if s == "lbfgs" else real(s))
    code, _, err = cli("compare", case, "--out", tmp_path / "o", "--solvers", "lbfgs,aqp",
                       "--energy", "dirichlet", "--quiet")
    assert code == 1
    one_error_line(err, "inverted elements during the solve of lbfgs", "files written")
    _, rows = read_csv(tmp_path / "o" / "history.csv")
    flips = {n: [int(r[5]) for r in rows if r[0] == n] for n in ("lbfgs", "aqp")}
    assert flips["lbfgs"][0] == 0 and max(flips["lbfgs"]) > 0 and max(flips["aqp"]) == 0
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    assert summary[0][1] == "not_injective" and int(summary[0][9]) == max(flips["lbfgs"])
    assert summary[1][1] == "converged" and summary[1][8:] == ["0", "0"]


# ------------------------------------------------------------------ refusals before solving


def test_tangled_case_is_refused_with_exit_2(cli, tmp_path, monkeypatch):
    V, S = square_mesh(4)
    t = rotated_interior(V, S, 90.0)
    case = lim_case(tmp_path / "tangled", V, S, t.x0, t.fixed)
    monkeypatch.setattr(compare_module, "_run", lambda *a, **k: pytest.fail("solved anyway"))
    code, _, err = cli("compare", case, "--out", tmp_path / "o", "--quiet")
    assert code == 2
    one_error_line(err, f"{t.inverted()} inverted", "flip-free start", "geomopt untangle")
    assert not (tmp_path / "o").exists()
    with pytest.raises(MeshError, match="start map x0 has"):
        geomopt.compare(Problem.planar(V, S, t.fixed, t.x0[t.fixed]), x0=t.x0)


def test_bad_arguments_and_outputs_fail_before_solving(cli, tmp_path, monkeypatch):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    monkeypatch.setattr(compare_module, "_run", lambda *a, **k: pytest.fail("solved anyway"))
    cases = {
        ("--solvers", "newton,bfgs"): ["unknown solver 'bfgs'", "valid solvers:"],
        ("--solvers", "newton,newton"): ["'newton' is given twice"],
        ("--solvers", ","): ["no solver given"],
        ("--energy", "sym"): ["unknown energy 'sym'"],
        ("--max-seconds", "-1"): ["max_seconds must be a positive number"],
        ("--max-seconds", "nan"): ["max_seconds must be a positive number"],
    }
    for extra, words in cases.items():
        code, _, err = cli("compare", mesh, "--out", tmp_path / "o", "--quiet", *extra)
        assert code == 2, extra
        one_error_line(err, *words)
    assert not (tmp_path / "o").exists()
    code, _, err = cli("compare", mesh, "--out", mesh, "--quiet")  # a file, not a folder
    assert code == 2
    one_error_line(err, "is not a folder")
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "newton.obj").mkdir()  # an output path that cannot be written
    code, _, err = cli("compare", mesh, "--out", tmp_path / "o", "--solvers", "newton", "--quiet")
    assert code == 2
    one_error_line(err, "newton.obj is a directory")
    with pytest.raises(ParameterError, match="cannot be a file name"):
        geomopt.compare(V3, F, solvers={"../up": "newton"})
    monkeypatch.setattr(compare_module, "_DENSE_LIMIT_BYTES", 1000)
    with pytest.raises(ParameterError, match="dense inverse Hessian"):
        geomopt.compare(V3, F, solvers=["optx-bfgs"])
    assert sorted(os.listdir(tmp_path / "o")) == ["newton.obj"]


# ------------------------------------------------------------------ limits


def test_max_steps_is_honoured(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    code, _, _ = cli("compare", mesh, "--out", tmp_path / "o", "--solvers", FAST, "--max-steps", "2", "--quiet")
    assert code == 0
    _, rows = read_csv(tmp_path / "o" / "history.csv")
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    for s in summary:
        assert s[1] == "max_steps" and s[2] == "2"
        assert [r[1] for r in rows if r[0] == s[0]] == ["0", "1", "2"]


def test_max_seconds_stops_each_solver_and_says_so():
    res = geomopt.compare(V3, F, solvers=["newton", "lbfgs"], max_seconds=1e-9)
    for name, r in res.results.items():
        # the first iteration already takes longer than a nanosecond
        assert r.stats.iterations == 1 and res.outcome(name) == "max_seconds"
        assert r.outcome is geomopt.Outcome.MAX_STEPS and r.reason == TIME_LIMIT
    assert [s[1] for s in res.summary_rows()] == ["max_seconds", "max_seconds"]

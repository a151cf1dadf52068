"""``geomopt compare`` and :func:`geomopt.compare`: the four kinds of output files, the API
agreeing with them bit for bit, fixed-boundary (LIM) cases, refusals before any solve, limits."""

from __future__ import annotations

import csv
import dataclasses
import importlib
import json
import logging
import os
import time

import numpy as np
import pytest

import geomopt
import geomopt.cli
from geomopt import CompareOptions, MeshError, ParameterError, Problem, io
from geomopt.experiments.comparison import HISTORY_COLUMNS, TOLERANCES, Comparison, summary_columns
from geomopt.experiments.report import STYLES, latex_table
from geomopt.experiments.manifest import array_hash
from geomopt.mesh.generators import boundary_vertices, box_mesh, rotated_interior, square_mesh
from geomopt.solvers.linesearch import InjectiveSearch
from geomopt.exact.predicates import count_inverted
from geomopt.solvers import LBFGS

from conftest import grid
from test_cli import one_error_line, read_uv_obj, write_obj

# geomopt.compare is the function (re-exported by geomopt); the module is this:
compare_module = importlib.import_module("geomopt.experiments.comparison")
inputs_module = importlib.import_module("geomopt.experiments.inputs")
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


def test_cli_writes_history_summary_table_manifest_maps_and_a_plot(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    out = tmp_path / "cmp"
    code, stdout, err = cli("compare", mesh, "-o", out, "--solvers", FAST, "--quiet")
    assert (code, stdout, err) == (0, "", "")
    names = FAST.split(",")
    assert sorted(os.listdir(out)) == sorted(["history.csv", "summary.csv", "table.tex", "manifest.json",
                                              "convergence.png"] + [n + ".obj" for n in names])

    head, rows = read_csv(out / "history.csv")
    assert tuple(head) == HISTORY_COLUMNS
    col = {c: k for k, c in enumerate(head)}
    assert [r[0] for r in rows if r[col["iteration"]] == "0"] == names  # every solver starts at iteration 0
    assert len({r[col["energy"]] for r in rows if r[col["iteration"]] == "0"}) == 1  # ... from the same start
    shead, summary = read_csv(out / "summary.csv")
    assert tuple(shead) == summary_columns()
    scol = {c: k for k, c in enumerate(shead)}
    assert [s[0] for s in summary] == names
    manifest = json.loads((out / "manifest.json").read_text())
    (ref,) = [c["reference"] for c in manifest["comparisons"].values()]
    assert ref["source"] == "auto" and ref["outcome"] == "converged" and ref["solver"]["rtol"] == 1e-14
    area = Problem.surface(V3, F).volumes.sum()
    for s in summary:
        mine = [r for r in rows if r[0] == s[0]]
        assert [int(r[col["iteration"]]) for r in mine] == list(range(int(s[scol["iterations"]]) + 1))
        t = np.array([float(r[col["wall_s"]]) for r in mine])
        e = np.array([float(r[col["energy"]]) for r in mine])
        gap = np.array([float(r[col["gap"]]) for r in mine])
        assert t[0] == 0 and np.all(np.diff(t) >= 0) and np.all(np.diff(e) <= 0)
        np.testing.assert_allclose([float(r[col["mean_energy"]]) for r in mine], e / area, rtol=1e-14)
        np.testing.assert_allclose(gap, (e - ref["energy"]) / ref["energy"], rtol=1e-12, atol=1e-15)
        assert all(r[col["flips"]] == "0" for r in mine) and s[scol["max_flips"]] == "0"
        assert s[scol["outcome"]] == "converged" and s[scol["certified"]] == "True"
        assert float(s[scol["gap"]]) < 1e-6  # a tiny disk: every fast solver converges
        for tol in TOLERANCES:  # the table: the first iterate at or below each tolerance
            k = int(np.flatnonzero(gap <= tol)[0])
            key = f"{tol:.0e}"
            assert int(s[scol[f"it_to_{key}"]]) == k and float(s[scol[f"wall_s_to_{key}"]]) == t[k]
        v, vt, f = read_uv_obj(out / f"{s[0]}.obj")
        assert np.array_equal(v, V3) and np.array_equal(f, F) and vt.shape == (len(V3), 2)
        assert count_inverted(vt, F) == 0
    assert "\\begin{tabular}" in (out / "table.tex").read_text()

    assert png_size((out / "convergence.png").read_bytes()) == (1500, 460)
    import matplotlib.image

    img = matplotlib.image.imread(out / "convergence.png")[..., :3]
    colours = {tuple(np.round(c * 255).astype(int)) for c in img.reshape(-1, 3)}
    for name in names:  # every solver in its own fixed colour
        rgb = tuple(int(STYLES[name][0][k:k + 2], 16) for k in (1, 3, 5))
        assert rgb in colours, (name, rgb)


def test_api_result_agrees_with_the_files(tmp_path):
    res = geomopt.compare(V3, F, solvers=["newton", "aqp"], out=tmp_path / "o")
    assert isinstance(res, Comparison) and list(res.results) == ["newton", "aqp"]
    area = res.area
    assert area == pytest.approx(Problem.surface(V3, F).volumes.sum())
    _, rows = read_csv(tmp_path / "o" / "history.csv")
    for name, r in res.results.items():
        mine = [row for row in rows if row[0] == name]
        assert len(mine) == r.iterations + 1 == len(r.energy_history)
        assert [float(x[3]) for x in mine] == list(r.time_history)
        assert [float(x[4]) for x in mine] == list(r.cpu_history)
        assert [float(x[5]) for x in mine] == list(r.energy_history)
        assert [float(x[8]) for x in mine] == list(r.grad_history)
        assert [int(x[9]) for x in mine] == list(r.flips_history)
        assert r.energy == r.energy_history[-1] and r.seconds == r.time_history[-1]
    # the reference: a tight Newton solve, at or below every solver's energy
    assert res.reference.source == "auto" and res.reference.detail["outcome"] == "converged"
    assert all(r.energy >= res.reference.energy for r in res.results.values())
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    for s in summary:
        r = res.results[s[0]]
        assert s[1] == r.outcome.value == "converged"
        assert (int(s[3]), float(s[4]), float(s[6])) == (r.iterations, r.seconds, r.setup_seconds)
        assert float(s[9]) == r.energy and float(s[10]) == r.energy / area and float(s[11]) == res.gap(s[0])[-1]
    _, vt, _ = read_uv_obj(tmp_path / "o" / "aqp.obj")
    assert np.array_equal(vt, res.results["aqp"].x)


def test_reference_best_given_and_auto():
    best = geomopt.compare(V3, F, solvers=["newton", "lbfgs"], options=CompareOptions(reference="best"))
    assert best.reference.source == "best" and min(best.gap(n)[-1] for n in best.results) == 0.0
    auto = geomopt.compare(V3, F, solvers=["newton", "lbfgs"])
    assert auto.reference.energy <= best.reference.energy
    given = geomopt.compare(V3, F, solvers=["lbfgs"],
                            options=CompareOptions(reference=auto.reference_mean_energy * (1 - 1e-3)))
    assert given.reference.source == "given"
    assert given.gap("lbfgs")[-1] == pytest.approx(1e-3 / (1 - 1e-3), rel=1e-6)
    for bad in ("median", float("nan"), [1.0]):
        with pytest.raises(ParameterError, match="reference must be"):
            geomopt.compare(V3, F, solvers=["lbfgs"], options=CompareOptions(reference=bad))


def test_repeats_report_medians_and_keep_the_median_run():
    res = geomopt.compare(V3, F, solvers=["newton"], options=CompareOptions(repeat=3))
    runs = res.runs["newton"]
    assert len(runs) == 3 and len({r.iterations for r in runs}) == 1
    row = res.summary_rows()[0]
    assert row["repeats"] == 3 and row["wall_s"] == np.median([r.seconds for r in runs])
    assert res.results["newton"].seconds == np.median([r.seconds for r in runs])
    assert row["cpu_s"] == np.median([r.cpu_seconds for r in runs])
    assert "medians of 3 runs" in res.report()
    with pytest.raises(ParameterError, match="repeat must be"):
        geomopt.compare(V3, F, solvers=["newton"], options=CompareOptions(repeat=0))


def test_manifest_records_solvers_environment_and_hashes(tmp_path):
    res = geomopt.compare(V3, F, solvers=["newton", "optx-lbfgs"], options=CompareOptions(max_steps=3), out=tmp_path)
    m = json.loads((tmp_path / "manifest.json").read_text())
    assert m["schema_version"] >= 2 and m["versions"]["geomopt"] == geomopt.__version__
    assert m["versions"]["jax"] and m["environment"]["logical_cpus"] >= 1 and m["environment"]["cpu"]
    (c,) = m["comparisons"].values()
    newton = c["solvers"]["newton"]
    assert newton["config"]["type"] == "geomopt.solvers.newton.Newton" and newton["config"]["max_steps"] == 3
    assert newton["config"]["search"]["safety"] == 0.9 and "geomopt's test" in newton["stopping"]
    optx = c["solvers"]["optx-lbfgs"]
    assert optx["config"]["solver"]["type"].startswith("optimistix") and "optimistix LBFGS" in optx["stopping"]
    assert c["problem"]["mesh_sha256"] == array_hash(V3, F) and c["problem"]["elements"] == len(F)
    assert c["energy"]["name"] == "symmetric_dirichlet" and "total" in c["energy"]["convention"]
    assert c["start_sha256"] == array_hash(res.start)


def test_several_meshes_formats_log_x_and_json(cli, tmp_path):
    a = write_obj(tmp_path / "a.obj", V3, F)
    b = write_obj(tmp_path / "b.obj", V3 * 2.0, F)
    out = tmp_path / "o"
    code, stdout, err = cli("compare", a, b, "--out", out, "--solvers", "newton,lbfgs", "--format", "pdf,svg",
                            "--log-x", "--quiet", "--json")
    assert (code, err) == (0, "")
    report = json.loads(stdout)
    assert report["schema_version"] >= 2 and report["exit_status"] == 0 and report["versions"]["geomopt"]
    assert [m["mesh"] for m in report["meshes"]] == ["a", "b"]
    assert [s["solver"] for s in report["meshes"][0]["solvers"]] == ["newton", "lbfgs"]
    assert set(summary_columns()) <= set(report["meshes"][0]["solvers"][0])
    for name in ("summary.csv", "table.tex", "manifest.json", "convergence.pdf", "convergence.svg",
                 "a/history.csv", "b/newton.obj", "b/convergence.svg"):
        assert (out / name).is_file(), name
    assert (out / "convergence.pdf").read_bytes()[:5] == b"%PDF-"
    assert b"<svg" in (out / "convergence.svg").read_bytes()[:1000]
    head, rows = read_csv(out / "summary.csv")
    assert head[0] == "mesh" and [r[0] for r in rows] == ["a", "a", "b", "b"]
    table = (out / "table.tex").read_text()
    assert "a.obj" in table and "b.obj" in table
    res = geomopt.experiments.comparison.compare_meshes({"a": a, "b": b}, solvers=["newton"])
    fig = res.figure(log_x=True)
    assert len(fig.axes) == 6 and fig.axes[1].get_xscale() == "log"
    with pytest.raises(ParameterError, match="same file name"):
        geomopt.experiments.comparison.compare_meshes([a, tmp_path / "x" / "a.obj"], solvers=["newton"])


def test_optimistix_progress_lines_show_no_nan(tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger="geomopt")
    geomopt.compare(V3, F, solvers=["optx-lbfgs"], options=CompareOptions(max_steps=60, reference="best"),
                    progress=True)
    err = "\n".join(r.getMessage() for r in caplog.records)
    lines = [line for line in err.splitlines() if "iter" in line]
    assert lines and not any("nan" in line or " inf" in line for line in lines), lines


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
        assert s[1] == "converged" and float(s[9]) == pytest.approx(float(summary[0][9]), rel=1e-8)


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
    assert res.results["accel"].outcome is geomopt.Outcome.CONVERGED and res.results["accel"].certified
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
    real = inputs_module.get_solver
    monkeypatch.setattr(inputs_module, "get_solver", lambda s: folding if s == "lbfgs" else real(s))
    code, _, err = cli("compare", case, "--out", tmp_path / "o", "--solvers", "lbfgs,aqp",
                       "--energy", "dirichlet", "--quiet")
    assert code == 1
    one_error_line(err, "not every solver converged with a certified map", "lbfgs (", "not certified)",
                   "files written")
    assert "aqp" not in err
    _, rows = read_csv(tmp_path / "o" / "history.csv")
    flips = {n: [int(r[9]) for r in rows if r[0] == n] for n in ("lbfgs", "aqp")}
    assert flips["lbfgs"][0] == 0 and max(flips["lbfgs"]) > 0 and max(flips["aqp"]) == 0
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    assert summary[0][2] == "False" and int(summary[0][12]) == max(flips["lbfgs"])
    assert summary[1][1] == "converged" and summary[1][2] == "True" and summary[1][12] == "0"


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
        ("--max-seconds", "-1"): ["max_seconds must be None or a finite number > 0"],
        ("--max-seconds", "nan"): ["max_seconds must be None or a finite number > 0"],
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
    monkeypatch.setattr(inputs_module, "DENSE_LIMIT_BYTES", 1000)
    with pytest.raises(ParameterError, match="dense inverse Hessian"):
        geomopt.compare(V3, F, solvers=["optx-bfgs"])
    assert sorted(os.listdir(tmp_path / "o")) == ["newton.obj"]


# ------------------------------------------------------------------ limits


def test_max_steps_is_honoured_and_exits_1(cli, tmp_path):
    """Exit status 1: a solver stopped by the limit did not converge (the documented rule)."""
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    code, _, err = cli("compare", mesh, "-o", tmp_path / "o", "--solvers", FAST, "--max-steps", "2", "--quiet")
    assert code == 1
    one_error_line(err, "not every solver converged", "newton (max_steps)", "files written")
    _, rows = read_csv(tmp_path / "o" / "history.csv")
    _, summary = read_csv(tmp_path / "o" / "summary.csv")
    for s in summary:
        assert s[1] == "max_steps" and s[3] == "2"
        assert [r[2] for r in rows if r[0] == s[0]] == ["0", "1", "2"]


def test_max_seconds_stops_each_solver_and_says_so():
    res = geomopt.compare(V3, F, solvers=["newton", "lbfgs"], options=CompareOptions(max_seconds=1e-9))
    for name, r in res.results.items():
        # the first iteration already takes longer than a nanosecond
        assert r.iterations == 1 and r.status == "max_seconds"
        assert r.outcome is geomopt.Outcome.MAX_STEPS and r.stopped == "max_seconds"
    assert [s["outcome"] for s in res.summary_rows()] == ["max_seconds", "max_seconds"]


# ------------------------------------------------------------------ submission-safe (issue 33 item 2)


def no_type3(path):
    """A PDF / PostScript figure whose text is embedded as TrueType (Type 42), not Type 3."""
    data = path.read_bytes()
    if path.suffix == ".pdf":
        assert b"/Subtype /Type3" not in data and (b"/Subtype /TrueType" in data or b"/CIDFontType2" in data)
    else:
        assert b"/FontType 3" not in data and b"/FontType 42" in data
    return True


def test_pdf_and_postscript_figures_embed_truetype_fonts(tmp_path):
    res = geomopt.compare(V3, F, solvers=["newton"], options=CompareOptions(formats=("pdf", "eps", "png")),
                          out=tmp_path / "o")
    assert no_type3(tmp_path / "o" / "convergence.pdf") and no_type3(tmp_path / "o" / "convergence.eps")
    assert res.figure().texts or res.figure().legends  # the figure has text to embed


class _Clock:
    """A process-CPU clock that runs 10 s per reading (wall time is untouched)."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        self.t += 10.0
        return self.t


def test_clock_cpu_drives_the_limit_the_axis_the_table_and_the_median(monkeypatch, tmp_path):
    monkeypatch.setattr(time, "process_time", _Clock())  # the solve loop's clock (geomopt.solvers.iterate)
    wall = geomopt.compare(V3, F, solvers=["newton"], options=CompareOptions(max_seconds=5.0, warmup=False))
    assert wall.clock == "wall" and wall.results["newton"].status == "converged"
    as_cpu, key = dataclasses.replace(wall, clock="cpu"), f"{TOLERANCES[0]:.0e}"
    row = as_cpu.summary_rows()[0]  # the table's seconds are the clock's: here 10 s per reading
    assert row[f"cpu_s_to_{key}"] > 5.0 and f" & {row[f'it_to_{key}']} & {row[f'cpu_s_to_{key}']:.2f} & " in \
        latex_table({"m": as_cpu})
    cpu = geomopt.compare(V3, F, solvers=["newton", "lbfgs"],
                          options=CompareOptions(max_seconds=5.0, clock="cpu", warmup=False, repeat=3), out=tmp_path / "o")
    for name, r in cpu.results.items():  # 20 "CPU seconds" per iteration: stopped at the first
        assert r.iterations == 1 and r.status == "max_seconds", name
        assert r.cpu_seconds > 5.0 > r.seconds
    line = cpu.figure().axes[0].lines[0]
    np.testing.assert_array_equal(line.get_xdata(), cpu.results["newton"].cpu_history[cpu.gap("newton") > 0])
    assert "CPU seconds" not in cpu.figure().axes[0].get_xlabel() and "(CPU" in cpu.figure().axes[0].get_xlabel()
    table = (tmp_path / "o" / "table.tex").read_text()
    assert "it & CPU s" in table and "wall s" not in table
    m = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert next(iter(m["comparisons"].values()))["timing"]["clock"] == "cpu"
    runs = cpu.runs["lbfgs"]  # the median run is the one of median CPU time
    assert cpu.results["lbfgs"].cpu_seconds == np.median([r.cpu_seconds for r in runs])
    with pytest.raises(ParameterError, match="clock must be"):
        geomopt.compare(V3, F, solvers=["newton"], options=CompareOptions(clock="gpu"))


@dataclasses.dataclass(frozen=True)
class LazyLBFGS(LBFGS):
    """L-BFGS whose first step in the process takes 1.5 s more (as lazy compilation does)."""

    def step(self, state):
        if not LAZY:
            time.sleep(1.5)
            LAZY.append(True)
        return super().step(state)


LAZY = []


@pytest.mark.parametrize("warmup", [True, False])
def test_one_untimed_warmup_keeps_lazy_compilation_out_of_the_solve_time(warmup):
    LAZY.clear()
    res = geomopt.compare(V3, F, solvers={"lazy": LazyLBFGS()}, options=CompareOptions(warmup=warmup))
    (run,) = res.runs["lazy"]
    assert LAZY and (run.seconds < 1.5 if warmup else run.seconds >= 1.5)
    assert res.warmup is warmup and ("untimed warm-up" if warmup else "cold") in res.report()


def test_column_figure_has_one_panel_per_mesh_and_the_font_size_asked(tmp_path):
    res = geomopt.experiments.comparison.compare_meshes({"a": write_obj(tmp_path / "a.obj", V3, F),
                                           "b": write_obj(tmp_path / "b.obj", 2 * V3, F)}, solvers=["newton"],
                                          options=CompareOptions(warmup=False))
    fig = res.figure(layout="column", font_size=6.5)
    assert len(fig.axes) == 2 and fig.get_size_inches()[0] == pytest.approx(3.4)
    assert {ax.xaxis.label.get_fontsize() for ax in fig.axes} == {6.5}
    assert fig.legends[0].get_texts()[0].get_fontsize() == 6.5
    wide = res.figure()
    assert len(wide.axes) == 6 and wide.get_size_inches()[0] == pytest.approx(15.0)
    assert wide.axes[0].xaxis.label.get_fontsize() == 10.0
    for bad in (dict(layout="tall"), dict(font_size=0), dict(font_size="big")):
        with pytest.raises(ParameterError, match="layout must be|font_size must be"):
            geomopt.compare(V3, F, solvers=["newton"], options=CompareOptions(**bad))


def test_cli_clock_warmup_layout_font_size_and_truetype_pdf(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    out = tmp_path / "o"
    code, stdout, err = cli("compare", mesh, "-o", out, "--solvers", "newton", "--clock", "cpu", "--no-warmup",
                            "--layout", "column", "--font-size", "7", "--format", "pdf,png", "--quiet")
    assert (code, stdout, err) == (0, "", "")
    m = json.loads((out / "manifest.json").read_text())
    timing = next(iter(m["comparisons"].values()))["timing"]
    assert (timing["clock"], timing["warmup"]) == ("cpu", False)
    assert m["figure"] == {"formats": ["pdf", "png"], "log_x": False, "layout": "column", "font_size": 7.0}
    assert png_size((out / "convergence.png").read_bytes())[0] == 340  # 3.4 in at 100 dpi
    assert no_type3(out / "convergence.pdf") and "it & CPU s" in (out / "table.tex").read_text()
    with pytest.raises(SystemExit) as exit_:
        cli("compare", mesh, "-o", tmp_path / "p", "--solvers", "newton", "--clock", "gpu")
    assert exit_.value.code == 2 and not (tmp_path / "p").exists()


def test_the_short_warm_up_leaves_nothing_to_compile_in_the_timed_runs(monkeypatch, caplog):
    """The warm-up (a few iterations, not a whole solve) compiles what every solver compiles
    lazily, its convergence steps included (Newton's polish once compiled an add per shape
    there): no timed run compiles anything, and the warm-up is no whole solve."""
    import jax

    from geomopt.experiments import comparison

    V, Fq = grid(9, jitter=0.3, seed=3)
    V3q = np.c_[V, 0.2 * np.sin(2.0 * V[:, 0]) * V[:, 1]]
    phase = {"now": "set-up"}
    warm_iterations = []
    run, warm_up, iterate = comparison._run, comparison._warm_up, comparison.iterate

    def timed(*args, **kw):
        phase["now"] = "timed"
        return run(*args, **kw)

    def warm(*args):
        phase["now"] = "warm-up"
        return warm_up(*args)

    def counted(*args, **kw):
        res = iterate(*args, **kw)
        if phase["now"] == "warm-up":
            warm_iterations.append(res.stats.iterations)
        return res

    monkeypatch.setattr(comparison, "_run", timed)
    monkeypatch.setattr(comparison, "_warm_up", warm)
    monkeypatch.setattr(comparison, "iterate", counted)
    compiled = []

    class Seen(logging.Handler):
        def emit(self, record):
            if record.getMessage().startswith("Compiling"):
                compiled.append((phase["now"], record.getMessage()[:100]))

    handler = Seen(level=logging.DEBUG)
    logging.getLogger("jax").addHandler(handler)
    try:
        with jax.log_compiles():
            c = geomopt.compare(V3q, Fq, solvers=["newton", "lbfgs", "aqp", "cm"], progress=False,
                                options=geomopt.CompareOptions(reference="best"))
    finally:
        logging.getLogger("jax").removeHandler(handler)
    assert all(r.outcome.value == "converged" for r in c.results.values())
    assert [w for w in compiled if w[0] == "timed"] == []
    assert max(warm_iterations) == geomopt.experiments.options.WARMUP_STEPS

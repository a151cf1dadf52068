"""``--json`` objects: a schema version and the versions that produced them in every one, one
energy convention (``energy`` total, ``mean_energy`` per rest area), and the fields scripts
need from each command."""

from __future__ import annotations

import json

import numpy as np
import pytest

import geomopt
from geomopt import Problem
from geomopt.experiments.manifest import SCHEMA_VERSION
from geomopt.mesh.generators import rotated_interior, square_mesh

from test_cli import write_obj
from test_compare import V3, F, lim_case


def check_header(report, command):
    assert report["command"] == command and report["schema_version"] == SCHEMA_VERSION
    assert report["versions"]["geomopt"] == geomopt.__version__
    assert report["versions"]["jax"] and report["versions"]["python"]


def test_param_json_energy_convention(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    code, out, _ = cli("param", mesh, "-o", tmp_path / "uv.obj", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0
    check_header(report, "param")
    area = Problem.surface(V3, F).volumes.sum()
    assert report["mean_energy"] == pytest.approx(report["energy"] / area, rel=1e-14)
    assert report["mean_energy"] > 4.0 - 1e-9  # symmetric Dirichlet's mean is at least 4


def test_failures_carry_the_header_too(cli, tmp_path):
    code, out, _ = cli("param", tmp_path / "missing.obj", "-o", tmp_path / "uv.obj", "--json", "--quiet")
    report = json.loads(out)
    assert code == 2 and report["success"] is False and report["error"]
    check_header(report, "param")


def test_untangle_json_single_case_and_batch(cli, tmp_path):
    V, S = square_mesh(5)
    t = rotated_interior(V, S, 120.0)
    case = lim_case(tmp_path / "case", V, S, t.x0, t.fixed)
    code, out, _ = cli("untangle", case, "-o", tmp_path / "out.obj", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0
    check_header(report, "untangle")
    assert report["vertices"] == len(V) and report["elements"] == len(S) and report["dim"] == 2
    assert report["inverted_before"] == t.inverted() > 0 and report["inverted"] == 0
    assert report["inner_iterations"] >= report["outer_iterations"] >= 1
    assert report["certified"] is True and report["outcome"] == "converged" and report["handles_moved"] == 0

    code, out, _ = cli("untangle", case, "-o", tmp_path / "batch", "--workers", "1", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0
    check_header(report, "untangle")
    assert (report["cases"], report["certified"], report["not_certified"]) == (1, 1, 0)
    (row,) = report["rows"]
    assert row["certified"] == "yes" and int(row["inverted_before"]) == t.inverted()
    assert np.isfinite(float(row["seconds"]))

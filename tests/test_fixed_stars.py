"""Handles that make every map fail the local certificate (certify.fixed_star_certificate).

A vertex (2D) or edge/vertex (3D) whose whole star has every vertex fixed is certified the
same way by every map with those handles; when that star already overlaps itself, that is a
property of the input: untangling solves the rest, certifies it wherever a free vertex reaches,
and reports the forced overlap (outcome ``certified_except_fixed``, CLI exit status 3, the map
written), never as plain success (LIM's armadillo-598 has 5 such boundary edges, issue 30).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_path
import dataclasses
import json

from geomopt import Problem, SolveError
from geomopt import cli
from geomopt.solvers import Outcome
from geomopt.exact.certify import fixed_star_certificate, local_certificate
from geomopt.io import read_vtk_tets
from geomopt.exact.predicates import count_inverted
from geomopt.mesh.generators import Tangle
from geomopt.lim import LimCase
from geomopt.untangling import untangle
from test_local_injectivity import edge_star, fan_2d, orient_tets


def with_free_vertex_2d(X, F, rest):
    """Add a free vertex beyond the outer edge (1, 2) of a fan: triangle (2, 1, w)."""
    def far(P):
        return 2.0 * (P[1] + P[2])
    F = np.vstack([F, [2, 1, len(X)]])
    return np.vstack([X, far(X)]), F, np.vstack([rest, far(rest)])


def with_free_vertex_3d(X, T, rest):
    """Add a free vertex beyond the outer face (0, 2, 3) of an edge star."""
    def far(P):
        return 1.5 * (P[0] + P[2] + P[3])
    X2, R2 = np.vstack([X, far(X)]), np.vstack([rest, far(rest)])
    T = np.vstack([T, [[0, 2, 3, len(X)]]])
    return X2, orient_tets(R2, T), R2


def fan_case(turns, rest_turns, k, closed):
    """A 2D fan around vertex 0 through ``k`` triangles turning ``turns`` times in the map and
    ``rest_turns`` at rest (closed: an interior vertex), every fan vertex fixed, plus one free
    vertex elsewhere."""
    def ring(t):
        a = np.linspace(0, 2 * np.pi * t, k + 1)
        X, F = fan_2d(a[:-1] if closed else a)
        if closed:
            F = np.vstack([F, [0, k, 1]])
        return X, F
    X, F = ring(turns)
    rest, _ = ring(rest_turns)
    fixed = np.arange(len(X))
    X, F, rest = with_free_vertex_2d(X, F, rest)
    return X, F, rest, fixed


def edge_case(turns, rest_turns, k, closed):
    """Tets around edge (0, 1) turning ``turns`` times (``rest_turns`` at rest), all fixed,
    plus one free vertex beyond an outer face."""
    X, T = edge_star(turns, k, closed)
    rest, _ = edge_star(rest_turns, k, closed)
    fixed = np.arange(len(X))
    X, T, rest = with_free_vertex_3d(X, T, rest)
    return X, T, rest, fixed


def _except_fixed(problem, X, field, where):
    """Solved, the free vertex moved, the forced overlap reported (not success, not refused)."""
    res = untangle(problem, X, progress=False)
    assert res.outcome is Outcome.CERTIFIED_EXCEPT_FIXED and not res.success, res.message
    cert = res.certificate
    assert cert.inverted == 0 and cert.handles_moved == 0 and not cert.ok and cert.valid_except_forced
    assert getattr(cert.forced, field).tolist() == where and cert.beyond(cert.forced).ok
    assert "handles alone" in res.message and "property of the input" in res.message
    with pytest.raises(SolveError, match="handles alone"):
        untangle(problem, X, progress=False, throw=True)
    return res


@pytest.mark.parametrize("closed, field", [(True, "branch_vertices"), (False, "boundary_overlaps")])
def test_fixed_2d_fan_that_overlaps_is_solved_and_reported(closed, field):
    X, F, rest, fixed = fan_case(2.0 if closed else 1.5, 1.0 if closed else 0.75, 12, closed)
    cert = fixed_star_certificate(X, F, fixed)
    assert not cert.ok and list(getattr(cert, field)) == [0]
    X = X.copy()
    X[-1] = -X[-1]  # the free vertex's triangle starts inverted: the solver must untangle it
    problem = Problem.planar(rest, F, fixed, X[fixed])
    assert problem.count_inverted(X) == 1
    _except_fixed(problem, X, field, [0])


@pytest.mark.parametrize("closed, field", [(True, "branch_edges"), (False, "boundary_edge_overlaps")])
def test_fixed_3d_edge_star_that_overlaps_is_solved_and_reported(closed, field):
    X, T, rest, fixed = edge_case(2.0 if closed else 1.5, 1.0 if closed else 0.75, 10, closed)
    cert = fixed_star_certificate(X, T, fixed)
    assert not cert.ok and getattr(cert, field).tolist() == [[0, 1]]
    for e in (-1000, 1000):  # extreme scales, exactly (powers of two)
        assert getattr(fixed_star_certificate(np.ldexp(X, e), T, fixed), field).tolist() == [[0, 1]]
    _except_fixed(Problem.tets(rest, T, fixed, X[fixed]), X, field, [[0, 1]])


def test_beyond_excuses_the_forced_stars_and_the_ends_of_forced_edges_only():
    X, T, rest, fixed = edge_case(1.5, 0.75, 10, False)
    forced = fixed_star_certificate(X, T, fixed)
    full = local_certificate(X, T)
    assert forced.boundary_edge_overlaps.tolist() == [[0, 1]] and 0 in full.boundary_overlaps
    assert not forced.failures == full.failures  # vertex 0's star holds the free vertex: not in forced...
    assert full.beyond(forced).ok  # ...but it is an end of the forced edge: it cannot be injective
    other = dataclasses.replace(full, boundary_overlaps=np.r_[full.boundary_overlaps, 7],
                                branch_edges=np.array([[2, 3]]))
    left = other.beyond(forced)
    assert left.boundary_overlaps.tolist() == [7] and left.branch_edges.tolist() == [[2, 3]] and not left.ok
    assert forced.beyond(forced).ok


def test_cli_writes_the_map_and_exits_3(tmp_path, capsys):
    X, T, rest, fixed = edge_case(1.5, 0.75, 10, False)
    folder = LimCase.from_tangle(Tangle("wrapped", rest, T, X, fixed)).write(tmp_path / "case")
    out = tmp_path / "out.vtk"
    assert cli.main(["untangle", str(folder), "-o", str(out), "--quiet", "--json"]) == cli.EXIT_EXCEPT_FIXED == 3
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "written but not certified everywhere" in err[0] and "(0, 1)" in err[0], err
    summary = json.loads(captured.out)
    assert (summary["outcome"], summary["success"], summary["certified"], summary["exit_status"]) == (
        "certified_except_fixed", False, False, 3)
    assert summary["forced_overlaps"] >= 1 and summary["inverted"] == 0 and summary["handles_moved"] == 0
    back = LimCase.read(folder).write_certified(read_vtk_tets(out)[0], tmp_path / "again.vtk")
    assert back["outcome"] == "certified_except_fixed" and not back["certified"] and back["forced"] >= 1


def test_write_certified_still_refuses_a_failure_a_free_vertex_reaches(tmp_path):
    """The forced overlap is excused in the written file, nothing else: the free vertex's tet
    inverted (or its boundary overlapping) is refused, and no file is left."""
    X, T, rest, fixed = edge_case(1.5, 0.75, 10, False)
    case = LimCase.from_tangle(Tangle("wrapped", rest, T, X, fixed))
    res = untangle(*case.to_problem()[:2], progress=False)
    assert res.outcome is Outcome.CERTIFIED_EXCEPT_FIXED
    assert case.write_certified(res, tmp_path / "ok.vtk")["outcome"] == "certified_except_fixed"
    bad = res.x.copy()
    free = np.setdiff1d(np.arange(len(X)), fixed)
    bad[free] = 2.0 * bad[0] - bad[free]  # the free vertex reflected through vertex 0
    with pytest.raises(SolveError, match="did not certify"):
        case.write_certified(bad, tmp_path / "bad.vtk")
    assert not (tmp_path / "bad.vtk").exists()


@pytest.mark.parametrize("dim", [2, 3])
def test_overlap_is_only_certain_with_the_whole_star_fixed(dim):
    """One free vertex in the star: a solver might (in principle) move it, so nothing is said."""
    X, S, rest, fixed = (fan_case(1.5, 0.75, 12, False) if dim == 2 else edge_case(1.5, 0.75, 10, False))
    assert not fixed_star_certificate(X, S, fixed).ok
    assert fixed_star_certificate(X, S, np.delete(fixed, 3)).ok  # a ring vertex set free
    assert fixed_star_certificate(X, S, fixed[1:]).ok  # the centre (2D) / an end of the edge (3D)


@pytest.mark.parametrize("dim", [2, 3])
def test_fixed_stars_that_are_injective_pass(dim):
    """Must pass: a boundary fan turning just under a turn (0.95), a concave interior star,
    and untangle solves the free part as usual."""
    if dim == 2:
        X, S, rest, fixed = fan_case(0.95, 0.5, 12, False)
        C, SC, _, fc = fan_case(1.0, 1.0, 12, True)
        C[1:13:2] *= 0.3  # concave: every other ring vertex pulled in
    else:
        X, S, rest, fixed = edge_case(0.95, 0.5, 10, False)
        C, SC, _, fc = edge_case(1.0, 1.0, 10, True)
        C[2:12:2, :2] *= 0.3
    assert fixed_star_certificate(X, S, fixed).ok
    assert fixed_star_certificate(C, SC, fc).ok
    problem = (Problem.planar if dim == 2 else Problem.tets)(rest, S, fixed, X[fixed])
    res = untangle(problem, X, progress=False)
    assert res.success, res.message


def test_inverted_fixed_elements_are_left_to_the_orientation_check():
    """A fully fixed star with an inverted element is not judged here (count_inverted's job)."""
    X, F, rest, fixed = fan_case(1.5, 0.75, 12, False)
    X[[3, 4]] = X[[4, 3]]  # two triangles of the fan flip
    cert = fixed_star_certificate(X, F, fixed)
    assert cert.ok and cert.inverted == 0
    # an inverted fixed triangle elsewhere does not hide an overlapping star
    X, F, rest, fixed = fan_case(1.5, 0.75, 12, False)
    n = len(X)
    X = np.vstack([X, [[5.0, 5.0], [5.0, 6.0], [6.0, 5.0]]])  # clockwise
    F = np.vstack([F, [[n, n + 1, n + 2]]])
    cert = fixed_star_certificate(X, F, np.r_[fixed, n, n + 1, n + 2])
    assert list(cert.boundary_overlaps) == [0]


def test_armadillo_598_is_solved_and_its_forced_overlap_reported(capsys, tmp_path):
    """LIM's armadillo-598: the benchmark's criterion (handles exact, no inverted tet) met in the
    file written, and the 5 boundary edges its handles make overlap reported (exit 3)."""
    folder = shared_path("lim", "3D", "Deform_Armadillo", "armadillo-598")
    case = LimCase.read(folder)
    problem, x0 = case.to_problem()[:2]  # its tets are listed clockwise
    cert = fixed_star_certificate(x0, problem.simplices, problem.fixed)
    assert len(cert.boundary_edge_overlaps) == 5 and cert.boundary_edge_overlaps[0].tolist() == [752, 782]
    out = tmp_path / "out.vtk"
    assert cli.main(["untangle", str(folder), "-o", str(out), "--quiet"]) == 3
    assert "(752, 782)" in capsys.readouterr().err
    X, T = read_vtk_tets(out)
    assert np.array_equal(T, case.simplices) and np.array_equal(X[case.handles], case.init[case.handles])
    vol = np.einsum("ij,ij->i", X[T[:, 1]] - X[T[:, 0]], np.cross(X[T[:, 2]] - X[T[:, 0]], X[T[:, 3]] - X[T[:, 0]]))
    assert (vol < 0).all()  # every tet keeps the (negative) rest orientation: none inverted
    assert count_inverted(X, problem.simplices) == 0  # and exactly so

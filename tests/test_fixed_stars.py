"""Handles that make every map fail the local certificate (certify.fixed_star_certificate).

A vertex (2D) or edge/vertex (3D) whose whole star has every vertex fixed is certified the
same way by every map with those handles; when that star already overlaps itself, untangling
is pointless and is refused before solving (LIM's armadillo-598 had 5 such boundary edges).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_path
from geomopt import MeshError, Problem
from geomopt import cli
from geomopt.certify import fixed_star_certificate
from geomopt.generators import Tangle
from geomopt.lim import LimCase
from geomopt.untangle import untangle
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


@pytest.mark.parametrize("closed, field", [(True, "branch_vertices"), (False, "boundary_overlaps")])
def test_fixed_2d_fan_that_overlaps_is_refused_before_solving(closed, field):
    X, F, rest, fixed = fan_case(2.0 if closed else 1.5, 1.0 if closed else 0.75, 12, closed)
    cert = fixed_star_certificate(X, F, fixed)
    assert not cert.ok and list(getattr(cert, field)) == [0]
    problem = Problem.planar(rest, F, fixed, X[fixed])
    with pytest.raises(MeshError, match=r"vertex 0 .*handles make a locally injective map impossible"):
        untangle(problem, X, progress=lambda *a: pytest.fail("solved"))


@pytest.mark.parametrize("closed, field", [(True, "branch_edges"), (False, "boundary_edge_overlaps")])
def test_fixed_3d_edge_star_that_overlaps_is_refused(closed, field):
    X, T, rest, fixed = edge_case(2.0 if closed else 1.5, 1.0 if closed else 0.75, 10, closed)
    cert = fixed_star_certificate(X, T, fixed)
    assert not cert.ok and getattr(cert, field).tolist() == [[0, 1]]
    for e in (-1000, 1000):  # extreme scales, exactly (powers of two)
        assert getattr(fixed_star_certificate(np.ldexp(X, e), T, fixed), field).tolist() == [[0, 1]]
    with pytest.raises(MeshError, match=r"edge \(0, 1\).*impossible"):
        untangle(Problem.tets(rest, T, fixed, X[fixed]), X, progress=False)


def test_cli_exits_2_and_writes_nothing(tmp_path, capsys):
    X, T, rest, fixed = edge_case(1.5, 0.75, 10, False)
    folder = LimCase.from_tangle(Tangle("wrapped", rest, T, X, fixed)).write(tmp_path / "case")
    out = tmp_path / "out.vtk"
    assert cli.main(["untangle", str(folder), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "impossible" in err[0] and "(0, 1)" in err[0], err
    assert not out.exists()


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


def test_armadillo_598_is_refused_naming_the_edge(capsys, tmp_path):
    """The API refusal is in test_untangle's LIM case test; here the certificate and the CLI."""
    folder = shared_path("lim", "3D", "Deform_Armadillo", "armadillo-598")
    problem, x0 = LimCase.read(folder).to_problem()[:2]  # its tets are listed clockwise
    cert = fixed_star_certificate(x0, problem.simplices, problem.fixed)
    assert len(cert.boundary_edge_overlaps) == 5 and cert.boundary_edge_overlaps[0].tolist() == [752, 782]
    out = tmp_path / "out.vtk"
    assert cli.main(["untangle", str(folder), "-o", str(out), "--quiet"]) == 2
    assert not out.exists() and "impossible" in capsys.readouterr().err

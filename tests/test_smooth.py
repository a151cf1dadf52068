"""`geomopt smooth` on valid inputs it used to refuse, and invalid ones it used to accept (issue 30
item 3): handles at -0.0 (mirrored, trigonometric and gmsh-made meshes) certify, an input that is
not locally injective is refused up front with the reason, and meshes at 1e200 or 1e-150 smooth
as at size 1 (as untangling does)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import geomopt
from geomopt import MeshError, io
from geomopt.mesh import generators as G
from geomopt.mesh.elements import certify_elements, quality
from geomopt.mesh.problem import Problem
from geomopt import smooth

from test_cli import one_error_line

FLIP = {4: [0, 3, 2, 1], 8: [0, 3, 2, 1, 4, 7, 6, 5]}  # a quad / hexahedron with the opposite orientation


def negative_zeros(P) -> int:
    return int(np.count_nonzero(np.signbit(P) & (P == 0)))


def _mirrored(V, E, axis=0):
    """``V`` mirrored in the plane of coordinate ``axis`` = 0 (its zeros become -0.0), ``E``
    reoriented."""
    W = V.copy()
    W[:, axis] = -W[:, axis]
    return W, E[:, FLIP[E.shape[1]]]


def _mirrored_meshes():
    quad = _mirrored(*G.sector_mesh(3, 6, angle_deg=90.0, perturb=0.3, seed=2), axis=1)  # r sin(0) -> -0.0
    hexes = _mirrored(G.perturb_mesh(*G.hex_mesh(3, 3, 2), 0.3, seed=2), G.hex_mesh(3, 3, 2)[1])
    return {"quad": quad, "hexahedron": hexes}


def _smooths_and_certifies(cli, tmp_path, src, kind):
    """Run `geomopt smooth` on ``src``; the file must certify with the handles in place."""
    V, E, _ = io.read_cells(src)
    assert negative_zeros(V) > 0  # the point of the test
    out = tmp_path / f"out-{kind}.vtk"
    code, _, err = cli("smooth", src, "-o", out, "--quiet")
    assert code == 0, err
    P, E2, _ = io.read_cells(out)
    d = 2 if kind == "quad" else 3
    V, P = V[:, :d], P[:, :d]
    problem = (Problem.quads if kind == "quad" else Problem.hexes)(V, E, rest="reference")
    b = problem.boundary_vertices()
    assert np.array_equal(E2, E) and certify_elements(P, problem.elements).certified
    assert np.array_equal(P[b], V[b])  # equal as numbers: -0.0 == 0.0
    assert quality(P, E).min >= quality(V, E).min and not np.array_equal(P, V)  # smoothed, nothing worse


@pytest.mark.parametrize("kind", ["quad", "hexahedron"])
def test_smooth_certifies_meshes_with_negative_zero_handles(cli, tmp_path, kind):
    """A handle at -0.0 that the solve returns as +0.0 was counted as moved (bits compared):
    exit 1, 'the written file did not certify (N handle(s) moved)'."""
    V, E = _mirrored_meshes()[kind]
    src = io.write_cells(tmp_path / f"{kind}.vtk", V, E, kind)
    _smooths_and_certifies(cli, tmp_path, src, kind)
    r = smooth(V, E)
    b = r.problem.boundary_vertices()
    assert r.details.improved and np.array_equal(r.x[b], V[b]) and r.certificate.handles_moved == 0


def _gmsh_mesh(path, dim):
    """A gmsh-made quad (``dim`` 2) or extruded hex mesh (3) of a square with a round hole,
    its sides on x = 0 and z = 0."""
    gmsh = pytest.importorskip("gmsh", reason="gmsh is not installed: the gmsh-made meshes are not tested "
                                             "(pip install gmsh)")
    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        occ = gmsh.model.occ
        face = occ.cut([(2, occ.addRectangle(0, 0, 0, 1, 1))], [(2, occ.addDisk(1, 1, 0, 0.5, 0.5))])[0]
        if dim == 3:
            occ.extrude(face, 0, 0, 0.5, numElements=[2], recombine=True)
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.2)
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.option.setNumber("Mesh.Algorithm", 8)  # frontal-Delaunay for quads
        gmsh.model.mesh.generate(dim)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return io.read_cells(path)


@pytest.mark.parametrize("dim", [2, 3])
def test_smooth_certifies_mirrored_gmsh_meshes(cli, tmp_path, dim):
    kind = "quad" if dim == 2 else "hexahedron"
    P, E, kind2 = _gmsh_mesh(tmp_path / "gmsh.msh", dim)
    assert kind2 == kind
    V, E = _mirrored(P[:, :dim], E)
    if dim == 3:
        V[:, 2] = -V[:, 2]  # mirrored twice: the orientation back, -0.0 on x = 0 and z = 0
        E = E[:, FLIP[8]]
    src = io.write_cells(tmp_path / "mirrored.msh", V, E, kind)
    _smooths_and_certifies(cli, tmp_path, src, kind)


def _fan(quads: int, closed: bool):
    """Valid quads around vertex 0, each turning 90 degrees about it: 8 ``closed`` ones wind
    twice around an interior vertex; 6 open ones turn 1.5 times around a boundary vertex."""
    ring = quads if closed else quads + 1
    t = np.deg2rad(90.0 * np.arange(ring))
    r = 1.0 + 0.05 * np.arange(ring)  # no two vertices at one place
    a = np.column_stack([r * np.cos(t), r * np.sin(t)])
    o = 2 * np.column_stack([r * np.cos(t + np.pi / 4), r * np.sin(t + np.pi / 4)])[:quads]
    k = np.arange(quads)
    Q = np.column_stack([np.zeros(quads, np.int64), 1 + k, 1 + ring + k, 1 + (k + 1) % ring])
    return np.vstack([[0.0, 0.0], a, o]), Q


def _extruded(V, Q):
    """The quads extruded to one layer of hexahedra (the doubly wound vertex becomes an edge)."""
    n = len(V)
    W = np.vstack([np.column_stack([V, np.zeros(n)]), np.column_stack([V, np.ones(n)])])
    return W, np.column_stack([Q, Q + n])


@pytest.mark.parametrize("name,words", [
    ("interior vertex wound twice", ["not locally injective", "interior vertex 0 is a branch point"]),
    ("boundary fan turning 1.5 times", ["not locally injective", "around boundary vertex 0 overlap"]),
    ("interior edge wound twice", ["not locally injective", "edge"]),
])
def test_smooth_refuses_an_input_that_is_not_locally_injective(cli, tmp_path, name, words):
    """Every element valid, yet not locally injective: accepted before, then 'not improved'
    after a full solve (exit 1); now exit 2 up front, with the reason."""
    V, E = _fan(8, True) if "interior" in name else _fan(6, False)
    kind = "quad"
    if "edge" in name:
        (V, E), kind = _extruded(V, E), "hexahedron"
    assert certify_elements(V, E).certified
    src = io.write_cells(tmp_path / "in.vtk", V, E, kind)
    code, _, err = cli("smooth", src, "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 2
    one_error_line(err, *words, "untangle it first")
    assert not (tmp_path / "out.vtk").exists()
    with pytest.raises(MeshError, match="not locally injective"):
        smooth(V, E)


@pytest.mark.parametrize("scale", [1e200, 1e-150])
@pytest.mark.parametrize("kind", ["quad", "hexahedron"])
def test_smooth_at_extreme_scales_as_at_size_one(cli, tmp_path, scale, kind):
    """At 1e200 the reference squares' sizes overflowed ('the mesh is degenerate'), hexahedra at
    1e-150 underflowed; like untangling, smoothing works on a copy scaled by a power of two."""
    V, E = G.sector_mesh(2, 4, 0 if kind == "quad" else 2, perturb=0.3, seed=3)
    one = smooth(V, E)
    big = smooth(V * scale, E)
    assert big.details.improved and big.details.scale != 1.0
    assert abs(big.details.after.min - one.details.after.min) < 1e-9
    b = big.problem.boundary_vertices()
    assert np.array_equal(big.x[b], (V * scale)[b])
    src = io.write_cells(tmp_path / "in.vtk", V * scale, E, kind)
    code, _, err = cli("smooth", src, "-o", tmp_path / "out.vtk", "--quiet")
    assert code == 0, err
    P, _, _ = io.read_cells(tmp_path / "out.vtk")
    assert np.allclose(P[:, : V.shape[1]] / scale, one.x, rtol=0, atol=1e-6)  # to the solver tolerance


def test_the_command_line_says_a_solve_stopped_at_its_step_limit_in_one_line(cli, tmp_path):
    """Issue 30 item 8: the MaxStepsWarning of a round stopped at --max-steps is one stderr line
    (even with --quiet); a converged run prints nothing."""
    V, E = G.sector_mesh(3, 5, perturb=0.3, seed=3)
    src = io.write_cells(tmp_path / "in.vtk", V, E, "quad")
    code, _, err = cli("smooth", src, "-o", tmp_path / "out.vtk", "--quiet", "--max-steps", "1")
    lines = err.strip().splitlines()
    assert code == 0 and lines and all(line.startswith("geomopt: warning: ") for line in lines), err
    assert "Newton stopped at its iteration limit (max_steps=1)" in lines[0] and "--max-steps" in lines[0]
    code, out, err = cli("smooth", src, "-o", tmp_path / "out1.vtk", "--quiet", "--max-steps", "1", "--json")
    assert json.loads(out)["outcome"] == "max_steps"  # a script reading --json sees it too
    code, out, err = cli("smooth", src, "-o", tmp_path / "out2.vtk", "--quiet", "--json")
    assert code == 0 and err == "" and json.loads(out)["outcome"] == "converged"


def test_smooth_throws_on_request_like_every_driver():
    """``throw=True`` raises SolveError (carrying the result) unless the result succeeds;
    without it the same result is returned (issue 49)."""
    from geomopt import SolveError
    from geomopt.smoothing import SmoothOptions

    V, Q = G.sector_mesh(2, 4, perturb=0.4, seed=1)
    assert smooth(V, Q, throw=True).success
    cut = SmoothOptions(max_steps=1)  # one Newton iteration: stopped at its limit, not converged
    with pytest.warns(geomopt.MaxStepsWarning):
        short = smooth(V, Q, options=cut)
    assert not short.success and short.outcome.value == "max_steps"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the error says it: no warning before it
        with pytest.raises(SolveError, match="smooth failed: stopped at the iteration limit") as info:
            smooth(V, Q, options=cut, throw=True)
    assert info.value.result.outcome.value == "max_steps" and info.value.result.certificate.ok


def _jittered(V, seed=0):
    """``V`` with every vertex moved a little (nothing is held here)."""
    rng = np.random.default_rng(seed)
    return V + 0.08 * rng.uniform(-1, 1, V.shape) * (np.ptp(V, axis=0) > 0)


@pytest.mark.parametrize("kind, energy", [("quad", "winslow"), ("quad", "mips"), ("hexahedron", "mips")])
def test_smoothing_with_nothing_fixed_keeps_the_mesh_where_and_as_large_as_it_was(kind, energy):
    """With no vertex fixed, a scale-invariant energy's minimisers are a similarity class: the
    solver drifted along it until the mesh had shrunk up to a million times, and reported success.
    The result is moved back to the input's centroid and size (its shapes unchanged)."""
    V, E = G.quad_mesh(2, 2, size=(2.0, 2.0)) if kind == "quad" else G.hex_mesh(2, 2, 2, size=(2.0, 2.0, 2.0))
    V = _jittered(V)
    res = smooth(V, E, energy=energy, fixed=[])
    assert res.success and res.details.improved
    assert np.allclose(res.x.mean(axis=0), V.mean(axis=0), atol=1e-9)
    size = lambda X: np.sqrt(np.mean((X - X.mean(axis=0)) ** 2))  # noqa: E731
    assert abs(size(res.x) / size(V) - 1) < 1e-9
    assert res.details.after.min > res.details.before.min


def test_smoothing_refuses_an_energy_that_shrinks_the_mesh_when_nothing_is_fixed(cli, tmp_path):
    """Winslow's 3D density falls with the size (|J^-1|^2 det J ~ s): with nothing fixed the
    mesh collapses to a point, so it is refused, saying what to do; in 2D it is scale-invariant."""
    from geomopt import ParameterError

    V, E = G.hex_mesh(2, 2, 2, size=(2.0, 2.0, 2.0))
    V = _jittered(V)
    with pytest.raises(ParameterError, match="no vertex fixed would collapse.*--fix boundary"):
        smooth(V, E, energy="winslow", fixed=[])
    src = io.write_cells(tmp_path / "in.vtk", V, E, "hexahedron")
    code, _, err = cli("smooth", src, "-o", tmp_path / "out.vtk", "--fix", "none", "--quiet")
    assert code == 2 and "collapse" in one_error_line(err) and not (tmp_path / "out.vtk").exists()

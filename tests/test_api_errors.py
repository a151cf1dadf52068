"""Public functions given malformed arguments raise one-line geomopt errors (MeshError /
ParameterError), never an IndexError, KeyError or TypeError from deep inside NumPy."""

from __future__ import annotations

import numpy as np
import pytest

from geomopt import MeshError, ParameterError, io, smooth
from geomopt.mesh import generators as G
from geomopt.exact.predicates import branch_vertices, vertex_windings


@pytest.mark.parametrize("kind", ["hex", "hexahedra", 12, ("hexahedron", "hex")])
def test_cell_kinds_outside_the_table_are_named(tmp_path, kind):
    P, H = G.hex_mesh(1, 1, 1)
    with pytest.raises(ParameterError, match="valid: 'tetra', 'hexahedron', 'quad'"):
        io.write_cells(tmp_path / "x.vtk", P, H, kind)
    assert not list(tmp_path.iterdir())
    io.write_cells(tmp_path / "x.vtk", P, H, "hexahedron")
    with pytest.raises(ParameterError, match="unknown cell kinds"):
        io.read_cells(tmp_path / "x.vtk", kind if isinstance(kind, tuple) else (kind,))
    assert io.read_cells(tmp_path / "x.vtk", "hexahedron")[2] == "hexahedron"  # one name, not its letters


@pytest.mark.parametrize("fn", [branch_vertices, vertex_windings])
@pytest.mark.parametrize("X, F", [
    (np.zeros((4, 2)), np.array([[0, 1]])),             # edges, not triangles
    (np.zeros((4, 3)), np.array([[0, 1, 2]])),          # 3D points
    (np.zeros((4, 2)), np.array([[0, 1, 9]])),          # index out of range
    (np.zeros((4, 2)), np.array([[0.0, 1.0, 2.0]])),    # float indices
])
def test_winding_predicates_check_their_arguments(fn, X, F):
    with pytest.raises(MeshError):
        fn(X, F)


@pytest.mark.parametrize("fixed, match", [([999], "outside"), ([0, 0], "more than once"), (np.array([1.0]), "integer")])
def test_smooth_checks_fixed_vertices(fixed, match):
    V, E = G.sector_mesh(3, 4, 0, perturb=0.3)
    with pytest.raises(MeshError, match=match):
        smooth(V, E, fixed=fixed)


def test_problem_refuses_vertices_no_element_uses():
    from geomopt import Problem

    V, F = G.square_mesh(3)
    V = np.vstack([V[:4], [[5.0, 5.0]], V[4:], [[6.0, 6.0]]])  # vertex 4 and the last one unused
    F = np.where(F >= 4, F + 1, F)
    with pytest.raises(MeshError, match=r"2 vertices are not used by any element \(first: \[4, 10\]\)"):
        Problem.planar(V, F)
    assert Problem.planar(V[[0, 1, 2, 3, 5, 6, 7, 8, 9]], np.where(F > 4, F - 1, F)).n_vertices == 9

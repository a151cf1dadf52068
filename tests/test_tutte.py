"""Tests for geomopt.mesh.tutte: flip-free Tutte embeddings onto the unit circle."""


import numpy as np
import pytest

from conftest import mesh_path
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from geomopt import MeshError, ParameterError
from geomopt.exact.predicates import count_inverted, simplex_orientations
from geomopt.exact.topology import boundary_loops, check_disk
from geomopt.mesh.tutte import WEIGHTS, scale_to_area, tutte_embedding, tutte_weights



def grid_disk(nx, ny, jitter=0.0, seed=0):
    """Counter-clockwise triangulated grid on [0, nx] x [0, ny]; interior vertices jittered."""
    x, y = np.meshgrid(np.arange(nx + 1.0), np.arange(ny + 1.0), indexing="ij")
    V = np.stack([x.ravel(), y.ravel()], axis=1)
    inner = ((V > 0) & (V < [nx, ny])).all(axis=1)
    V[inner] += np.random.default_rng(seed).uniform(-jitter, jitter, size=(inner.sum(), 2))
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def lifted(V2, amplitude=1.0):
    """A bumpy 3D surface over planar points."""
    z = amplitude * np.sin(V2[:, 0]) * np.cos(0.7 * V2[:, 1])
    return np.column_stack([V2, z])


def signed_areas(UV, F):
    u, v = UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]
    return 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])


def load(name):
    path = mesh_path(name)
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.load(path, process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


# ---------------------------------------------------------------- generated meshes


@pytest.mark.parametrize("weights", WEIGHTS)
def test_grid_disk_is_flip_free(weights):
    V2, F = grid_disk(12, 9, jitter=0.3)
    V = lifted(V2)
    UV = tutte_embedding(V, F, weights=weights)
    assert UV.shape == (V.shape[0], 2) and UV.dtype == np.float64
    assert count_inverted(UV, F) == 0
    assert (signed_areas(UV, F) > 0).all()
    loop = check_disk(F, V.shape[0])
    np.testing.assert_allclose(np.linalg.norm(UV[loop], axis=1), 1.0, rtol=0, atol=1e-14)
    interior = np.setdiff1d(np.arange(V.shape[0]), loop)
    assert (np.linalg.norm(UV[interior], axis=1) < 1.0).all()


def test_boundary_spaced_by_arc_length_counter_clockwise():
    V2, F = grid_disk(4, 2)
    V2[:, 0] *= 3.0  # boundary edges of lengths 3 and 1
    UV = tutte_embedding(V2, F)
    loop = check_disk(F, V2.shape[0])
    seg = np.linalg.norm(V2[np.roll(loop, -1)] - V2[loop], axis=1)
    angle = np.unwrap(np.arctan2(UV[loop, 1], UV[loop, 0]))
    steps = np.diff(np.append(angle, angle[0] + 2 * np.pi))
    assert (steps > 0).all()  # counter-clockwise
    np.testing.assert_allclose(steps, 2 * np.pi * seg / seg.sum(), atol=1e-12)
    np.testing.assert_allclose(UV[loop[0]], [1.0, 0.0], atol=1e-15)


def test_uniform_interior_vertex_is_neighbour_average():
    V2, F = grid_disk(6, 5, jitter=0.2)
    UV = tutte_embedding(lifted(V2), F, weights="uniform")
    loop = check_disk(F, V2.shape[0])
    A = tutte_weights(V2, F, "uniform")
    assert set(np.unique(A.data)) == {1.0}
    assert (A != A.T).nnz == 0
    avg = (A @ UV) / np.asarray(A.sum(axis=1))
    interior = np.setdiff1d(np.arange(V2.shape[0]), loop)
    np.testing.assert_allclose(UV[interior], avg[interior], atol=1e-13)


def test_mean_value_weights_reproduce_planar_positions():
    # mean-value coordinates have linear precision: x_i = sum_j lambda_ij x_j
    V2, F = grid_disk(7, 6, jitter=0.35, seed=3)
    W = tutte_weights(V2, F, "mean_value")
    assert isinstance(W, sp.csr_matrix) and (W.data > 0).all()
    assert (W != W.T).nnz > 0  # not symmetric
    loop = check_disk(F, V2.shape[0])
    interior = np.setdiff1d(np.arange(V2.shape[0]), loop)
    lam = W / np.asarray(W.sum(axis=1))
    np.testing.assert_allclose((lam @ V2)[interior], V2[interior], atol=1e-12)


def test_mean_value_weight_formula_on_one_fan():
    # vertex 0 at the origin with 4 neighbours at distance 1 and 2, right angles
    V = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [-1.0, 0.0], [0.0, -2.0]])
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    W = tutte_weights(V, F, "mean_value").toarray()
    t = np.tan(np.pi / 4)  # both angles at vertex 0 beside each edge are 90 degrees
    np.testing.assert_allclose(W[0, 1:], [2 * t / 1, 2 * t / 2, 2 * t / 1, 2 * t / 2])


def test_explicit_boundary_matches_default():
    V2, F = grid_disk(5, 5, jitter=0.2)
    V = lifted(V2)
    (loop,) = boundary_loops(F)
    for weights in WEIGHTS:
        np.testing.assert_allclose(
            tutte_embedding(V, F, weights, boundary=loop), tutte_embedding(V, F, weights)
        )


def test_all_vertices_on_boundary():
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    UV = tutte_embedding(V, np.array([[0, 1, 2]]))
    np.testing.assert_allclose(np.linalg.norm(UV, axis=1), 1.0)
    assert count_inverted(UV, np.array([[0, 1, 2]])) == 0


@settings(max_examples=20, deadline=None)
@given(
    nx=st.integers(2, 10),
    ny=st.integers(2, 10),
    jitter=st.floats(0.0, 0.45),
    amplitude=st.floats(0.0, 3.0),
    seed=st.integers(0, 2**32 - 1),
    weights=st.sampled_from(WEIGHTS),
)
def test_random_grids_are_flip_free(nx, ny, jitter, amplitude, seed, weights):
    V2, F = grid_disk(nx, ny, jitter=jitter, seed=seed)
    UV = tutte_embedding(lifted(V2, amplitude), F, weights)
    assert count_inverted(UV, F) == 0


# ---------------------------------------------------------------- real meshes


@pytest.mark.parametrize("weights", WEIGHTS)
@pytest.mark.parametrize("name", ["camelhead.off", "bunny_cut.obj"])
def test_real_mesh_is_flip_free(name, weights):
    V, F = load(name)
    UV = tutte_embedding(V, F, weights)
    assert np.isfinite(UV).all()
    assert count_inverted(UV, F) == 0
    assert (simplex_orientations(UV, F) == 1).all()
    scaled = scale_to_area(UV, V, F)
    rest = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    assert signed_areas(scaled, F).sum() == pytest.approx(rest.sum(), rel=1e-12)


# ---------------------------------------------------------------- scale_to_area


def test_scale_to_area():
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 3.0]])  # area 3
    F = np.array([[0, 1, 2]])
    UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # area 1/2
    out = scale_to_area(UV, V, F)
    np.testing.assert_allclose(out, UV * np.sqrt(6.0))
    V2 = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]])  # planar rest, area 1
    np.testing.assert_allclose(scale_to_area(UV, V2, F), UV * np.sqrt(2.0))
    with pytest.raises(MeshError, match="not positive"):
        scale_to_area(UV[:, ::-1], V, F)
    with pytest.raises(MeshError, match="vertices"):
        scale_to_area(UV[:2], V, F)


# ---------------------------------------------------------------- errors


def test_unknown_weights():
    V2, F = grid_disk(2, 2)
    with pytest.raises(ParameterError, match=r"'cotan'.*'uniform', 'mean_value'"):
        tutte_embedding(V2, F, weights="cotan")
    with pytest.raises(ParameterError, match="valid"):
        tutte_weights(V2, F, weights="harmonic")


def test_not_a_disk():
    t = 2 * np.pi * np.arange(8) / 8
    V = np.concatenate([np.stack([np.cos(t), np.sin(t)], 1), 2 * np.stack([np.cos(t), np.sin(t)], 1)])
    i, j = np.arange(8), (np.arange(8) + 1) % 8
    F = np.concatenate([np.stack([i, j + 8, j], 1), np.stack([i, i + 8, j + 8], 1)])
    with pytest.raises(MeshError, match="2 boundary loops"):
        tutte_embedding(V, F)


@pytest.mark.parametrize(
    "V, match",
    [
        (np.zeros((9, 4)), r"shape \(n, 2\) or \(n, 3\)"),
        (np.full((9, 3), np.nan), "NaN"),
    ],
)
def test_bad_vertices(V, match):
    _, F = grid_disk(2, 2)
    with pytest.raises(MeshError, match=match):
        tutte_embedding(V, F)


def test_bad_boundary_argument():
    V2, F = grid_disk(2, 2)
    with pytest.raises(MeshError, match="repeats a vertex"):
        tutte_embedding(V2, F, boundary=np.array([0, 1, 2, 1]))
    with pytest.raises(MeshError, match=r"must lie in \[0, 9\)"):
        tutte_embedding(V2, F, boundary=np.array([0, 1, 99]))


def test_mean_value_degenerate_rest_mesh():
    V = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [1.0, 1.0]])
    F = np.array([[0, 1, 3], [1, 2, 3], [0, 2, 1]])  # last face is flat (180 degrees at 1)
    with pytest.raises(MeshError, match="weights='uniform'"):
        tutte_weights(V, F, "mean_value")

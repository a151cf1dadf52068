"""The symmetric Dirichlet of affine maps between triangles from their metric tensors
(geomopt.mesh.quality.triangle_symmetric_dirichlet), in 2D and 3D."""

import numpy as np

from geomopt.mesh.quality import triangle_areas, triangle_symmetric_dirichlet


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q


def test_it_equals_the_jacobian_form_of_random_affine_maps():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(50, 3, 2))
    J = rng.normal(size=(50, 2, 2))
    Q = np.einsum("mij,mkj->mki", J, P) + rng.normal(size=(50, 1, 2))
    expected = (J**2).sum((1, 2)) + (np.linalg.inv(J) ** 2).sum((1, 2))
    np.testing.assert_allclose(triangle_symmetric_dirichlet(P, Q), expected, rtol=1e-9)
    # the same triangles placed in 3D by rotations: the same values
    R1, R2 = _rotation(rng), _rotation(rng)
    P3 = np.concatenate([P, np.zeros((50, 3, 1))], axis=2) @ R1.T
    Q3 = np.concatenate([Q, np.zeros((50, 3, 1))], axis=2) @ R2.T
    np.testing.assert_allclose(triangle_symmetric_dirichlet(P3, Q3), expected, rtol=1e-9)


def test_isometry_scaling_and_collapse():
    P = np.array([[[0.0, 0, 0], [1, 0, 0], [0.3, 0.8, 0]]])
    assert np.isclose(triangle_symmetric_dirichlet(P, P)[0], 4.0)
    s = 1.7
    assert np.isclose(triangle_symmetric_dirichlet(P, s * P)[0], 2 * (s * s + 1 / (s * s)))
    flat = P.copy()
    flat[0, 2] = [0.5, 0.0, 0.0]  # on the first edge: no area
    assert triangle_symmetric_dirichlet(P, flat)[0] == np.inf
    assert triangle_symmetric_dirichlet(P, np.zeros_like(P))[0] == np.inf  # a point: 0 / 0 otherwise


def test_triangle_areas_in_the_plane_and_in_space_either_orientation():
    rng = np.random.default_rng(1)
    P = rng.standard_normal((50, 3, 2))
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    signed = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    np.testing.assert_allclose(triangle_areas(P), np.abs(signed), rtol=1e-13)
    np.testing.assert_allclose(triangle_areas(P[:, ::-1]), np.abs(signed), rtol=1e-13)
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))  # the same triangles turned into space
    lifted = np.concatenate([P, rng.standard_normal((50, 1, 1)).repeat(3, axis=1)], axis=2) @ Q.T
    np.testing.assert_allclose(triangle_areas(lifted), np.abs(signed), rtol=1e-12)
    assert triangle_areas(np.zeros((1, 3, 3)))[0] == 0.0

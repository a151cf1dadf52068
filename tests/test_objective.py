"""Assembled energy, gradient and Hessian of whole meshes."""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

from geomopt._objective import Objective, hessian_pattern, project_psd
from geomopt.problem import Problem

from conftest import cube_tets, grid


def cot_laplacian(V, F):
    """Reference cotangent Laplacian (positive semi-definite): x^T L x = sum_e A_e |grad x|^2."""
    n = len(V)
    I, J, W = [], [], []
    for k in range(3):
        i, j, o = F[:, k], F[:, (k + 1) % 3], F[:, (k + 2) % 3]
        u, v = V[i] - V[o], V[j] - V[o]
        cot = np.einsum("ij,ij->i", u, v) / np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        I += [i, j, i, j]
        J += [j, i, i, j]
        W += [-cot / 2, -cot / 2, cot / 2, cot / 2]
    return sp.coo_matrix((np.concatenate(W), (np.concatenate(I), np.concatenate(J))), (n, n)).tocsr()


def test_dirichlet_hessian_is_cotangent_laplacian():
    V, F = grid(6, jitter=0.3)
    P = Problem.planar(V, F)
    obj = Objective(P, "dirichlet")
    # no gauge pin: compare the full matrix, so fix nothing and build the full pattern
    pat = hessian_pattern(P, np.ones((len(V), 2), bool))
    from geomopt._objective import hessian_kernel

    _, _, data = hessian_kernel(obj.energy.density, "none", pat.nnz, obj.geom, jnp.asarray(V),
                                obj.params(), jnp.asarray(pat.slots))
    H = pat.matrix(np.asarray(data)).toarray()
    L = cot_laplacian(V, F).toarray()
    np.testing.assert_allclose(H, 2.0 * np.kron(L, np.eye(2)), atol=1e-12)


def test_energy_and_gradient_match_finite_differences():
    V, F = grid(5, jitter=0.5)
    P = Problem.planar(V, F)
    rng = np.random.default_rng(1)
    x = V + 0.02 * rng.standard_normal(V.shape)
    for name in ("symmetric_dirichlet", "arap", "garanzha"):
        obj = Objective(P, name)
        p = obj.params()
        v, g = obj.value_and_grad(jnp.asarray(x), p)
        g = np.asarray(g)
        free = obj.free_dofs
        for (i, c) in [(7, 0), (12, 1), (18, 0)]:
            h = 1e-6
            xp, xm = x.copy(), x.copy()
            xp[i, c] += h
            xm[i, c] -= h
            fd = (float(obj.value(xp, p)) - float(obj.value(xm, p))) / (2 * h)
            assert g[i, c] == pytest.approx(fd if free[i, c] else 0.0, rel=1e-6, abs=1e-8)


def test_total_is_volume_weighted_sum_and_rest_value():
    V, T = cube_tets(2)
    P = Problem.tets(V, T)
    assert P.volumes.sum() == pytest.approx(1.0)
    obj = Objective(P, "symmetric_dirichlet")
    assert float(obj.value(jnp.asarray(V), obj.params())) == pytest.approx(6.0)


def test_hessian_is_symmetric_and_projected_psd():
    V, F = grid(6, jitter=0.3)
    P = Problem.planar(V, F)
    rng = np.random.default_rng(3)
    x = V + 0.05 * rng.standard_normal(V.shape)
    obj = Objective(P, "symmetric_dirichlet")
    for projection in ("clamp", "abs"):
        _, _, data = obj.hessian(jnp.asarray(x), obj.params(), projection)
        H = obj.pattern.matrix(np.asarray(data)).toarray()
        np.testing.assert_allclose(H, H.T, atol=1e-10 * np.abs(H).max())
        assert np.linalg.eigvalsh(H).min() > -1e-9 * np.abs(H).max()


@pytest.mark.parametrize("k", [4, 9])
def test_project_psd(k):
    rng = np.random.default_rng(k)
    A = rng.standard_normal((200, k, k))
    A = A + np.swapaxes(A, 1, 2)
    B = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(k)  # PSD blocks
    for method in ("clamp", "abs"):
        PA = np.asarray(project_psd(jnp.asarray(A), method))
        assert np.linalg.eigvalsh(PA).min() >= -1e-10 * np.abs(A).max()
        PB = np.asarray(project_psd(jnp.asarray(B), method))
        np.testing.assert_allclose(PB, B, rtol=1e-9, atol=1e-9 * np.abs(B).max())
    w_abs = np.sort(np.linalg.eigvalsh(np.asarray(project_psd(jnp.asarray(A), "abs"))), -1)
    np.testing.assert_allclose(w_abs, np.sort(np.abs(np.linalg.eigvalsh(A)), -1), rtol=1e-8, atol=1e-8)


def test_translation_pinned_only_for_free_problems():
    V, F = grid(4)
    P = Problem.planar(V, F)
    assert (~Objective(P, "symmetric_dirichlet").free_dofs).sum() == 2
    fixedP = P.with_fixed([0, 3], V[[0, 3]])
    assert (~Objective(fixedP, "dirichlet").free_dofs).sum() == 4
    V3, T = cube_tets(1)
    assert (~Objective(Problem.tets(V3, T), "arap").free_dofs).sum() == 3

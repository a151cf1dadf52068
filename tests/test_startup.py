"""Issue 8: the default linear solver, the persistent compilation cache with size buckets,
start-up without JAX, --json, trimesh input, meshio tet formats and pictures."""

import numpy as np
import pytest
import scipy.sparse as sp

from geomopt import linsolve


def _spd_lower(n=60, seed=0, shift=1.0):
    """A sparse SPD matrix (a shifted 1D Laplacian plus random symmetric couplings): the CSC
    pattern and data of its lower triangle, and the full matrix."""
    rng = np.random.default_rng(seed)
    A = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tolil()
    for _ in range(n):
        i, j = rng.integers(0, n, 2)
        if i != j:
            w = rng.uniform(0.1, 0.4)
            A[i, j] -= w
            A[j, i] -= w
            A[i, i] += w
            A[j, j] += w
    A = (A + shift * sp.eye(n)).tocsc()
    L = sp.tril(A).tocsc()
    L.sort_indices()
    return L.indptr, L.indices, L.data, A


@pytest.mark.parametrize("backend", linsolve.available_backends())
def test_backend_solves_two_factorizations_on_one_analysis(backend):
    ip, ix, data, A = _spd_lower()
    chol = linsolve.SparseCholesky(ip, ix, backend)
    chol.analyze()
    b = np.arange(A.shape[0], dtype=float)
    for scale in (1.0, 3.0):  # two factorizations on one analysis
        chol.factor(scale * data)
        x = chol.solve(b)
        np.testing.assert_allclose(scale * (A @ x), b, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("backend", linsolve.available_backends())
def test_backend_reports_an_indefinite_matrix_then_recovers(backend):
    ip, ix, data, A = _spd_lower()
    chol = linsolve.SparseCholesky(ip, ix, backend)
    bad = data.copy()
    bad[ip[:-1]] -= 10.0  # diagonal entries (first in each column): indefinite
    if backend == "superlu":
        pytest.skip("SuperLU factors indefinite matrices (no positive-definiteness check)")
    with pytest.raises(linsolve.NotPositiveDefinite):
        chol.factor(bad)
    chol.factor(data)
    b = np.ones(A.shape[0])
    np.testing.assert_allclose(A @ chol.solve(b), b, rtol=1e-10, atol=1e-10)


def test_auto_backend_is_the_measured_winner_when_installed():
    pytest.importorskip("pymklpardiso")
    assert linsolve.available_backends()[0] == "pardiso"
    ip, ix, _, _ = _spd_lower()
    assert linsolve.SparseCholesky(ip, ix).backend == "pardiso"

"""Issue 34: PARDISO called directly, its float32 factorization refined in float64 (half the
factor's memory at 10^6 triangles), and the numeric factor freed when a solve ends."""

import numpy as np
import pytest
import scipy.sparse as sp

from geomopt.linalg import linsolve, pardiso

pytestmark = pytest.mark.skipif(pardiso.entry_point() is None, reason="py-mkl-pardiso is not installed here")


def _laplacian(n=40, shift=1e-6, seed=0):
    """A 2D grid Laplacian with random weights plus ``shift`` I (ill-conditioned: a float32
    solve alone is off by ~1e-4), its lower-triangle CSC and the full matrix."""
    rng = np.random.default_rng(seed)
    N = n * n
    i = np.arange(N).reshape(n, n)
    rows = np.concatenate([i[:, :-1].ravel(), i[:-1, :].ravel()])
    cols = np.concatenate([i[:, 1:].ravel(), i[1:, :].ravel()])
    w = rng.uniform(0.5, 2.0, rows.size)
    W = sp.coo_matrix((w, (rows, cols)), shape=(N, N))
    W = W + W.T
    A = (sp.diags(np.asarray(W.sum(axis=1)).ravel() + shift) - W).tocsc()
    L = sp.tril(A).tocsc()
    L.sort_indices()
    return L, A


def _accurate(A, x, b, rtol):
    """``|b - A x| <= rtol |b|``, or the residual float64 can tell (``64 eps |A| |x|``) if
    larger: what a float64 factorization's solve achieves."""
    floor = 64 * np.finfo(float).eps * abs(A).sum(axis=1).max() * np.linalg.norm(x)
    return np.linalg.norm(A @ x - b) <= max(rtol * np.linalg.norm(b), floor)


def _single(L):
    chol = linsolve.SparseCholesky(L.indptr, L.indices, "pardiso", single=True)
    chol.factor(L.data)
    return chol


def test_a_float32_factorization_is_refined_to_float64_accuracy():
    L, A = _laplacian(shift=1e-3)
    chol = _single(L)
    b = np.cos(np.arange(A.shape[0]))
    raw = chol.precondition(b)
    raw_residual = np.linalg.norm(A @ raw - b) / np.linalg.norm(b)
    assert raw_residual > 1e-8  # float32 alone: the refinement has work to do
    for rtol in (1e-6, 1e-10, 1e-12):
        x = chol.solve(b, rtol=rtol)
        assert _accurate(A, x, b, rtol)
    assert 1 <= chol.refinements < pardiso.REFINE_ITERS
    X = chol.solve(np.stack([b, 2.0 * b], axis=1))  # several right-hand sides
    np.testing.assert_allclose(A @ X, np.stack([b, 2.0 * b], axis=1), rtol=0, atol=1e-9)
    # the factor's storage is float32: half of the float64 one's, as PARDISO reports it
    single, double = pardiso.Refined(L.indptr, L.indices), pardiso.Pardiso(L.indptr, L.indices)
    for h in (single, double):
        h.analyze()
        h.factor(L.data)
    assert 0 < single.factor_bytes < 0.6 * double.factor_bytes
    # ill-conditioned (1e-6 shift): the float64 factorization's accuracy
    L, A = _laplacian(shift=1e-6)
    x = _single(L).solve(b)
    assert _accurate(A, x, b, 1e-10)
    exact = linsolve.SparseCholesky.factored(A, "pardiso").solve(b)
    assert np.linalg.norm(x - exact) <= 1e-6 * np.linalg.norm(exact)


def test_single_precision_refuses_an_indefinite_matrix_and_recovers():
    L, A = _laplacian()
    chol = linsolve.SparseCholesky(L.indptr, L.indices, "pardiso", single=True)
    bad = L.data.copy()
    bad[L.indptr[:-1]] -= 10.0
    with pytest.raises(linsolve.NotPositiveDefinite):
        chol.factor(bad)
    assert not chol.has_factor
    chol.factor(L.data)
    b = np.ones(A.shape[0])
    assert _accurate(A, chol.solve(b), b, 1e-10)


def test_a_refinement_that_meets_negative_curvature_raises():
    """A matrix that factors in float32 but whose float64 values are indefinite (a negative
    eigenvalue below float32's resolution): conjugate gradients find it, the solve raises."""
    L, A = _laplacian(n=40, shift=0.0)
    ones = np.ones(A.shape[0]) / np.sqrt(A.shape[0])  # A's null vector: A - 1e-9 I is indefinite
    chol = linsolve.SparseCholesky(L.indptr, L.indices, "pardiso", single=True)
    data = L.data.copy()
    data[L.indptr[:-1]] -= 1e-9
    try:
        chol.factor(data)
    except linsolve.NotPositiveDefinite:
        pytest.skip("float32 pivots already saw it")
    with pytest.raises(linsolve.NotPositiveDefinite):
        chol.solve(ones + 1e-3 * np.sin(np.arange(A.shape[0])))


def test_forgotten_values_still_precondition_and_a_freed_factor_is_refactored():
    L, A = _laplacian()
    chol = _single(L)
    b = np.sin(np.arange(A.shape[0]))
    chol.forget_values()
    assert np.isfinite(chol.precondition(b)).all()
    with pytest.raises(RuntimeError, match="factor again"):
        chol.solve(b)
    generation = chol.generation
    chol.free_factor()
    assert not chol.has_factor and chol.generation == generation + 1
    chol.factor(2.0 * L.data)  # on the same analysis
    assert _accurate(2.0 * A, chol.solve(b), b, 1e-10)


@pytest.mark.parametrize("single", [False, True])
def test_the_direct_handle_frees_its_factor_and_factors_again(single):
    L, A = _laplacian(n=30)
    h = (pardiso.Refined if single else pardiso.Pardiso)(L.indptr, L.indices)
    h.analyze()
    h.factor(L.data)
    h.free_factor()
    h.factor(3.0 * L.data)
    b = np.arange(A.shape[0], dtype=float)
    assert _accurate(3.0 * A, h.solve(b, 1e-11), b, 1e-9)
    h.release()
    h.release()  # twice: a no-op


def test_newton_with_float32_factors_reaches_the_float64_minimum(monkeypatch):
    """A free-boundary parameterization by Newton with every factorization in float32 (the
    size threshold lowered): the same minimum, in about as many iterations."""
    import geomopt
    from geomopt.objective import objective as objective_module

    V, F = _cap()
    runs = {}
    for single_from in (10**9, 0):
        monkeypatch.setattr(objective_module, "SINGLE_FROM_ROWS", single_from)
        res = geomopt.parameterize(V, F, progress=False)
        chol = res.objective.cholesky()
        assert chol.single == (single_from == 0)
        assert not chol.has_factor  # freed when the solve ended (its analysis kept)
        runs[single_from] = res
    a, b = runs[10**9], runs[0]
    assert a.success and b.success
    assert abs(a.energy - b.energy) <= 1e-10 * abs(a.energy)
    assert abs(a.stats.iterations - b.stats.iterations) <= 1
    # the same map up to the free boundary's rigid motion (its gauge)
    pa, pb = a.x - a.x.mean(axis=0), b.x - b.x.mean(axis=0)
    u, _, vt = np.linalg.svd(pb.T @ pa)
    np.testing.assert_allclose(pb @ (u @ vt), pa, rtol=0, atol=1e-6)


def _cap():
    """A spherical cap (a disk surface) of ~1,000 triangles."""
    from geomopt.mesh import generators

    V2, F = generators.square_mesh(24)
    p = 2.0 * V2 - 1.0
    z = np.sqrt(np.maximum(3.0 - (p**2).sum(axis=1), 0.0))
    return np.column_stack([p, z]), F


def test_a_large_3d_laplacian_seed_is_a_float32_factor_applied_unrefined(monkeypatch):
    """L-BFGS's Laplacian seed from PARDISO_3D_FROM rows in 3D is factored in float32 and applied
    without refinement (half the bytes a solve reads: 10^6 tets 204 -> 116 ms): its solves are
    accurate to float32 (not float64), and those of a Laplacian float32 cannot hold (definite only
    by a tiny shift) are float64's."""
    import geomopt
    from geomopt.mesh import generators
    from geomopt.objective.objective import Objective
    from geomopt.solvers._laplacian import RestLaplacian, rest_laplacian

    monkeypatch.setattr(linsolve, "PARDISO_3D_FROM", 10)
    monkeypatch.setattr(linsolve, "available_backends", lambda: ["pardiso", "cholespy", "superlu"])
    V, T = generators.box_mesh(6, 6, 6)
    boundary = np.flatnonzero((np.abs(V - V.mean(axis=0)) > 0.49 * np.ptp(V, axis=0)).any(axis=1))
    problem = geomopt.Problem.tets(V, T, fixed=boundary, fixed_positions=V[boundary])
    obj = Objective(problem, "dirichlet")
    pre = RestLaplacian(obj, "host")
    free = problem.free_mask
    K = rest_laplacian(problem).tocsr()[free][:, free]
    q = np.random.default_rng(1).standard_normal((problem.n_vertices, 3))
    x = pre.solve(q)[free]
    error = np.linalg.norm(K @ x - q[free]) / np.linalg.norm(q[free])
    assert 1e-12 < error < 1e-4, error

    n = 300
    singular = sp.diags([-np.ones(n - 1), np.r_[1.0, 2 * np.ones(n - 2), 1.0], -np.ones(n - 1)], [-1, 0, 1])
    from geomopt.solvers import _laplacian
    held = _laplacian._seed_factor((singular + 2e-12 * sp.identity(n)).tocsc(), "pardiso")
    definite = _laplacian._seed_factor((singular + 1e-2 * sp.identity(n)).tocsc(), "pardiso")
    assert not held.single and definite.single


def test_a_large_2d_laplacian_seed_solves_each_coordinate_on_its_own_handle(monkeypatch):
    """From PARDISO_2D_FROM rows on two or more cores, the 2D seed is PARDISO's, each
    coordinate on its own float32 handle and thread: both coordinates solved (to float32), each
    from its own column."""
    import geomopt
    from geomopt.mesh import generators
    from geomopt.objective.objective import Objective
    from geomopt.solvers import _laplacian

    monkeypatch.setattr(linsolve, "PARDISO_2D_FROM", 10)
    monkeypatch.setattr(linsolve, "usable_cores", lambda: 2)
    monkeypatch.setattr(_laplacian, "usable_cores", lambda: 2)
    monkeypatch.setattr(linsolve, "available_backends", lambda: ["pardiso", "cholespy", "superlu"])
    together, at_once = [], _laplacian._at_once
    monkeypatch.setattr(_laplacian, "_at_once", lambda calls: together.append(len(calls)) or at_once(calls))
    V, F = generators.disk_mesh(12)
    t = generators.rotated_interior(V, F, 90.0)
    problem = geomopt.Problem.planar(t.rest, t.simplices, fixed=t.fixed, fixed_positions=t.x0[t.fixed])
    pre = _laplacian.RestLaplacian(Objective(problem, "dirichlet"), "host")
    free = problem.free_mask
    K = _laplacian.rest_laplacian(problem).tocsr()[free][:, free]
    q = np.random.default_rng(2).standard_normal((problem.n_vertices, 2))
    q[:, 1] *= 1e3  # columns of different sizes: a swapped column would be far off
    built = len(together)
    x = pre.solve(q)[free]
    assert together[built:] == [2]  # the solve too ran the two coordinates at once
    for c in range(2):
        error = np.linalg.norm(K @ x[:, c] - q[free, c]) / np.linalg.norm(q[free, c])
        assert 1e-12 < error < 1e-4, (c, error)
    assert together[0] == 2  # the two factorizations at once

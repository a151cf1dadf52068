"""Assembled energy, gradient and Hessian of whole meshes."""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

from geomopt.objective.objective import Objective, hessian_pattern, project_psd
from geomopt.mesh.problem import Problem

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
    from geomopt.objective.objective import hessian_kernel

    _, _, data = hessian_kernel(obj.energy.density, "none", 0, pat.n_blocks, obj.geom, jnp.ones_like(V),
                                jnp.asarray(V), obj.params(), 0, pat.blocks, pat.swap, pat.gather)
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
    import jax

    project = jax.jit(project_psd, static_argnums=1)
    rng = np.random.default_rng(k)
    A = rng.standard_normal((200, k, k))
    A = A + np.swapaxes(A, 1, 2)
    B = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(k)  # PSD blocks
    for method in ("clamp", "abs"):
        PA = np.asarray(project(jnp.asarray(A), method))
        assert np.linalg.eigvalsh(PA).min() >= -1e-10 * np.abs(A).max()
        PB = np.asarray(project(jnp.asarray(B), method))
        np.testing.assert_allclose(PB, B, rtol=1e-9, atol=1e-9 * np.abs(B).max())
    w_abs = np.sort(np.linalg.eigvalsh(np.asarray(project(jnp.asarray(A), "abs"))), -1)
    np.testing.assert_allclose(w_abs, np.sort(np.abs(np.linalg.eigvalsh(A)), -1), rtol=1e-8, atol=1e-8)


@pytest.mark.parametrize("k", [4, 9])
def test_the_traced_eigenvalue_filter_is_each_projection(k):
    """filter_eigenvalues with a traced code is project_psd with that method, and 'none'
    returns the blocks untouched."""
    import jax

    from geomopt.objective.projection import FILTER_CODES, filter_eigenvalues

    traced = jax.jit(filter_eigenvalues)
    A = np.random.default_rng(k).standard_normal((50, k, k))
    A = jnp.asarray(A + np.swapaxes(A, 1, 2))
    for method, code in FILTER_CODES.items():
        np.testing.assert_allclose(np.asarray(traced(A, np.int32(code))), np.asarray(project_psd(A, method)),
                                   rtol=0, atol=1e-13 * float(jnp.abs(A).max()))


def test_clamp_abs_and_exact_hessians_share_one_compiled_kernel():
    """A Newton solve clamps far from the minimum and takes the exact Hessian near it: one
    compiled Hessian program serves all three eigenvalue filters, with their own values (the
    exact one equal to JAX's dense Hessian)."""
    import jax

    from geomopt.objective.objective import hessian_kernel

    V, F = grid(7, jitter=0.4)
    obj = Objective(Problem.planar(V, F).with_fixed([0, 5], V[[0, 5]]), "symmetric_dirichlet")
    x = V * np.array([1.6, 0.7]) + 0.05 * np.random.default_rng(1).standard_normal(V.shape)
    params = obj.params()
    H = {"clamp": obj.pattern.matrix(np.asarray(obj.hessian(x, params, "clamp")[2])).toarray()}
    programs = hessian_kernel._cache_size()  # this shape's program, compiled or kept from an earlier test
    H.update({m: obj.pattern.matrix(np.asarray(obj.hessian(x, params, m)[2])).toarray() for m in ("abs", "none")})
    assert hessian_kernel._cache_size() == programs
    free = obj.free_dofs.reshape(-1)
    dense = np.asarray(jax.hessian(lambda y: obj.value(y.reshape(x.shape), params))(jnp.asarray(x).reshape(-1)))
    np.testing.assert_allclose(H["none"], dense[free][:, free], atol=1e-10 * np.abs(dense).max())
    assert np.linalg.eigvalsh(H["none"]).min() < 0 <= np.linalg.eigvalsh(H["clamp"]).min() + 1e-9
    assert not np.allclose(H["abs"], H["clamp"])


def test_translation_pinned_only_for_free_problems():
    V, F = grid(4)
    P = Problem.planar(V, F)
    assert (~Objective(P, "symmetric_dirichlet").free_dofs).sum() == 2
    fixedP = P.with_fixed([0, 3], V[[0, 3]])
    assert (~Objective(fixedP, "dirichlet").free_dofs).sum() == 4
    V3, T = cube_tets(1)
    assert (~Objective(Problem.tets(V3, T), "arap").free_dofs).sum() == 3


def _reference_pattern(problem, free_dofs):
    """The first pattern builder (a global np.unique over all element DOF pairs): the
    reference for the vertex-graph builder.  Returns (n, indptr, indices, slots, diag)."""
    from geomopt.objective.objective import local_pairs

    d = problem.dim
    free = np.asarray(free_dofs, bool).reshape(-1)
    red = np.full(problem.n_vertices * d, -1, np.int64)
    red[free] = np.arange(free.sum())
    n = int(free.sum())
    dof = (problem.simplices[:, :, None] * d + np.arange(d)).reshape(len(problem.simplices), -1)
    r = red[dof]
    p, q = local_pairs(d)
    rp, rq = r[:, p].reshape(-1), r[:, q].reshape(-1)
    rows, cols = np.maximum(rp, rq), np.minimum(rp, rq)
    valid = cols >= 0
    keys = cols[valid] * n + rows[valid]
    uniq, inv = np.unique(keys, return_inverse=True)
    slots = np.full(rows.shape, len(uniq), np.int64)
    slots[valid] = inv
    ucols, urows = np.divmod(uniq, n) if n else (uniq, uniq)
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(ucols, minlength=n), out=indptr[1:])
    diag = np.flatnonzero(urows == ucols)
    return n, indptr, urows, slots, diag


def _pattern_cases():
    from geomopt.mesh.generators import boundary_vertices

    V, F = grid(7, jitter=0.3)
    P = Problem.planar(V, F)
    rng = np.random.default_rng(0)
    yield "grid, all free", P, np.ones((len(V), 2), bool)
    yield "grid, Objective gauge pin", P, Objective(P, "dirichlet").free_dofs
    b = boundary_vertices(F, len(V))
    free = np.ones((len(V), 2), bool)
    free[b] = False
    yield "grid, fixed boundary", P, free
    yield "grid, random DOFs fixed", P, rng.random((len(V), 2)) > 0.3
    # a surface: a bumpy grid lifted to 3D, a few fixed vertices, shuffled vertex ids
    perm = rng.permutation(len(V))
    V3 = np.c_[V, 0.1 * np.sin(3 * V[:, 0])][np.argsort(perm)]
    F3 = perm[F]
    PS = Problem.surface(V3, F3)
    free = np.ones((len(V), 2), bool)
    free[[3, 17, 30]] = False
    yield "surface, fixed vertices", PS, free
    Vt, T = cube_tets(3)
    PT = Problem.tets(Vt, T)
    yield "tets, all free", PT, np.ones((len(Vt), 3), bool)
    free = np.ones((len(Vt), 3), bool)
    free[boundary_vertices(T, len(Vt))] = False
    yield "tets, fixed boundary", PT, free
    yield "tets, random DOFs fixed", PT, rng.random((len(Vt), 3)) > 0.5


def test_vertex_graph_pattern_equals_reference():
    for name, P, free in _pattern_cases():
        pat = hessian_pattern(P, free)
        n, indptr, indices, slots, diag = _reference_pattern(P, free)
        assert pat.n == n, name
        np.testing.assert_array_equal(pat.indptr, indptr, err_msg=name)
        np.testing.assert_array_equal(pat.indices, indices, err_msg=name)
        np.testing.assert_array_equal(pat.slots, slots, err_msg=name)
        np.testing.assert_array_equal(pat.diag, diag, err_msg=name)
        np.testing.assert_array_equal(pat.free_dofs, np.flatnonzero(np.asarray(free).ravel()), err_msg=name)


def _dense_hessian(obj, x, params):
    """The exact Hessian on the free DOFs: jax.hessian of each element's energy with respect
    to its vertex positions (not through J-space and G), summed densely with NumPy."""
    import jax

    S, Minv, vol = (np.asarray(a) for a in obj.geom)
    n, d = x.shape

    def element(X, Mi, v):
        return v * obj.energy.density((X[1:] - X[:1]).T @ Mi, params)

    He = np.asarray(jax.jit(jax.vmap(jax.hessian(element)))(jnp.asarray(x[S]), Minv, vol))
    dof = (S[:, :, None] * d + np.arange(d)).reshape(len(S), -1)
    H = np.zeros((n * d, n * d))
    k = dof.shape[1]
    np.add.at(H, (dof[:, :, None], dof[:, None, :]), He.reshape(len(S), k, k))
    free = obj.pattern.free_dofs
    return H[np.ix_(free, free)]


@pytest.mark.parametrize("dim", [2, 3])
def test_assembled_hessian_equals_dense_autodiff_and_chunks_agree(dim):
    """Unprojected, the assembled Hessian is the exact one (lifting, block orientation, gather);
    projected (2D), the chunked loop (a chunk size that does not divide m) equals the vmap."""
    rng = np.random.default_rng(dim)
    if dim == 2:
        V, S = grid(6, jitter=0.3)
        P = Problem.planar(V, S).with_fixed([0, 5], V[[0, 5]])
    else:
        V, S = cube_tets(2)
        P = Problem.tets(V, S).with_fixed([0], V[[0]])
    x = V + 0.05 * rng.standard_normal(V.shape)
    obj = Objective(P, "symmetric_dirichlet")
    p = obj.params()
    obj.chunk = 0
    _, _, data = obj.hessian(jnp.asarray(x), p, "none")
    np.testing.assert_allclose(obj.pattern.matrix(np.asarray(data)).toarray(), _dense_hessian(obj, x, p),
                               rtol=1e-10, atol=1e-10 * np.abs(np.asarray(data)).max())
    if dim == 3:
        return  # the chunk loop is dimension-independent: one check, one compilation less
    _, _, ref = obj.hessian(jnp.asarray(x), p, "clamp")
    assert len(S) % 7
    obj.chunk = 7
    _, _, data = obj.hessian(jnp.asarray(x), p, "clamp")
    np.testing.assert_allclose(np.asarray(data), np.asarray(ref), rtol=1e-12, atol=1e-14)


def test_pattern_index_width_does_not_change_it(monkeypatch):
    """The assembly maps are int32 below 2^31 entries (half the memory of a Newton step's
    largest kept arrays); built with int64 indices instead, the pattern is the same."""
    from geomopt.objective import pattern as pattern_module

    index_dtype = pattern_module.index_dtype
    assert index_dtype(2**31 - 2) == np.int32 and index_dtype(2**31) == np.int64
    cases = list(_pattern_cases())
    narrow = [hessian_pattern(P, free) for _, P, free in cases]
    monkeypatch.setattr(pattern_module, "index_dtype", lambda size: np.int64)
    for (name, P, free), a in zip(cases, narrow):
        b = hessian_pattern(P, free)
        assert a.gather.dtype == np.int32 and b.gather.dtype == np.int64, name
        for field in ("indptr", "indices", "diag", "gather", "blocks", "swap", "vertex_idx"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=f"{name}: {field}")


def test_energy_and_gradient_in_chunks_equal_all_at_once():
    """The kernels' energy and gradient run over chunks of ``grad_chunk`` elements (the last
    chunk shifted back and its repeated elements masked): the same energy and gradient as all
    elements at once (and as the Hessian kernel's), up to the order of the sums."""
    V, S = grid(12, jitter=0.3)  # 242 triangles
    P = Problem.planar(V, S).with_fixed([0, 11], V[[0, 11]])
    x = jnp.asarray(V + 0.01 * np.sin(5 * V[:, ::-1]))
    whole, parts = Objective(P, "symmetric_dirichlet"), Objective(P, "symmetric_dirichlet")
    whole.chunk, parts.chunk = 0, 1
    assert 0 < parts.grad_chunk < len(S) and len(S) % parts.grad_chunk  # several chunks, the last shifted
    p = whole.params()
    assert np.isfinite(float(whole.value(x, p)))  # no inverted element
    for a, b in ((whole.value_and_grad(x, p), parts.value_and_grad(x, p)),
                 (whole.hessian(x, p, "clamp")[:2], parts.hessian(x, p, "clamp")[:2])):
        np.testing.assert_allclose(float(b[0]), float(a[0]), rtol=1e-14)
        np.testing.assert_allclose(np.asarray(b[1]), np.asarray(a[1]), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(float(parts.value(x, p)), float(whole.value(x, p)), rtol=1e-14)


def test_kernel_maps_and_pattern_indices_are_not_copied():
    """At 10^6 triangles every copy of an index array costs tens of MB beside the factor: the
    pattern's assembly maps are views of the kernels' (device) copies on the CPU, its indices
    int32 and shared by the Cholesky."""
    import jax

    V, S = grid(6, jitter=0.3)
    obj = Objective(Problem.planar(V, S).with_fixed([0, 5], V[[0, 5]]), "symmetric_dirichlet")
    pat = obj.pattern
    assert pat.indices.dtype == pat.indptr.dtype == np.int32
    if jax.default_backend() == "cpu":
        blocks, swap, _ = obj.block_assembly
        assert np.shares_memory(np.asarray(blocks), pat.blocks) and np.shares_memory(np.asarray(swap), pat.swap)
    chol = obj.cholesky("superlu")
    assert chol.indices is pat.indices and chol.indptr is pat.indptr

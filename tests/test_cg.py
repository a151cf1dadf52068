"""The JAX-native CG Newton direction (geomopt.objective.cg) against the direct (Cholesky) step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from geomopt.objective.cg import NewtonCG, cg_system, pcg
from geomopt.objective.objective import Objective
from geomopt.mesh.generators import boundary_vertices
from geomopt.linalg.linsolve import SparseCholesky
from geomopt.mesh.problem import Problem

from conftest import cube_tets, grid


def _case(kind):
    """(objective, map): a jittered, perturbed grid with a fixed boundary, the same with only
    the Objective's translation pin (free boundary: rotations make the Hessian singular), and
    a tet cube with a fixed boundary."""
    rng = np.random.default_rng(len(kind))
    if kind == "tets":
        V, S = cube_tets(3)
        P = Problem.tets(V, S)
    else:
        V, S = grid(9, jitter=0.3)
        P = Problem.planar(V, S)
    if kind != "free":
        b = boundary_vertices(S, len(V))
        P = P.with_fixed(b, V[b])
    x = V + 0.01 * rng.standard_normal(V.shape)
    x[P.fixed] = V[P.fixed]
    obj = Objective(P, "symmetric_dirichlet")
    assert np.isfinite(float(obj.value(jnp.asarray(x), obj.params())))
    return obj, jnp.asarray(x)


def _direct(obj, x, params, projection, shift):
    """The direct step: assembled Hessian + shift * mean|diag| factored by SparseCholesky."""
    pat = obj.pattern
    _, g, data = obj.hessian(x, params, projection)
    data = np.array(data)
    data[pat.diag] += shift * np.mean(np.abs(data[pat.diag]))
    chol = SparseCholesky(pat.indptr, pat.indices)
    chol.factor(data)
    gf = np.asarray(g).reshape(-1)[pat.free_dofs]
    return -chol.solve(gf), gf


@pytest.mark.parametrize("kind, shift", [("fixed", 0.0), ("free", 1e-6), ("tets", 1e-9)])
def test_cg_direction_equals_direct_step(kind, shift):
    obj, x = _case(kind)
    p = obj.params()
    cg = NewtonCG(rtol=1e-13, max_iters=5000)
    dx, info = cg.direction(cg.prepare(obj), obj, x, p, "clamp", shift)
    d_direct, gf = _direct(obj, x, p, "clamp", shift)
    d_cg = np.asarray(dx).reshape(-1)[obj.pattern.free_dofs]
    assert float(info.residual) <= 1e-13 and bool(info.curvature)
    assert np.linalg.norm(d_cg - d_direct) <= 1e-8 * np.linalg.norm(d_direct)
    fixed = ~obj.free_dofs.reshape(-1)
    assert np.all(np.asarray(dx).reshape(-1)[fixed] == 0.0)
    assert np.allclose(np.asarray(info.grad).reshape(-1)[obj.pattern.free_dofs], gf)


def test_cg_operator_and_preconditioner_are_the_assembled_ones():
    """matvec is the assembled free-DOF Hessian plus the shift; the preconditioner inverts its
    diagonal vertex blocks (the free-boundary case has a fully pinned vertex)."""
    from geomopt.objective.objective import block_hessian

    obj, x = _case("free")
    p = obj.params()
    op = NewtonCG.prepare(obj)
    pat = obj.pattern
    VB = jax.jit(block_hessian, static_argnums=(0, 1, 2, 8))(
        obj.energy.density, "clamp", 0, obj.geom, x, p, op.blocks, op.swap, pat.n_blocks)
    matvec, precond = cg_system(VB, op, 1e-3)
    matvec, precond = jax.jit(jax.vmap(matvec)), jax.jit(precond)
    _, _, data = obj.hessian(x, p, "clamp")
    H = pat.matrix(np.asarray(data)).toarray()
    H += 1e-3 * np.mean(np.abs(np.diag(H))) * np.eye(pat.n)
    n, d = x.shape
    E = np.zeros((pat.n, n * d))
    E[np.arange(pat.n), pat.free_dofs] = 1.0  # free DOFs -> all DOFs
    cols = np.asarray(matvec(jnp.asarray(E.reshape(-1, n, d)))).reshape(pat.n, n * d)
    np.testing.assert_allclose(cols @ E.T, H, atol=1e-12 * np.abs(H).max())
    # block Jacobi: (H restricted to each vertex's free DOFs)^-1
    r = np.random.default_rng(0).standard_normal((n, d))
    z = np.asarray(precond(jnp.asarray(r)))
    free = obj.free_dofs
    for v in range(n):
        f = np.flatnonzero(free[v])
        if f.size == 0:
            assert np.all(z[v] == 0)
            continue
        idx = np.searchsorted(pat.free_dofs, v * d + f)
        np.testing.assert_allclose(z[v, f], np.linalg.solve(H[np.ix_(idx, idx)], r[v, f]), rtol=1e-10)


def test_cg_forcing_term_and_truncation_give_descent_directions():
    obj, x = _case("fixed")
    V = jnp.asarray(obj.problem.rest_vertices)
    x = V + 0.02 * (x - V)  # closer to the minimum: the forcing term is below eta_max
    p = obj.params()
    op = NewtonCG.prepare(obj)
    _, g = obj.value_and_grad(x, p)
    gnorm = float(jnp.linalg.norm(g))
    dx, info = NewtonCG().direction(op, obj, x, p)
    assert float(info.rtol) == pytest.approx(np.sqrt(gnorm)) and np.sqrt(gnorm) < 0.5
    _, info_ref = NewtonCG().direction(op, obj, x, p, gnorm_ref=16 * gnorm)  # scale-free form
    assert float(info_ref.rtol) == pytest.approx(0.25)
    _, info_fixed = NewtonCG().direction(op, obj, x, p, rtol=1e-3)
    assert float(info_fixed.rtol) == 1e-3 and float(info_fixed.residual) <= 1e-3
    assert float(info.residual) <= float(info.rtol) and int(info.iterations) > 0
    assert float(jnp.vdot(g, dx)) < 0
    _, info_tight = NewtonCG(rtol=1e-10).direction(op, obj, x, p)
    dx1, info1 = NewtonCG(rtol=1e-10, max_iters=2).direction(op, obj, x, p)
    assert int(info1.iterations) == 2 < int(info_tight.iterations)
    assert float(info1.residual) > float(info_tight.residual)
    assert float(jnp.vdot(g, dx1)) < 0
    # at the rest state (the minimum) the gradient and the direction vanish to rounding
    dx0, _ = NewtonCG().direction(op, obj, V, p)
    assert float(jnp.abs(dx0).max()) <= 1e-10 * float(jnp.abs(dx).max())


def test_pcg_matches_dense_solve_and_stops_on_negative_curvature():
    rng = np.random.default_rng(5)
    A = rng.standard_normal((30, 30))
    A = A @ A.T + 30 * np.eye(30)
    b = rng.standard_normal(30)
    Dinv = 1.0 / np.diag(A)
    run = jax.jit(lambda A, b, Dinv: pcg(lambda v: A @ v, lambda r: Dinv * r, b, 1e-14, 200))
    x, k, res, ok = run(jnp.asarray(A), jnp.asarray(b), jnp.asarray(Dinv))
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(A, b), rtol=1e-10)
    assert bool(ok) and float(res) <= 1e-14 and 0 < int(k) <= 60
    x0, k0, _, _ = run(jnp.asarray(A), jnp.zeros(30), jnp.asarray(Dinv))
    assert int(k0) == 0 and not np.any(np.asarray(x0))
    # indefinite: the first direction has zero curvature -> the preconditioned right-hand side
    A2 = jnp.diag(jnp.array([1.0, -1.0]))
    x2, k2, _, ok2 = pcg(lambda v: A2 @ v, lambda r: r, jnp.array([1.0, 1.0]), 1e-12, 10)
    assert not bool(ok2) and int(k2) == 1 and float(x2 @ jnp.array([1.0, 1.0])) > 0
    # negative curvature later: the last iterate is kept (still a descent direction for b)
    A3 = jnp.diag(jnp.array([1.0, 2.0, -10.0]))
    b3 = jnp.array([1.0, 1.0, 0.3])
    x3, k3, _, ok3 = pcg(lambda v: A3 @ v, lambda r: r, b3, 1e-12, 10)
    assert not bool(ok3) and int(k3) >= 2 and float(x3 @ b3) > 0


def test_newton_cg_rejects_bad_configuration():
    from geomopt import ParameterError

    for kw in ({"max_iters": 0}, {"rtol": 1.0}, {"eta_max": 0.0}):
        with pytest.raises(ParameterError):
            NewtonCG(**kw)
    obj, x = _case("fixed")
    with pytest.raises(ParameterError, match="projection"):
        NewtonCG().direction(NewtonCG.prepare(obj), obj, x, obj.params(), "clip")


def test_cg_direction_on_a_bucket_padded_objective():
    """With size buckets (padded elements, vertices and blocks, as ``parameterize`` uses) the
    CG direction is still the direct step, on the padded rows too (zero there)."""
    obj0, x = _case("fixed")
    obj = Objective(obj0.problem, "symmetric_dirichlet", buckets=True)
    assert obj.sizes.padded and obj.block_assembly[2] > obj.pattern.n_blocks
    p = obj.params()
    cg = NewtonCG(rtol=1e-13, max_iters=5000)
    dx, info = cg.direction(cg.prepare(obj), obj, x, p, "clamp", 1e-9)
    assert dx.shape == (obj.sizes.n_padded, 2) and not np.any(np.asarray(dx)[obj.sizes.n:])
    d_direct, _ = _direct(obj, x, p, "clamp", 1e-9)
    d_cg = np.asarray(dx).reshape(-1)[obj.pattern.free_dofs]
    assert np.linalg.norm(d_cg - d_direct) <= 1e-8 * np.linalg.norm(d_direct)


@pytest.mark.parametrize("kind", ["fixed", "tets"])
def test_newton_with_cg_solves_like_the_direct_newton(kind):
    """``Newton(linear_solver="cg")`` is the same solver (projection, line search, stopping)
    with the CG direction: it converges to the direct Newton's minimum."""
    import geomopt
    from geomopt.solvers import Newton

    obj, x = _case(kind)
    res = {(ls, pr): geomopt.minimize(obj, np.asarray(x), Newton(projection=pr, linear_solver=ls),
                                      progress=False)
           for ls, pr in (("superlu", "clamp"), ("cg", "clamp"), ("cg", "adaptive"))}
    direct = res["superlu", "clamp"]
    for pr in ("clamp", "adaptive"):
        r = res["cg", pr]
        assert r.outcome.value == "converged" and r.certificate.inverted == 0
        assert r.energy == pytest.approx(direct.energy, rel=1e-9)
        # Newton's convergence, not a first-order method's: as many iterations, give or take
        assert 2 <= r.stats.iterations <= direct.stats.iterations + 2


def test_auto_linear_solver_rule(monkeypatch):
    """``newton_linear_solver`` picks what its docstring says, and ``Newton`` follows it."""
    from geomopt import ParameterError
    from geomopt.linalg import linsolve
    from geomopt.solvers import SLIM, Newton

    rule = linsolve.newton_linear_solver
    assert rule(2, 10**7, "cpu") == "direct"  # triangles: the factorization at every size
    lim = linsolve.CG_FROM_DOFS[3]
    assert rule(3, lim - 1, "cpu") == "direct" and rule(3, lim, "cpu") == "cg"
    assert rule(2, 10, "gpu") == "cg" and rule(3, 10, "cuda") == "cg"
    obj, x = _case("tets")
    n_free = int(obj.free_dofs.sum())
    assert not Newton().uses_cg(obj)
    state = Newton().init(obj, x, obj.params())
    assert state.memory.factor is not None and state.memory.cg_op is None
    monkeypatch.setitem(linsolve.CG_FROM_DOFS, 3, n_free)
    assert Newton().uses_cg(obj) and Newton(projection="clamp").uses_cg(obj)
    state = Newton(projection="clamp").init(obj, x, obj.params())
    assert state.memory.cg_op is not None and state.memory.factor is None
    assert not Newton(linear_solver="pardiso" if "pardiso" in linsolve.available_backends()
                      else "superlu").uses_cg(obj)
    assert not SLIM().uses_cg(obj)  # proxies always factor
    with pytest.raises(ParameterError, match="proxy"):
        SLIM(linear_solver="cg").uses_cg(obj)


def test_newton_cg_keeps_the_direction_on_the_device():
    """The CG path's decrement is ``-g.dx / 2``, computed with the direction on the device
    (only scalars come back to the host), and the step descends."""
    from geomopt.solvers import Newton

    obj, x = _case("tets")
    solver = Newton(projection="clamp", linear_solver="cg")
    state = solver.init(obj, np.asarray(x), obj.params())
    nxt = solver.step(state)
    dx, info = solver.cg.direction(state.memory.cg_op, obj, state.x, state.params, "clamp",
                                   solver.regularization, gnorm_ref=state.memory.grad_ref)
    g = np.asarray(info.grad)
    assert nxt.decrement == pytest.approx(-0.5 * float(np.vdot(g, np.asarray(dx))), rel=1e-12)
    assert nxt.decrement > 0 and nxt.value < state.value

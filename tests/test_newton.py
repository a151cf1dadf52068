"""Projected Newton reaches known minima; parameterization of real meshes is flip-free."""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

import geomopt
from geomopt import Newton, Objective, Outcome, Problem, minimize, parameterize
from geomopt.exact.predicates import count_inverted

from conftest import grid, mesh_path
from test_objective import cot_laplacian


def developable_patch(n=12):
    """A grid rolled onto a cylinder, triangles spanning its rulings, so the polyhedral surface is
    exactly developable: the symmetric Dirichlet minimum is 4.  Vertices are jittered along the
    rulings only, so triangles are irregular but every quad stays planar."""
    V2, F = grid(n)
    inner = (V2[:, 1] > 0) & (V2[:, 1] < 1)
    V2[inner, 1] += 0.3 / (n - 1) * np.random.default_rng(5).uniform(-1, 1, inner.sum())
    theta = 1.5 * V2[:, 0]  # arc length = radius * angle, radius 1
    V = np.stack([np.cos(theta), np.sin(theta), V2[:, 1]], 1)
    return V, F


@pytest.mark.parametrize("projection", ["adaptive", "clamp", "abs"])
def test_developable_patch_reaches_isometry(projection):
    V, F = developable_patch()
    res = parameterize(V, F, solver=Newton(projection=projection, rtol=1e-14), progress=False)
    area = res.stats.volume
    assert res.success, res.message
    assert res.energy / area == pytest.approx(4.0, abs=1e-8)
    assert count_inverted(res.x, F) == 0


def test_dirichlet_with_fixed_boundary_is_the_harmonic_map():
    V, F = grid(8, jitter=0.3, seed=2)
    bnd = np.flatnonzero((V[:, 0] == 0) | (V[:, 0] == 1) | (V[:, 1] == 0) | (V[:, 1] == 1))
    target = V.copy()
    target[bnd, 0] = 2.0 * V[bnd, 0] + 0.3 * np.sin(3 * V[bnd, 1])
    P = Problem.planar(V, F, fixed=bnd, fixed_positions=target[bnd])
    res = minimize(Objective(P, "dirichlet"), V, Newton(), progress=False)
    assert res.outcome is Outcome.CONVERGED
    L = cot_laplacian(V, F).tocsc()
    inner = np.setdiff1d(np.arange(len(V)), bnd)
    ref = target.copy()
    ref[inner] = spla.spsolve(L[inner][:, inner], -L[inner][:, bnd] @ target[bnd])
    np.testing.assert_allclose(res.x, ref, atol=1e-9)
    np.testing.assert_array_equal(res.x[bnd], target[bnd])  # handles bit-exact


def test_every_energy_runs_with_newton_and_a_user_density():
    V, F = developable_patch(6)

    def quartic(J, params):  # a user-defined density: one function, nothing else
        C = J.T @ J
        return jnp.sum((C - jnp.eye(J.shape[0])) ** 2)

    # Dirichlet alone is left out: with a free boundary its infimum is the collapse to a point
    energies = [e for e in geomopt.energies.REGISTRY if e != "dirichlet"]
    energies += [geomopt.energies.Energy(quartic, name="quartic")]
    for e in energies:
        res = parameterize(V, F, energy=e, solver=Newton(max_steps=100), progress=False)
        assert res.certificate.inverted == 0 and np.isfinite(res.x).all(), e
        assert res.outcome in (Outcome.CONVERGED, Outcome.MAX_STEPS), (e, res.outcome)
        assert res.energy <= res.trace.energy[0] + 1e-12


def test_linear_solver_backends_agree():
    V, F = developable_patch(8)
    out = {}
    for backend in geomopt.linalg.linsolve.available_backends():
        out[backend] = parameterize(V, F, solver=Newton(linear_solver=backend), progress=False).energy
    vals = np.array(list(out.values()))
    assert np.allclose(vals, vals[0], rtol=1e-9), out


def test_camelhead_parameterizes_flip_free():
    from geomopt.io import read_mesh
    from pathlib import Path

    V, F = read_mesh(Path(geomopt.__file__).with_name("data") / "camelhead.off")
    res = parameterize(V, F, progress=False)
    assert res.success, res.message
    assert count_inverted(res.x, F) == 0
    mean = res.mean_energy
    assert 4.0 < mean < 7.45  # converged distortion (7.44640666 on this mesh)
    assert res.stats.iterations < 60


def test_bunny_cut_from_shared_data_flip_free():
    from geomopt.io import read_mesh

    V, F = read_mesh(mesh_path("bunny_cut.obj"))
    res = parameterize(V, F, progress=False)
    assert res.certificate.inverted == 0  # flip-free, but with the boundary free nothing stops it folding
    # over itself: 4 boundary fans turn 1.006-1.15 times (issue 19 item 2: it was a success).
    # The bijective mode's scaffold forbids that (tests/test_bijective.py)
    cert = res.certificate.local
    assert not res.success and res.injectivity == "none" and "boundary vertex" in res.message
    assert "--bijective" in res.message
    assert len(cert.boundary_overlaps) == 4 and len(cert.branch_vertices) == 0


def _swirled_grid(n=6):
    """A jittered grid with its boundary fixed and its interior swirled (injective)."""
    V, F = grid(n, jitter=0.2, seed=1)
    b = np.flatnonzero((V[:, 0] == 0) | (V[:, 0] == 1) | (V[:, 1] == 0) | (V[:, 1] == 1))
    obj = Objective(Problem.planar(V, F, fixed=b, fixed_positions=V[b]), "symmetric_dirichlet")
    x0 = V + 0.02 * np.sin(6 * V[:, ::-1]) * np.isin(np.arange(len(V)), b, invert=True)[:, None]
    return obj, x0


def test_pcg_solves_spd_systems_and_refuses_the_rest():
    from geomopt.linalg.linsolve import pcg

    rng = np.random.default_rng(0)
    B = rng.standard_normal((40, 40))
    A = B @ B.T + 40 * np.eye(40)
    b = rng.standard_normal(40)
    exact = np.linalg.solve(A, b)
    x, k = pcg(lambda v: A @ v, b, lambda r: r / np.diag(A), 1e-10, 200)
    np.testing.assert_allclose(x, exact, rtol=1e-8)
    assert np.linalg.norm(b - A @ x) <= 1e-10 * np.linalg.norm(b) and 1 < k < 40
    x, k = pcg(lambda v: A @ v, b, lambda r: np.linalg.solve(A, r), 1e-10, 5)  # the exact inverse
    assert k == 1
    np.testing.assert_allclose(x, exact, rtol=1e-10)
    assert pcg(lambda v: A @ v, b, lambda r: r, 1e-12, 3)[0] is None  # too few iterations
    assert pcg(lambda v: -(A @ v), b, lambda r: r, 1e-8, 100)[0] is None  # negative definite
    x, k = pcg(lambda v: A @ v, np.zeros(40), lambda r: r, 1e-8, 10)
    assert k == 0 and not x.any()


def test_reuse_factor_takes_cg_directions_preconditioned_by_the_held_factor():
    """With ``reuse_factor`` and a budget of CG iterations, Newton reaches the minimum without
    another factorization (each direction by CG preconditioned with the first iteration's
    factor); with no budget (a factorization cheaper than one CG iteration) it factors."""
    import dataclasses

    obj, x0 = _swirled_grid(8)
    ref = minimize(obj, x0, Newton(projection="clamp", rtol=1e-13), progress=False)
    solver = Newton(projection="clamp", reuse_factor=True)
    chol = obj.cholesky("auto")
    state = solver.step(solver.init(obj, x0, obj.params()))
    factored = chol.generation
    def costs(state, factor_s, iter_s):
        reuse = state.memory.reuse._replace(factor_s=factor_s, iter_s=iter_s)
        return dataclasses.replace(state, memory=state.memory._replace(reuse=reuse))

    solver.step(costs(state, 3e-3, 1e-3))
    assert chol.generation == factored + 1  # 3 CG iterations' time: too few, the second iteration factors
    state = costs(state, 1.0, 1e-6)
    for _ in range(8):
        state = solver.step(state)
    assert chol.generation == factored + 1
    assert float(state.value) == pytest.approx(float(ref.energy), rel=1e-12)
    np.testing.assert_allclose(np.asarray(obj.unpad_map(state.x)), ref.x, atol=1e-7)


def test_reuse_factor_waits_1_2_4_iterations_after_failed_tries(monkeypatch):
    """A try of CG with the held factor that misses the forcing term is followed by 1, then 2,
    then 4 iterations that factor without trying (a Hessian that changes too fast for the
    lagged factor costs at most O(log) wasted tries), and a try that succeeds resets the wait;
    no try follows a step the search cut."""
    import dataclasses

    from geomopt.solvers import newton
    from geomopt.solvers.newton import Reuse

    obj, x0 = _swirled_grid(8)
    solver = Newton(projection="clamp", reuse_factor=True, max_steps=50)
    tries = []

    def missing(matvec, b, precondition, rtol, maxiter):
        tries.append(len(tries))
        return None, 1

    monkeypatch.setattr(newton, "pcg", missing)
    state = solver.step(solver.init(obj, x0, obj.params()))
    state = dataclasses.replace(state, memory=state.memory._replace(reuse=state.memory.reuse._replace(factor_s=1.0)))
    tried_at = []
    for k in range(8):
        before = len(tries)
        state = solver.step(dataclasses.replace(state, memory=state.memory._replace(
            reuse=state.memory.reuse._replace(factor_s=1.0))))
        if len(tries) > before:
            tried_at.append(k)
    assert tried_at == [0, 2, 5]  # a try, 1 iteration factoring, a try, 2, a try, 4...
    assert Reuse(on=True, misses=3, wait=4).tried(True, 1e-3) == Reuse(on=True, iter_s=1e-3)
    # after a cut step (outside Newton's local regime, where the Hessian still changes fast) no try
    fresh = state.memory._replace(reuse=Reuse(on=True, factor_s=1.0, iter_s=1e-6))
    before = len(tries)
    solver.step(dataclasses.replace(state, memory=fresh, stats=state.stats._replace(step_size=0.5)))
    assert len(tries) == before
    solver.step(dataclasses.replace(state, memory=fresh, stats=state.stats._replace(step_size=1.0)))
    assert len(tries) == before + 1


def test_a_failed_factorization_is_not_reused(monkeypatch):
    """Near the minimum the adaptive projection tries the exact (indefinite) Hessian; when its
    factorizations fail, the clamped retry must not precondition CG with the factor those
    attempts destroyed (igea at 959,944 triangles ended "matrix is not factored" at iteration 11):
    it factors again and the step goes on."""
    import dataclasses

    from geomopt.linalg.linsolve import NotPositiveDefinite

    obj, x0 = _swirled_grid(8)
    solver = Newton(projection="clamp", reuse_factor=True)
    state = solver.step(solver.init(obj, x0, obj.params()))
    chol = state.memory.factor
    bad = np.ones(len(chol.indices))
    bad[chol.indptr[:-1]] = -1.0  # negative diagonal: not positive definite
    with pytest.raises(NotPositiveDefinite):
        chol.factor(bad)
    reuse = state.memory.reuse._replace(factor_s=1.0, iter_s=1e-6)  # trying CG would be cheap
    state = dataclasses.replace(state, memory=state.memory._replace(reuse=reuse),
                                stats=state.stats._replace(step_size=1.0))
    before = chol.generation
    new = solver.step(state)
    assert chol.generation == before + 1 and chol.has_factor  # factored afresh, no CG on the failed one
    assert new.stats.accepted and float(new.value) < float(state.value)


def test_a_few_huge_hessian_entries_do_not_shrink_the_whole_direction():
    """The diagonal shift is relative to the *median* diagonal: one very stiff element (here
    weighted 1e20, held at rest; at 853k triangles a sliver of the bijective scaffold, 1e28)
    made the mean diagonal, and the shift with it, so large that the direction vanished
    (decrement 5e-13) and Newton stopped "converged" far from the minimum (mean distortion 22
    against 4.1 there; here ARAP energy 0.5 against 0)."""
    V, F = grid(10, jitter=0.2, seed=3)
    weights = np.ones(len(F))
    weights[0] = 1e20
    x0 = V.copy()
    c = V[F[0]].mean(axis=0)
    others = np.setdiff1d(np.arange(len(V)), F[0])
    x0[others] = c + 1.5 * (V[others] - c)  # the stiff element at rest, every other one stretched
    res = minimize(Objective(Problem.planar(V, F), "arap", element_weights=weights), x0, Newton(), progress=False)
    assert res.energy < 1e-10 and np.abs(res.x - V).max() < 1e-6  # the rest shape: the minimum


def test_a_psd_shift_starts_where_the_last_one_factored(monkeypatch):
    """Where the smallest shifts never factor (a free boundary's rigid motions at 10^5-10^6
    triangles: three failed factorizations per iteration on an 853k chart), each iteration
    after the first tries at most one shift below the one that factored last."""
    from geomopt.solvers.newton import AbstractNewton

    real, offered = AbstractNewton._direction, []

    def direction(self, state, projection, shifts):
        offered.append(list(shifts))
        return real(self, state, projection, [s for s in shifts if s >= 1e-9 * 100**3])  # the others "fail"

    monkeypatch.setattr(AbstractNewton, "_direction", direction)
    V, F = developable_patch(8)
    res = parameterize(V, F, solver=Newton(projection="clamp", rtol=1e-12), progress=False)
    assert res.success and res.stats.iterations >= 3
    below = [sum(s < 1e-9 * 100**3 for s in shifts) for shifts in offered]
    assert below[0] == 3 and max(below[1:]) <= 1 and sum(below[1:]) < len(below) - 1, below


def test_reuse_factor_auto_from_a_size(monkeypatch):
    """``reuse_factor="auto"`` (the default) reuses the factorization only from
    ``REUSE_FROM_DOFS`` free DOFs; a value other than True, False, 'auto' is refused."""
    from geomopt.solvers import newton

    obj, x0 = _swirled_grid()
    assert Newton().reuse_factor == "auto"
    assert not Newton().init(obj, x0, obj.params()).memory.reuse.on
    assert Newton(reuse_factor=True).init(obj, x0, obj.params()).memory.reuse.on
    monkeypatch.setattr(newton, "REUSE_FROM_DOFS", 10)
    assert Newton().init(obj, x0, obj.params()).memory.reuse.on
    assert not Newton(reuse_factor=False).init(obj, x0, obj.params()).memory.reuse.on
    with pytest.raises(geomopt.ParameterError, match="reuse_factor must be True, False or 'auto'"):
        Newton(reuse_factor="yes")


def test_newton_shares_the_meshs_symbolic_analysis():
    """Newton factors with the mesh's one Cholesky (one symbolic analysis and one factor in
    memory per mesh and backend, "auto" resolved), and a derivative that factored the same
    Cholesky before a later solve refactored it still gets its own matrix back."""
    from geomopt.linalg.linsolve import available_backends

    obj, x0 = _swirled_grid()
    backend = available_backends()[0]
    assert obj.cholesky("auto") is obj.cholesky(backend)
    for name in ("auto", backend):
        state = Newton(linear_solver=name).init(obj, x0, obj.params())
        assert state.memory.factor is obj.cholesky(backend)
    first = minimize(obj, x0, Newton(linear_solver=backend), progress=False)
    again = minimize(obj, x0, Newton(linear_solver="auto"), progress=False)
    assert first.outcome is again.outcome is Outcome.CONVERGED
    np.testing.assert_allclose(again.x, first.x, atol=1e-12)


def test_newton_takes_its_last_step_where_the_energy_cannot_rank_steps():
    # once the decrement is ~1e-15 |E| the search's energy tests are rounding: it took no step, a
    # sliver or a doubled step, leaving the gradient at 2e-7 (maps accurate to ~1e-9, too little
    # for finite differences of re-solves); the full Newton step is taken when admissible
    from geomopt.mesh.generators import saddle

    V, F = saddle(rings=8, amplitude=1.2)
    d = np.random.default_rng(0).standard_normal(len(F))
    # plain weights: the search took no step; these: it doubled the last one
    for weights in (None, jnp.exp(-1e-3 * d / np.linalg.norm(d))):
        res = geomopt.parameterize(V, F, element_weights=weights, progress=False)
        grad = np.asarray(res.trace.grad_norm)
        assert res.success and grad[-1] < 1e-11 * grad[0]


def test_large_steps_hand_free_memory_back(monkeypatch):
    """From ``TRIM_FROM_DOFS`` free DOFs each step returns the C heap's free memory before its
    Hessian, after copying it (before the factorization), before and after its search (the temporaries of other threads' kernels would stay
    resident under the next ones: 10^6 triangles' peak 2.66 -> 2.52 GB); below it, never."""
    from geomopt._runtime.memory import release_free_memory
    from geomopt.solvers import newton

    assert isinstance(release_free_memory(), bool)
    calls = []
    monkeypatch.setattr(newton, "release_free_memory", lambda: calls.append(1))
    obj, x0 = _swirled_grid()
    solver = Newton(max_steps=2, rtol=1e-30)
    res = minimize(obj, x0, solver, progress=False)
    assert res.stats.iterations == 2 and not calls
    monkeypatch.setattr(newton, "TRIM_FROM_DOFS", 10)
    minimize(obj, x0, solver, progress=False)
    assert len(calls) == 8  # four a step

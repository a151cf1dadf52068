"""The solver zoo on one search/descent architecture: every solver x a problem zoo, the
proxies' defining properties, and tests that kill deliberate breaks of the shared search."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt.solvers.linesearch as linesearch_module
from geomopt import Objective, Outcome, Problem, minimize, parameterize
from geomopt.energies import get_energy
from geomopt.mesh.generators import boundary_vertices, box_mesh, disk_mesh
from geomopt.solvers.linesearch import InjectiveSearch, still_positive
from geomopt.exact.predicates import count_inverted
from geomopt.solvers import AQP, CM, LBFGS, SLIM, SOLVERS, Newton, get_solver
import geomopt.solvers.lbfgs as lbfgs_module
from geomopt.solvers.lbfgs import _two_loop
from geomopt.objective.projection import CMProxy, SLIMProxy, slim_weights, svd2, true_hessian_block

from conftest import grid
from test_newton import developable_patch

ALL = list(SOLVERS)


# ------------------------------------------------------------------------ problem zoo


def _affine_problem(dim, seed=0):
    """Fixed boundary at an affine image of the rest mesh, interior jittered (flip-free):
    for a polyconvex energy the affine map is the minimum, with known energy."""
    rng = np.random.default_rng(seed)
    if dim == 2:
        V, S = disk_mesh(4)
        A = np.array([[1.3, 0.2], [-0.1, 0.8]])
        make = Problem.planar
    else:
        V, S = box_mesh(2, 2, 2)
        A = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.1], [0.1, 0.0, 1.1]])
        make = Problem.tets
    b = boundary_vertices(S, len(V))
    target = V @ A.T
    problem = make(V, S, b, target[b])
    x0 = target.copy()
    inner = np.setdiff1d(np.arange(len(V)), b)
    x0[inner] += 0.03 * rng.standard_normal((inner.size, dim))
    assert count_inverted(x0, problem.simplices) == 0
    return problem, x0, target


def _run(problem, x0, energy, name, max_steps=3000):
    obj = Objective(problem, energy)
    solver = get_solver(name)
    solver = dataclasses.replace(solver, max_steps=max_steps)
    seen = []

    def progress(state, elapsed, mean):
        seen.append(count_inverted(np.asarray(state.x), problem.simplices))

    return obj, minimize(obj, x0, solver, progress=progress), seen


@pytest.mark.parametrize("name", ALL)
def test_fixed_boundary_2d_reaches_the_affine_minimum(name):
    problem, x0, target = _affine_problem(2)
    obj, res, seen = _run(problem, x0, "symmetric_dirichlet", name)
    assert res.success, (name, res.message)
    assert max(seen, default=0) == 0
    best = float(obj.value(jnp.asarray(target), obj.params()))
    assert res.energy == pytest.approx(best, rel=1e-6)
    np.testing.assert_allclose(res.x, target, atol=2e-4)


@pytest.mark.parametrize("name", [n for n in ALL if n != "cm"])
def test_tets_reach_the_affine_minimum(name):
    problem, x0, target = _affine_problem(3)
    obj, res, seen = _run(problem, x0, "symmetric_dirichlet", name)
    assert res.success, (name, res.message)
    assert max(seen, default=0) == 0
    best = float(obj.value(jnp.asarray(target), obj.params()))
    assert res.energy == pytest.approx(best, rel=1e-6)


def test_cm_refuses_tets_clearly():
    problem, x0, _ = _affine_problem(3)
    with pytest.raises(Exception, match="2D"):
        minimize(Objective(problem, "symmetric_dirichlet"), x0, CM(), progress=False)


@pytest.mark.parametrize("name", ALL)
def test_free_boundary_surface_reaches_isometry(name):
    V, F = developable_patch(7)
    solver = dataclasses.replace(get_solver(name), max_steps=3000)
    res = parameterize(V, F, solver=solver, progress=False)
    assert res.certificate.inverted == 0 and res.outcome is Outcome.CONVERGED, (name, res.message)
    assert res.mean_energy == pytest.approx(4.0, abs=2e-5)


@pytest.mark.parametrize("name", ["lbfgs", "aqp", "optx-bfgs", "optx-ncg", "newton"])
@pytest.mark.parametrize("energy", ["arap", "dirichlet"])
def test_no_barrier_energies_stay_flip_free(name, energy):
    """ARAP and Dirichlet are finite on inverted triangles: only the search keeps the map
    injective.  A fixed boundary pulled far to one side makes the unconstrained steps fold."""
    V, F = grid(6)
    b = np.flatnonzero((V[:, 0] == 0) | (V[:, 0] == 1) | (V[:, 1] == 0) | (V[:, 1] == 1))
    target = V.copy()
    target[b, 0] = V[b, 0] ** 3  # squeeze the left side: the interior must slide over
    problem = Problem.planar(V, F, b, target[b])
    obj, res, seen = _run(problem, V, energy, name, max_steps=300)
    assert res.certificate.inverted == 0 and max(seen, default=0) == 0, (name, energy, seen)
    assert res.energy < res.trace.energy[0]


def test_solver_names_are_accepted_everywhere():
    problem, x0, _ = _affine_problem(2)
    res = minimize(Objective(problem, "symmetric_dirichlet"), x0, "slim", progress=False)
    assert res.success and isinstance(res.solver, SLIM)


# ------------------------------------------------------------------------ proxies


def _random_jacobians(d, n=20, seed=1):
    rng = np.random.default_rng(seed)
    J = np.eye(d) + 0.4 * rng.standard_normal((n, d, d))
    J[np.linalg.det(J) < 0, 0] *= -1  # keep det > 0
    return jnp.asarray(J)


@pytest.mark.parametrize("d", [2, 3])
def test_slim_weights_equal_the_closed_form_for_symmetric_dirichlet(d):
    density = get_energy("symmetric_dirichlet").density
    for J in _random_jacobians(d):
        w2, (_, s, _) = slim_weights(density, J, {})
        np.testing.assert_allclose(w2, 1 + s**-1 + s**-2 + s**-3, rtol=1e-9)


def test_closed_form_svd2_matches_lapack():
    """Singular values (the small one to relative accuracy), orthogonal factors and the
    reconstruction, over random scales, inverted and nearly degenerate Jacobians."""
    rng = np.random.default_rng(5)
    J = rng.standard_normal((500, 2, 2)) * rng.uniform(1e-3, 1e3, (500, 1, 1))
    J[:4] = [np.eye(2), [[1.0, 0.0], [0.0, 1e-9]], [[0.0, -1.0], [1.0, 0.0]], [[2.0, 1e-12], [0.0, -3.0]]]
    U, s, Vt = (np.asarray(a) for a in jax.vmap(svd2)(jnp.asarray(J)))
    ref = np.linalg.svd(J, compute_uv=False)
    np.testing.assert_allclose(s, ref, rtol=1e-11)
    np.testing.assert_allclose(np.einsum("nij,nj,njk->nik", U, s, Vt), J,
                               atol=1e-14 * np.abs(J).max())
    for Q in (U, np.swapaxes(Vt, 1, 2)):
        np.testing.assert_allclose(np.einsum("nji,njk->nik", Q, Q), np.broadcast_to(np.eye(2), Q.shape),
                                   atol=1e-14)


@pytest.mark.parametrize("d", [2, 3])
def test_slim_proxy_gradient_matches_the_energy(d):
    """|W(J - R)|^2 with R = U V^T has the energy's gradient at J: the global step is a
    Newton step on the proxy with the true gradient."""
    density = get_energy("symmetric_dirichlet").density
    for J in _random_jacobians(d, 5):
        H = SLIMProxy()(density, J, {}).reshape(d * d, d * d)
        U, s, Vt = jnp.linalg.svd(J)
        R = U @ Vt
        grad_proxy = (H @ (J - R).reshape(-1)).reshape(d, d)  # d/dJ of (J-R):H:(J-R)/2
        np.testing.assert_allclose(grad_proxy, jax.grad(density)(J, {}), rtol=1e-8, atol=1e-10)
        assert np.linalg.eigvalsh(H).min() > 0


def test_aqp_proxy_is_scaled_to_the_energys_rest_curvature():
    """AQP's Laplacian proxy is scaled by the density's rest curvature (4 for symmetric
    Dirichlet), so near the minimum the search accepts its first trial t = 1 instead of halving
    a step four times too long in every iteration."""
    from geomopt.solvers.aqp import rest_curvature

    for name, c in (("symmetric_dirichlet", 4.0), ("dirichlet", 1.0), ("arap", 1.0)):
        for d in (2, 3):
            assert rest_curvature(get_energy(name).density, {}, d) == pytest.approx(c, rel=1e-12)
    problem, x0, _ = _affine_problem(2)
    steps = []
    res = minimize(Objective(problem, "symmetric_dirichlet"), x0, AQP(),
                   progress=lambda state, *_: steps.append(state.step_size))
    assert res.success
    assert np.median(steps[len(steps) // 2:]) == 1.0, steps


def test_aqp_search_keeps_the_blocking_element_away_from_collapse():
    """AQP's default search caps its first trial at a quarter of the flip bound: its Laplacian
    proxy ignores the barrier, and at the other solvers' 0.9 the element that blocks a step
    loses most of its area, so the next steps alternate tiny and short (16 iterations to 1e-4
    of the minimum here, 8 with the cap)."""
    from geomopt.mesh.generators import saddle
    from geomopt.param import start_map

    assert AQP().search.safety == 0.25
    V, F = saddle(16, amplitude=2.5)
    objective = Objective(Problem.surface(V, F), "symmetric_dirichlet")
    x0 = start_map(objective, None, "mean_value")[0]
    best = minimize(objective, x0, Newton(), progress=False).energy
    res = minimize(objective, x0, AQP(), progress=False)
    assert res.success and res.certificate.inverted == 0
    hits = np.nonzero(res.trace.energy <= best + 1e-4 * abs(best))[0]
    assert len(hits) and hits[0] <= 11, hits[:1]


def _camel_patch(k):
    """The ``k`` triangles of the bundled camel head nearest its largest-x vertex (a disk)."""
    from pathlib import Path

    import geomopt

    V, F = geomopt.io.read_mesh(Path(geomopt.__file__).with_name("data") / "camelhead.off")
    keep = F[np.argsort(np.linalg.norm(V[F].mean(axis=1) - V[np.argmax(V[:, 0])], axis=1))[:k]]
    used = np.unique(keep)
    index = np.full(len(V), -1)
    index[used] = np.arange(len(used))
    return V[used], index[keep]


def test_lbfgs_defaults_laplacian_seed_and_quarter_bound():
    """L-BFGS's defaults on a real free-boundary parameterization from its Tutte map: the
    Laplacian seed with the first trial capped at a quarter of the flip bound reaches 1e-4 of
    the minimum in 41 iterations (the 0.9 cap: 74; the scalar seed: 358)."""
    from geomopt.param import start_map

    assert LBFGS().precondition == "laplacian" and LBFGS().search.safety == 0.25
    V, F = _camel_patch(1000)
    objective = Objective(Problem.surface(V, F), "symmetric_dirichlet")
    x0 = start_map(objective)[0]
    best = minimize(objective, x0, Newton(), progress=False).energy
    res = minimize(objective, x0, LBFGS(), progress=False)
    assert res.success and res.certificate.inverted == 0
    hits = np.nonzero(res.trace.energy <= best + 1e-4 * abs(best))[0]
    assert len(hits) and hits[0] <= 55, hits[:1]


def test_cm_proxy_is_psd_and_majorizes_along_lines():
    rng = np.random.default_rng(3)
    for name in ("symmetric_dirichlet", "mips"):
        density = get_energy(name).density
        for J in _random_jacobians(2, 30, seed=4):
            H = np.asarray(CMProxy()(density, J, {})).reshape(4, 4)
            T = np.asarray(true_hessian_block(density, J, {})).reshape(4, 4)
            assert np.linalg.eigvalsh(H).min() >= -1e-9 * np.abs(H).max()
            for _ in range(5):
                v = rng.standard_normal(4)
                assert v @ H @ v >= v @ T @ v - 1e-9 * abs(v @ T @ v), name


def test_cm_converges_fast_on_2d():
    """CM's majorizer is close to the Hessian: far fewer iterations than SLIM on a fixed boundary."""
    problem, x0, _ = _affine_problem(2, seed=3)
    cm = minimize(Objective(problem, "symmetric_dirichlet"), x0, CM(), progress=False)
    slim = minimize(Objective(problem, "symmetric_dirichlet"), x0, SLIM(), progress=False)
    assert cm.success and slim.success and cm.stats.iterations < slim.stats.iterations


# ------------------------------------------------------------------------ L-BFGS


def test_two_loop_matches_the_materialized_inverse_hessian():
    rng = np.random.default_rng(0)
    n, m = 7, 4
    A = rng.standard_normal((n, n))
    A = A @ A.T + n * np.eye(n)  # SPD: y = A s
    S = rng.standard_normal((m, n))
    Y = S @ A.T
    rho = 1.0 / np.einsum("ij,ij->i", S, Y)
    gamma = float(S[-1] @ Y[-1] / (Y[-1] @ Y[-1]))
    H = gamma * np.eye(n)
    for s, y, r in zip(S, Y, rho):  # BFGS inverse update, oldest first
        V = np.eye(n) - r * np.outer(y, s)
        H = V.T @ H @ V + r * np.outer(s, s)
    g = rng.standard_normal(n)
    # ring buffer with the newest pair at slot (k-1) % m, k = m + 2 (wrapped twice)
    k = m + 2
    order = [(k - m + j) % m for j in range(m)]
    Sb, Yb, rb = np.zeros((m, n)), np.zeros((m, n)), np.zeros(m)
    for j, slot in enumerate(order):
        Sb[slot], Yb[slot], rb[slot] = S[j], Y[j], rho[j]
    d = _two_loop(jnp.asarray(Sb), jnp.asarray(Yb), jnp.asarray(rb), jnp.int32(k),
                  lambda q: gamma * q, jnp.asarray(g[:, None]))
    np.testing.assert_allclose(np.asarray(d)[:, 0], -H @ g, rtol=1e-10)


@pytest.mark.parametrize("k", [3, 7])  # memory partly filled; ring buffer wrapped
def test_compact_direction_equals_the_two_loop_with_the_same_seed(k):
    """The Laplacian seed's compact form (carried P y_i, P g and their products) gives the
    two-loop's direction with the seed gamma P applied inside (P a fixed SPD matrix)."""
    rng = np.random.default_rng(1)
    n, m = 9, 4
    A = rng.standard_normal((n, n))
    P = A @ A.T + n * np.eye(n)
    S, Y = rng.standard_normal((m, n, 2)), rng.standard_normal((m, n, 2))
    Y += 3.0 * S  # positive curvature s.y for every pair
    rho = 1.0 / np.einsum("inc,inc->i", S, Y)
    g = rng.standard_normal((n, 2))
    W = np.einsum("ab,ibc->iac", P, Y)
    gamma = 0.7
    if k < m:  # slots k.. hold stale pairs the memory must ignore
        S[k:] *= 50.0
    apply = lbfgs_module._two_loop(jnp.asarray(S.reshape(m, -1)), jnp.asarray(Y.reshape(m, -1)), jnp.asarray(rho),
                                   jnp.int32(k), lambda q: gamma * (P @ q.reshape(n, 2)).reshape(-1),
                                   jnp.asarray(g))
    SY, YW = np.einsum("inc,jnc->ij", S, Y), np.einsum("inc,jnc->ij", Y, W)
    compact = lbfgs_module._compact_direction(
        jnp.asarray(S.reshape(m, -1)), jnp.asarray(W.reshape(m, -1)), jnp.asarray(np.einsum("inc,nc->i", S, g)),
        jnp.asarray(np.einsum("inc,nc->i", W, g)), jnp.asarray(SY), jnp.asarray(YW), jnp.int32(k),
        jnp.float64(gamma), jnp.asarray(P @ g))
    np.testing.assert_allclose(np.asarray(compact), np.asarray(apply), rtol=1e-10, atol=1e-12)


def test_the_compact_forms_carried_products_are_those_of_the_memory():
    """After a Laplacian-seeded solve that wrapped its ring buffer and a change of eps, the
    carried ``a = S^T g``, ``b = W^T g`` (at the new gradient), ``s_i . y_j`` (older i) and
    ``y_i . w_j`` equal the products of the buffers (the incremental updates from the change
    of a and b)."""
    V, F = grid(12, jitter=0.3, seed=3)
    b = boundary_vertices(F, len(V))
    A = np.array([[1.3, 0.2], [-0.1, 0.8]])
    problem = Problem.planar(V, F, b, V[b] @ A.T)  # the interior at rest: far from the minimum
    solver = LBFGS(history=3, precondition="laplacian", rtol=0.0, gtol=0.0, max_steps=6,
                   search=InjectiveSearch(injective=False))
    obj = Objective(problem, "garanzha")
    x0 = V.copy()
    x0[b] = V[b] @ A.T
    state = solver.init(obj, x0, obj.params(eps=0.5))
    pairs = {}  # slot -> y of the pair stored there (the compact form keeps no Y buffer)
    for _ in range(6):
        k0, g0 = int(state.memory.carry["k"]), np.asarray(state.memory.carry["g"])
        state = solver.step(state)
        if int(state.memory.carry["k"]) == k0 + 1:
            pairs[k0 % 3] = np.asarray(state.memory.carry["g"]) - g0
    c = solver.reparam(state, obj.params(eps=0.1)).memory.carry  # a new gradient, the memory kept
    g = np.asarray(c["g"])
    S, W = (np.asarray(c[key]).reshape(-1, *g.shape) for key in ("S", "W"))
    k, m = int(c["k"]), S.shape[0]
    assert k > m and "Y" not in c, "the solve should have wrapped its memory, holding no Y"
    Y = np.stack([pairs[i] for i in range(m)])
    a, b = np.einsum("inc,nc->i", S, g), np.einsum("inc,nc->i", W, g)
    np.testing.assert_allclose(c["a"], a, rtol=1e-9, atol=1e-9 * abs(a).max())
    np.testing.assert_allclose(c["b"], b, rtol=1e-9, atol=1e-9 * abs(b).max())
    order = [(k - m + j) % m for j in range(m)]
    SY, YW = np.einsum("inc,jnc->ij", S, Y), np.einsum("inc,jnc->ij", Y, W)
    for p, i in enumerate(order):
        for j in order[p:]:
            np.testing.assert_allclose(c["SY"][i, j], SY[i, j], rtol=1e-7, atol=1e-12 * abs(SY).max())
            np.testing.assert_allclose(c["YW"][i, j], YW[i, j], rtol=1e-7, atol=1e-12 * abs(YW).max())


def test_the_search_the_user_passes_is_the_one_that_runs():
    problem, x0, _ = _affine_problem(2, seed=5)
    obj = Objective(problem, "symmetric_dirichlet")
    a = minimize(obj, x0, LBFGS(search=InjectiveSearch(c2=0.9)), progress=False)
    b = minimize(obj, x0, LBFGS(search=InjectiveSearch(c2=0.9, expand=5)), progress=False)
    assert a.success and b.success
    assert not np.array_equal(a.trace.energy, b.trace.energy)


# ------------------------------------------------------------------------ the search


def _quadratic_line(n=50):
    """A Dirichlet problem whose Newton step is t = 1: searching along d/10 wants t = 10."""
    problem, x0, target = _affine_problem(2, seed=7)
    obj = Objective(problem, "dirichlet")
    p = obj.params()
    x = jnp.asarray(problem.check_map(x0))
    v, g = obj.value_and_grad(x, p)
    d = jnp.asarray(target) - x  # exact minimiser of the quadratic along d at t = 1
    return obj, p, x, v, g, d


def test_expansion_doubles_accepted_steps():
    obj, p, x, v, g, d = _quadratic_line()
    t0, *_ = InjectiveSearch(expand=0)(obj, p, x, v, g, d / 8)
    t3, _, f3, _, _ = InjectiveSearch(expand=3)(obj, p, x, v, g, d / 8)
    assert t0 == 1.0 and t3 == 8.0
    assert f3 < float(v)


def test_newton_expansion_saves_iterations():
    V, F = developable_patch(10)
    plain = parameterize(V, F, solver=Newton(projection="clamp", search=InjectiveSearch()), progress=False)
    expand = parameterize(V, F, solver=Newton(projection="clamp", search=InjectiveSearch(expand=3)),
                          progress=False)
    assert plain.success and expand.success
    assert expand.stats.iterations < plain.stats.iterations


def test_adaptive_newton_switches_to_the_exact_hessian():
    """Clamped projected Newton converges linearly near a minimum where element Hessians
    are indefinite; the adaptive mode factors the exact Hessian there (quadratic tail).
    (Step doubling is off: it hides part of the difference.)"""
    V, F = disk_mesh(12)
    V3 = np.column_stack([V, 3.0 * (1 - (V ** 2).sum(1))])  # a tall cap: far from developable
    V3[:, 0] *= 1 + 0.3 * V3[:, 1]
    runs = {p: parameterize(V3, F, solver=Newton(projection=p, rtol=1e-13, search=InjectiveSearch()),
                            progress=False) for p in ("clamp", "adaptive")}
    clamp, adaptive = runs["clamp"], runs["adaptive"]
    assert clamp.success and adaptive.success
    assert adaptive.energy == pytest.approx(clamp.energy, rel=1e-9)
    assert adaptive.stats.iterations <= 0.7 * clamp.stats.iterations, (adaptive.stats.iterations, clamp.stats.iterations)


def test_still_positive_rejects_a_flip_inside_the_step():
    V, F = grid(3)
    S = jnp.asarray(Problem.planar(V, F).simplices)
    x = jnp.asarray(V)
    d = np.zeros_like(V)
    d[4] = [3.0, 3.0]  # the centre vertex crosses its neighbours' edges
    was = jnp.ones(len(F), bool)
    assert not bool(still_positive(S, x, jnp.asarray(d), 1.0, was))
    assert bool(still_positive(S, x, jnp.asarray(d), 0.01, was))


def test_search_keeps_orientation_without_the_closed_form_bound(monkeypatch):
    """With the closed-form bound disabled, the per-trial positivity check alone keeps every
    trial flip-free, on an energy that rewards folding (its line minimum is folded)."""
    monkeypatch.setattr(linesearch_module, "injective_step_bound", lambda S, x, d, chunk=0: jnp.inf)
    from geomopt.energies import Energy
    from geomopt.mesh.geometry import det

    V, F = grid(3)
    b = np.setdiff1d(np.arange(len(V)), [4])
    problem = Problem.planar(V, F, b, V[b])
    obj = Objective(problem, Energy(lambda J, prm: -det(J) ** 2, name="folding"))
    p = obj.params()
    x = jnp.asarray(V)
    v, g = obj.value_and_grad(x, p)
    d = np.zeros_like(V)
    d[4] = [0.8, 0.0]  # the centre vertex moves through the edge x = 1 at t = 0.625
    xt = jnp.asarray(V + d)  # a folded point of lower energy (an acceptable Armijo point)
    assert count_inverted(np.asarray(xt), problem.simplices) > 0
    assert float(obj.value(xt, p)) < float(v) + 1e-4 * float(jnp.vdot(g, jnp.asarray(d)))
    t, xn, *_ = InjectiveSearch()(obj, p, x, float(v), g, jnp.asarray(d))
    assert count_inverted(np.asarray(xn), problem.simplices) == 0


# ------------------------------------------------------------------------ optimistix


def test_objective_is_a_plain_function_for_optimistix():
    import optimistix as optx

    from geomopt.solvers.optimistix import objective_function

    problem, x0, target = _affine_problem(2, seed=2)
    obj = Objective(problem, "symmetric_dirichlet")
    fn = objective_function(obj, x0)
    sol = optx.minimise(fn, optx.BFGS(rtol=1e-10, atol=1e-10), jnp.asarray(x0), args=obj.params(),
                        max_steps=500)
    x = np.where(np.asarray(obj.free_dofs), np.asarray(sol.value), x0)
    np.testing.assert_allclose(x, target, atol=1e-5)


# ------------------------------------------------------------------ certification of minimize


def test_minimize_demotes_a_converged_folded_map_to_not_injective():
    """An energy that rewards folding (its minimum is a reflection, ``det J = -1``) minimised
    with a search that is not injective converges to a mirrored map: ``minimize`` must report
    NOT_INJECTIVE (never CONVERGED, never success), with the inverted elements counted."""
    from geomopt.energies import Energy

    def folding(J, params):
        d = J.shape[-1]
        return jnp.sum((J.T @ J - jnp.eye(d)) ** 2) + (jnp.linalg.det(J) + 1.0) ** 2

    V, F = grid(4, jitter=0.2)
    obj = Objective(Problem.planar(V, F), Energy(folding, name="folding"))
    for solver in (Newton(projection="clamp", search=InjectiveSearch(injective=False)),
                   LBFGS(search=InjectiveSearch(injective=False, c2=0.9), precondition="scalar")):
        res = minimize(obj, V, solver, progress=False)
        assert res.certificate.inverted == len(F) == count_inverted(res.x, F), solver
        assert res.outcome is Outcome.NOT_INJECTIVE and not res.success, (solver, res.outcome)
        assert float(obj.value(res.x, obj.params())) < 1e-12  # it did converge, to a fold

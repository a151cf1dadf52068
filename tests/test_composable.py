"""Issue 17 item 1: the mesh energy composes with jit / grad / hessian / jvp / vjp / vmap, and a
Problem built from traced rest vertices gives the shape derivative."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from geomopt import MeshError, Objective, ParameterError, Problem
from geomopt.mesh.problem import check_rest_values

from conftest import cube_tets, grid


def _surface(n=5):
    V, F = grid(n, jitter=0.3)
    return np.c_[V, 0.3 * np.sin(3 * V[:, 0]) * V[:, 1]], F


def _case(kind, fixed=False):
    """(builder V -> Problem, rest V, a map x near rest) for a small mesh of ``kind``."""
    rng = np.random.default_rng(4)
    if kind == "tet":
        V, T = cube_tets(2)
        V = V + 0.03 * rng.standard_normal(V.shape)
        handles = (np.array([0, 5]),) if fixed else ()
        build = (lambda V: Problem.tets(V, T, handles[0], V[handles[0]])) if fixed else (lambda V: Problem.tets(V, T))
        return build, V, V + 0.03 * rng.standard_normal(V.shape)
    if kind == "surface":
        V, F = _surface()
        return (lambda V: Problem.surface(V, F)), V, V[:, :2] + 0.03 * rng.standard_normal((len(V), 2))
    V, F = grid(5, jitter=0.3)
    build = (lambda V: Problem.planar(V, F, [0, 4], V[jnp.array([0, 4])])) if fixed else (lambda V: Problem.planar(V, F))
    return build, V, V + 0.03 * rng.standard_normal(V.shape)


KINDS = ["planar", "surface", "tet"]


@pytest.mark.parametrize("buckets", [False, True])
@pytest.mark.parametrize("kind", KINDS)
def test_jit_grad_equals_the_kernel_gradient(kind, buckets):
    build, V, x = _case(kind, fixed=True)
    for energy in ("symmetric_dirichlet", "garanzha"):
        obj = Objective(build(V), energy, buckets=buckets)
        p = obj.params()
        g = jax.jit(jax.grad(lambda x: obj.value(x, p)))(jnp.asarray(x))
        v, gk = obj.value_and_grad(x, p)
        g = np.asarray(g) * obj.free_dofs
        assert np.linalg.norm(g - np.asarray(gk)) <= 1e-12 * np.linalg.norm(gk)
        assert float(jax.jit(obj.value)(x, p)) == pytest.approx(float(v), rel=1e-14)
        # traced value_and_grad (pure path) = the kernel's, fixed rows zeroed
        vt, gt = jax.jit(obj.value_and_grad)(x, p)
        np.testing.assert_allclose(np.asarray(gt), np.asarray(gk), rtol=0, atol=1e-12 * np.abs(gk).max())


@pytest.mark.parametrize("kind", KINDS)
def test_jax_hessian_equals_the_assembled_unprojected_hessian(kind):
    build, V, x = _case(kind, fixed=True)
    obj = Objective(build(V), "symmetric_dirichlet")
    p = obj.params()
    n, d = x.shape
    H = np.asarray(jax.jit(jax.hessian(lambda x: obj.value(x, p)))(jnp.asarray(x))).reshape(n * d, n * d)
    free = obj.free_dofs.reshape(-1)
    _, _, data = obj.hessian(x, p, "none")
    Ha = obj.pattern.matrix(np.asarray(data)).toarray()
    np.testing.assert_allclose(Ha, H[np.ix_(free, free)], rtol=0, atol=1e-10 * np.abs(H).max())


def test_jvp_and_vjp_agree_with_the_gradient():
    build, V, x = _case("planar")
    obj = Objective(build(V), "arap")
    p = obj.params()
    t = np.random.default_rng(0).standard_normal(x.shape)
    _, jv = jax.jvp(lambda x: obj.value(x, p), (jnp.asarray(x),), (jnp.asarray(t),))
    v, pull = jax.vjp(lambda x: obj.value(x, p), jnp.asarray(x))
    g = pull(jnp.ones(()))[0]
    assert float(jv) == pytest.approx(float(jnp.vdot(g, t)), rel=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_vmap_over_maps_parameters_and_rest_shapes_equals_the_loop(kind):
    build, V, x = _case(kind)
    obj = Objective(build(V), "garanzha")
    xs = jnp.stack([x, 1.1 * x, x + 0.01])
    loop = [float(obj.value(xi, obj.params())) for xi in xs]
    np.testing.assert_allclose(jax.vmap(lambda x: obj.value(x))(xs), loop, rtol=1e-13)
    lams = jnp.array([0.25, 1.0, 3.0])
    loop = [float(obj.value(x, obj.params(lam=float(l)))) for l in lams]
    np.testing.assert_allclose(jax.vmap(lambda l: obj.value(x, obj.params(lam=l)))(lams), loop, rtol=1e-13)
    Vs = np.stack([V, 1.2 * V, V + 0.01 * np.cos(V)])
    loop = [float(Objective(build(Vi), "garanzha").value(x)) for Vi in Vs]
    np.testing.assert_allclose(jax.vmap(lambda V: Objective(build(V), "garanzha").value(x))(jnp.asarray(Vs)),
                               loop, rtol=1e-12)
    # a batch of problems (one connectivity, stacked rest arrays) is a pytree too
    problems = jax.vmap(build)(jnp.asarray(Vs))
    np.testing.assert_allclose(jax.vmap(lambda P: Objective(P, "garanzha").value(x))(problems), loop, rtol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_shape_derivative_matches_central_differences(kind):
    build, V, x = _case(kind, fixed=True)
    f = lambda V: Objective(build(V), "symmetric_dirichlet").value(x)  # noqa: E731
    g = np.asarray(jax.grad(f)(jnp.asarray(V)))
    assert np.abs(g).max() > 0
    rng = np.random.default_rng(1)
    for _ in range(3):
        i, c = int(rng.integers(len(V))), int(rng.integers(V.shape[1]))
        h = 1e-6
        Vp, Vm = V.copy(), V.copy()
        Vp[i, c] += h
        Vm[i, c] -= h
        fd = (float(f(Vp)) - float(f(Vm))) / (2 * h)
        assert g[i, c] == pytest.approx(fd, rel=1e-6, abs=1e-8 * np.abs(g).max())


def test_handle_positions_and_element_weights_are_differentiable():
    V, F = grid(5, jitter=0.3)
    rng = np.random.default_rng(2)
    x = V + 0.03 * rng.standard_normal(V.shape)
    P = Problem.planar(V, F)
    w = 1.0 + rng.uniform(size=len(F))
    # dE/dw_e = vol_e psi(J_e): the per-element energies
    gw = jax.grad(lambda w: Objective(P, "arap", element_weights=w).value(x))(jnp.asarray(w))
    from geomopt.objective.objective import element_densities

    obj = Objective(P, "arap")
    np.testing.assert_allclose(gw, P.volumes * np.asarray(element_densities(obj, x)), rtol=1e-12)
    assert float(Objective(P, "arap", element_weights=w).value(x)) == pytest.approx(float(jnp.vdot(gw, w)), rel=1e-12)
    with pytest.raises(ParameterError, match="element_weights"):
        Objective(P, "arap", element_weights=-w)
    with pytest.raises(ParameterError, match="shape"):
        Objective(P, "arap", element_weights=w[:-1])
    # handle positions enter the problem as pytree leaves
    H = np.array([0, 4, 24])
    gh = jax.grad(lambda h: jnp.sum(Problem.planar(V, F, H, h).fixed_positions ** 2))(jnp.asarray(x[H]))
    np.testing.assert_allclose(gh, 2 * x[H])


def test_problem_and_objective_are_pytrees_keyed_by_content():
    V, F = _surface()
    P1, P2 = Problem.surface(V, F), Problem.surface(V.copy(), F.copy())
    assert jax.tree_util.tree_structure(P1) == jax.tree_util.tree_structure(P2)
    assert jax.tree_util.tree_structure(P1) != jax.tree_util.tree_structure(Problem.surface(V, F[:, [1, 2, 0]]))
    P3 = jax.tree_util.tree_map(lambda a: a, P1)
    assert np.array_equal(P3.simplices, P1.simplices) and P3.kind == "surface"
    traces = []

    @jax.jit
    def f(obj, x):
        traces.append(1)
        return obj.value(x)

    x = V[:, :2]
    a = f(Objective(P1, "mips"), x)
    b = f(Objective(P2, "mips"), x)  # another objective of the same mesh: no new trace
    assert len(traces) == 1 and float(a) == float(b)
    f(Objective(P2, "mips", element_weights=np.ones(len(F))), x)
    assert len(traces) == 2


def test_traced_construction_skips_value_checks_that_concrete_input_runs():
    V, F = grid(4)
    Fcw = F[:, [0, 2, 1]]
    # concrete: a clockwise mesh is reordered; traced: taken as given, its values checked on the
    # host with the program (issue 30: a bad traced rest element gave a NaN energy, no error)
    assert (Problem.planar(V, Fcw).volumes > 0).all()
    with pytest.raises(Exception, match="MeshError: every rest triangle is negatively oriented"):
        jax.block_until_ready(jax.jit(lambda V: Problem.planar(V, Fcw).volumes)(V))
    flipped = dataclasses.replace(Problem.planar(V, F), volumes=-Problem.planar(V, F).volumes)
    with pytest.raises(MeshError, match="negatively oriented"):
        check_rest_values(flipped)
    check_rest_values(jax.jit(lambda V: Problem.planar(V, F))(V))
    with pytest.raises(ParameterError, match="traced float32"):
        jax.jit(lambda V: Problem.planar(V, F))(V.astype(np.float32))
    # the connectivity must stay concrete: refused with the way out, not a MeshError
    with pytest.raises(ParameterError, match="traced JAX"):
        jax.jit(lambda F: Problem.planar(V, F))(F)


def test_host_only_methods_refuse_tracers_with_the_traceable_way():
    build, V, x = _case("planar", fixed=True)
    obj = Objective(build(V), "arap")
    with pytest.raises(ParameterError, match="jax.hessian"):
        jax.jit(lambda x: obj.hessian(x, obj.params())[0])(x)

"""Issue 30 items 1 and 7: differentiable solves batched (vmap), repeated on one Objective in one
loss, differentiated in forward mode, and their refusals under jax.jit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from geomopt import GeomoptError, MeshError, Objective, Problem, SolveError, implicit
from geomopt.solvers import Newton
from geomopt.topology import boundary_vertices

from conftest import cube_tets, grid

FD_RTOL = 1e-5


def _handles(kind):
    """(make, V, S, H, h0, probe vertex, x0): a small 2D or tet problem held by its boundary."""
    if kind == "tet":
        V, S = cube_tets(2)
        make = Problem.tets
    else:
        V, S = grid(5, jitter=0.25)
        make = Problem.planar
    H = boundary_vertices(S, len(V))
    h0 = V[H] + 0.05 * np.random.default_rng(3).standard_normal((len(H), V.shape[1]))
    inner = np.setdiff1d(np.arange(len(V)), H)
    return make, V, S, H, h0, inner[len(inner) // 2], V.copy()


def _handle_loss(kind, linear_solver):
    make, V, S, H, h0, v, x0 = _handles(kind)
    w = np.linspace(1.0, 2.0, x0.shape[1])

    def loss(h, lam):
        obj = Objective(make(V, S, H, h), "garanzha", eps=1e-2, lam=lam)
        return jnp.dot(implicit.minimize(obj, x0, linear_solver=linear_solver)[v], w)

    rng = np.random.default_rng(7)
    hs = h0 + 0.01 * rng.standard_normal((3,) + h0.shape)
    return loss, (hs, np.array([0.4, 0.9, 1.7]))


def _param_loss(kind, linear_solver):
    """Free-boundary parameterization of a grid bumped by ``t``, batched over ``t`` and the
    per-triangle weights: a gauge-invariant loss (squared area ratios)."""
    V2, F = grid(5, jitter=0.25)
    bump = np.sin(3 * V2[:, 0]) * V2[:, 1]

    def loss(w, t):
        V = jnp.concatenate([jnp.asarray(V2), t * bump[:, None]], axis=1)
        x = implicit.parameterize(V, F, element_weights=w, linear_solver=linear_solver)
        e1, e2 = x[F[:, 1]] - x[F[:, 0]], x[F[:, 2]] - x[F[:, 0]]
        a = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        return jnp.sum((a / Problem.surface(V, F).volumes - 1.0) ** 2)

    rng = np.random.default_rng(8)
    return loss, (1.0 + 0.5 * rng.uniform(size=(3, len(F))), np.array([0.2, 0.3, 0.45]))


CASES = {"planar": _handle_loss, "tet": _handle_loss, "surface": _param_loss}


@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
@pytest.mark.parametrize("linear_solver", ["auto", "cg"])
@pytest.mark.parametrize("kind", ["planar", "surface", "tet"])
def test_vmap_grad_through_solves_equals_the_loop(kind, linear_solver, jit):
    """Item 1: a batch of solves, each backward with the factorization of its own optimum."""
    loss, batch = CASES[kind](kind, linear_solver)
    grad = jax.grad(loss, argnums=(0, 1))
    batched = jax.vmap(grad)
    if jit:
        batched = jax.jit(batched)
    got = batched(*batch)
    for i in range(len(batch[1])):
        want = grad(*(b[i] for b in batch))
        for a, b in zip(got, want):
            np.testing.assert_allclose(a[i], b, rtol=1e-8, atol=1e-8 * np.abs(b).max())
            assert np.abs(b).max() > 1e-6  # real sensitivities


@pytest.mark.parametrize("linear_solver", ["auto", "cg"])
@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
def test_two_solves_on_one_objective_in_one_loss_match_re_solves(jit, linear_solver):
    """Item 1: two solves of one Objective (two values of lam) before the backward pass."""
    make, V, S, H, h0, v, x0 = _handles("planar")
    obj = Objective(make(V, S, H, h0), "garanzha", eps=1e-2)

    def loss(lam):
        a = implicit.minimize(obj, x0, params={"lam": lam}, linear_solver=linear_solver)
        b = implicit.minimize(obj, x0, params={"lam": 3.0 * lam}, linear_solver=linear_solver)
        return a[v, 0] - 2.0 * b[v, 1] + a[v, 1] * b[v, 0]

    lam, step = 0.6, 1e-5
    g = float((jax.jit(jax.grad(loss)) if jit else jax.grad(loss))(lam))
    fd = (float(loss(lam + step)) - float(loss(lam - step))) / (2 * step)
    assert abs(g - fd) <= FD_RTOL * abs(fd) and abs(fd) > 1e-6, (g, fd)


def test_lax_map_and_jacrev_rows_after_other_solves():
    """Item 1: lax.map over solves, and the rows of a jacrev taken after other solves of the
    same mesh ran in between (one factorization per map, never another map's)."""
    loss, (hs, lams) = _handle_loss("planar", "auto")
    grad = jax.grad(loss, argnums=(0, 1))
    mapped = jax.lax.map(lambda a: grad(*a), (hs, lams))
    for i in range(len(lams)):
        for a, b in zip(mapped, grad(hs[i], lams[i])):
            np.testing.assert_allclose(a[i], b, rtol=1e-8, atol=1e-8 * np.abs(b).max())

"""Issue 17 item 2: derivatives of converged solves by the implicit function theorem, checked
against central finite differences of re-solves."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import Objective, ParameterError, Problem, SolveError
from geomopt.param import parameterize_map
from geomopt.solvers import minimize_map
from geomopt.untangling import UntangleOptions, untangle
from geomopt.untangling.implicit import untangle_map
from geomopt.energies import Energy
from geomopt.solvers import LBFGS, Newton
from geomopt.exact.topology import boundary_vertices

from conftest import cube_tets, grid

RTOL = 1e-5


def _directional_check(loss, args, grads, rng, step=1e-5, which=None):
    """Central differences of ``loss`` along a random direction of each argument in ``which``
    against ``<grad, direction>``, to RTOL relative (of the larger of the two)."""
    for k in which if which is not None else range(len(args)):
        a = np.asarray(args[k], np.float64)
        t = rng.standard_normal(a.shape)
        t /= np.linalg.norm(t) if t.ndim else 1.0
        up = list(args)
        dn = list(args)
        up[k], dn[k] = a + step * t, a - step * t
        fd = (float(loss(*up)) - float(loss(*dn))) / (2 * step)
        an = float(np.sum(np.asarray(grads[k]) * t))
        assert abs(an - fd) <= RTOL * max(abs(fd), abs(an)), (k, an, fd)
        assert abs(an) > 1e-8, (k, an)  # a real sensitivity, not two zeros


def _handles_case(kind):
    rng = np.random.default_rng(3)
    if kind == "tet":
        V, S = cube_tets(2)
        make = Problem.tets
    else:
        V2, S = grid(5, jitter=0.25)
        V = V2 if kind == "planar" else np.c_[V2, 0.2 * np.sin(3 * V2[:, 0]) * V2[:, 1]]
        make = Problem.planar if kind == "planar" else Problem.surface
    H = boundary_vertices(S, len(V))
    d = 3 if kind == "tet" else 2
    h0 = V[H][:, :d] + 0.05 * rng.standard_normal((len(H), d))
    inner = np.setdiff1d(np.arange(len(V)), H)
    x0 = V[:, :d].copy()
    return make, V, S, H, h0, inner[len(inner) // 2], x0


@pytest.mark.parametrize("kind", ["planar", "surface", "tet"])
def test_minimize_with_handles_matches_re_solves(kind):
    """Loss: one interior vertex's position; derivative with respect to the rest vertices, the
    handle positions and garanzha's lam, eagerly and under jax.jit."""
    make, V, S, H, h0, v, x0 = _handles_case(kind)
    w = np.linspace(1.0, 2.0, x0.shape[1])

    def loss(V, h, lam):
        P = make(V, S, H, h)
        return jnp.dot(minimize_map(Objective(P, "garanzha", eps=1e-2, lam=lam), x0)[v], w)

    args = (V, h0, 0.7)
    g = jax.grad(loss, argnums=(0, 1, 2))(*args)
    gj = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(*args)
    for a, b in zip(g, gj):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)
    _directional_check(loss, args, g, np.random.default_rng(0))


def _area_loss(F, normalise):
    """Squared (triangle area / rest area - 1), the areas normalised to the rest total when
    ``normalise``: invariant under translations and rotations (and scaling if normalised)."""
    def loss(x, V):
        P = Problem.surface(V, F)
        e1, e2 = x[F[:, 1]] - x[F[:, 0]], x[F[:, 2]] - x[F[:, 0]]
        a = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        a = a / jnp.sum(a) * jnp.sum(P.volumes) if normalise else a
        return jnp.sum((a / P.volumes - 1.0) ** 2)
    return loss


@pytest.mark.parametrize("energy", ["symmetric_dirichlet", "arap", "mips"])
def test_parameterize_free_boundary_gauge_invariant_loss_matches_re_solves(energy):
    """Free boundary: the map is defined up to translation and rotation, and scale for MIPS
    (scale-invariant); the loss (squared area ratios minus one, the areas normalised for MIPS)
    is invariant under that gauge, so re-solves give its gradient (with respect to the rest
    vertices and the per-triangle weights)."""
    V2, F = grid(5, jitter=0.25)
    V = np.c_[V2, 0.3 * np.sin(3 * V2[:, 0]) * V2[:, 1]]
    rng = np.random.default_rng(1)
    w = 1.0 + 0.5 * rng.uniform(size=len(F))
    area = _area_loss(F, normalise=energy == "mips")

    def loss(V, w):
        return area(parameterize_map(V, F, energy=energy, element_weights=w), V)

    g = jax.grad(loss, argnums=(0, 1))(V, w)
    if energy == "symmetric_dirichlet":
        gj = jax.jit(jax.grad(loss, argnums=(0, 1)))(V, w)
        for a, b in zip(g, gj):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-14)
    _directional_check(loss, (V, w), g, rng)


def test_untangled_map_derivative_matches_re_solves():
    V, F = grid(6)
    B = boundary_vertices(F, len(V))
    inner = np.setdiff1d(np.arange(len(V)), B)
    rng = np.random.default_rng(2)
    x0 = V.copy()
    c = V[inner] - 0.5
    x0[inner] = 0.5 + c @ np.array([[np.cos(2.0), -np.sin(2.0)], [np.sin(2.0), np.cos(2.0)]]).T
    h0 = V[B] + 0.03 * rng.standard_normal((len(B), 2))
    assert Problem.planar(V, F, B, h0).count_inverted(x0) > 0

    def loss(h, theta):
        x = untangle_map(untangle, Problem.planar(V, F, B, h), x0, theta)
        return x[inner[3], 0] + 2 * x[inner[7], 1]

    args = (h0, 0.1)
    g = jax.grad(loss, argnums=(0, 1))(*args)
    _directional_check(loss, args, g, rng, step=1e-6)
    x = untangle_map(untangle, Problem.planar(V, F, B, h0), x0, 0.1)
    assert Problem.planar(V, F, B, h0).count_inverted(np.asarray(x)) == 0


def test_untangled_map_derivative_through_equilateral_rest_triangles():
    """Rest triangles above max_aspect are replaced by equilateral ones of their mean edge
    length (geomopt.untangling.equilateral_rest): the derivative with respect to the rest
    vertices flows through those edge lengths, against re-solves."""
    from geomopt.untangling import badly_shaped

    V, F = grid(5, jitter=0.3)
    B = boundary_vertices(F, len(V))
    inner = np.setdiff1d(np.arange(len(V)), B)
    x0 = V.copy()
    c = V[inner] - 0.5
    x0[inner] = 0.5 + c @ np.array([[np.cos(1.5), -np.sin(1.5)], [np.sin(1.5), np.cos(1.5)]]).T
    bad = badly_shaped(Problem.planar(V, F, B, V[B]), 2.0)
    assert 0 < bad.sum() < len(F)
    rng = np.random.default_rng(4)

    def loss(V):
        x = untangle_map(untangle, Problem.planar(V, F, B, x0[B]), x0, 0.1, options=UntangleOptions(max_aspect=2.0))
        return x[inner[2], 0] + 2 * x[inner[5], 1]

    _directional_check(loss, (V,), (jax.grad(loss)(V),), rng, step=1e-6)


def test_min_norm_gauge_convention_against_a_dense_pseudo_inverse():
    """A gauge-dependent quantity (the whole map) gets dx = -H^+ dg/dt: orthogonal to the
    translations and the rotation at the optimum."""
    V2, F = grid(4, jitter=0.3)
    V = np.c_[V2, 0.3 * V2[:, 0] * V2[:, 1]]
    rng = np.random.default_rng(5)
    dV = rng.standard_normal(V.shape)
    x = np.asarray(parameterize_map(V, F))
    Jx = np.asarray(jax.jacrev(lambda t: parameterize_map(V + t * dV, F))(0.0)).reshape(-1)
    obj = Objective(Problem.surface(V, F), "symmetric_dirichlet")
    grad = lambda x, t: jax.grad(lambda x: Objective(Problem.surface(V + t * dV, F),  # noqa: E731
                                                     "symmetric_dirichlet").value(x))(x).reshape(-1)
    n = x.size
    H = np.asarray(jax.hessian(lambda y: obj.value(y.reshape(x.shape)))(jnp.asarray(x).reshape(-1)))
    b = np.asarray(jax.jacfwd(lambda t: grad(jnp.asarray(x), t))(0.0))
    ref = -np.linalg.pinv(H, rcond=1e-9) @ b
    np.testing.assert_allclose(Jx, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
    N = np.stack([np.tile([1.0, 0.0], n // 2), np.tile([0.0, 1.0], n // 2),
                  np.stack([-x[:, 1], x[:, 0]], 1).reshape(-1)], 1)
    assert np.abs(N.T @ Jx).max() <= 1e-9 * np.abs(Jx).max()


def test_cg_adjoint_equals_the_direct_one():
    make, V, S, H, h0, v, x0 = _handles_case("tet")

    def pos(h, linear_solver):
        P = make(V, S, H, h)
        return minimize_map(Objective(P, "symmetric_dirichlet"), x0, adjoint=linear_solver)[v]

    a = jax.jacrev(pos)(h0, "auto")
    b = jax.jacrev(pos)(h0, "cg")
    np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-12 * np.abs(a).max())


def _rest_saddle():
    """A map that a solve accepts (zero gradient at the rest shape) where the exact Hessian is
    indefinite: Dirichlet minus a strong volume term (a bump with div u != 0 lowers it)."""
    def density(J, params):
        D = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
        return jnp.sum(J * J) - 3.0 * (D - 1.0) ** 2

    return Energy(density, name="saddle")


def test_refuses_unconverged_indefinite_and_loose_optima():
    V, F = grid(5, jitter=0.2)
    B = boundary_vertices(F, len(V))
    rng = np.random.default_rng(0)
    h = V[B] + 0.05 * rng.standard_normal((len(B), 2))
    obj = Objective(Problem.planar(V, F, B, h), "symmetric_dirichlet")
    with pytest.raises(SolveError, match="did not succeed"):
        minimize_map(obj, V, Newton(max_steps=1))
    saddle = Objective(Problem.planar(V, F, B, V[B]), _rest_saddle())
    assert geomopt.minimize(saddle, V, progress=False).success  # a plain solve accepts the rest map
    with pytest.raises(SolveError, match="not positive definite"):  # its derivative is refused
        jax.grad(lambda h: jnp.sum(minimize_map(Objective(Problem.planar(V, F, B, h), _rest_saddle()), V)))(V[B])
    loose = LBFGS(rtol=1e-4, gtol=1e-3)
    assert geomopt.minimize(obj, V, loose, progress=False).success
    with pytest.raises(SolveError, match="tight enough"):
        minimize_map(obj, V, loose)
    with pytest.raises(ParameterError, match="linear_solver"):
        minimize_map(obj, V, adjoint="qr")

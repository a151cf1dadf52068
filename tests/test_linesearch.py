"""The injective line search: never inverts an element, tight bound, survives inf/NaN."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from geomopt.objective.objective import Objective
from geomopt.energies import Energy
from geomopt.solvers.linesearch import InjectiveSearch, max_injective_step
from geomopt.exact.predicates import simplex_orientations
from geomopt.mesh.problem import Problem

from conftest import cube_tets, grid

V2, F2 = grid(4, jitter=0.3, seed=1)
V3, T3 = cube_tets(2)


def _check(V, S, seed, scale):
    rng = np.random.default_rng(seed)
    dx = scale * rng.standard_normal(V.shape)
    t = float(max_injective_step(jnp.asarray(S), jnp.asarray(V), jnp.asarray(dx)))
    assert t > 0
    # every step short of t keeps every element positive, by the exact predicate
    for s in np.linspace(0.0, 0.999, 12)[1:]:
        ts = s * t if np.isfinite(t) else s * 1e3
        assert (simplex_orientations(V + ts * dx, S) > 0).all(), (s, t)
    # the bound is tight: just past it some element is no longer positive
    if np.isfinite(t):
        assert (simplex_orientations(V + 1.001 * t * dx, S) <= 0).any()


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), scale=st.floats(1e-3, 10.0))
def test_max_step_2d_never_inverts(seed, scale):
    _check(V2, F2, seed, scale)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10**6), scale=st.floats(1e-3, 10.0))
def test_max_step_3d_never_inverts(seed, scale):
    _check(V3, T3, seed, scale)


def test_degenerate_coefficients():
    # pure translation: det constant -> no root; uniform scaling towards zero: root at t = 1
    S = jnp.asarray(F2)
    x = jnp.asarray(V2)
    assert float(max_injective_step(S, x, jnp.ones_like(x))) == np.inf
    # a double root (det = (1-t)^2 det A) is ill-conditioned: accurate to sqrt(eps), never above
    assert 1.0 - 1e-7 < float(max_injective_step(S, x, -x)) <= 1.0 + 1e-12
    S3, x3 = jnp.asarray(T3), jnp.asarray(V3)
    assert float(max_injective_step(S3, x3, jnp.ones_like(x3))) == np.inf
    assert float(max_injective_step(S3, x3, -x3)) == pytest.approx(1.0, rel=1e-12)
    # squash one axis only: linear det in 2D, cubic with a triple structure in 3D
    d3 = np.zeros_like(V3)
    d3[:, 2] = -V3[:, 2]
    assert float(max_injective_step(S3, x3, jnp.asarray(d3))) == pytest.approx(1.0, rel=1e-12)


def test_backtracking_survives_inf_and_nan():
    P = Problem.planar(V2, F2)
    obj = Objective(P, "symmetric_dirichlet")
    p = obj.params()
    x = jnp.asarray(V2)
    v, g = obj.value_and_grad(x, p)
    dx = -jnp.asarray(np.random.default_rng(0).standard_normal(V2.shape)) * 10
    # non-injective search: trial points with inverted elements give inf and are rejected
    t, xn, vn, _, _ = InjectiveSearch(injective=False)(obj, p, x, float(v), g, -g * 1e6)
    assert np.isfinite(vn) and vn <= float(v)

    nan = Objective(P, Energy(lambda J, prm: jnp.nan * jnp.sum(J), name="nan"))
    t, xn, vn, _, _ = InjectiveSearch()(nan, p, x, float(v), g, dx)
    assert t == 0.0 and vn == float(v)


def test_armijo_rejects_a_full_step_that_does_not_decrease():
    """Along ``d`` the energy ``|x - 0.5|^2`` is the same at ``t = 1`` as at ``t = 0``: Armijo's
    sufficient decrease (``c1 > 0``) must reject the full step and backtrack to ``t = 0.5``,
    the minimum.  With ``c1 = 0`` (no decrease required) the full step would be taken."""
    import jax

    x = jnp.zeros((3, 2))
    d = jnp.ones((3, 2))

    def vg(y):
        return jnp.sum((y - 0.5) ** 2), 2.0 * (y - 0.5)

    f, g = vg(x)
    for search in (InjectiveSearch(injective=False), InjectiveSearch(injective=False, c2=0.9)):
        t, xt, ft, _, ok, _ = jax.jit(lambda x, f, g, d: search.search(vg, None, x, f, g, d))(x, f, g, d)
        assert float(vg(x + d)[0]) == float(f)  # the full step gives no decrease
        assert bool(ok) and float(t) == 0.5 and float(ft) < float(f)
        np.testing.assert_array_equal(np.asarray(xt), np.full((3, 2), 0.5))


def test_injective_bound_and_orientation_test_in_chunks():
    """:func:`injective_step_bound` and :func:`still_positive` over chunks of elements (the last
    one shifted back, its repeated elements masked) give what all elements at once give (the
    bound up to rounding), also with inverted elements (not tested) among the repeated ones."""
    from geomopt.solvers.linesearch import injective_step_bound, still_positive
    from geomopt.mesh.geometry import dets

    V, S = grid(9, jitter=0.3, seed=2)  # 128 triangles
    rng = np.random.default_rng(0)
    S, x = jnp.asarray(S), jnp.asarray(V + 0.06 * rng.standard_normal(V.shape))
    was = dets(S, x) > 0
    assert 0 < int(was.sum()) < len(S)  # some inverted elements
    for chunk in (7, 30, 50):
        assert len(S) % chunk
        for scale in (0.05, 0.3):
            dx = jnp.asarray(scale * rng.standard_normal(V.shape))
            np.testing.assert_allclose(float(injective_step_bound(S, x, dx, chunk)),  # in-loop rounding
                                       float(injective_step_bound(S, x, dx)), rtol=1e-13)
            for t in (0.0, 0.01, 0.5):
                assert bool(still_positive(S, x, dx, t, was, chunk)) == bool(still_positive(S, x, dx, t, was))

"""Issue 32 item 4: the drivers are differentiable by default.  ``jax.grad`` (and ``jit``,
``vmap``) of a loss of ``geomopt.parameterize(...).x``, ``geomopt.minimize(...).x`` and
``geomopt.untangle(...).x`` take the implicit adjoint at the optimum and match central
differences of re-solves; concrete inputs still give the ordinary Result."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import Objective, ParamOptions, ParameterError, Problem
from geomopt.exact.topology import boundary_vertices
from geomopt.mesh import generators
from geomopt.param import parameterize_map
from geomopt.solvers import ForwardCertificate
from geomopt.untangling import UntangleOptions, untangle
from geomopt.untangling.implicit import untangle_map

#: a plain re-solve stops by its energy rule, its map accurate to about 1e-9 relative: central
#: differences of such re-solves take a step of 1e-3 (truncation ~1e-6, noise ~1e-6) and agree
#: to RTOL; re-solves of the polished map (``*_map``) to 1e-5 with steps of 1e-5
RTOL = 1e-4
STEP = 1e-3
TIGHT = geomopt.Newton(rtol=1e-13)


def directional(loss, a, grad, seed=0, step=STEP):
    """``<grad, t>`` and the central difference of ``loss`` along a random unit ``t``."""
    t = np.random.default_rng(seed).standard_normal(np.shape(a))
    t /= np.linalg.norm(t)
    fd = (float(loss(a + step * t)) - float(loss(a - step * t))) / (2 * step)
    return float(np.sum(np.asarray(grad) * t)), fd


def close(an, fd):
    return abs(an - fd) <= RTOL * max(abs(an), abs(fd)) and abs(an) > 1e-8


def bumpy_disk(n=5):
    V, F = generators.square_mesh(n)
    return np.c_[V, 0.3 * np.sin(3 * V[:, 0]) * V[:, 1]], F


def squared_areas(x, F):
    e, f = x[F[:, 1]] - x[F[:, 0]], x[F[:, 2]] - x[F[:, 0]]
    return jnp.sum((e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]) ** 2)


def test_grad_of_parameterize_matches_re_solves():
    """A gauge-invariant loss (squared areas) of the free-boundary UV map, in the rest vertices."""
    V, F = bumpy_disk()
    with jax.enable_x64(True):
        loss = lambda V: squared_areas(geomopt.parameterize(V, F, solver=TIGHT, progress=False).x, F)
        g = jax.grad(loss)(jnp.asarray(V))
        an, fd = directional(loss, V, g)  # the re-solves are plain concrete calls of the driver
    assert close(an, fd), (an, fd)


def _held(n=4):
    V, F = generators.square_mesh(n)
    B = boundary_vertices(F, len(V))
    return V, F, B


def test_grad_of_minimize_matches_re_solves_and_jit_and_vmap_agree():
    V, F, B = _held()
    v = len(V) // 2 + 1
    x0 = V.copy()

    def loss(h):
        P = Problem.planar(V, F, B, h)
        return geomopt.minimize(Objective(P, "symmetric_dirichlet"), x0, TIGHT, progress=False).x[v, 0]

    h0 = V[B] * np.array([1.2, 0.9])
    with jax.enable_x64(True):
        g = jax.grad(loss)(jnp.asarray(h0))
        an, fd = directional(loss, h0, g, seed=1)
        assert close(an, fd), (an, fd)
        gj = jax.jit(jax.grad(loss))(jnp.asarray(h0))
        hs = jnp.stack([h0, h0 * 1.1])
        gv = jax.vmap(jax.grad(loss))(hs)
    np.testing.assert_allclose(gj, g, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(gv[0], g, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(gv[1], _grad64(loss, hs[1]), rtol=1e-8, atol=1e-12)


def _grad64(loss, a):
    with jax.enable_x64(True):
        return jax.grad(loss)(jnp.asarray(a))


def test_grad_of_untangle_in_theta_and_handles_matches_re_solves():
    """``geomopt.untangle`` on a traced problem or ``options.theta``: the untangled map's derivative
    equals central differences of the untangled-and-polished map (the function it is the
    derivative of, :func:`~geomopt.untangling.implicit.untangle_map`)."""
    V, F, B = _held(6)
    inner = np.setdiff1d(np.arange(len(V)), B)
    rng = np.random.default_rng(2)
    x0 = V.copy()
    turn = np.array([[np.cos(2.0), -np.sin(2.0)], [np.sin(2.0), np.cos(2.0)]])
    x0[inner] = 0.5 + (V[inner] - 0.5) @ turn.T
    h0 = V[B] + 0.03 * rng.standard_normal((len(B), 2))
    assert Problem.planar(V, F, B, h0).count_inverted(x0) > 0

    def loss(h, theta):
        x = geomopt.untangle(Problem.planar(V, F, B, h), x0, options=UntangleOptions(theta=theta), progress=False).x
        return x[inner[3], 0] + 2 * x[inner[7], 1]

    def resolve(h, theta):
        x = untangle_map(untangle, Problem.planar(V, F, B, h), x0, theta)
        return x[inner[3], 0] + 2 * x[inner[7], 1]

    with jax.enable_x64(True):
        gh, gt = jax.grad(loss, argnums=(0, 1))(jnp.asarray(h0), 0.1)
        an, fd = directional(lambda h: resolve(h, 0.1), h0, gh, seed=2, step=1e-6)
        assert close(an, fd), (an, fd)
        fd = (float(resolve(h0, 0.1 + 1e-6)) - float(resolve(h0, 0.1 - 1e-6))) / 2e-6
    assert close(float(gt), fd), (float(gt), fd)


def test_traced_calls_return_a_result_and_concrete_calls_are_unchanged():
    V, F = bumpy_disk(3)
    seen = {}

    def loss(V):
        res = geomopt.parameterize(V, F, progress=False)
        seen["result"] = res
        return squared_areas(res.x, F)

    with jax.enable_x64(True):
        jax.grad(loss)(jnp.asarray(V))
    res = seen["result"]
    assert isinstance(res, geomopt.Result) and isinstance(res.x, jax.core.Tracer)
    assert res.success and isinstance(res.certificate, ForwardCertificate)
    plain = geomopt.parameterize(V, F, progress=False)
    assert isinstance(plain.x, np.ndarray) and plain.success and plain.stats.iterations > 0
    assert not isinstance(plain.certificate, ForwardCertificate)


def test_a_traced_call_that_does_not_succeed_raises_instead_of_returning():
    V, F, B = _held(3)
    obj = Objective(Problem.planar(V, F, B, V[B]), "symmetric_dirichlet")
    x0 = V.copy()
    x0[4] += [0.2, -0.1]
    with jax.enable_x64(True), pytest.raises(geomopt.SolveError, match="did not succeed"):
        jax.grad(lambda x: geomopt.minimize(obj, x, geomopt.Newton(max_steps=1), progress=False).x.sum())(
            jnp.asarray(x0))


def test_bijective_is_refused_under_tracing():
    V, F = bumpy_disk(3)
    with jax.enable_x64(True), pytest.raises(ParameterError, match=r"bijective=True\) is not differentiable"):
        jax.grad(lambda V: geomopt.parameterize(V, F, options=ParamOptions(bijective=True), progress=False).x.sum())(
            jnp.asarray(V))


def test_energy_parameters_go_with_the_energy():
    """Issue 32 item 3: every driver takes ``energy=(name, {parameter: value})``; the old loose
    keywords (deprecated, removed in 0.2.0) are refused."""
    V, F = bumpy_disk(4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = geomopt.parameterize(V, F, ("garanzha", {"lam": 0.5, "eps": 0.1}), progress=False)
    assert new.success and new.objective.params()["lam"] == 0.5
    with pytest.raises(TypeError, match="unexpected keyword argument 'lam'"):
        geomopt.parameterize(V, F, "garanzha", progress=False, lam=0.5, eps=0.1)
    with pytest.raises(ParameterError, match="a pair \\(name, \\{parameter: value\\}\\)"):
        geomopt.parameterize(V, F, ("garanzha", 0.5, 0.1), progress=False)
    with jax.enable_x64(True):  # a traced parameter inside the pair is differentiable
        g = jax.grad(lambda lam: squared_areas(
            geomopt.parameterize(V, F, ("garanzha", {"lam": lam, "eps": 0.1}), progress=False).x, F))(0.5)
    assert np.isfinite(float(g)) and float(g) != 0.0


def test_untangle_settings_go_in_the_options_object():
    tangle = generators.rotated_interior(*generators.square_mesh(4), 180.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = geomopt.untangle(tangle.problem(), tangle.x0, options=UntangleOptions(theta=0.1), progress=False)
    assert new.success and new.details.theta == 0.1
    with pytest.raises(TypeError, match="unexpected keyword argument 'theta'"):
        geomopt.untangle(tangle.problem(), tangle.x0, theta=0.1, progress=False)
    with pytest.raises(ParameterError, match="untangle: options must be a UntangleOptions or None, got dict"):
        geomopt.untangle(tangle.problem(), tangle.x0, options={"theta": 0.1}, progress=False)
    with pytest.raises(ParameterError, match="theta must be None or a finite number in \\(0, 1\\)"):
        UntangleOptions(theta=1.5)  # a concrete value is still checked (a traced one passes)

"""Every registered energy: finite-difference derivatives, rest values, invariances, barriers."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from geomopt.energies import REGISTRY, chi, get_energy
from geomopt import ParameterError

NAMES = sorted(REGISTRY)
rng = np.random.default_rng(42)


def rotation(d, seed):
    Q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((d, d)))
    Q[:, 0] *= np.sign(np.linalg.det(Q))
    return Q


def random_J(d, seed, spread=0.4):
    r = np.random.default_rng(seed)
    while True:
        J = np.eye(d) + spread * r.standard_normal((d, d))
        if np.linalg.det(J) > 0.2:
            return J


def params_of(e):
    return {k: jnp.float64(v) for k, v in e.params.items()}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("d", [2, 3])
def test_gradient_and_hessian_match_finite_differences(name, d):
    e = REGISTRY[name]
    p = params_of(e)
    f = jax.jit(lambda J: e.density(J, p))
    grad = jax.jit(jax.grad(f))
    for seed in range(3):
        J = random_J(d, seed)
        g = np.asarray(grad(jnp.asarray(J)))
        H = np.asarray(jax.hessian(f)(jnp.asarray(J))).reshape(d * d, d * d)
        h = 1e-6
        g_fd = np.zeros(d * d)
        H_fd = np.zeros((d * d, d * d))
        for k in range(d * d):
            dJ = np.zeros(d * d)
            dJ[k] = h
            dJ = dJ.reshape(d, d)
            g_fd[k] = (float(f(J + dJ)) - float(f(J - dJ))) / (2 * h)
            H_fd[:, k] = (np.asarray(grad(J + dJ)) - np.asarray(grad(J - dJ))).ravel() / (2 * h)
        np.testing.assert_allclose(g.ravel(), g_fd, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(H, H.T, atol=1e-10)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("d", [2, 3])
def test_rotation_invariance(name, d):
    e = REGISTRY[name]
    p = params_of(e)
    for seed in range(3):
        J = random_J(d, seed + 10)
        R1, R2 = rotation(d, seed), rotation(d, seed + 100)
        v = float(e.density(jnp.asarray(J), p))
        assert float(e.density(jnp.asarray(R1 @ J), p)) == pytest.approx(v, rel=1e-12, abs=1e-12)
        assert float(e.density(jnp.asarray(J @ R2), p)) == pytest.approx(v, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("name", [n for n in NAMES if REGISTRY[n].rest_value is not None])
@pytest.mark.parametrize("d", [2, 3])
def test_rest_value(name, d):
    e = REGISTRY[name]
    R = jnp.asarray(rotation(d, 7))
    assert float(e.density(R, params_of(e))) == pytest.approx(e.value_at_rest(d), abs=1e-12)


def test_known_rest_values():
    R2, R3 = jnp.asarray(rotation(2, 1)), jnp.asarray(rotation(3, 1))
    sd = get_energy("symmetric_dirichlet")
    assert float(sd.density(R2, {})) == pytest.approx(4.0, abs=1e-13)
    assert float(sd.density(R3, {})) == pytest.approx(6.0, abs=1e-13)
    assert float(get_energy("arap").density(R3, {})) == pytest.approx(0.0, abs=1e-13)


@pytest.mark.parametrize("name", ["symmetric_dirichlet", "mips", "arap", "winslow"])
@pytest.mark.parametrize("d", [2, 3])
def test_stationary_at_rotation_for_scale_free_energies(name, d):
    if name == "winslow" and d == 3:
        pytest.skip("3D Winslow is not scale-invariant: a rotation is not stationary")
    e = REGISTRY[name]
    g = jax.grad(e.density)(jnp.asarray(rotation(d, 3)), params_of(e))
    assert np.abs(np.asarray(g)).max() < 1e-12


def test_arap_matches_svd():
    for d in (2, 3):
        for seed in range(5):
            J = random_J(d, seed, spread=0.8)
            U, s, Vt = np.linalg.svd(J)
            if np.linalg.det(U @ Vt) < 0:
                s[-1] = -s[-1]
            ref = np.sum((s - 1.0) ** 2)
            assert float(REGISTRY["arap"].density(jnp.asarray(J), {})) == pytest.approx(ref, rel=1e-10, abs=1e-12)


@pytest.mark.parametrize("name", [n for n in NAMES if REGISTRY[n].barrier])
@pytest.mark.parametrize("d", [2, 3])
def test_barrier_is_inf_with_finite_gradient(name, d):
    e = REGISTRY[name]
    J = np.eye(d)
    J[0, 0] = -1.0  # inverted
    J = jnp.asarray(J)
    assert float(e.density(J, e.params)) == np.inf  # with its own parameters: a row of the table may have some
    assert np.isfinite(np.asarray(jax.grad(e.density)(J, e.params))).all()
    assert np.isfinite(np.asarray(jax.hessian(e.density)(J, e.params))).all()
    assert float(e.density(jnp.zeros((d, d)), e.params)) == np.inf


def test_chi_is_cancellation_safe():
    eps = 1e-3
    assert (-1e6 + np.sqrt(eps**2 + 1e12)) / 2.0 == 0.0  # the textbook form loses everything
    for D in (-1e3, -1e6, -1e9):
        ref = eps**2 / (2.0 * (np.sqrt(eps**2 + D**2) - D))  # no cancellation in this form
        assert float(chi(jnp.float64(D), eps)) == pytest.approx(ref, rel=1e-14)
    assert float(chi(jnp.float64(2.0), eps)) == pytest.approx((2 + np.sqrt(4 + eps**2)) / 2, rel=1e-15)
    # smooth through D = 0
    g = jax.grad(lambda D: chi(D, eps))
    assert float(g(-1e-12)) == pytest.approx(float(g(1e-12)), rel=1e-6)


def test_garanzha_finite_everywhere_and_params():
    e = get_energy("garanzha", eps=1e-2, lam=0.5)
    for d in (2, 3):
        J = -jnp.eye(d) if d == 3 else jnp.asarray([[-1.0, 0.0], [0.0, 1.0]])
        assert np.isfinite(float(e.density(J, params_of(e))))
        assert np.isfinite(np.asarray(jax.hessian(e.density)(J, params_of(e)))).all()


def test_registry_errors():
    with pytest.raises(ParameterError, match="valid energies"):
        get_energy("dirichlett")
    with pytest.raises(ParameterError, match="eps"):
        get_energy("garanzha", eps=0.0)
    with pytest.raises(ParameterError, match="lam"):
        get_energy("garanzha", lam=-1.0)
    with pytest.raises(ParameterError, match="no parameter"):
        get_energy("dirichlet", eps=1.0)

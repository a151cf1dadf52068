"""Issue 48 item 1: ``jax.grad`` (eager and under ``jax.jit``) of a loss of
``geomopt.untangle(problem, x0).x`` equals central differences of the plain (eager) call, with
respect to the rest vertices and the handle positions; the traced and the eager call return
the same map (the minimiser of the energy at the fixed polishing eps)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import Objective, Problem
from geomopt.mesh import generators
from geomopt.objective.adjoint import argmin
from geomopt.solvers import Newton, minimize as run_min

RTOL = 1e-6


def _case(kind, scale):
    """(make, rest vertices jittered by 0.03 edge-ish units, simplices, handles, handle
    positions (rest x scale), tangled start): a 5 x 5 square grid with its interior rotated by
    100 degrees, or a 3 x 3 x 3 cube of tets with its interior vertices rotated by 70 degrees."""
    if kind == "tri":
        t = generators.rotated_interior(*generators.square_mesh(5), 100.0)
        make = Problem.planar
    else:
        t = generators.rotated_interior(*generators.box_mesh(3, 3, 3), 70.0)
        make = Problem.tets
    V = t.rest + 0.03 * np.random.default_rng(0).standard_normal(t.rest.shape)
    h = t.rest[t.fixed] * scale
    x0 = t.x0.copy()
    x0[t.fixed] = h
    assert make(V, t.simplices, t.fixed, h).count_inverted(x0) > 0
    return make, V, t.simplices, t.fixed, h, x0


def _loss(make, S, B, x0, w):
    def loss(V, h):
        return jnp.sum(geomopt.untangle(make(V, S, B, h), x0, progress=False).x * w)
    return loss


def _central(loss, args, k, t, step=1e-6):
    up, dn = list(args), list(args)
    up[k], dn[k] = args[k] + step * t, args[k] - step * t
    return (float(loss(*up)) - float(loss(*dn))) / (2 * step)


@pytest.mark.parametrize("kind,scale", [("tri", 1.0), ("tri", 1.1), ("tet", 1.0)])
def test_grad_of_untangle_matches_central_differences_of_eager_re_solves(kind, scale):
    make, V, S, B, h, x0 = _case(kind, scale)
    w = np.random.default_rng(1).standard_normal(x0.shape)
    loss = _loss(make, S, B, x0, w)
    g = jax.grad(loss, argnums=(0, 1))(V, h)
    gj = jax.jit(jax.grad(loss, argnums=(0, 1)))(V, h)
    rng = np.random.default_rng(2)
    for k in (0, 1):
        np.testing.assert_allclose(gj[k], g[k], rtol=1e-8, atol=1e-10 * np.abs(g[k]).max())
        t = rng.standard_normal(g[k].shape)
        fd, an = _central(loss, (V, h), k, t), float(np.sum(np.asarray(g[k]) * t))
        assert abs(an - fd) <= RTOL * abs(fd), (k, an, fd)
        # and a single coordinate (the worst case was one coordinate)
        i = np.unravel_index(np.argmax(np.abs(g[k])), g[k].shape)
        e = np.zeros(g[k].shape)
        e[i] = 1.0
        fd = _central(loss, (V, h), k, e)
        assert abs(float(g[k][i]) - fd) <= RTOL * abs(fd), (k, i, float(g[k][i]), fd)


@pytest.mark.parametrize("kind", ["tri", "tet"])
def test_eager_and_traced_untangle_return_the_same_map(kind):
    make, V, S, B, h, x0 = _case(kind, 1.0)
    eager = geomopt.untangle(make(V, S, B, h), x0, progress=False)
    assert eager.success
    traced = jax.jit(lambda V: geomopt.untangle(make(V, S, B, h), x0, progress=False).x)(V)
    np.testing.assert_allclose(np.asarray(traced), eager.x, rtol=0, atol=1e-12)


def test_the_map_is_the_minimiser_at_the_final_eps_whatever_the_path():
    """The tangled start (eps 1 -> floor) and an untangled one whose loop stops at eps = 2
    (``energy_tol=0.9``) end at the same map: the polish runs at the constant final eps."""
    from geomopt.untangling import UntangleOptions, final_eps

    make, V, S, B, h, x0 = _case("tri", 1.0)
    P = make(V, S, B, h)
    tangled = geomopt.untangle(P, x0, progress=False)
    start = generators.square_mesh(5)[0]
    short = geomopt.untangle(P, start, progress=False, options=UntangleOptions(energy_tol=0.9, eps0=2.0))
    assert tangled.success and short.success and tangled.details.polished and short.details.polished
    assert short.trace.phases[0].eps == 2.0 and short.trace.phases[-1].eps == final_eps(2)
    np.testing.assert_allclose(short.x, tangled.x, rtol=0, atol=1e-11)
    plain = geomopt.untangle(P, x0, progress=False, options=UntangleOptions(polish=False))
    assert plain.success and not plain.details.polished
    assert len(plain.trace.phases) == len(tangled.trace.phases) - 1
    with pytest.raises(geomopt.ParameterError, match="polish=True"):
        jax.grad(lambda V: jnp.sum(geomopt.untangle(make(V, S, B, h), x0, progress=False,
                                                    options=UntangleOptions(polish=False)).x))(V)


def test_auto_polish_skips_large_eager_solves_but_never_a_traced_one(monkeypatch):
    """``polish="auto"`` (the default) polishes an eager solve up to POLISH_UP_TO free
    coordinates (a Newton step at 10^6 elements costs more than the untangling), and every
    traced one whatever its size; ``polish=False`` is refused when differentiated."""
    from geomopt.untangling import driver

    make, V, S, B, h, x0 = _case("tri", 1.0)
    problem = make(V, S, B, h)
    assert geomopt.untangle(problem, x0, progress=False).details.polished
    monkeypatch.setattr(driver, "POLISH_UP_TO", 0)
    res = geomopt.untangle(problem, x0, progress=False)
    assert res.success and not res.details.polished
    forced = geomopt.untangle(problem, x0, progress=False, options=geomopt.UntangleOptions(polish=True))
    assert forced.details.polished
    w = np.random.default_rng(1).standard_normal(x0.shape)
    g = jax.grad(_loss(make, S, B, x0, w))(V, h)  # traced: polished although above the size
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0
    with pytest.raises(geomopt.ParameterError, match="polish"):
        jax.grad(lambda V: jnp.sum(geomopt.untangle(make(V, S, B, h), x0, progress=False,
                                                     options=geomopt.UntangleOptions(polish=False)).x))(V)
    with pytest.raises(geomopt.ParameterError, match="polish must be"):
        geomopt.UntangleOptions(polish="always")


def test_the_polish_pattern_and_analysis_are_built_ahead_once_and_change_nothing(monkeypatch):
    """From AHEAD_FROM free coordinates the polish's Hessian pattern and Cholesky analysis are
    built on a thread while the eps loop runs (one thread, one analysis: the polish's Newton
    finds them made); the map is the one built without the thread, bit for bit.  Nothing is
    started without the polish or below AHEAD_FROM."""
    from geomopt.linalg import linsolve
    from geomopt.untangling import continuation

    started, made = [], []
    real_ahead, real_init = continuation.ahead, linsolve.SparseCholesky.__init__

    def recording_ahead(work):
        started.append(work)
        return real_ahead(work)

    def counting_init(self, indptr, *args, **kwargs):
        made.append(len(indptr) - 1)
        return real_init(self, indptr, *args, **kwargs)

    monkeypatch.setattr(continuation, "ahead", recording_ahead)
    monkeypatch.setattr(linsolve.SparseCholesky, "__init__", counting_init)
    t = generators.rotated_interior(*generators.square_mesh(50), 90.0)
    problem = t.problem()
    assert 2 * problem.free_mask.sum() >= continuation.AHEAD_FROM
    res = geomopt.untangle(problem, t.x0, progress=False)
    assert res.success and res.details.polished
    assert len(started) == 1 and made.count(2 * int(problem.free_mask.sum())) == 1  # the polish's, once
    monkeypatch.setattr(continuation, "AHEAD_FROM", 10**9)
    plain = geomopt.untangle(problem, t.x0, progress=False)
    assert len(started) == 1 and plain.details.polished
    np.testing.assert_array_equal(res.x, plain.x)
    monkeypatch.setattr(continuation, "AHEAD_FROM", 0)
    geomopt.untangle(problem, t.x0, progress=False, options=geomopt.UntangleOptions(polish=False))
    assert len(started) == 1


def test_the_polish_tries_no_step_longer_than_newtons():
    """The polish's Newton steps near the minimum take the full step at the first trial: one
    energy evaluation a step (a doubling tried after it would cost another)."""
    from geomopt.untangling import polish_solver
    from geomopt.solvers import minimize

    make, V, S, B, h, x0 = _case("tri", 1.0)
    problem = make(V, S, B, h)
    near = geomopt.untangle(problem, x0, progress=False, options=geomopt.UntangleOptions(polish=False))
    obj = Objective(problem, "garanzha", eps=1e-9, lam=1.0 / 127.0)
    res = minimize(obj, near.x, polish_solver(), progress=False)
    assert res.success and res.stats.iterations >= 2
    assert res.stats.evaluations <= res.stats.iterations + 1, (res.stats.evaluations, res.stats.iterations)

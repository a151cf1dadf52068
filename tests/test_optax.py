"""Issue 17 item 4: the injective search as an optax line search keeps an optax loop flip-free."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import Objective, ParameterError, Problem
from geomopt.mesh.generators import tutte_nonconvex
from geomopt.solvers.linesearch import InjectiveSearch

optax = pytest.importorskip("optax")
from geomopt.optax import energy_fn, injective_linesearch, run  # noqa: E402


@pytest.fixture(scope="module")
def star():
    """A disk whose boundary is held on a star: its Dirichlet (harmonic) map folds near the
    reflex corners, and a flip-free start (the untangled Tutte map)."""
    tg = tutte_nonconvex(4, "star")
    P = Problem.planar(tg.rest, tg.simplices, tg.fixed, tg.x0[tg.fixed])
    x0 = geomopt.untangling.untangle(P, tg.x0, progress=False).x
    assert P.count_inverted(x0) == 0
    return P, x0


def _loop(opt, f, x0, P, steps=40):
    """Run ``steps`` optax updates from ``x0``; the energy and the worst exact inverted count
    seen at any iterate."""
    x, state = jnp.asarray(x0), opt.init(jnp.asarray(x0))
    vg = optax.value_and_grad_from_state(f)

    @jax.jit
    def step(x, state):
        value, grad = vg(x, state=state)
        updates, state = opt.update(grad, state, x, value=value, grad=grad, value_fn=f)
        return optax.apply_updates(x, updates), state

    worst = 0
    for _ in range(steps):
        x, state = step(x, state)
        worst = max(worst, P.count_inverted(np.asarray(x)))
    return float(f(x)), worst, np.asarray(x)


def test_plain_optax_lbfgs_folds_where_the_injective_search_does_not(star):
    P, x0 = star
    obj = Objective(P, "dirichlet")
    f = energy_fn(obj)
    e_plain, worst_plain, _ = _loop(optax.lbfgs(), f, x0, P)
    e_inj, worst_inj, x = _loop(optax.lbfgs(linesearch=injective_linesearch(obj)), f, x0, P)
    assert worst_plain > 0  # the harmonic map with this boundary folds, and plain L-BFGS finds it
    assert worst_inj == 0  # every iterate certified flip-free (exact predicate)
    assert e_inj < float(f(x0))  # and it did descend
    np.testing.assert_array_equal(x[P.fixed], P.fixed_positions)  # handles never move


def test_chained_after_sgd_is_flip_free_gradient_descent(star):
    P, x0 = star
    obj = Objective(P, "arap")
    f = energy_fn(obj)
    e, worst, _ = _loop(optax.chain(optax.sgd(1.0), injective_linesearch(obj, InjectiveSearch())), f, x0, P, 20)
    assert worst == 0 and e < float(f(x0))


def test_energy_fn_holds_handles_and_refusals(star):
    P, x0 = star
    obj = Objective(P, "dirichlet")
    g = jax.grad(energy_fn(obj))(jnp.asarray(x0))
    assert np.all(np.asarray(g)[P.fixed] == 0) and np.abs(np.asarray(g)).max() > 0
    with pytest.raises(ParameterError, match="injective=True"):
        injective_linesearch(obj, InjectiveSearch(injective=False))
    with pytest.raises(ParameterError, match="Objective"):
        injective_linesearch(P)


def test_run_is_one_compiled_loop_flip_free_and_descending(star):
    """geomopt.optax.run: every iterate certified flip-free (the run stopped after k steps is the
    k-th iterate), the energy lower, the handles in place, and one trace for every call with
    another start or step count."""
    P, x0 = star
    obj = Objective(P, "dirichlet")
    energy = energy_fn(obj)
    traces = []

    def f(x):
        traces.append(1)  # runs only while JAX traces f
        return energy(x)

    opt = optax.lbfgs(linesearch=injective_linesearch(obj))
    x, state, steps = run(opt, f, x0, max_steps=60)
    first = len(traces)
    # the harmonic map folds: the search ends where no flip-free step lowers the energy, and
    # the loop stops there (an iteration that moved nothing), well before max_steps
    assert first > 0 and 5 < steps < 60 and float(optax.tree_utils.tree_get(state, "learning_rate")) == 0.0
    for k in range(1, steps + 1):
        xk, _, run_k = run(opt, f, x0, max_steps=k)
        assert run_k == k and P.count_inverted(xk) == 0, k
    np.testing.assert_array_equal(xk, x)  # the same iterates, deterministically
    assert len(traces) == first  # no re-trace: max_steps is traced
    e = float(energy(x))
    assert e < float(energy(x0))
    np.testing.assert_array_equal(x[P.fixed], P.fixed_positions)
    x2, _, _ = run(opt, f, x, max_steps=10)  # another start: still the same program
    assert len(traces) == first and float(energy(x2)) <= e and P.count_inverted(x2) == 0
    _, _, steps = run(opt, f, x0, max_steps=10, tol=1e9)  # the gradient is below tol at once
    assert steps == 1


def test_run_refuses_bad_settings(star):
    P, x0 = star
    obj = Objective(P, "dirichlet")
    opt, f = optax.lbfgs(linesearch=injective_linesearch(obj)), energy_fn(obj)
    for bad in (-1, True, 2.5):
        with pytest.raises(ParameterError, match="max_steps"):
            run(opt, f, x0, max_steps=bad)
    with pytest.raises(ParameterError, match="tol"):
        run(opt, f, x0, tol=float("nan"))

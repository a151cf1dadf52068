"""An optax L-BFGS loop with geomopt's injective line search, beside geomopt's own L-BFGS.

On the bundled camel head (22.7k triangles, symmetric Dirichlet, from the Tutte start map that
``parameterize`` uses), per iteration, in one process:

* **optax eager**: ``optax.lbfgs(linesearch=injective_linesearch(obj))``, one Python call of
  ``opt.update`` per iteration, not jitted (what ``geomopt.optax``'s docstring showed before);
* **optax jit(step)**: the same step under ``jax.jit``, one dispatch per iteration;
* **optax run**: :func:`geomopt.optax.run`, the whole loop in one ``lax.while_loop``;
* **geomopt LBFGS**: ``geomopt.minimize(obj, x0, LBFGS(...))`` with its default Laplacian seed,
  and with the scalar seed optax's L-BFGS uses.

Every row is timed warm (its programs compiled by a first call, reported apart), wall and
process CPU seconds; the energy gap after the run is relative to Newton's optimum.  Every
iterate of the optax runs is certified flip-free at the end (exact predicate).

    python benchmarks/optax_loop.py                  # 300 iterations
    python benchmarks/optax_loop.py --steps 100 --eager-steps 3
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import optax  # noqa: E402

import geomopt  # noqa: E402
from geomopt import LBFGS, Newton, Objective, Problem  # noqa: E402
from geomopt.optax import energy_fn, injective_linesearch, run  # noqa: E402
from geomopt.param import start_map  # noqa: E402


def clocks():
    return time.perf_counter(), time.process_time()


def since(t):
    w, c = clocks()
    return w - t[0], c - t[1]


def optax_step(opt, f):
    vg = optax.value_and_grad_from_state(f)

    def step(x, state):
        value, grad = vg(x, state=state)
        updates, state = opt.update(grad, state, x, value=value, grad=grad, value_fn=f)
        return optax.apply_updates(x, updates), state

    return step


def loop(step, x, state, n):
    for _ in range(n):
        x, state = step(x, state)
    return jax.block_until_ready(x), state


def time_steps(step, x0, opt, n):
    """(first call s, (wall, cpu) per iteration over n more, final x)."""
    x, state = jax.numpy.asarray(x0), opt.init(jax.numpy.asarray(x0))
    t = clocks()
    x, state = loop(step, x, state, 1)
    first = since(t)[0]
    t = clocks()
    x, state = loop(step, x, state, n)
    wall, cpu = since(t)
    return first, (wall / n, cpu / n), n + 1, np.asarray(x)


def time_run(opt, f, x0, n):
    t = clocks()
    run(opt, f, x0, max_steps=1)
    first = since(t)[0]
    t = clocks()
    x, _, steps = run(opt, f, x0, max_steps=n)
    wall, cpu = since(t)
    return first, (wall / steps, cpu / steps), steps, x


def time_geomopt(obj, x0, solver):
    t = clocks()
    geomopt.minimize(obj, x0, solver, progress=False)
    first = since(t)[0]
    t = clocks()
    r = geomopt.minimize(obj, x0, solver, progress=False)
    wall, cpu = since(t)
    it = max(r.stats.iterations, 1)
    return first, (r.stats.seconds / it, cpu / it), r.stats.iterations, r.x


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--eager-steps", type=int, default=5)
    args = ap.parse_args()
    warnings.simplefilter("ignore", geomopt.MaxStepsWarning)
    V, F = geomopt.data.load("camelhead")
    problem = Problem.surface(V, F)
    obj = Objective(problem, "symmetric_dirichlet")
    x0 = start_map(obj)[0]
    f = energy_fn(obj)
    opt = optax.lbfgs(linesearch=injective_linesearch(obj))
    best = geomopt.minimize(obj, x0, Newton(rtol=1e-12), progress=False).energy
    print(f"camelhead: {len(F)} triangles; load average before {os.getloadavg()}")
    step = optax_step(opt, f)
    n = args.steps
    rows = {
        "optax eager": time_steps(step, x0, opt, args.eager_steps),
        "optax jit(step)": time_steps(jax.jit(step), x0, opt, n),
        "optax run (while_loop)": time_run(opt, f, x0, n),
        "geomopt LBFGS (laplacian)": time_geomopt(obj, x0, LBFGS(max_steps=n, rtol=0.0, gtol=0.0)),
        "geomopt LBFGS (scalar)": time_geomopt(obj, x0, LBFGS(max_steps=n, rtol=0.0, gtol=0.0,
                                                             precondition="scalar")),
    }
    ref = rows["geomopt LBFGS (laplacian)"][1][0]
    print(f"{'':>27} {'iters':>6} {'first s':>8} {'wall s/it':>10} {'cpu s/it':>9} {'x geomopt':>9} "
          f"{'energy gap':>10} {'flips':>5}")
    for name, (first, (wall, cpu), iters, x) in rows.items():
        gap = (float(obj.value(x, obj.params())) - best) / best
        flips = problem.count_inverted(x)
        print(f"{name:>27} {iters:6d} {first:8.2f} {wall:10.4f} {cpu:9.4f} {wall / ref:9.2f} {gap:10.2e} {flips:5d}")
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()

"""Cost of differentiating through a converged solve, and of the composable mesh energy.

Usage::

    python benchmarks/implicit.py [--repeat 3] [--tets 50000] [--triangles 1000000] [--only vjp|energy]

Prints one JSON object per line:

* ``vjp`` rows (camelhead parameterized with a free boundary, and a box of about ``--tets``
  tetrahedra whose boundary handles are twisted by 30 degrees, symmetric Dirichlet, projected
  Newton): ``newton_iter_s`` the median time of one iteration of the forward solve (its
  ``time_history``), ``forward_s`` the differentiable forward (solve + refining Newton step),
  ``solve_s`` the plain solve (``geomopt.parameterize`` / ``geomopt.minimize``), ``vjp_s`` one
  VJP (``jax.vjp``'s pullback applied to a cotangent: adjoint solve + JAX pullback), with
  ``vjp_refactor_s`` the same plus assembling and factoring the exact Hessian at the map (where
  the forward's factorization cannot be reused: done by the forward-mode rule, timed here
  directly), ``vjp_after_other_solve_s`` the
  same after another solve of the mesh refactored the shared numeric factor (the adjoint
  refactors the matrix its forward kept), and the ratios to
  ``newton_iter_s``; medians of ``--repeat`` warm runs.
* ``energy`` row: energy + gradient of ``--triangles`` triangles (symmetric Dirichlet), median
  of 20 warm calls: ``kernel_s`` today's ``Objective.value_and_grad`` kernel,
  ``jit_grad_s`` a user's ``jax.jit(jax.grad(lambda x: objective.value(x, p)))``,
  ``jit_value_and_grad_s`` ``jax.jit(jax.value_and_grad(...))``, both ratios, CPU seconds too.

Timings on a shared machine are noisy: compare ratios from the same run, and quote ``load``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import geomopt  # noqa: E402
from geomopt import Objective, Problem  # noqa: E402
from geomopt.objective.adjoint import AdjointSystem  # noqa: E402
from geomopt.param import parameterize_map  # noqa: E402
from geomopt.solvers import minimize_map  # noqa: E402
from geomopt.mesh import generators as G  # noqa: E402
from geomopt.exact.topology import boundary_vertices  # noqa: E402


def _median_time(f, repeat):
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(f())
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def _cpu_and_wall(f, repeat):
    f()
    w, c = [], []
    for _ in range(repeat):
        t, p = time.perf_counter(), time.process_time()
        jax.block_until_ready(f())
        w.append(time.perf_counter() - t)
        c.append(time.process_time() - p)
    return statistics.median(w), statistics.median(c)


def _vjp_row(name, plain, differentiable, args, repeat):
    """Time the plain solve, the differentiable forward and one VJP (reused and refactored)."""
    res = plain()
    newton = float(np.median(np.diff(res.time_history)))
    loss = lambda *a: jnp.sum(differentiable(*a) ** 2)  # noqa: E731
    jax.vjp(loss, *args)[1](1.0)  # compile everything
    fwd, vjp, vjp2, vjp3 = [], [], [], []
    for _ in range(repeat):
        t = time.perf_counter()
        _, pull = jax.vjp(loss, *args)
        fwd.append(time.perf_counter() - t)
        t = time.perf_counter()
        jax.block_until_ready(pull(1.0))
        vjp.append(time.perf_counter() - t)
        jax.vjp(loss, *args)  # another solve of the mesh: it refactors the shared numeric factor
        t = time.perf_counter()
        jax.block_until_ready(pull(1.0))
        vjp3.append(time.perf_counter() - t)
        t = time.perf_counter()
        AdjointSystem(res.objective, {}, np.asarray(res.x), check=False)
        vjp2.append(time.perf_counter() - t + vjp[-1])
    solve = _median_time(plain, repeat)
    m = statistics.median
    return {"case": name, "elements": res.objective.problem.n_elements, "newton_iters": res.stats.iterations, "newton_iter_s": newton, "solve_s": solve,
            "forward_s": m(fwd), "vjp_s": m(vjp), "vjp_refactor_s": m(vjp2),
            "vjp_after_other_solve_s": m(vjp3), "vjp_after_other_solve_over_newton_iter": m(vjp3) / newton,
            "vjp_over_newton_iter": m(vjp) / newton, "vjp_refactor_over_newton_iter": m(vjp2) / newton,
            "load": os.getloadavg()[0]}


def camelhead(repeat):
    V, F = geomopt.io.read_mesh(os.path.join(os.path.dirname(geomopt.__file__), "data", "camelhead.off"))
    return _vjp_row("camelhead", lambda: geomopt.parameterize(V, F, progress=False),
                    lambda V: parameterize_map(V, F), (jnp.asarray(V),), repeat)


def twisted_box(tets, repeat):
    n = max(2, round((tets / 6 / 2) ** (1 / 3)))
    V, T = G.box_mesh(n, n, 2 * n, size=(1.0, 1.0, 2.0))
    B = boundary_vertices(T, len(V))
    a = np.deg2rad(30.0) * V[:, 2] / 2.0
    c, s = np.cos(a), np.sin(a)
    X = np.stack([0.5 + c * (V[:, 0] - 0.5) - s * (V[:, 1] - 0.5),
                  0.5 + s * (V[:, 0] - 0.5) + c * (V[:, 1] - 0.5), V[:, 2]], 1)
    obj = Objective(Problem.tets(V, T, B, X[B]), "symmetric_dirichlet")

    def plain():
        return geomopt.minimize(obj, X, progress=False)

    return _vjp_row(f"twisted box {len(T)} tets", plain,
                    lambda h: minimize_map(Objective(Problem.tets(V, T, B, h), "symmetric_dirichlet"), X),
                    (jnp.asarray(X[B]),), repeat)


def energy(triangles, repeat):
    from geomopt.objective.objective import value_and_grad_kernel

    n = max(2, round((triangles / 2) ** 0.5)) + 1
    V, F = G.square_mesh(n)
    obj = Objective(Problem.planar(V, F), "symmetric_dirichlet")
    x = jax.device_put(V + 0.0)
    p = obj.params()
    k = lambda: value_and_grad_kernel(obj.energy.density, obj.grad_chunk, obj.geom, obj.free_mask, x, p)  # noqa: E731
    g = jax.jit(jax.grad(lambda x: obj.value(x, p)))
    vg = jax.jit(jax.value_and_grad(lambda x: obj.value(x, p)))
    kw, kc = _cpu_and_wall(k, 20)
    gw, gc = _cpu_and_wall(lambda: g(x), 20)
    vw, vc = _cpu_and_wall(lambda: vg(x), 20)
    return {"case": "energy", "triangles": len(F), "kernel_s": kw, "jit_grad_s": gw, "jit_value_and_grad_s": vw,
            "jit_grad_over_kernel": gw / kw, "jit_value_and_grad_over_kernel": vw / kw,
            "kernel_cpu_s": kc, "jit_grad_cpu_s": gc, "jit_value_and_grad_cpu_s": vc,
            "load": os.getloadavg()[0]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tets", type=int, default=50_000)
    ap.add_argument("--triangles", type=int, default=1_000_000)
    ap.add_argument("--only", choices=["vjp", "energy"])
    args = ap.parse_args(argv)
    if args.only != "energy":
        print(json.dumps(camelhead(args.repeat)), flush=True)
        print(json.dumps(twisted_box(args.tets, args.repeat)), flush=True)
    if args.only != "vjp":
        print(json.dumps(energy(args.triangles, args.repeat)), flush=True)


if __name__ == "__main__":
    main()

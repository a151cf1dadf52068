"""Scale benchmark: energy, gradient, Hessian, pattern and Newton iterations on big meshes.

Usage::

    python benchmarks/scale.py --elements 1e4 1e5 1e6 --dim 2 3 [--repeat 10] [--cg]
                               [--no-direct] [--untangle] [--json out.jsonl]

Every (elements, dim) configuration runs in a fresh Python process, so that its peak memory
(``ru_maxrss``) is its own, and prints one JSON object per line on stdout with the keys

* ``elements, dim, device``: the mesh (a triangulated square grid in 2D, a Kuhn box of 6 tets
  per cube in 3D, boundary fixed, interior displaced by a smooth injective swirl) and JAX's
  default device;
* ``energy_grad_s``: median of ``--repeat`` warm jitted energy + gradient evaluations;
* ``hessian_s``: median of 3 warm evaluations of energy, gradient and the assembled projected
  (clamp) Hessian data (device to host copy included);
* ``pattern_s``: median of 3 builds of the CSC Hessian pattern;
* ``newton_iter_s``: median of 3 projected-Newton iterations with the direct solver
  (``geomopt.solvers.Newton(projection="clamp")``: Hessian, factorization by
  ``SparseCholesky``, solve, injective line search), omitted with ``--no-direct``;
* ``peak_mem_mb``: ``ru_maxrss`` of the process at the end.

and extra keys: ``vertices, dofs, nnz, setup_s`` (mesh and ``Problem``), ``compile_s`` (first
energy + gradient + Hessian calls), ``factor_s, solve_s, linesearch_s`` (parts of the direct
iteration, medians), with ``--cg`` ``cg_iter_s`` (median Newton iteration with the CG direction
of ``geomopt._cg`` and the same line search), ``cg_iters`` (CG iterations of that direction),
``cg_direct_rel`` (relative difference of the two directions; with ``--no-direct`` absent), and
with ``--untangle`` ``untangle_outer_s`` / ``untangle_setup_s`` / ``untangle_inner`` (one outer
iteration of :func:`geomopt.untangle.untangle` on the same mesh with its interior rotated by 90
degrees in 2D, a box twisted by a quarter turn in 3D) and ``untangle_peak_mem_mb``.

Timings on a shared machine are noisy: the medians are still only indicative.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import numpy as np


def _mesh(elements: int, dim: int):
    """(V, S): about ``elements`` triangles (2D grid) or tets (3D Kuhn box)."""
    from geomopt import generators as G

    if dim == 2:
        n = max(2, int(round(np.sqrt(elements / 2.0))) + 1)
        return G.square_mesh(n)
    k = max(1, int(round((elements / 6.0) ** (1.0 / 3.0))))
    return G.box_mesh(k, k, k)


def _swirl(V):
    """A smooth displacement vanishing on the unit box boundary; its gradient stays below 0.25,
    so the map ``V + u`` is injective."""
    s = np.prod(np.sin(np.pi * V), axis=1)
    u = np.stack([np.sin(2 * np.pi * V[:, (i + 1) % V.shape[1]]) for i in range(V.shape[1])], 1)
    return V + 0.05 * s[:, None] * u


CPU = {}  # key -> median CPU seconds (process time, all threads) of the last timing of key


def _median(f, repeat, key=None):
    """Median wall seconds of ``repeat`` calls of ``f`` and the last result; the median CPU
    seconds go to ``CPU[key]`` (on a loaded machine they are the steadier number)."""
    ts, cs = [], []
    out = None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = f()
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    if key:
        CPU[key] = statistics.median(cs)
    return statistics.median(ts), out


def _peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_one(elements: int, dim: int, repeat: int, cg: bool, direct: bool, untangle: bool):
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from geomopt import generators as G
    from geomopt._objective import Objective, hessian_pattern
    from geomopt.linsolve import SparseCholesky
    from geomopt.problem import Problem
    from geomopt.solvers import Newton

    out = {"elements": None, "dim": dim, "device": str(jax.devices()[0].platform)}
    t = time.perf_counter()
    V, S = _mesh(elements, dim)
    fixed = G.boundary_vertices(S, len(V))
    P = (Problem.planar if dim == 2 else Problem.tets)(V, S, fixed, V[fixed])
    out["setup_s"] = time.perf_counter() - t
    out["elements"], out["vertices"] = int(len(S)), int(len(V))
    obj = Objective(P, "symmetric_dirichlet")
    params = obj.params()
    x = jnp.asarray(_swirl(V))
    assert bool((obj.dets(x) > 0).all()), "the benchmark map must be injective"

    out["pattern_s"], pat = _median(lambda: hessian_pattern(P, obj.free_dofs), 3, "pattern_s")
    out["dofs"], out["nnz"] = pat.n, pat.nnz

    t = time.perf_counter()
    jax.block_until_ready(obj.value_and_grad(x, params))
    jax.block_until_ready(obj.hessian(x, params, "clamp"))
    out["compile_s"] = time.perf_counter() - t
    out["energy_grad_s"], _ = _median(lambda: jax.block_until_ready(obj.value_and_grad(x, params)),
                                      repeat, "energy_grad_s")
    out["hessian_s"], (_, grad, data) = _median(
        lambda: tuple(np.array(a) for a in obj.hessian(x, params, "clamp")), 3, "hessian_s")

    g = grad.reshape(-1)[pat.free_dofs]
    d_direct = None
    if direct:
        chol = SparseCholesky(pat.indptr, pat.indices)
        chol.analyze()
        out["factor_s"], _ = _median(lambda: chol.factor(data), 3, "factor_s")
        out["solve_s"], d_direct = _median(lambda: -chol.solve(g), 3, "solve_s")
        newton = Newton(projection="clamp")
        state = newton.init(obj, x, params)
        dx = np.zeros(x.size)
        dx[pat.free_dofs] = d_direct
        dx = jnp.asarray(dx.reshape(x.shape))
        value = float(obj.value(x, params))
        out["linesearch_s"], _ = _median(
            lambda: newton.line_search(obj, params, x, value, jnp.asarray(grad), dx), 3, "linesearch_s")
        out["direct_iter_s"], _ = _median(lambda: newton.step(state), 3, "direct_iter_s")
    if cg:
        from geomopt._cg import NewtonCG

        newton = Newton(projection="clamp")
        for key, solver in (("cg", NewtonCG()), ("cg_tight", NewtonCG(rtol=1e-8))):
            op = solver.prepare(obj)
            step = lambda: jax.block_until_ready(solver.direction(op, obj, x, params, "clamp"))  # noqa: E731
            step()
            out[f"{key}_step_s"], (dcg, info) = _median(step, 3, f"{key}_step_s")
            out[f"{key}_iters"] = int(info.iterations)

            def cg_iter():
                dcg, info = solver.direction(op, obj, x, params, "clamp")
                return newton.line_search(obj, params, x, float(info.value), info.grad, dcg)

            out[f"{key}_iter_s"], _ = _median(cg_iter, 3, f"{key}_iter_s")
            if d_direct is not None:
                dc = np.asarray(dcg).reshape(-1)[pat.free_dofs]
                out[f"{key}_direct_rel"] = float(np.linalg.norm(dc - d_direct) / np.linalg.norm(d_direct))
    out.update({k[:-2] + "_cpu_s": v for k, v in CPU.items()})
    iters = [out[k] for k in ("direct_iter_s", "cg_iter_s") if k in out]
    if iters:
        out["newton_iter_s"] = min(iters)
    out["peak_mem_mb"] = round(_peak_mb(), 1)
    if untangle:
        from geomopt.untangle import untangle as run_untangle

        tangle = G.rotated_interior(V, S, 90.0) if dim == 2 else \
            G.Tangle("twist", V, S, _twist(V, fixed), fixed)
        res = run_untangle(tangle.problem(), tangle.x0, max_outer=1, progress=False)
        out["untangle_outer_s"] = res.seconds
        out["untangle_setup_s"] = res.setup_seconds
        out["untangle_inner"] = int(res.inner_iterations)
        out["untangle_inverted"] = [int(res.initially_inverted), int(res.inverted)]
        out["untangle_peak_mem_mb"] = round(_peak_mb(), 1)
    return {k: (round(v, 4) if isinstance(v, float) and k != "peak_mem_mb" else v) for k, v in out.items()}


def _twist(V, fixed):
    """The unit box with its boundary turned by a quarter turn about z, increasing with z; the
    interior stays at rest (tangled near the top)."""
    x0 = V.copy()
    a = 0.5 * np.pi * V[fixed, 2]
    c = V[fixed, :2] - 0.5
    x0[fixed, 0] = 0.5 + np.cos(a) * c[:, 0] - np.sin(a) * c[:, 1]
    x0[fixed, 1] = 0.5 + np.sin(a) * c[:, 0] + np.cos(a) * c[:, 1]
    return x0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--elements", type=float, nargs="+", default=[1e4, 1e5, 1e6])
    ap.add_argument("--dim", type=int, nargs="+", default=[2, 3], choices=(2, 3))
    ap.add_argument("--repeat", type=int, default=10, help="warm energy + gradient runs (median)")
    ap.add_argument("--cg", action="store_true", help="also time the CG Newton direction")
    ap.add_argument("--no-direct", action="store_true", help="skip the direct (Cholesky) Newton step")
    ap.add_argument("--untangle", action="store_true", help="also time one untangling outer iteration")
    ap.add_argument("--json", help="append the JSON lines to this file too")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        res = run_one(int(a.elements[0]), a.dim[0], a.repeat, a.cg, not a.no_direct, a.untangle)
        print(json.dumps(res), flush=True)
        return 0
    status = 0
    for dim in a.dim:
        for n in a.elements:
            cmd = [sys.executable, __file__, "--one", "--elements", str(int(n)), "--dim", str(dim),
                   "--repeat", str(a.repeat)] + ["--cg"] * a.cg + ["--no-direct"] * a.no_direct \
                + ["--untangle"] * a.untangle
            proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
            line = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
            if proc.returncode or not line.startswith("{"):
                status = 1
                line = json.dumps({"elements": int(n), "dim": dim, "error": f"exit status {proc.returncode}"})
            print(line, flush=True)
            if a.json:
                with open(a.json, "a") as f:
                    f.write(line + "\n")
    return status


if __name__ == "__main__":
    sys.exit(main())

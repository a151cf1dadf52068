"""Scale benchmark: energy, gradient, Hessian, pattern and Newton iterations on big meshes.

Usage::

    python benchmarks/scale.py --elements 1e4 1e5 1e6 --dim 2 3 [--repeat 10] [--cg]
                               [--no-direct] [--solve] [--untangle] [--json out.jsonl]
    python benchmarks/scale.py --mesh ../shared/data/meshes/camelhead.off --cg --solve

Every configuration runs in a fresh Python process, so that its peak memory (``ru_maxrss``)
is its own, and prints one JSON object per line on stdout with the keys

* ``elements, dim, device``: the mesh (a triangulated square grid in 2D, a Kuhn box of 6 tets
  per cube in 3D, boundary fixed, interior displaced by a smooth injective swirl; or with
  ``--mesh`` a surface parameterized with a free boundary from a Tutte map) and JAX's device;
* ``energy_grad_s``: median of ``--repeat`` warm jitted energy + gradient evaluations;
* ``hessian_s``: median of 3 warm evaluations of energy, gradient and the assembled projected
  (clamp) Hessian data, copied to the host;
* ``pattern_s``: median of 3 builds of the CSC Hessian pattern;
* ``newton_iter_s``: one iteration of ``geomopt.solvers.Newton(projection="clamp")`` (its
  ``step``: Hessian, direction, injective line search, stopping test) with the linear solver
  that ``linear_solver="auto"`` picks here (``newton_pick``,
  :func:`geomopt.linalg.linsolve.newton_linear_solver`): ``direct_iter_s`` (the fastest installed
  Cholesky, PARDISO; skipped with ``--no-direct``) or ``cg_iter_s`` (``--cg``:
  ``linear_solver="cg"``); the median of 3 iterations after the first, which is what a user
  pays per iteration; when the pick was not measured, the faster of the two;
* ``peak_mem_mb``: ``ru_maxrss`` of the process after these (before ``--solve``).

Extra keys: ``vertices, dofs, nnz, setup_s`` (mesh and ``Problem``), ``compile_s`` (first
energy + gradient + Hessian calls), ``analyze_s`` (the Cholesky's symbolic analysis, once per
mesh), ``direct_init_s`` / ``cg_init_s`` (``Newton.init``: the mesh's analysis, done here
before the factorization timings and shared, or the CG operator; ahead of time compilation
from the warm in-process cache), ``*_first_iter_s`` (the first iteration
after ``init``), ``factor_s, solve_s, linesearch_s`` (parts of the direct iteration); with
``--cg``: ``cg_step_s, cg_iters`` (the CG direction alone with Newton's forcing term),
``cg_tight_*`` (the same with ``rtol=1e-8``), ``*_direct_rel`` (relative distance to the direct
step); ``*_cpu_s``: median CPU seconds (all threads) of each timing, steadier than wall time
on a loaded machine; with ``--solve``: ``direct_*`` / ``cg_*`` ``solve_s, newton_iters,
energy, outcome`` (projected Newton to convergence, second run; ``direct_*`` factors every
iteration, ``reuse_factor=False``; ``reuse_*``: ``Newton(reuse_factor=True)``).  ``--untangle`` measures
instead, alone in the process: ``untangle_outer_s, untangle_setup_s, untangle_cpu_s,
untangle_inner, untangle_inverted`` (before, after) and ``untangle_peak_mem_mb`` for one
outer iteration of :func:`geomopt.untangling.untangle` (its default solver) on the mesh with
its interior rotated by 90 degrees in 2D, the box's boundary twisted by a quarter turn in 3D.
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
    from geomopt.mesh import generators as G

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


def run_solves(obj, x0):
    """Projected Newton (clamp) to convergence with the direct direction, the direct one
    with ``reuse_factor`` (CG preconditioned by the factorization held, refactoring only when
    that costs more) and the CG direction: warm seconds (the second of two runs), Newton
    iterations, final energy."""
    import geomopt
    from geomopt.linalg.linsolve import available_backends
    from geomopt.solvers import Newton

    out = {}
    backend = available_backends()[0]
    for key, solver in (("direct", Newton(projection="clamp", linear_solver=backend, reuse_factor=False)),
                        ("reuse", Newton(projection="clamp", linear_solver=backend, reuse_factor=True)),
                        ("cg", Newton(projection="clamp", linear_solver="cg"))):
        for _ in range(2):  # the first run compiles
            c = time.process_time()
            res = geomopt.minimize(obj, x0, solver, progress=False)
            cpu = time.process_time() - c
        out[f"{key}_solve_s"] = round(res.stats.seconds, 3)
        out[f"{key}_solve_cpu_s"] = round(cpu, 3)
        out[f"{key}_newton_iters"] = int(res.stats.iterations)
        out[f"{key}_energy"] = float(res.energy) / obj.total_volume
        out[f"{key}_outcome"] = res.outcome.value
    return out


def run_one(elements: int, dim: int, repeat: int, cg: bool, direct: bool, untangle: bool,
            solve: bool = False, mesh: str | None = None):
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from geomopt.mesh import generators as G
    from geomopt.objective.objective import Objective, hessian_pattern
    from geomopt.linalg.linsolve import available_backends, newton_linear_solver
    from geomopt.mesh.problem import Problem
    from geomopt.solvers import Newton

    out = {"elements": None, "dim": dim, "device": str(jax.devices()[0].platform)}
    t = time.perf_counter()
    if mesh:  # a surface to parameterize: free boundary, Tutte start (as benchmarks/param.py)
        from geomopt.io import read_mesh
        from param import start_map

        V, S = read_mesh(mesh)[:2]
        P = Problem.surface(V, S)
        out["mesh"] = mesh
    else:
        V, S = _mesh(elements, dim)
        fixed = G.boundary_vertices(S, len(V))
        P = (Problem.planar if dim == 2 else Problem.tets)(V, S, fixed, V[fixed])
    out["setup_s"] = time.perf_counter() - t
    out["elements"], out["vertices"] = int(len(S)), int(len(V))
    if untangle:  # alone in its process, so that the peak memory is its own
        return _round(dict(out, **run_untangle_outer(V, S, fixed)))
    obj = Objective(P, "symmetric_dirichlet")
    params = obj.params()
    x = jnp.asarray(start_map(obj, V, S)[0] if mesh else _swirl(V))
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
    # Newton's relative diagonal shift, so that the direct and CG steps solve one system
    data[pat.diag] += Newton.regularization * np.mean(np.abs(data[pat.diag]))
    d_direct = None
    if direct:
        # the mesh's analysis (once per mesh), which Newton shares: no second PARDISO instance
        out["analyze_s"], chol = _median(lambda: obj.cholesky(available_backends()[0]), 1, "analyze_s")
        out["factor_s"], _ = _median(lambda: chol.factor(data), 3, "factor_s")
        out["solve_s"], d_direct = _median(lambda: -chol.solve(g), 3, "solve_s")
        newton = Newton(projection="clamp", linear_solver=available_backends()[0], reuse_factor=False)
        out["direct_init_s"], state = _median(lambda: newton.init(obj, x, params), 1, "direct_init_s")
        dx = np.zeros(x.size)
        dx[pat.free_dofs] = d_direct
        dx = jnp.asarray(dx.reshape(x.shape))
        value = float(obj.value(x, params))
        out["linesearch_s"], _ = _median(
            lambda: newton.search(obj, params, x, value, jnp.asarray(grad), dx), 3, "linesearch_s")
        out["direct_first_iter_s"], _ = _median(lambda: newton.step(state), 1, "direct_first_iter_s")
        out["direct_iter_s"], _ = _median(lambda: newton.step(state), 3, "direct_iter_s")
    if cg:
        from geomopt.objective.cg import NewtonCG

        newton = Newton(projection="clamp", linear_solver="cg")
        out["cg_init_s"], state = _median(lambda: newton.init(obj, x, params), 1, "cg_init_s")
        out["cg_first_iter_s"], _ = _median(lambda: newton.step(state), 1, "cg_first_iter_s")
        out["cg_iter_s"], _ = _median(lambda: newton.step(state), 3, "cg_iter_s")
        # the direction alone, with Newton's forcing term (from the first gradient norm, as
        # in a solve) and with a tight tolerance
        gref = state.memory.grad_ref
        for key, solver in (("cg", newton.cg), ("cg_tight", NewtonCG(rtol=1e-8))):
            op = state.memory.cg_op
            step = lambda: jax.block_until_ready(  # noqa: E731
                solver.direction(op, obj, x, params, "clamp", newton.regularization, gref))
            step()
            out[f"{key}_step_s"], (dcg, info) = _median(step, 3, f"{key}_step_s")
            out[f"{key}_iters"] = int(info.iterations)
            if d_direct is not None:
                dc = np.asarray(dcg).reshape(-1)[pat.free_dofs]
                out[f"{key}_direct_rel"] = float(np.linalg.norm(dc - d_direct) / np.linalg.norm(d_direct))
    out.update({k[:-2] + "_cpu_s": v for k, v in CPU.items()})
    out["newton_pick"] = newton_linear_solver(dim, pat.n, out["device"])
    pick = "cg_iter_s" if out["newton_pick"] == "cg" else "direct_iter_s"
    iters = [out[k] for k in ("direct_iter_s", "cg_iter_s") if k in out]
    if pick in out:
        out["newton_iter_s"] = out[pick]
    elif iters:
        out["newton_iter_s"] = min(iters)
    out["peak_mem_mb"] = round(_peak_mb(), 1)
    if solve:
        out.update(run_solves(obj, np.asarray(x)))
    return _round(out)


def _round(out):
    return {k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in out.items()}


def run_untangle_outer(V, S, fixed):
    """One outer iteration of :func:`geomopt.untangling.untangle` (default solver) on the mesh
    with its interior rotated by 90 degrees (2D) or its boundary twisted (3D)."""
    from geomopt.mesh import generators as G
    from geomopt.untangling import UntangleOptions, untangle

    tangle = G.rotated_interior(V, S, 90.0) if V.shape[1] == 2 else \
        G.Tangle("twist", V, S, _twist(V, fixed), fixed)
    c = time.process_time()
    res = untangle(tangle.problem(), tangle.x0, options=UntangleOptions(max_outer=1), progress=False)
    return {"untangle_outer_s": res.stats.seconds, "untangle_setup_s": res.stats.setup_seconds,
            "untangle_cpu_s": time.process_time() - c, "untangle_inner": int(res.stats.iterations),
            "untangle_inverted": [int(res.stats.inverted_at_start), int(res.certificate.inverted)],
            "untangle_solver": type(res.solver).__name__,
            "untangle_peak_mem_mb": round(_peak_mb(), 1)}


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
    ap.add_argument("--untangle", action="store_true",
                    help="time one untangling outer iteration instead (alone in its process)")
    ap.add_argument("--solve", action="store_true",
                    help="also solve to convergence with the direct and the CG direction")
    ap.add_argument("--mesh", nargs="+", default=[],
                    help="surface meshes to parameterize instead of the generated grids")
    ap.add_argument("--json", help="append the JSON lines to this file too")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.mesh and a.untangle:
        ap.error("--untangle uses the generated meshes (their boundary is the handle set), not --mesh")
    if a.one:
        res = run_one(int(a.elements[0]), a.dim[0], a.repeat, a.cg, not a.no_direct, a.untangle,
                      a.solve, a.mesh[0] if a.mesh else None)
        print(json.dumps(res), flush=True)
        return 0
    status = 0
    configs = [(n, dim, None) for dim in a.dim for n in a.elements] if not a.mesh else \
        [(0, 2, m) for m in a.mesh]
    for n, dim, mesh in configs:
        cmd = [sys.executable, __file__, "--one", "--elements", str(int(n)), "--dim", str(dim),
               "--repeat", str(a.repeat)] + ["--cg"] * a.cg + ["--no-direct"] * a.no_direct \
            + ["--untangle"] * a.untangle + ["--solve"] * a.solve + (["--mesh", mesh] if mesh else [])
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

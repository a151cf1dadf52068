"""The first minute: the whole ``geomopt param`` process against libigl's SLIM, per mesh.

For every mesh in ``../shared/data/meshes`` (or ``--meshes``):

* **cold**: ``python -m geomopt param MESH -o OUT --json --quiet`` with an empty persistent
  cache folder (``GEOMOPT_CACHE_DIR``): start-up, JAX compilation, solve, write, the whole
  process, timed from outside (wall seconds);
* **warm**: the same command again (the cache now holds its kernels);
* **sibling**: a *different* mesh of the same size bucket (the mesh less a few boundary ear
  triangles, so different vertex, face and Hessian counts), same warm cache: what a user
  meets on a new mesh of a similar size.  Its cache misses (programs compiled) are reported;
* **SLIM**: libigl's ``slim_precompute`` + ``slim_solve(data, 1)`` from the same start map
  (uniform Tutte, centred, scaled to the rest area, optimal scale: what ``parameterize``
  does), until its mean symmetric Dirichlet energy is within each ``--rtols`` of what the cold
  geomopt process reached (or ``--slim-seconds`` pass); the ratios use the last ``--rtols``
  value (default 1e-6, as DESIGN.md's "reach the converged energy").  SLIM's time counts
  ``slim_precompute`` and its iterations, not its process start-up.

Also timed: ``geomopt --help`` (median of 7 processes), and, when scikit-sparse's CHOLMOD is
importable, the Newton seconds per iteration with the default linear solver against CHOLMOD
(warm kernels, same process).

    python benchmarks/startup.py                      # every mesh (igea_cut: SLIM capped)
    python benchmarks/startup.py --meshes camelhead face --json out.json

Needs libigl (``pip install ".[bench]"``).  Wall times on a shared machine are noisy: the
script reports the medians of ``--repeat`` warm and sibling runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MESH_DIR = REPO.parent / "shared/data/meshes"
MESH_EXTS = (".obj", ".off", ".ply", ".stl")


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_cli(args, cache):
    """(wall seconds, CPU seconds (user + sys, all threads), --json summary) of one
    ``python -m geomopt`` process.  On a shared machine CPU time is the steadier measure."""
    env = {**os.environ, "GEOMOPT_CACHE_DIR": str(cache), "PYTHONPATH": str(REPO)}
    c0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "geomopt", *map(str, args)], capture_output=True,
                          text=True, env=env)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if proc.returncode != 0:
        raise RuntimeError(f"geomopt {' '.join(map(str, args))} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return wall, cpu, json.loads(proc.stdout.strip().splitlines()[-1])


def help_seconds(n=7):
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "geomopt", "--help"], capture_output=True,
                       env={**os.environ, "PYTHONPATH": str(REPO)}, check=True)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def sibling(V, F, remove=3):
    """The mesh less ``remove`` boundary ears (a boundary vertex used by one triangle only,
    removed with its triangle): still a disk, with different n, m and Hessian size."""
    for _ in range(remove):
        counts = np.bincount(F.ravel(), minlength=len(V))
        ears = np.flatnonzero(counts == 1)
        if not ears.size:
            break
        v = ears[0]
        F = F[~(F == v).any(axis=1)]
        keep = np.ones(len(V), bool)
        keep[v] = False
        V, F = V[keep], (np.cumsum(keep) - 1)[F]
    return V, F


def same_bucket(A, B):
    from geomopt import Objective, Problem
    from geomopt._runtime.padding import power_bucket

    oa, ob = (Objective(Problem.surface(*M), "symmetric_dirichlet", buckets=True) for M in (A, B))
    return (oa.sizes.n_padded, oa.sizes.m_padded, power_bucket(oa.pattern.nnz)) == \
        (ob.sizes.n_padded, ob.sizes.m_padded, power_bucket(ob.pattern.nnz))


def start_map(V, F):
    """What parameterize starts from: uniform Tutte, centred, rest area, optimal scale."""
    from geomopt import Objective, Problem
    from geomopt.param import _to_rest_area, optimal_scale
    from geomopt.mesh.tutte import tutte_embedding

    problem = Problem.surface(V, F)
    objective = Objective(problem, "symmetric_dirichlet", buckets=True)
    x0 = _to_rest_area(problem, tutte_embedding(V, F, "uniform"))
    return optimal_scale(objective, x0) * x0, objective


def slim_to(V, F, x0, objective, targets, seconds):
    """libigl SLIM from ``x0`` until its mean energy is <= every one of ``targets``: the
    (wall, CPU) seconds incl. precompute at which each target was first reached (None: not
    within ``seconds`` of wall time), iterations, mean energy reached, precompute seconds.
    The energy evaluations between iterations are not counted."""
    import igl

    params = objective.params()
    area = objective.total_volume
    t0, c0 = time.perf_counter(), time.process_time()
    data = igl.slim_precompute(np.asfortranarray(V, dtype=np.float64), np.asfortranarray(F, dtype=np.int32),
                               np.asfortranarray(x0, dtype=np.float64), igl.MappingEnergyType.SYMMETRIC_DIRICHLET,
                               np.array([], dtype=np.int32), np.zeros((0, 2), order="F"), 0.0)
    pre = time.perf_counter() - t0
    elapsed, cpu, it, e = pre, time.process_time() - c0, 0, float("inf")
    reached = [None] * len(targets)
    while elapsed < seconds and None in reached:
        t0, c0 = time.perf_counter(), time.process_time()
        x = igl.slim_solve(data, 1)
        elapsed += time.perf_counter() - t0
        cpu += time.process_time() - c0
        it += 1
        e = float(objective.value(np.ascontiguousarray(x), params)) / area
        reached = [r if r is not None or e > t else (elapsed, cpu) for r, t in zip(reached, targets)]
    return reached, it, e, pre


def backend_iteration_seconds(V, F):
    """Warm Newton seconds per iteration, default linear solver vs CHOLMOD (None if absent)."""
    import geomopt
    from geomopt.linalg import linsolve

    out = {}
    for backend in ("auto", "cholmod"):
        if backend == "cholmod" and "cholmod" not in linsolve.available_backends():
            out[backend] = None
            continue
        solver = geomopt.Newton(linear_solver=backend)
        geomopt.parameterize(V, F, solver=solver, progress=False)  # compile
        per_it = []
        for _ in range(3):  # median of 3: one run in two can stall on a shared machine
            c0 = time.process_time()
            r = geomopt.parameterize(V, F, solver=solver, progress=False)
            per_it.append((r.stats.seconds / max(r.stats.iterations, 1), (time.process_time() - c0) / max(r.stats.iterations, 1)))
        out[backend] = statistics.median(p[0] for p in per_it)
        out[backend + "_cpu"] = statistics.median(p[1] for p in per_it)  # whole parameterize / iterations
    out["auto_backend"] = linsolve.available_backends()[0]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="*", help="mesh file stems (default: every mesh)")
    ap.add_argument("--repeat", type=int, default=3, help="warm and sibling runs per mesh (median)")
    ap.add_argument("--rtols", type=float, nargs="+", default=[1e-3, 1e-6],
                    help="SLIM's targets: geomopt's energy * (1 + rtol); the table compares with the last")
    ap.add_argument("--slim-seconds", type=float, default=300.0, help="SLIM's time cap per mesh")
    ap.add_argument("--backends", action="store_true", help="also time s/iteration vs CHOLMOD")
    ap.add_argument("--heldout", action="store_true",
                    help="held-out surfaces of 30k-50k triangles (heldout.surfaces) and face instead")
    ap.add_argument("--json", help="write the raw results here")
    args = ap.parse_args(argv)
    if not MESH_DIR.is_dir():
        sys.exit(f"meshes not found at {MESH_DIR}: clone the project next to its shared/ folder")
    sys.path.insert(0, str(REPO))
    from geomopt import io

    results = {"help_seconds": help_seconds(), "machine_load": os.getloadavg(), "meshes": []}
    log(f"geomopt --help: {results['help_seconds']:.3f} s (median of 7)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = sorted(p for p in MESH_DIR.iterdir() if p.suffix.lower() in MESH_EXTS)
        if args.heldout:
            sys.path.insert(0, str(Path(__file__).parent))
            import heldout

            paths = heldout.surfaces(MESH_DIR, tmp / "heldout") + [MESH_DIR / "face.obj"]
        if args.meshes:
            paths = [p for p in paths if p.stem in args.meshes]
        for path in paths:
            V, F = io.read_mesh(path)
            Vs, Fs = sibling(V, F)
            sib = tmp / f"{path.stem}_sibling.obj"
            io.write_obj_with_uv(sib, Vs, Fs, np.zeros((len(Vs), 2)))
            bucket_ok = same_bucket((V, F), (Vs, Fs))
            cache = tmp / f"cache_{path.stem}"
            out = tmp / "out.obj"
            log(f"{path.stem}: {len(F)} faces; cold run")
            try:
                cold = run_cli(["param", path, "-o", out, "--json", "--quiet"], cache)
            except RuntimeError as exc:  # e.g. not certified: a free boundary that folds over itself
                log(f"  skipped: {exc}")
                results.setdefault("skipped", {})[path.stem] = str(exc)[-400:]
                continue
            summary = cold[2]
            warm = [run_cli(["param", path, "-o", out, "--json", "--quiet"], cache) for _ in range(args.repeat)]
            sibs = [run_cli(["param", sib, "-o", out, "--json", "--quiet"], cache) for _ in range(args.repeat)]
            targets = [summary["mean_energy"] * (1 + r) for r in args.rtols]
            med = (lambda runs, k: statistics.median(r[k] for r in runs))
            log(f"  cold {cold[0]:.2f} s ({cold[1]:.2f} CPU s), warm {med(warm, 0):.2f} s ({med(warm, 1):.2f} CPU s), "
                f"sibling {med(sibs, 0):.2f} s ({med(sibs, 1):.2f} CPU s, first sibling misses "
                f"{sibs[0][2]['cache_misses']}); SLIM to E <= {targets[-1]:.10g}")
            x0, objective = start_map(V, F)
            reached, it_slim, e_slim, pre = slim_to(V, F, x0, objective, targets, args.slim_seconds)
            row = {"mesh": path.stem, "faces": len(F), "sibling_faces": len(Fs), "same_bucket": bucket_ok,
                   "cold_s": cold[0], "cold_cpu_s": cold[1], "warm_s": med(warm, 0), "warm_cpu_s": med(warm, 1),
                   "sibling_s": med(sibs, 0), "sibling_cpu_s": med(sibs, 1),
                   "runs": {"warm": [r[:2] for r in warm], "sibling": [r[:2] for r in sibs]},
                   "sibling_first_misses": sibs[0][2]["cache_misses"], "geomopt": summary,
                   "warm_misses": sum(r[2]["cache_misses"] for r in warm),
                   "warm_split": {k: statistics.median(r[2]["timing"][k] for r in warm)
                                  for k in warm[0][2].get("timing", {})},
                   "slim": dict(zip(map(str, args.rtols), reached)), "slim_iterations": it_slim,
                   "slim_energy": e_slim, "slim_precompute_s": pre, "slim_cap_s": args.slim_seconds}
            if args.backends:
                row["s_per_iter"] = backend_iteration_seconds(V, F)
            results["meshes"].append(row)
            log(f"  SLIM {reached} (wall, CPU s per rtol) in {it_slim} it")
            log(f"  warm split (--json timing, medians): {row['warm_split']}, misses {row['warm_misses']}")
    results["machine_load_after"] = os.getloadavg()
    print(table(results))
    for name, why in results.get("skipped", {}).items():
        print(f"skipped {name}: {why.strip().splitlines()[-1]}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))


def table(results):
    """Markdown: wall and CPU seconds of the whole process, SLIM's time to each energy target,
    and the ratios against SLIM's time to the last (tightest) target."""
    rtols = list(results["meshes"][0]["slim"]) if results["meshes"] else []
    lines = [f"geomopt --help: {results['help_seconds']:.3f} s (median of 7); load average "
             f"{', '.join(f'{v:.1f}' for v in results['machine_load'])}", "",
             "wall s / CPU s of the whole `geomopt param` process; SLIM: slim_precompute + iterations",
             "",
             "| mesh | #F | geomopt cold | warm | sibling (warm cache) | sibling misses | its "
             + "".join(f"| SLIM to rtol {r} " for r in rtols) + "| warm / SLIM (wall, CPU) | cold / SLIM (wall, CPU) |",
             "|---" * (9 + len(rtols)) + "|"]

    def ws(w, c):
        return f"{w:.2f} / {c:.2f}"

    for r in results["meshes"]:
        slim = r["slim"][rtols[-1]]
        cells = [("never in %.0f s" % r["slim_cap_s"]) if v is None else ws(*v) for v in r["slim"].values()]

        def ratio(w, c):
            if slim is None:
                return f"< {w / r['slim_cap_s']:.2f} (wall)"
            return f"{w / slim[0]:.2f}, {c / slim[1]:.2f}"

        lines.append(f"| {r['mesh']} | {r['faces']} | {ws(r['cold_s'], r['cold_cpu_s'])} | "
                     f"{ws(r['warm_s'], r['warm_cpu_s'])} | {ws(r['sibling_s'], r['sibling_cpu_s'])}"
                     f"{'' if r['same_bucket'] else ' (other bucket)'} | {r['sibling_first_misses']} | "
                     f"{r['geomopt']['iterations']} | " + " | ".join(cells) + " | "
                     f"{ratio(r['warm_s'], r['warm_cpu_s'])} | {ratio(r['cold_s'], r['cold_cpu_s'])} |")
    phases = ("import", "read", "compile", "setup", "certify", "write")
    lines += ["", "warm `--json` timing split (medians, wall s) and persistent-cache misses of the warm runs; "
              f"load average after {', '.join(f'{v:.1f}' for v in results.get('machine_load_after', ()))}", "",
              "| mesh | " + " | ".join(phases) + " | outside solve | solve | warm misses |", "|---" * 10 + "|"]
    for r in results["meshes"]:
        sp = r["warm_split"]
        outside = sum(sp.get(k, 0.0) for k in phases)
        lines.append(f"| {r['mesh']} | " + " | ".join(f"{sp.get(k, 0.0):.2f}" for k in phases)
                     + f" | {outside:.2f} | {sp.get('solve', 0.0):.2f} | {r['warm_misses']} |")
    rows = [r for r in results["meshes"] if r.get("s_per_iter")]
    if rows:
        lines += ["", "Newton seconds per iteration, warm: wall (solve only) / CPU (whole parameterize "
                  "call, all threads)", "",
                  "| mesh | default backend | s/iter default | s/iter CHOLMOD | ratio |", "|---|---|---|---|---|"]
        for r in rows:
            b = r["s_per_iter"]
            ch = b.get("cholmod")
            cholmod = "n/a" if ch is None else f"{ch:.3f} / {b['cholmod_cpu']:.3f}"
            ratio = "n/a" if ch is None else f"{b['auto'] / ch:.2f} / {b['auto_cpu'] / b['cholmod_cpu']:.2f}"
            lines.append(f"| {r['mesh']} | {b['auto_backend']} | {b['auto']:.3f} / {b['auto_cpu']:.3f} | "
                         f"{cholmod} | {ratio} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()

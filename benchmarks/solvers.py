"""Solver zoo benchmark: every geomopt solver and libigl's SLIM from the same Tutte start.

For every mesh in ``../shared/data/meshes`` (relative to the repository root): one start map,
the uniform Tutte embedding centred and scaled for symmetric Dirichlet
(``benchmarks/param.py``'s ``start_map``); libigl SLIM from it (``param.py``'s ``run_slim``:
``slim_precompute`` + ``slim_solve(data, 1)`` per iteration, each timed alone); every geomopt
solver from it through :func:`geomopt.compare` (solve time per iteration, setup excluded,
exact flips of every iterate).  geomopt runs once cold with ``--cold-seconds`` per solver (its
setup time is the "compile" column; it also warms the kernels some solvers compile in their
first steps) and ``--repeat`` times warm; medians of the warm runs are printed.

Per mesh, a Markdown table: iterations and seconds to a relative gap of 1e-2, 1e-4 and 1e-6
(the gap ``(E - E*) / E*`` to the best energy any solver reached in this run), iterations and
seconds to the reference energy of libigl's SLIM measured in the issue (``REFERENCES``), s/it,
compile seconds, final gap, final and maximum flips over every iterate, and the outcome.
Energies are geomopt's symmetric Dirichlet, area-weighted mean (4 at an isometry).

    python benchmarks/solvers.py --meshes camelhead bunny_cut --repeat 2 --max-seconds 60

``--refine``: iteration counts under refinement instead (no libigl): the same shape at several
resolutions (a generated ruffled disk or saddle at ``--refine-rings``, or a shared mesh and its midpoint
subdivisions), the chosen solvers (default aqp, slim, newton, lbfgs) from the Tutte start
(``--refine-start``: mean-value weights by default), iterations
and seconds to a relative gap of ``--refine-tol`` (default 1e-4) to the best energy at that
resolution.  AQP's proxy (the rest Laplacian) is resolution-independent, so its count should stay
nearly flat, while L-BFGS's grows (Kovalsky et al. 2016, beside L-BFGS and accelerated gradient descent).

    python benchmarks/solvers.py --refine saddle --refine-amplitude 2.5 --refine-rings 16 --refine-levels 2
    python benchmarks/solvers.py --refine bunny_cut --refine-levels 2
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import param as bench  # noqa: E402  (benchmarks/param.py: start map, libigl SLIM, helpers)

TOLS = (1e-2, 1e-4, 1e-6)
# libigl SLIM in the issue, this machine: (iterations, seconds) to the energy E
REFERENCES = {"camelhead": (74, 9.5, 7.448), "bunny_cut": (126, 6.6, 4.1417)}


def first_hit(energies, target):
    """Index of the first energy <= target, or None."""
    hit = np.flatnonzero(np.asarray(energies) <= target)
    return int(hit[0]) if hit.size else None


def trace_stats(times, energies, best, iterations, seconds, ref_energy):
    """Iterations / seconds to each tolerance and to ``ref_energy`` of one trace."""
    stats = {"iterations": iterations, "seconds": seconds, "s_per_it": seconds / max(iterations, 1),
             "final_gap": (energies[-1] - best) / abs(best)}
    targets = {f"{tol:g}": best + tol * abs(best) for tol in TOLS}
    if ref_energy is not None:
        targets["ref"] = ref_energy
    for key, target in targets.items():
        k = first_hit(energies, target)
        stats[f"it_{key}"] = k
        stats[f"t_{key}"] = None if k is None else float(times[k])
    return stats


def median_stats(runs):
    """Per key, the median over warm runs (None when any run never got there)."""
    out = {}
    for key in runs[0]:
        vals = [r[key] for r in runs]
        if all(isinstance(v, (int, float)) and v is not None for v in vals):
            out[key] = statistics.median(vals)
        elif all(isinstance(v, str) for v in vals):
            out[key] = vals[0] if len(set(vals)) == 1 else "/".join(vals)
        else:
            out[key] = None
    return out


def num(v):
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)


def cell(it, t):
    if it is None:
        return "never"
    return f"{it:.0f} / {bench.fmt_s(t)}"


def table(mesh, n_faces, rows, ref):
    keys = [f"{tol:g}" for tol in TOLS] + (["ref"] if ref else [])
    head = (["solver"] + [f"it / s to {k}" if k != "ref" else f"it / s to E={ref[2]}" for k in keys]
            + ["s/it", "compile s", "final gap", "flips (final/max)", "outcome"])
    lines = [f"### {mesh} ({n_faces} triangles)", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for name, r in rows.items():
        lines.append("| " + " | ".join(
            [name] + [cell(r[f"it_{k}"], r[f"t_{k}"]) for k in keys]
            + [f"{r['s_per_it']:.3g}", r.get("compile", ""), f"{r['final_gap']:.1e}",
               f"{num(r['flips'])}/{num(r['max_flips'])}", r["outcome"]]) + " |")
    if ref:
        lines.append(f"| libigl SLIM (issue) | | | | {ref[0]} / {ref[1]} | {ref[1] / ref[0]:.3g} | | | | |")
    return "\n".join(lines)


def midpoint_subdivide(V, F):
    """One 1-to-4 midpoint subdivision: the same piecewise-flat surface, 4x the triangles.

    V (n, 3), F (m, 3) -> V (n + edges, 3), F (4m, 3), orientation kept."""
    F = np.asarray(F, np.int64)
    n = len(V)
    # the three edges of each face (opposite corners 0, 1, 2): (1,2), (2,0), (0,1)
    pairs = np.stack([F[:, [1, 2]], F[:, [2, 0]], F[:, [0, 1]]], axis=1).reshape(-1, 2)
    key = np.sort(pairs, axis=1)
    edges, idx = np.unique(key, axis=0, return_inverse=True)
    mid = n + idx.reshape(-1, 3)  # (m, 3): midpoint vertex opposite each corner
    V = np.concatenate([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])])
    a, b, c = F.T
    ma, mb, mc = mid.T  # ma on edge (b, c), mb on (c, a), mc on (a, b)
    F = np.concatenate([np.stack(t, 1) for t in ((a, mc, mb), (b, ma, mc), (c, mb, ma), (ma, mb, mc))])
    return V, F


def refinement_shapes(args):
    """[(label, V, F)] of one shape at several resolutions."""
    from geomopt.mesh.generators import ruffled_disk, saddle
    from geomopt.io import read_mesh

    amp = {} if args.refine_amplitude is None else {"amplitude": args.refine_amplitude}
    generated = {"ruffled": lambda r: ruffled_disk(r, **amp), "saddle": lambda r: saddle(r, **amp)}
    if args.refine in generated and not args.refine_levels:
        return [(f"{args.refine} rings={r}", *generated[args.refine](r)) for r in args.refine_rings]
    if args.refine in generated:
        r = args.refine_rings[0]
        V, F = generated[args.refine](r)
        out = [(f"{args.refine} rings={r}", V, F)]
    else:
        path = next((p for p in bench.MESH_DIR.iterdir() if p.stem == args.refine), None)
        if path is None:
            sys.exit(f"error: --refine takes 'ruffled', 'saddle' or a mesh name in {bench.MESH_DIR}, "
                     f"got {args.refine!r}")
        V, F = read_mesh(path)
        out = [(args.refine, V, F)]
    levels = args.refine_levels if args.refine in generated else (args.refine_levels or 1)
    for k in range(levels):
        V, F = midpoint_subdivide(V, F)
        out.append((f"{out[0][0]} subdivided x{k + 1}", V, F))
    return out


def refine_report(args):
    """The ``--refine`` table: iterations (and seconds) to ``--refine-tol`` per resolution."""
    import geomopt
    from geomopt import Objective, Problem
    from geomopt.param import start_map

    wanted = args.solvers.split(",") if args.solvers else ["aqp", "slim", "newton", "lbfgs"]
    shapes = refinement_shapes(args)
    rows = []
    for label, V, F in shapes:
        objective = Objective(Problem.surface(V, F), "symmetric_dirichlet")
        x0 = start_map(objective, None, args.refine_start)[0]
        # compile what the solvers compile in their first steps (per size), outside the timings
        cold = geomopt.CompareOptions(max_seconds=args.cold_seconds, reference="best")
        geomopt.compare(V, F, x0=x0, solvers=wanted, options=cold)
        c = geomopt.compare(V, F, x0=x0, solvers=wanted,
                            options=geomopt.CompareOptions(max_seconds=args.max_seconds, reference="best"))
        best = c.best_mean_energy
        row = {"shape": label, "n_faces": len(F), "E_best": best}
        for name in wanted:
            r = c.results[name]
            e = r.trace.energy / c.area
            hit = first_hit(e, best + args.refine_tol * abs(best))
            row[name] = {"iterations": hit, "seconds": None if hit is None else float(r.trace.seconds[hit]),
                         "outcome": c.outcome(name), "flips": r.certificate.inverted}
        rows.append(row)
        bench.log(f"  {label}: {len(F)} triangles, E* = {best:.10g}")
    head = ["shape", "#F"] + [f"{n}: it / s to {args.refine_tol:g}" for n in wanted]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        lines.append("| " + " | ".join([row["shape"], str(row["n_faces"])] + [
            cell(row[n]["iterations"], row[n]["seconds"])
            + ("" if row[n]["flips"] == 0 else f" ({row[n]['flips']} flips)") for n in wanted]) + " |")
    print("\n".join(lines))
    print(f"\nrelative gap to the best energy of the listed solvers at each resolution; at most "
          f"{args.max_seconds:g} s per solver", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str))
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", nargs="+", metavar="NAME", help="mesh names (file stems); default: all")
    ap.add_argument("--solvers", default=None,
                    help="comma-separated geomopt solvers (default: every one in geomopt.solvers.SOLVERS; "
                         "those refused for a mesh, e.g. optx-bfgs's dense matrix, are listed and skipped)")
    ap.add_argument("--max-seconds", type=float, default=60.0, help="solve-time limit per solver and run")
    ap.add_argument("--cold-seconds", type=float, default=3.0, help="solve-time limit of the cold run")
    ap.add_argument("--repeat", type=int, default=1, help="warm runs (median reported)")
    ap.add_argument("--slim-iters", type=int, default=300, help="libigl SLIM iterations (default 300)")
    ap.add_argument("--json", type=Path, help="write the per-mesh statistics here")
    ap.add_argument("--refine", metavar="SHAPE",
                    help="iterations under refinement instead: 'ruffled' or 'saddle' (geomopt.mesh.generators, at "
                         "--refine-rings) or a mesh name (and --refine-levels midpoint subdivisions); default "
                         "solvers aqp,slim,newton")
    ap.add_argument("--refine-rings", type=int, nargs="+", default=[16, 32, 64],
                    help="resolutions of a generated shape (disk rings; 6 rings^2 triangles), default 16 32 64")
    ap.add_argument("--refine-levels", type=int, default=0,
                    help="midpoint subdivisions (the exact same surface): of a mesh (default 1), or of a "
                         "generated shape at the first --refine-rings (default 0: generate at every ring count)")
    ap.add_argument("--refine-amplitude", type=float, help="amplitude of the generated shape (its default: "
                    "ruffled 0.6, saddle 1)")
    ap.add_argument("--refine-start", choices=("mean_value", "uniform"), default="mean_value",
                    help="Tutte weights of the start map (default mean_value: it converges under refinement, "
                         "the uniform one does not on irregular meshes, so each resolution would start elsewhere)")
    ap.add_argument("--refine-tol", type=float, default=1e-4, help="relative gap counted (default 1e-4)")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.slim_iters < 1:
        ap.error("--repeat and --slim-iters must be at least 1")
    if args.json:
        from geomopt.io import check_output_path

        check_output_path(args.json)
    if args.refine:
        if not bench.MESH_DIR.is_dir() and args.refine not in ("ruffled", "saddle"):
            sys.exit(f"error: mesh folder {bench.MESH_DIR} not found (see shared/data/meshes/SOURCES.md)")
        return refine_report(args)
    try:
        import igl  # noqa: F401
    except ImportError:
        sys.exit("error: libigl is not installed; pip install 'geomopt[bench]' (or pip install libigl)")
    if not bench.MESH_DIR.is_dir():
        sys.exit(f"error: mesh folder {bench.MESH_DIR} not found (see shared/data/meshes/SOURCES.md)")

    import geomopt
    from geomopt import Objective, ParameterError, Problem
    from geomopt.io import read_mesh
    from geomopt.solvers import SOLVERS

    available = {p.stem: p for p in sorted(bench.MESH_DIR.iterdir()) if p.suffix.lower() in bench.MESH_EXTS}
    names = args.meshes or list(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        sys.exit(f"error: unknown mesh(es) {', '.join(unknown)}; available: {', '.join(available)}")
    wanted = args.solvers.split(",") if args.solvers else list(SOLVERS)

    report = {}
    for mesh in names:
        V, F = read_mesh(available[mesh])
        bench.log(f"{mesh}: {len(V)} vertices, {len(F)} triangles")
        objective = Objective(Problem.surface(V, F), "symmetric_dirichlet")
        x0, _ = bench.start_map(objective, V, F)
        solvers, skipped, cold = [], {}, {}
        for name in wanted:  # one solver at a time: compare refuses a list with any unfit solver
            try:
                cold[name] = geomopt.compare(V, F, x0=x0, solvers=[name], options=geomopt.CompareOptions(
                    max_seconds=args.cold_seconds, reference="best"))
                solvers.append(name)
            except ParameterError as exc:
                skipped[name] = str(exc)
                bench.log(f"  skipped {name}: {exc}")
        warm = []
        for k in range(args.repeat):
            warm.append(geomopt.compare(V, F, x0=x0, solvers=solvers, options=geomopt.CompareOptions(
                max_seconds=args.max_seconds, reference="best")))
            bench.log(f"  warm run {k + 1}:\n" + warm[-1].report())
        slim = bench.run_slim(V, F, x0, args.slim_iters, objective, objective.params())
        ref = REFERENCES.get(mesh)
        best = min([slim["energies"][-1]] + [c.best_mean_energy for c in warm])
        rows = {}
        for name in solvers:
            runs = []
            for c in warm:
                r = c.results[name]
                e = r.energy_history / c.area
                stats = trace_stats(r.time_history, e, best, r.iterations, r.seconds, ref and ref[2])
                stats.update(flips=r.inverted, max_flips=int(r.flips_history.max()),
                             outcome=c.outcome(name))
                runs.append(stats)
            rows[name] = median_stats(runs)
            rows[name]["compile"] = f"{cold[name].results[name].stats.setup_seconds:.2f}"
        s = trace_stats(slim["times"], slim["energies"], best, slim["iterations"], slim["seconds"],
                        ref and ref[2])
        s.update(flips=slim["flips"], max_flips="n/a", outcome=f"{slim['iterations']} it",
                 compile=f"{slim['setup_seconds']:.2f} (precompute)")
        rows["libigl SLIM (here)"] = s
        report[mesh] = {"n_faces": len(F), "E_best": best, "rows": rows, "skipped": skipped,
                        "warm_seconds": {n: [c.results[n].stats.seconds for c in warm] for n in solvers}}
        print(table(mesh, len(F), rows, ref))
        print(f"\nE* = {best:.10g}; medians of {args.repeat} warm run(s), at most {args.max_seconds:g} s "
              f"per solver; skipped: {', '.join(skipped) or 'none'}\n", flush=True)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())

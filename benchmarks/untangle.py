"""Untangling benchmark: every LIM case in ../shared/data/lim plus generated families.

Usage::

    python benchmarks/untangle.py [--repeat 3] [--sizes 1000,10000,100000] [--only PATTERN]
                                  [--solver lbfgs|newton] [--no-families] [--no-lim]

For each case it runs :func:`geomopt.untangling.untangle` once cold (compilation included) and
``--repeat`` times warm, and prints one row: elements, initially inverted elements, outer
iterations, inner iterations, energy (and gradient) evaluations, median warm seconds (the
whole untangling call: problem set-up, normalisation, outer loop, certification; file
reading excluded), compile seconds (cold minus warm), the smallest signed area/volume relative to the mean, and
whether the result is certified (zero inverted elements by the exact predicate, handles
bit-identical).  Reference times are the authors' C++ code (L-BFGS, one thread) on the
project's 2-core machine.  Timings on a shared machine are noisy: compare medians.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from geomopt.mesh import generators as G  # noqa: E402
from geomopt import MeshError  # noqa: E402
from geomopt.lim import LimCase, untangle_case  # noqa: E402
from geomopt.exact.predicates import count_inverted  # noqa: E402
from geomopt.untangling import untangle  # noqa: E402

LIM_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lim"

# Garanzha et al.'s C++ code (L-BFGS inner solver, single thread) on the project machine
REFERENCE_SECONDS = {"WeberZorin14_fig19": 4.2, "armadillo-598": 3.8, "disk46-noise2": 1.5}


def families(sizes):
    """(name, group, factory) for the generated cases of about ``sizes`` elements
    (among 1e2, 1e3, 1e4, 1e5; 1e2 is for tests/test_untangle_families.py)."""
    out = []
    sq = {100: 8, 1_000: 23, 10_000: 72, 100_000: 225}  # 2 (n-1)^2 triangles
    disk = {100: 4, 1_000: 13, 10_000: 41, 100_000: 129}  # 6 R^2 triangles
    cube = {100: 3, 1_000: 6, 10_000: 12, 100_000: 26}  # 6 n^3 tets
    rod = {100: (3, 10), 1_000: (4, 10), 10_000: (8, 26), 100_000: (16, 65)}  # 6 c^2 l tets
    for size in (100, 1_000, 10_000, 100_000):
        if size not in sizes:
            continue
        n, R, c = sq[size], disk[size], cube[size]
        rc, rl = rod[size]
        for angle in (90, 180, 270):
            out.append((f"square{n}-rot{angle}", "rotated", lambda n=n, a=angle: G.rotated_interior(*G.square_mesh(n), a)))
        out.append((f"disk{R}-noise2", "noise", lambda R=R: G.noisy_interior(*G.disk_mesh(R), 2.0, seed=1)))
        out.append((f"disk{R}-tutte-star", "tutte", lambda R=R: G.tutte_nonconvex(R, "star", arms=5, depth=0.6)))
        out.append((f"disk{R}-tutte-L", "tutte", lambda R=R: G.tutte_nonconvex(R, "L")))
        out.append((f"rod{rc}x{rl}-twist1", "twist", lambda rc=rc, rl=rl: G.twisted_box(rc, rl, 1.0)))
        out.append((f"rod{rc}x{rl}-bend180", "bend", lambda rc=rc, rl=rl: G.bent_box(rc, rl, 180.0)))
        out.append((f"cube{c}-twist0.5", "twist", lambda c=c: G.twisted_box(c, c, 0.5)))
        out.append((f"cube{c}-rot180", "rotated", lambda c=c: G.rotated_interior(*G.box_mesh(c, c, c), 180)))
        if size == 10_000:  # the size of the authors' noisy-disk example
            out.append(("disk46-noise2", "noise", lambda: G.noisy_interior(*G.disk_mesh(46), 2.0, seed=1)))
    return out


def run_case(name, call, repeat):
    """Cold run, then ``repeat`` warm runs of ``call() -> (result, S, orientation, x0, fixed)``."""
    t = time.perf_counter()
    result, S, orientation, handles_ref, fixed = call()
    cold = time.perf_counter() - t
    warm = []
    for _ in range(repeat):
        t = time.perf_counter()
        result, S, orientation, handles_ref, fixed = call()
        warm.append(time.perf_counter() - t)
    inverted = count_inverted(result.x, S, orientation=orientation)
    handles_ok = np.array_equal(result.x[fixed].view(np.uint64), handles_ref.view(np.uint64))
    certified = result.success and inverted == 0 and handles_ok
    w = statistics.median(warm) if warm else cold
    return {
        "name": name, "elements": len(S), "inverted0": result.stats.inverted_at_start,
        "outer": result.stats.outer_iterations, "inner": result.stats.iterations,
        "evals": result.stats.evaluations, "warm": w,
        "warm_min": min(warm) if warm else cold, "compile": max(cold - w, 0.0),
        "min_det": result.min_det_rel, "certified": certified,
    }


def lim_call(folder, solver):
    case = LimCase.read(folder)  # file reading is not timed

    def call():
        _, result = untangle_case(case, solver=solver, progress=False)
        H = case.handles
        return result, case.simplices, case.to_problem().orientation, np.ascontiguousarray(case.init[H]), H
    return call


def family_call(tangle, solver):
    problem = tangle.problem()

    def call():
        result = untangle(problem, tangle.x0, solver=solver, progress=False)
        return result, tangle.simplices, 1, np.ascontiguousarray(tangle.x0[tangle.fixed]), tangle.fixed
    return call


HEADER = (f"{'case':28s} {'group':10s} {'elements':>9s} {'inv0':>6s} {'outer':>5s} {'inner':>6s} {'evals':>6s} "
          f"{'warm s':>8s} {'compile s':>9s} {'ref s':>6s} {'min det':>8s}  certified")


def row(r, group):
    ref = REFERENCE_SECONDS.get(r["name"])
    return (f"{r['name']:28s} {group:10s} {r['elements']:9d} {r['inverted0']:6d} {r['outer']:5d} "
            f"{r['inner']:6d} {r['evals']:6d} {r['warm']:8.3f} {r['compile']:9.2f} {ref if ref else '':>6} "
            f"{r['min_det']:8.1e}  {'yes' if r['certified'] else 'NO'}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3, help="warm runs per case (median reported)")
    ap.add_argument("--sizes", default="1000,10000,100000",
                    help="family sizes to run (elements, among 100, 1000, 10000, 100000)")
    ap.add_argument("--only", default="", help="run cases whose name contains this")
    ap.add_argument("--solver", default="lbfgs", choices=["lbfgs", "newton"])
    ap.add_argument("--no-families", action="store_true")
    ap.add_argument("--no-lim", action="store_true")
    ap.add_argument("--lim", default=str(LIM_ROOT), help="LIM root folder")
    args = ap.parse_args(argv)

    jobs = []
    if not args.no_lim:
        root = Path(args.lim)
        if root.is_dir():
            jobs += [(c.name, "LIM", lambda c=c: lim_call(c, args.solver)) for c in LimCase.cases(root)]
        else:
            print(f"(LIM data not found at {root}; skipping the shared cases)", file=sys.stderr)
    if not args.no_families:
        jobs += [(n, g, lambda f=f: family_call(f(), args.solver)) for n, g, f in families({int(float(v)) for v in args.sizes.split(",")})]
    jobs = [j for j in jobs if args.only in j[0]]

    print(f"untangling benchmark: solver={args.solver}, {args.repeat} warm run(s) per case, "
          f"jax {jax.__version__} on {jax.devices()[0].platform}")
    print(HEADER)
    print("-" * len(HEADER))
    rows = []
    refused = []
    for name, group, make in jobs:
        try:
            r = run_case(name, make(), args.repeat)
        except MeshError as exc:  # refused before solving (e.g. handles no injective map satisfies)
            refused.append(name)
            print(f"{name:28s} {group:10s} refused: {exc}", flush=True)
            continue
        rows.append((r, group))
        print(row(r, group), flush=True)
    print("-" * len(HEADER))
    ok = sum(r["certified"] for r, _ in rows)
    print(f"certified: {ok}/{len(rows)}" + (f"; refused before solving: {', '.join(refused)}" if refused else ""))
    lim = [r for r, g in rows if g == "LIM"]
    if lim:
        print(f"LIM cases: median warm {statistics.median(r['warm'] for r in lim):.3f} s, "
              f"total warm {sum(r['warm'] for r in lim):.2f} s, total compile {sum(r['compile'] for r in lim):.1f} s")
    for r, _ in rows:
        ref = REFERENCE_SECONDS.get(r["name"])
        if ref:
            print(f"  {r['name']}: {r['warm']:.3f} s warm vs {ref} s reference ({ref / r['warm']:.1f}x)")
    return 0 if ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())

"""Batch benchmark: 1,000 small generated untangling cases through ``geomopt untangle ROOT -o OUT``
against one process per case.

Usage::

    python benchmarks/batch.py [--cases 1000] [--workers 2] [--root DIR] [--single 20] [--serial]

1. Generates ``--cases`` LIM case folders under ``ROOT/cases`` (kept and reused when already
   there with the same count): 2D rotated squares, noisy disks and Tutte maps onto star /
   L / crescent polygons of about 300-3,000 triangles, and 3D twisted or bent rods and rotated
   cubes of about 300-3,000 tets (one in seven cases), all from :mod:`geomopt.mesh.generators`,
   written with :meth:`geomopt.lim.LimCase.write`.
2. Batch, cold: ``python -m geomopt untangle ROOT/cases -o ROOT/out-cold --workers N`` with an
   empty compilation cache (``GEOMOPT_CACHE_DIR``); the whole process is timed, start-up,
   Dask cluster and compilation included.
3. Batch, warm: the same command again with the cache the cold run filled (new processes).
   With ``--serial`` also ``--workers 1`` (in one process, cold cache).
4. One process per case, on ``--single`` cases spread over the sizes: (a) as before buckets,
   a process that solves the case at its own size (``bucket=False``) without a persistent
   cache, i.e. compiling everything; (b) ``python -m geomopt untangle CASE -o OUT.obj`` with
   the cache the batch filled.  Both extrapolated to all cases (mean x count).

It prints the load average before and after (the machine is shared: compare ratios), the
number of certified cases, wall and CPU seconds (user + system of the command and the
processes it reaped: on a loaded machine the CPU seconds say what an idle one would take, up
to the parallel speed-up), cases per second, and whether the cold and warm batches wrote the
same bytes.
"""

from __future__ import annotations

import argparse
import csv
import filecmp
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from geomopt.mesh import generators as G  # noqa: E402
from geomopt._runtime.padding import bucket_sizes  # noqa: E402
from geomopt.lim import LimCase  # noqa: E402


def make_tangle(i, rng):
    """Case ``i``: one of the families, sizes about 300-3,000 elements."""
    kind = i % 7
    if kind == 6:  # 3D
        sub = (i // 7) % 3
        if sub == 0:
            c = int(rng.integers(3, 5))
            lo, hi = -(-300 // (6 * c * c)), 3000 // (6 * c * c)
            return G.twisted_box(c, int(rng.integers(lo, hi + 1)), float(rng.choice([0.25, 0.5])))
        if sub == 1:
            return G.bent_box(3, int(rng.integers(6, 18)), float(rng.choice([90.0, 120.0, 180.0])))
        k = int(rng.integers(4, 8))
        return G.rotated_interior(*G.box_mesh(k, k, k), float(rng.choice([60.0, 90.0])))
    if kind in (0, 1):
        n = int(rng.integers(13, 40))  # 2 (n-1)^2 triangles
        return G.rotated_interior(*G.square_mesh(n), float(rng.choice([60.0, 90.0, 120.0, 180.0])))
    if kind in (2, 3):
        R = int(rng.integers(7, 23))  # 6 R^2 triangles
        return G.noisy_interior(*G.disk_mesh(R), float(rng.choice([0.5, 1.0, 2.0])), seed=int(rng.integers(1 << 30)))
    R = int(rng.integers(7, 23))
    shape = str(rng.choice(["star", "L", "crescent"]))
    return G.tutte_nonconvex(R, shape, arms=int(rng.integers(4, 7)), depth=float(rng.choice([0.4, 0.5])))


def generate(root, count, seed=0):
    """Write ``count`` cases under ``root/cases`` (reused when present); returns the folder."""
    folder = root / "cases"
    stamp = folder / f".generated-{count}-{seed}"
    if stamp.exists():
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    for i in range(count):
        t = make_tangle(i, rng)
        LimCase.from_tangle(t).write(folder / f"case{i:05d}-{t.dim}d-{t.name}-{t.n_elements}")
    stamp.write_text("")
    print(f"generated {count} cases in {time.perf_counter() - t0:.1f} s under {folder}", file=sys.stderr)
    return folder


def run(cmd, env=None):
    """Run ``cmd``; (wall seconds, CPU seconds of it and its reaped children, the process)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, proc


def summary(out):
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return rows, sum(r["certified"] == "yes" for r in rows)


def same_files(a, b):
    names = sorted(p.name for p in a.iterdir() if p.name != "summary.csv")
    if names != sorted(p.name for p in b.iterdir() if p.name != "summary.csv"):
        return False
    return all(filecmp.cmp(a / n, b / n, shallow=False) for n in names)


NO_BUCKET = ("import sys; from geomopt.lim import untangle_case; "
             "case, res = untangle_case(sys.argv[1], progress=False); "
             "sys.exit(0 if res.success and case.write_certified(res, sys.argv[2]) else 1)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--root", default=None, help="work folder (default: a folder under the temp dir)")
    ap.add_argument("--single", type=int, default=20, help="cases timed one process each (0: skip)")
    ap.add_argument("--serial", action="store_true", help="also time --workers 1 (one process, cold)")
    args = ap.parse_args(argv)
    root = Path(args.root or Path(tempfile.gettempdir()) / "geomopt-batch-bench")
    root.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    cases = generate(root, args.cases)
    folders = sorted(p for p in cases.iterdir() if p.is_dir())
    buckets = {}
    for f in folders:
        dim, m = (2 if "-2d-" in f.name else 3), int(f.name.rsplit("-", 1)[1])
        buckets.setdefault((dim, bucket_sizes(0, m, dim)[1]), 0)
        buckets[(dim, bucket_sizes(0, m, dim)[1])] += 1
    print(f"{len(folders)} cases; element buckets (dim, elements): count = {dict(sorted(buckets.items()))}",
          file=sys.stderr)
    py = [sys.executable, "-m", "geomopt", "untangle"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    results = []
    cache = root / "cache"
    shutil.rmtree(cache, ignore_errors=True)
    configs = [("batch, cold cache", f"--workers={args.workers}", "out-cold", cache),
               ("batch, warm cache", f"--workers={args.workers}", "out-warm", cache)]
    if args.serial:
        shutil.rmtree(root / "cache-serial", ignore_errors=True)
        configs.append(("batch in one process, cold cache", "--workers=1", "out-serial", root / "cache-serial"))
    for label, workers, out, cdir in configs:
        shutil.rmtree(root / out, ignore_errors=True)
        seconds, cpu, proc = run(py + [str(cases), "-o", str(root / out), workers, "--quiet"],
                                 {**env, "GEOMOPT_CACHE_DIR": str(cdir)})
        _, ok = summary(root / out)
        results.append((label, seconds, cpu, ok))
        print(f"{label}: {seconds:.1f} s, CPU {cpu:.1f} s, {ok}/{len(folders)} certified, exit {proc.returncode}",
              file=sys.stderr)
    same = same_files(root / "out-cold", root / "out-warm")
    if args.single:
        pick = [folders[int(i)] for i in np.linspace(0, len(folders) - 1, args.single)]
        for label, make in [
            ("one process per case, own size, no cache", lambda f, o: [sys.executable, "-c", NO_BUCKET, str(f), str(o)]),
            ("one process per case (CLI), warm cache", lambda f, o: py + [str(f), "-o", str(o), "--quiet"]),
        ]:
            times, cpus, ok = [], [], 0
            for f in pick:
                out = root / "single" / (f.name + (".obj" if "-2d-" in f.name else ".vtk"))
                out.parent.mkdir(exist_ok=True)
                seconds, cpu, proc = run(make(f, out), {**env, "GEOMOPT_CACHE_DIR": str(cache)})
                times.append(seconds)
                cpus.append(cpu)
                ok += proc.returncode == 0
            results.append((f"{label} (x{len(folders)} from {len(pick)}: median {np.median(times):.2f} s, "
                            f"CPU {np.median(cpus):.2f} s per case)", np.mean(times) * len(folders),
                            np.mean(cpus) * len(folders), f"{ok}/{len(pick)}"))
            print(results[-1], file=sys.stderr)
    load1 = os.getloadavg()
    print(f"\nload average (1, 5, 15 min) before {load0[0]:.1f} {load0[1]:.1f} {load0[2]:.1f}, after "
          f"{load1[0]:.1f} {load1[1]:.1f} {load1[2]:.1f}; {os.cpu_count()} cores")
    print(f"cold and warm batches wrote the same bytes: {'yes' if same else 'NO'}\n")
    print("| run | wall s | CPU s | cases/s (wall) | certified |\n|---|---|---|---|---|")
    for label, seconds, cpu, ok in results:
        print(f"| {label} | {seconds:.1f} | {cpu:.1f} | {len(folders) / seconds:.1f} | {ok} |")


if __name__ == "__main__":
    main()

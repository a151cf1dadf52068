"""Untangling beside the authors' C++ (Garanzha et al. 2021): whole processes, equal cores.

Usage::

    python benchmarks/untangle_cpp.py --cpp DIR [--geomopt CMD] [--repeat 3] [--only PATTERN]
                                      [--max-elements N] [--scaling] [--root DIR] [--json FILE]
    python benchmarks/untangle_cpp.py --no-cpp ...            # geomopt only

``DIR`` holds the authors' ``untangle2d`` and ``untangle3d`` (``ssloy/invertible-maps``; build
them yourself, see ``benchmarks/README.md``; a path to ``untangle3d`` itself works too).
``--geomopt`` is the command that runs geomopt (default: ``geomopt`` on the PATH, else this
Python's ``-m geomopt``); install geomopt with ``pip install .`` so that the whole process is
what a user runs.

Cases (``CASES``): 2D and 3D, 10^3 to 1.35 x 10^5 elements, fixed boundaries: the structured
families (disks and squares with noisy or rotated interiors, Tutte maps onto non-convex
polygons, cubes rotated / twisted / noisy, rods twisted and bent, LIM's armadillo-598) and
held-out ones (``benchmarks/heldout.py``: irregular Delaunay balls and disks, an annulus, an
L-shaped and a genus-1 box, a squashed cube, a bent rod).  Each case is written once as a LIM
case folder under ``--root`` (kept for reuse).

Per case: ``geomopt untangle CASE -o OUT --json`` runs once to fill the persistent compilation
cache; then ``--repeat`` rounds, each running, one after the other so that all see the same
load, the C++ with ``OMP_NUM_THREADS=1``, the C++ with all cores, and the geomopt process
(optionally ``--scaling``: geomopt again pinned to one core with ``taskset -c 0``).  Reported,
medians of the rounds:

* solve seconds: the C++'s own printed "running time" (its eps loop) and geomopt's ``solve``
  from its ``--json`` timing split (the outer loop);
* whole-process wall seconds, timed from outside (process start to exit: reading, set-up,
  solve, writing; geomopt also loads its compiled programs and certifies the written file);
* geomopt's split outside the solve (``--json`` ``timing``) and its persistent-cache misses
  in the measured rounds (0 = nothing compiled);
* quality of the rest mesh and of both results (:mod:`geomopt.mesh.quality`): smallest
  size / mean size and smallest scaled Jacobian, and whether each output has no inverted
  element by the exact predicate (:func:`geomopt.exact.predicates.count_inverted`).

Ratios are geomopt / C++ with all cores.  The last lines are the summary against issue 22's
targets, with the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import heldout as H  # noqa: E402

from geomopt.mesh import generators as G  # noqa: E402
from geomopt.io import read_mesh, read_vtk_tets  # noqa: E402
from geomopt.lim import LimCase  # noqa: E402
from geomopt.exact.predicates import count_inverted  # noqa: E402
from geomopt.mesh.quality import element_quality  # noqa: E402

LIM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lim"
LIM_ARMADILLO = LIM / "3D" / "Deform_Armadillo" / "armadillo-598"

#: name -> Tangle factory; the "held-out" marks families no default was tuned on
CASES = {
    # 2D, structured
    "disk13-noise": lambda: G.noisy_interior(*G.disk_mesh(13), 2.0, seed=1),
    "disk46-noise": lambda: G.noisy_interior(*G.disk_mesh(46), 2.0, seed=1),
    "disk46-rot180": lambda: G.rotated_interior(*G.disk_mesh(46), 180),
    "square72-rot180": lambda: G.rotated_interior(*G.square_mesh(72), 180),
    "disk41-tutte-star": lambda: G.tutte_nonconvex(41, "star", arms=5, depth=0.6),
    "disk150-noise": lambda: G.noisy_interior(*G.disk_mesh(150), 2.0, seed=1),
    "disk150-rot180": lambda: G.rotated_interior(*G.disk_mesh(150), 180),
    # 2D, held-out
    "ddisk12k-noise": lambda: H.delaunay_disk(6000, "noise2"),
    "ddisk12k-rot180": lambda: H.delaunay_disk(6000, "rot180"),
    "annulus12k-rot180": lambda: H.delaunay_annulus(6000, "rot180"),
    "ddisk100k-rot90": lambda: H.delaunay_disk(50000, "rot90"),
    # 3D, structured
    "cube8-rot90": lambda: G.rotated_interior(*G.box_mesh(8, 8, 8), 90),
    "cube14-rot180": lambda: G.rotated_interior(*G.box_mesh(14, 14, 14), 180),
    "rod8x64-twist1.5": lambda: G.twisted_box(8, 64, 1.5),
    "rod8x64-bend180": lambda: G.bent_box(8, 64, 180.0),
    "cube20-twist1": lambda: G.twisted_box(20, 20, 1.0),
    "cube20-noise": lambda: G.noisy_interior(*G.box_mesh(20, 20, 20), 2.0, seed=1),
    "cube24-rot90": lambda: G.rotated_interior(*G.box_mesh(24, 24, 24), 90),
    "cube24-rot180": lambda: G.rotated_interior(*G.box_mesh(24, 24, 24), 180),
    # 3D, held-out
    "ball3k-rot180": lambda: H.delaunay_ball(400, "rot180"),
    "ball12k-rot180": lambda: H.delaunay_ball(1500, "rot180"),
    "ball12k-noise": lambda: H.delaunay_ball(1500, "noise2"),
    "ball60k-rot180": lambda: H.delaunay_ball(8000, "rot180"),
    "ball60k-noise": lambda: H.delaunay_ball(8000, "noise2"),
    "lbox20-rot90": lambda: G.rotated_interior(*H.l_box(20), 90),
    "lrod10x40-twist0.5": lambda: H.twisted(*H.l_box(10, 40), 0.5, "lrod-twist0.5"),
    "torus20-twist0.5": lambda: H.twisted(*H.torus_box(20), 0.5, "torus-twist0.5"),
    "cube20-squash0.25": lambda: H.squashed_box(20, 0.25),
    "rod6x48-bend120": lambda: G.bent_box(6, 48, 120.0),
}
HELD_OUT = ("ddisk", "annulus", "ball", "lbox", "lrod", "torus", "squash", "rod6x48")


def prepare(name, root):
    """The LIM case folder of ``name`` under ``root`` (written once), its dim and simplices."""
    if name == "armadillo-598":
        folder = LIM_ARMADILLO
    else:
        folder = Path(root) / name
        if not (folder / "handles.txt").exists():
            LimCase.from_tangle(CASES[name]()).write(folder)
    case = LimCase.read(folder)
    S = case["faces"] if case["dim"] == 2 else case["tets"]
    rest = np.asarray(case["rest"])[:, : case["dim"]]
    # LIM cases may list every element clockwise (2D: in the map; 3D: at rest as in the map)
    orientation = 1 if _signed(case["init"] if case["dim"] == 2 else rest, S) > 0 else -1
    return folder, case["dim"], S, rest, orientation


def _signed(x, S):
    """The total signed area / volume of the simplices S of x."""
    E = np.asarray(x, np.float64)[S][:, 1:] - np.asarray(x, np.float64)[S][:, :1]
    return float(np.linalg.det(E).sum())


def cpp_binary(path, dim):
    p = Path(path)
    return (p.parent if p.is_file() else p) / f"untangle{dim}d"


def cpp_args(binary, folder, dim, out):
    """The command line of the C++ on the case folder ``folder`` writing ``out``."""
    folder = Path(folder)
    return [str(binary), str(folder / "input.obj"), str(out)] if dim == 2 else \
        [str(binary), str(folder / "init.vtk"), str(folder / "rest.vtk"), str(out)]


def cpp_solve_seconds(text):
    """The C++'s own solve seconds ("running time", its eps loop) from its output, or nan."""
    m = re.search(r"running time: ([0-9.e+-]+) s", text)
    return float(m.group(1)) if m else float("nan")


def read_map(out, dim):
    """The map a run wrote to ``out`` (OBJ in 2D, VTK tets in 3D)."""
    return read_mesh(out)[0][:, :2] if dim == 2 else read_vtk_tets(out)[0]


def run_cpp(binary, folder, dim, threads, out):
    """(solve s, whole-process wall s, the output map or None) of the C++ on one case."""
    t = time.perf_counter()
    p = subprocess.run(cpp_args(binary, folder, dim, out), capture_output=True, text=True,
                       env=dict(os.environ, OMP_NUM_THREADS=str(threads)))
    wall = time.perf_counter() - t
    if p.returncode != 0 or not out.exists():
        return float("nan"), wall, None
    return cpp_solve_seconds(p.stderr + p.stdout), wall, read_map(out, dim)


def geomopt_args(cmd, folder, out, pin=None, command="untangle", quiet=True):
    """The command line of one ``geomopt untangle`` (or ``command``) process with ``--json``
    (and ``--quiet`` unless ``quiet`` is false: then its progress goes to stderr)."""
    return (["taskset", "-c", pin] if pin else []) + cmd + [command, str(folder), "-o", str(out), "--json"] + \
        ["--quiet"] * quiet


def json_summary(stdout, stderr):
    """The ``--json`` summary (the last stdout line) of a geomopt process, or a failure record."""
    try:
        return json.loads(stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        return {"success": False, "error": stderr[-300:]}


def run_geomopt(cmd, folder, out, pin=None):
    """(whole-process wall s, the --json summary) of one ``geomopt untangle`` process."""
    t = time.perf_counter()
    p = subprocess.run(geomopt_args(cmd, folder, out, pin), capture_output=True, text=True)
    wall = time.perf_counter() - t
    return wall, json_summary(p.stdout, p.stderr)


def _med(values):
    values = [v for v in values if v == v]
    return statistics.median(values) if values else float("nan")


def measure(name, a, cores):
    folder, dim, S, rest, orientation = prepare(name, a.root)
    ext = ".obj" if dim == 2 else ".vtk"
    out_g, out_c = Path(a.root) / f"_geomopt{ext}", Path(a.root) / f"_cpp{ext}"
    run_geomopt(a.geomopt, folder, out_g)  # fills the persistent cache
    row = {"case": name, "dim": dim, "elements": len(S), "held_out": name.startswith(HELD_OUT),
           "rest": element_quality(rest, S, orientation)}
    runs = {"cpp1": [], "cppN": [], "geo": [], "geo1": []}
    x_cpp = None
    for _ in range(a.repeat):
        if a.cpp:
            for key, threads in (("cpp1", 1), ("cppN", cores)):
                out_c.unlink(missing_ok=True)
                solve, wall, x = run_cpp(cpp_binary(a.cpp, dim), folder, dim, threads, out_c)
                runs[key].append((solve, wall))
                x_cpp = x if key == "cppN" else x_cpp
        wall, js = run_geomopt(a.geomopt, folder, out_g)
        runs["geo"].append((js.get("timing", {}).get("solve", float("nan")), wall, js))
        if a.scaling:
            wall1, js1 = run_geomopt(a.geomopt, folder, out_g, pin="0")
            runs["geo1"].append((js1.get("timing", {}).get("solve", float("nan")), wall1))
    js = runs["geo"][-1][2]
    for key, rounds in runs.items():
        row[key + "_solve"] = _med(r[0] for r in rounds)
        row[key + "_wall"] = _med(r[1] for r in rounds)
    split = [r[2].get("timing", {}) for r in runs["geo"]]
    row["geo_outside"] = _med(s.get("total", np.nan) - s.get("solve", np.nan) for s in split)
    row["geo_split"] = {k: _med(s.get(k, np.nan) for s in split) for k in
                        ("import", "read", "compile", "setup", "solve", "certify", "write", "other")}
    row["misses"] = sum(r[2].get("cache_misses", -1) for r in runs["geo"])
    row["outer"], row["inner"] = js.get("outer_iterations"), js.get("inner_iterations")
    row["geo_certified"] = bool(js.get("certified")) and all(r[2].get("certified") for r in runs["geo"])
    row["geo_quality"] = {k: js.get(k, float("nan")) for k in ("min_size_ratio", "min_scaled_jacobian",
                                                               "mean_scaled_jacobian")}
    if x_cpp is not None:
        row["cpp_certified"] = count_inverted(x_cpp, S, orientation=orientation) == 0
        row["cpp_quality"] = element_quality(x_cpp, S, orientation)
    return row


def _f(v, fmt="{:.2f}"):
    return "-" if v is None or v != v else fmt.format(v)


def print_tables(rows, cores):
    print(f"\n| case | dim | elements | C++ solve 1 thread | C++ solve {cores} threads | geomopt solve | "
          f"solve ratio | C++ wall {cores} threads | geomopt wall | wall ratio | geomopt outside solve | "
          f"outer / inner | misses |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        name = r["case"] + (" (held-out)" if r["held_out"] else "")
        print(f"| {name} | {r['dim']} | {r['elements']:,} | {_f(r['cpp1_solve'])} | {_f(r['cppN_solve'])} | "
              f"{_f(r['geo_solve'])} | {_f(r['geo_solve'] / r['cppN_solve'])} | {_f(r['cppN_wall'])} | "
              f"{_f(r['geo_wall'])} | {_f(r['geo_wall'] / r['cppN_wall'])} | {_f(r['geo_outside'])} | "
              f"{r['outer']} / {r['inner']} | {r['misses']} |")
    print("\n| case | rest min size/mean | C++ | geomopt | rest min scaled Jacobian | C++ | geomopt | "
          "geomopt mean scaled Jacobian | certified C++ / geomopt |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        c = r.get("cpp_quality", {})
        g, rest = r["geo_quality"], r["rest"]
        print(f"| {r['case']} | {_f(rest['min_size_ratio'], '{:.4f}')} | {_f(c.get('min_size_ratio'), '{:.4f}')} | "
              f"{_f(g['min_size_ratio'], '{:.4f}')} | {_f(rest['min_scaled_jacobian'], '{:.4f}')} | "
              f"{_f(c.get('min_scaled_jacobian'), '{:.4f}')} | {_f(g['min_scaled_jacobian'], '{:.4f}')} | "
              f"{_f(g['mean_scaled_jacobian'], '{:.3f}')} | {r.get('cpp_certified', '-')} / {r['geo_certified']} |")
    split = " | ".join(["import", "read", "compile", "setup", "certify", "write", "other"])
    print(f"\n| case | elements | {split} | solve |")
    print("|---|---|" + "---|" * 8)
    for r in rows:
        s = r["geo_split"]
        cells = " | ".join(_f(s[k]) for k in ("import", "read", "compile", "setup", "certify", "write", "other"))
        print(f"| {r['case']} | {r['elements']:,} | {cells} | {_f(s['solve'])} |")
    if any(r["geo1_solve"] == r["geo1_solve"] for r in rows):
        print("\n| case | C++ solve 1 / all threads | geomopt solve 1 core / all cores |")
        print("|---|---|---|")
        for r in rows:
            print(f"| {r['case']} | {_f(r['cpp1_solve'] / r['cppN_solve'])} | "
                  f"{_f(r['geo1_solve'] / r['geo_solve'])} |")


def summary(rows):
    for dim in (2, 3):
        ratios = [r["geo_solve"] / r["cppN_solve"] for r in rows if r["dim"] == dim]
        ratios = [v for v in ratios if v == v]
        if ratios:
            print(f"{dim}D solve ratio (geomopt / C++ all cores): median {statistics.median(ratios):.2f}, "
                  f"largest {max(ratios):.2f} over {len(ratios)} cases (targets <= 0.6, <= 1.0)")
    big = [(r["case"], r["geo_wall"] / r["cppN_wall"]) for r in rows if r["elements"] >= 20_000]
    big = [(n, v) for n, v in big if v == v]
    if big:
        worst = max(big, key=lambda t: t[1])
        print(f"whole-process wall ratio from 20k elements: largest {worst[1]:.2f} ({worst[0]}), "
              f"{sum(v <= 1.0 for _, v in big)} of {len(big)} cases <= 1.0")
    q = [(r["case"], r["geo_quality"]["min_size_ratio"] / r["cpp_quality"]["min_size_ratio"])
         for r in rows if "cpp_quality" in r and r["cpp_quality"]["min_size_ratio"] > 0]
    if q:
        low = [f"{n} {v:.2f}" for n, v in q if v < 0.9]
        print(f"smallest size / mean, geomopt over C++: {sum(v >= 0.9 for _, v in q)} of {len(q)} cases at "
              f"least 0.9x" + (f"; below: {', '.join(low)}" if low else ""))
    print(f"persistent-cache misses in the measured rounds: {sum(r['misses'] for r in rows)}; "
          f"certified: geomopt {sum(r['geo_certified'] for r in rows)}/{len(rows)}, C++ "
          f"{sum(bool(r.get('cpp_certified')) for r in rows)}/{len(rows)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpp", help="folder of the authors' untangle2d / untangle3d (or the path of one)")
    ap.add_argument("--no-cpp", action="store_true", help="time geomopt alone")
    ap.add_argument("--geomopt", default=None, help="command running geomopt (default: geomopt on PATH)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", default="", help="comma-separated substrings: run the matching cases")
    ap.add_argument("--max-elements", type=float, default=float("inf"))
    ap.add_argument("--scaling", action="store_true", help="also run geomopt pinned to one core (taskset -c 0)")
    ap.add_argument("--root", default=os.path.join(os.environ.get("TMPDIR", "/tmp"), "geomopt-untangle-cases"),
                    help="where the case folders are written (kept)")
    ap.add_argument("--json", help="write every row here")
    a = ap.parse_args(argv)
    if a.no_cpp:
        a.cpp = None
    elif not (a.cpp and os.access(cpp_binary(a.cpp, 3), os.X_OK)):
        ap.error("give --cpp DIR holding the authors' untangle2d/untangle3d (see benchmarks/README.md), or --no-cpp")
    exe = shutil.which("geomopt")
    a.geomopt = a.geomopt.split() if a.geomopt else ([exe] if exe else [sys.executable, "-m", "geomopt"])
    Path(a.root).mkdir(parents=True, exist_ok=True)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    names = [*CASES, "armadillo-598"] if LIM_ARMADILLO.is_dir() else list(CASES)
    pats = [p for p in a.only.split(",") if p]
    names = [n for n in names if not pats or any(p in n for p in pats)]
    load0 = os.getloadavg()
    print(f"geomopt: {' '.join(a.geomopt)}; C++: {a.cpp}; {cores} cores; {a.repeat} rounds; "
          f"load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}", flush=True)
    rows = []
    for name in names:
        folder, dim, S, _, _ = prepare(name, a.root)
        if len(S) > a.max_elements:
            continue
        rows.append(measure(name, a, cores))
        r = rows[-1]
        print(f"{name}: {r['elements']} elements, geomopt solve {r['geo_solve']:.3f} s wall {r['geo_wall']:.2f} s, "
              f"C++ {cores} threads solve {r['cppN_solve']:.3f} s wall {r['cppN_wall']:.2f} s", file=sys.stderr, flush=True)
    print_tables(rows, cores)
    print()
    summary(rows)
    load1 = os.getloadavg()
    print(f"load average before {load0[0]:.2f}, after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()

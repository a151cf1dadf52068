"""A million elements end to end: untangling and parameterization at 10^6, and the kernels
against the machine's memory bandwidth (issue 34).

Usage::

    python benchmarks/million.py [--cpp DIR] [--cap 600] [--geomopt-cap 600] [--repeat 1]
                                 [--only PATTERN] [--root /work/scratch/million] [--no-warmup]
                                 [--no-geomopt] [--profile DIR] [--kernels] [--json FILE]
    python benchmarks/million.py --kernels --only none          # the bandwidth ratios alone

The geomopt processes are ``--geomopt CMD`` (default: this Python's ``-m geomopt``, which
imports the ``geomopt`` of the current directory first: run from the repository root to
measure the checkout).  ``--no-geomopt`` runs the C++ alone (to run it beside another
session; the rows merge by case).  ``--profile DIR`` attaches ``py-spy`` (``pip install
py-spy``) to each geomopt process by pid, 10 samples a second with idle waits, one raw
(collapsed-stack) file per case.

Cases (``CASES``; each written once under ``--root``, which should lie outside the
repository, and reused): a box of 55^3 cubes = 998,250 tets with its interior rotated by 90
degrees, its boundary twisted by one turn, its interior displaced by noise; a disk of 408
rings = 998,784 triangles with its interior rotated by 180 degrees and with noise (LIM case
folders, boundary fixed); and the Igea scan (``shared/data/meshes/igea_cut.ply``, a disk)
midpoint-subdivided once (trimesh) to 959,944 triangles, parameterized by ``geomopt param``.

Per case, ``--repeat`` rounds of whole processes timed from outside (start to exit):
``geomopt untangle CASE -o OUT --json`` (``geomopt param MESH -o OUT --json``), after one
process that fills the persistent compilation cache (``--no-warmup`` skips it; then the
split's ``compile`` holds the compilation), and with ``--cpp`` the authors' C++
(``untangle2d`` / ``untangle3d``, Garanzha et al. 2021, with all cores) on the same case
folder, killed after ``--cap`` seconds (its progress when killed is reported: outer
iterations started and inverted elements after the last finished one); geomopt is killed
after ``--geomopt-cap`` seconds (its last progress line is kept).  Reported per run:
wall seconds, geomopt's ``--json`` timing split, peak resident memory of the process
(``ru_maxrss`` from ``os.wait4``), outer / inner iterations, certified (geomopt's own exact
certificate; the C++ output by the exact orientation predicate), the load average before.

``--kernels`` also measures, in a fresh process per dimension at 10^6 elements (the
``benchmarks/scale.py`` grid and swirl map, symmetric Dirichlet): the machine's memory
bandwidth (best of 5 streaming copies of a 1 GiB array: 2 GiB moved each) and, warm (after
compilation), the median of several calls with ``block_until_ready`` of energy + gradient
(:meth:`geomopt.Objective.value_and_grad`), the assembled projected Hessian
(:meth:`geomopt.Objective.hessian`), the injective bound (:func:`geomopt.solvers.linesearch.max_injective_step`)
and one injective search (:class:`geomopt.solvers.linesearch.InjectiveSearch`), each as a ratio to the
time its bytes take to move once at that bandwidth: the arrays it must read (positions,
directions, element indices, rest inverse matrices and sizes, the free mask, the Hessian's
assembly maps) and write (gradient, Hessian values, the new point), each counted once; and as
a ratio to the time of its floating-point operations (XLA's cost analysis of the same jitted
computation) at the machine's float64 arithmetic rate (an XLA kernel of fused multiply-adds
alone): a kernel near neither limit is bound by something else (irregular gathers and
scatter-adds, latency).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import untangle_cpp as U  # noqa: E402

from geomopt.mesh import generators as G  # noqa: E402
from geomopt.exact.predicates import count_inverted  # noqa: E402

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes"

#: untangling cases, name -> Tangle factory (registered with untangle_cpp's cases: same writer)
UNTANGLE = {
    "box55-rot90": lambda: G.rotated_interior(*G.box_mesh(55, 55, 55), 90),
    "box55-twist1": lambda: G.twisted_box(55, 55, 1.0),
    "box55-noise": lambda: G.noisy_interior(*G.box_mesh(55, 55, 55), 2.0, seed=1),
    "disk408-rot180": lambda: G.rotated_interior(*G.disk_mesh(408), 180),
    "disk408-noise": lambda: G.noisy_interior(*G.disk_mesh(408), 2.0, seed=1),
}
#: surfaces to parameterize, name -> (shared mesh, midpoint subdivisions)
SURFACES = {"igea-sub1": ("igea_cut.ply", 1)}
CASES = [*UNTANGLE, *SURFACES]
U.CASES.update(UNTANGLE)


class Run(dict):
    """One process: wall seconds, exit code (None when killed at the cap), stdout, stderr,
    peak resident MB, whether it was capped, the 1-minute load average before it."""


def run_process(args, cap=None, env=None, profile=None) -> Run:
    """Run ``args`` to exit (or kill its process group after ``cap`` seconds), timing it from
    outside and reading its peak resident memory from ``os.wait4``; with ``profile`` (a file)
    py-spy samples it from outside (attached by pid: it writes its file when the process ends,
    killed or not, and adds nothing to its memory)."""
    load = os.getloadavg()[0]
    t = time.perf_counter()
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         start_new_session=True)
    spy = subprocess.Popen(["py-spy", "record", "--pid", str(p.pid), "-r", "10", "--idle", "--threads", "-f",
                            "raw", "-o", str(profile)], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL) if profile else None
    streams = {"stdout": [], "stderr": []}
    readers = [threading.Thread(target=lambda f, acc: acc.extend(f), args=(getattr(p, k), streams[k]), daemon=True)
               for k in streams]
    for r in readers:
        r.start()
    capped = False
    while True:
        pid, status, usage = os.wait4(p.pid, os.WNOHANG)
        if pid:
            break
        if cap and time.perf_counter() - t > cap:
            os.killpg(p.pid, signal.SIGKILL)
            pid, status, usage = os.wait4(p.pid, 0)
            capped = True
            break
        time.sleep(0.05)
    wall = time.perf_counter() - t
    p.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
    for r in readers:
        r.join()
    if spy is not None:
        spy.wait(timeout=120)
    return Run(wall=wall, rc=None if capped else p.returncode, stdout="".join(streams["stdout"]),
               stderr="".join(streams["stderr"]), peak_mb=usage.ru_maxrss / 1024.0, capped=capped, load=load)


def surface_file(name, root):
    """The subdivided surface of ``name`` as a PLY under ``root`` (written once), its faces."""
    import trimesh

    path = Path(root) / f"{name}.ply"
    src, levels = SURFACES[name]
    if not path.exists():
        mesh = trimesh.load(MESHES / src, process=False)
        V, F = mesh.vertices, mesh.faces
        for _ in range(levels):
            V, F = trimesh.remesh.subdivide(V, F)
        trimesh.Trimesh(V, F, process=False).export(path)
    return path, len(trimesh.load(path, process=False).faces)


def cpp_progress(text):
    """(outer iterations started, inverted elements after the last finished one or None)."""
    outer = text.count("iteration #")
    ninv = [int(line.rsplit("ninv:", 1)[1]) for line in text.splitlines() if "ninv:" in line]
    return outer, (ninv[-1] if ninv else None)


def measure_cpp(a, name, folder, dim, S, orientation, cores):
    """The C++ on one case folder with all cores, capped at ``a.cap`` seconds."""
    out = Path(a.root) / f"_cpp{'.obj' if dim == 2 else '.vtk'}"
    out.unlink(missing_ok=True)
    run = run_process(U.cpp_args(U.cpp_binary(a.cpp, dim), folder, dim, out), cap=a.cap,
                      env=dict(os.environ, OMP_NUM_THREADS=str(cores)))
    text = run["stderr"] + run["stdout"]
    outer, ninv = cpp_progress(text)
    certified = None
    if not run["capped"] and run["rc"] == 0 and out.exists():
        certified = count_inverted(U.read_map(out, dim), S, orientation=orientation) == 0
    return {"wall": run["wall"], "solve": U.cpp_solve_seconds(text), "peak_mb": run["peak_mb"],
            "capped": run["capped"], "outer": outer, "inverted_last": ninv, "certified": certified,
            "load": run["load"], "rc": run["rc"]}


def measure_geomopt(a, name, source, command):
    """One ``geomopt untangle`` / ``param`` process on ``source``."""
    out = Path(a.root) / ("_geomopt" + (".ply" if command == "param" else ".obj" if "disk" in name else ".vtk"))
    profile = None
    if a.profile:  # sampled, idle waits included, one raw (collapsed) stack file per case
        Path(a.profile).mkdir(parents=True, exist_ok=True)
        profile = Path(a.profile) / f"{name}.txt"
    run = run_process(U.geomopt_args(a.geomopt, source, out, command=command, quiet=False), cap=a.geomopt_cap,
                      profile=profile)
    js = U.json_summary(run["stdout"], run["stderr"])
    progress = [line for line in run["stderr"].splitlines() if line.startswith(("outer", "iter", "it "))]
    certified = js.get("certified") if command == "untangle" else js.get("injectivity") in ("local", "global")
    return {"wall": run["wall"], "peak_mb": run["peak_mb"], "capped": run["capped"], "load": run["load"],
            "split": js.get("timing", {}), "outer": js.get("outer_iterations"),
            "inner": js.get("inner_iterations", js.get("iterations")), "certified": bool(certified),
            "misses": js.get("cache_misses"), "outcome": js.get("outcome"), "message": js.get("message"),
            "injectivity": js.get("injectivity"), "last_progress": progress[-1] if progress else ""}


def measure(a, name, cores):
    """A row: the case, geomopt's rounds and the C++'s (untangling cases with ``--cpp``)."""
    if name in SURFACES:
        source, elements = surface_file(name, a.root)
        dim, command = 2, "param"
    else:
        t = time.perf_counter()
        source, dim, S, _, orientation = U.prepare(name, a.root)
        print(f"{name}: case ready in {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
        elements, command = len(S), "untangle"
    row = {"case": name, "dim": dim, "elements": elements, "geomopt": [], "cpp": []}
    if a.warmup and a.geomopt_runs:
        measure_geomopt(a, name, source, command)
    for _ in range(a.repeat):
        if a.cpp and command == "untangle":
            row["cpp"].append(measure_cpp(a, name, source, dim, S, orientation, cores))
            print(f"  C++: {row['cpp'][-1]}", file=sys.stderr, flush=True)
        if a.geomopt_runs:
            row["geomopt"].append(measure_geomopt(a, name, source, command))
            print(f"  geomopt: {row['geomopt'][-1]}", file=sys.stderr, flush=True)
    return row


def _median_run(runs):
    """The run of median wall time (the lower middle one of an even count)."""
    return sorted(runs, key=lambda r: r["wall"])[(len(runs) - 1) // 2] if runs else None


def _f(v, fmt="{:.1f}"):
    return "-" if v is None or v != v else fmt.format(v)


SPLIT = ("import", "read", "compile", "setup", "solve", "certify", "write", "other")


def print_cases(rows, cores):
    print(f"\n| case | elements | geomopt wall s | peak GB | outer / inner | certified | load | "
          f"C++ {cores} threads wall s | C++ solve s | C++ peak GB | C++ outer started | C++ certified | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        g, c = _median_run(r["geomopt"]), _median_run(r["cpp"])
        cells = [r["case"], f"{r['elements']:,}"]
        if g:
            gw = f"killed at {g['wall']:.0f}" if g["capped"] else _f(g["wall"])
            cells += [gw, _f(g["peak_mb"] / 1024, "{:.2f}"), f"{g['outer']} / {g['inner']}", str(g["certified"]),
                      _f(g["load"])]
        else:
            cells += ["-"] * 5
        if c:
            cw = f"killed at {c['wall']:.0f}" if c["capped"] else _f(c["wall"])
            outer = f"{c['outer']}" + (f" (ninv {c['inverted_last']} when killed)" if c["capped"] else "")
            cells += [cw, _f(c["solve"]), _f(c["peak_mb"] / 1024, "{:.2f}"), outer, str(c["certified"]),
                      _f(c["load"])]
        else:
            cells += ["-"] * 6
        print("| " + " | ".join(cells) + " |")
    print("\n| case | " + " | ".join(SPLIT) + " | total | cache misses |")
    print("|---|" + "---|" * (len(SPLIT) + 2))
    for r in rows:
        g = _median_run(r["geomopt"])
        if not g:
            continue
        s = g["split"]
        print(f"| {r['case']} | " + " | ".join(_f(s.get(k), "{:.2f}") for k in SPLIT) +
              f" | {_f(s.get('total'), '{:.2f}')} | {g['misses']} |")


# ------------------------------------------------------------------ the physical limit


def bandwidth_gbs(nbytes=1 << 30, repeat=5):
    """Streaming copy bandwidth, GB/s: (read + write) bytes / best time of ``repeat`` copies."""
    src = np.ones(nbytes // 8)
    dst = np.empty_like(src)
    best = min(_timed(lambda: np.copyto(dst, src)) for _ in range(repeat))
    return 2.0 * src.nbytes / best / 1e9


def flop_rate_gflops(n=1 << 20, depth=64, repeat=7):
    """Float64 arithmetic rate, GFLOP/s, of an XLA kernel that does nothing else: ``depth``
    fused multiply-adds per element of an ``n``-array in cache-sized passes (best of ``repeat``;
    XLA's own count of its flops)."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)

    @jax.jit
    def horner(x):
        y = x
        for _ in range(depth):
            y = y * x + 0.5
        return y

    x = jnp.linspace(0.1, 0.9, n)
    flops = _xla_flops(horner, x)
    jax.block_until_ready(horner(x))
    best = min(_timed(lambda: jax.block_until_ready(horner(x))) for _ in range(repeat))
    return flops / best / 1e9


def _xla_flops(jitted, *args):
    """XLA's count of the floating-point operations of ``jitted`` on ``args`` (its cost
    analysis: a division or square root counts one), None where the backend gives none."""
    cost = jitted.lower(*args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost["flops"]) if cost and cost.get("flops") else None


def _timed(f):
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def _warm_median(f, repeat):
    """Median seconds of ``repeat`` calls of ``f`` after one warm-up call (compilation)."""
    f()
    return statistics.median(_timed(f) for _ in range(repeat))


def _nbytes(*arrays):
    return int(sum(np.asarray(a).nbytes if not hasattr(a, "nbytes") else a.nbytes for a in arrays))


def kernel_rows(dim, repeat):
    """Warm kernel seconds at 10^6 elements of dimension ``dim`` and the bytes each moves."""
    import jax
    import jax.numpy as jnp

    import scale
    from geomopt import Objective, Problem
    from geomopt.energies import garanzha
    from geomopt.solvers.linesearch import InjectiveSearch, max_injective_step
    from geomopt.linalg.linsolve import SparseCholesky, repeated_solves_backend
    from geomopt.solvers import rest_laplacian

    jax.config.update("jax_enable_x64", True)
    V, S = scale._mesh(1e6, dim)
    fixed = G.boundary_vertices(S, len(V))
    P = (Problem.planar if dim == 2 else Problem.tets)(V, S, fixed, V[fixed])
    obj = Objective(P, "symmetric_dirichlet")
    params = obj.params()
    x = jnp.asarray(scale._swirl(V))
    d = jnp.asarray(V) - x  # towards the rest map (the minimum): an injective path
    Sd, Minv, vol = obj.geom
    free = obj.free_mask
    value, grad = obj.value_and_grad(x, params)
    rows = []

    def add(name, f, reads, writes, note="", flops=None):
        t = _warm_median(f, repeat)
        rows.append({"kernel": name, "dim": dim, "elements": len(S), "seconds": t,
                     "bytes": _nbytes(*reads) + _nbytes(*writes), "flops": flops, "note": note})
        print(f"  {dim}D {name}: {t:.4f} s", file=sys.stderr, flush=True)

    add("energy + gradient", lambda: jax.block_until_ready(obj.value_and_grad(x, params)),
        (Sd, x, Minv, vol, free), (grad,), flops=_xla_flops(jax.jit(lambda y: obj.value_and_grad(y, params)), x))
    data = obj.hessian(x, params, "clamp")[2]
    blocks, swap, _ = obj.block_assembly
    add("Hessian (values, clamp)", lambda: jax.block_until_ready(obj.hessian(x, params, "clamp")),
        (Sd, x, Minv, vol, free, blocks, swap, obj.pattern.gather), (grad, data),
        f"nnz {obj.pattern.nnz:,}")
    add("injective bound", lambda: jax.block_until_ready(max_injective_step(Sd, x, d)), (Sd, x, d), (),
        flops=_xla_flops(jax.jit(max_injective_step), Sd, x, d))
    search = InjectiveSearch()
    evals = search(obj, params, x, float(value), grad, d)[4]
    add("injective search", lambda: search(obj, params, x, float(value), grad, d),
        (Sd, x, d, Minv, vol, free), (x, grad), f"{evals} energy evaluation(s)")
    # what an untangling inner iteration costs besides its search: Garanzha's energy (eps,
    # lam traced) and the L-BFGS Laplacian seed's host solve (time only: the factor's size
    # is the backend's)
    unt = Objective(P, garanzha.with_params(eps=1e-3, lam=1.0 / 127 if dim == 2 else 1.0))
    up = unt.params()
    g_unt = unt.value_and_grad(x, up)[1]
    add("energy + gradient (untangling)", lambda: jax.block_until_ready(unt.value_and_grad(x, up)),
        (Sd, x, unt.geom[1], unt.geom[2], unt.free_mask), (g_unt,),
        flops=_xla_flops(jax.jit(lambda y: unt.value_and_grad(y, up)), x))
    free_v = np.flatnonzero(np.asarray(obj.free_dofs).all(axis=1))
    K = rest_laplacian(P)[free_v][:, free_v].tocsc()
    backend = repeated_solves_backend(dim, len(free_v))
    t = time.perf_counter()
    chol = SparseCholesky.factored(K, backend)
    factor_s = time.perf_counter() - t
    q = np.ascontiguousarray(np.asarray(grad)[free_v])
    add("Laplacian seed solve", lambda: chol.solve(q), (), (),
        f"{backend}, {len(free_v):,} rows x {dim} right-hand sides; factored once in {factor_s:.2f} s")
    rows[-1]["bytes"] = None
    return rows


def kernels_in_subprocess(dim, repeat):
    """:func:`kernel_rows` in a fresh process (its memory its own), with the bandwidth."""
    run = run_process([sys.executable, __file__, "--kernel-child", str(dim), "--repeat", str(repeat)])
    if run["rc"] != 0:
        print(run["stderr"][-2000:], file=sys.stderr)
        return {"dim": dim, "error": f"exit status {run['rc']}", "rows": []}
    out = json.loads(run["stdout"].strip().splitlines()[-1])
    out.update(peak_mb=run["peak_mb"], load=run["load"])
    return out


def print_kernels(results):
    """The kernels' table: each kernel's time against the time of its bytes at the streaming
    bandwidth and of its flops (XLA's count) at the measured arithmetic rate; the last column
    is the time over the larger of the two (1 = at the machine's limit)."""
    print("\n| kernel | dim | elements | warm s (median) | bytes once (MB) | at bandwidth s | ratio | "
          "MFLOP | at flop rate s | ratio to the larger | note |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for res in results:
        bw, rate = res.get("bandwidth_gbs"), res.get("gflops")
        for r in res["rows"]:
            t_bytes = r["bytes"] / (bw * 1e9) if r["bytes"] else None
            t_flops = r["flops"] / (rate * 1e9) if r.get("flops") and rate else None
            limit = max((t for t in (t_bytes, t_flops) if t), default=None)
            mb = r["bytes"] / 1e6 if r["bytes"] else None
            mflop = r["flops"] / 1e6 if r.get("flops") else None
            print(f"| {r['kernel']} | {r['dim']} | {r['elements']:,} | {r['seconds']:.4f} | {_f(mb, '{:.0f}')} | "
                  f"{_f(t_bytes, '{:.4f}')} | {_f(r['seconds'] / t_bytes if t_bytes else None)} | "
                  f"{_f(mflop, '{:.0f}')} | {_f(t_flops, '{:.4f}')} | {_f(r['seconds'] / limit if limit else None)} | "
                  f"{r['note']} |")
    for res in results:
        print(f"{res['dim']}D: bandwidth {_f(res.get('bandwidth_gbs'), '{:.2f}')} GB/s (streaming copy, best of 5), "
              f"arithmetic {_f(res.get('gflops'), '{:.1f}')} GFLOP/s (fused multiply-adds, best of 7), "
              f"peak {_f(res.get('peak_mb', float('nan')) / 1024, '{:.2f}')} GB, load {_f(res.get('load'))}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpp", help="folder of the authors' untangle2d / untangle3d (or the path of one)")
    ap.add_argument("--cap", type=float, default=600.0, help="seconds after which the C++ is killed")
    ap.add_argument("--geomopt-cap", type=float, default=600.0, help="seconds after which geomopt is killed")
    ap.add_argument("--geomopt", default=None, help="command running geomopt (default: this Python's -m geomopt)")
    ap.add_argument("--repeat", type=int, default=1, help="measured rounds per case (kernels: calls, default 5)")
    ap.add_argument("--only", default="", help="comma-separated substrings: run the matching cases")
    ap.add_argument("--root", default="/work/scratch/million", help="where the cases are written (kept)")
    ap.add_argument("--no-geomopt", dest="geomopt_runs", action="store_false",
                    help="run the C++ only (e.g. in a second session; rows merge by case)")
    ap.add_argument("--no-warmup", dest="warmup", action="store_false",
                    help="no cache-filling process before the measured ones")
    ap.add_argument("--profile", help="record each geomopt process with py-spy into this folder")
    ap.add_argument("--kernels", action="store_true", help="also the kernels against the memory bandwidth")
    ap.add_argument("--kernel-dims", type=int, nargs="+", default=[2, 3], choices=(2, 3))
    ap.add_argument("--json", help="write every row here")
    ap.add_argument("--kernel-child", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.kernel_child:
        out = {"dim": a.kernel_child, "bandwidth_gbs": bandwidth_gbs(), "gflops": flop_rate_gflops()}
        out["rows"] = kernel_rows(a.kernel_child, max(a.repeat, 5))
        print(json.dumps(out))
        return 0
    if a.cpp and not os.access(U.cpp_binary(a.cpp, 3), os.X_OK):
        ap.error("--cpp DIR must hold the authors' untangle2d/untangle3d (see benchmarks/README.md)")
    a.geomopt = a.geomopt.split() if a.geomopt else [sys.executable, "-m", "geomopt"]
    Path(a.root).mkdir(parents=True, exist_ok=True)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    pats = [p for p in a.only.split(",") if p]
    names = [n for n in CASES if not pats or any(p in n for p in pats)]
    load0 = os.getloadavg()
    print(f"geomopt: {' '.join(a.geomopt)}; C++: {a.cpp} (cap {a.cap:.0f} s); {cores} cores; {a.repeat} rounds; "
          f"load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}", flush=True)
    rows = [measure(a, name, cores) for name in names]
    if rows:
        print_cases(rows, cores)
    kernels = [kernels_in_subprocess(dim, max(a.repeat, 5)) for dim in a.kernel_dims] if a.kernels else []
    if kernels:
        print_kernels(kernels)
    load1 = os.getloadavg()
    print(f"\nload average before {load0[0]:.2f}, after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    if a.json:
        for r in rows:
            for run in r["geomopt"] + r["cpp"]:
                run.pop("stdout", None)
        Path(a.json).write_text(json.dumps({"cases": rows, "kernels": kernels}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())

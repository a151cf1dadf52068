"""``geomopt.plot.show`` off-screen: first and later frames per viewer, beside the NumPy pictures.

For each viewer (polyscope, pyvista) in a fresh process: the import, the first
``show(result, screenshot=PATH)`` of the camel head's parameterization (the viewer starts its
renderer: polyscope's EGL backend, a VTK window), the later frames (``show`` again, median of
``--repeat``), and a frame of another map (a 6k-tet untangled box, coloured by distortion).
Beside them, in its own process, the matplotlib picture of the same map
(``geomopt.plot.param_figure`` saved as PNG, the NumPy rasteriser).  Wall seconds; the solve
is not timed.  Rows for a viewer that is not installed say so.

    python benchmarks/view.py                 # 800 x 800 pixels
    python benchmarks/view.py --size 1200 900 --repeat 9
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings


def _maps():
    import geomopt
    from geomopt.mesh import generators

    V, F = geomopt.data.load("camelhead")
    param = geomopt.parameterize(V, F, progress=False)
    tangle = generators.bent_box(8, 16, 120.0)
    tets = geomopt.untangling.untangle(tangle.problem(), tangle.x0, progress=False)
    return param, tets


def measure(backend, size, repeat):
    """One process: the timings of one viewer (or of the NumPy figure), as a dict."""
    warnings.simplefilter("ignore")
    param, tets = _maps()
    out = tempfile.mkdtemp()
    if backend == "numpy":
        from geomopt import plot

        t = time.perf_counter()
        plot.save_param_figure(os.path.join(out, "fig.png"), param.problem.rest_vertices,
                               param.problem.input_simplices, param.x)
        return {"figure": time.perf_counter() - t}
    import importlib

    t = time.perf_counter()
    try:
        importlib.import_module(backend)
    except ImportError:
        return {"missing": True}
    rows = {"import": time.perf_counter() - t}
    from geomopt import plot

    def frame(result, name):
        t = time.perf_counter()
        plot.show(result, backend=backend, screenshot=os.path.join(out, name), size=size)
        return time.perf_counter() - t

    rows["first"] = frame(param, "first.png")
    rows["later"] = statistics.median(frame(param, f"later{k}.png") for k in range(repeat))
    rows["tets"] = statistics.median(frame(tets, f"tets{k}.png") for k in range(max(repeat // 2, 1)))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, nargs=2, default=(800, 800))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(measure(args.child, tuple(args.size), args.repeat)))
        return
    print(f"load average before {os.getloadavg()}; {args.size[0]} x {args.size[1]} pixels")
    print(f"{'':>10} {'import s':>9} {'first s':>8} {'later s':>8} {'tets s':>7}")
    for backend in ("polyscope", "pyvista", "numpy"):
        cmd = [sys.executable, __file__, "--child", backend, "--size", *map(str, args.size),
               "--repeat", str(args.repeat)]
        r = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.splitlines()[-1])
        if r.get("missing"):
            print(f"{backend:>10}  not installed")
        elif backend == "numpy":
            print(f"{'matplotlib':>10} {'':>9} {r['figure']:8.2f}  (param_figure saved as PNG, 1760 x 825)")
        else:
            print(f"{backend:>10} {r['import']:9.2f} {r['first']:8.2f} {r['later']:8.3f} {r['tets']:7.3f}")
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()

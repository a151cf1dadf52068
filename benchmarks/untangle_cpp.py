"""3D untangling side by side with the authors' C++ (Garanzha et al. 2021, ``untangle3d``).

Usage::

    python benchmarks/untangle_cpp.py --cpp /path/to/untangle3d [--repeat 3] [--only PATTERN]
    python benchmarks/untangle_cpp.py --no-cpp                  # geomopt only (no reference)

The reference is not part of geomopt: build it once, outside the repository::

    git clone https://github.com/ssloy/invertible-maps /tmp/im
    cmake -S /tmp/im/cpp -B /tmp/im/build -DCMAKE_BUILD_TYPE=Release && make -C /tmp/im/build -j2

Cases: generated 3D families of 1.6-8.3 x 10^4 tets with fixed boundaries (cubes with the
interior rotated by 90/180 degrees, twisted by half and whole turns, noisy interiors; rods twisted
and bent) and the LIM benchmark's armadillo-598 (``../shared/data/lim``, skipped with a message
when absent).  Per case: geomopt once cold (compilation), then ``--repeat`` rounds, each running
the C++ (``OMP_NUM_THREADS=1``, as in the paper's timings) and then geomopt warm, so that both see
the same machine load.  C++ seconds are its own printed solve time ("running time"); geomopt
seconds are the whole :func:`geomopt.untangle.untangle` call (set-up, outer loop,
certification).  Both outputs are checked with the exact orientation predicate
(:func:`geomopt.predicates.count_inverted`); a row's ``certified`` is true only when both have no
inverted tet.  Prints one row per case and the median and largest geomopt / C++ ratio.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from geomopt import generators as G  # noqa: E402
from geomopt.io import read_vtk_tets, write_vtk_tets  # noqa: E402
from geomopt.lim import LimCase  # noqa: E402
from geomopt.predicates import count_inverted  # noqa: E402
from geomopt.untangle import lim_problem, untangle  # noqa: E402

LIM_ARMADILLO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lim" / "3D" / \
    "Deform_Armadillo" / "armadillo-598"

#: name -> generator of a geomopt.generators.Tangle (fixed boundary)
FAMILIES = {
    "cube24-rot90": lambda: G.rotated_interior(*G.box_mesh(24, 24, 24), 90),
    "cube24-rot180": lambda: G.rotated_interior(*G.box_mesh(24, 24, 24), 180),
    "cube20-twist1": lambda: G.twisted_box(20, 20, 1.0),
    "cube20-twist0.5": lambda: G.twisted_box(20, 20, 0.5),
    "cube20-noise": lambda: G.noisy_interior(*G.box_mesh(20, 20, 20), 2.0, seed=1),
    "rod8x64-twist1.5": lambda: G.twisted_box(8, 64, 1.5),
    "rod8x64-twist0.5": lambda: G.twisted_box(8, 64, 0.5),
    "rod8x64-bend180": lambda: G.bent_box(8, 64, 180.0),
    "rod10x80-bend270": lambda: G.bent_box(10, 80, 270.0),
    "cube14-rot180": lambda: G.rotated_interior(*G.box_mesh(14, 14, 14), 180),
}


def load(name, tmp):
    """(problem, x0, tets, orientation, init.vtk, rest.vtk) of a case."""
    if name == "armadillo-598":
        case = LimCase.read(LIM_ARMADILLO)
        problem, x0, orientation, _ = lim_problem(case)
        return problem, x0, case.simplices, orientation, LIM_ARMADILLO / "init.vtk", LIM_ARMADILLO / "rest.vtk"
    t = FAMILIES[name]()
    init, rest = Path(tmp) / f"{name}-init.vtk", Path(tmp) / f"{name}-rest.vtk"
    write_vtk_tets(init, t.x0, t.simplices)
    write_vtk_tets(rest, t.rest, t.simplices)
    return t.problem(), t.x0, t.simplices, 1, init, rest


def run_cpp(binary, init, rest, tets, orientation, out):
    """The C++ solve seconds and whether its output has no inverted tet."""
    p = subprocess.run([binary, str(init), str(rest), str(out)], capture_output=True, text=True,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
    m = re.search(r"running time: ([0-9.e+-]+) s", p.stderr + p.stdout)
    if p.returncode != 0 or m is None:
        return float("nan"), False
    X, _ = read_vtk_tets(out)
    return float(m.group(1)), count_inverted(X, tets, orientation=orientation) == 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpp", help="the authors' untangle3d binary")
    ap.add_argument("--no-cpp", action="store_true", help="time geomopt alone")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", default="", help="run the cases whose name contains this")
    a = ap.parse_args(argv)
    if not a.no_cpp and not (a.cpp and os.access(a.cpp, os.X_OK)):
        ap.error("give --cpp PATH to the authors' untangle3d binary (see the module docstring), or --no-cpp")
    names = [n for n in [*FAMILIES, "armadillo-598"] if a.only in n]
    if "armadillo-598" in names and not LIM_ARMADILLO.is_dir():
        print(f"skipping armadillo-598: {LIM_ARMADILLO} not found", file=sys.stderr)
        names.remove("armadillo-598")
    ratios = []
    print("| case | tets | C++ s | geomopt s | ratio | outer | inner | evaluations | compile s | certified |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            problem, x0, tets, orientation, init, rest = load(name, tmp)
            t = time.perf_counter()
            r = untangle(problem, x0, progress=False)
            cold = time.perf_counter() - t
            cpp_s, geo_s, ok = [], [], True
            for _ in range(a.repeat):
                if not a.no_cpp:
                    s, cok = run_cpp(a.cpp, init, rest, tets, orientation, Path(tmp) / "out.vtk")
                    cpp_s.append(s)
                    ok &= cok
                t = time.perf_counter()
                r = untangle(problem, x0, progress=False)
                geo_s.append(time.perf_counter() - t)
                ok &= bool(r.success) and count_inverted(r.x, tets, orientation=orientation) == 0
            c = statistics.median(cpp_s) if cpp_s else float("nan")
            g = statistics.median(geo_s)
            if cpp_s:
                ratios.append(g / c)
            print(f"| {name} | {problem.n_elements} | {c:.2f} | {g:.2f} | {g / c:.2f} | {r.outer_iterations} | "
                  f"{r.inner_iterations} | {r.info['evaluations']} | {max(cold - g, 0.0):.1f} | {ok} |", flush=True)
    if ratios:
        print(f"\nmedian ratio {statistics.median(ratios):.2f}, largest {max(ratios):.2f} "
              f"(geomopt / C++ solve seconds, {len(ratios)} cases, load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()

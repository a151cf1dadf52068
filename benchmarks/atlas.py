"""Texture atlases: geomopt's ``make_atlas`` beside xatlas (PyPI ``xatlas``, default options).

For every mesh both tools make an atlas of the same ``V``, ``F``; both atlases are measured by
the same code (:func:`geomopt.atlas.atlas_metrics`, from per-corner UV indices alone): charts,
seam length (3D length of the input edges whose two faces do not share the edge's UVs), the
area-weighted mean symmetric Dirichlet of the map scaled to the surface's area (4 = isometric),
the worst triangle, packing efficiency (UV area / bounding square), mirrored charts (negative
total signed UV area).  "certified" is geomopt's exact atlas certificate; for xatlas the same
certificate is run on its output (it fails on mirrored charts).  Wall times: the first call in
this process (cold: JIT compilation for geomopt) and a second call (warm).

    python benchmarks/atlas.py                                   # shared/data/closed + generated
    python benchmarks/atlas.py MESH.off ... [--no-generated]     # more meshes (any readable file)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CLOSED = REPO.parent / "shared/data/closed"


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def meshes(paths, generated):
    from geomopt.mesh import generators
    from geomopt.io import read_mesh

    out = {}
    for p in paths or sorted(CLOSED.glob("*.off")):
        out[Path(p).stem] = read_mesh(p)
    if generated:
        out["plate-genus5 (generated)"] = generators.holed_plate(5, cells=3)
    return out


def run_xatlas(V, F):
    import xatlas

    t = time.perf_counter()
    _, uv_faces, uv = xatlas.parametrize(V, F)
    return uv, uv_faces.astype(np.int64), time.perf_counter() - t


def run_geomopt(V, F):
    from geomopt.atlas import make_atlas

    t = time.perf_counter()
    a = make_atlas(V, F, progress=False)
    return a, time.perf_counter() - t


def row(name, tool, m, certified, cold, warm):
    return (f"| {name} | {tool} | {m.charts} | {m.seam_length:.4g} | {m.mean_symmetric_dirichlet:.4f} | "
            f"{m.worst_symmetric_dirichlet:.4g} | {m.efficiency:.3f} | {m.mirrored_charts} | "
            f"{'yes' if certified else 'no'} | {cold:.2f} / {warm:.2f} |")


def main(argv=None):
    from geomopt import MeshError
    from geomopt.atlas import atlas_metrics, certify_atlas, uv_charts

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("meshes", nargs="*", help="mesh files (default: shared/data/closed/*.off)")
    ap.add_argument("--no-generated", action="store_true", help="skip the generated genus-5 plate")
    args = ap.parse_args(argv)
    print("| mesh | tool | charts | seam length | mean sym. Dirichlet | worst | efficiency | mirrored | "
          "certified | seconds cold / warm |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, (V, F) in meshes(args.meshes, not args.no_generated).items():
        log(f"{name}: {len(V)} vertices, {len(F)} faces")
        uv, T, cold = run_xatlas(V, F)
        _, _, warm = run_xatlas(V, F)
        ok = certify_atlas(uv, T, uv_charts(T)[1]).ok
        print(row(name, "xatlas", atlas_metrics(V, F, uv, T), ok, cold, warm), flush=True)
        try:
            a, cold = run_geomopt(V, F)
        except MeshError as exc:  # refused (non-manifold...): say so and go on with the next mesh
            print(f"| {name} | geomopt | refused: {exc} | | | | | | | |", flush=True)
            continue
        a, warm = run_geomopt(V, F)
        print(row(name, "geomopt", a.metrics, a.success, cold, warm), flush=True)


if __name__ == "__main__":
    main()

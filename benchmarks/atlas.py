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


def cad_cylinder(n=64, r=1.0, h=5.0):
    """A closed cylinder as CAD exports triangulate it: two triangles per side facet, each cap a
    fan from one rim vertex (slivers)."""
    t = 2 * np.pi * np.arange(n) / n
    bottom = np.c_[r * np.cos(t), r * np.sin(t), np.zeros(n)]
    i, j = np.arange(n), (np.arange(n) + 1) % n
    k = np.arange(1, n - 1)
    side = np.stack([np.c_[i, j, n + j], np.c_[i, n + j, n + i]], axis=1).reshape(-1, 3)
    caps = np.stack([np.c_[0 * k, k + 1, k], np.c_[n + 0 * k, n + k, n + k + 1]], axis=1).reshape(-1, 3)
    return np.r_[bottom, bottom + [0.0, 0.0, h]], np.r_[side, caps]


def holed_block(n=16, a=2.0, r=0.5, h=1.0):
    """A square block with a round through hole (genus 1): each face a ring of quads, split in two."""
    t = 2 * np.pi * np.arange(n) / n
    c = np.c_[np.cos(t), np.sin(t)]
    square, ring = c / np.abs(c).max(axis=1, keepdims=True) * a / 2, c * r
    V = np.concatenate([np.c_[p, np.full(n, z)] for z in (0.0, h) for p in (square, ring)])
    i, j = np.arange(n), (np.arange(n) + 1) % n
    S0, R0, S1, R1 = 0, n, 2 * n, 3 * n
    F = [np.c_[S0 + i, R0 + j, S0 + j], np.c_[S0 + i, R0 + i, R0 + j],  # bottom (normal -z)
         np.c_[S1 + i, S1 + j, R1 + j], np.c_[S1 + i, R1 + j, R1 + i],  # top
         np.c_[S0 + i, S0 + j, S1 + j], np.c_[S0 + i, S1 + j, S1 + i],  # outer wall
         np.c_[R0 + i, R1 + j, R0 + j], np.c_[R0 + i, R1 + i, R1 + j]]  # the hole's wall
    return V, np.stack(F, axis=1).reshape(-1, 3)  # the 8 faces of each step around, in turn


def meshes(paths, generated):
    from geomopt.mesh import generators
    from geomopt.io import read_mesh

    out = {}
    for p in paths or sorted(CLOSED.glob("*.off")):
        out[Path(p).stem] = read_mesh(p)
    if generated:
        out["plate-genus5 (generated)"] = generators.holed_plate(5, cells=3)
        out["CAD cylinder (generated)"] = cad_cylinder()
        out["holed block (generated)"] = holed_block()
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
    ap.add_argument("--no-generated", action="store_true",
                    help="skip the generated meshes (a genus-5 plate, a CAD-style cylinder, a holed block)")
    args = ap.parse_args(argv)
    try:
        import xatlas  # noqa: F401
    except ImportError:
        ap.exit(2, "atlas.py: xatlas is not installed; install the benchmark extra: pip install \".[bench]\"\n")
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
        print(row(name, "geomopt", a.details.metrics, a.success, cold, warm), flush=True)


if __name__ == "__main__":
    main()

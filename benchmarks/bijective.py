"""Bijective (scaffold) vs plain free-boundary parameterization, and the global certificate.

For every case both modes start from the same map and minimise symmetric Dirichlet with
projected Newton:

* plain: :func:`geomopt.parameterize` (locally injective only);
* bijective: :func:`geomopt.bijective.bijective_parameterize`.

Cases: the shared meshes (``../shared/data/meshes`` from the repository root; Tutte start) and
generated surfaces whose flattening may overlap (:mod:`geomopt.mesh.generators`: spiral strips from
their ``xy`` projection, a ruffled disk and saddles from Tutte).  Each mode is run once cold (JIT
compilation) and ``--repeat`` times warm; the warm run with the median total time is reported
(total = the whole call: start map, scaling, solve, and for bijective the scaffold and the
certificate).  For each result the exact certificate
(:func:`geomopt.exact.certify.certify_bijective`) counts inverted triangles and crossing boundary edge
pairs; its time is reported for the plain result.

``--certificate-edges N`` (default 10^6) also times the certificate on a polygon of N edges and
on a strip mesh with N boundary edges (loop given, as in the solver).

    python benchmarks/bijective.py                      # all cases
    python benchmarks/bijective.py --cases spiral ruffle camelhead --repeat 3
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MESH_DIR = REPO.parent / "shared/data/meshes"
SHARED = ("camelhead", "bunny_cut", "face", "armadillo_cut_low", "igea_cut")


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def generated():
    from geomopt.mesh import generators as g

    return {
        "spiral": (*g.spiral_strip(), "xy"),
        "spiral-long": (*g.spiral_strip(turns=5.0, spacing=0.4, width=0.25, lift=2.5), "xy"),
        "ruffle": (*g.ruffled_disk(24, waves=12, amplitude=0.6), None),
        "saddle": (*g.saddle(24, order=2, amplitude=2.0), None),
        "monkey-saddle": (*g.saddle(24, order=3, amplitude=2.0), None),
    }


def load(name, gen):
    from geomopt.io import read_mesh

    if name in gen:
        V, F, start = gen[name]
        return V, F, (V[:, :2].copy() if start == "xy" else None)
    path = next((p for p in sorted(MESH_DIR.glob(name + ".*")) if p.suffix != ".md"), None)
    if path is None:
        raise SystemExit(f"no mesh {name!r} in {MESH_DIR}")
    V, F = read_mesh(path)[:2]
    return V, F, None


def timed(fn, repeat):
    fn()  # cold: compiles
    runs = []
    for _ in range(repeat):
        t = time.perf_counter()
        r = fn()
        runs.append((time.perf_counter() - t, r))
    runs.sort(key=lambda tr: tr[0])
    return runs[(len(runs) - 1) // 2]


def run_case(name, gen, repeat, args):
    import geomopt
    from geomopt.exact.certify import certify_bijective
    from geomopt.bijective import ScaffoldOptions, bijective_parameterize

    V, F, x0 = load(name, gen)
    log(f"{name}: {len(V)} vertices, {len(F)} triangles")
    t_plain, plain = timed(lambda: geomopt.parameterize(V, F, x0=x0, progress=False), repeat)
    area = plain.problem.volumes.sum()
    cert_times = []
    for _ in range(max(repeat, 3)):
        c = certify_bijective(plain.x, plain.problem.simplices)
        cert_times.append(c.seconds)
    cert_plain = c
    opts = ScaffoldOptions(**{k: v for k, v in (("scaffold_weight", args.weight), ("inner_steps", args.inner))
                              if v is not None})
    t_bij, bij = timed(lambda: bijective_parameterize(V, F, x0=x0, options=opts, progress=False), repeat)
    cb = bij.certificate
    row = dict(
        case=name, faces=len(F), boundary=len(cb.loop),
        E_plain=plain.energy / area, t_plain=t_plain, it_plain=plain.stats.iterations,
        flips_plain=plain.certificate.inverted, cross_plain=len(cert_plain.crossings),
        cert_s=statistics.median(cert_times),
        E_bij=bij.energy / area, t_bij=t_bij, it_bij=bij.stats.iterations,
        outer=bij.stats.outer_iterations, flips_bij=cb.inverted, cross_bij=len(cb.crossings),
        success=bij.success, injectivity=bij.injectivity,
    )
    log("  " + "  ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    return row


def table(rows):
    head = ("| case | faces | bnd edges | E plain | t plain (s) | flips / crossings plain | cert (s) "
            "| E bijective | t bijective (s) | outer / inner it | flips / crossings bij | success "
            "| E gap | t ratio |")
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        gap = (r["E_bij"] - r["E_plain"]) / r["E_plain"]
        ok = "" if r["cross_plain"] == 0 else " (plain overlaps)"
        out.append(
            f"| {r['case']} | {r['faces']} | {r['boundary']} | {r['E_plain']:.6f} | {r['t_plain']:.2f} "
            f"| {r['flips_plain']} / {r['cross_plain']} | {r['cert_s']:.4f} | {r['E_bij']:.6f} "
            f"| {r['t_bij']:.2f} | {r['outer']} / {r['it_bij']} | {r['flips_bij']} / {r['cross_bij']} "
            f"| {'yes' if r['success'] else 'NO'} ({r['injectivity']}) | {100 * gap:+.3f}%{ok} "
            f"| {r['t_bij'] / r['t_plain']:.2f}x |")
    return "\n".join(out)


def certificate_timing(n_edges, repeat):
    """Median seconds of polygon_crossings on an n-edge spiral band polygon and of
    certify_bijective on a strip mesh with about n boundary edges."""
    from geomopt.exact.certify import certify_bijective, polygon_crossings
    from geomopt.mesh.generators import spiral_strip
    from geomopt.exact.topology import check_disk

    half = n_edges // 2
    t = np.linspace(0.0, 40 * np.pi, half)
    r = 1 + 0.3 * t / (2 * np.pi)
    P = np.concatenate([np.stack([r * np.cos(t), r * np.sin(t)], 1),
                        np.stack([(r + 0.1) * np.cos(t), (r + 0.1) * np.sin(t)], 1)[::-1]])
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        q = polygon_crossings(P)
        times.append(time.perf_counter() - t0)
    # a planar strip one quad wide with about n_edges boundary edges (rows as long as wide)
    turns, radius, spacing = 20.0, 1.0, 0.5
    arc = 2 * np.pi * turns * (radius + spacing * turns / 2)
    V, F = spiral_strip(turns=turns, radius=radius, spacing=spacing, width=arc / half, lift=0.0,
                        n_across=1)
    loop = check_disk(F, len(V))
    x = V[:, :2]
    mesh_times = []
    for _ in range(repeat):
        mesh_times.append(certify_bijective(x, F, loop).seconds)
    return len(P), len(q), statistics.median(times), len(loop), statistics.median(mesh_times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", help="case names (generated or shared mesh stems); "
                    "default: all generated and the shared meshes but igea_cut")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--weight", type=float, default=None, help="scaffold_weight (default: the library's)")
    ap.add_argument("--inner", type=int, default=None, help="inner_steps (default: the library's)")
    ap.add_argument("--certificate-edges", type=int, default=10**6)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(REPO))
    from geomopt.bijective import bijective_parameterize  # noqa: F401  (import check)

    gen = generated()
    cases = args.cases or [*gen, *[m for m in SHARED if m != "igea_cut"]]
    rows = [run_case(c, gen, args.repeat, args) for c in cases]
    print(table(rows))
    if args.certificate_edges:
        k, q, t_poly, kb, t_mesh = certificate_timing(args.certificate_edges, max(args.repeat, 3))
        print(f"\ncertificate: polygon_crossings on {k} edges: {t_poly:.3f} s ({q} crossings); "
              f"certify_bijective on a strip with {kb} boundary edges: {t_mesh:.3f} s (median)")


if __name__ == "__main__":
    main()

"""Surface smoothing side by side: geomopt.fairing's methods beside trimesh.smoothing's filters
on noisy copies of clean closed meshes.


Each clean mesh gets Gaussian noise of ``--noise`` mean edge lengths per coordinate (default 0.5%,
2% and 20%); every method smooths the noisy copy, and its output is measured against the clean
surface: the RMS distance of the output vertices to the clean surface (closest points, over the
bounding-box diagonal), the relative volume change against the clean volume, the faces folded
by geomopt's exact certificate, the faces opposing the clean surface (their normal at a negative
or zero dot product with the same face's clean normal), the smallest angle and the wall time.
The anchors: trimesh's ``filter_laplacian``, ``filter_taubin`` and ``filter_humphrey`` with
their defaults (10 iterations).

    python benchmarks/fairing.py [--meshes cheburashka cow] [--noise 0.2 0.5] [--methods taubin energy]
    python benchmarks/fairing.py --scale 2 --methods taubin implicit least_squares   # 10^5 vertices

``--scale k`` subdivides the mesh ``k`` times (4^k as many faces) before the noise: the timing
rows at 10^5 (cheburashka, k = 2) and 10^6 (k = 4) vertices.  ``relax`` rows also give the
two-sided distance between the output and the input surface (at 45 points per face).

    python benchmarks/fairing.py --timing --meshes cheburashka --scale 2 --noise 0.02 --repeat 3

``--timing`` times instead each method of ``--methods`` (default taubin, implicit, least_squares)
beside its anchor, in the same process and alternating, ``--repeat`` times after one cold round:
trimesh's ``filter_taubin`` (10 iterations) and ``filter_laplacian``, and for the solved methods
libigl's recipe with SciPy (cotangent and barycentric mass matrices, one ``spsolve`` of
``(M - h^2 L) p = M p0``; the normal equations ``(A^T A + I) p = p0`` of the uniform ``A = D^-1 L
- I``).  Wall and CPU seconds (``time.process_time``, all threads), medians, and the ratio of
geomopt's CPU seconds to the anchor's.

    python benchmarks/fairing.py --stages --meshes cheburashka --scale 2 --noise 0.02 --repeat 3

``--stages`` gives instead the CPU seconds of each stage of a warm ``fair`` call (topology, the
method's target, the input and output certificates, the fold-safe step, fold removal, the shape
measures, the rest) beside trimesh's ``filter_taubin``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from geomopt.fairing import FairOptions, certify_folds, fair
from geomopt.fairing.surface import closest_points, face_distances, triangle_angles, volume
from geomopt.io import read_mesh

DATA = "/work/shared/data/closed"
OURS = {"laplacian": FairOptions(method="laplacian"), "taubin": FairOptions(method="taubin"),
        "implicit": FairOptions(method="implicit"), "least_squares": FairOptions(method="least_squares"),
        "energy": FairOptions(method="energy"), "spectral": FairOptions(method="spectral"),
        "tangential": FairOptions(method="tangential"), "relax": FairOptions(method="relax"),
        # the shrinking methods with the input's volume kept, beside trimesh's volume-constrained Laplacian
        "laplacian, volume kept": FairOptions(method="laplacian", preserve_volume=True),
        "implicit, volume kept": FairOptions(method="implicit", preserve_volume=True),
        "energy, volume kept": FairOptions(method="energy", preserve_volume=True)}
ANCHORS = {"trimesh laplacian": trimesh.smoothing.filter_laplacian, "trimesh taubin": trimesh.smoothing.filter_taubin,
           "trimesh humphrey": trimesh.smoothing.filter_humphrey}


def measure(name, X, V, F, seconds):
    """One row: RMS distance to the clean ``V``, volume change, folded and opposing faces..."""
    Q, _ = closest_points(X, V, F)
    diag = np.linalg.norm(V.max(0) - V.min(0))
    n_out = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    n_clean = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return {"method": name, "rms": float(np.sqrt(np.mean(np.sum((X - Q) ** 2, 1)))) / diag,
            "dvol": volume(X, F) / volume(V, F) - 1.0, "folded": certify_folds(X, F).inverted,
            "opposing": int(np.count_nonzero(np.sum(n_out * n_clean, 1) <= 0)),
            "min_angle": float(triangle_angles(X, F).min()), "seconds": seconds}


def subdivided(V, F):
    """Each triangle split in four at its edge midpoints (the surface unchanged)."""
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(edges, axis=0, return_inverse=True)
    mid = len(V) + inv.reshape(3, -1).T
    V = np.vstack([V, (V[uniq[:, 0]] + V[uniq[:, 1]]) / 2])
    (a, b, c), (ab, bc, ca) = F.T, mid.T
    return V, np.concatenate([np.stack(x, 1) for x in ([a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca])])


def run(mesh, sigma, seed=0, methods=None, scale=0):
    V, F = read_mesh(f"{DATA}/{mesh}.off")
    for _ in range(scale):
        V, F = subdivided(V, F)
    h = np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))
    X0 = V + sigma * h * np.random.default_rng(seed).normal(size=V.shape)
    rows = [measure("noisy input", X0, V, F, 0.0)]
    for name, o in OURS.items():
        if methods and name not in methods:
            continue
        t = time.perf_counter()  # (the host path: NumPy and SciPy, nothing to compile)
        r = fair(X0, F, options=o)
        rows.append(measure(name, r.x, V, F, time.perf_counter() - t) | {"added": r.details.folds_added})
        if o.method == "relax":
            diag = np.linalg.norm(X0.max(0) - X0.min(0))
            rows[-1]["hausdorff"] = max(face_distances(r.x, F, X0, F, order=8).max(),
                                        face_distances(X0, F, r.x, F, order=8).max()) / diag
    for name, filt in ANCHORS.items():
        if methods and name not in methods and "anchors" not in methods:
            continue
        m = trimesh.Trimesh(X0.copy(), F.copy(), process=False)
        t = time.perf_counter()
        filt(m)
        rows.append(measure(name, np.asarray(m.vertices), V, F, time.perf_counter() - t))
    return rows


def _scipy_implicit(X, F):
    """One implicit step with libigl's recipe in SciPy: ``(M - h^2 L) p = M p0``."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    n, rows, cols, vals = len(X), [], [], []
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        u, v = X[i] - X[o], X[j] - X[o]
        cot = 0.5 * np.sum(u * v, 1) / np.linalg.norm(np.cross(u, v), axis=1)
        rows += [i, j]
        cols += [j, i]
        vals += [cot, cot]
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    L = W - sp.diags(np.asarray(W.sum(1)).ravel())
    area = np.linalg.norm(np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]), axis=1) / 2
    m = np.bincount(F.ravel(), np.repeat(area / 3, 3), n)
    h = np.mean(np.linalg.norm(X[F[:, 1]] - X[F[:, 0]], axis=1))
    return spsolve((sp.diags(m) - h * h * L).tocsc(), m[:, None] * X)


def _scipy_least_squares(X, F):
    """Laplacian mesh optimization's normal equations in SciPy: ``(A^T A + I) p = p0``."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    n, e = len(X), np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    W = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    W.data[:] = 1.0
    A = sp.diags(1.0 / np.asarray(W.sum(1)).ravel()) @ W - sp.eye(n)
    return spsolve((A.T @ A + sp.eye(n)).tocsc(), X)


def _trimesh(name):
    def run(X, F):
        filt = getattr(trimesh.smoothing, name)
        return filt(trimesh.Trimesh(X.copy(), F.copy(), process=False)).vertices
    return run


TIMING_ANCHORS = {"taubin": ("trimesh filter_taubin", _trimesh("filter_taubin")),
                  "laplacian": ("trimesh filter_laplacian", _trimesh("filter_laplacian")),
                  "implicit": ("scipy implicit step", _scipy_implicit),
                  "least_squares": ("scipy least squares", _scipy_least_squares)}


def timing(mesh, sigma, methods, scale, repeat):
    """Rows ``(vertices, name, wall, cpu, ratio)``: each geomopt method beside its anchor (see
    the module notes)."""
    V, F = read_mesh(f"{DATA}/{mesh}.off")
    for _ in range(scale):
        V, F = subdivided(V, F)
    h = np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))
    X0 = V + sigma * h * np.random.default_rng(0).normal(size=V.shape)
    rows = []
    for method in methods:
        runs = {f"geomopt {method}": lambda X, F, m=method: fair(X, F, options=OURS[m]),
                TIMING_ANCHORS[method][0]: TIMING_ANCHORS[method][1]}
        seconds = {name: [] for name in runs}
        for round_ in range(repeat + 1):  # the first round cold, not counted
            for name, run_ in runs.items():
                wall, cpu = time.perf_counter(), time.process_time()
                run_(X0, F)
                if round_:
                    seconds[name].append((time.perf_counter() - wall, time.process_time() - cpu))
        ours = np.median([c for _, c in seconds[f"geomopt {method}"]])
        for name, s in seconds.items():
            cpu = float(np.median([c for _, c in s]))
            rows.append((len(V), name, float(np.median([w for w, _ in s])), cpu, ours / cpu))
    return rows


#: the stages of a ``fair`` call that ``--stages`` times: (label, names in geomopt.fairing.driver)
STAGES = [("topology (edge table)", ("Topology.of",)), ("method target", ("TARGETS",)),
          ("certificates (input + output)", ("certify_folds", "recertified")), ("fold-safe step", ("safe_step",)),
          ("fold removal", ("remove_folds",)), ("shape measures (input + output)", ("shape_measures",))]


def stages(mesh, sigma, method, scale, repeat):
    """Rows ``(label, CPU seconds per round)``: where a warm ``fair`` call spends its time, each
    stage's function wrapped in the driver's namespace (medians of ``repeat`` rounds after a cold
    one), the rest of the call ("other": input checks, the vertex stars, the result), the whole
    call, and trimesh's ``filter_taubin`` beside it."""
    import geomopt.fairing.driver as driver

    V, F = read_mesh(f"{DATA}/{mesh}.off")
    for _ in range(scale):
        V, F = subdivided(V, F)
    h = np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))
    X0 = V + sigma * h * np.random.default_rng(0).normal(size=V.shape)
    spent = {}

    def timed(label, f):
        def run_(*a, **k):
            cpu = time.process_time()
            try:
                return f(*a, **k)
            finally:
                spent[label] = spent.get(label, 0.0) + time.process_time() - cpu
        return run_

    saved = {"Topology.of": driver.Topology.__dict__["of"], "TARGETS": dict(driver.TARGETS)}
    saved.update({name: getattr(driver, name) for _, names in STAGES for name in names if name not in saved})
    driver.Topology.of = classmethod(timed(STAGES[0][0], saved["Topology.of"].__func__))
    driver.TARGETS[method] = timed(STAGES[1][0], saved["TARGETS"][method])
    for label, names in STAGES[2:]:
        for name in names:
            setattr(driver, name, timed(label, saved[name]))
    rounds = []
    try:
        for round_ in range(repeat + 1):  # the first round cold, not counted
            spent.clear()
            cpu = time.process_time()
            fair(X0, F, method)
            total = time.process_time() - cpu
            anchor = time.process_time()
            _trimesh("filter_taubin")(X0, F)
            if round_:
                rest = total - sum(spent.values())
                rounds.append(dict(spent, total=total, rest=rest, trimesh=time.process_time() - anchor))
    finally:
        driver.Topology.of = saved["Topology.of"]
        driver.TARGETS.update(saved["TARGETS"])
        for _, names in STAGES[2:]:
            for name in names:
                setattr(driver, name, saved[name])
    median = {key: float(np.median([r.get(key, 0.0) for r in rounds])) for key in rounds[0]}
    rows = [(label, median.get(label, 0.0)) for label, _ in STAGES]
    rows.append(("other (input checks, vertex stars, result)", median["rest"]))
    return [(len(V), label, t) for label, t in rows + [("whole call", median["total"]),
                                                         ("trimesh filter_taubin", median["trimesh"])]]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["cheburashka", "bunny", "cow"])
    ap.add_argument("--noise", nargs="+", type=float, default=[0.005, 0.02, 0.2, 0.5])
    ap.add_argument("--methods", nargs="+", default=None,
                    help="row names to run (ours, trimesh's, or 'anchors' for all three of trimesh's)")
    ap.add_argument("--scale", type=int, default=0, help="subdivide the mesh this many times first")
    ap.add_argument("--timing", action="store_true", help="time each method beside its anchor instead")
    ap.add_argument("--repeat", type=int, default=3, help="--timing: timed rounds after a cold one")
    ap.add_argument("--stages", action="store_true",
                    help="CPU seconds per stage of one method (the first of --methods, default taubin) instead")
    args = ap.parse_args()
    if args.stages:
        print("| mesh | noise | vertices | stage | CPU s |\n|---|---|---|---|---|")
        for mesh in args.meshes:
            for sigma in args.noise:
                for n, label, cpu in stages(mesh, sigma, (args.methods or ["taubin"])[0], args.scale, args.repeat):
                    print(f"| {mesh} | {sigma:.1%} | {n:,} | {label} | {cpu:.3f} |", flush=True)
        return
    if args.timing:
        print("| mesh | vertices | method | wall s | CPU s | geomopt CPU / this |\n|---|---|---|---|---|---|")
        for mesh in args.meshes:
            for sigma in args.noise:
                for n, name, wall, cpu, ratio in timing(mesh, sigma, args.methods or ["taubin", "implicit",
                                                        "least_squares"], args.scale, args.repeat):
                    print(f"| {mesh} | {n:,} | {name} | {wall:.3f} | {cpu:.3f} | {ratio:.2f} |", flush=True)
        return
    print("| mesh | noise | method | RMS / diag | volume change | folded (added) | opposing | min angle | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for mesh in args.meshes:
        for sigma in args.noise:
            for r in run(mesh, sigma, methods=args.methods, scale=args.scale):
                added = f" ({r['added']})" if "added" in r else ""
                extra = f" Hausdorff {r['hausdorff']:.1e}" if "hausdorff" in r else ""
                print(f"| {mesh} | {sigma:.1%} | {r['method']}{extra} | {r['rms']:.3e} | {r['dvol']:+.2e} | "
                      f"{r['folded']}{added} | {r['opposing']} | {r['min_angle']:.2f} | {r['seconds']:.3f} |", flush=True)


if __name__ == "__main__":
    main()

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

    python benchmarks/fairing.py [--meshes bunny cow] [--noise 0.005 0.02]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from geomopt.fairing import FairOptions, certify_folds, fair
from geomopt.fairing.surface import closest_points, triangle_angles, volume
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


def run(mesh, sigma, seed=0):
    V, F = read_mesh(f"{DATA}/{mesh}.off")
    h = np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))
    X0 = V + sigma * h * np.random.default_rng(seed).normal(size=V.shape)
    rows = [measure("noisy input", X0, V, F, 0.0)]
    for name, o in OURS.items():
        t = time.perf_counter()  # (the host path: NumPy and SciPy, nothing to compile)
        r = fair(X0, F, options=o)
        rows.append(measure(name, r.x, V, F, time.perf_counter() - t))
    for name, filt in ANCHORS.items():
        m = trimesh.Trimesh(X0.copy(), F.copy(), process=False)
        t = time.perf_counter()
        filt(m)
        rows.append(measure(name, np.asarray(m.vertices), V, F, time.perf_counter() - t))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["bunny", "cow"])
    ap.add_argument("--noise", nargs="+", type=float, default=[0.005, 0.02, 0.2])
    args = ap.parse_args()
    print("| mesh | noise | method | RMS / diag | volume change | folded | opposing | min angle | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for mesh in args.meshes:
        for sigma in args.noise:
            for r in run(mesh, sigma):
                print(f"| {mesh} | {sigma:.1%} | {r['method']} | {r['rms']:.3e} | {r['dvol']:+.2e} | {r['folded']} | "
                      f"{r['opposing']} | {r['min_angle']:.2f} | {r['seconds']:.3f} |", flush=True)


if __name__ == "__main__":
    main()

"""Spherical maps of closed genus-0 meshes: geomopt.sphere_map beside Kazhdan et al. 2012's
conformalized mean curvature flow (cMCF) projected to the sphere.

The baseline, as the paper describes it: the surface flows by ``(M_t + delta L_0) X_{t+1} =
M_t X_t`` (``L_0`` the cotangent stiffness of the input, fixed: the "conformalized" flow;
``M_t`` the lumped mass matrix of the current surface), recentred and rescaled to unit area
after each step, until it is round; then every vertex is projected from the area centroid onto
the unit sphere.  Both maps are measured the same way (:func:`geomopt.sphere.sphere_distortion`):
the area-weighted mean symmetric Dirichlet density of the chord triangles (4 at an isometry), the
area ratio (spherical over rest area, both normalised to 4 pi: min / max / mean), the triangles
not positively oriented about the centre (exact), and the wall time (geomopt's warm: its
compiled kernels cached).

    python benchmarks/sphere.py [--steps 30] [--delta 1e-3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import geomopt
from geomopt.io import read_mesh
from geomopt.sphere import sphere_distortion

DATA = "/work/shared/data/closed"


def cot_stiffness(V, F):
    """(n, n) the cotangent Laplacian ``L`` (positive semidefinite: ``x^T L x`` is twice the
    Dirichlet energy)."""
    n = len(V)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        a, b = V[i] - V[o], V[j] - V[o]
        cot = np.einsum("ij,ij->i", a, b) / np.linalg.norm(np.cross(a, b), axis=1)
        rows += [i, j, i, j]
        cols += [j, i, i, j]
        vals += [-0.5 * cot, -0.5 * cot, 0.5 * cot, 0.5 * cot]
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def lumped_mass(V, F):
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return sp.diags(np.bincount(F.ravel(), np.repeat(area / 3.0, 3), minlength=len(V)))


def normalised(V, F):
    """``V`` centred at its area centroid and scaled to unit area."""
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    centre = np.sum(area[:, None] * V[F].mean(axis=1), axis=0) / area.sum()
    return (V - centre) / np.sqrt(area.sum())


def cmcf_sphere(V, F, steps=30, delta=1e-3):
    """Kazhdan, Solomon & Ben-Chen 2012's cMCF, then projected from the centroid to the sphere."""
    X = normalised(V, F)
    L0 = cot_stiffness(X, F)
    for _ in range(steps):
        M = lumped_mass(X, F)
        X = normalised(spla.splu((M + delta * L0).tocsc()).solve(M @ X), F)
    return X / np.linalg.norm(X, axis=1, keepdims=True)


def blob():
    """A generated genus-0 mesh: a level-4 icosphere with smooth radial bumps (2562 vertices)."""
    import trimesh

    m = trimesh.creation.icosphere(4)
    P = np.asarray(m.vertices)
    r = 1.0 + 0.35 * np.sin(3 * P[:, 0]) * np.cos(2 * P[:, 1]) + 0.25 * P[:, 2] ** 3
    return P * r[:, None] * [1.4, 1.0, 0.8], np.asarray(m.faces)


def row(name, method, seconds, V, F, x, extra=""):
    d = sphere_distortion(V, F, x)
    print(f"| {name} | {len(F)} | {method} | {d['symmetric_dirichlet']:.4g} | {d['area_min']:.3g} | "
          f"{d['area_max']:.3g} | {d['area_mean']:.3g} | {d['inverted']} | {seconds:.1f} | {extra} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--delta", type=float, default=1e-3)
    ap.add_argument("--meshes", default="bunny,cheburashka,cow,blob",
                    help="comma-separated names in shared/data/closed, 'blob', or paths of other closed meshes")
    args = ap.parse_args()
    print("| mesh | faces | method | mean sym. Dirichlet | area ratio min | max | mean | inverted | seconds | "
          "certificate |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.meshes.split(","):
        V, F = blob() if name == "blob" else read_mesh(name if "/" in name else f"{DATA}/{name}.off")
        name = name.rsplit("/", 1)[-1]
        t = time.perf_counter()
        x = cmcf_sphere(V, F, args.steps, args.delta)
        row(name, f"cMCF ({args.steps} x {args.delta:g}) + projection", time.perf_counter() - t, V, F, x,
            "ok" if geomopt.exact.certify.certify_sphere(x, F).ok else "fails")
        t = time.perf_counter()
        res = geomopt.sphere_map(V, F, progress=False)
        cert = res.certificate
        row(name, "geomopt.sphere_map", time.perf_counter() - t, V, F, res.x,
            f"{'ok' if res.success else 'FAILS'}: {res.stats.iterations} it ({res.stats.seconds:.1f} s), area {cert.area:.12g}")


if __name__ == "__main__":
    main()

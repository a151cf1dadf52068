"""Held-out untangling families for the benchmarks (not used to tune geomopt's defaults).

Each function returns a :class:`geomopt.mesh.generators.Tangle` with the boundary fixed:

* :func:`delaunay_ball` / :func:`delaunay_disk` -- irregular meshes: ``scipy.spatial.Delaunay``
  of a random point cloud in the unit ball / disk with points spread evenly over the sphere /
  circle (a Fibonacci lattice), tangled by :func:`geomopt.mesh.generators.rotated_interior` or
  :func:`~geomopt.mesh.generators.noisy_interior`;
* :func:`delaunay_annulus` -- a 2D domain with a hole (both circles fixed);
* :func:`l_box` -- a non-convex tet domain (a box less one quarter column);
* :func:`torus_box` -- a genus-1 tet domain (a box with a square hole along z);
* :func:`twisted` -- any tet mesh whose boundary is twisted about the z axis, interior at rest;
* :func:`squashed_box` -- a cube whose boundary is squashed along z, interior at rest.

:func:`surfaces` writes held-out disk-topology surfaces of 30k-50k triangles for the
parameterization benchmarks (``startup.py --heldout``): the shared meshes decimated or
subdivided then decimated (libigl), and generated ruffled and saddle disks.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from geomopt.mesh import generators as G


def _fibonacci_sphere(k):
    i = np.arange(k) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / k)
    theta = np.pi * (1.0 + 5.0**0.5) * i
    return np.c_[np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)]


def _orient(V, S):
    P = V[S]
    E = P[:, 1:] - P[:, :1]
    det = np.linalg.det(E)
    S = S[np.abs(det) > 1e-12 * np.abs(det).max()].copy()  # no flat hull slivers
    det = np.linalg.det(V[S][:, 1:] - V[S][:, :1])
    S[det < 0] = S[det < 0][:, [1, 0] + list(range(2, S.shape[1]))]
    return S


def _compact(V, S):
    used = np.unique(S)
    new = np.full(len(V), -1)
    new[used] = np.arange(len(used))
    return V[used], new[S]


def ball_mesh(n_points: int, seed: int = 0):
    """A Delaunay tet mesh of the unit ball from about ``n_points`` points (~6.5 tets each)."""
    rng = np.random.default_rng(seed)
    h = (4.0 / 3.0 * np.pi / n_points) ** (1.0 / 3.0)
    surface = _fibonacci_sphere(int(round(4.0 * np.pi / (0.9 * h * h))))
    P = rng.uniform(-1.0, 1.0, (4 * n_points, 3))
    P = P[np.linalg.norm(P, axis=1) < 1.0 - 0.5 * h][:n_points]
    V = np.vstack([surface, P])
    return _compact(V, _orient(V, Delaunay(V).simplices))


def disk_points(n_points: int, seed: int = 0, inner: float = 0.0):
    """A Delaunay triangulation of the unit disk (or the annulus ``inner < r < 1``)."""
    rng = np.random.default_rng(seed)
    h = np.sqrt(np.pi * (1.0 - inner**2) / n_points)
    circles = [np.c_[np.cos(t), np.sin(t)] for t in [np.linspace(0, 2 * np.pi, int(2 * np.pi / h), endpoint=False)]]
    if inner > 0:
        k = int(2 * np.pi * inner / h)
        t = np.linspace(0, 2 * np.pi, k, endpoint=False)
        circles.append(inner * np.c_[np.cos(t), np.sin(t)])
    P = rng.uniform(-1.0, 1.0, (4 * n_points, 2))
    r = np.linalg.norm(P, axis=1)
    P = P[(r < 1.0 - 0.5 * h) & (r > inner + 0.5 * h)][:n_points]
    V = np.vstack([*circles, P])
    F = Delaunay(V).simplices
    if inner > 0:
        F = F[np.linalg.norm(V[F].mean(axis=1), axis=1) > inner]
    return _compact(V, _orient(V, F))


def delaunay_ball(n_points: int, tangle: str = "rot180", seed: int = 0) -> G.Tangle:
    V, T = ball_mesh(n_points, seed)
    return _tangle(V, T, tangle, f"ball{len(T)}")


def delaunay_disk(n_points: int, tangle: str = "rot180", seed: int = 0) -> G.Tangle:
    V, F = disk_points(n_points, seed)
    return _tangle(V, F, tangle, f"ddisk{len(F)}")


def delaunay_annulus(n_points: int, tangle: str = "rot180", seed: int = 0, inner: float = 0.4) -> G.Tangle:
    V, F = disk_points(n_points, seed, inner)
    return _tangle(V, F, tangle, f"annulus{len(F)}")


def _tangle(V, S, how, name):
    if how.startswith("rot"):
        return G.rotated_interior(V, S, float(how[3:]), name=f"{name}-{how}")
    if how.startswith("noise"):
        return G.noisy_interior(V, S, float(how[5:] or 2.0), seed=1, name=f"{name}-{how}")
    raise ValueError(how)


def _box_without(n, m, drop):
    V, T = G.box_mesh(n, n, m, size=(1.0, 1.0, m / n))
    c = V[T].mean(axis=1)
    return _compact(V, T[~drop(c)])


def l_box(n: int, m: int | None = None):
    """A box of n x n x m cubes (6 tets each) less the quarter column x, y > 1/2: non-convex."""
    return _box_without(n, m or n, lambda c: (c[:, 0] > 0.5) & (c[:, 1] > 0.5))


def torus_box(n: int, m: int | None = None, hole: float = 0.34):
    """A box of n x n x m cubes less the column |x - 1/2|, |y - 1/2| < hole / 2: genus 1."""
    return _box_without(n, m or n, lambda c: (np.abs(c[:, 0] - 0.5) < hole / 2) & (np.abs(c[:, 1] - 0.5) < hole / 2))


def twisted(V, T, turns: float, name: str) -> G.Tangle:
    """The boundary of a tet mesh rotated about the vertical axis through its centre by
    ``turns * 360`` degrees times the relative height; the interior at rest."""
    fixed = G.boundary_vertices(T, len(V))
    lo, hi = V.min(axis=0), V.max(axis=0)
    c = 0.5 * (lo[:2] + hi[:2])
    a = 2 * np.pi * turns * (V[fixed, 2] - lo[2]) / (hi[2] - lo[2])
    d = V[fixed, :2] - c
    x0 = V.copy()
    x0[fixed, 0] = c[0] + np.cos(a) * d[:, 0] - np.sin(a) * d[:, 1]
    x0[fixed, 1] = c[1] + np.sin(a) * d[:, 0] + np.cos(a) * d[:, 1]
    return G.Tangle(name, V, T, x0, fixed)


def squashed_box(n: int, factor: float = 0.25) -> G.Tangle:
    """A cube of n^3 cubes whose boundary is squashed to ``factor`` of its height (z), interior
    at rest: the interior sticks out of the flattened box.  The squashed rest mesh is injective."""
    V, T = G.box_mesh(n, n, n)
    fixed = G.boundary_vertices(T, len(V))
    x0 = V.copy()
    x0[fixed, 2] *= factor
    return G.Tangle(f"cube{n}-squash{factor:g}", V, T, x0, fixed)


def _disk_check(V, F):
    """(V, F) without unused vertices, or None unless a disk (Euler characteristic 1, one
    boundary loop) with no zero-area triangle."""
    import igl

    V, F = _compact(np.asarray(V, float), np.asarray(F, np.int64))
    chi = len(V) - len(igl.edges(F)) + len(F)
    ok = chi == 1 and len(igl.boundary_loop_all(F)) == 1 and igl.doublearea(V, F).min() > 0
    return (V, F) if ok else None


def surfaces(mesh_dir, out_dir):
    """Write the held-out surfaces (OBJ) under ``out_dir``; return their paths.

    igea_cut decimated to 44k triangles, armadillo_cut_low to 36k, bunny_cut upsampled then
    decimated to 40k, camelhead Loop-subdivided then decimated to 48k (libigl's edge-collapse
    ``decimate``), a ruffled disk of 42k and a saddle of 33k (:mod:`geomopt.mesh.generators`).
    A result that is not a disk is skipped."""
    import igl
    from pathlib import Path

    from geomopt import io

    mesh_dir, out_dir = Path(mesh_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    read = lambda name: io.read_mesh(mesh_dir / name)  # noqa: E731
    made = {
        "igea44k": lambda: igl.decimate(*read("igea_cut.ply"), 44000)[:2],
        "armadillo36k": lambda: igl.decimate(*read("armadillo_cut_low.obj"), 36000)[:2],
        "bunny40k": lambda: igl.decimate(*igl.upsample(*read("bunny_cut.obj")), 40000)[:2],
        "camel48k": lambda: igl.decimate(*igl.loop(*read("camelhead.off")), 48000)[:2],
        "ruffled42k": lambda: G.ruffled_disk(rings=84),
        "saddle33k": lambda: G.saddle(rings=74, amplitude=1.5),
    }
    paths = []
    for name, make in made.items():
        mesh = _disk_check(*make())
        if mesh is not None:
            paths.append(out_dir / f"{name}.obj")
            io.write_obj_with_uv(paths[-1], *mesh, np.zeros((len(mesh[0]), 2)))
    return paths

"""Synthetic meshes and tangled maps with fixed boundaries, for tests and benchmarks.

Meshes (plain NumPy, every element positively oriented):

* :func:`square_mesh` — a triangulated square grid;
* :func:`disk_mesh` — a disk of concentric rings (``6 r`` vertices on ring ``r``), whose
  boundary vertices are joined only to their boundary neighbours and to the next ring, so
  that no triangle or interior edge has all its vertices on the boundary;
* :func:`box_mesh` — a box of ``nx x ny x nz`` cubes, 6 tetrahedra each (Kuhn);
* :func:`quad_mesh`, :func:`hex_mesh` — the same grids as quads / hexahedra (VTK order);
* :func:`sector_mesh` — quads or hexahedra of a structured annulus sector (a non-box shape),
  optionally with its interior vertices perturbed (a valid mesh to smooth).

Tangles — each returns a :class:`Tangle` (rest mesh, start map, fixed vertices) whose fixed
vertices are the boundary, and for which an injective map exists:

* :func:`rotated_interior` — interior vertices rotated about the centre (2D, or 3D about z);
* :func:`noisy_interior` — interior vertices displaced by random noise of a few edge lengths;
* :func:`tutte_nonconvex` — a disk's boundary mapped to a star / L-shaped / crescent polygon
  and the interior by Tutte's barycentric embedding (flips near reflex corners);
* :func:`random_interior` — interior vertices scattered uniformly over the bounding box;
* :func:`twisted_box` — a rod or cube whose boundary is twisted about its axis while the
  interior stays at rest;
* :func:`bent_box` — a rod whose boundary is bent into an arc, interior at rest (the
  interior sticks out of the bent boundary, as in the LIM deformation groups).

* :func:`squashed_boundary` — the boundary pushed in along the last axis by a bump (the top
  side dips towards the bottom), interior at rest.

Every tangle takes simplices, quads (2D) or hexahedra (3D): the fixed set is the boundary of
the elements given (:func:`geomopt.mesh.elements.boundary_vertices` for quads and hexahedra).
These reproduce the families of the LIM benchmark (Du et al. 2020) that are not shipped.

Surfaces whose free-boundary flattening overlaps itself (for the bijective mode) -- each returns
``V`` (n, 3), ``F`` (m, 3) counter-clockwise seen from +z, and is a graph over its ``xy``
projection, so ``V[:, :2]`` is a bijective start map:

* :func:`spiral_strip` — a narrow band along an Archimedean spiral, lifted into a ramp;
* :func:`ruffled_disk` — a disk with large waves along its rim (a lettuce leaf);
* :func:`saddle` — a (monkey) saddle over a disk.

Closed surfaces (for atlases): :func:`holed_plate` — a slab with square holes, of any genus.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._runtime.errors import ParameterError
from ..exact.topology import boundary_vertices  # noqa: F401  (re-exported: the generators' fixed sets)

__all__ = [
    "Tangle", "square_mesh", "disk_mesh", "box_mesh", "quad_mesh", "hex_mesh", "sector_mesh",
    "boundary_vertices", "rotated_interior", "noisy_interior", "random_interior", "tutte_nonconvex",
    "twisted_box", "bent_box", "squashed_boundary", "perturb_mesh",
    "polygon", "POLYGONS", "spiral_strip", "ruffled_disk", "saddle", "holed_plate",
]


@dataclasses.dataclass(frozen=True, eq=False)
class Tangle:
    """A rest mesh, a (tangled) start map and its fixed vertices.

    Attributes
    ----------
    name : str
    rest : (n, d) rest positions.
    simplices : (m, d+1) triangles (d=2) or tetrahedra (d=3), or (m, 4) quads (d=2) or (m, 8)
        hexahedra (d=3), positively oriented at rest.
    x0 : (n, d) start map; ``x0[fixed]`` are the prescribed handle positions.
    fixed : (k,) int64 vertex ids.
    """

    name: str
    rest: np.ndarray
    simplices: np.ndarray
    x0: np.ndarray
    fixed: np.ndarray

    @property
    def dim(self) -> int:
        return self.rest.shape[1]

    @property
    def n_elements(self) -> int:
        return len(self.simplices)

    @property
    def is_simplicial(self) -> bool:
        return self.simplices.shape[1] == self.dim + 1

    def problem(self):
        """The :class:`~geomopt.mesh.problem.Problem` (planar, tets, quads or hexes) with the
        handles fixed."""
        from .problem import Problem

        if self.is_simplicial:
            make = Problem.planar if self.dim == 2 else Problem.tets
        else:
            make = Problem.quads if self.dim == 2 else Problem.hexes
        return make(self.rest, self.simplices, self.fixed, self.x0[self.fixed])

    def inverted(self) -> int:
        """Elements of ``x0`` that are not positively oriented (exact predicate; quads and
        hexahedra: not valid everywhere, :func:`geomopt.mesh.elements.count_invalid`)."""
        if not self.is_simplicial:
            from .elements import count_invalid

            return count_invalid(self.x0, self.simplices)
        from ..exact.predicates import count_inverted

        return count_inverted(self.x0, self.simplices)


# ------------------------------------------------------------------------------ meshes


def _orient(V, S):
    """Reorder simplices so that each is positively oriented."""
    E = V[S[:, 1:]] - V[S[:, :1]]
    det = np.linalg.det(E)
    S = S.copy()
    S[det < 0] = S[det < 0][:, [0, 2, 1] + list(range(3, S.shape[1]))]
    return S


def square_mesh(n: int, size: float = 1.0):
    """An ``n x n``-vertex grid on ``[0, size]^2``, each cell split along the same diagonal.

    Returns ``V`` (n^2, 2), ``F`` (2 (n-1)^2, 3)."""
    if n < 2:
        raise ParameterError(f"square_mesh needs n >= 2, got {n}")
    t = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(t, t, indexing="xy")
    V = np.stack([X.ravel(), Y.ravel()], 1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="xy")
    a = (j * n + i).ravel()
    b, c, d = a + 1, a + n, a + n + 1
    F = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return V, _orient(V, F.astype(np.int64))


def disk_mesh(rings: int, radius: float = 1.0):
    """A unit disk of ``rings`` concentric rings: ``1 + 3 R (R + 1)`` vertices, ``6 R^2`` triangles.

    Ring ``r`` holds ``6 r`` equally spaced vertices; consecutive rings are zipped by angle.
    The boundary (last ring) vertices are the last ``6 R`` ones.  Returns ``V`` (n, 2), ``F``."""
    if rings < 1:
        raise ParameterError(f"disk_mesh needs rings >= 1, got {rings}")
    V = [np.zeros((1, 2))]
    start = [0]
    F = []
    count = 1
    for r in range(1, rings + 1):
        k = 6 * r
        ang = 2 * np.pi * (np.arange(k) + 0.5 * (r % 2)) / k
        V.append(radius * r / rings * np.stack([np.cos(ang), np.sin(ang)], 1))
        start.append(count)
        count += k
    V = np.concatenate(V)
    F.extend([[0, 1 + j, 1 + (j + 1) % 6] for j in range(6)])
    for r in range(2, rings + 1):
        inner, outer = 6 * (r - 1), 6 * r
        ai = 2 * np.pi * (np.arange(inner) + 0.5 * ((r - 1) % 2)) / inner
        ao = 2 * np.pi * (np.arange(outer) + 0.5 * (r % 2)) / outer
        # merge the two rings by angle (unwrapped so both start at the same angle)
        i = o = 0
        si, so = start[r - 1], start[r]
        base = min(ai[0], ao[0])
        while i < inner or o < outer:
            ni = ai[(i + 1) % inner] + (2 * np.pi if i + 1 >= inner else 0.0)
            no = ao[(o + 1) % outer] + (2 * np.pi if o + 1 >= outer else 0.0)
            if o < outer and (i >= inner or no - base <= ni - base):
                F.append([si + i % inner, so + o % outer, so + (o + 1) % outer])
                o += 1
            else:
                F.append([si + i % inner, so + o % outer, si + (i + 1) % inner])
                i += 1
    return V, _orient(V, np.asarray(F, dtype=np.int64))


def _box_grid(name, nx, ny, nz, size):
    """The grid vertices of a box of ``nx ny nz`` cells, ``V`` ((nx+1)(ny+1)(nz+1), 3), their
    index array ``idx`` (nx+1, ny+1, nz+1) and each cell's lowest corner ``(i, j, k)``."""
    if min(nx, ny, nz) < 1:
        raise ParameterError(f"{name} needs positive sizes, got {(nx, ny, nz)}")
    axes = [np.linspace(0.0, s, n + 1) for s, n in zip(size, (nx, ny, nz))]
    V = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(len(V)).reshape(nx + 1, ny + 1, nz + 1)
    cells = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"))
    return V, idx, tuple(cells)


def box_mesh(nx: int, ny: int, nz: int, size=(1.0, 1.0, 1.0)):
    """A box of ``nx ny nz`` cubes, each split into 6 tetrahedra around its main diagonal.

    Returns ``V`` ((nx+1)(ny+1)(nz+1), 3), ``T`` (6 nx ny nz, 4)."""
    V, idx, (ci, cj, ck) = _box_grid("box_mesh", nx, ny, nz, size)
    T = []
    for perm in [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]:
        c = [ci.copy(), cj.copy(), ck.copy()]
        tet = [idx[c[0], c[1], c[2]]]
        for axis in perm:
            c[axis] = c[axis] + 1
            tet.append(idx[c[0], c[1], c[2]])
        T.append(np.stack(tet, 1))
    return V, _orient(V, np.concatenate(T).astype(np.int64))


def quad_mesh(nx: int, ny: int, size=(1.0, 1.0)):
    """An ``nx x ny`` grid of quads on ``[0, size[0]] x [0, size[1]]``, counter-clockwise.

    Returns ``V`` ((nx+1)(ny+1), 2), ``Q`` (nx ny, 4); vertex ``(i, j)`` is ``j (nx+1) + i``."""
    if min(nx, ny) < 1:
        raise ParameterError(f"quad_mesh needs positive sizes, got {(nx, ny)}")
    X, Y = np.meshgrid(np.linspace(0.0, size[0], nx + 1), np.linspace(0.0, size[1], ny + 1), indexing="xy")
    V = np.stack([X.ravel(), Y.ravel()], 1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    a = (j * (nx + 1) + i).ravel()
    return V, np.stack([a, a + 1, a + nx + 2, a + nx + 1], 1).astype(np.int64)


def hex_mesh(nx: int, ny: int, nz: int, size=(1.0, 1.0, 1.0)):
    """A box of ``nx ny nz`` hexahedra (VTK order, positive), the vertices of :func:`box_mesh`.

    Returns ``V`` ((nx+1)(ny+1)(nz+1), 3), ``H`` (nx ny nz, 8)."""
    V, idx, (i, j, k) = _box_grid("hex_mesh", nx, ny, nz, size)
    H = [idx[i + a, j + b, k + c] for c in (0, 1) for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]
    return V, np.stack(H, 1).astype(np.int64)


def sector_mesh(n_r: int, n_t: int, n_z: int = 0, angle_deg: float = 120.0, radii=(1.0, 2.0),
                height: float = 1.0, perturb: float = 0.0, seed: int = 0):
    """A structured mesh of an annulus sector (a non-box shape): quads when ``n_z == 0``, else
    hexahedra of the sector extruded to ``height`` in ``n_z`` layers.

    ``perturb`` > 0 moves every interior vertex by uniform noise of that many local edge
    lengths, keeping every element valid (noise that would invalidate one is halved until none
    is): a valid but poor mesh to smooth.

    Returns ``V`` (n, 2 or 3), ``E`` (m, 4 or 8), positively oriented.
    """
    V, E = quad_mesh(n_t, n_r) if n_z == 0 else hex_mesh(n_t, n_r, n_z)
    t = np.deg2rad(angle_deg) * (1.0 - V[:, 0])  # reversed: keeps the orientation positive
    r = radii[0] + (radii[1] - radii[0]) * V[:, 1]
    W = V.copy()
    W[:, 0], W[:, 1] = r * np.cos(t), r * np.sin(t)
    if n_z:
        W[:, 2] = height * V[:, 2] / max(V[:, 2].max(), 1.0)
    if perturb > 0:
        W = perturb_mesh(W, E, perturb, seed)
    return W, E


def perturb_mesh(V, E, scale, seed=0):
    """A valid but poor copy of a valid mesh: interior vertices of ``V`` (n, d) moved by uniform
    noise of ``scale`` mean edge lengths; every vertex of an element the noise would make
    invalid (:func:`geomopt.mesh.elements.valid_elements`) gets half of its noise, until none is
    (the input unchanged if 60 halvings do not get there).  ``E``: quads (2D) or hexahedra,
    oriented."""
    from .elements import valid_elements

    V = np.asarray(V, dtype=np.float64)
    rng = np.random.default_rng(seed)
    free = np.ones(len(V), bool)
    free[_fixed_boundary(V, E)] = False
    step = np.zeros_like(V)
    step[free] = scale * _mean_edge(V, E) * rng.uniform(-1.0, 1.0, (free.sum(), V.shape[1]))
    for _ in range(60):
        bad = ~valid_elements(V + step, E)
        if not bad.any():
            break
        step[np.unique(E[bad])] *= 0.5
    else:
        step[:] = 0.0
    return V + step


def _fixed_boundary(V, S):
    """The boundary vertices of simplices, quads (2D) or hexahedra (3D) ``S`` on ``V``."""
    S = np.asarray(S)
    if S.shape[1] == np.asarray(V).shape[1] + 1:
        return boundary_vertices(S, len(V))
    from .elements import boundary_vertices as element_boundary

    return element_boundary(S, len(V))


def _mean_edge(V, S):
    k = S.shape[1]
    e = [np.linalg.norm(V[S[:, i]] - V[S[:, j]], axis=1) for i in range(k) for j in range(i + 1, k)]
    return float(np.mean(np.concatenate(e)))


# ------------------------------------------------------------------------------ tangles


def rotated_interior(V, S, angle_deg: float, name: str | None = None) -> Tangle:
    """Rotate every interior vertex about the bounding-box centre by ``angle_deg`` (about z
    in 3D); the boundary is fixed.  The rest mesh itself is the injective solution."""
    V = np.asarray(V, dtype=np.float64)
    fixed = _fixed_boundary(V, S)
    free = np.ones(len(V), bool)
    free[fixed] = False
    c = 0.5 * (V.min(0) + V.max(0))
    a = np.deg2rad(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    x0 = V.copy()
    x0[free, :2] = (V[free, :2] - c[:2]) @ R.T + c[:2]
    return Tangle(name or f"rotated{angle_deg:g}", V, np.asarray(S), x0, fixed)


def noisy_interior(V, S, scale: float = 2.0, seed: int = 0, name: str | None = None) -> Tangle:
    """Displace every interior vertex by Gaussian noise of standard deviation ``scale`` mean
    edge lengths; the boundary is fixed."""
    V = np.asarray(V, dtype=np.float64)
    fixed = _fixed_boundary(V, S)
    free = np.ones(len(V), bool)
    free[fixed] = False
    rng = np.random.default_rng(seed)
    x0 = V.copy()
    x0[free] += scale * _mean_edge(V, np.asarray(S)) * rng.standard_normal((free.sum(), V.shape[1]))
    return Tangle(name or f"noise{scale:g}", V, np.asarray(S), x0, fixed)


def random_interior(V, S, seed: int = 0, name: str | None = None) -> Tangle:
    """Scatter every interior vertex uniformly over the bounding box; the boundary is fixed."""
    V = np.asarray(V, dtype=np.float64)
    fixed = _fixed_boundary(V, S)
    free = np.ones(len(V), bool)
    free[fixed] = False
    rng = np.random.default_rng(seed)
    lo, hi = V.min(0), V.max(0)
    x0 = V.copy()
    x0[free] = lo + (hi - lo) * rng.random((free.sum(), V.shape[1]))
    return Tangle(name or "random", V, np.asarray(S), x0, fixed)


POLYGONS = ("star", "L", "crescent")


def polygon(shape: str, arms: int = 5, depth: float = 0.5) -> np.ndarray:
    """Corners (k, 2) of a simple counter-clockwise polygon: ``"star"`` (``arms`` points,
    inner radius ``1 - depth``), ``"L"`` (unit square minus a quadrant) or ``"crescent"``."""
    if shape == "star":
        a = np.pi / 2 + np.pi * np.arange(2 * arms) / arms
        r = np.where(np.arange(2 * arms) % 2 == 0, 1.0, 1.0 - depth)
        return np.stack([r * np.cos(a), r * np.sin(a)], 1)
    if shape == "L":
        return np.array([[0, 0], [1, 0], [1, 0.5], [0.5, 0.5], [0.5, 1], [0, 1]], dtype=np.float64)
    if shape == "crescent":
        # the unit disk minus a disk of radius 0.7 centred at (0.5, 0); tips at (0.76, +-0.65)
        tip = np.arctan2(0.65, 0.76)
        t = np.linspace(tip, 2 * np.pi - tip, 24)
        outer = np.stack([np.cos(t), np.sin(t)], 1)
        a = np.arctan2(-0.65, 0.76 - 0.5) % (2 * np.pi)  # inner circle, from the lower tip ...
        b = np.arctan2(0.65, 0.76 - 0.5)  # ... clockwise through its leftmost point to the upper tip
        u = np.linspace(a, b, 18)[1:-1]
        inner = 0.7 * np.stack([np.cos(u), np.sin(u)], 1) + [0.5, 0.0]
        return np.concatenate([outer, inner])
    raise ParameterError(f"unknown polygon {shape!r}; valid: {', '.join(POLYGONS)}")


def _on_polygon(P, s):
    """Points at arc-length fractions ``s`` (k,) in [0, 1) along the closed polygon P."""
    seg = np.roll(P, -1, axis=0) - P
    L = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(L)]) / L.sum()
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(P) - 1)
    t = (s - cum[i]) / (cum[i + 1] - cum[i])
    return P[i] + t[:, None] * seg[i]


def tutte_nonconvex(rings: int, shape: str = "star", arms: int = 5, depth: float = 0.5,
                    name: str | None = None) -> Tangle:
    """A :func:`disk_mesh` whose boundary is mapped onto a non-convex polygon (by angle along the
    boundary ring, so every polygon corner gets a vertex) and whose interior is placed by
    Tutte's embedding with uniform weights: triangles near reflex corners fold over."""
    V, F = disk_mesh(rings)
    n = len(V)
    nb = 6 * rings
    loop = np.arange(n - nb, n)  # the outer ring, counter-clockwise by construction
    P = polygon(shape, arms, depth)
    # snap polygon corners to boundary vertices: distribute vertices per edge by length
    seg = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    counts = np.maximum(1, np.floor(nb * seg / seg.sum()).astype(int))
    while counts.sum() > nb:
        counts[np.argmax(counts)] -= 1
    while counts.sum() < nb:
        counts[np.argmax(seg / counts)] += 1
    pts = []
    for k in range(len(P)):
        t = np.arange(counts[k]) / counts[k]
        pts.append(P[k] + t[:, None] * (P[(k + 1) % len(P)] - P[k]))
    B = np.concatenate(pts)
    # keep the rotation of the ring: the first boundary vertex has the smallest angle
    x0 = np.zeros((n, 2))
    x0[loop] = B
    # Tutte: uniform weights on the mesh graph
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    deg = np.asarray(A.sum(1)).ravel()
    interior = np.arange(n - nb)
    L = sp.diags(deg) - A
    Lii = L[interior][:, interior].tocsc()
    rhs = -(L[interior][:, loop] @ B)
    x0[interior] = spla.splu(Lii).solve(rhs)
    # rest: the disk scaled to the polygon's area, so the untangled map is area-balanced
    area_poly = 0.5 * np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
    V = V * np.sqrt(abs(area_poly) / np.pi)
    return Tangle(name or f"tutte-{shape}", V, F, x0, loop.astype(np.int64))


def _rod(n_cross, n_long, hexes):
    """A rod of :func:`box_mesh` tets or :func:`hex_mesh` hexahedra along z, and its boundary."""
    make = hex_mesh if hexes else box_mesh
    V, T = make(n_cross, n_cross, n_long, size=(1.0, 1.0, n_long / n_cross))
    return V, T, _fixed_boundary(V, T)


def twisted_box(n_cross: int, n_long: int, turns: float = 0.5, name: str | None = None,
                hexes: bool = False) -> Tangle:
    """A rod (``n_long > n_cross``) or cube of :func:`box_mesh` tets (:func:`hex_mesh`
    hexahedra with ``hexes``) along z whose boundary is twisted about the z axis by
    ``turns * 360`` degrees (linearly along z), interior at rest.  The twisted rest mesh is
    the injective solution when the twist per layer is moderate."""
    V, T, fixed = _rod(n_cross, n_long, hexes)
    z = V[:, 2] / V[:, 2].max()
    a = 2 * np.pi * turns * z
    c = np.array([0.5, 0.5])
    x0 = V.copy()
    d = V[fixed, :2] - c
    ca, sa = np.cos(a[fixed]), np.sin(a[fixed])
    x0[fixed, 0] = c[0] + ca * d[:, 0] - sa * d[:, 1]
    x0[fixed, 1] = c[1] + sa * d[:, 0] + ca * d[:, 1]
    return Tangle(name or f"twist{turns:g}", V, T, x0, fixed)


def bent_box(n_cross: int, n_long: int, angle_deg: float = 180.0, name: str | None = None,
             hexes: bool = False) -> Tangle:
    """A rod of :func:`box_mesh` tets (:func:`hex_mesh` hexahedra with ``hexes``) along z whose
    boundary is bent about the y axis into an arc of ``angle_deg`` degrees (the rod's centre
    line keeps its length), interior at rest.  The bent rest mesh is the injective solution
    when the bend radius exceeds the thickness."""
    V, T, fixed = _rod(n_cross, n_long, hexes)
    length = V[:, 2].max()
    phi = np.deg2rad(angle_deg)
    R = length / phi  # radius of the centre line (x = 0.5)
    theta = V[fixed, 2] / R
    r = R + (V[fixed, 0] - 0.5)
    x0 = V.copy()
    x0[fixed, 0] = 0.5 - R + r * np.cos(theta)
    x0[fixed, 2] = r * np.sin(theta)
    return Tangle(name or f"bend{angle_deg:g}", V, T, x0, fixed)


def squashed_boundary(V, S, depth: float = 0.6, name: str | None = None) -> Tangle:
    """Push the boundary in along the last axis: a boundary vertex at height ``h`` goes to
    ``h (1 - depth b)`` with the bump ``b = prod_i sin(pi s_i)`` over the other coordinates
    ``s_i`` normalised to [0, 1], so the top side dips towards the bottom; interior at rest (it
    sticks out of the squashed boundary).  The same squash applied to every vertex is an
    injective solution for ``depth < 1``."""
    V = np.asarray(V, dtype=np.float64)
    if not 0.0 < depth < 1.0:
        raise ParameterError(f"squashed_boundary needs 0 < depth < 1, got {depth}")
    fixed = _fixed_boundary(V, S)
    lo, hi = V.min(0), V.max(0)
    s = (V[fixed] - lo) / np.where(hi > lo, hi - lo, 1.0)
    bump = np.prod(np.sin(np.pi * s[:, :-1]), axis=1)
    x0 = V.copy()
    x0[fixed, -1] = lo[-1] + (V[fixed, -1] - lo[-1]) * (1.0 - depth * bump)
    return Tangle(name or f"squash{depth:g}", V, np.asarray(S), x0, fixed)


# ------------------------------------------------------------- surfaces that overlap when flattened


def spiral_strip(turns: float = 3.0, radius: float = 1.0, spacing: float = 0.5, width: float = 0.3,
                 lift: float = 1.7, n_across: int = 4, name=None):
    """A band along an Archimedean spiral, lifted into a ramp: its flattening overlaps itself.

    The centre line is ``r(t) = radius + spacing * t / (2 pi)`` for ``t`` in
    ``[0, 2 pi turns]``; the band spans ``r(t) +- width / 2`` radially and rises by ``z = lift * t``.
    Its ``xy`` projection is injective when ``width < spacing``.  Lifting shortens the band's
    geodesic curvature from about ``1 / r`` to ``r / (r^2 + lift^2)``, so its near-isometric
    flattening is a spiral whose successive turns lie about
    ``spacing * |1 - lift^2 / r^2| * sqrt(1 + lift^2 / r^2)`` apart (for small ``spacing``): with
    ``lift`` near ``r`` that is less than ``width`` and the flattened turns overlap.

    Parameters
    ----------
    turns, radius, spacing, width, lift : float
    n_across : int, quads across the band (>= 1), each split in two triangles; along the band
        the quads are about as long (in 3D) as they are wide.

    Returns
    -------
    V : (n, 3) float64;  F : (m, 3) int64, counter-clockwise in the ``xy`` projection.
    """
    if not (turns > 0 and radius > 0 and spacing > 0 and 0 < width < 2 * radius and lift >= 0):
        raise ParameterError(
            f"spiral_strip needs turns, radius, spacing > 0, 0 < width < 2 radius and lift >= 0, got "
            f"turns={turns}, radius={radius}, spacing={spacing}, width={width}, lift={lift}")
    if int(n_across) < 1:
        raise ParameterError(f"spiral_strip needs n_across >= 1, got {n_across}")
    n_across = int(n_across)
    t_end = 2 * np.pi * turns
    b = spacing / (2 * np.pi)
    # arc length of the 3D centre line: |dP/dt| = sqrt(b^2 + r^2 + lift^2)
    tt = np.linspace(0.0, t_end, 4096)
    speed = np.sqrt(b**2 + (radius + b * tt) ** 2 + lift**2)
    arc = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(tt))])
    h = width / n_across
    n_along = max(2, int(np.ceil(arc[-1] / h))) + 1
    t = np.interp(np.linspace(0.0, arc[-1], n_along), arc, tt)
    s = np.linspace(-width / 2, width / 2, n_across + 1)
    T, S = np.meshgrid(t, s, indexing="ij")  # (n_along, n_across + 1)
    R = radius + b * T + S
    V = np.stack([R * np.cos(T), R * np.sin(T), lift * T], -1).reshape(-1, 3)
    k = n_across + 1
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_across), indexing="ij")
    a = (i * k + j).ravel()
    F = np.concatenate([np.stack([a, a + k, a + k + 1], 1), np.stack([a, a + k + 1, a + 1], 1)])
    return V, _orient(V[:, :2], F.astype(np.int64))


def _graph_over_disk(rings, height):
    """:func:`disk_mesh` lifted to ``z = height(r, theta)``: V (n, 3), F (m, 3)."""
    V2, F = disk_mesh(int(rings))
    r = np.hypot(V2[:, 0], V2[:, 1])
    th = np.arctan2(V2[:, 1], V2[:, 0])
    return np.column_stack([V2, height(r, th)]), F


def ruffled_disk(rings: int = 16, waves: int = 9, amplitude: float = 0.6, power: float = 3.0):
    """A unit disk with waves along its rim: ``z = amplitude * r**power * sin(waves * theta)``.

    The rim is much longer than ``2 pi``, so a near-isometric flattening must fold the rim into
    petals, which overlap for large ``amplitude * waves``.  Returns V (n, 3), F (m, 3) (see
    :func:`disk_mesh` for the sizes)."""
    if int(waves) < 1 or not amplitude > 0 or not power > 0:
        raise ParameterError(f"ruffled_disk needs waves >= 1, amplitude > 0 and power > 0, got "
                             f"{waves}, {amplitude}, {power}")
    return _graph_over_disk(rings, lambda r, th: amplitude * r**power * np.sin(waves * th))


def saddle(rings: int = 16, order: int = 2, amplitude: float = 1.0):
    """A saddle over the unit disk: ``z = amplitude * r**order * cos(order * theta)`` (order 2:
    ``amplitude * (x^2 - y^2)``; 3: a monkey saddle).  Returns V (n, 3), F (m, 3)."""
    if int(order) < 2 or not amplitude > 0:
        raise ParameterError(f"saddle needs order >= 2 and amplitude > 0, got {order}, {amplitude}")
    return _graph_over_disk(rings, lambda r, th: amplitude * r**order * np.cos(order * th))


def holed_plate(holes: int = 2, cells: int = 2, thickness: float = 1.0):
    """A closed surface of genus ``holes``: a slab ``(2 holes + 1) x 3`` blocks wide with a square
    hole through every other block of its middle row, each block ``cells x cells`` grid squares
    of side 1, ``thickness`` thick (one cell of wall).  Sharp edges everywhere (a CAD-like part).

    Returns ``V`` (n, 3), ``F`` (m, 3) consistently oriented, outward normals."""
    if int(holes) < 0 or int(cells) < 1 or not thickness > 0:
        raise ParameterError(f"holed_plate needs holes >= 0, cells >= 1 and thickness > 0, got "
                             f"{holes}, {cells}, {thickness}")
    holes, cells = int(holes), int(cells)
    nx, ny = (2 * holes + 1) * cells, 3 * cells
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    keep = ~(((i // cells) % 2 == 1) & (j // cells == 1))
    i, j = i[keep], j[keep]
    corner = lambda di, dj: (i + di) * (ny + 1) + (j + dj)  # noqa: E731
    a, b, c, d = corner(0, 0), corner(1, 0), corner(0, 1), corner(1, 1)
    top = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    n2 = (nx + 1) * (ny + 1)
    gx, gy = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    V = np.concatenate([np.column_stack([gx.ravel(), gy.ravel(), np.full(n2, thickness)]),
                        np.column_stack([gx.ravel(), gy.ravel(), np.zeros(n2)])]).astype(np.float64)
    H = np.stack([top, np.roll(top, -1, axis=1)], axis=-1).reshape(-1, 2)
    key = H[:, 0] * n2 + H[:, 1]
    rim = H[~np.isin(key, H[:, 1] * n2 + H[:, 0])]  # half-edges a -> b with no twin
    p, q = rim[:, 0], rim[:, 1]
    walls = np.concatenate([np.stack([q, p, p + n2], 1), np.stack([q, p + n2, q + n2], 1)])
    F = np.concatenate([top, top[:, ::-1] + n2, walls])
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3).astype(np.int64)

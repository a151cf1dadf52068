"""What :func:`~geomopt.atlas.make_atlas` is given, as one triangle mesh: several meshes side by
side (one atlas shared by all of them), polygons cut into fans of triangles, and the way back
from the atlas's triangles to each input mesh and polygon.

A polygon ``c0 c1 .. c(k-1)`` becomes the fan ``(c0, ci, ci+1)``, ``i = 1 .. k-2``, as the
mesh readers cut them (:func:`geomopt.io.fan_triangulate`); its *diagonals* ``(c0, ci)``,
``i = 2 .. k-2``, are edges of the triangles only, which the atlas's seams avoid, so that every
polygon lies in one chart and is written back with one UV per corner
(:func:`polygon_uv_faces`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._runtime.errors import MeshError, ParameterError
from ..io import fan_triangulate

__all__ = ["AtlasInput", "atlas_input", "polygon_uv_faces"]


@dataclasses.dataclass(frozen=True)
class AtlasInput:
    """The meshes given to :func:`~geomopt.atlas.make_atlas` as one triangle mesh.

    Attributes
    ----------
    V : (n, 3) the vertices of every mesh, mesh after mesh.
    F : (m, 3) int64 triangles into ``V`` (polygons fan-triangulated), mesh after mesh.
    counts : (p,) int64 corners of each input face (3 for a triangle), mesh after mesh; the
        fan of face ``j`` is the ``counts[j] - 2`` consecutive rows of ``F`` from
        ``sum(counts[:j] - 2)``.
    vertex_offsets : (k + 1,) int64, mesh ``i``'s vertices are rows
        ``vertex_offsets[i]:vertex_offsets[i + 1]`` of ``V``.
    face_offsets : (k + 1,) int64, mesh ``i``'s faces (polygons) are entries
        ``face_offsets[i]:face_offsets[i + 1]`` of ``counts``.
    several : whether a list of meshes was given (even of one).
    """

    V: np.ndarray
    F: np.ndarray
    counts: np.ndarray
    vertex_offsets: np.ndarray
    face_offsets: np.ndarray
    several: bool

    def diagonals(self) -> np.ndarray:
        """(m, 3) bool, the half-edges of ``F`` that are polygon diagonals (edges of the fans
        only); half-edge ``(f, c)`` runs from ``F[f, c]`` to ``F[f, (c + 1) % 3]``."""
        c = self.counts
        first = np.cumsum(c - 2) - (c - 2)  # each polygon's first fan triangle
        k = np.repeat(c, c - 2)
        i = np.arange(len(self.F)) - np.repeat(first, c - 2) + 1  # triangle (c0, ci, ci+1)
        out = np.zeros(self.F.shape, dtype=bool)
        out[:, 0] = i >= 2  # (c0, ci)
        out[:, 2] = i + 1 <= k - 2  # (ci+1, c0)
        return out


def _polygons(F, name):
    """``(corners (c,), counts (p,))`` of faces given as an (m, k) array or a list of sequences."""
    if isinstance(F, np.ndarray) and F.dtype != object and F.ndim == 2:
        if F.shape[1] < 3:
            raise MeshError(f"{name} has {F.shape[1]} columns; a face needs at least 3 corners")
        return F.reshape(-1), np.full(len(F), F.shape[1], dtype=np.int64)
    try:
        faces = [np.asarray(f).reshape(-1) for f in F]
    except TypeError as exc:
        raise MeshError(f"{name} must be an (m, k) integer array or a list of polygons, got "
                        f"{type(F).__name__}") from exc
    counts = np.array([len(f) for f in faces], dtype=np.int64)
    if counts.size and counts.min() < 3:
        j = int(np.argmin(counts))
        raise MeshError(f"{name}: face {j} has {counts[j]} corner(s); a face needs at least 3")
    corners = np.concatenate(faces) if faces else np.zeros(0)
    return corners, counts


def _one(V, F, name):
    """``(V (n, 3), corners, counts)`` of one mesh: arrays, or a mesh object as ``V`` with ``F=None``."""
    if F is None:
        if hasattr(V, "vertices") and hasattr(V, "faces"):
            V, F = V.vertices, V.faces
        else:
            raise ParameterError(f"give the faces F with the vertices, or one mesh object with .vertices and "
                                 f".faces (e.g. a trimesh.Trimesh), or a list of meshes; got {type(V).__name__} "
                                 f"and no faces")
    V = np.asarray(V, dtype=np.float64)
    corners, counts = _polygons(F if isinstance(F, (list, tuple)) else np.asarray(F), name)
    if corners.size and (not np.issubdtype(corners.dtype, np.number)
                         or not np.array_equal(corners, np.round(corners))):
        raise MeshError(f"{name} must hold integer vertex indices")
    return V, corners.astype(np.int64), counts


def atlas_input(V, F=None) -> AtlasInput:
    """The :class:`AtlasInput` of ``make_atlas(V, F)``: ``V`` (n, 3) with faces ``F`` ((m, 3)
    triangles, (m, k) polygons of k corners, or a list of polygons), a mesh object with
    ``F=None``, or, with ``F=None``, a list of meshes (mesh objects or ``(V, F)`` pairs).
    Polygons must be convex (their fans must not fold)."""
    several = F is None and isinstance(V, (list, tuple)) and len(V) > 0 and not np.isscalar(V[0]) \
        and (hasattr(V[0], "vertices") or (isinstance(V[0], (list, tuple)) and len(V[0]) == 2
                                           and np.ndim(V[0][0]) == 2))
    meshes = [(m, None) if hasattr(m, "vertices") else tuple(m) for m in V] if several else [(V, F)]
    Vs, Fs, counts, nv, nf = [], [], [], [0], [0]
    for i, (Vi, Fi) in enumerate(meshes):
        name = f"mesh {i}'s faces" if several else "F"
        Vi, corners, ci = _one(Vi, Fi, name)
        if Vi.ndim != 2 or Vi.shape[1] != 3:
            raise MeshError(f"{'mesh %d: ' % i if several else ''}V must be (n, 3) vertices, got shape {Vi.shape}")
        if corners.size and (corners.min() < 0 or corners.max() >= len(Vi)):
            raise MeshError(f"{name} index vertices outside 0..{len(Vi) - 1}")
        Fs.append(fan_triangulate(corners, ci, Vi) + nv[-1])
        Vs.append(Vi)
        counts.append(ci)
        nv.append(nv[-1] + len(Vi))
        nf.append(nf[-1] + len(ci))
    return AtlasInput(np.concatenate(Vs), np.concatenate(Fs).astype(np.int64), np.concatenate(counts),
                      np.asarray(nv, dtype=np.int64), np.asarray(nf, dtype=np.int64), several)


def polygon_uv_faces(uv_faces, counts):
    """The atlas's UV rows per polygon corner, where every polygon lies in one chart.

    Parameters
    ----------
    uv_faces : (m, 3) int the UV row of each fan triangle's corner.
    counts : (p,) int corners of each polygon (``sum(counts - 2) == m``).

    Returns
    -------
    (uv_corners (c,) int64 the UV row of each polygon corner in polygon order, whole (p,) bool
    whether the polygon's fan triangles agree on every shared corner): a polygon crossed by a seam
    (possible only where a packing split cut through it) is not whole, and its corners then
    carry its first fan triangle's rows only where they agree.
    """
    counts = np.asarray(counts, dtype=np.int64)
    T = np.asarray(uv_faces, dtype=np.int64)
    n = counts - 2
    first = np.cumsum(n) - n
    last = first + n - 1
    starts = np.cumsum(counts) - counts
    out = np.empty(int(counts.sum()), dtype=np.int64)
    out[starts] = T[first, 0]
    tri = np.arange(len(T))
    j = tri - np.repeat(first, n) + 1  # triangle (c0, cj, cj+1) of its polygon
    out[np.repeat(starts, n) + j] = T[:, 1]
    out[starts + counts - 1] = T[last, 2]
    owner = np.repeat(np.arange(len(counts)), n)
    agree = (T[:, 0] == out[np.repeat(starts, n)]) & (T[:, 1] == out[np.repeat(starts, n) + j]) \
        & (T[:, 2] == out[np.repeat(starts, n) + j + 1])
    whole = np.ones(len(counts), dtype=bool)
    np.logical_and.at(whole, owner, agree)
    return out, whole

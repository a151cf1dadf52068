"""What the surface formats share: polygons cut into fans of triangles, and the checked arrays a
mesh-with-map writer takes."""

from __future__ import annotations

import numpy as np

from .._runtime.errors import MeshError, MeshFormatError
from .._runtime.validate import validate_simplices, validate_vertices

__all__ = ["fan", "mesh_with_uv"]


def fan(indices, counts, V=None, path=None):
    """Fan-triangulate polygons given as flat corner ``indices`` (int64) and per-polygon ``counts`` (>= 3).

    Returns (sum(counts - 2), 3) int64: polygon ``c0 c1 .. ck`` gives ``(c0, ci, ci+1)``.  With
    the vertex positions ``V``, a polygon whose fan folds (a fan triangle facing against the
    polygon's Newell normal: a non-convex or twisted polygon) is refused, because the triangles
    would not tile the polygon (``path``, the file read, starts the message).  Public as
    :func:`geomopt.io.fan_triangulate`.
    """
    counts = np.asarray(counts, dtype=np.int64)
    if counts.size and (counts == 3).all():
        return indices.reshape(-1, 3)
    starts = np.cumsum(counts) - counts
    ntri = counts - 2
    first = np.repeat(starts, ntri)
    local = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    F = np.stack([indices[first], indices[first + local + 1], indices[first + local + 2]], axis=1)
    if V is not None and indices.size and 0 <= indices.min() and indices.max() < len(V):
        _check_fans(np.asarray(V, np.float64), indices, counts, F, np.repeat(np.arange(counts.size), ntri), path)
    return F


def _check_fans(V, indices, counts, F, owner, path):
    """Refuse polygons (``counts > 3``) whose fan triangles ``F`` (polygon ``owner``) fold."""
    P = np.zeros((V.shape[0], 3))
    P[:, :V.shape[1]] = V
    poly = np.repeat(np.arange(counts.size), counts)
    nxt = np.arange(indices.size) + 1
    nxt[np.cumsum(counts) - 1] = np.cumsum(counts) - counts  # each polygon closes on its first corner
    normal = np.zeros((counts.size, 3))
    np.add.at(normal, poly, np.cross(P[indices], P[indices[nxt]]))  # Newell's normal (twice the area)
    tri = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    bad = (np.einsum("ij,ij->i", tri, normal[owner]) <= 0) & (counts[owner] > 3)
    if bad.any():
        k = int(owner[np.flatnonzero(bad)[0]])
        where = "" if path is None else f"{path}: "
        raise MeshFormatError(
            f"{where}face {k + 1} is a polygon of {counts[k]} corners that is not convex (or is twisted): "
            f"cutting it into a fan of triangles folds it; triangulate the mesh before reading it")


def mesh_with_uv(V, F, UV, uv_faces=None):
    """Validated ``(V (n,3), F (m,3), UV (n,2))`` for the writers; with ``uv_faces`` (m, 3),
    ``(V, F, UV (k, 2), uv_faces)``: one UV row per face corner group (an atlas)."""
    V = validate_vertices(V, "V", dim=3)
    UV = validate_vertices(UV, "UV", dim=2)
    if uv_faces is not None:
        F = validate_simplices(F, V.shape[0], 3, "F")
        T = validate_simplices(uv_faces, UV.shape[0], 3, "uv_faces")
        if T.shape != F.shape:
            raise MeshError(f"uv_faces has {T.shape[0]} rows but F has {F.shape[0]}; give one UV triangle per face")
        return V, F, UV, T
    if UV.shape[0] != V.shape[0]:
        raise MeshError(f"UV has {UV.shape[0]} rows but V has {V.shape[0]}; give one UV per vertex")
    return V, validate_simplices(F, V.shape[0], 3, "F"), UV

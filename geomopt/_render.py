"""Per-pixel rendering of a textured triangle surface in NumPy (no OpenGL, no display).

matplotlib's 3D axes colour whole polygons, so a checkerboard drawn through a UV map comes
out one colour per triangle: jagged and stripy wherever a check is smaller than a triangle,
and useless for judging conformality.  :func:`render_uv_checker` rasterises the surface
instead: an orthographic camera, a z-buffer, and per pixel the UV coordinates interpolated
barycentrically, the checkerboard evaluated there, and Lambert shading from the face normal.
Everything is vectorised over (triangle, candidate pixel) pairs, in chunks.
"""

from __future__ import annotations

import numpy as np

__all__ = ["camera_rotation", "project", "rasterize", "render_uv_checker", "vertex_normals", "CHECKER_COLORS"]

#: the two squares of the checkerboard (RGB in [0, 1]): white and orange
CHECKER_COLORS = ((0.97, 0.97, 0.95), (0.95, 0.55, 0.10))
_CHUNK = 4_000_000  # candidate (triangle, pixel) pairs per vectorised batch


def camera_rotation(elev: float, azim: float, up: str = "y") -> np.ndarray:
    """(3, 3) rotation taking world coordinates to camera coordinates (x right, y up, z
    towards the viewer) for a view from elevation ``elev`` and azimuth ``azim`` in degrees
    about the world axis ``up`` (``"x"``, ``"y"`` or ``"z"``; azimuth 0 looks along the
    next axis after it: from +z for y up, as OpenGL, from +x for z up, as matplotlib)."""
    k = "xyz".index(up)
    U, F0 = np.eye(3)[k], np.eye(3)[(k + 1) % 3] if up != "y" else np.eye(3)[2]
    S = np.cross(U, F0)
    e, a = np.radians(elev), np.radians(azim)
    towards = np.cos(e) * (np.cos(a) * F0 + np.sin(a) * S) + np.sin(e) * U
    right = np.cos(a) * S - np.sin(a) * F0  # horizontal: defined straight from above too
    return np.stack([right, np.cross(towards, right), towards])


def project(V, rotation, size):
    """Pixel coordinates of the vertices ``V`` (n, 3): (n, 2) float (column, row from the top)
    and (n,) depth (larger is nearer), the mesh fitted into ``size`` = (width, height) with a
    2% margin and equal scales."""
    P = (np.asarray(V, np.float64) - np.asarray(V).mean(axis=0)) @ rotation.T
    lo, hi = P[:, :2].min(axis=0), P[:, :2].max(axis=0)
    width, height = size
    scale = 0.96 * min(width / max(hi[0] - lo[0], 1e-300), height / max(hi[1] - lo[1], 1e-300))
    mid = (lo + hi) / 2
    col = (P[:, 0] - mid[0]) * scale + width / 2
    row = height / 2 - (P[:, 1] - mid[1]) * scale
    return np.c_[col, row], P[:, 2]


def rasterize(xy, depth, F, size):
    """Visible triangle and barycentric coordinates per pixel.

    Parameters
    ----------
    xy : (n, 2) pixel coordinates (column, row) of the vertices;  depth : (n,), larger nearer.
    F : (m, 3) triangles;  size : (width, height) in pixels.

    Returns
    -------
    face : (height, width) int, the nearest triangle covering each pixel centre, -1 for none.
    bary : (height, width, 3) float, its barycentric coordinates there (0 where ``face`` is -1).
    """
    width, height = size
    F = np.asarray(F, np.int64)
    T = xy[F]  # (m, 3, 2)
    lo = np.clip(np.floor(T.min(axis=1) - 0.5).astype(np.int64) + 1, 0, [width, height])
    hi = np.clip(np.floor(T.max(axis=1) - 0.5).astype(np.int64) + 1, 0, [width, height])
    count = np.maximum(hi[:, 0] - lo[:, 0], 0) * np.maximum(hi[:, 1] - lo[:, 1], 0)
    best = np.full(width * height, -np.inf)
    face = np.full(width * height, -1, np.int64)
    bary = np.zeros((width * height, 3))
    ends = np.searchsorted(np.cumsum(count), np.arange(_CHUNK, count.sum() + _CHUNK, _CHUNK), side="right")
    start = 0
    for end in np.unique(np.r_[ends, len(F)]):
        if end > start:
            _raster_chunk(np.arange(start, end), T, depth[F], lo, hi, count, width, best, face, bary)
        start = end
    return face.reshape(height, width), bary.reshape(height, width, 3)


def _raster_chunk(tri, T, Z, lo, hi, count, width, best, face, bary):
    """Rasterise the triangles ``tri`` into the flat buffers ``best`` / ``face`` / ``bary``."""
    n = count[tri]
    tri = np.repeat(tri, n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # index within each box
    w = np.maximum(hi[tri, 0] - lo[tri, 0], 1)
    px = lo[tri, 0] + k % w + 0.5
    py = lo[tri, 1] + k // w + 0.5
    a, b, c = T[tri, 0], T[tri, 1], T[tri, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ok = np.abs(area) > 1e-12
    area = np.where(ok, area, 1.0)
    l1 = ((c[:, 0] - px) * (a[:, 1] - py) - (c[:, 1] - py) * (a[:, 0] - px)) / area
    l2 = ((a[:, 0] - px) * (b[:, 1] - py) - (a[:, 1] - py) * (b[:, 0] - px)) / area
    l0 = 1.0 - l1 - l2
    tol = -1e-9
    inside = ok & (l0 >= tol) & (l1 >= tol) & (l2 >= tol)
    lam = np.stack([l0, l1, l2], axis=1)[inside]
    tri, pix = tri[inside], (py[inside] - 0.5).astype(np.int64) * width + (px[inside] - 0.5).astype(np.int64)
    z = np.einsum("ij,ij->i", lam, Z[tri])
    np.maximum.at(best, pix, z)  # the nearest depth per pixel, over this and earlier chunks
    win = z == best[pix]
    face[pix[win]], bary[pix[win]] = tri[win], lam[win]


def render_uv_checker(V, F, uv, size=(900, 900), elev=15.0, azim=30.0, up="y", checks=20,
                      light=(0.35, 0.5, 1.0), supersample=2):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3)
    textured with a ``checks`` x ``checks`` checkerboard through the UV map ``uv`` (n, 2),
    evaluated per pixel.

    The checkerboard spans the UV map's bounding square: its squares come out as squares on
    the surface where the map is conformal, all of one size where it preserves area.  The
    view: orthographic, from elevation ``elev`` and azimuth ``azim`` (degrees) about the world
    axis ``up`` (:func:`camera_rotation`; the default is a three-quarter view from +z, y up,
    the usual convention of scanned meshes).  Smooth Lambert shading from ``light`` (camera
    coordinates), two-sided; the image is rendered ``supersample`` times larger and averaged
    down (anti-aliased edges); pixels the surface does not cover are transparent.
    """
    V, uv = np.asarray(V, np.float64), np.asarray(uv, np.float64)
    F = np.asarray(F, np.int64)
    R = camera_rotation(elev, azim, up)
    big = (size[0] * supersample, size[1] * supersample)
    face, bary = rasterize(*project(V, R, big), F, big)
    hit = face >= 0
    f, b = face[hit], bary[hit]
    lo, span = uv.min(axis=0), max(float(np.ptp(uv, axis=0).max()), 1e-300)
    t = np.einsum("ij,ijk->ik", b, (uv[F[f]] - lo) / span * checks)
    odd = (np.floor(t[:, 0]) + np.floor(t[:, 1])) % 2 == 1
    rgb = np.where(odd[:, None], CHECKER_COLORS[1], CHECKER_COLORS[0])
    normal = np.einsum("ij,ijk->ik", b, vertex_normals(V, F)[F[f]]) @ R.T
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    lam = np.abs(normal @ (np.asarray(light) / np.linalg.norm(light)))
    image = np.zeros(face.shape + (4,))
    image[hit, :3] = np.clip(rgb * (0.3 + 0.7 * lam[:, None]), 0.0, 1.0)
    image[hit, 3] = 1.0
    s = supersample
    image = image.reshape(size[1], s, size[0], s, 4)
    alpha = image[..., 3].mean(axis=(1, 3))
    rgb = (image[..., :3] * image[..., 3:]).mean(axis=(1, 3)) / np.maximum(alpha, 1e-300)[..., None]
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def vertex_normals(V, F):
    """(n, 3) unit vertex normals: the sums of the area-weighted normals of their faces."""
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.zeros_like(V)
    for k in range(3):
        np.add.at(out, F[:, k], N)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)

"""Per-pixel rendering of a textured triangle surface in NumPy (no OpenGL, no display).

matplotlib's 3D axes colour whole polygons, so a checkerboard drawn through a UV map comes
out one colour per triangle: jagged and stripy wherever a check is smaller than a triangle,
and useless for judging conformality.  :func:`render_uv_checker` rasterises the surface
instead: an orthographic camera, a z-buffer, and per pixel the UV coordinates interpolated
barycentrically, the checkerboard evaluated there, and Lambert shading from the face normal.
Triangles are scan-converted by matplotlib's Agg (:func:`rasterize`); the per-pixel work
is vectorised NumPy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["camera_rotation", "project", "rasterize", "render_surface", "render_uv_checker", "render_sphere_checker",
           "vertex_normals", "CHECKER_COLORS"]

#: the two squares of the checkerboard (RGB in [0, 1]): white and orange
CHECKER_COLORS = ((0.97, 0.97, 0.95), (0.95, 0.55, 0.10))
#: bits of a triangle's number drawn at once (three 8-bit colour channels); more triangles
#: than 2**CODE_BITS - 1 are drawn again for the higher bits
CODE_BITS = 24


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

    The triangles are drawn far to near (by the depth of their centroids: the painter's
    algorithm) by matplotlib's Agg rasteriser, each in a flat colour that encodes its index,
    and read back; per covered pixel the barycentric coordinates of its centre in that
    triangle follow from the triangle's two edge functions.  A C++ scanline fill of each
    triangle once, then O(pixels) NumPy: about 6x cheaper than testing every (triangle, pixel
    of its bounding box) pair against a z-buffer.  Agg fills every pixel a triangle touches,
    so a pixel on an edge goes to the nearer of the two triangles and its coordinates may lie
    just outside it; they are clipped to the triangle.

    Parameters
    ----------
    xy : (n, 2) pixel coordinates (column, row) of the vertices;  depth : (n,), larger nearer.
    F : (m, 3) triangles;  size : (width, height) in pixels.

    Returns
    -------
    face : (height, width) int, the nearest triangle covering each pixel, -1 for none.
    bary : (height, width, 3) float, its barycentric coordinates there (0 where ``face`` is -1).
    """
    width, height = size
    xy, F = np.asarray(xy, np.float64), np.asarray(F, np.int64)
    T = xy[F]  # (m, 3, 2)
    e1, e2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    drawn = np.flatnonzero(np.abs(area) > 1e-12)  # a triangle of no area covers no pixel centre
    drawn = drawn[np.argsort(np.asarray(depth, np.float64)[F[drawn]].mean(axis=1), kind="stable")]
    face = np.full(height * width, -1, np.int64)
    shift = 0
    while (len(F) + 1) >> shift:  # CODE_BITS bits of the face number per drawing
        code = _draw_codes(T[drawn], ((drawn + 1) >> shift) & ((1 << CODE_BITS) - 1), size).ravel()
        face = np.where(code >= 0, np.maximum(face, 0) + (code << shift), face)
        shift += CODE_BITS
    face -= face >= 0  # codes are face + 1: 0 is a pixel no triangle covers
    hit = np.flatnonzero(face >= 0)
    f = face[hit]
    px, py = hit % width + 0.5, hit // width + 0.5
    l1 = ((px - T[f, 0, 0]) * e2[f, 1] - (py - T[f, 0, 1]) * e2[f, 0]) / area[f]
    l2 = ((py - T[f, 0, 1]) * e1[f, 0] - (px - T[f, 0, 0]) * e1[f, 1]) / area[f]
    lam = np.clip(np.stack([1.0 - l1 - l2, l1, l2], axis=1), 0.0, None)
    bary = np.zeros((height * width, 3))
    bary[hit] = lam / lam.sum(axis=1, keepdims=True)
    return face.reshape(height, width), bary.reshape(height, width, 3)


def _draw_codes(T, codes, size):
    """(height, width) int: the 24-bit ``codes`` (k,) of the triangles ``T`` (k, 3, 2), drawn
    in order (later ones on top) without anti-aliasing, or -1 where none is drawn."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    width, height = size
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    fig.patch.set_alpha(0.0)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)  # row 0 at the top
    rgba = np.ones((len(codes), 4))
    rgba[:, :3] = np.stack([codes >> 16, (codes >> 8) & 255, codes & 255], axis=1) / 255.0
    ax.add_collection(PolyCollection(T, facecolors=rgba, edgecolors="none", linewidths=0.0,
                                     antialiaseds=False, snap=False))
    canvas.draw()
    buf = np.asarray(canvas.buffer_rgba()).astype(np.int64)
    code = (buf[..., 0] << 16) | (buf[..., 1] << 8) | buf[..., 2]
    return np.where(buf[..., 3] == 255, code, -1)


def render_surface(V, F, colour, size=(900, 900), elev=15.0, azim=30.0, up="y", light=(0.35, 0.5, 1.0),
                   supersample=2):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3), each
    pixel coloured by ``colour(face, bary, hit)`` -> (k, 3) RGB: ``face`` (k,) and ``bary``
    (k, 3) the face and barycentric coordinates of the k covered pixels, ``hit`` (h, w) bool
    which pixels they are (row-major).

    The view: orthographic, from elevation ``elev`` and azimuth ``azim`` (degrees) about the
    world axis ``up`` (:func:`camera_rotation`; the default is a three-quarter view from +z, y
    up, the usual convention of scanned meshes).  Smooth Lambert shading from ``light`` (camera
    coordinates), two-sided, evaluated at the vertices and interpolated; the image is rendered
    ``supersample`` times larger and averaged down (anti-aliased edges); pixels the surface does
    not cover are transparent.
    """
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    R = camera_rotation(elev, azim, up)
    big = (size[0] * supersample, size[1] * supersample)
    face, bary = rasterize(*project(V, R, big), F, big)
    hit = face >= 0
    f, b = face[hit], bary[hit]
    rgb = colour(f, b, hit)
    lit = vertex_normals(V, F) @ (R.T @ (np.asarray(light, np.float64) / np.linalg.norm(light)))
    lam = np.abs(np.einsum("ij,ij->i", b, lit[F[f]]))  # Gouraud: shaded per vertex, interpolated
    image = np.zeros(face.shape + (4,))
    image[hit, :3] = np.clip(rgb * (0.3 + 0.7 * lam[:, None]), 0.0, 1.0)
    image[hit, 3] = 1.0
    s = supersample
    image = image.reshape(size[1], s, size[0], s, 4)
    alpha = image[..., 3].mean(axis=(1, 3))
    rgb = (image[..., :3] * image[..., 3:]).mean(axis=(1, 3)) / np.maximum(alpha, 1e-300)[..., None]
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def _checker_rgb(orange):
    """(k, 3) the checkerboard's colours for the (k,) shares of its second colour."""
    orange = orange[:, None]
    return (1.0 - orange) * np.asarray(CHECKER_COLORS[0]) + orange * np.asarray(CHECKER_COLORS[1])


def render_uv_checker(V, F, uv, size=(900, 900), elev=15.0, azim=30.0, up="y", checks=20,
                      light=(0.35, 0.5, 1.0), supersample=2):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3)
    textured with a ``checks`` x ``checks`` checkerboard through the UV map ``uv`` (n, 2),
    evaluated per pixel and box-filtered over its footprint (:func:`render_surface`: the view,
    shading and anti-aliasing).

    The checkerboard spans the UV map's bounding square: its squares come out as squares on
    the surface where the map is conformal, all of one size where it preserves area.
    """
    uv, F = np.asarray(uv, np.float64), np.asarray(F, np.int64)
    lo, span = uv.min(axis=0), max(float(np.ptp(uv, axis=0).max()), 1e-300)

    def colour(f, b, hit):
        return _checker_rgb(_filtered_checker(np.einsum("ij,ijk->ik", b, (uv[F[f]] - lo) / span * checks), hit))

    return render_surface(V, F, colour, size, elev, azim, up, light, supersample)


def render_sphere_checker(V, F, x, size=(900, 900), elev=15.0, azim=30.0, up="y", checks=12,
                          light=(0.35, 0.5, 1.0), supersample=2):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3)
    textured through its map ``x`` (n, 3) onto the unit sphere with a latitude-longitude
    checkerboard (``checks`` bands of latitude, ``2 checks`` of longitude), evaluated per pixel
    on the interpolated and normalised sphere point (no seam; anti-aliased by supersampling).
    Where the map is conformal the checks look as they do on the sphere (squares away from the
    poles)."""
    x, F = np.asarray(x, np.float64), np.asarray(F, np.int64)

    def colour(f, b, hit):
        p = np.einsum("ij,ijk->ik", b, x[F[f]])
        p /= np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-300)
        lat = np.floor(np.arccos(np.clip(p[:, 2], -1.0, 1.0)) / np.pi * checks)
        lon = np.floor((np.arctan2(p[:, 1], p[:, 0]) / np.pi + 1.0) * checks)
        return _checker_rgb(np.mod(lat + lon, 2.0))

    return render_surface(V, F, colour, size, elev, azim, up, light, supersample)


def _filtered_checker(t, hit):
    """(k,) share of the second colour in each pixel: the checkerboard ``t`` (k, 2) (UV in
    checks; squares with an odd sum of floors are the second colour) box-filtered over the
    pixel's footprint, its UV change to the neighbouring pixels (``hit`` (h, w): the pixels
    ``t`` belongs to, in row-major order).  Anti-aliased borders without supersampling: a
    pixel whose centre lies on one side of a border is mostly of that side's colour."""
    grid = np.full(hit.shape + (2,), np.nan)
    grid[hit] = t
    foot = np.zeros_like(grid)
    for a in (0, 1):  # per direction, the larger of the steps to the pixels on either side
        step = np.abs(np.diff(grid, axis=a))
        before, after = ([(0, 0)] * 3 for _ in range(2))
        before[a], after[a] = (1, 0), (0, 1)
        foot += np.nan_to_num(np.fmax(np.pad(step, before, constant_values=np.nan),
                                      np.pad(step, after, constant_values=np.nan)))
    w = np.minimum(foot[hit], 2.0)  # at two checks per pixel the average is the mean colour

    def ramp(x):  # the integral of the square wave +1 on [0, 1), -1 on [1, 2)
        return 1.0 - np.abs(np.mod(x, 2.0) - 1.0)

    sharp = np.where(np.mod(np.floor(t), 2.0) == 0.0, 1.0, -1.0)
    safe = np.maximum(w, 1e-9)
    wave = np.where(w > 1e-9, (ramp(t + safe / 2) - ramp(t - safe / 2)) / safe, sharp)
    return 0.5 - 0.5 * wave[:, 0] * wave[:, 1]


def vertex_normals(V, F):
    """(n, 3) unit vertex normals: the sums of the area-weighted normals of their faces."""
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.zeros_like(V)
    for k in range(3):
        np.add.at(out, F[:, k], N)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)

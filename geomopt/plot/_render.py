"""Per-pixel rendering of a textured triangle surface in NumPy (no OpenGL, no display).

matplotlib's 3D axes colour whole polygons, so a checkerboard drawn through a UV map comes
out one colour per triangle: jagged and stripy wherever a check is smaller than a triangle,
and useless for judging conformality.  :func:`render_uv_checker` rasterises the surface
instead: an orthographic camera, a z-buffer, and per pixel the UV coordinates interpolated
barycentrically, the checkerboard evaluated there (box-filtered over the pixel), and Lambert
shading interpolated from the vertex normals.  Everything is vectorised NumPy, the scan
conversion too (:func:`visible_pixels`: runs of pixels per triangle and row, a z-buffer by
``np.maximum.at``); no matplotlib.
"""

from __future__ import annotations

import numpy as np

__all__ = ["camera_rotation", "project", "rasterize", "render_surface", "render_uv_checker", "render_sphere_checker",
           "vertex_normals", "visible_pixels", "nearest_faces", "plane_values", "barycentric_planes",
           "CHECKER_COLORS"]

#: the two squares of the checkerboard (RGB in [0, 1]): white and orange
CHECKER_COLORS = ((0.97, 0.97, 0.95), (0.95, 0.55, 0.10))


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
    """Visible triangle and barycentric coordinates per pixel (:func:`visible_pixels` as images).

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
    pixels, f, lam = visible_pixels(xy, depth, F, size)
    face = np.full(height * width, -1, np.int64)
    face[pixels] = f
    bary = np.zeros((height * width, 3))
    bary[pixels] = lam
    return face.reshape(height, width), bary.reshape(height, width, 3)


def visible_pixels(xy, depth, F, size):
    """The covered pixels, the nearest triangle at each and the barycentric coordinates of
    its centre there (:func:`nearest_faces`, :func:`plane_values`).

    Returns
    -------
    pixels : (k,) int, row-major indices of the covered pixels, ascending.
    face : (k,) int, the nearest triangle at each.
    bary : (k, 3) float, the barycentric coordinates of the pixel centre in it (clipped to it).
    """
    pixels, face, planes = nearest_faces(xy, depth, F, size)
    lam = np.clip(plane_values(planes, pixels, face, size[0]), 0.0, None)  # a centre on an edge may round outside
    lam /= np.maximum(lam.sum(axis=1, keepdims=True), 1e-300)
    return pixels, face, lam


def nearest_faces(xy, depth, F, size):
    """The covered pixels and the nearest triangle at each.

    Scan conversion in vectorised NumPy: a triangle covers the pixels whose centres lie in it,
    found as runs (:func:`_spans`: one per triangle and row, between its edges, so no pixel of
    a bounding box is tested in vain); of the triangles covering a pixel the nearest there
    wins: a z-buffer, the depth interpolated at the pixel centre, resolved by one
    ``np.maximum.at`` over keys holding the quantised depth (30 bits) above the run's number.

    Parameters
    ----------
    xy : (n, 2) pixel coordinates (column, row) of the vertices;  depth : (n,), larger nearer.
    F : (m, 3) triangles;  size : (width, height) in pixels.

    Returns
    -------
    pixels : (k,) int, row-major indices of the covered pixels, ascending.
    face : (k,) int, the nearest triangle at each.
    planes : (m, 3, 3) the triangles' :func:`barycentric_planes` (zero for one of no area).
    """
    width, height = size
    xy, F, depth = np.asarray(xy, np.float64), np.asarray(F, np.int64), np.asarray(depth, np.float64)
    planes, ok = barycentric_planes(xy[F])
    face, row, c0, count = _spans(xy, F, np.flatnonzero(ok), size)  # one of no area covers no centre
    dz = np.einsum("fij,fj->fi", planes, depth[F])[face]  # per run: the depth plane, z = (x, y, 1) @ dz
    start = np.cumsum(count) - count
    first = row * width + c0
    z = np.repeat(dz @ np.array([0.5, 0.5, 1.0]) + dz[:, 0] * (c0 - start) + dz[:, 1] * row, count)
    z += np.repeat(dz[:, 0], count) * np.arange(len(z))  # the depth at each candidate pixel's centre
    lo, hi = float(depth.min(initial=0.0)), float(depth.max(initial=0.0))
    z = np.clip((z - lo) * ((2.0**30 - 1) / (hi - lo) if hi > lo else 0.0), 0, 2**30 - 1).astype(np.int64)
    z <<= 32
    z |= np.repeat(np.arange(len(face), dtype=np.int64), count)
    best = np.full(height * width, -1, np.int64)
    np.maximum.at(best, np.repeat(first - start, count) + np.arange(len(z)), z)
    pixels = np.flatnonzero(best >= 0)
    return pixels, face[best[pixels] & 0xFFFFFFFF], planes


def plane_values(P, pixels, face, width):
    """(k, a) the affine functions ``P`` (m, 3, a) of the pixel (``(x, y, 1) @ P[f]``) of the
    triangles ``face`` (k,) at the centres of the ``pixels`` (k,) (row-major, ``width`` wide)."""
    row, col = np.divmod(pixels, width)
    out = (col + 0.5)[:, None] * np.take(P[:, 0], face, axis=0)  # one (k, a) gather at a time: a
    out += (row + 0.5)[:, None] * np.take(P[:, 1], face, axis=0)  # third of the memory, half the time
    out += np.take(P[:, 2], face, axis=0)
    return out


def barycentric_planes(T):
    """(m, 3, 3) ``B`` with ``(x, y, 1) @ B[f]`` the barycentric coordinates of the point (x, y)
    in the triangle ``T[f]`` (m, 3, 2), and (m,) bool: the triangles of some area (twice it at
    least 1e-12; ``B`` is 0 for the others)."""
    e1, e2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(area) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, area, 1.0), 0.0)
    B = np.empty((len(T), 3, 3))
    B[:, 0, 1], B[:, 1, 1] = e2[:, 1] * inv, -e2[:, 0] * inv  # l1 = ((x - x0) e2y - (y - y0) e2x) / area
    B[:, 0, 2], B[:, 1, 2] = -e1[:, 1] * inv, e1[:, 0] * inv  # l2 = ((y - y0) e1x - (x - x0) e1y) / area
    B[:, 2, 1:] = -(T[:, 0, 0, None] * B[:, 0, 1:] + T[:, 0, 1, None] * B[:, 1, 1:])
    B[:, :2, 0] = -(B[:, :2, 1] + B[:, :2, 2])  # l0 = 1 - l1 - l2
    B[:, 2, 0] = np.where(ok, 1.0 - B[:, 2, 1] - B[:, 2, 2], 0.0)
    return B, ok


def _spans(xy, F, drawn, size):
    """The runs of pixels whose centres lie in the triangles ``drawn`` (rows of ``F``), inside
    the image ``size`` = (width, height): (face, row, first column, count), one run per
    (triangle, row).  Each edge is evaluated from its end with the lower vertex number, so the
    two triangles of a shared edge find the same crossing: a centre on it is in one of them
    at least (no cracks)."""
    width, height = size
    E = np.stack([F[drawn][:, [a, b]] for a, b in ((0, 1), (1, 2), (2, 0))], axis=1)  # (t, 3, 2) edges
    E.sort(axis=2)
    P, Q = xy[E[..., 0]], xy[E[..., 1]]  # (t, 3, 2)
    dy = Q[..., 1] - P[..., 1]
    slope = (Q[..., 0] - P[..., 0]) / np.where(dy != 0.0, dy, 1.0)
    ylo, yhi = np.minimum(P[..., 1], Q[..., 1]), np.maximum(P[..., 1], Q[..., 1])
    ylo[dy == 0.0], yhi[dy == 0.0] = np.inf, -np.inf  # a level edge is crossed by no row line
    r0 = np.clip(np.ceil(ylo.min(axis=1) - 0.5), 0, height).astype(np.int64)  # rows whose centres it spans
    r1 = np.clip(np.floor(yhi.max(axis=1) - 0.5), -1, height - 1).astype(np.int64)
    n = np.maximum(r1 - r0 + 1, 0)
    owner = np.repeat(np.arange(len(drawn)), n)
    rows = np.arange(len(owner)) + np.repeat(r0 - (np.cumsum(n) - n), n)
    yc = rows + 0.5
    left, right = np.full(len(rows), np.inf), np.full(len(rows), -np.inf)
    for e in range(3):  # where the row's centre line crosses each edge
        on = (ylo[owner, e] <= yc) & (yc <= yhi[owner, e])
        x = P[owner, e, 0] + (yc - P[owner, e, 1]) * slope[owner, e]
        np.minimum(left, np.where(on, x, np.inf), out=left)
        np.maximum(right, np.where(on, x, -np.inf), out=right)
    c0 = np.clip(np.ceil(left - 0.5), 0, width).astype(np.int64)
    c1 = np.clip(np.floor(right - 0.5), -1, width - 1).astype(np.int64)
    return drawn[owner], rows, c0, np.maximum(c1 - c0 + 1, 0)


def _view(V, size, elev, azim, up, supersample):
    """The camera rotation, the vertices' pixel coordinates and depths in the image rendered
    ``supersample`` times larger than ``size``, and that image's size."""
    R = camera_rotation(elev, azim, up)
    big = (size[0] * supersample, size[1] * supersample)
    return R, *project(V, R, big), big


def render_surface(V, F, colour, size=(900, 900), elev=15.0, azim=30.0, up="y", light=(0.35, 0.5, 1.0),
                   supersample=2, attributes=None):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3), each
    pixel coloured by ``colour(face, values, hit)`` -> (k, 3) RGB: ``face`` (k,) the faces of
    the k covered pixels, ``hit`` (h, w) bool which pixels they are (row-major), ``values`` the
    per-vertex ``attributes`` (n, a) interpolated at their centres, (k, a) (one gather and
    three products per pixel: each face's attributes as an affine function of the pixel), or
    when ``attributes`` is None their barycentric coordinates (k, 3).

    The view: orthographic, from elevation ``elev`` and azimuth ``azim`` (degrees) about the
    world axis ``up`` (:func:`camera_rotation`; the default is a three-quarter view from +z, y
    up, the usual convention of scanned meshes).  Smooth Lambert shading from ``light`` (camera
    coordinates), two-sided, evaluated at the vertices and interpolated; the image is rendered
    ``supersample`` times larger and averaged down (anti-aliased edges); pixels the surface does
    not cover are transparent.
    """
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    R, xy, depth, big = _view(V, size, elev, azim, up, supersample)
    pixels, f, planes = nearest_faces(xy, depth, F, big)
    lit = vertex_normals(V, F) @ (R.T @ (np.asarray(light, np.float64) / np.linalg.norm(light)))
    corner = np.broadcast_to(np.eye(3), (len(F), 3, 3)) if attributes is None else np.asarray(attributes, np.float64)[F]
    values = plane_values(planes @ np.concatenate([corner, lit[F][..., None]], axis=2), pixels, f, big[0])
    lam = np.abs(values[:, -1])  # Gouraud: shaded per vertex, interpolated
    values = values[:, :-1]
    if attributes is None:  # a centre on an edge may round to just outside
        values = np.clip(values, 0.0, None)
        values /= np.maximum(values.sum(axis=1, keepdims=True), 1e-300)
    hit = np.zeros(big[1] * big[0], bool)
    hit[pixels] = True
    rgb = colour(f, values, hit.reshape(big[1], big[0]))
    rgba = np.ones((len(pixels), 4), np.float32)  # 8-bit output: float32 is exact enough, half the bytes
    np.clip(rgb * (0.3 + 0.7 * lam[:, None]), 0.0, 1.0, out=rgba[:, :3])
    image = np.zeros((big[1] * big[0], 4), np.float32)
    image[pixels] = rgba  # whole rows: one scatter
    s = supersample
    if s == 1:
        return image.reshape(size[1], size[0], 4)
    image = image.reshape(size[1], s, size[0], s, 4)
    alpha = image[..., 3].mean(axis=(1, 3))
    rgb = (image[..., :3] * image[..., 3:]).mean(axis=(1, 3)) / np.maximum(alpha, 1e-300)[..., None]
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def _checker_rgb(orange):
    """(k, 3) the checkerboard's colours for the (k,) shares of its second colour."""
    orange = orange[:, None]
    rgb = (1.0 - orange) * np.asarray(CHECKER_COLORS[0])
    rgb += orange * np.asarray(CHECKER_COLORS[1])
    return rgb


def render_uv_checker(V, F, uv, size=(900, 900), elev=15.0, azim=30.0, up="y", checks=20,
                      light=(0.35, 0.5, 1.0), supersample=2):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3)
    textured with a ``checks`` x ``checks`` checkerboard through the UV map ``uv`` (n, 2),
    evaluated per pixel and box-filtered over its footprint (:func:`render_surface`: the view,
    shading and anti-aliasing).

    The checkerboard spans the UV map's bounding square: its squares come out as squares on
    the surface where the map is conformal, all of one size where it preserves area.
    """
    V, uv, F = np.asarray(V, np.float64), np.asarray(uv, np.float64), np.asarray(F, np.int64)
    lo, span = uv.min(axis=0), max(float(np.ptp(uv, axis=0).max()), 1e-300)
    t = (uv - lo) / span * checks  # (n, 2) UV in checks
    xy = _view(V, size, elev, azim, up, supersample)[1]
    foot = _footprints(xy[F], t[F])

    def colour(f, tt, hit):
        return _checker_rgb(_filtered_checker(tt, foot[f]))

    return render_surface(V, F, colour, size, elev, azim, up, light, supersample, attributes=t)


def _footprints(T, tex):
    """(m, 2) the texture coordinates ``tex`` (m, 3, 2) of the triangles ``T`` (m, 3, 2, pixels)
    change over a pixel of each, per coordinate: ``|d tex / d column| + |d tex / d row|``, as
    the differences to the neighbouring pixels inside the triangle (the texture is affine on it);
    0 for a triangle of no area (it covers no pixel)."""
    E = np.stack([T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]], axis=1)  # (m, 2, 2): rows the edges in pixels
    D = np.stack([tex[:, 1] - tex[:, 0], tex[:, 2] - tex[:, 0]], axis=1)  # their texture changes
    det = E[:, 0, 0] * E[:, 1, 1] - E[:, 0, 1] * E[:, 1, 0]
    ok = np.abs(det) > 1e-12
    inv = np.stack([np.stack([E[:, 1, 1], -E[:, 0, 1]], 1), np.stack([-E[:, 1, 0], E[:, 0, 0]], 1)], 1)
    G = inv / np.where(ok, det, 1.0)[:, None, None] @ D  # (m, 2, 2): d tex_c / d pixel axis i = G[:, i, c]
    return np.where(ok[:, None], np.abs(G).sum(axis=1), 0.0)


def render_sphere_checker(V, F, x, size=(900, 900), elev=15.0, azim=30.0, up="y", checks=12,
                          light=(0.35, 0.5, 1.0), supersample=2):
    """RGBA image (height, width, 4) in [0, 1] of the surface ``V`` (n, 3), ``F`` (m, 3)
    textured through its map ``x`` (n, 3) onto the unit sphere with a latitude-longitude
    checkerboard (``checks`` bands of latitude, ``2 checks`` of longitude), evaluated per pixel
    on the interpolated and normalised sphere point (no seam; anti-aliased by supersampling).
    Where the map is conformal the checks look as they do on the sphere (squares away from the
    poles)."""
    x, F = np.asarray(x, np.float64), np.asarray(F, np.int64)

    def colour(f, p, hit):
        p /= np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-300)
        lat = np.floor(np.arccos(np.clip(p[:, 2], -1.0, 1.0)) / np.pi * checks)
        lon = np.floor((np.arctan2(p[:, 1], p[:, 0]) / np.pi + 1.0) * checks)
        return _checker_rgb(np.mod(lat + lon, 2.0))

    return render_surface(V, F, colour, size, elev, azim, up, light, supersample, attributes=x)


def _filtered_checker(t, foot):
    """(k,) share of the second colour in each pixel: the checkerboard ``t`` (k, 2) (UV in
    checks; squares with an odd sum of floors are the second colour) box-filtered over the
    pixel's footprint ``foot`` (k, 2), how far the UV move to the neighbouring pixels
    (:func:`_footprints`).  Anti-aliased borders without supersampling: a pixel whose centre
    lies on one side of a border is mostly of that side's colour."""
    w = np.minimum(foot, 2.0)  # at two checks per pixel the average is the mean colour

    def ramp(x):  # the integral of the square wave +1 on [0, 1), -1 on [1, 2): 1 - |x mod 2 - 1|, in place
        np.mod(x, 2.0, out=x)
        x -= 1.0
        np.abs(x, out=x)
        return np.subtract(1.0, x, out=x)

    np.maximum(w, 1e-9, out=w)  # no narrower than 1e-9: the sharp wave to 1e-7
    half = w / 2
    wave = ramp(t + half)  # in place: a quarter of the temporaries (first touches of fresh memory)
    wave -= ramp(np.subtract(t, half, out=half))
    wave /= w
    return 0.5 - 0.5 * wave[:, 0] * wave[:, 1]


def vertex_normals(V, F):
    """(n, 3) unit vertex normals: the sums of the area-weighted normals of their faces."""
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.zeros_like(V)
    for k in range(3):
        np.add.at(out, F[:, k], N)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)

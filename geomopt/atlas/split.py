"""Split flattened charts where the atlas packs badly.

One large chart of irregular outline (long arms, deep notches) wastes the square it is packed
into; two halves of it leave less empty space.  :func:`split_flat_chart` cuts a flattened chart
across its longest direction (the principal axis of its triangles' centroids, area-weighted) at
the area median: each side's connected pieces keep their flattened coordinates (a part of a
flip-free, injective map is one), so no chart is solved again.  :func:`split_to_pack` splits the
largest chart not tried yet and repacks, keeping a split only when the packing efficiency grows,
while it is below the goal.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .charts import ChartMesh

__all__ = ["split_flat_chart", "split_to_pack"]


def _face_pairs(F):
    """``(a, b)``: the pairs of faces of ``F`` (m, 3) that share an edge."""
    from ..exact.topology import unique_edges

    _, _, edge_of = unique_edges(F)
    e = edge_of.ravel()
    f = np.repeat(np.arange(len(F)), 3)
    order = np.argsort(e, kind="stable")
    e, f = e[order], f[order]
    pair = np.flatnonzero(e[1:] == e[:-1])
    return f[pair], f[pair + 1]


def _face_components(F, keep):
    """Labels (len(keep),) of the faces ``F[keep]`` joined across shared edges."""
    from scipy.sparse.csgraph import connected_components

    G = F[keep]
    a, b = _face_pairs(G)
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(len(G), len(G)))
    return connected_components(graph.tocsr(), directed=False)[1]


def _smoothed(F, side, rounds=3):
    """``side`` (m,) bool with every face that has at least two edge neighbours on the other
    side moved over, ``rounds`` times: a straighter cut line, without faces that touch the other
    side at a vertex only (which would leave a piece pinched there, not a disk)."""
    a, b = _face_pairs(F)
    side = side.copy()
    for _ in range(rounds):
        other = np.bincount(a, side[b] != side[a], minlength=len(F)) + np.bincount(b, side[a] != side[b],
                                                                                    minlength=len(F))
        flip = other >= 2
        if not flip.any():
            break
        side[flip] = ~side[flip]
    return side


def split_flat_chart(mesh: ChartMesh, x, quantile: float = 0.5, axis: int = -1):
    """Cut a flattened chart in two across its longest direction (module doc).

    Parameters
    ----------
    mesh : the chart's :class:`~geomopt.atlas.charts.ChartMesh`;  x : (nc, 2) its flattening.
    quantile : where along the axis, as a fraction of the chart's area.
    axis : -1 across the longest direction, 0 across the shortest.

    Returns
    -------
    list of ``(ChartMesh, x_piece)``, each piece a disk; None when a piece would not be a disk
    or the chart cannot be split (fewer than 2 faces).
    """
    x = np.asarray(x, dtype=np.float64)
    if len(mesh.F) < 2:
        return None
    P = x[mesh.F]
    c = P.mean(axis=1)
    A = _areas(P)
    mean = np.average(c, axis=0, weights=A)
    cov = ((c - mean) * A[:, None]).T @ (c - mean)
    t = c @ np.linalg.eigh(cov)[1][:, axis]
    order = np.argsort(t)
    cut_at = t[order][np.searchsorted(np.cumsum(A[order]), quantile * A.sum())]
    pieces = []
    low = _smoothed(mesh.F, t <= cut_at)
    for side in (low, ~low):
        if not side.any():
            return None
        faces = np.flatnonzero(side)
        labels = _face_components(mesh.F, side)
        for k in range(labels.max() + 1):
            sel = faces[labels == k]
            rows, local = np.unique(mesh.F[sel], return_inverse=True)
            piece = ChartMesh(mesh.faces[sel], local.reshape(-1, 3), mesh.wedges[rows], mesh.vertices[rows])
            if piece.disk_loop() is None:
                return None
            pieces.append((piece, x[rows]))
    return pieces


def split_to_pack(meshes, maps, pack, goal, max_splits=16, min_gain=0.01):
    """Split the largest chart not tried yet and repack (``pack(maps, faces) -> Packing``),
    keeping the split when it raises the packing efficiency by at least ``min_gain`` (a split
    costs a seam and a chart: one that buys less packing is not worth them), while the
    efficiency is below ``goal`` (at most ``max_splits`` tries).

    Returns
    -------
    ``(meshes, maps, packing, owner)``: the charts, their flattenings, their packing, and for
    each chart the index of the chart of the input it came from.
    """
    owner = list(range(len(meshes)))
    packing = pack(maps, [m.F for m in meshes])
    tried = set()
    for _ in range(max_splits):
        if packing.efficiency >= goal:
            break
        area = [_uv_area(x, m.F) if i not in tried else -1.0 for i, (m, x) in enumerate(zip(meshes, maps))]
        i = int(np.argmax(area))
        if area[i] < 0:
            break
        tried.add(i)
        pieces = next(filter(None, (split_flat_chart(meshes[i], maps[i], q, axis) for axis in (-1, 0)
                                    for q in (0.5, 0.35, 0.65))), None)
        if pieces is None:
            continue
        new_meshes = meshes[:i] + [p[0] for p in pieces] + meshes[i + 1:]
        new_maps = maps[:i] + [p[1] for p in pieces] + maps[i + 1:]
        trial = pack(new_maps, [m.F for m in new_meshes])
        if trial.efficiency < packing.efficiency + min_gain or trial.efficiency <= packing.efficiency:
            continue  # this chart stays whole; try the next largest
        shift = len(pieces) - 1
        tried = {j if j < i else j + shift for j in tried if j != i}
        meshes, maps, packing = new_meshes, new_maps, trial
        owner = owner[:i] + [owner[i]] * len(pieces) + owner[i + 1:]
    return meshes, maps, packing, owner


def _areas(P):
    """(m,) areas of the 2D triangles ``P`` (m, 3, 2)."""
    a, b = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    return 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def _uv_area(x, F):
    return float(_areas(np.asarray(x)[F]).sum())

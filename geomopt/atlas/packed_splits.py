"""Straighten the borders of the packing splits in place, after packing.

A packing split (:func:`~geomopt.atlas.flat_splits.split_to_pack`) cuts a flattened chart into
pieces along a line of the plane, and each piece is packed by a rigid motion of the parent's
flattening (``scale * x @ R.T + offset``, :class:`~geomopt.atlas.Packing`).  Such a border
zigzags along the surface's edges; :func:`~geomopt.atlas.seams.straighten_split` reroutes it by
the surface's seam cost and turning, but repacking the reshaped pieces gives back some of the
luck of the split search.  Here the pieces keep their motions: a face that changes piece takes
its new piece's motion (every piece is a part of the one injective flattening, so each stays
injective).  The border is rerouted only through faces that would land, moved so, inside the
square and clear of the other charts (a cheap screen), and kept only when it is no longer on the
surface, the atlas so made is certified exactly (:func:`~geomopt.atlas.certify_atlas`: no chart
overlaps itself or another, all in the unit square) and every piece stays at least the packing's
margin from every other chart.  The charts' area and bounding square are unchanged, so is the
packing efficiency.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..exact.topology import boundary_half_edges
from ._certify import certify_atlas
from .seams import edge_graph, straighten_split

__all__ = ["straighten_packed", "closer_than"]

_AVOID = 1e6  # how much dearer a border is through faces that would not fit where they go


def _moved(packing, k, x) -> np.ndarray:
    """Piece ``k``'s packing motion applied to flat coordinates ``x`` (n, 2)."""
    a = float(packing.angles[k])
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return packing.scale * (np.asarray(x, dtype=np.float64) @ R.T) + packing.offsets[k]


def _segments(mesh, u) -> np.ndarray:
    """(s, 2, 2) the boundary edges of a piece (``mesh.F`` into ``u``) as point pairs."""
    return np.asarray(u)[boundary_half_edges(mesh.F)]


def _point_segment(p, a, b) -> np.ndarray:
    """Distances of points ``p`` (q, 2) to segments ``a``-``b`` (q, 2) each."""
    d = b - a
    t = np.clip(np.sum((p - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), np.finfo(float).tiny), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def closer_than(S, T, margin: float) -> bool:
    """Whether two sets of segments ``S`` (s, 2, 2) and ``T`` (t, 2, 2) that do not cross
    (certified elsewhere) come closer than ``margin``: two such segments' distance is reached at
    an end of one of them, so it is whether an end of one set lies closer than ``margin`` to a
    segment of the other (candidate pairs: ends within ``margin`` plus the longest half-length
    of the segment's midpoint, by k-d trees)."""
    for A, B in ((S, T), (T, S)):
        if not len(A) or not len(B):
            return False
        mid = B.mean(axis=1)
        reach = margin + 0.5 * float(np.linalg.norm(B[:, 1] - B[:, 0], axis=1).max())
        ends = np.concatenate([A[:, 0], A[:, 1]])
        pairs = cKDTree(ends).sparse_distance_matrix(cKDTree(mid), reach, output_type="ndarray")
        if len(pairs):
            i, j = pairs["i"], pairs["j"]
            if (_point_segment(ends[i], B[j, 0], B[j, 1]) < margin).any():
                return True
    return False


def _matched(new, old):
    """For each new piece (``(ChartMesh, x)``) the old piece (ChartMesh) it shares the most faces
    with, when that is one-to-one, else None."""
    share = np.array([[np.count_nonzero(np.isin(p.faces, o.faces, assume_unique=True)) for o in old]
                      for p, _ in new])
    order = np.argmax(share, axis=1)
    return order if len(new) == len(old) and len(np.unique(order)) == len(old) else None


def _placed(piece, x, old, u_old, packing, k) -> np.ndarray:
    """The new piece ``piece`` (flat coordinates ``x``) by the motion of the old piece ``k``
    (``old``, packed at ``u_old``): the old piece's vertices where they were, exactly, and the
    others moved as the old piece was."""
    u = _moved(packing, k, x)
    order = np.argsort(old.wedges)
    at = np.minimum(np.searchsorted(old.wedges, piece.wedges, sorter=order), len(order) - 1)
    same = old.wedges[order[at]] == piece.wedges
    u[same] = np.asarray(u_old)[order[at[same]]]
    return u


def _fits(meshes, uvs, changed, margin) -> bool:
    """Whether the pieces ``meshes`` packed at ``uvs`` are a certified atlas
    (:func:`~geomopt.atlas.certify_atlas`) whose pieces ``changed`` are at least ``margin`` from
    every other piece."""
    sizes = np.array([len(u) for u in uvs])
    shift = np.cumsum(sizes) - sizes
    F = np.concatenate([m.F + s for m, s in zip(meshes, shift)])
    chart = np.repeat(np.arange(len(meshes)), [len(m.F) for m in meshes])
    if not certify_atlas(np.concatenate(uvs), F, chart).ok:
        return False
    segments = [_segments(m, u) for m, u in zip(meshes, uvs)]
    for k in changed:
        others = np.concatenate([s for i, s in enumerate(segments) if i != k])
        if closer_than(segments[k], others, margin):
            return False
    return True


def _near(P, meshes, uvs, skip, margin) -> np.ndarray:
    """(q,) bool: which triangles ``P`` (q, 3, 2) leave the unit square or have a vertex near a
    piece other than ``skip``: within ``margin`` plus the longest boundary edge of its boundary
    vertices (a cheap screen of where faces may not go; :func:`_fits` decides)."""
    out = ~((P >= 0.0) & (P <= 1.0)).all(axis=(1, 2))
    others = np.concatenate([_segments(m, w) for i, (m, w) in enumerate(zip(meshes, uvs)) if i != skip])
    reach = margin + float(np.linalg.norm(others[:, 1] - others[:, 0], axis=1).max())
    d, _ = cKDTree(others[:, 0]).query(P.reshape(-1, 2), distance_upper_bound=reach)
    return out | (d < np.inf).reshape(-1, 3).any(axis=1)


def _movable(g, chart, x, mine, meshes, uvs, packing, margin) -> np.ndarray:
    """(k,) bool, the edges of ``g`` a border of the pieces ``mine`` of ``chart`` may take: the
    borders as packed, and edges all of whose faces would fit (:func:`_near`) in the nearest
    other piece of the chart (in the flattening ``x``), moved as it is."""
    label = np.full(len(g.F), -1, dtype=np.int64)
    for j, k in enumerate(mine):
        label[meshes[k].faces] = j
    P = np.asarray(x)[chart.F]
    centre, own = P.mean(axis=1), label[chart.faces]
    far = np.stack([cKDTree(centre[own == j]).query(centre)[0] for j in range(len(mine))], axis=1)
    far[np.arange(len(own)), own] = np.inf
    target = np.argmin(far, axis=1)
    fits = np.zeros(len(g.F), dtype=bool)
    for j, k in enumerate(mine):
        to = target == j
        moved = _moved(packing, k, P[to].reshape(-1, 2)).reshape(-1, 3, 2)
        fits[chart.faces[to]] = ~_near(moved, meshes, uvs, k, margin)
    f0, f1 = g.edge_faces[:, 0], g.edge_faces[:, 1]
    inner = f1 >= 0
    f1 = np.where(inner, f1, f0)
    border = inner & (label[f0] >= 0) & (label[f1] >= 0) & (label[f0] != label[f1])
    return border | (fits[f0] & fits[f1])


def straighten_packed(g, cost, charts, flat, owner, meshes, maps, packing, margin: float, turn: float = 1.0):
    """The packed pieces of the packing splits with each chart's borders between its pieces
    straightened in place (module doc), where the atlas stays certified and ``margin`` apart.

    Parameters
    ----------
    g : the surface's :class:`~geomopt.atlas.seams.EdgeGraph`; cost : (k,) its edges' seam costs.
    charts : list of :class:`~geomopt.atlas.charts.ChartMesh`, the charts before the splits;
    flat : their flattenings (nc, 2).
    owner : (p,) int, the chart each piece came from.
    meshes, maps : the p pieces (:class:`~geomopt.atlas.charts.ChartMesh`) and their flat
        coordinates (parts of their chart's flattening).
    packing : their :class:`~geomopt.atlas.Packing` (each piece's rotation and translation).
    margin : the least distance a moved piece keeps from every other (a fraction of the square).
    turn : the price of turning (:func:`~geomopt.atlas.seams.straighten_split`).

    Returns
    -------
    ``(meshes, maps, uvs, moved)``: the pieces, their flat and packed coordinates (lists, in the
    order given, each chart's pieces as given where its border did not move), and how many
    charts' borders moved.
    """
    meshes, maps, uvs = list(meshes), list(maps), [np.asarray(u, dtype=np.float64) for u in packing.uvs]
    owner = np.asarray(owner, dtype=np.int64)
    moved = 0
    for c in np.unique(owner):
        mine = np.flatnonzero(owner == c)
        if len(mine) < 2:
            continue
        trial = _straightened(g, cost, charts[c], flat[c], mine, meshes, maps, uvs, packing, margin, turn)
        if trial is not None:
            (meshes, maps, uvs), moved = trial, moved + 1
    return meshes, maps, uvs, moved


def _straightened(g, cost, chart, x, mine, meshes, maps, uvs, packing, margin, turn):
    """``(meshes, maps, uvs)`` with the pieces ``mine`` of ``chart`` (flattening ``x``)
    straightened in place (:func:`straighten_packed`), or None.  The border is rerouted only
    through edges whose faces would fit where they go (:func:`_movable`; the others priced
    ``_AVOID`` times higher), kept when it is no longer on the surface and checked exactly
    (:func:`_fits`)."""
    given = [(meshes[k], maps[k]) for k in mine]
    cost = np.array(cost, dtype=np.float64)
    cost[~_movable(g, chart, x, mine, meshes, uvs, packing, margin)] *= _AVOID
    new = straighten_split(g, cost, chart, x, given, turn)
    order = None if new is given else _matched(new, [m for m, _ in given])
    if order is None or _border_length(g, chart, [m for m, _ in new]) > _border_length(g, chart, [m for m, _ in given]):
        return None
    trial_m, trial_x, trial_u = list(meshes), list(maps), list(uvs)
    for (piece, xp), j in zip(new, order):
        k = int(mine[j])
        trial_m[k], trial_x[k] = piece, np.asarray(xp)
        trial_u[k] = _placed(piece, xp, meshes[k], uvs[k], packing, k)
    return (trial_m, trial_x, trial_u) if _fits(trial_m, trial_u, mine, margin) else None


def _border_length(g, chart, pieces) -> float:
    """The surface length of the edges between two of the ``pieces`` (ChartMesh) of ``chart``
    that the chart itself glues (not its own slits, seams already)."""
    label = np.empty(len(chart.F), dtype=np.int64)
    for j, m in enumerate(pieces):
        label[np.searchsorted(chart.faces, m.faces)] = j
    own = edge_graph(g.V[chart.vertices], chart.F)
    a, b = label[own.edge_faces[:, 0]], label[np.maximum(own.edge_faces[:, 1], 0)]
    return float(own.length[~own.boundary & (a != b)].sum())

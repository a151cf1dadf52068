"""Split flattened charts where the atlas packs badly.

One large chart of irregular outline (long arms, deep notches) wastes the square it is packed
into; pieces of it leave less empty space.  A split is a straight cut across the flattened chart
(:func:`split_flat_chart`): the faces whose centroids lie on one side of a line, the line placed
at a quantile of the chart's area along a direction, the sides smoothed; each side's connected
pieces keep their flattened coordinates (a part of a flip-free, injective map is one), so no
chart is solved again.  :func:`split_to_pack` tries the largest chart not tried yet: every
distinct cut of :func:`candidate_splits` (``_DIRECTIONS`` directions from the principal axis,
``_QUANTILES`` positions) is screened by a cheap packing of its pieces (with a ``prescreen``,
a cheaper packing of all of them ranks them first and only the ``_SHORTLIST`` best are screened:
a guided rather than exhaustive search), the ``_FINALISTS`` best
are packed with all the charts, and the best is kept when it pays, while the efficiency is below
the goal.  A split is charged, in efficiency, ``min_gain`` per chart it adds and ``seam_cost``
per square root of the surface's area of seam it adds (3D length of the cut edges), both when
ranking the candidates and when deciding whether the best pays: among cuts that pack about alike
the shortest wins (across a neck rather than along an arm), and a long cut must buy more packing.
The cut that packs best is seldom the one across the principal axis at the median: it is where
the outline has a notch or an arm.  A long chart (a needle: the flattened tube of a thin cylinder
or torus, straight or curled) is also cut across into ``m`` bands of equal area at once, by the
distance along it (shortest paths between faces), up to about the square root of its aspect
ratio (pieces about square): halving a needle leaves each half a
needle that decides the square alone, so no single cut after the first gains anything.  And a
split that multiplies the efficiency (``_MULTIPLY``) pays, however small the first gain: a needle
packs at a few thousandths, below any charge per chart.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._runtime.errors import ParameterError
from ..mesh.quality import triangle_areas
from .charts import ChartMesh, face_pairs, patch_is_disk

__all__ = ["candidate_splits", "piece_boundaries", "split_flat_chart", "split_to_pack", "separate_overlaps"]

_DIRECTIONS = 8  # straight cuts tried across this many directions over half a turn
_QUANTILES = (0.1, 0.25, 0.4, 0.5, 0.6, 0.75, 0.9)  # at these fractions of the chart's area
_FINALISTS = 3  # the best screened splits packed with all the charts
_SHORTLIST = 16  # more candidates are screened coarsely first, and this many best again
_SLIVER = 0.01  # a piece of a split under this fraction of the chart's area joins the other side
_PATIENCE = 3  # split_to_pack stops after this many charts in a row that no split improved
_SEAM_COST = 0.05  # efficiency a split must buy per sqrt(surface area) of seam it adds
_MULTIPLY = 2.0  # a split that multiplies the efficiency by this pays, whatever its charge
_BANDS = (3, 4, 6, 8, 12, 16, 24, 32, 48, 64)  # a long chart is also cut across into this many bands
_BAND_REACH = 1.5  # ... up to this times the square root of its aspect ratio (pieces about square)


def _compact(F, size):
    """``(rows, local)``: the sorted distinct vertex ids of the faces ``F`` and ``F`` renumbered
    into them (``np.unique(F, return_inverse=True)``, linear)."""
    seen = np.zeros(size, dtype=bool)
    seen[F.ravel()] = True
    return np.flatnonzero(seen), (np.cumsum(seen) - 1)[F]


def _face_components(F, keep, pairs=None):
    """Labels (len(keep),) of the faces ``F[keep]`` joined across shared edges (``pairs``: the
    face pairs of ``F`` sharing an edge, :func:`~geomopt.atlas.charts.face_pairs`, when known)."""
    a, b = face_pairs(F)[:2] if pairs is None else pairs
    return _restrict(_Dual(a, b, len(F)).sides(keep), keep)


def _restrict(labels, side):
    """The labels of the faces ``side`` (m,) bool among ``labels`` (m,) (components that never
    leave ``side``), renumbered 0, 1, ... by their first face, as ``connected_components``
    numbers the faces of ``side`` alone."""
    return np.unique(labels[side], return_inverse=True)[1].reshape(-1)


class _Dual:
    """The dual graph of a chart, faces ``a[k]``--``b[k]`` joined across the edge they share,
    its adjacency sorted once: the pieces of both sides of any cut then cost one masked copy and
    one :func:`scipy.sparse.csgraph.connected_components` (no sparse matrix assembled and sorted
    per query)."""

    def __init__(self, a, b, m: int):
        order = np.argsort(a, kind="stable")
        self.a, self.b, self.m = a[order], b[order], m

    def sides(self, low):
        """(m,) labels of the connected pieces of both sides of ``low`` (m,) bool: faces joined
        across the pairs whose faces are on the same side; numbered by their first face."""
        from scipy.sparse.csgraph import connected_components

        use = low[self.a] == low[self.b]
        indptr = np.zeros(self.m + 1, dtype=np.int64)
        np.cumsum(np.bincount(self.a[use], minlength=self.m), out=indptr[1:])
        graph = sp.csr_matrix((np.ones(int(indptr[-1]), np.int8), self.b[use], indptr), shape=(self.m, self.m))
        return connected_components(graph, directed=False)[1]


def _smoothed(F, side, rounds=3, pairs=None):
    """``side`` (m,) bool with every face that has at least two edge neighbours on the other
    side moved over, ``rounds`` times: a straighter cut line, without faces that touch the other
    side at a vertex only (which would leave a piece pinched there, not a disk)."""
    a, b = face_pairs(F)[:2] if pairs is None else pairs
    side = side.copy()
    for _ in range(rounds):
        other = np.bincount(a, side[b] != side[a], minlength=len(F)) + np.bincount(b, side[a] != side[b],
                                                                                    minlength=len(F))
        flip = other >= 2
        if not flip.any():
            break
        side[flip] = ~side[flip]
    return side


class _Cutter:
    """One flattened chart, ready to be cut by straight lines many times: its faces' edge ids,
    face adjacency, centroids and areas are computed once."""

    def __init__(self, mesh: ChartMesh, x, V=None):
        self.mesh, self.x = mesh, np.asarray(x, dtype=np.float64)
        P = self.x[mesh.F]
        self.c, self.A = P.mean(axis=1), triangle_areas(P)
        self.a, self.b, edge, E, self.edge_of = face_pairs(mesh.F)
        self.E, self.dual = E, _Dual(self.a, self.b, len(mesh.F))
        self.nv, self.ne = len(self.x), len(E)
        # the length of the edge between each face pair: 3D when the surface is known, else in UV
        X = self.X = self.x if V is None else np.asarray(V)[mesh.vertices]
        self.length = np.linalg.norm(X[E[edge, 1]] - X[E[edge, 0]], axis=1)
        mean = np.average(self.c, axis=0, weights=self.A)
        cov = ((self.c - mean) * self.A[:, None]).T @ (self.c - mean)
        self.axes = np.linalg.eigh(cov)[1]  # columns: shortest, longest direction

    def sides(self, direction, quantiles):
        """Per quantile, (m,) bool: the faces on the low side of the line across ``direction``
        that leaves that fraction of the area there, smoothed (:func:`_smoothed`)."""
        t = self.c @ direction
        order = np.argsort(t)
        at = np.minimum(np.searchsorted(np.cumsum(self.A[order]), np.asarray(quantiles) * self.A.sum()), len(t) - 1)
        return [self._without_slivers(_smoothed(self.mesh.F, t <= t[order][k], pairs=(self.a, self.b)))
                for k in at]

    def along(self):
        """(m,) each face's distance along the chart from one end of it: the least over its
        corners of their shortest-path distance along the chart's edges (3D with the surface's
        vertices, else in UV: a flattening may curl a needle) from the vertex
        farthest from vertex 0 (a double sweep: on a strip, straight or curled, one of its ends).
        Faces are banded by their lowest corner, so a band's border runs along edges: across a
        strip of quads, its rings, not a staircase of the quads' diagonals.  Also the chart's
        length (the largest vertex distance) as ``self.length_along``."""
        from scipy.sparse.csgraph import dijkstra

        if not hasattr(self, "_along"):
            E = self.E
            w = np.linalg.norm(self.X[E[:, 1]] - self.X[E[:, 0]], axis=1) + 1e-300
            graph = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(self.nv, self.nv)).tocsr()
            d = dijkstra(graph, directed=False, indices=int(self.mesh.F[0, 0]))
            d = dijkstra(graph, directed=False, indices=int(np.argmax(np.where(np.isfinite(d), d, -1))))
            d = np.where(np.isfinite(d), d, 0.0)
            self._along, self.length_along = d[self.mesh.F].min(axis=1), float(d.max())
        return self._along

    def bands(self, m: int):
        """(m,) bool: the faces of the even ones of ``m`` bands of about equal area along the chart
        (:meth:`along`: across a needle, straight or curled; each cut at the widest gap between
        the faces' distances within a quarter band of its place, so that a ring of faces at
        about one distance is not split), smoothed and without slivers as
        :meth:`sides` makes them (each band a connected piece of its side)."""
        t = self.along()
        order = np.argsort(t, kind="stable")
        ts, below = t[order], np.cumsum(self.A[order]) / self.A.sum()  # area up to each face, in order
        gap = np.diff(ts)
        cuts = []
        for k in range(1, m):  # each cut at the widest gap between the distances within a quarter band
            near = np.flatnonzero(np.abs(below[:-1] - k / m) <= 0.25 / m)
            if len(near):
                i = near[np.argmax(gap[near])]
                cuts.append(0.5 * (ts[i] + ts[i + 1]))
        band = np.searchsorted(np.array(cuts), t)
        return self._without_slivers(_smoothed(self.mesh.F, band % 2 == 0, pairs=(self.a, self.b)))

    def band_counts(self):
        """The band counts of :data:`_BANDS` up to ``_BAND_REACH`` times the square root of the
        chart's aspect ratio, its length (:meth:`along`) squared over its area (about 1 for a
        disk or a square, the length over the width for a strip)."""
        self.along()
        aspect = self.length_along ** 2 / max(float(self.A.sum()), 1e-300)
        return [m for m in _BANDS if m <= _BAND_REACH * np.sqrt(aspect)]

    def seam(self, low) -> float:
        """The length of the seam that cutting the chart between ``low`` and the rest adds."""
        return float(self.length[low[self.a] != low[self.b]].sum())

    def _without_slivers(self, low, rounds=3):
        """``low`` with every connected piece of either side under ``_SLIVER`` of the chart's
        area moved to the other side (which surrounds it), again until none is left (at most
        ``rounds`` times): a line across a ragged outline or a diagonal of the grid leaves such
        crumbs, each of which would be a chart of its own."""
        low = low.copy()
        for _ in range(rounds):
            labels = self.dual.sides(low)  # the pieces of both sides
            flip = (np.bincount(labels, self.A) < _SLIVER * self.A.sum())[labels]
            if not flip.any():
                break
            low ^= flip
        return low

    def _is_disk(self, sel) -> bool:
        """Whether the edge-connected faces ``sel`` of the chart (a disk) form a disk: exactly
        when their Euler characteristic is 1.  They lie in a disk, so (Alexander duality) the
        characteristic is 1 minus the number of bounded regions of the disk they leave out:
        holes, and at a vertex where the faces meet in two fans, the region between the fans
        that a path of faces from one fan to the other encloses."""
        return patch_is_disk(self.mesh.F, self.edge_of, sel, self.nv, self.ne)

    def pieces(self, low):
        """``[(ChartMesh, x_piece), ...]``: the connected pieces of both sides of ``low`` (m,)
        bool, or None when a side is empty or a piece is not a disk or is under ``_SLIVER`` of
        the chart's area."""
        mesh, pieces = self.mesh, []
        both = self.dual.sides(low)
        for side in (low, ~low):
            if not side.any():
                return None
            faces = np.flatnonzero(side)
            labels = _restrict(both, side)
            for k in range(labels.max() + 1):
                sel = faces[labels == k]
                if not self._is_disk(sel) or self.A[sel].sum() < _SLIVER * self.A.sum():
                    return None  # not a disk, or a crumb that absorbing did not remove
                rows, local = _compact(mesh.F[sel], self.nv)
                pieces.append((ChartMesh(mesh.faces[sel], local, mesh.wedges[rows],
                                         mesh.vertices[rows]), self.x[rows]))
        return pieces


def split_flat_chart(mesh: ChartMesh, x, quantile: float = 0.5, axis: int = -1, direction=None):
    """Cut a flattened chart in two across a direction (module doc).

    Parameters
    ----------
    mesh : the chart's :class:`~geomopt.atlas.charts.ChartMesh`;  x : (nc, 2) its flattening.
    quantile : where along the direction, as a fraction of the chart's area.
    axis : -1 across the longest direction, 0 across the shortest (principal axes of the faces'
        centroids, area-weighted).
    direction : (2,) unit vector, the direction to cut across instead of ``axis``.

    Returns
    -------
    list of ``(ChartMesh, x_piece)``, each piece a disk; None when a piece would not be a disk
    or the chart cannot be split (fewer than 2 faces).
    """
    if len(mesh.F) < 2:
        return None
    cutter = _Cutter(mesh, x)
    d = cutter.axes[:, axis] if direction is None else np.asarray(direction, dtype=np.float64)
    return cutter.pieces(cutter.sides(d, [quantile])[0])


def candidate_splits(mesh: ChartMesh, x, directions: int = _DIRECTIONS, quantiles=_QUANTILES, V=None,
                     seams: bool = False):
    """Every distinct straight split of a flattened chart that leaves disks: across
    ``directions`` directions evenly spaced over half a turn from the longest principal axis,
    at each of ``quantiles`` of the area (:func:`split_flat_chart`'s cuts); and for a long chart
    the cuts across it into bands of equal area by the distance along it (:meth:`_Cutter.bands`,
    :meth:`_Cutter.band_counts` of them, each a piece).  Returns a list of
    piece lists (each as :func:`split_flat_chart` returns it); with ``seams``, a list of
    ``(pieces, seam)``, ``seam`` the length of the cut (3D with the surface's vertices ``V``,
    which ``mesh.vertices`` index; else in UV)."""
    if len(mesh.F) < 2:
        return []
    cutter = _Cutter(mesh, x, V)
    a0 = np.arctan2(cutter.axes[1, -1], cutter.axes[0, -1])
    seen, out = set(), []
    cuts = [low for a in a0 + np.pi * np.arange(directions) / directions
            for low in cutter.sides(np.array([np.cos(a), np.sin(a)]), quantiles)]
    for low in cuts + [cutter.bands(m) for m in cutter.band_counts()]:
        key = np.packbits(low ^ low[0]).tobytes()  # a partition, whichever side is low
        if key in seen:
            continue
        seen.add(key)
        pieces = cutter.pieces(low)
        if pieces is not None:
            out.append((pieces, cutter.seam(low)) if seams else pieces)
    return out


def piece_boundaries(mesh: ChartMesh, splits):
    """Per split (a list of pieces ``(ChartMesh, x)`` of the chart ``mesh``), each piece's
    boundary half-edges in its vertex ids, as :func:`~geomopt.exact.topology.boundary_half_edges`
    gives them, from the chart's edges found once: a piece's half-edge is on its boundary when its
    edge has one face in the piece (the chart is a disk: an edge's second face runs it the other way)."""
    from ..exact.topology import half_edges, unique_edges

    E, _, edge_of = unique_edges(mesh.F)
    row = np.full(int(mesh.faces.max()) + 1, -1, dtype=np.int64)
    row[mesh.faces] = np.arange(len(mesh.faces))
    out = []
    for pieces in splits:
        bounds = []
        for piece, _ in pieces:
            e = edge_of[row[piece.faces]]
            once = np.bincount(e.ravel(), minlength=len(E))[e] == 1
            bounds.append(half_edges(piece.F)[once.ravel()])
        out.append(bounds)
    return out


def _best_split(meshes, maps, i, pack, screen, charge, current, prescreen=None):
    """The split of chart ``i`` (:func:`candidate_splits`) that packs best less its cost
    ``charge(pieces, seam)`` (in efficiency: its extra charts and its seam), among those that pay
    (the packing's efficiency rises above ``current`` by at least the charge, or to ``_MULTIPLY``
    times ``current`` or more; a split that cannot be packed at the margin, ParameterError, pays
    nothing): every candidate's
    pieces are packed alone by ``screen`` (a cheap estimate; with ``prescreen``, a cheaper one,
    and more than ``_SHORTLIST`` candidates, only the ``_SHORTLIST`` that ``prescreen`` ranks
    best), the ``_FINALISTS`` best are packed with all the other charts by ``pack``.  Returns ``(pieces, packing)`` or None when no split
    pays."""
    cands = candidate_splits(meshes[i], maps[i], V=charge.V, seams=True)
    can_pay = _PayBound(meshes, maps, i, charge, current)
    cands = [(pieces, seam) for pieces, seam in cands if can_pay(pieces, seam)]
    bounds = piece_boundaries(meshes[i], [c for c, _ in cands])

    def estimate(k, screen):
        (pieces, seam), B = cands[k], bounds[k]
        try:
            return screen([p[1] for p in pieces], [p[0].F for p in pieces], B) - charge(pieces, seam)
        except ParameterError:  # more pieces than the margin can keep apart
            return -np.inf

    short = range(len(cands))
    if prescreen is not None and len(cands) > _SHORTLIST:  # the prescreen's shortlist; the others out
        coarse = np.array([estimate(k, prescreen) for k in short])
        short = [k for k in np.argsort(coarse, kind="stable")[::-1][:_SHORTLIST] if coarse[k] > -np.inf]
    est = np.full(len(cands), -np.inf)
    for k in short:
        est[k] = estimate(k, screen)
    best = None
    for j in np.argsort(est)[::-1][:_FINALISTS]:
        if est[j] == -np.inf:
            break
        pieces, seam = cands[j]
        try:
            trial = pack(maps[:i] + [p[1] for p in pieces] + maps[i + 1:],
                         [m.F for m in meshes[:i]] + [p[0].F for p in pieces] + [m.F for m in meshes[i + 1:]])
        except ParameterError:  # more charts than the margin can keep apart (pack_charts' widest_margin)
            continue
        score = trial.efficiency - charge(pieces, seam)
        if trial.efficiency <= current or (score < current and trial.efficiency < _MULTIPLY * current):
            continue
        if best is None or score > best[0]:
            best = (score, pieces, trial)
    return None if best is None else best[1:]


class _PayBound:
    """Whether a split of chart ``i`` can pay at all: its packing's efficiency is at most the
    charts' area over the square of the largest least side of a square (any rotation) that
    holds one of them (:func:`~geomopt.atlas._pack.smallest_square_angle` of its hull), and a
    split whose bound does not pay (:func:`_best_split`'s rule) is neither screened nor packed.
    A chart whose every cut runs along it (the sides of a thin cylinder or capsule are single
    triangles as long as the part: no cut crosses them) has only such splits, each of whose
    packings, of pieces hundreds of pixels long, cost seconds."""

    def __init__(self, meshes, maps, i, charge, current):
        self.charge, self.current = charge, current
        self.area = sum(float(triangle_areas(np.asarray(x)[m.F]).sum()) for m, x in zip(meshes, maps))
        self.others = max([_least_square(x) for j, x in enumerate(maps) if j != i], default=0.0)

    def __call__(self, pieces, seam) -> bool:
        side = max(self.others, max(_least_square(x) for _, x in pieces))
        bound = self.area / side**2 * (1 + 1e-9) if side > 0 else np.inf
        charge = self.charge(pieces, seam)
        return bound > self.current and (bound - charge >= self.current or bound >= _MULTIPLY * self.current)


def _least_square(x) -> float:
    """The side of the smallest square, at any rotation, holding the points ``x`` (n, 2); 0 (no
    bound) where they have no hull (collinear)."""
    from scipy.spatial import ConvexHull

    from ._pack import smallest_square_angle

    x = np.asarray(x, dtype=np.float64)
    try:
        hull = x[ConvexHull(x).vertices]
    except Exception:  # noqa: BLE001 -- qhull refuses flat or tiny point sets
        return 0.0
    return smallest_square_angle(hull)[1]


class _Charge:
    """The cost of a split in packing efficiency: ``min_gain`` per chart it adds, and
    ``seam_cost`` per ``unit`` of seam length it adds (``unit``: the square root of the charts'
    total area, 3D with the surface's vertices ``V``, else in UV), so that among splits that pack
    about as well the one with the shorter cut wins, and a long cut must buy more packing.  The
    unit is the whole surface's, not the chart's: the seam and the efficiency are the atlas's."""

    def __init__(self, meshes, maps, V, min_gain, seam_cost):
        self.V, self.min_gain, self.seam_cost = V, min_gain, seam_cost
        if V is None:
            area = sum(float(triangle_areas(np.asarray(x)[m.F]).sum()) for m, x in zip(meshes, maps))
        else:
            V = np.asarray(V, dtype=np.float64)
            area = sum(float(triangle_areas(V[m.vertices][m.F]).sum()) for m in meshes)
        self.unit = max(np.sqrt(area), 1e-300)

    def __call__(self, pieces, seam) -> float:
        return self.min_gain * (len(pieces) - 1) + self.seam_cost * seam / self.unit


def _boundary_face(F, a, b):
    """The face of ``F`` (m, 3) holding the boundary edge ``(a, b)``."""
    return int(np.argmax((F == a).any(axis=1) & (F == b).any(axis=1)))


def _min_cut_side(n, a, b, capacity, sources, sinks):
    """(n,) bool, the nodes on the source side of a minimum cut of the undirected graph with
    edges ``(a, b)`` and integer ``capacity`` between the node sets ``sources`` and ``sinks``."""
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    s, t = n, n + 1
    big = int(capacity.sum()) + 1
    i = np.r_[a, b, np.full(len(sources), s), sinks]
    j = np.r_[b, a, sources, np.full(len(sinks), t)]
    cap = np.r_[capacity, capacity, np.full(len(sources) + len(sinks), big)].astype(np.int64)
    C = sp.csr_matrix((cap, (i, j)), shape=(n + 2, n + 2))
    flow = maximum_flow(C, s, t).flow
    residual = (C - flow).tocsr()
    residual.data = np.where(residual.data > 0, 1, 0)
    residual.eliminate_zeros()
    side = np.zeros(n + 2, dtype=bool)
    side[breadth_first_order(residual, s, directed=True, return_predecessors=False)] = True
    return side[:n]


def _overlap_halves(mesh: ChartMesh, x, V, crossing):
    """The pieces of a chart cut between the two faces ``fa``, ``fb`` of a boundary crossing,
    along the shortest cut (3D length) between the faces nearer than a quarter of their distance
    to ``fa`` and those as near to ``fb`` (a minimum cut of the faces' dual graph, distances
    between centroids across shared edges): the narrowest neck of the chart between the two
    sheets.  Smoothed and without slivers as :class:`_Cutter` makes its sides; returns
    :meth:`_Cutter.pieces`'s list, or None."""
    from scipy.sparse.csgraph import dijkstra

    from ..exact.topology import check_disk

    loop = check_disk(mesh.F, len(mesh.wedges))
    i, j = (int(k) for k in crossing)
    seeds = [_boundary_face(mesh.F, loop[k], loop[(k + 1) % len(loop)]) for k in (i, j)]
    if seeds[0] == seeds[1]:
        return None
    cutter = _Cutter(mesh, x, V)  # its lengths in 3D
    Vc = V[mesh.vertices]
    c = Vc[mesh.F].mean(axis=1)
    w = np.linalg.norm(c[cutter.a] - c[cutter.b], axis=1) + 1e-300
    m = len(mesh.F)
    graph = sp.coo_matrix((w, (cutter.a, cutter.b)), shape=(m, m)).tocsr()
    d = dijkstra(graph, directed=False, indices=seeds)
    reach = d[0, seeds[1]] / 4
    length = cutter.length
    capacity = np.maximum(1, np.round(length / length.max() * 2 ** 20)).astype(np.int64)
    low = _min_cut_side(m, cutter.a, cutter.b, capacity, np.flatnonzero(d[0] < reach), np.flatnonzero(d[1] < reach))
    return cutter.pieces(cutter._without_slivers(_smoothed(mesh.F, low, pairs=(cutter.a, cutter.b))))


def separate_overlaps(mesh: ChartMesh, x, V, max_pieces: int = 16):
    """A flip-free flattening whose boundary overlaps itself, cut into pieces that each map
    injectively, keeping their coordinates (no chart solved again).

    While a piece's exact certificate (:func:`~geomopt.exact.certify.certify_bijective`) finds
    two boundary edges crossing, the piece is cut between their two faces
    (:func:`_overlap_halves`): the overlap is two sheets of the map that meet only far apart on
    the surface, and a cut half-way between them puts them in different pieces.

    Parameters
    ----------
    mesh : the chart's :class:`~geomopt.atlas.charts.ChartMesh`;  x : (nc, 2) its locally
        injective flattening;  V : (n, 3) the surface's vertices (``mesh.vertices`` index them).
    max_pieces : give up (None) when more pieces would be needed.

    Returns
    -------
    list of ``(ChartMesh, x_piece, certificate)``, every piece certified globally injective, or
    None (a piece not locally injective, a cut that leaves no disks, too many pieces).
    """
    from ..exact.certify import certify_bijective

    todo, done = [(mesh, np.asarray(x, dtype=np.float64))], []
    while todo:
        piece, xp = todo.pop()
        cert = certify_bijective(xp, piece.F)
        if cert.globally_injective:
            done.append((piece, xp, cert))
            continue
        if not cert.locally_injective or not len(cert.crossings) or len(done) + len(todo) + 2 > max_pieces:
            return None
        halves = _overlap_halves(piece, xp, V, cert.crossings[0])
        if halves is None:
            return None
        todo.extend(halves)
    return done


def split_to_pack(meshes, maps, pack, goal, max_splits=16, min_gain=0.01, screen=None, V=None,
                  seam_cost=_SEAM_COST, prescreen=None):
    """Split the largest chart not tried yet and repack (``pack(maps, faces) -> Packing``),
    keeping the best split (:func:`_best_split`) when it raises the packing efficiency by at
    least its charge: ``min_gain`` per extra chart and ``seam_cost`` per unit of seam (a split
    costs a seam and charts: one that buys less packing is not worth them), while the efficiency
    is below ``goal`` (at most ``max_splits`` charts tried; none more after ``_PATIENCE`` in a row
    that stay whole: charts are tried by decreasing area, and a smaller chart's split moves the
    packing less).
    ``screen(maps, faces, boundaries) -> float`` estimates a packing's efficiency cheaply
    (``boundaries``: each chart's boundary half-edges, :func:`piece_boundaries`; default:
    ``pack``'s efficiency); ``prescreen``, the same call, cheaper still: when given, it ranks
    the candidates of a chart with more than ``_SHORTLIST`` and ``screen`` only the best
    ``_SHORTLIST`` (a guided search: most candidates pack far worse than the best).  The seam's unit is the square root of the charts' total area
    (:class:`_Charge`), seams and areas measured on the surface ``V`` (the vertices that the
    charts' ``vertices`` index) when given, else in UV.

    Returns
    -------
    ``(meshes, maps, packing, owner)``: the charts, their flattenings, their packing, and for
    each chart the index of the chart of the input it came from.
    """
    screen = screen or (lambda m, f, b: pack(m, f).efficiency)
    charge = _Charge(meshes, maps, V, min_gain, seam_cost)
    owner = list(range(len(meshes)))
    packing = pack(maps, [m.F for m in meshes])
    tried, failed = set(), 0
    for _ in range(max_splits):
        if packing.efficiency >= goal or failed >= _PATIENCE:
            break
        area = [float(triangle_areas(np.asarray(x)[m.F]).sum()) if i not in tried else -1.0
                for i, (m, x) in enumerate(zip(meshes, maps))]
        i = int(np.argmax(area))
        if area[i] < 0:
            break
        tried.add(i)
        best = _best_split(meshes, maps, i, pack, screen, charge, packing.efficiency, prescreen)
        if best is None:
            failed += 1
            continue  # this chart stays whole; try the next largest
        pieces, trial = best
        failed = 0
        shift = len(pieces) - 1
        tried = {j if j < i else j + shift for j in tried if j != i}
        meshes = meshes[:i] + [p[0] for p in pieces] + meshes[i + 1:]
        maps = maps[:i] + [p[1] for p in pieces] + maps[i + 1:]
        packing = trial
        owner = owner[:i] + [owner[i]] * len(pieces) + owner[i + 1:]
    return meshes, maps, packing, owner



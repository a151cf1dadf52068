"""The seam graph of an atlas: which edges to cut so that every chart is a disk that flattens with
low distortion.

Three steps (in the spirit of Sheffer & Hart's Seamster and of Gu, Gortler & Hoppe's geometry
images): (a) topology, :func:`~geomopt.atlas.seams.shortest_topological_cut` opens every
component with handles or several boundary loops into a disk along cheap edges (from the best of
several roots); (a') on CAD-like parts, whose curvature sits in strong cones (corners of angle
defect at least 45 degrees), the strong cones are first joined by a cheap tree
(:func:`~geomopt.atlas.seams.steiner_tree`) on which the loops of (a) are rooted: a disk whose
curvature is all on its boundary flattens isometrically; the tree's dangling paths that the
estimate of (c) can do without are then uncut (:func:`trim`); (b) a closed genus-0 component is
opened by one cheap path between its two points of most concentrated curvature, far apart; (c)
distortion, greedy cone cuts: while the estimated mean symmetric Dirichlet
(:func:`~geomopt.atlas.cones.scale_estimate`) is above the target, the chart with the most
excess gets a cheapest cut to its boundary from its most shrunk vertex (or, with ``_CONE_SLACK``
above 0, from whichever vertex about as shrunk the seam cost reaches most cheaply).  A cut from an interior
vertex to the boundary keeps a disk a disk, so every chart stays one.  When the cuts stall short
of the target, the later ones that did not pay for their seam are taken back (:func:`relieve`);
the charts are then split into nearly developable pieces instead, by measurement
(:func:`~geomopt.atlas.flatten.split_to_goal`).  :func:`cut_surface` makes the seam graph with
and without (a') and keeps the shorter that reaches the target, then (d) straightens its paths
(:func:`~geomopt.atlas.seams.straighten`): the same nodes joined by paths that turn less.
"""

from __future__ import annotations

import numpy as np

from ..mesh.quality import triangle_areas
from .charts import charts_of_cut
from .cones import ChartScale, angle_defects, log_scale, scale_estimate
from .seams import (EdgeGraph, cut_path_to_seams, dangling_paths, saddle_factor, shortest_topological_cut, slits,
                    steiner_tree, straighten)

__all__ = ["cut_surface", "chart_estimate", "relieve", "strong_cones", "trim"]

# a cone cut that the target was not reached with must lower the area-weighted estimate by this
# much per unit of seam length (in units of the square root of the surface's area)
_SEAM_WORTH = 0.5
# a cone cut may end at any interior vertex whose log area scale is within this of the chart's least
# (0: the most shrunk only; 0.25 hid bunny's seams but moved the later splits of cheburashka and
# 3holes to longer seams: benchmarks/README.md)
_CONE_SLACK = 0.0


def _component_roots(g: EdgeGraph):
    """``(labels, closed_roots)``: the component of each vertex and one vertex of every
    component without boundary."""
    from ..exact.topology import connected_components

    _, labels = connected_components(g.F, len(g.V))
    open_ = np.zeros(labels.max() + 1, dtype=bool)
    open_[labels[g.E[g.boundary].ravel()]] = True
    _, first = np.unique(labels, return_index=True)
    return labels, first[~open_]


def _open_spheres(g: EdgeGraph, cost, cut, labels, roots):
    """Cut every closed component that the topological cut left whole (genus 0) along the
    cheapest path between its most shrunk vertex ``a`` (most concentrated curvature, by
    :func:`~geomopt.atlas.cones.log_scale` on the closed surface) and the most shrunk vertex
    among those at least half its largest distance from ``a``."""
    from scipy.sparse.csgraph import dijkstra

    touched = np.zeros(labels.max() + 1, dtype=bool)
    touched[labels[g.E[cut].ravel()]] = True
    adjacency = g.adjacency(g.length)
    for r in roots:
        comp = labels[r]
        if touched[comp]:
            continue
        verts = np.flatnonzero(labels == comp)
        faces = np.flatnonzero(labels[g.F[:, 0]] == comp)
        local = np.searchsorted(verts, g.F[faces])
        u = log_scale(g.V[verts], local, [])
        a = verts[int(np.argmin(u))]
        d = dijkstra(adjacency, indices=a)[verts]
        far = np.flatnonzero(d >= 0.5 * d.max())
        b = verts[far[int(np.argmin(u[far]))]]
        cut[cut_path_to_seams(g, cost, a, np.array([b]))] = True
    return _without_slits(g, cost, cut)


def _without_slits(g: EdgeGraph, cost, cut):
    """``cut`` with each of its :func:`~geomopt.atlas.seams.slits` (a lone interior edge: its two
    sides on the same two vertices, which no chart mesh can hold) extended by the cheapest other
    edge at its second end, into a path of two edges: a disk's boundary of four half-edges."""
    cut = cut.copy()
    for e in np.flatnonzero(slits(g, cut)):
        v = g.E[e, 1]
        at = np.flatnonzero((g.E == v).any(axis=1))
        at = at[at != e]
        cut[at[np.argmin(cost[at])]] = True
    return cut


def chart_estimate(g: EdgeGraph, chart, seams, scale=None):
    """``(mean, area, vertex, near)``: the estimated mean symmetric Dirichlet of a disk chart
    (:class:`~geomopt.atlas.charts.ChartMesh` of a cut of ``g``), its 3D area, its most shrunk
    interior vertex (an input vertex id of ``g.V``, or -1 when it has none), and the interior
    vertices about as shrunk (log area scale within ``_CONE_SLACK`` of the least; input ids), among
    which a cone cut starts where the seam cost reaches most cheaply.  ``seams`` (k,) bool:
    the cut and boundary edges of ``g``; the chart's boundary is where its faces meet them (no
    topology check: a connected, oriented manifold chart is a disk exactly when its Euler
    characteristic is 1, counted here).  ``scale``: a :class:`~geomopt.atlas.cones.ChartScale`
    kept for this chart's faces across its cone cuts (its analysis reused), else None."""
    Vc = g.V[chart.vertices]
    rows, corner = np.nonzero(seams[g.edge_of[chart.faces]])  # the chart's boundary half-edges
    if not len(rows) or 2 * len(Vc) - len(chart.F) - len(rows) != 2:  # 2 (V - E + F) with 2 E = 3 F + b
        raise RuntimeError("a chart of the seam graph is not a disk")  # never: see module doc
    loop = np.unique(np.r_[chart.F[rows, corner], chart.F[rows, (corner + 1) % 3]])
    if scale is None:
        u = log_scale(Vc, chart.F, loop, g.angles[chart.faces])
    else:
        u = scale(Vc, chart.F, loop, g.angles[chart.faces], chart.vertices, chart.faces)
    mean, log_area = scale_estimate(Vc, chart.F, u)
    area = float(triangle_areas(Vc[chart.F]).sum())
    inner = np.ones(len(Vc), dtype=bool)
    inner[loop] = False
    k = np.flatnonzero(inner)
    if not len(k):
        return mean, area, -1, np.zeros(0, dtype=np.int64)
    near = k[log_area[k] <= log_area[k].min() + _CONE_SLACK]
    return mean, area, int(chart.vertices[k[np.argmin(log_area[k])]]), chart.vertices[near]


def _stalled(history, window=10, gain=1e-3):
    """Whether the last ``window`` cuts lowered the estimate by less than ``gain`` (relative):
    on coarse meshes the most shrunk vertex can sit next to the seams, and more slits there
    only make the chart ragged."""
    return len(history) > window and history[-window - 1] - history[-1] < gain * history[-1]


def _worth_keeping(history, seam, scale, worth=_SEAM_WORTH):
    """How many of the cuts to keep: the count ``j`` minimising ``history[j] + worth *
    seam[j] / scale`` (the estimate after ``j`` cuts plus the price of their seam)."""
    return int(np.argmin(np.asarray(history) + worth * np.asarray(seam) / scale))


def relieve(g: EdgeGraph, cost, cut, target, max_cuts, prune=False):
    """Greedy cone cuts (module doc, step c) until the area-weighted estimate is at most
    ``target``, ``max_cuts`` cuts were made, or the last cuts stopped helping.  With ``prune``,
    when the target was not reached, only the first cuts that paid for their seam are kept
    (:func:`_worth_keeping`): on a coarse mesh whose curvature is spread out the later cuts are
    slits that buy little, and their seam is better spent on splitting the charts
    (:func:`~geomopt.atlas.flatten.split_to_goal`).

    Returns
    -------
    cut : (k,) bool, ``cut`` with the new cuts;  estimate : float, the area-weighted estimate
    at the end;  made : int, the number of cuts made.
    """
    known = {}  # chart key (its first face) -> (mean, area, vertex)
    scales = {}  # chart key -> its ChartScale: a cone cut keeps the chart's faces, fixes more vertices
    cut = cut.copy()
    history, seam, paths = [], [], []
    for made in range(max_cuts + 1):
        split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
        first = np.full(split.count, len(g.F))
        np.minimum.at(first, split.chart, np.arange(len(g.F)))
        rows = []
        for c in range(split.count):
            if int(first[c]) not in known:
                scale = scales.setdefault(int(first[c]), ChartScale())
                known[int(first[c])] = chart_estimate(g, split.mesh(c), cut | g.boundary, scale)
            rows.append(known[int(first[c])])
        mean = np.array([r[0] for r in rows])
        area = np.array([r[1] for r in rows])
        estimate = float(np.sum(mean * area) / area.sum())
        history.append(estimate)
        seam.append(float(g.length[cut].sum()))
        if estimate <= target or made == max_cuts or _stalled(history):
            break
        excess = np.where([r[2] >= 0 for r in rows], (mean - target) * area, -np.inf)
        c = int(np.argmax(excess))
        if not np.isfinite(excess[c]):
            break  # no chart has an interior vertex left to cut from
        seams = np.unique(g.E[cut | g.boundary].ravel())
        path = cut_path_to_seams(g, cost, rows[c][3], seams)
        paths.append(np.asarray(path)[~cut[path]])
        cut[path] = True
        known.pop(int(first[c]))
    if prune and estimate > target and made:
        made = _worth_keeping(history, seam, np.sqrt(triangle_areas(g.V[g.F]).sum()))
        for path in paths[made:]:
            cut[path] = False
        estimate = history[made]
    return cut, estimate, made


def strong_cones(g: EdgeGraph, least: float = np.pi / 4) -> np.ndarray:
    """Interior vertices whose angle defect is at least ``least`` (radians) in magnitude, most
    concentrated first: the corners of CAD-like parts, where no flattening without a seam
    through the vertex is near isometric (a cone of defect ``K`` on a seam opens by ``K``)."""
    K = angle_defects(g.V, g.F)
    K[g.E[g.boundary].ravel()] = 0.0
    strong = np.flatnonzero(np.abs(K) >= least)
    return strong[np.argsort(-np.abs(K[strong]), kind="stable")]


def _relieved(g: EdgeGraph, cost, tree):
    """``cost`` without :func:`~geomopt.atlas.seams.edge_costs`' saddle factor at the vertices of
    ``tree``: a saddle on a seam already, that one more seam through it splits further, no longer
    keeps more than a full turn on one side."""
    on = np.zeros(len(g.V), dtype=bool)
    on[g.E[tree].ravel()] = True
    relief = np.where(on, saddle_factor(angle_defects(g.V, g.F)), 1.0)
    return cost / (relief[g.E[:, 0]] * relief[g.E[:, 1]])


def _topological(g: EdgeGraph, cost, tree_cost, labels, roots, least, target):
    """The topological cut (step a, with the strong cones of defect at least ``least`` joined
    first by a cheap tree, step a'; none when ``least`` is None), spheres opened (step b)."""
    tree = np.zeros(len(g.E), dtype=bool)
    if least is not None:
        tree = steiner_tree(g, tree_cost, strong_cones(g, least), labels)
    cut = shortest_topological_cut(g, _relieved(g, cost, tree), labels, roots, opened=tree)
    cut = _open_spheres(g, cost, cut, labels, roots)
    return cut if least is None else trim(g, cut, target)


def _estimates(g: EdgeGraph, cut, known):
    """``(split, rows)``: the charts of ``cut`` and their :func:`chart_estimate` rows, reusing
    those in ``known`` (keyed by the chart's first face and face count)."""
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    rows = []
    for c in range(split.count):
        mesh = split.mesh(c)
        key = (int(mesh.faces[0]), len(mesh.faces))
        if key not in known:
            known[key] = chart_estimate(g, mesh, cut | g.boundary)
        rows.append(known[key])
    return split, rows


def trim(g: EdgeGraph, cut, target, max_trials: int = 64):
    """``cut`` without those of its dangling paths (:func:`~geomopt.atlas.seams.dangling_paths`,
    longest first) that the estimate (area-weighted, as in :func:`relieve`) can do without while
    it stays at most ``target``: joining every strong cone is isometric but may cut more than
    the goal needs.  At most ``max_trials`` paths are tried (each costs a chart's estimate)."""
    known, cut = {}, cut.copy()
    tried = set()
    while len(tried) < max_trials:
        split, rows = _estimates(g, cut, known)
        mean, area = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
        paths = [p for p in dangling_paths(g, cut) if tuple(p) not in tried]
        for path in sorted(paths, key=lambda p: -float(g.length[p].sum()))[:max_trials - len(tried)]:
            tried.add(tuple(path))
            trial = cut.copy()
            trial[path] = False
            face = g.edge_faces[path[0], 0]
            c = int(split.chart[face])
            joined = charts_of_cut(g.F, g.edge_of, g.edge_faces, trial)
            after = chart_estimate(g, joined.mesh(int(joined.chart[face])), trial | g.boundary)[0]
            if float(np.sum(mean * area) + (after - mean[c]) * area[c]) / area.sum() <= target:
                cut = trial
                mesh = split.mesh(c)  # same faces, new gluing: its cached estimate is stale
                known.pop((int(mesh.faces[0]), len(mesh.faces)))
                break
        else:
            return cut
    return cut


def cut_surface(g: EdgeGraph, cost, target: float, max_cuts: int = 200, tree_cost=None,
                levels=(None, np.pi / 4), turn: float = 0.0):
    """The interior edges of ``g`` to cut (module doc), as :func:`relieve` returns them.

    Parameters
    ----------
    g : :class:`~geomopt.atlas.seams.EdgeGraph` of a manifold, consistently oriented mesh.
    cost : (k,) edge costs (:func:`~geomopt.atlas.seams.edge_costs`).
    target : the estimated area-weighted mean symmetric Dirichlet to reach (4 = isometric).
    max_cuts : the most cone cuts.
    tree_cost : (k,) edge costs of the tree joining the strong cones (default ``cost``).
    levels : the least angle defects of the strong cones to try joining (None: none joined).
        Each seam graph is relieved (step c); the shortest one that reaches ``target`` is kept,
        or, when none does, the one with the lowest estimate.
    turn : the price of turning of :func:`~geomopt.atlas.seams.straighten` (0: not straightened;
        the estimate returned is the unstraightened seams').
    """
    labels, roots = _component_roots(g)
    tree_cost = cost if tree_cost is None else tree_cost
    best, seen = None, set()
    for least in levels:
        start = _topological(g, cost, tree_cost, labels, roots, least, target)
        if start.tobytes() in seen:
            continue  # e.g. no strong cone to join: the same cut, relieved the same way
        seen.add(start.tobytes())
        cut, estimate, made = relieve(g, cost, start, target, max_cuts, prune=True)
        key = (estimate > target, estimate if estimate > target else float(g.length[cut].sum()))
        if best is None or key < best[0]:
            best = (key, (cut, estimate, made))
    cut, estimate, made = best[1]
    return _without_slits(g, cost, straighten(g, cost, cut, turn)), estimate, made

"""Where the seams of an atlas go: the edge graph of a surface, the cost of cutting each edge, a
topological cut graph (tree-cotree) that opens every component into a disk, and cheapest cut
paths from a vertex to the seams.

Costs follow Seamster's idea (Sheffer & Hart 2002) that a seam is least seen along creases: an
edge costs its 3D length divided by ``1 + crease * sharpness``, where sharpness is the dihedral
angle (radians, 0 = flat) and counts 1.5 times at a concave crease.  The topological cut is the
tree-cotree construction of Eppstein (2003) with Erickson & Whittlesey's (2005) greedy choice:
a shortest-path forest ``T`` grown by cost from the boundary vertices (or one root per closed
component), a maximum dual spanning tree ``C`` of the edges outside ``T`` weighted by the cost of
the loop each closes, and the edges in neither, together with their ``T`` paths, as the cut.
On a closed component every loop passes through the root, so the root decides the cut's cost:
Erickson & Whittlesey's shortest system of loops is the greedy one from the best root, and
:func:`shortest_topological_cut` tries several roots spread over each component (farthest-point
sampling) and keeps the cheapest cut of each.  Edges cut already (``opened``, e.g. a
:func:`steiner_tree` joining the corners of a CAD-like part, Takahashi & Matsuyama's heuristic
improved by key-path exchange) count as boundary: the forest grows from them and they are kept.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.sparse as sp

from ..exact.topology import ranges, unique_edges

__all__ = ["EdgeGraph", "edge_graph", "edge_costs", "exposure", "underside", "topological_cut", "shortest_topological_cut",
           "steiner_tree", "saddle_factor", "dangling_paths", "cut_path_to_seams", "slits", "straighten",
           "straighten_split", "straighten_splits"]


@dataclasses.dataclass(frozen=True)
class EdgeGraph:
    """The edges of a manifold, consistently oriented triangle mesh.

    Attributes
    ----------
    V : (n, 3) float64;  F : (m, 3) int64.
    E : (k, 2) int64 unique edges, ``E[:, 0] < E[:, 1]``.
    edge_of : (m, 3) int64, the edge of half-edge ``(F[f, c], F[f, c + 1])``.
    edge_faces : (k, 2) int64, the faces on each edge (``-1`` in column 1 on the boundary).
    length : (k,) float64 3D edge lengths.
    """

    V: np.ndarray
    F: np.ndarray
    E: np.ndarray
    edge_of: np.ndarray
    edge_faces: np.ndarray
    length: np.ndarray

    @property
    def boundary(self) -> np.ndarray:
        """(k,) bool, edges with one face."""
        return self.edge_faces[:, 1] < 0

    @functools.cached_property
    def angles(self) -> np.ndarray:
        """(m, 3) the interior angle at each face corner (computed once: every chart's
        estimate gathers its own)."""
        from .cones import corner_angles

        return corner_angles(self.V, self.F)

    def adjacency(self, weight) -> sp.csr_matrix:
        """(n, n) symmetric sparse matrix of ``weight`` (k,) on the edges (positive weights)."""
        n = len(self.V)
        i, j = self.E[:, 0], self.E[:, 1]
        return sp.coo_matrix((np.r_[weight, weight], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()


def edge_graph(V, F) -> EdgeGraph:
    """The :class:`EdgeGraph` of ``V`` (n, 3) and ``F`` (m, 3) (edges used by at most 2 faces)."""
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    E, _, edge_of = unique_edges(F)
    faces = np.full((len(E), 2), -1, dtype=np.int64)
    flat, f = edge_of.ravel(), np.repeat(np.arange(len(F)), 3)
    order = np.argsort(flat, kind="stable")
    first = np.r_[True, flat[order][1:] != flat[order][:-1]]
    faces[flat[order][first], 0] = f[order][first]
    faces[flat[order][~first], 1] = f[order][~first]
    length = np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
    return EdgeGraph(V, F, E, edge_of, faces, length)


def edge_costs(g: EdgeGraph, crease: float = 2.0, defects=None, visibility=None, hide: float = 2.0,
               up=None) -> np.ndarray:
    """(k,) cost of cutting each edge: its length over ``1 + crease * sharpness`` (module doc).

    Boundary edges get their length (they are open already).  With ``defects`` (n,) (the angle
    defects), an edge costs ``1 + 4 max(0, -K)`` times more at each saddle end ``K < 0``: a seam
    bending at a saddle leaves one side more than a full turn, which no flip-free flattening
    keeps from overlapping itself there.  With ``visibility`` (n,) (each vertex's ambient
    visibility in ``[0, 1]``, :func:`~geomopt.atlas.visibility.ambient_visibility`), an interior
    edge costs :func:`exposure` of its ends' mean times more: seams go where the surface is
    occluded (cavities, the insides of limbs, concave creases).  With ``up`` (3,) a unit
    vector, an interior edge whose normal points down costs less (:func:`underside`)."""
    N = np.cross(g.V[g.F[:, 1]] - g.V[g.F[:, 0]], g.V[g.F[:, 2]] - g.V[g.F[:, 0]])
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    inner = ~g.boundary
    f1, f2 = g.edge_faces[inner, 0], g.edge_faces[inner, 1]
    angle = np.arccos(np.clip(np.sum(N[f1] * N[f2], axis=1), -1.0, 1.0))
    # concave when the far corner of the second face lies above the first face's plane
    far = g.F[f2].sum(axis=1) - g.E[inner].sum(axis=1)
    concave = np.sum((g.V[far] - g.V[g.E[inner, 0]]) * N[f1], axis=1) > 0
    sharp = angle * np.where(concave, 1.5, 1.0)
    cost = g.length.copy()
    cost[inner] /= 1.0 + crease * sharp
    if visibility is not None:
        vis = np.asarray(visibility, dtype=np.float64)
        cost[inner] *= exposure(0.5 * (vis[g.E[inner, 0]] + vis[g.E[inner, 1]]), hide)
    if up is not None:
        normal = N[f1] + N[f2]
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        cost[inner] *= underside(normal @ np.asarray(up, dtype=np.float64))
    if defects is not None:
        saddle = saddle_factor(defects)
        cost *= saddle[g.E[:, 0]] * saddle[g.E[:, 1]]
    return np.maximum(cost, 1e-12 * max(float(g.length.max()), 1e-300))


def exposure(visibility, hide: float = 2.0) -> np.ndarray:
    """How much more a seam costs where its ambient visibility is ``visibility`` (in [0, 1]):
    ``max(visibility, 0.05) ** hide`` (1 where fully exposed; ``hide = 0``: no preference)."""
    return np.maximum(np.asarray(visibility, dtype=np.float64), 0.05) ** hide


def underside(height) -> np.ndarray:
    """How much more a seam costs where its normal's component along the up axis is ``height``
    (in [-1, 1]): from 1 facing up to 0.25 facing down."""
    return 0.25 + 0.375 * (1.0 + np.asarray(height, dtype=np.float64))


def saddle_factor(defects) -> np.ndarray:
    """(n,) how much more an edge costs per saddle end in :func:`edge_costs`: ``1 + 4 max(0, -K)``."""
    return 1.0 + 4.0 * np.maximum(-np.asarray(defects, dtype=np.float64), 0.0)


def _dijkstra(adjacency, sources, limit=np.inf):
    """Distances and predecessors of a multi-source shortest-path forest (vertices farther than
    ``limit`` unreached: infinite distance)."""
    from scipy.sparse.csgraph import dijkstra

    dist, pred, _ = dijkstra(adjacency, directed=False, indices=np.asarray(sources), min_only=True,
                             return_predecessors=True, limit=limit)
    return dist, pred


def _edge_index(g: EdgeGraph):
    """A function mapping vertex pairs (a, b) to edge rows of ``g.E``."""
    n = len(g.V)
    keys = g.E[:, 0] * n + g.E[:, 1]

    def index(a, b):
        a, b = np.asarray(a), np.asarray(b)
        return np.searchsorted(keys, np.minimum(a, b) * n + np.maximum(a, b))

    return index


def _max_spanning_forest(n_nodes, a, b, weight) -> np.ndarray:
    """(len(a),) bool, the edges ``(a, b)`` of a maximum spanning forest: Kruskal's greedy over
    the edges by decreasing ``weight``, ties in the order given (a stable sort).  Each edge's
    weight is replaced by its rank in that order, so the forest is unique and is the one
    :func:`scipy.sparse.csgraph.minimum_spanning_tree` finds on the ranks (compiled; of parallel
    edges the first ranked stands for all: the later ones close a cycle)."""
    from scipy.sparse.csgraph import minimum_spanning_tree

    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    order = np.argsort(-np.asarray(weight, dtype=np.float64), kind="stable")
    lo, hi = np.minimum(a[order], b[order]), np.maximum(a[order], b[order])
    _, first = np.unique(lo * n_nodes + hi, return_index=True)  # of parallel edges, the first ranked
    first = first[lo[first] != hi[first]]  # a loop never joins two parts
    rank = (first + 1).astype(np.float64)  # ranks 1.. (a csgraph edge of weight 0 is no edge)
    graph = sp.csr_matrix((rank, (lo[first], hi[first])), shape=(n_nodes, n_nodes))
    tree = minimum_spanning_tree(graph).tocoo()
    keep = np.zeros(len(a), dtype=bool)
    keep[order[tree.data.astype(np.int64) - 1]] = True
    return keep


def _prune(g: EdgeGraph, cut: np.ndarray, kept=None) -> np.ndarray:
    """``cut`` without its dangling interior edges: repeatedly drop an interior cut edge with
    an end that no other cut, boundary or ``kept`` edge touches (cutting it opens nothing).
    The edges dropped do not depend on the order (a degree only falls), so the vertices of
    degree 1 are stripped a layer at a time, each layer in one vectorised step."""
    cut = cut.copy()
    on = cut | g.boundary | (False if kept is None else kept)
    n = len(g.V)
    degree = np.bincount(g.E[on].ravel(), minlength=n)
    edges = np.flatnonzero(cut)
    ends = np.r_[g.E[edges, 0], g.E[edges, 1]]
    order = np.argsort(ends, kind="stable")
    incident = np.r_[edges, edges][order]  # the cut edges at each vertex, vertex by vertex
    start = np.searchsorted(ends[order], np.arange(n + 1))
    leaves = np.flatnonzero(degree == 1)
    while len(leaves):
        rows = ranges(start, leaves)
        drop = np.unique(incident[rows][cut[incident[rows]]])  # a leaf's one edge, if it is a cut edge
        cut[drop] = False
        np.subtract.at(degree, g.E[drop].ravel(), 1)
        touched = np.unique(g.E[drop].ravel())
        leaves = touched[degree[touched] == 1]
    return cut


def topological_cut(g: EdgeGraph, cost: np.ndarray, roots, opened=None) -> np.ndarray:
    """(k,) bool, interior edges to cut so that every component becomes a disk, or (for a
    closed genus-0 component) stays a sphere that a single cut path then opens.

    Parameters
    ----------
    g : the mesh's :class:`EdgeGraph`;  cost : (k,) positive edge costs (:func:`edge_costs`).
    roots : vertex ids, one per closed component without ``opened`` edges (the boundary and
        ``opened`` vertices root the others).
    opened : (k,) bool or None, interior edges cut already (a tree, e.g. :func:`steiner_tree`):
        they count as boundary, the loops are rooted on them, and they are in the result.
    """
    opened = np.zeros(len(g.E), dtype=bool) if opened is None else np.asarray(opened, dtype=bool)
    sources = np.unique(np.r_[g.E[g.boundary | opened].ravel(), np.asarray(roots, dtype=np.int64)])
    dist, pred = _dijkstra(g.adjacency(cost), sources)
    index = _edge_index(g)
    child = np.flatnonzero(pred >= 0)
    in_tree = np.zeros(len(g.E), dtype=bool)
    in_tree[index(child, pred[child])] = True
    inner = ~g.boundary & ~opened
    loop = dist[g.E[:, 0]] + dist[g.E[:, 1]] + cost
    # tree edges may join the dual tree only when nothing else connects it
    weight = np.where(in_tree, -1.0 - loop.max(), loop)
    e = np.flatnonzero(inner)
    dual = _max_spanning_forest(len(g.F), g.edge_faces[e, 0], g.edge_faces[e, 1], weight[e])
    cut = inner.copy()
    cut[e[dual]] = False
    return _prune(g, cut, opened) | opened


def _spread_roots(g: EdgeGraph, cost, labels, roots, tries):
    """(len(roots), tries) vertex ids: per closed component, its root then the vertices farthest
    (by ``cost``) from those chosen before (farthest-point sampling)."""
    adjacency = g.adjacency(cost)
    out = np.empty((len(roots), tries), dtype=np.int64)
    for i, r in enumerate(roots):
        inside = labels == labels[r]
        out[i, 0] = r
        near = np.full(len(g.V), np.inf)
        for k in range(1, tries):
            near = np.minimum(near, _dijkstra(adjacency, [out[i, k - 1]])[0])
            out[i, k] = int(np.argmax(np.where(inside & np.isfinite(near), near, -1.0)))
    return out


def shortest_topological_cut(g: EdgeGraph, cost: np.ndarray, labels, roots, tries: int = 16,
                             opened=None) -> np.ndarray:
    """:func:`topological_cut` with the root of each closed component chosen among ``tries``
    spread vertices (module doc) to make that component's cut cheapest; the first try is
    ``roots`` itself, so the cut never costs more than ``topological_cut(g, cost, roots)``.

    Parameters
    ----------
    labels : (n,) component of each vertex;  roots : one vertex per closed component.
    opened : as for :func:`topological_cut`; the components it touches need no root.
    """
    roots = np.asarray(roots, dtype=np.int64)
    if opened is not None:
        roots = roots[~np.isin(labels[roots], labels[g.E[opened].ravel()])]
    spheres = _spheres(g, labels)[labels[roots]]  # their cut is empty from any root: nothing to try
    fixed, roots = roots[spheres], roots[~spheres]
    if len(roots) == 0 or tries <= 1:
        return topological_cut(g, cost, np.r_[roots, fixed], opened)
    candidates = _spread_roots(g, cost, labels, roots, tries)
    comp = labels[g.E[:, 0]]
    best, best_cost = roots.copy(), np.full(len(roots), np.inf)
    for k in range(tries):
        cut = topological_cut(g, cost, np.r_[candidates[:, k], fixed], opened)
        spent = np.bincount(comp[cut], cost[cut], minlength=labels.max() + 1)[labels[roots]]
        better = spent < best_cost
        best[better], best_cost[better] = candidates[better, k], spent[better]
    return topological_cut(g, cost, np.r_[best, fixed], opened)


def _spheres(g: EdgeGraph, labels) -> np.ndarray:
    """(components,) bool, the closed genus-0 components (Euler characteristic 2: a tree and a
    dual tree take every edge, so their topological cut is empty whatever the root)."""
    size = labels.max() + 1
    chi = (np.bincount(labels, minlength=size) - np.bincount(labels[g.E[:, 0]], minlength=size)
           + np.bincount(labels[g.F[:, 0]], minlength=size))
    closed = np.ones(size, dtype=bool)
    closed[labels[g.E[g.boundary, 0]]] = False
    return closed & (chi == 2)


def steiner_tree(g: EdgeGraph, cost: np.ndarray, terminals, labels) -> np.ndarray:
    """(k,) bool, interior edges of a cheap forest joining the ``terminals`` (vertex ids) of each
    component (the shortest-path heuristic of Takahashi & Matsuyama 1980, at most twice the
    cheapest Steiner tree): from the first terminal of a component, add the cheapest path from
    the tree to the nearest terminal not on it, until all are on it.  A component with boundary
    starts from its boundary instead (the terminals are joined to it)."""
    adjacency = g.adjacency(np.where(g.boundary, 0.0, cost) + 1e-300)
    tree = np.zeros(len(g.E), dtype=bool)
    index = _edge_index(g)
    terminals = np.asarray(terminals, dtype=np.int64)
    rim = np.unique(g.E[g.boundary].ravel())
    for comp in np.unique(labels[terminals]):
        todo = terminals[labels[terminals] == comp]
        on = rim[labels[rim] == comp]
        on = on if len(on) else todo[:1]
        reached = np.zeros(len(g.V), dtype=bool)
        reached[on] = True
        while not reached[todo].all():
            dist, pred = _dijkstra(adjacency, np.flatnonzero(reached))
            v = int(todo[~reached[todo]][np.argmin(dist[todo[~reached[todo]]])])
            if not np.isfinite(dist[v]):
                break
            while not reached[v]:
                tree[index(v, pred[v])] = True
                reached[v] = True
                v = int(pred[v])
    return _exchange_key_paths(g, cost, tree & ~g.boundary, terminals)


def _key_paths(g: EdgeGraph, tree, key):
    """The key paths of the forest ``tree | boundary``: lists of its interior edges between two
    vertices of ``key`` (bool, (n,)) or of degree other than 2, through none (boundary skipped)."""
    on = tree | g.boundary
    incident = [[] for _ in range(len(g.V))]
    for e in np.flatnonzero(on).tolist():
        incident[g.E[e, 0]].append(e)
        incident[g.E[e, 1]].append(e)
    node = key | np.array([len(i) not in (0, 2) for i in incident])
    paths, seen = [], np.zeros(len(g.E), dtype=bool)
    for v in np.flatnonzero(node).tolist():
        for e in incident[v]:
            if seen[e]:
                continue
            path, w = [], v
            while True:
                seen[e] = True
                path.append(e)
                w = int(g.E[e, 0] + g.E[e, 1] - w)
                if node[w]:
                    break
                e = next(f for f in incident[w] if f != e)
            if not g.boundary[path].any():
                paths.append(path)
    return paths


def _exchange_key_paths(g: EdgeGraph, cost, tree, terminals, rounds: int = 4):
    """``tree`` improved by key-path exchange (a local search for Steiner trees): take out one
    key path (between terminals or branch vertices) and join the two parts it held together by
    their cheapest path instead, when that is cheaper; until no exchange helps."""
    from scipy.sparse.csgraph import connected_components

    adjacency = g.adjacency(np.where(g.boundary, 0.0, cost) + 1e-300)
    index = _edge_index(g)
    key = np.zeros(len(g.V), dtype=bool)
    key[np.asarray(terminals, dtype=np.int64)] = True
    for _ in range(rounds):
        changed = False
        for path in _key_paths(g, tree, key):
            if not tree[path].all():
                continue  # an earlier exchange of this round moved it
            rest = tree.copy()
            rest[path] = False
            on = np.flatnonzero(rest | g.boundary)
            n = len(g.V)
            links = sp.coo_matrix((np.ones(len(on)), (g.E[on, 0], g.E[on, 1])), shape=(n, n))
            _, part = connected_components(links, directed=False)
            a, b = part[list(_ends(g, path))]
            if a == b:
                continue
            dist, pred = _dijkstra(adjacency, np.flatnonzero(part == a), limit=cost[path].sum())
            there = np.flatnonzero(part == b)
            v = int(there[np.argmin(dist[there])])
            if not dist[v] < cost[path].sum() * (1 - 1e-9):
                continue
            while pred[v] >= 0:
                rest[index(v, pred[v])] = True
                v = int(pred[v])
            tree, changed = rest & ~g.boundary, True
        if not changed:
            break
    return tree


def _ends(g: EdgeGraph, path):
    """The two end vertices of a path of edges (rows of ``g.E``)."""
    count = np.bincount(g.E[path].ravel(), minlength=len(g.V))
    ends = np.flatnonzero(count == 1)
    return int(ends[0]), int(ends[1])


def dangling_paths(g: EdgeGraph, cut: np.ndarray) -> list:
    """The paths of ``cut`` that hang off the rest of the seams: lists of interior edges from a
    vertex of degree 1 in ``cut | boundary`` through vertices of degree 2 up to a vertex of
    degree 3 or more (a cut that is one lone path has none).  Uncutting one keeps every chart
    a disk."""
    on = cut | g.boundary
    incident = [[] for _ in range(len(g.V))]
    for e in np.flatnonzero(on).tolist():
        incident[g.E[e, 0]].append(e)
        incident[g.E[e, 1]].append(e)
    paths = []
    for v in [v for v in range(len(g.V)) if len(incident[v]) == 1]:
        path, e, w = [], incident[v][0], v
        while True:
            path.append(e)
            w = int(g.E[e, 0] + g.E[e, 1] - w)
            if len(incident[w]) != 2:
                break
            e = incident[w][0] if incident[w][0] != e else incident[w][1]
        if len(incident[w]) >= 3 and not g.boundary[path].any():
            paths.append(path)
    return paths


def cut_path_to_seams(g: EdgeGraph, cost: np.ndarray, target, seams: np.ndarray) -> list:
    """Edges (rows of ``g.E``) of the cheapest path from vertex ``target`` (or from the nearest,
    by ``cost``, of the vertex ids ``target``) to any vertex of ``seams`` (a vertex id array),
    by ``cost``; empty when ``target`` is on the seams."""
    dist, pred = _dijkstra(g.adjacency(cost), seams)
    index = _edge_index(g)
    target = np.atleast_1d(np.asarray(target, dtype=np.int64))
    path, v = [], int(target[np.argmin(dist[target])])
    while pred[v] >= 0:
        path.append(int(index(v, pred[v])))
        v = int(pred[v])
    return path


# a straightened path may cost (without its turning) at most this much more than the path it replaces
_STRAIGHT_SLACK = 1.25


def _turn_graph(g: EdgeGraph):
    """The line graph of ``g``'s half-edges: half-edge ``h`` runs ``E[h // 2]`` forward when
    ``h`` is even, backward when odd.  Returns ``(tail, head, a, b, angle)``: each half-edge's
    vertices and each pair ``a -> b`` of consecutive half-edges (``b`` leaving the vertex ``a``
    enters, not back along ``a``) with the turning angle between them (radians, 0: straight)."""
    tail = np.ravel(np.c_[g.E[:, 0], g.E[:, 1]])
    head = np.ravel(np.c_[g.E[:, 1], g.E[:, 0]])
    order = np.argsort(tail, kind="stable")
    start = np.searchsorted(tail[order], np.arange(len(g.V) + 1))
    a = np.repeat(np.arange(len(tail)), start[head + 1] - start[head])
    b = order[ranges(start, head)]
    keep = head[b] != tail[a]
    a, b = a[keep], b[keep]
    u = g.V[head] - g.V[tail]
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(u[a] * u[b], axis=1), -1.0, 1.0))
    return tail, head, a, b, angle


def slits(g: EdgeGraph, cut) -> np.ndarray:
    """(k,) bool, the interior cut edges that no other cut or boundary edge touches at either
    end.  Cutting such an edge alone opens a disk whose boundary is a two-gon (both sides of the
    edge on the same two vertices): a disk topologically, but no triangle mesh (its two boundary
    edges are one edge with two faces on each side, so the chart reads as closed)."""
    on = np.asarray(cut, dtype=bool) | g.boundary
    degree = np.bincount(g.E[on].ravel(), minlength=len(g.V))
    return on & ~g.boundary & (degree[g.E[:, 0]] == 1) & (degree[g.E[:, 1]] == 1)


def _disks(g: EdgeGraph, cut) -> tuple:
    """``(count, all_disks)``: the charts of ``cut`` and whether each is a disk (Euler
    characteristic 1 of a connected chart: wedges - edges + faces, its edges counted from its
    faces' half-edges, each glued pair once) that a triangle mesh can hold (no :func:`slits`)."""
    from .charts import charts_of_cut

    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    faces = np.bincount(split.chart, minlength=split.count)
    open_half = np.bincount(split.chart, (cut | g.boundary)[g.edge_of].sum(axis=1), minlength=split.count)
    wedge_chart = np.zeros(split.wedge.max() + 1, dtype=np.int64)
    wedge_chart[split.wedge.ravel()] = np.repeat(split.chart, 3)
    wedges = np.bincount(wedge_chart, minlength=split.count)
    chi = 2 * wedges - (3 * faces + open_half) + 2 * faces
    return split.count, bool(np.all(chi == 2)) and not slits(g, cut).any()


def straighten(g: EdgeGraph, cost: np.ndarray, cut: np.ndarray, turn: float = 1.0, slide: float = 0.0) -> np.ndarray:
    """``cut`` with its paths straightened: each path of the seam graph between two of its
    nodes (ends, branches, boundary vertices) is replaced by the path between the same nodes
    that is cheapest when each edge costs ``cost`` plus ``turn * angle`` times the geometric
    mean of its cost and the median one, ``angle`` the turn (radians) from the edge before it
    (:func:`_turn_price`; a shortest path in the line graph, which knows
    where a path came from), avoiding every other seam, when that is cheaper, costs at most
    ``_STRAIGHT_SLACK`` times as much by ``cost`` alone (a straight seam is no excuse for an
    exposed one), and every chart stays a disk (same number of charts).  Edge paths on a triangle mesh zigzag where their
    direction is not an edge's; the turning charge trades a little length for straight runs.
    With ``slide`` > 0, an end of a path on the boundary where no other seam meets it may move
    along the boundary, to any boundary vertex within ``slide`` times the distance between the
    path's ends (:func:`_slid`)."""
    cut = np.asarray(cut, dtype=bool).copy()
    if turn <= 0 or not cut.any():
        return cut
    lines = _TurnGraph(g, cost, turn)
    charts, disks = _disks(g, cut)
    for path in _key_paths(g, cut & ~g.boundary, np.zeros(len(g.V), dtype=bool)):
        if not cut[path].all():
            continue
        verts, count = np.unique(g.E[path].ravel(), return_counts=True)
        ends = verts[count == 1]
        if len(ends) != 2:
            continue  # a loop through a single node
        s, t = (int(v) for v in (ends if ends[0] in g.E[path[0]] else ends[::-1]))
        on = np.zeros(len(g.V), dtype=bool)
        rest = cut.copy()
        rest[path] = False
        on[g.E[rest | g.boundary].ravel()] = True
        S, T = _slid(g, rest & ~g.boundary, s, t, slide)
        on[S | T] = False
        old = _path_price(g, path, s, cost, turn, lines.typical)
        new = lines.cheapest(S, T, on, old)
        if new is None or len(set(new)) != len(new) or cost[new].sum() > _STRAIGHT_SLACK * cost[path].sum():
            continue
        trial = cut.copy()
        trial[path] = False
        trial[new] = True
        if _disks(g, trial) == (charts, disks):
            cut = trial
    return cut


class _TurnGraph:
    """The line graph of :func:`_turn_graph` priced as :func:`straighten` prices it, indexed so
    that the part of it a search can reach is gathered in time proportional to that part: a
    path's search (:meth:`cheapest`) then costs the neighbourhood the path's own price reaches,
    not the whole surface again for every seam path."""

    def __init__(self, g: EdgeGraph, cost, turn):
        self.g, self.cost = g, cost
        self.tail, self.head, self.a, self.b, angle = _turn_graph(g)
        self.edge = np.arange(len(self.tail)) // 2
        self.typical = float(np.median(cost))
        self.price = _turn_price(cost[self.edge[self.b]], angle, turn, self.typical)
        self.leaving = np.argsort(self.tail, kind="stable")  # half-edges by tail vertex
        self.leaving_start = np.searchsorted(self.tail[self.leaving], np.arange(len(g.V) + 1))
        self.pair_start = np.searchsorted(self.a, np.arange(len(self.tail) + 1))  # pairs by first half-edge
        self.adjacency = g.adjacency(cost)

    def _out_of(self, vertices):
        return np.sort(self.leaving[ranges(self.leaving_start, vertices)])

    def cheapest(self, S, T, on, limit):
        """Edges (rows of ``g.E``, in order from ``T`` back to ``S``) of the cheapest priced path
        from a vertex of ``S`` to one of ``T`` ((n,) bool each) through no vertex of ``on`` nor
        along the boundary, entering no vertex of ``S`` and leaving none of ``T``, when one is
        priced below ``limit`` (else None).  A path priced at most ``limit`` costs at most that
        by ``cost`` alone, so it runs among the vertices within ``limit`` of ``S`` along the edges
        (one Dijkstra stopped at ``limit``): only the pairs of half-edges there are gathered."""
        from scipy.sparse.csgraph import dijkstra

        g, tail, head, a, b, edge = self.g, self.tail, self.head, self.a, self.b, self.edge
        reach = np.isfinite(dijkstra(self.adjacency, indices=np.flatnonzero(S), min_only=True, limit=limit))
        near = self._out_of(np.flatnonzero(reach))
        p = ranges(self.pair_start, near[reach[head[near]]])
        p = p[reach[head[b[p]]]]

        def ok(h):
            return ~on[tail[h]] & ~on[head[h]] & ~S[head[h]] & ~T[tail[h]] & ~g.boundary[edge[h]]

        p = p[ok(a[p]) & ok(b[p])]
        start = self._out_of(np.flatnonzero(S))
        start = start[ok(start)]
        n = len(tail)  # node n: the source; weights: the edge entered plus the turn
        graph = sp.csr_matrix((np.r_[self.price[p], self.cost[edge[start]]] + 1e-300,
                               (np.r_[a[p], np.full(len(start), n)], np.r_[b[p], start])), shape=(n + 1, n + 1))
        dist, pred = dijkstra(graph, indices=n, return_predecessors=True, limit=limit)
        arrive = np.flatnonzero(T[head] & np.isfinite(dist[:n]))
        if not len(arrive):
            return None
        h = int(arrive[np.argmin(dist[arrive])])
        if dist[h] >= limit * (1 - 1e-9):
            return None
        new = []
        while h != n:
            new.append(int(edge[h]))
            h = int(pred[h])
        return new


def _slid(g: EdgeGraph, others, s, t, slide):
    """``(S, T)``, (n,) bool: the vertices a path from ``s`` to ``t`` may start and end at in
    :func:`straighten`: ``s`` and ``t`` themselves, and, for an end on the boundary that no other
    seam (``others``, (k,) bool interior edges) touches, the boundary vertices within ``slide``
    times ``|s - t|`` of it that no other seam touches (both ends fixed when the two sets
    would meet)."""
    S, T = np.zeros(len(g.V), dtype=bool), np.zeros(len(g.V), dtype=bool)
    S[s], T[t] = True, True
    if slide <= 0:
        return S, T
    rim = np.zeros(len(g.V), dtype=bool)
    rim[g.E[g.boundary].ravel()] = True
    touched = np.zeros(len(g.V), dtype=bool)
    touched[g.E[others].ravel()] = True
    reach = slide * float(np.linalg.norm(g.V[t] - g.V[s]))
    near = {v: rim & ~touched & (np.linalg.norm(g.V - g.V[v], axis=1) <= reach) for v in (s, t)}
    for v, end in ((s, S), (t, T)):
        if rim[v] and near[v][v]:
            end |= near[v]
    if (S & T).any():
        S[:], T[:] = False, False
        S[s], T[t] = True, True
    return S, T


def _turn_price(cost, angle, turn, typical):
    """The price of entering edges of ``cost`` after turning by ``angle`` (radians): the cost
    plus ``turn * angle`` times the geometric mean of the cost and the ``typical`` one (turning
    charged by the local price, so that a cheap hidden place stays cheap, but not for nothing)."""
    return cost + turn * angle * np.sqrt(cost * typical)


def _path_price(g: EdgeGraph, path, s, cost, turn, typical) -> float:
    """The price :func:`straighten` puts on the edge path ``path`` (in order) from vertex ``s``
    (:func:`_turn_price`, no turn into the first edge)."""
    verts = [int(s)]
    for e in path:
        verts.append(int(g.E[e, 0] + g.E[e, 1] - verts[-1]))
    P = g.V[verts]
    d = np.diff(P, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    angle = np.r_[0.0, np.arccos(np.clip(np.sum(d[1:] * d[:-1], axis=1), -1.0, 1.0))]
    return float(np.sum(_turn_price(cost[path], angle, turn, typical)))



# a packing split's border ends may slide along the chart's boundary by this much of its length
_SPLIT_SLIDE = 0.25


def _kept_areas(before, after, area) -> bool:
    """Whether each piece of ``after`` (m,) (labels of the faces) has between half and twice the
    area (``area`` (m,)) of the piece of ``before`` it shares the most area with."""
    joint = sp.coo_matrix((area, (after, before))).toarray()
    own = np.bincount(before, area)[np.argmax(joint, axis=1)]
    new = joint.sum(axis=1)
    return bool(np.all((new >= 0.5 * own) & (new <= 2.0 * own)))


def straighten_split(g: EdgeGraph, cost: np.ndarray, mesh, x, pieces, turn: float = 1.0) -> list:
    """The pieces of a flattened disk chart with the borders between them straightened.

    A split of a flattened chart keeps its coordinates in every piece (a part of an injective
    map is one) wherever the border runs, so the border can follow the surface: a border drawn
    in the plane (a straight line across the flattening) zigzags along the surface's edges and
    ignores where the surface is seen.  Each border path is rerouted as :func:`straighten`
    reroutes seams, inside the chart, by the surface's seam ``cost`` and turning: the pieces stay
    disks and keep their number, and each keeps its faces' coordinates.  A border's ends may slide
    along the chart's boundary (``_SPLIT_SLIDE``, :func:`straighten`) while every piece keeps
    between half and twice its area.

    Parameters
    ----------
    g : the surface's :class:`EdgeGraph`, whose vertices ``mesh.vertices`` index;
    cost : (k,) its edges' seam costs (:func:`edge_costs`).
    mesh : the chart's :class:`~geomopt.atlas.charts.ChartMesh`;  x : (nc, 2) its flattening.
    pieces : list of ``(ChartMesh, x_piece)``, a partition of the chart's faces into disks (as
        :func:`~geomopt.atlas.flat_splits.split_flat_chart` returns it).
    turn : the price of turning (:func:`straighten`; 0: the pieces as given).

    Returns
    -------
    list of ``(ChartMesh, x_piece)``: the pieces given when no border changed.
    """
    from .charts import charts_of_cut

    if turn <= 0 or len(pieces) < 2:
        return pieces
    label = np.empty(len(mesh.F), dtype=np.int64)
    for k, (piece, _) in enumerate(pieces):
        label[np.searchsorted(mesh.faces, piece.faces)] = k
    chart = edge_graph(g.V[mesh.vertices], mesh.F)  # the chart's own gluing: its slits are boundary
    f1, f2 = chart.edge_faces[:, 0], np.maximum(chart.edge_faces[:, 1], 0)
    border = ~chart.boundary & (label[f1] != label[f2])
    index = _edge_index(g)
    local_cost = cost[index(mesh.vertices[chart.E[:, 0]], mesh.vertices[chart.E[:, 1]])]
    area = np.linalg.norm(np.cross(chart.V[chart.F[:, 1]] - chart.V[chart.F[:, 0]],
                                   chart.V[chart.F[:, 2]] - chart.V[chart.F[:, 0]]), axis=1)
    for slide in (_SPLIT_SLIDE, 0.0):
        new = straighten(chart, local_cost, border, turn, slide)
        split = charts_of_cut(chart.F, chart.edge_of, chart.edge_faces, new)
        if _kept_areas(label, split.chart, area):
            break
    else:
        return pieces
    if np.array_equal(new, border):
        return pieces
    out = []
    for c in range(split.count):
        part, rows = mesh.part(split.faces_of(c))
        out.append((part, np.asarray(x)[rows]))
    return out


def straighten_splits(g: EdgeGraph, cost: np.ndarray, charts, maps, owner, pieces, turn: float = 1.0):
    """:func:`straighten_split` for every chart that a later split cut into pieces (as
    :func:`~geomopt.atlas.flat_splits.split_to_pack` does, keeping each piece's coordinates).

    Parameters
    ----------
    g, cost : as :func:`straighten_split`.
    charts : list of :class:`~geomopt.atlas.charts.ChartMesh`, the charts before the splits;
    maps : their flattenings (nc, 2).
    owner : (p,) int, the chart each piece came from.
    pieces : list of ``(ChartMesh, x_piece)``, the pieces.

    Returns
    -------
    ``(pieces, owner, changed)``: the pieces of each chart together (in the order of the charts),
    each chart's borders straightened; the chart of each; whether a border moved.
    """
    owner = np.asarray(owner, dtype=np.int64)
    out, out_owner, changed = [], [], False
    for c, (mesh, x) in enumerate(zip(charts, maps)):
        mine = [pieces[k] for k in np.flatnonzero(owner == c)]
        if len(mine) > 1:
            new = straighten_split(g, cost, mesh, x, mine, turn)
            mine, changed = new, changed or new is not mine
        out.extend(mine)
        out_owner.extend([c] * len(mine))
    return out, out_owner, changed

"""The atlas's fast paths equal the plain ones they replace (issue 50): the compiled spanning
forest and the layered pruning of the topological cut."""

from __future__ import annotations

import numpy as np
import pytest

from geomopt.atlas import seams
from geomopt.atlas.seams import edge_costs, edge_graph, topological_cut
from geomopt.mesh.generators import holed_plate


def _kruskal(n_nodes, a, b, weight):
    """The plain Kruskal the compiled forest replaces: edges by decreasing weight, ties in order."""
    parent = list(range(n_nodes))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    keep = np.zeros(len(a), dtype=bool)
    for e in np.argsort(-weight, kind="stable").tolist():
        ra, rb = find(int(a[e])), find(int(b[e]))
        if ra != rb:
            parent[ra] = rb
            keep[e] = True
    return keep


def _strip(g, cut, kept=None):
    """The plain pruning the layered one replaces: one dangling edge at a time, from a stack."""
    cut = cut.copy()
    on = cut | g.boundary | (False if kept is None else kept)
    degree = np.bincount(g.E[on].ravel(), minlength=len(g.V))
    incident = [[] for _ in range(len(g.V))]
    for e in np.flatnonzero(cut).tolist():
        incident[g.E[e, 0]].append(e)
        incident[g.E[e, 1]].append(e)
    stack = [v for v in range(len(g.V)) if degree[v] == 1]
    while stack:
        v = stack.pop()
        for e in incident[v]:
            if cut[e]:
                cut[e] = False
                for w in g.E[e].tolist():
                    degree[w] -= 1
                    if degree[w] == 1:
                        stack.append(w)
                break
    return cut


def _plate():
    V, F = holed_plate(3, cells=3)
    return edge_graph(V, F)


@pytest.mark.parametrize("levels", [3, 1000])
def test_the_compiled_spanning_forest_is_kruskals_ties_parallel_edges_and_loops_included(levels):
    """Few weight levels make many ties (broken by the edges' order, as Kruskal's stable sort
    does); repeated pairs and a loop are mixed in."""
    rng = np.random.default_rng(levels)
    n = 300
    a, b = rng.integers(0, n, 2000), rng.integers(0, n, 2000)
    a[:50], b[:50] = b[50:100], a[50:100]  # parallel edges, either way round
    b[100] = a[100]  # a loop
    w = rng.integers(0, levels, len(a)).astype(np.float64)
    keep = seams._max_spanning_forest(n, a, b, w)
    assert np.array_equal(keep, _kruskal(n, a, b, w))
    assert keep.sum() == n - 1 or keep.sum() < n - 1  # a forest: never more than n - 1 edges


def test_the_spanning_forest_of_a_disconnected_graph_spans_each_part():
    a, b = np.array([0, 1, 0, 3, 4]), np.array([1, 2, 2, 4, 5])
    keep = seams._max_spanning_forest(7, a, b, np.array([1.0, 1.0, 5.0, 2.0, 2.0]))
    assert keep.tolist() == [True, False, True, True, True]


def test_layered_pruning_drops_exactly_the_dangling_edges_the_plain_one_drops():
    g = _plate()
    rng = np.random.default_rng(1)
    for p in (0.2, 0.5, 0.8):
        cut = (rng.random(len(g.E)) < p) & ~g.boundary
        kept = (rng.random(len(g.E)) < 0.05) & ~g.boundary & ~cut
        for k in (None, kept):
            assert np.array_equal(seams._prune(g, cut, k), _strip(g, cut, k))


def test_the_topological_cut_is_unchanged_by_the_fast_paths(monkeypatch):
    g = _plate()
    cost = edge_costs(g, 2.0)
    fast = topological_cut(g, cost, [0])
    monkeypatch.setattr(seams, "_max_spanning_forest", _kruskal)
    monkeypatch.setattr(seams, "_prune", _strip)
    assert np.array_equal(fast, topological_cut(g, cost, [0]))
    assert fast.sum() > 0


def test_the_ray_grid_lists_only_the_cells_that_hold_a_ray():
    """Ray casting joins the triangles' grid cells to the rays' (visibility._grid_join): one ray
    pairs only with the triangles whose boxes meet its own cell, not every triangle's cells."""
    from geomopt.atlas import visibility

    V, F = holed_plate(3, cells=3)
    P = V[:, :2][F]
    Q = V[:1, :2] + 1e-3
    tri, first, many, points = visibility._grid_join(P, Q, 2.0)
    assert len(tri) == many.sum() and np.all(points[first] == 0)
    lo, hi = P.min(axis=1), P.max(axis=1)
    around = np.all((lo <= Q[0] + 1.0) & (hi >= Q[0] - 1.0), axis=1)  # boxes within a wide reach of the ray
    assert 0 < len(tri) <= around.sum() < len(F) // 4
    assert set(tri.tolist()) >= set(np.flatnonzero(np.all((lo <= Q[0]) & (hi >= Q[0]), axis=1)).tolist())


def _bumpy_disk(n=24):
    from geomopt.mesh.generators import square_mesh

    X, F = square_mesh(n)
    z = 0.4 * np.exp(-20 * ((X[:, 0] - 0.4) ** 2 + (X[:, 1] - 0.6) ** 2)) - 0.3 * np.exp(
        -30 * ((X[:, 0] - 0.7) ** 2 + (X[:, 1] - 0.3) ** 2))
    V = np.c_[X, z]
    rim = np.flatnonzero((X.min(axis=1) == 0) | (X.max(axis=1) == 1))
    return V, F, rim


def _counting(monkeypatch):
    """The number of sparse Cholesky objects made (each a symbolic analysis) while counted."""
    from geomopt.linalg import linsolve

    made = []

    class Counted(linsolve.SparseCholesky):
        def __init__(self, *args, **kwargs):
            made.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(linsolve, "SparseCholesky", Counted)
    return made


def test_a_charts_conformal_scale_across_cone_cuts_is_log_scales_with_one_analysis(monkeypatch):
    """ChartScale: the cone cuts fix more vertices of the same faces; each later solve equals a
    fresh log_scale (to rounding), and only the first call analyses (makes a factorization)."""
    from geomopt.atlas.cones import ChartScale, log_scale

    V, F, rim = _bumpy_disk()
    ids, faces = np.arange(len(V)), np.arange(len(F))
    made = _counting(monkeypatch)
    scale = ChartScale()
    rng = np.random.default_rng(0)
    inner = np.setdiff1d(np.arange(len(V)), rim)
    boundary = rim
    for cut in range(4):
        u = scale(V, F, boundary, None, ids, faces)
        ref = log_scale(V, F, boundary)
        assert np.allclose(u, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
        assert np.all(u[boundary] == 0.0) and np.abs(u).max() > 0.01
        boundary = np.union1d(boundary, rng.choice(inner, 15, replace=False))  # a cut fixes more
    assert len(made) == 1 + 4  # one SparseCholesky for ChartScale, one per fresh log_scale reference


def test_a_chart_scale_analyses_afresh_for_other_faces_or_a_freed_vertex(monkeypatch):
    from geomopt.atlas.cones import ChartScale, log_scale

    V, F, rim = _bumpy_disk(12)
    ids, faces = np.arange(len(V)), np.arange(len(F))
    scale = ChartScale()
    inner = np.setdiff1d(np.arange(len(V)), rim)
    more = np.union1d(rim, inner[:5])
    ref = log_scale(V, F, rim)
    scale(V, F, more, None, ids, faces)
    made = _counting(monkeypatch)
    u = scale(V, F, rim, None, ids, faces)  # a vertex freed: not a restriction of the first system
    assert len(made) == 1 and np.allclose(u, ref, rtol=0, atol=1e-12)
    scale(V, F, more, None, ids, faces + 1)  # other faces
    assert len(made) == 2
    scale(V, F, np.union1d(more, inner[5:7]), None, ids, faces + 1)  # then more fixed: reused
    assert len(made) == 2


def test_the_greedy_cone_cuts_analyse_each_chart_once(monkeypatch):
    from geomopt.atlas.cutting import relieve

    V, F, _ = _bumpy_disk(30)
    V = V * [1.0, 1.0, 3.0]  # steep bumps: several cone cuts
    g = edge_graph(V, F)
    made = _counting(monkeypatch)
    cut, estimate, cuts = relieve(g, edge_costs(g, 2.0), np.zeros(len(g.E), dtype=bool), 4.05, 6)
    assert cuts >= 3 and cut.sum() > 0
    assert len(made) == 1  # one chart, analysed once for all its estimates

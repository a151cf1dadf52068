"""The atlas's stages stay near-linear in the mesh (issue 50): work that is done per chart, per
seam path or per split touches that chart's or path's part, not the whole mesh again.  Counted
(operations on whole-mesh arrays), not timed."""

from __future__ import annotations

import numpy as np

from geomopt.atlas.charts import ChartSplit
from geomopt.mesh.generators import square_mesh


class _Counted(np.ndarray):
    """An array that counts the ufuncs (comparisons, arithmetic) applied to it whole."""

    calls = 0

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        type(self).calls += 1
        inputs = tuple(np.asarray(x) if isinstance(x, _Counted) else x for x in inputs)
        return getattr(ufunc, method)(*inputs, **kwargs)


def test_every_chart_mesh_of_a_split_costs_one_pass_over_the_faces_not_one_per_chart():
    _, F = square_mesh(24)  # 1058 triangles, in 46 charts of 23 faces
    F = np.asarray(F)
    chart = (np.arange(len(F)) // 23).astype(np.int64)
    rng = np.random.default_rng(0)
    chart = rng.permutation(chart.max() + 1)[chart]  # charts not in face order
    split = ChartSplit(chart.view(_Counted), np.arange(F.size).reshape(F.shape), F.ravel().copy(), int(chart.max()) + 1)
    _Counted.calls = 0
    meshes = [split.mesh(c) for c in range(split.count)]
    assert _Counted.calls <= 2  # a scan of the whole chart array per chart would be 46
    for c, mesh in enumerate(meshes):
        np.testing.assert_array_equal(mesh.faces, np.flatnonzero(np.asarray(chart) == c))
        np.testing.assert_array_equal(mesh.vertices[mesh.F], F[mesh.faces])


def _charts(k, seed):
    """``k`` flip-free disk charts (fine grids, most vertices inside), turned and moved."""
    rng = np.random.default_rng(seed)
    uvs, faces = [], []
    for _ in range(k):
        V, F = square_mesh(int(rng.integers(12, 30)))
        V = V * rng.uniform(0.2, 2.0, size=2)
        a = rng.uniform(0, 2 * np.pi)
        uvs.append(V @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T + rng.normal(size=2))
        faces.append(F)
    return uvs, faces


def test_packing_layouts_see_only_the_charts_boundaries_and_pack_as_with_every_vertex(monkeypatch):
    from geomopt.atlas import _pack, pack_charts
    from geomopt.exact.topology import boundary_half_edges

    uvs, faces = _charts(7, 3)
    seen = []
    layout = _pack._layout

    def counted(U, *args, **kwargs):
        seen.append(sum(len(u) for u in U))
        return layout(U, *args, **kwargs)

    monkeypatch.setattr(_pack, "_layout", counted)
    packed = pack_charts(uvs, faces, margin=0.01)
    boundary = sum(len(np.unique(boundary_half_edges(f))) for f in faces)
    assert packed.efficiency > 0.3 and seen and set(seen) == {boundary}  # far fewer than every vertex
    assert boundary < sum(len(u) for u in uvs) / 3
    # the same layout as from every vertex: the boundary holds every extreme of a flip-free chart
    _packs_as_from_every_vertex(monkeypatch, uvs, faces, packed)


def _packs_as_from_every_vertex(monkeypatch, uvs, faces, packed):
    """``packed`` equals the packing whose layouts are drawn from every vertex of the charts."""
    from geomopt.atlas import _pack, pack_charts

    monkeypatch.setattr(_pack, "_outlines", lambda U, Bs: (U, Bs))
    whole = pack_charts(uvs, faces, margin=0.01)
    assert whole.efficiency == packed.efficiency
    np.testing.assert_array_equal(whole.angles, packed.angles)
    for a, b in zip(whole.uvs, packed.uvs):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_a_short_seam_paths_straightening_search_gathers_only_its_neighbourhood(monkeypatch):
    from geomopt.atlas import seams
    from geomopt.atlas.seams import edge_graph, _TurnGraph

    V, F = square_mesh(61)  # 7200 triangles
    g = edge_graph(np.c_[V, np.zeros(len(V))], F)
    cost = g.length.copy()
    lines = _TurnGraph(g, cost, 3.0)
    gathered = []
    ranges = seams.ranges
    monkeypatch.setattr(seams, "ranges", lambda start, idx: gathered.append(len(idx)) or ranges(start, idx))
    s, t = 30 * 61 + 28, 30 * 61 + 33  # five edges apart along a row, mid-square
    S, T = np.zeros(len(g.V), dtype=bool), np.zeros(len(g.V), dtype=bool)
    S[s], T[t] = True, True
    new = lines.cheapest(S, T, np.zeros(len(g.V), dtype=bool), 5.5 * float(cost.min()) * 1.0001)
    assert new is not None and len(new) == 5 and set(g.E[new].ravel()) == set(range(s, t + 1))
    assert sum(gathered) < 0.02 * (len(lines.tail) + len(g.V))  # not the whole surface's half-edges
    gathered.clear()
    assert lines.cheapest(S, T, np.zeros(len(g.V), dtype=bool), 4.9 * float(cost.min())) is None  # priced above


def _cheapest_unbounded(lines, S, T, on, limit):
    """The price of :meth:`_TurnGraph.cheapest`'s path searched over the whole line graph (no
    neighbourhood gathered first), or None: the reference the bounded search must equal."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    g, tail, head, a, b, edge = lines.g, lines.tail, lines.head, lines.a, lines.b, lines.edge
    ok = ~on[tail] & ~on[head] & ~S[head] & ~T[tail] & ~g.boundary[edge]
    use, start = ok[a] & ok[b], np.flatnonzero(ok & S[tail])
    n = len(tail)
    graph = sp.csr_matrix((np.r_[lines.price[use], lines.cost[edge[start]]] + 1e-300,
                           (np.r_[a[use], np.full(len(start), n)], np.r_[b[use], start])), shape=(n + 1, n + 1))
    dist = dijkstra(graph, indices=n, limit=limit)[:n]
    arrive = np.flatnonzero(T[head] & np.isfinite(dist))
    best = dist[arrive].min(initial=np.inf)
    return None if best >= limit * (1 - 1e-9) else best


def test_the_bounded_straightening_search_finds_what_the_unbounded_one_finds():
    """Gathering only what lies within the price limit of ``S`` (by cost alone) loses no path
    priced below the limit: turns only add to the price.  Costs over six decades, a strong turn
    price, start and end sets of several vertices, vertices to avoid, and limits from tight (no
    path) to loose: the same verdict and the same price as a search over the whole line graph."""
    from geomopt.atlas.seams import _TurnGraph, edge_graph

    rng = np.random.default_rng(7)
    V, F = square_mesh(14)
    g = edge_graph(np.c_[V, 0.05 * rng.normal(size=len(V))], F)
    cost = g.length * 10.0 ** rng.uniform(-3, 3, size=len(g.length))
    found = missed = 0
    for turn in (0.01, 4.0):
        lines = _TurnGraph(g, cost, turn)
        for _ in range(30):
            S, T, on = (np.zeros(len(g.V), dtype=bool) for _ in range(3))
            S[rng.choice(len(g.V), rng.integers(1, 4), replace=False)] = True
            T[rng.choice(np.flatnonzero(~S), rng.integers(1, 4), replace=False)] = True
            on[rng.choice(np.flatnonzero(~S & ~T), 20, replace=False)] = True
            best = _cheapest_unbounded(lines, S, T, on, np.inf)
            if best is None:
                continue
            limit = best * rng.uniform(0.9, 1.1)  # the cheapest path priced just under or over it
            want = _cheapest_unbounded(lines, S, T, on, limit)
            got = lines.cheapest(S, T, on, limit)
            assert (got is None) == (want is None)
            if got is not None:
                assert abs(_path_price_of(lines, got[::-1], S) - want) <= 1e-12 * want
                found += 1
            else:
                missed += 1
    assert found >= 10 and missed >= 10  # both verdicts exercised


def _path_price_of(lines, path, S):
    """The line graph's price of the edge path ``path`` (rows of ``g.E``, from ``S``): the first
    edge's cost, then each pair's price."""
    g = lines.g
    s = next(v for v in g.E[path[0]] if S[v]) if len(path) > 1 else None
    if s is None:
        return float(lines.cost[path[0]])
    halves, v = [], s
    for e in path:
        h = 2 * e if g.E[e, 0] == v else 2 * e + 1
        halves.append(h)
        v = lines.head[h]
    price = float(lines.cost[path[0]])
    for h0, h1 in zip(halves, halves[1:]):
        k = np.flatnonzero((lines.a == h0) & (lines.b == h1))
        price += float(lines.price[k[0]]) + 1e-300
    return price + 1e-300


def _frame(n, seed):
    """A flip-free square frame chart (a grid with a square hole: two boundary loops, most
    vertices inside), turned and moved."""
    V, F = square_mesh(n)
    c = V[F].mean(axis=1)
    F = F[np.abs(c - 0.5).max(axis=1) > 0.2]
    used, F = np.unique(F, return_inverse=True)
    a = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    return V[used] @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T, F.reshape(-1, 3)


def test_packing_charts_with_holes_from_their_boundaries_packs_as_with_every_vertex(monkeypatch):
    """Charts with several boundary loops (frames, turned to their minimum-area rectangle and by
    quarter turns), small ones fitting in a large one's hole: the outer loop holds every
    extreme, the holes are drawn from their loops."""
    from geomopt.atlas import pack_charts

    charts = [_frame(n, n) for n in (26, 9, 9, 9)]  # the small frames fit in the large one's hole
    uvs, faces = [u * (1.0 if i == 0 else 0.3) for i, (u, _) in enumerate(charts)], [f for _, f in charts]
    _packs_as_from_every_vertex(monkeypatch, uvs, faces, pack_charts(uvs, faces, margin=0.01))

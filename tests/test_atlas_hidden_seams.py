"""Hidden, smooth seams (issue 50): the ambient visibility of edges by exact ray casting, the
turning of seams, cut costs that prefer occluded edges, creases and the underside, and seam
paths straightened."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from geomopt._runtime.errors import ParameterError
from geomopt.atlas import AtlasOptions, seam_metrics
from geomopt.atlas.charts import charts_of_cut
from geomopt.atlas.cones import angle_defects
from geomopt.atlas.cutting import cut_surface
from geomopt.atlas.metrics import seam_turning
from geomopt.atlas.seams import edge_costs, edge_graph, straighten
from geomopt.atlas.visibility import (ambient_visibility, edge_visibility, hemisphere_directions,
                                      vertex_normals, vertex_visibility)
from geomopt.exact.topology import unique_edges
from geomopt.mesh.generators import square_mesh

REPO = Path(__file__).resolve().parents[1]


def _grid(nx, ny, height=None):
    """A grid over ``[0, nx] x [0, ny]`` (or over the coordinates ``nx``, ``ny`` when arrays; two
    triangles a cell, upward normals), ``z = height(x, y)``."""
    xs = np.arange(nx + 1.0) if np.isscalar(nx) else np.asarray(nx, dtype=float)
    ys = np.arange(ny + 1.0) if np.isscalar(ny) else np.asarray(ny, dtype=float)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    z = np.zeros_like(x) if height is None else height(x, y)
    V = np.c_[x.ravel(), y.ravel(), z.ravel()]
    i, j = np.meshgrid(np.arange(len(xs) - 1), np.arange(len(ys) - 1), indexing="ij")
    a = (i * len(ys) + j).ravel()
    b, c, d = a + len(ys), a + len(ys) + 1, a + 1
    return V, np.r_[np.c_[a, b, c], np.c_[a, c, d]]


# a groove 3 deep in a plane: walls nearly vertical at x = 5, 6 and y = 1, 5
_XS = [0, 1, 2, 3, 4, 5, 5.001, 5.5, 5.999, 6, 7, 8, 9, 10, 11]
_YS = [0, 1, 1.001, 2, 3, 4, 4.999, 5, 6]


def _groove(x, y):
    return np.where((x > 5) & (x < 6) & (y > 1) & (y < 5), -3.0, 0.0)


def _icosphere(level=2):
    """A unit icosphere (outward normals)."""
    t = (1 + 5 ** 0.5) / 2
    V = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    F = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    V, F = np.array(V, dtype=float), np.array(F)
    for _ in range(level):
        E, _, edge_of = unique_edges(F)
        mid = len(V) + edge_of
        V = np.r_[V, V[E].mean(axis=1)]
        F = np.r_[np.c_[F[:, 0], mid[:, 0], mid[:, 2]], np.c_[F[:, 1], mid[:, 1], mid[:, 0]],
                  np.c_[F[:, 2], mid[:, 2], mid[:, 1]], mid]
    return V / np.linalg.norm(V, axis=1, keepdims=True), F


def _brute_visibility(V, F, points, normals, rays, offset=1e-5):
    """Ambient visibility by Moller-Trumbore against every triangle (the same ray set)."""
    origins = points + offset * np.linalg.norm(np.ptp(V, axis=0)) * normals
    H = hemisphere_directions(rays)
    P0, P1, P2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = P1 - P0, P2 - P0
    out = np.zeros(len(points))
    for p, (o, n) in enumerate(zip(origins, normals)):
        D = np.where((H @ n >= 0)[:, None], H, -H)  # (rays, 3)
        pv = np.cross(D[:, None, :], e2[None])  # (rays, m, 3)
        det = np.sum(e1[None] * pv, axis=2)
        s = o - P0
        u = np.sum(s[None] * pv, axis=2) / det
        q = np.cross(s, e1)
        v = np.sum(D[:, None, :] * q[None], axis=2) / det
        t = np.sum(e2 * q, axis=1)[None] / det
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (det != 0)
        out[p] = np.mean(~hit.any(axis=1))
    return out


def test_hemisphere_directions_are_unit_upward_and_spread():
    H = hemisphere_directions(96)
    assert H.shape == (96, 3)
    assert np.allclose(np.linalg.norm(H, axis=1), 1.0) and (H[:, 2] > 0).all()
    assert abs(H[:, 2].mean() - 0.5) < 1e-12  # equal-area: heights uniform in (0, 1)
    assert np.linalg.norm(H[:, :2].mean(axis=0)) < 0.05  # no side preferred


def test_ray_casting_matches_brute_force_on_a_bumpy_closed_surface():
    V, F = _icosphere(2)
    rng = np.random.default_rng(3)
    V = V * (1 + 0.35 * np.sin(5 * V[:, [0]]) * np.cos(4 * V[:, [1]]))  # concave dents
    N = vertex_normals(V, F)
    pick = rng.choice(len(V), 40, replace=False)
    fast = ambient_visibility(V, F, V[pick], N[pick], rays=48)
    slow = _brute_visibility(V, F, V[pick], N[pick], rays=48)
    assert np.array_equal(fast, slow)
    assert fast.min() < 0.9  # the dents occlude some rays: the test compares something


def test_a_flat_plane_is_fully_visible_and_a_convex_surface_almost():
    V, F = _grid(8, 8)
    E, _, _ = unique_edges(F)
    assert np.all(edge_visibility(V, F, E) == 1.0)
    V, F = _icosphere(2)
    E, _, _ = unique_edges(F)
    vis = edge_visibility(V, F, E)
    assert vis.mean() > 0.99 and vis.min() >= 0.97  # only rays grazing the facets hit


def _capsule(radius, length, sections=12, rings=6):
    """A UV sphere of ``radius`` cut at its equator and its halves pulled ``length`` apart: the
    side is one band of triangles as long as the part, the caps many small ones."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, 2 * rings + 1)[1:-1]
    phi = 2 * np.pi * np.arange(sections) / sections
    z, rr = np.repeat(np.sin(lat), sections) * radius, np.repeat(np.cos(lat), sections) * radius
    V = np.c_[rr * np.tile(np.cos(phi), len(lat)), rr * np.tile(np.sin(phi), len(lat)), z]
    V[z >= 0, 2] += length
    V = np.r_[V, [[0, 0, -radius], [0, 0, radius + length]]]
    ring = lambda i, j: i * sections + j % sections  # noqa: E731
    F = [f for i in range(len(lat) - 1) for j in range(sections)
         for f in ([ring(i, j), ring(i, j + 1), ring(i + 1, j + 1)], [ring(i, j), ring(i + 1, j + 1), ring(i + 1, j)])]
    top = len(lat) - 1
    F += [[len(V) - 2, ring(0, j + 1), ring(0, j)] for j in range(sections)]
    F += [[len(V) - 1, ring(top, j), ring(top, j + 1)] for j in range(sections)]
    return V, np.array(F)


def test_a_few_long_triangles_among_small_ones_keep_visibility_in_bounded_memory():
    """The projections' grid is as fine as the median triangle needs, but never lists more
    (triangle, cell) pairs than a bound: a thin capsule's sides (single triangles as long as the
    part, among the caps' small ones) asked 468 million pairs (19 GB) of a 512-face mesh."""
    import tracemalloc

    V, F = _capsule(0.02, 10.0)
    tracemalloc.start()
    try:
        vis = vertex_visibility(V, F)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 500e6 and np.all(vis == 1.0)  # convex: every ray leaves


def test_the_bottom_of_a_deep_narrow_groove_is_hidden():
    V, F = _grid(_XS, _YS, _groove)
    # the middle of the bottom sees the sky through the slot: |dx| < dz (0.5 / 3), |dy| < dz (2 / 3)
    H = hemisphere_directions(96)
    depth = 3 + 1e-5 * np.linalg.norm(np.ptp(V, axis=0))
    expected = np.mean((np.abs(H[:, 0]) * depth < 0.5 * H[:, 2]) & (np.abs(H[:, 1]) * depth < 2 * H[:, 2]))
    centre = ambient_visibility(V, F, [[5.5, 3.0, -3.0]], [[0.0, 0.0, 1.0]])
    assert 0 < expected < 0.15 and centre[0] == expected
    E, _, _ = unique_edges(F)
    vis = edge_visibility(V, F, E)
    mid = V[E].mean(axis=1)
    bottom = (mid[:, 2] == -3.0) & (mid[:, 1] > 2) & (mid[:, 1] < 4)
    top = (mid[:, 2] == 0.0) & ((mid[:, 0] < 3) | (mid[:, 0] > 8))
    assert bottom.any() and top.any()
    assert vis[bottom].max() < 0.2
    assert vis[top].min() == 1.0


def test_turning_of_straight_zigzag_and_branching_seams():
    V = np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)]
    straight = np.c_[np.arange(5), np.arange(1, 6)]
    assert seam_turning(V, straight) == 0.0
    Z = np.c_[np.arange(6.0), np.arange(6) % 2, np.zeros(6)]  # 45-degree zigzag: turns of 90 degrees
    assert seam_turning(Z, straight) == pytest.approx(90.0)
    T = np.r_[Z, [[2.0, -3.0, 0.0]]]  # a third seam edge at vertex 2: no longer passed through
    turn = seam_turning(T, np.r_[straight, [[2, 6]]])
    assert turn == pytest.approx(90.0)
    assert np.isnan(seam_turning(V, straight[:1]))


def _groove_box():
    """A closed box whose top has the deep narrow groove of :func:`_groove`, normals outward."""
    V, F = _grid(_XS, _YS, _groove)
    nx, ny, n = len(_XS), len(_YS), len(V)
    B = V.copy()
    B[:, 2] = -5.0
    vid = lambda i, j: i * ny + j  # noqa: E731
    loop = ([vid(i, 0) for i in range(nx)] + [vid(nx - 1, j) for j in range(1, ny)]
            + [vid(i, ny - 1) for i in range(nx - 2, -1, -1)] + [vid(0, j) for j in range(ny - 2, 0, -1)])
    side = []
    for a, b in zip(loop, loop[1:] + loop[:1]):
        side += [[a, b + n, b], [a, a + n, b + n]]
    return np.r_[V, B], np.r_[F, F[:, ::-1] + n, np.array(side)]


def test_seam_visibility_ratio_of_hidden_and_exposed_seams():
    V, F = _groove_box()
    E, _, _ = unique_edges(F)
    mid = V[E].mean(axis=1)
    bottom = E[(mid[:, 2] == -3.0) & (mid[:, 1] > 2) & (mid[:, 1] < 4)]
    exposed = E[(mid[:, 2] == 0.0) & (mid[:, 0] > 1) & (mid[:, 0] < 4) & (mid[:, 1] == 3)]
    assert seam_metrics(V, F, bottom, rays=32).visibility < 0.5
    assert seam_metrics(V, F, exposed, rays=32).visibility > 1.0
    assert np.isnan(seam_metrics(V, F, np.zeros((0, 2), dtype=int)).visibility)


def test_occluded_edges_concave_creases_and_the_underside_cost_less():
    V, F = _groove_box()
    g = edge_graph(V, F)
    vis = vertex_visibility(g.V, g.F, 32)
    mid = g.V[g.E].mean(axis=1)
    flat = np.flatnonzero((mid[:, 2] == 0.0) & (mid[:, 0] > 1) & (mid[:, 0] < 4) & (mid[:, 1] > 1)
                          & (mid[:, 1] < 5))
    crease = np.flatnonzero((mid[:, 2] == -3.0) & (mid[:, 1] > 2) & (mid[:, 1] < 4)
                            & ((mid[:, 0] == 5.001) | (mid[:, 0] == 5.999)))
    bottom = np.flatnonzero((mid[:, 2] == -5.0) & (mid[:, 0] > 1) & (mid[:, 0] < 10) & (mid[:, 1] > 0.5)
                            & (mid[:, 1] < 5.5))
    plain = edge_costs(g, 0.0) / g.length
    hidden = edge_costs(g, 0.0, visibility=vis) / g.length
    assert np.allclose(plain[flat], 1.0) and np.allclose(hidden[flat], 1.0)  # exposed: full price
    assert hidden[crease].max() < 0.2  # the groove's inner creases: occluded
    creased = edge_costs(g, 2.0) / g.length
    assert creased[crease].max() < 0.5 * creased[flat].min()
    up = edge_costs(g, 0.0, up=[0.0, 0.0, 1.0]) / g.length
    assert up[bottom].max() < 0.3 and up[flat].min() == pytest.approx(1.0)
    down = edge_costs(g, 0.0, up=[0.0, 0.0, -1.0]) / g.length
    assert down[flat].max() < 0.3


def test_up_and_hide_options_are_checked():
    assert AtlasOptions(up="-y").up == "-y"
    with pytest.raises(ParameterError, match="up"):
        AtlasOptions(up="w")
    with pytest.raises(ParameterError, match="hide"):
        AtlasOptions(hide=-1.0)
    with pytest.raises(ParameterError, match="straighten"):
        AtlasOptions(straighten=-1.0)
    assert AtlasOptions().straighten_packed and not AtlasOptions(straighten_packed=False).straighten_packed
    with pytest.raises(ParameterError, match="straighten_packed"):
        AtlasOptions(straighten_packed="yes")


def _zigzag_cut(g, nx, row):
    """A staircase path of interior edges across a grid from (0, row) to (nx, row)."""
    n = len(g.V)
    keys = g.E[:, 0] * n + g.E[:, 1]
    vid = lambda i, j: i * (nx + 1) + j  # noqa: E731 (the grid of square_mesh is not this one)
    path, j = [], row
    for i in range(nx):
        a, b = vid(i, j), vid(i + 1, j)
        path.append((a, b))
        if i < nx - 2:  # an even number of steps: it ends on its starting row
            step = 1 if i % 2 == 0 else -1
            path.append((b, vid(i + 1, j + step)))
            j += step
    cut = np.zeros(len(g.E), dtype=bool)
    for a, b in path:
        cut[np.searchsorted(keys, min(a, b) * n + max(a, b))] = True
    return cut


def test_straighten_replaces_a_zigzag_by_a_straight_path_keeping_the_charts():
    nx = 10
    V, F = _grid(nx, nx)
    g = edge_graph(V, F)
    cut = _zigzag_cut(g, nx, 4)
    cost = edge_costs(g, 2.0)
    before = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    new = straighten(g, cost, cut, 1.0)
    after = charts_of_cut(g.F, g.edge_of, g.edge_faces, new)
    assert before.count == after.count == 2
    assert all(after.mesh(c).disk_loop() is not None for c in range(2))
    assert seam_turning(g.V, g.E[cut]) > 40
    assert seam_turning(g.V, g.E[new]) < 1e-9
    assert np.array_equal(straighten(g, cost, cut, 0.0), cut)


def _capped_cylinder(n=64, h=5.0):
    """A closed cylinder of one row of side facets (each side edge the full height), each cap a
    fan from one rim vertex: as CAD exports it."""
    t = 2 * np.pi * np.arange(n) / n
    bottom = np.c_[np.cos(t), np.sin(t), np.zeros(n)]
    i, j, k = np.arange(n), (np.arange(n) + 1) % n, np.arange(1, n - 1)
    side = np.stack([np.c_[i, j, n + j], np.c_[i, n + j, n + i]], axis=1).reshape(-1, 3)
    caps = np.stack([np.c_[0 * k, k + 1, k], np.c_[n + 0 * k, n + k, n + k + 1]], axis=1).reshape(-1, 3)
    return np.r_[bottom, bottom + [0.0, 0.0, h]], np.r_[side, caps]


def test_a_lone_interior_edge_is_a_slit_and_straightening_never_makes_one():
    """Cutting one interior edge alone leaves a chart that reads as closed (both sides of the edge
    on the same two vertices): ``slits`` finds it, straightening refuses to shorten a path of two
    edges to the one edge joining its ends, and ``cut_surface`` never returns one (the capped
    cylinder's cheapest seam between its rims, its topological cut, is a single side edge)."""
    from geomopt.atlas.seams import slits

    n = 64
    V, F = _capped_cylinder(n)
    g = edge_graph(V, F)
    index = {tuple(sorted(e)): k for k, e in enumerate(g.E.tolist())}
    i = 5
    side, rim, diagonal = index[(i, n + i)], index[(i - 1, i)], index[(i - 1, n + i)]
    lone = np.zeros(len(g.E), dtype=bool)
    lone[diagonal] = True
    assert np.array_equal(np.flatnonzero(slits(g, lone)), [diagonal])
    path = np.zeros(len(g.E), dtype=bool)
    path[[side, rim]] = True  # a disk of four boundary half-edges; its ends are the diagonal's
    assert not slits(g, path).any()
    cost = edge_costs(g, 0.0)  # no crease preference: the diagonal is the straightest path
    for cut in (path, straighten(g, cost, path, 1.0), cut_surface(g, cost, 4.5, max_cuts=0)[0],
                cut_surface(g, cost, 4.5, turn=1.0)[0]):
        assert cut.any() and not slits(g, cut).any()
        split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
        assert split.count == 1 and split.mesh(0).disk_loop() is not None


def test_make_atlas_of_a_cad_cylinder_is_certified():
    from geomopt.atlas import certify_atlas, make_atlas

    V, F = _capped_cylinder()
    atlas = make_atlas(V, F, progress=False)
    d = atlas.details
    assert atlas.success and certify_atlas(atlas.x, d.uv_faces, d.chart).ok


def test_a_chart_solve_at_its_limit_warns_nothing_beside_the_atlas(monkeypatch):
    """A chart's flattening that stops at its iteration limit is the atlas's to judge (a
    scaffold, a cut, its own message): its MaxStepsWarning printed after a certified atlas
    only alarmed (a red-team sweep's needle-triangle sphere)."""
    import warnings

    import geomopt.param
    from geomopt import MaxStepsWarning
    from geomopt.atlas import make_atlas

    real = geomopt.param.parameterize

    def parameterize(*args, **kwargs):
        warnings.warn("stopped at the limit", MaxStepsWarning, stacklevel=2)
        return real(*args, **kwargs)

    monkeypatch.setattr(geomopt.param, "parameterize", parameterize)
    V, F = _capped_cylinder()
    with warnings.catch_warnings():
        warnings.simplefilter("error", MaxStepsWarning)
        assert make_atlas(V, F, progress=False).success


def test_a_chart_whose_uniform_tutte_map_inverts_by_rounding_is_flattened_from_another_start():
    """The capped cylinder cut along one side edge and one rim edge: a chart of long slivers
    whose uniform Tutte map has inverted triangles in floating point; the chart is still
    flattened (mean-value weights) and certified, instead of the atlas failing."""
    from geomopt.atlas.flatten import flatten_chart
    from geomopt.param import parameterize

    n = 64
    V, F = _capped_cylinder(n)
    g = edge_graph(V, F)
    index = {tuple(sorted(e)): k for k, e in enumerate(g.E.tolist())}
    cut = np.zeros(len(g.E), dtype=bool)
    cut[[index[(45, n + 45)], index[(n + 45, n + 46)]]] = True
    chart = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut).mesh(0)
    Vc = g.V[chart.vertices]
    with pytest.raises(Exception, match="Tutte start map has"):
        parameterize(Vc, chart.F, progress=False)
    res = flatten_chart(Vc, chart.F, "symmetric_dirichlet", None, {})
    assert res.success and res.injectivity == "global"


def test_hidden_costs_make_the_cut_of_a_mesh_less_visible_and_straighter():
    """3holes, cut (topology, cone cuts) with the old costs and with visibility and straightening."""
    from geomopt.io import read_mesh

    V, F = read_mesh(REPO / "geomopt/data/3holes.off")
    g = edge_graph(V, F)
    K = angle_defects(g.V, g.F)
    figures = []
    for vis, turn in ((None, 0.0), (vertex_visibility(g.V, g.F, 32), 3.0)):
        cost = edge_costs(g, 2.0, K, visibility=vis)
        cut = cut_surface(g, cost, 4.5, tree_cost=edge_costs(g, 2.0, visibility=vis), turn=turn)[0]
        figures.append(seam_metrics(g.V, g.F, g.E[cut], rays=32))
    old, new = figures
    assert new.visibility < old.visibility - 0.08
    assert new.turning_degrees < old.turning_degrees


def test_up_puts_the_seams_of_an_atlas_on_the_underside():
    from geomopt.atlas import make_atlas

    V, F = _icosphere(2)
    V = V * [1.0, 1.0, 0.6] + 0.15 * np.sin(3 * V[:, [0]])  # no symmetry to tie the choices
    heights = {}
    for up in ("z", "-z"):
        atlas = make_atlas(V, F, options=AtlasOptions(up=up), progress=False)
        assert atlas.success
        heights[up] = float(V[atlas.details.seams].mean(axis=(0, 1))[2])
    assert heights["z"] < -0.2 < 0.2 < heights["-z"]


def test_the_cli_takes_an_up_axis():
    from geomopt.cli.parser import UsageError, build_parser

    parser = build_parser()
    assert parser.parse_args(["param", "a.off", "-o", "b.obj", "--up=-y"]).up == "-y"
    assert parser.parse_args(["param", "a.off", "-o", "b.obj"]).up is None
    with pytest.raises(UsageError, match="--up"):
        parser.parse_args(["param", "a.off", "-o", "b.obj", "--up", "w"])


def _split_grid(nx, low_rows):
    """A flat grid chart (its own flattening) split into two pieces: the faces whose centroid's
    grid row ``y`` is below ``low_rows(x)`` (x the centroid's column)."""
    from geomopt.atlas.charts import ChartMesh

    V, F = _grid(nx, nx)
    g = edge_graph(V, F)
    mesh = ChartMesh(np.arange(len(F)), F, np.arange(len(V)), np.arange(len(V)))
    c = V[F].mean(axis=1)
    low = c[:, 1] < low_rows(c[:, 0])
    pieces = [mesh.part(np.flatnonzero(side)) for side in (low, ~low)]
    return g, mesh, V[:, :2], [(p, V[rows, :2]) for p, rows in pieces]


def _border(mesh, pieces):
    """The interior edges (vertex pairs) between the pieces of a chart."""
    label = np.empty(len(mesh.F), dtype=np.int64)
    for k, (p, _) in enumerate(pieces):
        label[np.searchsorted(mesh.faces, p.faces)] = k
    g = edge_graph(np.zeros((len(mesh.vertices), 3)), mesh.F)
    inner = ~g.boundary
    f1, f2 = g.edge_faces[inner, 0], g.edge_faces[inner, 1]
    return mesh.vertices[g.E[inner][label[f1] != label[f2]]]


def test_a_packing_split_is_straightened_along_the_surface_keeping_its_coordinates():
    """A split across a flattened chart that zigzags (as a straight line in the plane does across
    an irregular mesh) becomes a straight border; each piece keeps its faces' coordinates."""
    from geomopt.atlas.seams import straighten_split

    nx = 11
    g, mesh, x, pieces = _split_grid(nx, lambda cx: 4.0 + (np.floor(cx) % 2))  # rows 4 and 5 alternate
    cost = edge_costs(g, 2.0)
    assert seam_turning(g.V, _border(mesh, pieces)) > 40
    new = straighten_split(g, cost, mesh, x, pieces, 1.0)
    assert len(new) == 2 and all(p.disk_loop() is not None for p, _ in new)
    assert sorted(np.r_[new[0][0].faces, new[1][0].faces].tolist()) == list(range(len(g.F)))
    for p, xp in new:
        assert np.array_equal(xp, x[p.vertices])  # the chart's own coordinates
    assert seam_turning(g.V, _border(mesh, new)) < 1e-9
    assert straighten_split(g, cost, mesh, x, pieces, 0.0) is pieces


def test_a_packing_split_moves_to_the_hidden_row_of_the_surface():
    """The seam cost decides where a split's border runs: with the edges of one grid row
    occluded (cheap), the straight split two rows away moves onto it."""
    from geomopt.atlas.seams import straighten_split

    nx = 10
    g, mesh, x, pieces = _split_grid(nx, lambda cx: np.full_like(cx, 4.0))  # border on row 4
    visibility = np.where(np.isclose(g.V[:, 1], 6.0), 0.2, 1.0)  # row 6 hidden
    cost = edge_costs(g, 2.0, visibility=visibility, hide=2.0)
    new = straighten_split(g, cost, mesh, x, pieces, 1.0)
    border = _border(mesh, new)
    assert len(border) and np.allclose(g.V[border][..., 1], 6.0)
    assert len(new) == 2 and all(p.disk_loop() is not None for p, _ in new)


def test_the_borders_of_every_split_chart_are_straightened_and_the_pieces_regrouped():
    """straighten_splits: each chart's pieces together, in chart order, a zigzag border made
    straight, a chart of one piece left as it is."""
    from geomopt.atlas.seams import straighten_splits

    nx = 11
    g, mesh, x, pieces = _split_grid(nx, lambda cx: 4.0 + (np.floor(cx) % 2))
    whole = _split_grid(nx, lambda cx: np.full_like(cx, -1.0))[3]  # one piece: all faces
    whole = [p for p in whole if len(p[0].faces)]
    cost = edge_costs(g, 2.0)
    out, owner, changed = straighten_splits(g, cost, [mesh, mesh], [x, x], [1, 0, 1],
                                            [pieces[0], whole[0], pieces[1]], 1.0)
    assert changed and owner == [0, 1, 1] and out[0] is whole[0]
    assert seam_turning(g.V, _border(mesh, out[1:])) < 1e-9
    same = straighten_splits(g, cost, [mesh], [x], [0, 0], pieces, 0.0)
    assert not same[2] and same[0] == pieces


def test_sampled_vertex_visibility_is_cast_from_an_independent_set_and_close_to_the_full_one():
    from geomopt.atlas.visibility import independent_vertices

    V, F = _icosphere(3)
    V = V * (1 + 0.35 * np.sin(5 * V[:, [0]]) * np.cos(4 * V[:, [1]]))
    E, _, _ = unique_edges(F)
    chosen = independent_vertices(len(V), E)
    assert not (chosen[E[:, 0]] & chosen[E[:, 1]]).any()  # independent
    near = chosen.copy()
    near[E[chosen[E[:, 0]], 1]] = near[E[chosen[E[:, 1]], 0]] = True
    assert near.all()  # maximal: every vertex chosen or next to a chosen one
    assert chosen.mean() < 0.35
    full = vertex_visibility(V, F, 32)
    sampled = vertex_visibility(V, F, 32, sampled=True)
    assert np.array_equal(sampled[chosen], full[chosen])
    assert full.min() < 0.8 and np.abs(sampled - full).mean() < 0.05


def test_a_cone_cut_ends_at_the_candidate_cheapest_to_reach():
    """cut_path_to_seams from several candidate cone vertices (those about as shrunk as the
    most shrunk one) runs from the one the seam cost reaches most cheaply: with a hidden
    (cheap) column, from the candidate on it, though a farther one by length."""
    from geomopt.atlas.seams import cut_path_to_seams

    V, F = _grid(8, 8)
    g = edge_graph(V, F)
    vid = lambda i, j: i * 9 + j  # noqa: E731
    seams = np.array([vid(i, 0) for i in range(9)])  # the row y = 0
    visibility = np.where(np.isclose(g.V[:, 0], 6.0), 0.1, 1.0)  # the column x = 6 hidden
    cost = edge_costs(g, 0.0, visibility=visibility, hide=2.0)
    near, hidden = vid(2, 4), vid(6, 5)
    path = cut_path_to_seams(g, cost, [near, hidden], seams)
    assert hidden in g.E[path] and near not in g.E[path]
    assert np.allclose(g.V[g.E[path]][..., 0], 6.0)
    assert cut_path_to_seams(g, cost, near, seams) == cut_path_to_seams(g, cost, [near], seams)


def test_a_charts_cone_candidates_are_its_vertices_about_as_shrunk_as_the_most(monkeypatch):
    """chart_estimate's candidates: the most shrunk interior vertex and every interior vertex
    whose log area scale is within _CONE_SLACK of it (a bump's top ring, not only its apex)."""
    from geomopt.atlas import cutting
    from geomopt.atlas.cones import log_scale, scale_estimate

    monkeypatch.setattr(cutting, "_CONE_SLACK", 0.25)

    ticks = np.linspace(0.0, 12.0, 37)
    V, F = _grid(ticks, ticks, lambda x, y: 4.0 * np.exp(-((x - 6) ** 2 + (y - 6) ** 2) / 6.0))
    g = edge_graph(V, F)
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, np.zeros(len(g.E), dtype=bool))
    mesh = split.mesh(0)
    mean, area, vertex, near = cutting.chart_estimate(g, mesh, g.boundary)
    loop = np.unique(g.E[g.boundary])
    log_area = scale_estimate(g.V, g.F, log_scale(g.V, g.F, loop))[1]
    inner = np.setdiff1d(np.arange(len(g.V)), loop)
    least = log_area[inner].min()
    assert vertex == inner[np.argmin(log_area[inner])] and vertex in near
    expected = inner[log_area[inner] <= least + cutting._CONE_SLACK]
    assert 1 < len(near) < len(inner) and np.array_equal(np.sort(near), np.sort(mesh.vertices[np.searchsorted(
        mesh.vertices, expected)]))


def test_a_cone_cut_starts_from_a_hidden_candidate_not_the_exposed_apex(monkeypatch):
    """relieve: on a bump whose apex is exposed and whose column beside it is hidden, the one
    cone cut runs down the hidden column from the apex's neighbour (as shrunk, within
    _CONE_SLACK), not from the apex."""
    from geomopt.atlas import cutting
    from geomopt.atlas.cutting import relieve

    monkeypatch.setattr(cutting, "_CONE_SLACK", 0.25)
    ticks = np.linspace(0.0, 12.0, 37)
    V, F = _grid(ticks, ticks, lambda x, y: 4.0 * np.exp(-((x - 6) ** 2 + (y - 6) ** 2) / 6.0))
    g = edge_graph(V, F)
    column = np.isclose(g.V[:, 0], ticks[19]) & (g.V[:, 1] <= 6.0 + 1e-9)
    cost = edge_costs(g, 0.0, visibility=np.where(column, 0.05, 1.0), hide=2.0)
    cut, _, made = relieve(g, cost, np.zeros(len(g.E), dtype=bool), 4.0001, 1)
    apex = int(np.argmax(g.V[:, 2]))
    assert made == 1 and cut.any()
    assert apex not in g.E[cut] and column[g.E[cut]].all()


def _packed_split(blocker=None, rows=lambda cx: 4.0 + (np.floor(cx / 2) % 2)):
    """A split grid (11 x 11; ``rows`` as :func:`_split_grid`'s, by default a zigzag whose
    straightened border runs on row 4 or 5) packed by hand: the pieces 1/30 the grid's size,
    apart in the unit square, unrotated; and, when ``blocker`` ``(k, point)`` is given, a third
    chart, a small triangle at ``point`` of the grid in the frame of piece ``k``."""
    from geomopt.atlas import Packing
    from geomopt.atlas.charts import ChartMesh

    g, mesh, x, pieces = _split_grid(11, rows)  # by default notches 2 cells wide
    meshes, maps = [p for p, _ in pieces], [xp for _, xp in pieces]
    scale, offsets = 1.0 / 30.0, np.array([[0.05, 0.05], [0.05, 0.55]])
    uvs = [scale * xp + o for xp, o in zip(maps, offsets)]
    if blocker is not None:
        k, point = blocker
        tri = point + 0.1 * np.array([[-1.0, -0.5], [1.0, -0.5], [0.0, 1.0]])
        meshes.append(ChartMesh(np.array([len(g.F)]), np.array([[0, 1, 2]]), np.arange(3), np.arange(3)))
        maps.append(tri)
        uvs.append(scale * tri + offsets[k])
        offsets = np.r_[offsets, offsets[k:k + 1]]
    packing = Packing(uvs, scale, np.zeros(len(uvs)), offsets, 0.0)
    return g, mesh, x, meshes, maps, packing


def _as_atlas(meshes, uvs):
    sizes = np.array([len(u) for u in uvs])
    F = np.concatenate([m.F + s for m, s in zip(meshes, np.cumsum(sizes) - sizes)])
    return np.concatenate(uvs), F, np.repeat(np.arange(len(meshes)), [len(m.F) for m in meshes])


def test_a_packed_split_is_straightened_in_place_keeping_each_pieces_motion():
    """straighten_packed: the zigzag border between two packed pieces becomes straight, each
    piece keeping its packed rotation and translation (a face that changes piece takes the
    other's), the atlas certified; its pieces' total area, so the efficiency, unchanged."""
    from geomopt.atlas import certify_atlas
    from geomopt.atlas.packed_splits import straighten_packed
    from geomopt.mesh.quality import triangle_areas

    g, mesh, x, meshes, maps, packing = _packed_split()
    cost = edge_costs(g, 2.0)
    before = [(m, xp) for m, xp in zip(meshes, maps)]
    assert seam_turning(g.V, _border(mesh, before)) > 40
    out, out_x, uvs, moved = straighten_packed(g, cost, [mesh], [x], [0, 0], meshes, maps, packing, 0.005, 1.0)
    assert moved == 1 and certify_atlas(*_as_atlas(out, uvs)).ok
    assert seam_turning(g.V, _border(mesh, list(zip(out, out_x)))) < 1e-9
    for m, xp, u, o in zip(out, out_x, uvs, packing.offsets):
        assert np.array_equal(xp, x[m.vertices]) and np.allclose(u, packing.scale * xp + o, atol=1e-15)
    area = lambda ms, us: sum(triangle_areas(u[m.F]).sum() for m, u in zip(ms, us))  # noqa: E731
    assert np.isclose(area(out, uvs), area(meshes, packing.uvs))
    assert straighten_packed(g, cost, [mesh], [x], [0, 0], meshes, maps, packing, 0.005, 0.0)[3] == 0


def test_a_packed_split_stays_as_packed_where_its_straight_border_would_overlap(monkeypatch):
    """A chart packed where a straightened border's faces would land (in the frame of the
    piece they join): the border goes straight the other way round it, and the atlas stays
    certified (no overlap), by the exact check even when the screen of where faces may go
    lets every edge through (the border then stays as packed)."""
    from geomopt.atlas import certify_atlas
    from geomopt.atlas import packed_splits
    from geomopt.atlas.packed_splits import straighten_packed

    g, mesh, x, meshes, maps, packing = _packed_split()
    cost = edge_costs(g, 2.0)
    out = straighten_packed(g, cost, [mesh], [x], [0, 0], meshes, maps, packing, 0.005, 1.0)[0]
    k = next(i for i in range(2) if not np.isin(out[i].faces, meshes[i].faces).all())  # the piece that grew
    face = out[k].faces[~np.isin(out[k].faces, meshes[k].faces)][0]
    g, mesh, x, meshes, maps, packing = _packed_split((k, g.V[g.F[face], :2].mean(axis=0)))
    assert certify_atlas(*_as_atlas(meshes, packing.uvs)).ok  # the blocker sits in the gap as packed
    args = (g, cost, [mesh, mesh], [x, x], [0, 0, 1], meshes, maps, packing, 0.005, 1.0)
    out, out_x, uvs, moved = straighten_packed(*args)
    assert certify_atlas(*_as_atlas(out, uvs)).ok
    assert moved == 1 and not np.isin(face, out[k].faces)  # rerouted around the blocker, on the other row
    assert seam_turning(g.V, _border(mesh, list(zip(out[:2], out_x[:2])))) < 1e-9
    monkeypatch.setattr(packed_splits, "_movable", lambda g, *a: np.ones(len(g.E), dtype=bool))
    out, out_x, uvs, moved = straighten_packed(*args)
    assert moved == 0 and all(a is b for a, b in zip(out, meshes))
    assert certify_atlas(*_as_atlas(out, uvs)).ok


def test_a_packed_split_border_is_not_made_longer():
    """A straight border whose cheapest reroute is a detour through a hidden U (longer on the
    surface, at any turning price) stays as packed."""
    from geomopt.atlas.packed_splits import straighten_packed
    from geomopt.atlas.seams import straighten_split

    g, mesh, x, meshes, maps, packing = _packed_split(rows=lambda cx: np.full_like(cx, 4.0))
    X, Y = g.V[:, 0], g.V[:, 1]
    hidden = (np.isin(X, [3.0, 8.0]) & (Y >= 4) & (Y <= 7)) | ((Y == 7) & (X >= 3) & (X <= 8))
    cost = edge_costs(g, 2.0, visibility=np.where(hidden, 0.05, 1.0), hide=2.0)
    new = straighten_split(g, cost, mesh, x, list(zip(meshes, maps)), 1.0)
    assert len(_border(mesh, new)) > len(_border(mesh, list(zip(meshes, maps))))  # the detour is longer
    out, _, uvs, moved = straighten_packed(g, cost, [mesh], [x], [0, 0], meshes, maps, packing, 0.005, 1.0)
    assert moved == 0 and all(a is b for a, b in zip(out, meshes))


def test_closer_than_measures_segment_sets_at_their_ends():
    from geomopt.atlas.packed_splits import closer_than

    S = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    T = np.array([[[0.5, 0.01], [0.5, 2.0]]])  # a T: its end 0.01 above S's middle
    assert closer_than(S, T, 0.02) and closer_than(T, S, 0.02)
    assert not closer_than(S, T, 0.005)
    assert not closer_than(S, np.zeros((0, 2, 2)), 1.0)


def test_make_atlas_straightens_a_packed_split_in_place():
    """On a holed plate that a packing split cuts in two (its straightened border repacks
    worse, so it is not kept), the in-place straightening shortens and straightens the seams at
    the same charts, distortion and efficiency, certified."""
    from geomopt.atlas import make_atlas
    from geomopt.mesh import generators

    V, F = generators.holed_plate(2, cells=6)
    on, off = (make_atlas(V, F, options=AtlasOptions(straighten_packed=s), progress=False) for s in (True, False))
    a, b = on.details.metrics, off.details.metrics
    assert on.success and off.success and on.certificate.ok
    assert a.charts == b.charts and a.mean_symmetric_dirichlet == pytest.approx(b.mean_symmetric_dirichlet, rel=1e-12)
    assert a.efficiency == pytest.approx(b.efficiency, rel=1e-12)  # the same placements (up to rounding)
    V3 = np.c_[V, np.zeros(len(V))]
    assert a.seam_length < b.seam_length - 1.0
    assert seam_turning(V3, on.details.seams) < seam_turning(V3, off.details.seams) - 1.0

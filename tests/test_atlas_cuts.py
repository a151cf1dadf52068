"""The topological cut of a closed surface with handles: the root of its system of loops is chosen
to make the cut cheapest (issue 31)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from geomopt.atlas.cones import angle_defects
from geomopt.atlas.charts import charts_of_cut
from geomopt.atlas.seams import edge_costs, edge_graph, shortest_topological_cut, topological_cut
from geomopt.mesh.generators import holed_plate


def _labels(g):
    from geomopt.exact.topology import connected_components

    return connected_components(g.F, len(g.V))[1]


def _plates():
    """Two genus-5 plates side by side (two closed components)."""
    V, F = holed_plate(5, cells=3)
    return edge_graph(np.r_[V, V + [0.0, 20.0, 0.0]], np.r_[F, F + len(V)])


def test_the_cheapest_root_opens_each_handle_body_into_one_disk_more_cheaply():
    g = _plates()
    cost = edge_costs(g, 2.0, angle_defects(g.V, g.F))
    labels = _labels(g)
    roots = np.array([0, len(g.V) // 2])  # the first vertex of each plate: a corner, far from most holes
    old = topological_cut(g, cost, roots)
    new = shortest_topological_cut(g, cost, labels, roots)
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, new)
    assert split.count == 2
    assert all(split.mesh(c).disk_loop() is not None for c in range(2))
    comp = labels[g.E[:, 0]]
    for k in range(2):
        here = comp == labels[roots[k]]
        assert cost[new & here].sum() < cost[old & here].sum() - 1e-9
        assert g.length[new & here].sum() < g.length[old & here].sum()


def test_closed_spheres_beside_handle_bodies_take_no_root_search_and_change_no_cut(monkeypatch):
    """A closed genus-0 component's topological cut is empty from any root, so the search for
    the cheapest roots spreads candidates over the handle bodies only (a scene of many small
    closed parts spent most of its cut there), and the plates' cut is the one they get alone."""
    import geomopt.atlas.seams as seams

    plates = _plates()
    ball = trimesh.creation.icosphere(subdivisions=2)
    balls = [np.asarray(ball.vertices) * 2.0 + [40.0 + 10.0 * k, 0.0, 0.0] for k in range(3)]
    n = len(plates.V)
    F = np.r_[plates.F, *[np.asarray(ball.faces) + n + k * len(ball.vertices) for k in range(3)]]
    g = edge_graph(np.r_[plates.V, *balls], F)
    labels = _labels(g)
    roots = np.unique(labels, return_index=True)[1]
    spread = seams._spread_roots
    searched = []

    def spy(g_, cost_, labels_, roots_, tries):
        searched.append(np.asarray(roots_).copy())
        return spread(g_, cost_, labels_, roots_, tries)

    monkeypatch.setattr(seams, "_spread_roots", spy)
    cut = shortest_topological_cut(g, edge_costs(g, 2.0, angle_defects(g.V, g.F)), labels, roots)
    assert len(searched) == 1 and sorted(labels[searched[0]]) == sorted(set(labels[plates.F[:, 0]]))
    alone = shortest_topological_cut(plates, edge_costs(plates, 2.0, angle_defects(plates.V, plates.F)),
                                     _labels(plates), np.array([0, n // 2]))
    assert not cut[len(plates.E):].any()  # the balls' edges come after the plates' (sorted by vertex)
    assert np.array_equal(cut[:len(plates.E)], alone)
    searched.clear()
    only_balls = edge_graph(np.r_[*balls], F[len(plates.F):] - n)
    assert not shortest_topological_cut(only_balls, edge_costs(only_balls, 2.0), _labels(only_balls),
                                        np.unique(_labels(only_balls), return_index=True)[1]).any()
    assert not searched


def test_strong_cones_joined_by_a_tree_open_a_cad_part_nearly_isometrically_with_less_seam():
    """Every corner of a holed plate is a cone of +-90 degrees: the greedy cone cuts alone stall
    above the target (estimate 4.71, seam 69); joining the corners by a cheap tree before the
    system of loops reaches it with a shorter seam, and every chart stays a disk."""
    from geomopt.atlas.cutting import cut_surface, strong_cones
    from geomopt.atlas.seams import steiner_tree

    V, F = holed_plate(2, cells=2)
    g = edge_graph(V, F)
    cost = edge_costs(g, 2.0, angle_defects(g.V, g.F))
    cones = strong_cones(g)
    assert len(cones) == 8 + 8 * 2
    tree = steiner_tree(g, edge_costs(g, 2.0), cones, _labels(g))
    assert np.isin(cones, g.E[tree].ravel()).all()
    cut, estimate, _ = cut_surface(g, cost, 4.5, tree_cost=edge_costs(g, 2.0))
    assert estimate <= 4.5
    assert g.length[cut].sum() <= 50.0
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    assert all(split.mesh(c).disk_loop() is not None for c in range(split.count))


def _open_box():
    """A subdivided cube without its top: a disk of five flat sides."""
    import trimesh

    m = trimesh.creation.box().subdivide().subdivide()
    V, F = np.asarray(m.vertices), np.asarray(m.faces)
    F = F[~(V[F][:, :, 2] > 0.49).all(axis=1)]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def test_normal_regions_finds_the_flat_sides_of_an_open_box():
    from geomopt.atlas.regions import normal_regions
    from geomopt.exact.topology import check_disk

    V, F = _open_box()
    piece = normal_regions(V, F, 5)
    assert piece is not None and piece.max() == 4
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N /= np.linalg.norm(N, axis=1)[:, None]
    for p in range(5):
        sel = F[piece == p]
        assert np.ptp(N[piece == p], axis=0).max() < 1e-9  # one flat side each
        used, local = np.unique(sel, return_inverse=True)
        check_disk(local.reshape(-1, 3), len(used))


def _bumpy_sphere():
    """A coarse icosphere with strong bumps: its curvature is spread over many vertices, so cone
    cuts relieve little and the charts must be split into nearly developable pieces."""
    import trimesh

    s = trimesh.creation.icosphere(1)
    P = np.asarray(s.vertices)
    r = 1 + 0.6 * np.sin(6 * P[:, 0]) * np.sin(6 * P[:, 1]) * np.sin(6 * P[:, 2])
    return P * r[:, None] * [1.0, 1.3, 0.8], np.asarray(s.faces)


def test_charts_above_the_goal_without_cone_cuts_left_are_split_into_developable_pieces():
    from geomopt.atlas.cutting import cut_surface
    from geomopt.atlas.flatten import flatten_chart, flatten_to

    g = edge_graph(*_bumpy_sphere())
    cost = edge_costs(g, 2.0, angle_defects(g.V, g.F))
    cut, estimate, _ = cut_surface(g, cost, 4.2, max_cuts=0)  # the topological cut only

    def solve(Vc, Fc, free=None, scaffold=True):
        return flatten_chart(Vc, Fc, "symmetric_dirichlet", None, {}, free=free, scaffold=scaffold)

    said = []
    new, split, meshes, results = flatten_to(g, cost, cut, estimate, 4.01, solve, 0,
                                             lambda stage, **info: said.append((stage, info)))
    flat = [i["mean_symmetric_dirichlet"] for s, i in said if s == "flattened"]
    splits = [i for s, i in said if s == "split"]
    assert splits and all(i["rate"] >= 0.06 for i in splits)
    assert splits[-1]["mean_symmetric_dirichlet"] < flat[0] - 0.05
    assert split.count == splits[-1]["charts"] > 1 and (new >= cut).all()
    assert all(r.success for r in results) and all(m.disk_loop() is not None for m in meshes)


def test_trim_keeps_the_estimate_of_every_chart_at_the_target():
    """Two holed plates in one mesh (two charts): each uncut path changes one chart's gluing but
    not its faces, so an estimate cached by faces went stale and later trims counted the trimmed
    chart at its old, lower estimate (the result 4.95 for a target of 4.5)."""
    from geomopt.atlas.cutting import chart_estimate, strong_cones, trim
    from geomopt.atlas.seams import steiner_tree

    (V1, F1), (V2, F2) = holed_plate(2, cells=2), holed_plate(3, cells=2)
    V, F = np.vstack([V1, V2 + [0.0, 20.0, 0.0]]), np.vstack([F1, F2 + len(V1)])
    g = edge_graph(V, F)
    cost = edge_costs(g, 2.0, angle_defects(g.V, g.F))
    tree = steiner_tree(g, edge_costs(g, 2.0), strong_cones(g), _labels(g))
    labels = _labels(g)
    cut = shortest_topological_cut(g, cost, labels, np.unique(labels, return_index=True)[1], opened=tree)
    for target in (4.5, 4.8):
        trimmed = trim(g, cut, target)
        assert trimmed.sum() < cut.sum()
        split = charts_of_cut(g.F, g.edge_of, g.edge_faces, trimmed)
        rows = np.array([chart_estimate(g, split.mesh(c), trimmed | g.boundary)[:2] for c in range(split.count)])
        assert split.count == 2 and rows[:, 0] @ rows[:, 1] / rows[:, 1].sum() <= target + 1e-9


def test_a_charts_estimate_takes_its_boundary_from_the_seams_and_refuses_a_non_disk():
    """chart_estimate finds a chart's boundary where its faces meet the seams (no topology check:
    the Euler characteristic is counted) and gives the estimate of the chart's own boundary loop
    (check_disk's); a chart that is not a disk (an annulus: a torus cut along one loop) is refused."""
    from geomopt.atlas.cones import log_scale, scale_estimate
    from geomopt.atlas.cutting import chart_estimate, relieve
    from geomopt.exact.topology import check_disk

    t = trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12)
    g = edge_graph(np.asarray(t.vertices), np.asarray(t.faces))
    cost = edge_costs(g, 2.0, angle_defects(g.V, g.F))
    labels = _labels(g)
    cut = shortest_topological_cut(g, cost, labels, np.unique(labels, return_index=True)[1])
    cut, _, made = relieve(g, cost, cut, 4.0, 3)  # a slit or more inside the chart too
    assert made > 0
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    for c in range(split.count):
        mesh = split.mesh(c)
        Vc = g.V[mesh.vertices]
        expected = scale_estimate(Vc, mesh.F, log_scale(Vc, mesh.F, check_disk(mesh.F, len(mesh.wedges))))[0]
        assert chart_estimate(g, mesh, cut | g.boundary)[0] == pytest.approx(expected, rel=1e-9)
    from geomopt.mesh.generators import square_mesh

    V, F = square_mesh(9)  # a flat annulus: the faces around the centre removed
    F = F[np.linalg.norm(V[F].mean(axis=1) - 0.5, axis=1) > 0.2]
    used, F = np.unique(F, return_inverse=True)
    a = edge_graph(np.c_[V[used], np.zeros(len(used))], F.reshape(-1, 3))
    none = np.zeros(len(a.E), dtype=bool)
    with pytest.raises(RuntimeError, match="not a disk"):
        chart_estimate(a, charts_of_cut(a.F, a.edge_of, a.edge_faces, none).mesh(0), a.boundary)


def test_a_level_that_starts_from_the_same_cut_is_not_relieved_again(monkeypatch):
    """cut_surface relieves the topological cut of each level of strong cones; on a smooth torus
    there is no strong cone to join, both levels start from the same cut, and the second
    relieving (tens of estimates on a large mesh) would repeat the first."""
    from geomopt.atlas import cutting

    t = trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12)
    g = edge_graph(np.asarray(t.vertices), np.asarray(t.faces))
    cost = edge_costs(g, 2.0, angle_defects(g.V, g.F))
    assert not len(cutting.strong_cones(g))
    calls = []
    real = cutting.relieve
    monkeypatch.setattr(cutting, "relieve", lambda *a, **k: calls.append(1) or real(*a, **k))
    cut, estimate, _ = cutting.cut_surface(g, cost, 4.3)
    assert len(calls) == 1 and cut.any() and estimate > 4.0


def test_the_scale_estimate_holds_scales_beyond_floating_point_range():
    """A long chart's conformal scales span more than exp's range: the estimate is computed in
    logs (finite log area, an infinite mean, no warning), and equals the direct formula where
    that is finite."""
    import warnings

    from geomopt.atlas.cones import scale_estimate
    from geomopt.mesh.generators import square_mesh

    V, F = square_mesh(6)
    V3 = np.c_[V, np.zeros(len(V))]
    u = np.linspace(-0.3, 0.2, len(V))
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    A = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    s = np.exp(2 * u[F].mean(axis=1))
    c = np.sqrt(np.sum(A / s) / np.sum(A * s))
    mean, log_area = scale_estimate(V3, F, u)
    assert mean == pytest.approx(np.sum(A * 2 * (c * s + 1 / (c * s))) / A.sum(), rel=1e-12)
    np.testing.assert_allclose(log_area, 2 * u + np.log(c), rtol=1e-12, atol=1e-14)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mean, log_area = scale_estimate(V3, F, 800.0 * np.linspace(-1.0, 1.0, len(V)))
    assert mean == np.inf and np.isfinite(log_area).all()

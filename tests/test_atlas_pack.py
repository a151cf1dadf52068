"""Chart packing (geomopt.atlas.pack_charts) and the exact atlas certificate (certify_atlas)."""

import numpy as np
import pytest

from geomopt.mesh import generators as g
from geomopt._runtime.errors import MeshError, ParameterError
from geomopt.atlas import AtlasCertificate, certify_atlas, chart_boundary_loops, pack_charts
from geomopt.exact.certify import loop_crossings
from geomopt.exact.predicates import orient2d

# ------------------------------------------------------------------ chart zoo


def _keep(V, F, keep):
    """The faces ``F[keep]`` with their vertices renumbered."""
    F = F[keep]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def grid_chart(rng):
    V, F = g.square_mesh(int(rng.integers(3, 9)))
    return V * [rng.uniform(0.3, 2.0), rng.uniform(0.3, 2.0)], F


def strip_chart(rng):
    V, F = g.square_mesh(6)
    return V * [rng.uniform(1.0, 3.0), rng.uniform(0.02, 0.08)], F


def l_chart(rng):
    V, F = g.square_mesh(9)
    c = V[F].mean(axis=1)
    return _keep(V * rng.uniform(0.5, 2.0), F, ~((c[:, 0] > 0.5) & (c[:, 1] > 0.5)))


def star_chart(rng, n_r=5, n_t=40):
    """A polar grid (centre fan, then rings) whose rays are scaled by a positive function of
    the angle: every triangle keeps two vertices on one ray and one on the next, so it stays
    counter-clockwise."""
    arms, depth = int(rng.integers(3, 8)), rng.uniform(0.2, 0.7)
    t = 2 * np.pi * np.arange(n_t) / n_t
    f = 1 - depth * 0.5 * (1 + np.cos(arms * t))
    r = np.arange(1, n_r + 1) / n_r
    V = np.concatenate([[[0.0, 0.0]], (np.outer(r, f)[..., None] * np.stack([np.cos(t), np.sin(t)], 1)).reshape(-1, 2)])
    j = np.arange(n_t)
    F = [np.stack([np.zeros(n_t, np.int64), 1 + j, 1 + (j + 1) % n_t], 1)]
    for i in range(n_r - 1):
        a, b = 1 + i * n_t + j, 1 + i * n_t + (j + 1) % n_t
        F += [np.stack([a, a + n_t, b + n_t], 1), np.stack([a, b + n_t, b], 1)]
    return V * rng.uniform(0.2, 1.5), np.concatenate(F)


def disk_chart(rng):
    V, F = g.disk_mesh(int(rng.integers(2, 6)))
    return V * rng.uniform(0.2, 1.5), F


def annulus(r0, r1, turn, n_t=48, n_r=3):
    """An annular sector from angle 0 to ``turn`` (radians): a closed ring for ``turn = 2 pi``."""
    closed = np.isclose(turn, 2 * np.pi)
    m = n_t if closed else n_t + 1
    t = np.linspace(0, turn, m, endpoint=not closed)
    r = np.linspace(r0, r1, n_r)
    V = np.stack([np.outer(r, np.cos(t)).ravel(), np.outer(r, np.sin(t)).ravel()], 1)
    F = []
    for i in range(n_r - 1):
        for j in range(n_t):
            a, b = i * m + j, i * m + (j + 1) % m
            F += [[a, b + m, b], [a, a + m, b + m]]
    return V, np.array(F, dtype=np.int64)


def ring_chart(rng):
    """A chart with a hole (smaller charts may be packed into it)."""
    V, F = annulus(rng.uniform(0.3, 0.7), 1.0, 2 * np.pi, n_t=24)
    return V * rng.uniform(0.5, 1.5), F


ZOO = (grid_chart, strip_chart, l_chart, star_chart, disk_chart, ring_chart)


def random_charts(k, seed):
    """``k`` charts of the zoo, each turned by a random angle and moved anywhere."""
    rng = np.random.default_rng(seed)
    uvs, faces = [], []
    for _ in range(k):
        V, F = ZOO[int(rng.integers(len(ZOO)))](rng)
        a = rng.uniform(0, 2 * np.pi)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        V = V @ R.T + rng.normal(size=2) * 3
        assert (orient2d(V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]) == 1).all()
        uvs.append(V)
        faces.append(F)
    return uvs, faces


def as_atlas(uvs, faces):
    """Concatenate per-chart arrays into (uv, uv_faces, chart)."""
    sizes = [len(u) for u in uvs]
    shift = np.cumsum(sizes) - sizes
    F = np.concatenate([f + s for f, s in zip(faces, shift)])
    chart = np.repeat(np.arange(len(faces)), [len(f) for f in faces])
    return np.concatenate(uvs), F, chart


def signed_area(u, f):
    a, b, c = u[f[:, 0]], u[f[:, 1]], u[f[:, 2]]
    return 0.5 * np.sum((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def segment_distance(a, b, c, d):
    """Distances between segments ab and cd (rows), assuming they do not intersect."""
    def point_seg(p, a, b):
        e = b - a
        t = np.clip(np.sum((p - a) * e, -1) / np.maximum(np.sum(e * e, -1), 1e-300), 0, 1)
        return np.linalg.norm(p - a - t[..., None] * e, axis=-1)
    return np.minimum.reduce([point_seg(a, c, d), point_seg(b, c, d), point_seg(c, a, b), point_seg(d, a, b)])


def min_chart_distance(uvs, faces, within):
    """The least distance between boundary edges of two different charts, or ``within`` when no
    two charts' bounding boxes come closer than that (brute force over those pairs)."""
    segs = []
    for u, f in zip(uvs, faces):
        loops, _ = chart_boundary_loops(f, np.zeros(len(f), np.int64))
        lp = np.concatenate(loops)
        nxt = np.concatenate([np.roll(x, -1) for x in loops])
        segs.append((u[lp], u[nxt]))
    lo = np.array([u.min(axis=0) for u in uvs]) - within
    hi = np.array([u.max(axis=0) for u in uvs])
    best = within
    for i in range(len(uvs)):
        for j in range(i + 1, len(uvs)):
            if (lo[i] <= hi[j]).all() and (lo[j] <= hi[i]).all():
                (a, b), (c, d) = segs[i], segs[j]
                best = min(best, float(segment_distance(a[:, None], b[:, None], c[None], d[None]).min()))
    return best


# ------------------------------------------------------------------ packing


@pytest.mark.parametrize("k, seed, resolution", [(1, 0, 128), (2, 1, 128), (7, 2, 256), (30, 3, 128), (60, 4, 128)])
def test_packing_is_certified_rigid_in_range_and_spaced(k, seed, resolution):
    uvs, faces = random_charts(k, seed)
    margin = 0.01
    p = pack_charts(uvs, faces, margin=margin, resolution=resolution)
    cert = certify_atlas(*as_atlas(p.uvs, faces))
    assert cert.ok, cert.message
    allpts = np.concatenate(p.uvs)
    assert allpts.min() >= 0 and allpts.max() <= 1
    assert np.isclose(max(np.ptp(allpts, axis=0)), 1.0, atol=1e-12)  # the bounding square is the unit square
    assert p.angles.shape == (k,) and p.offsets.shape == (k, 2)
    for u_in, f, u, a, o in zip(uvs, faces, p.uvs, p.angles, p.offsets):
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])  # det +1: no mirror
        np.testing.assert_allclose(u, p.scale * u_in @ R.T + o, atol=1e-12)
        assert np.isclose(signed_area(u, f), p.scale**2 * signed_area(u_in, f), rtol=1e-9)
    area = sum(signed_area(u, f) for u, f in zip(p.uvs, faces))
    assert np.isclose(p.efficiency, area / max(np.ptp(allpts, axis=0)) ** 2, rtol=1e-12)
    if k > 1:
        assert min_chart_distance(p.uvs, faces, 2 * margin) >= margin
    assert p.efficiency > (0.3 if k > 1 else 0.2)


def test_packing_keeps_charts_unturned_without_rotate():
    uvs, faces = random_charts(5, 7)
    p = pack_charts(uvs, faces, rotate=False, resolution=128)
    assert np.all(p.angles == 0)
    assert certify_atlas(*as_atlas(p.uvs, faces)).ok


def test_packing_turns_tilted_rectangles_upright_and_tiles_them():
    """Equal rectangles given at random angles: turned to their minimum-area rectangles they tile,
    and a good packer fills most of the square (margin 0)."""
    V, F = g.square_mesh(3)
    rng = np.random.default_rng(3)
    uvs = []
    for a in rng.uniform(0, 2 * np.pi, 8):
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        uvs.append((V * [2.0, 1.0]) @ R.T)
    p = pack_charts(uvs, [F] * 8, margin=0.0, resolution=256)
    assert certify_atlas(*as_atlas(p.uvs, [F] * 8)).ok
    assert p.efficiency > 0.85


@pytest.mark.parametrize("n", [9, 25, 36])
def test_equal_squares_tile_the_square(n):
    """``n`` equal squares (n a perfect square), turned and moved at random, margin 0: a packer
    that finds the smallest square reaches the tiling's side up to the conservative raster (one
    pixel a chart at 512 pixels a side), so the efficiency is far above what a greedy packing
    without a search on the side gets."""
    V, F = g.square_mesh(2)
    rng = np.random.default_rng(n)
    uvs = []
    for a in rng.uniform(0, 2 * np.pi, n):
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        uvs.append(V @ R.T + rng.normal(size=2))
    p = pack_charts(uvs, [F] * n, margin=0.0)
    assert certify_atlas(*as_atlas(p.uvs, [F] * n)).ok
    assert p.efficiency > 0.9


def test_mixed_rectangles_pack_tightly():
    """Forty rectangles of random sides in [0.2, 1] (sides ratio up to 5), margin 0.005: a good
    packer leaves little space (xatlas gets about 0.6-0.65 on real atlases)."""
    V, F = g.square_mesh(2)
    rng = np.random.default_rng(5)
    uvs = [V * rng.uniform(0.2, 1.0, 2) + rng.normal(size=2) for _ in range(40)]
    p = pack_charts(uvs, [F] * 40, margin=0.005)
    assert certify_atlas(*as_atlas(p.uvs, [F] * 40)).ok
    assert min_chart_distance(p.uvs, [F] * 40, 0.01) >= 0.005
    assert p.efficiency > 0.79


def _bitmap_shapes(rng, count, size, r):
    """``count`` random masks (5 to ``size`` pixels a side, spanning their box), each as two
    orientations (itself and its transpose) with ``mask`` and ``grown`` (by ``r``), for the placer."""
    from geomopt.atlas._raster import dilate

    class Shape:
        def __init__(self, mask):
            self.mask, self.grown = mask, dilate(mask, r)

    shapes = []
    for _ in range(count):
        m = rng.random((int(rng.integers(5, size)), int(rng.integers(5, size)))) < 0.8
        m[0, :] = m[-1, :] = m[:, 0] = m[:, -1] = True  # the mask spans its box
        shapes.append([Shape(m), Shape(m.T.copy())])
    return shapes


def test_place_pack_square_keeps_masks_apart_and_inside():
    """The square placer on bitmaps: every mask inside the S x S square, grown masks meeting no
    other mask (checked on a fresh canvas), and None when the area cannot fit."""
    from geomopt.atlas._place import pack_square

    r = 2
    shapes = _bitmap_shapes(np.random.default_rng(0), 30, 30, r)
    order = np.argsort([-s[0].mask.sum() for s in shapes])
    for rule in ("square", "bottom"):
        placed = pack_square(shapes, order, r, 150, 4, {}, rule)
        assert placed is not None
        occ = np.zeros((150 + 2 * r, 150 + 2 * r), np.int64)
        for s, y, x in placed:
            h, w = s.mask.shape
            assert r <= y and y + h <= 150 + r and r <= x and x + w <= 150 + r
            occ[y:y + h, x:x + w] += s.mask
        assert occ.max() == 1
        assert placed[order[0]][1:] == (r, r)  # the first chart in the bottom-left corner
        for s, y, x in placed:  # the grown mask meets nothing but its own chart
            h, w = s.mask.shape
            own = np.zeros_like(occ)
            own[y:y + h, x:x + w] = s.mask
            assert not ((occ - own)[y - r:y + h + r, x - r:x + w + r] * s.grown).any()
        area = sum(min(int(v.mask.sum()) for v in sh) for sh in shapes)
        assert pack_square(shapes, order, r, int(np.sqrt(area)) - 1, 4, {}, rule) is None


@pytest.mark.parametrize("scale", [2.0**-900, 1.0, 2.0**900])
def test_packing_at_extreme_scales(scale):
    uvs, faces = random_charts(4, 11)
    p = pack_charts([u * scale for u in uvs], faces, resolution=128)
    assert certify_atlas(*as_atlas(p.uvs, faces)).ok
    for u_in, u, a, o in zip(uvs, p.uvs, p.angles, p.offsets):
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        np.testing.assert_allclose(u, (p.scale * scale) * u_in @ R.T + o, atol=1e-12)


def test_pack_refuses_bad_charts():
    V, F = g.square_mesh(3)
    with pytest.raises(MeshError, match="not positively oriented"):
        pack_charts([V, V * [-1, 1]], [F, F])
    with pytest.raises(MeshError, match="one face array per chart"):
        pack_charts([V], [F, F])
    with pytest.raises(MeshError, match="no face uses"):
        pack_charts([np.concatenate([V, [[5.0, 5.0]]])], [F])
    with pytest.raises(ParameterError, match="margin"):
        pack_charts([V], [F], margin=0.5)


# ------------------------------------------------------------------ the certificate


def two_squares(gap_x):
    """Two unit-grid squares of side 0.3: [0.1, 0.4]^2 and [gap_x, gap_x + 0.3] x [0.1, 0.4]."""
    V, F = g.square_mesh(4, 0.3)
    return as_atlas([V + [0.1, 0.1], V + [gap_x, 0.1]], [F, F])


def test_certificate_accepts_a_clean_atlas():
    cert = certify_atlas(*two_squares(0.5))
    assert isinstance(cert, AtlasCertificate)
    assert cert.ok and "certified" in cert.message


def test_certificate_decides_a_one_ulp_overlap_exactly():
    right = float(two_squares(0.5)[0][:16, 0].max())  # the first square's right side, as rounded
    apart = certify_atlas(*two_squares(np.nextafter(right, 1)))
    touching = certify_atlas(*two_squares(right))
    crossing = certify_atlas(*two_squares(np.nextafter(right, 0)))
    assert apart.ok, apart.message
    assert touching.overlapping_pairs.tolist() == [[0, 1]]
    assert crossing.overlapping_pairs.tolist() == [[0, 1]]
    assert not touching.ok and not crossing.ok


def test_certificate_finds_a_flipped_triangle_and_a_mirrored_chart():
    uv, F, chart = two_squares(0.5)
    F1 = F.copy()
    F1[3] = F1[3][[0, 2, 1]]
    cert = certify_atlas(uv, F1, chart)
    assert cert.inverted.tolist() == [3] and not cert.ok
    uv2 = uv.copy()
    second = np.unique(F[chart == 1])
    uv2[second, 0] = 1.3 - uv2[second, 0]  # the second chart mirrored in place
    cert = certify_atlas(uv2, F, chart)
    assert set(cert.inverted.tolist()) == set(np.flatnonzero(chart == 1).tolist())
    assert cert.self_overlapping.tolist() == [1] and not cert.ok


def test_certificate_finds_a_chart_inside_another():
    V, F = g.square_mesh(4, 0.6)
    W, G = g.square_mesh(3, 0.1)
    cert = certify_atlas(*as_atlas([V + 0.1, W + 0.3], [F, G]))
    assert cert.overlapping_pairs.tolist() == [[0, 1]]
    assert len(cert.self_overlapping) == 0 and len(cert.inverted) == 0 and not cert.ok


def test_certificate_finds_a_chart_overlapping_itself():
    V, F = annulus(0.2, 0.4, 2 * np.pi + 0.7)  # positively oriented everywhere, wraps past its start
    uv, F, chart = as_atlas([V + 0.5], [F])
    assert (orient2d(uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]) == 1).all()
    cert = certify_atlas(uv, F, chart)
    assert cert.self_overlapping.tolist() == [0] and not cert.ok


def test_certificate_of_a_chart_with_a_hole():
    """A ring is injective; a chart in its hole is not inside it; one on the ring is."""
    V, F = annulus(0.2, 0.4, 2 * np.pi)
    W, G = g.square_mesh(3, 0.1)
    alone = certify_atlas(*as_atlas([V + 0.5], [F]))
    assert alone.ok, alone.message
    in_hole = certify_atlas(*as_atlas([V + 0.5, W + 0.45], [F, G]))
    assert in_hole.ok, in_hole.message
    on_ring = certify_atlas(*as_atlas([V + 0.5, W + [0.75, 0.45]], [F, G]))
    assert on_ring.overlapping_pairs.tolist() == [[0, 1]]
    wound_twice = np.concatenate([F, F + len(V)])  # two copies of the ring stacked: coverage 2
    cert = certify_atlas(np.concatenate([V, V]) + 0.5, wound_twice, np.zeros(len(wound_twice), np.int64))
    assert cert.self_overlapping.tolist() == [0]


def test_certificate_finds_a_t_touch():
    V, F = g.square_mesh(4, 0.3)  # [0.1, 0.4]^2; the triangle's tip touches its right side
    tri = np.array([[0.4, 0.25], [0.6, 0.1], [0.6, 0.4]])
    cert = certify_atlas(*as_atlas([V + 0.1, tri], [F, np.array([[0, 1, 2]])]))
    assert cert.overlapping_pairs.tolist() == [[0, 1]] and not cert.ok
    tri[0, 0] = np.nextafter(0.4, 1)
    assert certify_atlas(*as_atlas([V + 0.1, tri], [F, np.array([[0, 1, 2]])])).ok


def test_certificate_counts_uvs_out_of_range():
    uv, F, chart = two_squares(0.5)
    uv[0] = [-1e-300, 0.1]
    uv[-1, 1] = 1.0 + 2**-52
    cert = certify_atlas(uv, F, chart)
    assert cert.out_of_range == 2 and not cert.ok and "outside" in cert.message


def test_certificate_refuses_malformed_input():
    uv, F, chart = two_squares(0.5)
    with pytest.raises(MeshError, match="chart"):
        certify_atlas(uv, F, chart[:-1])
    with pytest.raises(MeshError, match="uv"):
        certify_atlas(uv[:, :1], F, chart)


def test_chart_boundary_loops_split_shared_rows():
    V, F = g.square_mesh(3)  # 8 triangles; charts: left and right halves share the middle column
    c = V[F].mean(axis=1)[:, 0] > 0.5
    loops, owner = chart_boundary_loops(F, c.astype(np.int64))
    assert owner.tolist() == [0, 1]
    assert all(len(lp) == 6 for lp in loops)
    assert set(loops[0].tolist()) == {0, 1, 3, 4, 6, 7}


def test_loop_crossings_of_several_loops_match_brute_force():
    rng = np.random.default_rng(5)
    for _ in range(20):
        sizes = rng.integers(3, 7, size=3)
        P = rng.integers(0, 4, size=(sizes.sum(), 2)).astype(np.float64)
        start = np.cumsum(sizes) - sizes
        nxt = np.arange(len(P)) + 1
        nxt[start + sizes - 1] = start
        want = set()
        for i in range(len(P)):
            for j in range(i + 1, len(P)):
                a, b, cc, d = P[i], P[nxt[i]], P[j], P[nxt[j]]
                if nxt[i] == j or nxt[j] == i:
                    # consecutive: bad iff collinear and not pointing opposite ways from the shared vertex
                    e0, e1 = (b - a, d - cc) if nxt[i] == j else (d - cc, b - a)
                    bad = e0[0] * e1[1] - e0[1] * e1[0] == 0 and np.dot(e0, e1) <= 0
                else:
                    bad = _brute_meet(a, b, cc, d)
                if bad:
                    want.add((i, j))
        got = {tuple(p) for p in loop_crossings(P, nxt).tolist()}
        assert got == want


def _brute_meet(a, b, c, d):
    def o(p, q, r):
        return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    def on(p, q, r):
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])
    o1, o2, o3, o4 = o(a, b, c), o(a, b, d), o(c, d, a), o(c, d, b)
    if o1 * o2 < 0 and o3 * o4 < 0:
        return True
    return ((o1 == 0 and on(a, b, c)) or (o2 == 0 and on(a, b, d)) or (o3 == 0 and on(c, d, a))
            or (o4 == 0 and on(c, d, b)))


def test_place_bottom_rule_fills_a_cavity():
    """A table-shaped chart (a bar on two legs) goes first; with the "bottom" rule a small square
    goes under the table (the lowest free spot), not on it (where sliding down from above ends)."""
    from geomopt.atlas._place import pack_square

    class Shape:
        def __init__(self, mask):
            self.mask = self.grown = mask

    table = np.zeros((20, 40), bool)
    table[16:] = True  # the bar, on top (rows grow upwards)
    table[:, :4] = table[:, -4:] = True  # the legs
    square = np.ones((8, 8), bool)
    placed = pack_square([[Shape(table)], [Shape(square)]], [0, 1], 0, 40, 1, {}, "bottom")
    assert placed[0][1:] == (0, 0)
    assert placed[1][1:] == (0, 4)


def test_place_skips_an_orientation_longer_than_the_square():
    """A chart whose one orientation is longer than the square (and than the FFT of its coarse
    grid) goes in at its other orientation: the long one is skipped, not an error."""
    from geomopt.atlas._place import pack_square

    class Shape:
        def __init__(self, mask):
            self.mask = self.grown = mask

    small = np.ones((4, 4), bool)
    shapes = [[Shape(small)], [Shape(np.ones((4, 90), bool)), Shape(np.ones((4, 60), bool))]]
    placed = pack_square(shapes, [0, 1], 0, 64, 4, {}, "bottom")
    assert placed is not None and placed[1][0].mask.shape == (4, 60)


def test_a_packing_split_must_buy_at_least_min_gain_of_efficiency():
    """split_to_pack keeps a split only when the repacked efficiency rises by ``min_gain``: a
    seam and a chart are not spent on a marginal packing gain (issue 31: charts and seams)."""
    from geomopt.atlas.charts import ChartMesh
    from geomopt.atlas.flat_splits import split_to_pack
    from geomopt.mesh.generators import square_mesh

    V, F = square_mesh(8)
    n = len(V)
    mesh = ChartMesh(np.arange(len(F)), F, np.arange(n), np.arange(n))
    stretched = V * [4.0, 1.0]  # a long chart: splitting it packs better

    class Packed:
        def __init__(self, maps):
            self.efficiency = 0.5 + 0.005 * (len(maps) > 1)  # a split gains half a point

    pack = lambda maps, faces: Packed(maps)
    # seam_cost=0: the charge per chart alone (the seam's: test_among_splits_that_pack_alike_the_shortest...)
    meshes, _, packing, owner = split_to_pack([mesh], [stretched], pack, goal=0.9, min_gain=0.01, seam_cost=0.0)
    assert len(meshes) == 1 and packing.efficiency == 0.5 and owner == [0]
    meshes, _, packing, owner = split_to_pack([mesh], [stretched], pack, goal=0.9, min_gain=0.001, seam_cost=0.0)
    assert len(meshes) > 1 and packing.efficiency > 0.5 and owner == [0] * len(meshes)


# ------------------------------------------------------------------ packing splits (issue 31)


def _chart(V, F):
    from geomopt.atlas.charts import ChartMesh

    n = len(V)
    return ChartMesh(np.arange(len(F)), F, np.arange(n), np.arange(n))


def _shape_chart(inside, n=25, size=(3.0, 3.0)):
    """The faces of an ``n x n`` grid on [0, size] whose centroids ``inside(c)`` keeps, as a chart."""
    V, F = g.square_mesh(n)
    V = V * size
    V, F = _keep(V, F, inside(V[F].mean(axis=1)))
    return _chart(V, F), V


def test_a_split_that_pays_is_found_and_kept_with_the_real_packer():
    """A unit square with an arm as long as its side (a 2 x 1 outline, 5/8 of it chart) packs
    into a square of side 2; cut where the arm begins it packs into about 1.25 x 1.25.  That cut
    is neither across the principal axis at the median nor one of the old three quantiles:
    split_to_pack must find it among its candidates and keep it (two pieces: each extra chart
    must buy ``min_gain``)."""
    from geomopt.atlas.flat_splits import split_to_pack

    mesh, x = _shape_chart(lambda c: ((c[:, 0] < 1.0) & (c[:, 1] < 1.0)) | (c[:, 1] < 0.25), n=17, size=(2.0, 2.0))
    pack = lambda maps, faces: pack_charts(maps, faces)
    whole = pack([x], [mesh.F]).efficiency
    meshes, maps, packing, owner = split_to_pack([mesh], [x], pack, goal=0.7, min_gain=0.01)
    assert whole < 0.4 and packing.efficiency > 0.7, (whole, packing.efficiency)
    assert len(meshes) == 2 and owner == [0, 0]
    assert sum(len(m.F) for m in meshes) == len(mesh.F)
    for m, u in zip(meshes, maps):
        assert m.disk_loop() is not None and np.array_equal(u, x[m.wedges])


def test_splits_that_cannot_pay_are_neither_screened_nor_packed():
    """A strip whose every triangle runs its whole length can only be cut along it, into strips
    as long: no such split can pay (the packing's square is at least the longest piece's
    smallest square), so none is screened or packed; a thin capsule's side spent 43 s there and a
    thin cylinder's 110 s.  A chart whose splits can pay is screened as before."""
    from geomopt.atlas.flat_splits import split_to_pack

    k = np.arange(9.0)
    x = np.r_[np.c_[np.zeros(9), k], np.c_[np.full(9, 100.0), k]]  # (0, k) and (100, k)
    F = np.array([f for i in range(8) for f in ([i, 9 + i, 10 + i], [i, 10 + i, i + 1])])
    calls = []

    def pack(maps, faces):
        calls.append("pack")
        return pack_charts(maps, faces)

    def screen(maps, faces, boundaries):
        calls.append("screen")
        return pack(maps, faces).efficiency

    meshes, _, packing, _ = split_to_pack([_chart(x, F)], [x], pack, goal=0.7, screen=screen, prescreen=screen)
    assert len(meshes) == 1 and calls == ["pack"] and packing.efficiency < 0.2
    calls.clear()
    mesh, y = _shape_chart(lambda c: ((c[:, 0] < 1.0) & (c[:, 1] < 1.0)) | (c[:, 1] < 0.25), n=17, size=(2.0, 2.0))
    split_to_pack([mesh], [y], pack, goal=0.7, screen=screen, prescreen=screen)
    assert calls.count("screen") > 10


def test_a_long_thin_chart_is_placed_on_a_coarse_grid(monkeypatch):
    """The coarse grid's blocks follow the squares tried, whose side is at least the longest
    chart's, not the charts' area alone: a strip thousands of pixels long and a few wide has
    little area, and a grid from the area was the fine grid itself (an FFT of millions of cells
    per chart placed: 16 s of a 48-face thin cylinder's atlas)."""
    from geomopt.atlas import _place

    blocks = []
    real = _place.coarse_factor
    monkeypatch.setattr(_place, "coarse_factor", lambda side: blocks.append(real(side)) or blocks[-1])
    x = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 1.0], [0.0, 1.0]])
    packing = pack_charts([x, x * 0.5], [np.array([[0, 1, 2], [0, 2, 3]])] * 2)
    assert packing.efficiency > 0 and min(blocks) > 1, blocks


def test_each_extra_chart_of_a_split_must_buy_min_gain():
    """A U-shaped chart has cuts into two pieces and cuts into three (across both arms).  With a
    packer that gains 1.2 points for two pieces and 1.8 for three, a charge of one point per extra
    chart prefers two pieces (0.2 net against -0.2), and refuses three when two are impossible."""
    from geomopt.atlas.flat_splits import candidate_splits, split_to_pack

    mesh, x = _shape_chart(lambda c: ~((c[:, 0] > 1.0) & (c[:, 0] < 2.0) & (c[:, 1] > 1.0)))
    counts = {len(c) for c in candidate_splits(mesh, x)}
    assert {2, 3} <= counts, counts

    class Packed:
        def __init__(self, maps):
            self.efficiency = 0.5 + {1: 0.0, 2: 0.012}.get(len(maps), 0.018)

    pack = lambda maps, faces: Packed(maps)
    meshes, _, packing, _ = split_to_pack([mesh], [x], pack, goal=0.9, max_splits=1, min_gain=0.01, seam_cost=0.0)
    assert len(meshes) == 2 and packing.efficiency == pytest.approx(0.512)

    class NoPairs(Packed):
        def __init__(self, maps):
            self.efficiency = 0.5 + {1: 0.0, 2: -0.1}.get(len(maps), 0.018)

    meshes, _, packing, _ = split_to_pack([mesh], [x], lambda m, f: NoPairs(m), goal=0.9, max_splits=1,
                                          min_gain=0.01, seam_cost=0.0)
    assert len(meshes) == 1 and packing.efficiency == 0.5


def test_the_fast_disk_test_of_split_pieces_agrees_with_check_disk():
    """The pieces of a split are tested for being disks by counting (Euler characteristic 1, two
    boundary edges at each boundary vertex); on random face subsets of a grid (holes, pinched
    vertices, plain disks) it must agree with the full check."""
    from geomopt.atlas.flat_splits import _Cutter, _face_components

    rng = np.random.default_rng(5)
    V, F = g.square_mesh(7)
    cutter = _Cutter(_chart(V, F), V)
    kinds = set()
    for _ in range(300):
        keep = rng.random(len(F)) < rng.uniform(0.5, 0.95)
        if not keep.any():
            continue
        faces = np.flatnonzero(keep)
        labels = _face_components(F, keep)
        for k in range(labels.max() + 1):
            sel = faces[labels == k]
            rows, local = np.unique(F[sel], return_inverse=True)
            want = _chart(V[rows], local.reshape(-1, 3)).disk_loop() is not None
            assert cutter._is_disk(sel) == want
            kinds.add(want)
    assert kinds == {True, False}


def test_packing_estimate_is_close_to_pack_charts():
    """The cheap screening estimate (coarse bitmap, no in-between angles, no certificate) stays
    within a few points of the certified packing's efficiency."""
    from geomopt.atlas._pack import packing_estimate

    rng = np.random.default_rng(2)
    for _ in range(3):
        charts = [grid_chart(rng) for _ in range(4)] + [l_chart(rng)]
        U, Fs = [c[0] for c in charts], [c[1] for c in charts]
        est, full = packing_estimate(U, Fs), pack_charts(U, Fs).efficiency
        assert abs(est - full) < 0.08, (est, full)


def test_the_exact_smallest_square_angle_beats_every_sampled_angle():
    """smallest_square_angle (critical angles and width = height crossings) gives a bounding
    square no larger than any of 360 sampled angles, and the side it reports is the side at the
    angle it returns, on random convex polygons of every aspect."""
    from scipy.spatial import ConvexHull

    from geomopt.atlas._pack import smallest_square_angle

    def sides(P, a):
        c, s = np.cos(a)[:, None], np.sin(a)[:, None]
        return np.maximum(np.ptp(c * P[:, 0] - s * P[:, 1], axis=1), np.ptp(s * P[:, 0] + c * P[:, 1], axis=1))

    rng = np.random.default_rng(11)
    sampled = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    strictly = 0
    for _ in range(200):
        P = rng.normal(size=(int(rng.integers(3, 30)), 2)) * [rng.uniform(0.1, 4.0), 1.0]
        hull = P[ConvexHull(P).vertices]
        a, side = smallest_square_angle(hull)
        assert 0.0 <= a < np.pi / 2
        assert side == pytest.approx(sides(hull, np.array([a]))[0], rel=1e-12)
        best = sides(hull, sampled).min()
        assert side <= best * (1 + 1e-12)
        strictly += side < best * (1 - 1e-9)
    assert strictly > 150  # a sampled angle almost never hits the optimum


def test_split_candidates_leave_no_crumbs():
    """A straight cut across a grid's diagonal or a ragged outline leaves single triangles
    joined to their side by a vertex only; each would become a chart.  Every piece of every
    candidate split keeps more than a sliver of the chart."""
    from geomopt.atlas.flat_splits import _SLIVER, candidate_splits

    mesh, x = _shape_chart(lambda c: (c[:, 0] < 1.0) | (c[:, 1] < 0.2))
    total = _uv_area(x, mesh.F)
    cands = candidate_splits(mesh, x)
    assert len(cands) > 10
    for pieces in cands:
        for m, u in pieces:
            assert _uv_area(u, m.F) >= _SLIVER * total and len(m.F) > 1


def _uv_area(x, F):
    P = x[F]
    a, b = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    return 0.5 * float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))


def test_among_splits_that_pack_alike_the_shortest_seam_in_3d_wins():
    """Every split of a 3 x 1 rectangle packs alike here (a stand-in packer that counts charts),
    so the split kept must be the one adding the least seam, measured on the surface: stretched
    five times across in 3D, the cut across the chart's length (3 long) is shorter there than
    the one across its width (1 in UV, 5 in 3D).  The seam is charged when deciding whether a
    split pays too: at a high enough price per length, the same split is refused."""
    from geomopt.atlas.flat_splits import candidate_splits, split_to_pack

    mesh, x = _shape_chart(lambda c: c[:, 1] < 1.0, n=13, size=(3.0, 3.0))
    V = np.c_[x * [1.0, 5.0], np.zeros(len(x))]

    class Packed:  # (efficiencies a real packing could reach: each split's bound is above them)
        def __init__(self, maps):
            self.efficiency = 0.25 + 0.2 * (len(maps) == 2)

    pack = lambda maps, faces: Packed(maps)
    screen = lambda maps, faces, boundaries: Packed(maps).efficiency
    cands = candidate_splits(mesh, x, V=V, seams=True)
    seams = [seam for pieces, seam in cands if len(pieces) == 2]
    assert min(seams) == pytest.approx(3.0) and max(seams) > 4.0, seams
    meshes, maps, packing, _ = split_to_pack([mesh], [x], pack, goal=0.9, max_splits=1, screen=screen, V=V)
    assert len(meshes) == 2 and packing.efficiency == 0.45
    cut = np.intersect1d(*[m.vertices for m in meshes])  # the vertices on the new seam
    assert np.ptp(V[cut, 1]) < 1e-9 and np.ptp(V[cut, 0]) == pytest.approx(3.0), V[cut]
    meshes, _, packing, _ = split_to_pack([mesh], [x], pack, goal=0.9, max_splits=1, screen=screen, V=V,
                                          seam_cost=1.0)  # 0.01 + 1.0 * 3 / sqrt(15) > 0.2
    assert len(meshes) == 1 and packing.efficiency == 0.25


def test_place_reusing_a_larger_squares_trace_packs_alike(monkeypatch):
    """A packing that reuses the placements of the same charts in a larger square (while their
    spots are offered) is the packing a full search finds, with fewer searches."""
    from geomopt.atlas import _place

    r = 2
    shapes = _bitmap_shapes(np.random.default_rng(1), 12, 40, r)
    order = np.argsort([-s[0].mask.sum() for s in shapes])
    searches = []
    best_spot = _place._best_spot
    monkeypatch.setattr(_place, "_best_spot", lambda *a: searches.append(1) or best_spot(*a))
    for rule in ("square", "bottom"):
        _, trace = _place._pack_traced(shapes, order, r, 160, 4, {}, rule, 0)
        reused = 0
        for S in range(96, 161, 8):
            fresh = _place.pack_square(shapes, order, r, S, 4, {}, rule)
            n = len(searches)
            again, _ = _place._pack_traced(shapes, order, r, S, 4, {}, rule, 0, trace)
            reused += len(shapes) - (len(searches) - n)
            assert (fresh is None) == (again is None)
            if fresh is not None:
                assert [(id(s), y, x) for s, y, x in fresh] == [(id(s), y, x) for s, y, x in again]
        assert reused > len(shapes)  # charts were placed from the trace, not searched


def test_place_pool_marks_the_blocks_holding_a_pixel():
    """The coarse grid: block (i, j) is set exactly when a pixel of its c x c block is, for block
    sizes read as machine words (2, 4, 8) and not, and masks not a multiple of the block."""
    from geomopt.atlas._place import pool

    rng = np.random.default_rng(3)
    for c in range(1, 10):
        for shape in [(1, 1), (3, 7), (17, 33), (40, 9)]:
            m = rng.random(shape) < 0.05
            want = [[m[i * c:(i + 1) * c, j * c:(j + 1) * c].any() for j in range(-(-shape[1] // c))]
                    for i in range(-(-shape[0] // c))]
            assert np.array_equal(pool(m, c), np.array(want, bool))


def test_pack_search_reports_the_true_side_of_its_packing():
    """The side that the square search ranks packings by (from each orientation's box, moved)
    is the side of the charts it places, computed from all their points."""
    from geomopt.atlas import _pack

    uvs, faces = random_charts(6, 5)
    U, _, area, Bs, bases, turns = _pack._prepare(uvs, faces, True)
    h, r = np.sqrt(area / 0.6) / 128, 2
    shapes = [_pack._shapes(u, B, base, turns, h, r) for u, B, base in zip(U, Bs, bases)]
    placement, side = _pack._search(U, shapes, h, r, 12)
    assert side == _pack._side([(u @ R.T) / h + t for u, (R, t) in zip(U, placement)])


def test_piece_boundaries_are_the_boundary_half_edges_of_the_pieces():
    """The screens' boundaries of split pieces, from the chart's edges counted once, are each
    piece's own boundary half-edges (the same rows in the same order), for pieces of pieces too."""
    from geomopt.atlas.flat_splits import candidate_splits, piece_boundaries
    from geomopt.exact.topology import boundary_half_edges

    mesh, x = _shape_chart(lambda c: (c[:, 1] < 1.0) | (c[:, 0] < 1.0), n=13, size=(3.0, 3.0))
    splits = candidate_splits(mesh, x)
    piece, xp = max(splits[0], key=lambda p: len(p[0].F))
    for chart, u in [(mesh, x), (piece, xp)]:
        splits = candidate_splits(chart, u)
        assert len(splits) > 3
        for pieces, bounds in zip(splits, piece_boundaries(chart, splits)):
            assert len(bounds) == len(pieces)
            for (p, _), B in zip(pieces, bounds):
                assert np.array_equal(B, boundary_half_edges(p.F))


def _supercover_by_box(a, b, shape):
    """Every pixel of each segment's bounding box tested against the segment's line (within the
    rasteriser's tolerance): the slow reference of the conservative raster's boundary pixels."""
    from geomopt.atlas import _raster

    eps, out = _raster._EPS, set()
    for p, q in zip(a, b):
        lo, hi = np.floor(np.minimum(p, q) - eps).astype(int), np.floor(np.maximum(p, q) + eps).astype(int)
        nx, ny = p[1] - q[1], q[0] - p[0]
        for row in range(max(lo[1], 0), min(hi[1] + 1, shape[0])):
            for col in range(max(lo[0], 0), min(hi[0] + 1, shape[1])):
                d = [nx * (col + i - p[0]) + ny * (row + j - p[1]) for i in (0, 1) for j in (0, 1)]
                tol = eps * (abs(nx) + abs(ny))
                if min(d) <= tol and max(d) >= -tol:
                    out.add((row, col))
    return out


@pytest.mark.parametrize("kind", ["any", "vertical", "horizontal", "on grid lines"])
def test_the_boundary_raster_walks_each_segment_and_meets_the_box_test(kind):
    """The boundary pixels of the conservative raster, walked column by column, are exactly the
    pixels of each segment's bounding box that the segment meets (or comes within _EPS of)."""
    from geomopt.atlas import _raster

    rng = np.random.default_rng(["any", "vertical", "horizontal", "on grid lines"].index(kind))
    for _ in range(150):
        a, b = rng.uniform(-3, 30, (3, 2)), rng.uniform(-3, 30, (3, 2))
        if kind == "vertical":
            b[:, 0] = a[:, 0]
        elif kind == "horizontal":
            b[:, 1] = a[:, 1]
        elif kind == "on grid lines":
            a, b = np.round(a), np.round(b)
        got = set(zip(*(v.tolist() for v in _raster._supercover(a, b, (27, 31)))))
        assert got == _supercover_by_box(a, b, (27, 31))


def test_a_thin_strip_is_packed_on_a_bitmap_of_bounded_size():
    """A chart 1000 times longer than wide sets the packing's side: its pixels are chosen so that
    it spans at most a few times ``resolution`` (pixels sized by the total area would have made
    a bitmap of ~10^4 pixels a side; a box of 1000 x 1 x 1 hung in the packer)."""
    from geomopt.atlas import _pack

    V, F = g.square_mesh(3)
    U = [V * [1000.0, 1.0]]
    U, unit, area, Bs, bases, turns = _pack._prepare(U, [F], True)
    R, t, h = _pack._layout(U, Bs, bases, turns, area, 0.005, 128)
    assert np.ptp(U[0], axis=0).max() / h <= _pack._LONG_SIDE * 128 + 1
    packing = pack_charts([V * [1000.0, 1.0]], [F], resolution=128)
    assert certify_atlas(packing.uvs[0], F, np.zeros(len(F), int)).ok


def test_split_sides_pieces_match_separate_connected_components():
    """The pieces of both sides of a cut (one masked dual graph, ``_Dual.sides``) are the
    connected components of each side's faces alone, numbered alike (by their first face), on
    random sides of a grid with many pieces each."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from geomopt.atlas.charts import face_pairs
    from geomopt.atlas.flat_splits import _Dual, _face_components, _restrict

    rng = np.random.default_rng(11)
    V, F = g.square_mesh(9)
    a, b = face_pairs(F)[:2]
    dual = _Dual(a, b, len(F))
    for _ in range(50):
        low = rng.random(len(F)) < rng.uniform(0.2, 0.8)
        both = dual.sides(low)
        for side in (low, ~low):
            if not side.any():
                continue
            idx = np.cumsum(side) - 1
            keep = side[a] & side[b]
            n = int(side.sum())
            graph = sp.coo_matrix((np.ones(int(keep.sum())), (idx[a[keep]], idx[b[keep]])), shape=(n, n))
            want = connected_components(graph.tocsr(), directed=False)[1]
            assert np.array_equal(_restrict(both, side), want)
            assert np.array_equal(_face_components(F, side), want)
        assert len(np.unique(both)) > 2


def test_the_prescreen_shortlists_the_candidates_that_are_screened():
    """With a prescreen and more than ``_SHORTLIST`` candidates, only the prescreen's best
    ``_SHORTLIST`` are screened: a prescreen that ranks the best split last keeps it out (a worse
    one is kept), one that ranks it first lets it in; without a prescreen every candidate is
    screened."""
    from geomopt.atlas.flat_splits import _SHORTLIST, candidate_splits, split_to_pack

    mesh, x = _shape_chart(lambda c: ((c[:, 0] < 1.0) & (c[:, 1] < 1.0)) | (c[:, 1] < 0.25), n=17, size=(2.0, 2.0))
    cands = candidate_splits(mesh, x)
    assert len(cands) > _SHORTLIST + 1
    counts = [len(c[0][0].F) for c in cands]  # a split recognised by its first piece's face count
    key = {next(n for n in counts if counts.count(n) == 1): 1.0}  # the best split: a distinct one

    def score(maps, faces, boundaries=None):
        return key.get(len(faces[0]), 0.5) if len(faces) > 1 else 0.4

    class Packed:
        def __init__(self, maps, faces):
            self.efficiency = score(maps, faces)

    pack = lambda maps, faces: Packed(maps, faces)
    run = lambda **kw: split_to_pack([mesh], [x], pack, goal=0.99, max_splits=1, min_gain=0.0, seam_cost=0.0,
                                     screen=score, **kw)[2].efficiency
    assert run() == 1.0
    assert run(prescreen=lambda m, f, b: -score(m, f)) == 0.5  # the best ranked last: left out
    assert run(prescreen=score) == 1.0


def test_the_support_vertex_of_a_convex_polygon_is_the_farthest_along_each_direction():
    """``_support`` (a binary search over the hull's edge angles, so the minimum-area rectangle
    costs O(h log h), not O(h^2)) returns a vertex whose projection is the largest, for random
    directions and the edges' own directions and normals (the ties of the rectangle search), on
    random hulls, some of them with collinear and grid-snapped points."""
    from scipy.spatial import ConvexHull

    from geomopt.atlas._pack import _support

    rng = np.random.default_rng(3)
    for t in range(300):
        P = rng.normal(size=(int(rng.integers(3, 200)), 2)) * rng.uniform(0.1, 10.0, size=2)
        if t % 3 == 0:
            P = np.round(P * 4) / 4
        hull = P[ConvexHull(P).vertices]
        e = np.roll(hull, -1, axis=0) - hull
        e /= np.linalg.norm(e, axis=1, keepdims=True)
        d = np.r_[rng.normal(size=(20, 2)), e, -e, np.stack([-e[:, 1], e[:, 0]], 1)]
        proj = d @ hull.T
        got = proj[np.arange(len(d)), _support(e, d)]
        assert np.all(got >= proj.max(axis=1) - 1e-12 * np.abs(proj).max()), t

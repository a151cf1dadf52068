"""What texture pipelines expect of an atlas (issue 50, item 3): padding in texels at a texture
resolution, several meshes in one atlas, polygons kept in the OBJ, and the atlas as a Result
that saves like every other map."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import geomopt
from geomopt import ParameterError
from geomopt.atlas import AtlasOptions, certify_atlas, make_atlas
from geomopt.atlas.build import welded
from geomopt.exact.topology import boundary_half_edges

from test_atlas import read_obj_corners  # (v, vt, f: vertex and vt per corner)


def quad_torus(n=12, m=6, R=2.0, r=0.7):
    """A torus of n x m quads, (V (n m, 3), Q (n m, 4)) counter-clockwise seen from outside."""
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a, b = 2 * np.pi * i.ravel() / n, 2 * np.pi * j.ravel() / m
    V = np.stack([(R + r * np.cos(b)) * np.cos(a), (R + r * np.cos(b)) * np.sin(a), r * np.sin(b)], 1)
    k = lambda u, v: (u % n) * m + (v % m)  # noqa: E731
    Q = np.array([[k(u, v), k(u + 1, v), k(u + 1, v + 1), k(u, v + 1)] for u in range(n) for v in range(m)])
    return V, Q


def twisted_quad_torus(n=8, m=8, R=2.0, r=0.7):
    """A torus of parallelogram quads whose fan diagonals (corner 0 to corner 2) line up into
    meridians, shorter than the quads' sides: the cheapest seams of a torus, were they allowed."""
    V, Q = quad_torus(n, m, R, r)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a, b = 2 * np.pi * (i.ravel() - j.ravel()) / n, 2 * np.pi * j.ravel() / m
    V = np.stack([(R + r * np.cos(b)) * np.cos(a), (R + r * np.cos(b)) * np.sin(a), r * np.sin(b)], 1)
    return V, Q


def triangles(Q):
    return np.r_[Q[:, [0, 1, 2]], Q[:, [0, 2, 3]]]


def _segment_distances(P, Q, R, S):
    """(a, b) Euclidean distance between every segment ``P[i] Q[i]`` (a, 2) and ``R[j] S[j]`` (b, 2):
    0 where they cross, else the least of the four endpoint-to-segment distances."""
    def point_segment(X, A, B):  # X (a, 1, 2) or (1, b, 2) against segments A B of the other shape
        d = B - A
        t = np.clip(np.sum((X - A) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-300), 0.0, 1.0)
        return np.linalg.norm(X - (A + t[..., None] * d), axis=-1)

    P, Q, R, S = P[:, None], Q[:, None], R[None], S[None]
    d = np.minimum(np.minimum(point_segment(P, R, S), point_segment(Q, R, S)),
                   np.minimum(point_segment(R, P, Q), point_segment(S, P, Q)))

    def side(A, B, C):
        return np.sign((B[..., 0] - A[..., 0]) * (C[..., 1] - A[..., 1]) - (B[..., 1] - A[..., 1]) * (C[..., 0] - A[..., 0]))
    crossing = (side(P, Q, R) * side(P, Q, S) < 0) & (side(R, S, P) * side(R, S, Q) < 0)
    return np.where(crossing, 0.0, d)


def chart_gap(uv, uv_faces, chart) -> float:
    """The least distance between two charts' triangles, measured from the UVs alone: the least
    distance between boundary edges of different charts (where no chart holds another, which the
    exact certificate checks, the closest points of two disjoint polygons lie on their boundaries)."""
    B = boundary_half_edges(uv_faces)  # (s, 2) UV rows
    owner = np.zeros(len(uv), dtype=np.int64)
    owner[uv_faces.ravel()] = np.repeat(chart, 3)
    c = owner[B[:, 0]]
    best = np.inf
    for k in np.unique(c):
        mine, other = B[c == k], B[c > k]
        if len(other):
            best = min(best, float(_segment_distances(uv[mine[:, 0]], uv[mine[:, 1]],
                                                      uv[other[:, 0]], uv[other[:, 1]]).min()))
    return best


def test_the_gap_measure_itself():
    uv = np.array([[0, 0], [1, 0], [0, 1], [3, 0], [4, 0], [3, 1], [0.5, 2.5], [1.5, 2.5], [0.5, 3.5]], float)
    T = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    assert chart_gap(uv, T, np.array([0, 1, 2])) == pytest.approx(np.sqrt(2.5))  # (0, 1) to (0.5, 2.5)
    crossed = uv.copy()
    crossed[3:6] -= [2.8, 0.2]  # the second triangle now crosses the first
    assert chart_gap(crossed, T, np.array([0, 1, 2])) == 0.0


@pytest.mark.parametrize("N, P", [(64, 3.0), (200, 8.0)])
def test_padding_keeps_every_two_charts_that_many_texels_apart(N, P):
    V, Q = quad_torus()
    result = make_atlas(V, triangles(Q), options=AtlasOptions(resolution=N, padding=P), progress=False)
    d = result.details
    assert result.success and d.metrics.charts >= 2, result.message
    gap = chart_gap(result.x, d.uv_faces, d.chart) * N
    assert gap >= P * (1 - 1e-9), (gap, P)
    assert d.margin == pytest.approx(P / N)
    # half the padding inside the square's edges: P apart across the edges of a repeating texture
    assert result.x.min() * N >= P / 2 * (1 - 1e-9) and (1 - result.x.max()) * N >= P / 2 * (1 - 1e-9)


def test_resolution_and_padding_are_validated(cli, tmp_path):
    with pytest.raises(ParameterError, match="padding .* needs the texture's resolution"):
        AtlasOptions(padding=2)
    with pytest.raises(ParameterError, match="margin .* or a resolution"):
        AtlasOptions(margin=0.01, resolution=256)
    with pytest.raises(ParameterError, match="too wide for a 64-texel texture"):
        AtlasOptions(resolution=64, padding=13)
    assert AtlasOptions(resolution=100).packing() == pytest.approx((2 / 98, 0.01))
    assert AtlasOptions().packing() == (0.005, 0.0)
    V, Q = quad_torus(8, 4)
    mesh = tmp_path / "t.obj"
    geomopt.io.write_obj(mesh, V, triangles(Q))
    code, _, err = cli("param", mesh, "-o", tmp_path / "out.obj", "--padding", "2", "--quiet")
    assert code == 2 and "--padding (texels) goes with --resolution" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.obj"]


def test_several_meshes_share_one_atlas():
    V1, Q1 = quad_torus(10, 5)
    V2, Q2 = quad_torus(8, 4, R=1.0, r=0.3)
    V2 = V2 + [5.0, 0.0, 0.0]
    result = make_atlas([(V1, triangles(Q1)), (V2, triangles(Q2))], progress=False)
    d = result.details
    assert result.success and d.meshes == 2
    parts = [d.part(result.x, i) for i in range(2)]
    for (V, Q), part in zip([(V1, Q1), (V2, Q2)], parts):
        assert np.array_equal(part.V, V) and np.array_equal(part.faces, triangles(Q))
        assert np.all((part.uv >= 0) & (part.uv <= 1))
    # the two meshes' charts share the square without overlapping: certified together
    uv = np.r_[parts[0].uv, parts[1].uv]
    T = np.r_[parts[0].uv_faces, parts[1].uv_faces + len(parts[0].uv)]
    assert certify_atlas(uv, T, np.r_[np.zeros(len(parts[0].faces)), np.ones(len(parts[1].faces))].astype(int)).ok
    with pytest.raises(ParameterError, match="2 mesh"):
        d.part(result.x, 2)


def test_param_writes_one_obj_per_input_into_the_folder(cli, tmp_path):
    V1, Q1 = quad_torus(10, 5)
    V2, Q2 = quad_torus(8, 4, R=1.0, r=0.3)
    a, b = tmp_path / "a.obj", tmp_path / "b.off"
    geomopt.io.write_obj(a, V1, triangles(Q1))
    b.write_text(f"OFF\n{len(V2)} {len(Q2)} 0\n" + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in V2.tolist())
                 + "".join(f"4 {p} {q} {r} {s}\n" for p, q, r, s in Q2.tolist()))
    out = tmp_path / "atlas"
    code, stdout, err = cli("param", a, b, "-o", out, "--json", "--quiet", "--png", tmp_path / "atlas.png")
    assert code == 0, err
    assert json.loads(stdout)["input"] == [str(a), str(b)]
    assert sorted(p.name for p in out.iterdir()) == ["a.obj", "b.obj"] and (tmp_path / "atlas.png").stat().st_size
    uv, T = [], []
    for k, (path, V) in enumerate([(out / "a.obj", V1), (out / "b.obj", V2)]):
        W, vt, F = read_obj_corners(path)
        assert np.allclose(W, V) and np.all((vt >= 0) & (vt <= 1))
        T.append(F[:, :, 1] + sum(len(u) for u in uv))
        uv.append(vt)
    assert certify_atlas(np.concatenate(uv), np.concatenate(T), _charts(np.concatenate(T))).ok


def _charts(T):
    """The connected components of the UV triangles ``T`` (their charts)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = int(T.max()) + 1
    A = coo_matrix((np.ones(2 * len(T)), (np.r_[T[:, 0], T[:, 1]], np.r_[T[:, 1], T[:, 2]])), shape=(n, n))
    return connected_components(A, directed=False)[1][T[:, 0]]



def test_quads_stay_quads_with_one_vt_per_corner():
    V, Q = twisted_quad_torus()
    E = np.linalg.norm(V[Q] - V[np.roll(Q, -1, axis=1)], axis=2)
    assert np.linalg.norm(V[Q[:, 2]] - V[Q[:, 0]], axis=1).max() < E.min()  # the diagonals are the shortest edges
    result = make_atlas(V, Q, options=AtlasOptions(min_efficiency=0.0), progress=False)
    d = result.details
    assert result.success and len(d.split_polygons()) == 0  # no seam along a quad's diagonal
    part = d.part(result.x)
    assert np.array_equal(np.array(part.faces), Q)
    T = d.uv_faces  # quad q is the fan (c0, c1, c2), (c0, c2, c3): rows 2q and 2q + 1
    expected = np.c_[T[0::2], T[1::2, 2]]
    assert np.array_equal(np.array(part.uv_faces), expected)
    assert np.array_equal(part.uv, result.x)


def test_param_keeps_an_obj_inputs_polygons(cli, tmp_path):
    V, Q = quad_torus()
    polygons = Q.tolist()
    polygons[5] = polygons[5][:3]  # a triangle among the quads (and a hole beside it): a mixed mesh
    mesh = tmp_path / "quads.obj"
    mesh.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
                    + "".join("f " + " ".join(str(i + 1) for i in q) + "\n" for q in polygons))
    code, _, err = cli("param", mesh, "-o", tmp_path / "out.obj", "--quiet")
    assert code == 0, err
    lines = [line.split()[1:] for line in (tmp_path / "out.obj").read_text().splitlines() if line.startswith("f ")]
    crossed = int(err.split("a seam crosses ")[1].split()[0]) if "a seam crosses" in err else 0
    quads = [[int(c.split("/")[0]) - 1 for c in line] for line in lines if len(line) == 4]
    assert len(quads) == len(Q) - 1 - crossed and len(lines) == len(Q) + crossed  # a crossed quad: two triangles
    assert {tuple(q) for q in quads} <= {tuple(q) for q in polygons}
    assert crossed <= len(Q) // 10


def test_polygons_of_any_size_round_trip_through_obj(tmp_path):
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [0, 1, 0], [1.5, 1.8, 0]], float)
    faces = [[0, 1, 4, 5], [1, 2, 3, 6, 4]]
    result = make_atlas(V, faces, options=AtlasOptions(), progress=False)
    assert result.success
    paths = result.save(tmp_path / "poly.obj", png=tmp_path / "poly.png")
    assert [p.name for p in paths] == ["poly.obj", "poly.png"] and paths[1].stat().st_size > 0
    W, read = geomopt.io.read_obj_polygons(tmp_path / "poly.obj")
    assert np.array_equal(W, V) and [f.tolist() for f in read] == faces
    text = (tmp_path / "poly.obj").read_text()
    assert text.count("\nvt ") + text.startswith("vt ") == len(result.x)


def test_an_atlas_result_saves_as_every_map_does(tmp_path):
    V, Q = quad_torus(8, 4)
    result = make_atlas(V, triangles(Q), progress=False)
    assert isinstance(result, geomopt.Result) and result.injectivity == "global" and result.mean_energy >= 4.0
    assert result.message == "converged"
    assert result.save(tmp_path / "t.obj") == (tmp_path / "t.obj",)
    v, vt, f = read_obj_corners(tmp_path / "t.obj")
    assert np.array_equal(v, V) and np.array_equal(f[:, :, 0], triangles(Q))
    assert np.array_equal(vt, result.x) and np.array_equal(f[:, :, 1], result.details.uv_faces)
    with pytest.raises(geomopt.GeomoptError, match="extension"):
        result.save(tmp_path / "t.ply")


def _unwelded(V, F):
    """Every face its own three vertices (an export that splits vertices at every face)."""
    return np.asarray(V)[np.asarray(F)].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3)


def test_an_unwelded_mesh_is_welded_into_the_atlas_of_the_welded_one():
    V, Q = quad_torus(6, 3)
    F = triangles(Q)
    Vu, Fu = _unwelded(V, F)
    Fw, joined = welded(Vu, Fu, np.array([0, len(Vu)]))
    assert joined == len(Vu) - len(V) and len(np.unique(Fw)) == len(V)
    assert np.array_equal(Vu[Fw], Vu[Fu])  # same positions, vertices shared
    a, b = make_atlas(V, F, progress=False), make_atlas(Vu, Fu, progress=False)
    assert a.success and b.success
    # the welded mesh's atlas (not a chart per triangle): its vertices are numbered otherwise, so
    # its sums may round otherwise
    ma, mb = dataclasses.astuple(a.details.metrics), dataclasses.astuple(b.details.metrics)
    assert (mb[0], mb[-1]) == (ma[0], ma[-1]) and mb == pytest.approx(ma, rel=1e-9)
    assert np.array_equal(b.details.faces, Fu)  # the input's faces, kept
    assert np.array_equal(Vu[b.details.vertex][b.details.uv_faces], Vu[Fu])  # each UV row at its corner


def test_welding_keeps_apart_what_it_may_not_join():
    # three triangles on copies of one edge: joined, that edge would have three faces
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0, 0, 0], [1, 0, 0], [0.5, -1, 0],
                  [0, 0, 0], [1, 0, 0], [0.5, 0, 1]], dtype=float)
    F = np.arange(9).reshape(3, 3)
    assert welded(V, F, np.array([0, 9]))[1] == 0
    # two meshes are never joined, even where joined they would make one good mesh: the two
    # halves of a torus, each given with all the torus's vertices
    Vt, Qt = quad_torus(6, 3)
    T = triangles(Qt)
    half = len(T) // 2
    V2, F2 = np.r_[Vt, Vt], np.r_[T[:half], T[half:] + len(Vt)]
    F_, joined = welded(V2, F2, np.array([0, len(Vt), 2 * len(Vt)]))
    assert joined == 0 and np.array_equal(F_, F2)
    assert welded(V2, F2, np.array([0, 2 * len(Vt)]))[1] == len(Vt)  # as one mesh they would join

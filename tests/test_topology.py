"""Tests for geomopt.exact.topology: edges, boundary loops, components and the disk check."""


import numpy as np
import pytest

from hypothesis import given, settings
from hypothesis import strategies as st

from geomopt import MeshError
from geomopt.exact.topology import (unique_pairs, ranges, boundary_half_edges, boundary_loops, check_disk, connected_components,
    half_edges, unique_edges)

from conftest import mesh_path



def grid_disk(nx, ny):
    """(nx+1)*(ny+1) vertices on [0, nx] x [0, ny], 2*nx*ny counter-clockwise triangles."""
    x, y = np.meshgrid(np.arange(nx + 1.0), np.arange(ny + 1.0), indexing="ij")
    V = np.stack([x.ravel(), y.ravel()], axis=1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def annulus(n_around=12, n_radial=2):
    """A ring of quads split into triangles, counter-clockwise; inner radius 1."""
    t = 2 * np.pi * np.arange(n_around) / n_around
    r = 1.0 + np.arange(n_radial + 1)
    V = np.concatenate([np.stack([ri * np.cos(t), ri * np.sin(t)], 1) for ri in r])
    idx = np.arange(V.shape[0]).reshape(n_radial + 1, n_around)
    nxt = np.roll(idx, -1, axis=1)
    a, b = idx[:-1].ravel(), nxt[:-1].ravel()
    c, d = nxt[1:].ravel(), idx[1:].ravel()
    F = np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])
    return V, F


def torus(nu=6, nv=5):
    """A closed torus of 2*nu*nv triangles, consistently oriented (chi = 0)."""
    idx = np.arange(nu * nv).reshape(nu, nv)
    i1, j1 = np.roll(idx, -1, axis=0), np.roll(idx, -1, axis=1)
    ij1 = np.roll(i1, -1, axis=1)
    a, b, c, d = idx.ravel(), i1.ravel(), ij1.ravel(), j1.ravel()
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


TET_SURFACE = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


def polygon_area(P):
    x, y = P[:, 0], P[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def same_cycle(loop, expected):
    loop, expected = list(loop), list(expected)
    if len(loop) != len(expected) or expected[0] not in loop:
        return False
    k = loop.index(expected[0])
    return loop[k:] + loop[:k] == expected


# ---------------------------------------------------------------- edges


def test_half_edges_order():
    H = half_edges(np.array([[0, 1, 2], [0, 2, 3]]))
    np.testing.assert_array_equal(H, [[0, 1], [1, 2], [2, 0], [0, 2], [2, 3], [3, 0]])


def test_unique_edges_of_square():
    F = np.array([[0, 1, 2], [0, 2, 3]])
    E, count, edge_of = unique_edges(F)
    np.testing.assert_array_equal(E, [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]])
    np.testing.assert_array_equal(count, [1, 2, 1, 1, 1])
    H = half_edges(F)
    np.testing.assert_array_equal(np.sort(H, axis=1), E[edge_of.ravel()])


@pytest.mark.parametrize("seed", [0, 1])
def test_unique_pairs_is_numpys_unique_of_sorted_rows(seed):
    """The integer-key edge table equals NumPy's row-wise unique of the sorted pairs: edges,
    inverse and counts (pairs repeated, in both directions, vertex 0 and the largest id used)."""
    rng = np.random.default_rng(seed)
    n = 60
    pairs = rng.integers(0, n, size=(400, 2))
    pairs[:3] = [[0, n - 1], [n - 1, 0], [0, n - 1]]
    E, inverse, counts = unique_pairs(pairs, n)
    want = np.unique(np.sort(pairs, axis=1), axis=0, return_inverse=True, return_counts=True)
    for got, ref in zip((E, inverse, counts), want):
        np.testing.assert_array_equal(got, ref.reshape(got.shape))
        assert got.dtype == np.int64
    assert [len(a) for a in unique_pairs(np.zeros((0, 2), np.int64), 0)] == [0, 0, 0]


def test_ranges_are_the_csr_rows_end_to_end():
    start = np.array([0, 2, 2, 5, 6])
    np.testing.assert_array_equal(ranges(start, [3, 0, 2, 1, 0]), [5, 0, 1, 2, 3, 4, 0, 1])
    assert ranges(start, []).shape == (0,) and ranges(start, []).dtype == np.int64


def test_boundary_half_edges_of_square():
    B = boundary_half_edges(np.array([[0, 1, 2], [0, 2, 3]]))
    np.testing.assert_array_equal(B, [[0, 1], [1, 2], [2, 3], [3, 0]])


# ---------------------------------------------------------------- loops


def test_single_triangle_loop():
    (loop,) = boundary_loops(np.array([[4, 7, 5]]))
    assert loop.dtype == np.int64
    assert same_cycle(loop, [4, 7, 5])


def test_square_loop_follows_half_edges():
    (loop,) = boundary_loops(np.array([[0, 1, 2], [0, 2, 3]]))
    assert same_cycle(loop, [0, 1, 2, 3])
    (loop,) = boundary_loops(np.array([[0, 2, 1], [0, 3, 2]]))
    assert same_cycle(loop, [0, 3, 2, 1])


def test_grid_loop_is_counter_clockwise():
    V, F = grid_disk(5, 3)
    (loop,) = boundary_loops(F)
    assert loop.size == 2 * (5 + 3)
    assert polygon_area(V[loop]) == pytest.approx(15.0)
    # consecutive loop vertices are mesh boundary edges
    B = {tuple(e) for e in boundary_half_edges(F)}
    assert all((a, b) in B for a, b in zip(loop, np.roll(loop, -1)))
    (rev,) = boundary_loops(F[:, ::-1])
    assert polygon_area(V[rev]) == pytest.approx(-15.0)


def test_annulus_loops_largest_first():
    V, F = annulus(n_around=12, n_radial=2)
    F = np.concatenate([F, [[F.max() + 1, F.max() + 2, F.max() + 3]]])  # add a stray triangle
    loops = boundary_loops(F)
    assert [len(lp) for lp in loops] == [12, 12, 3]
    outer, inner = (loops[0], loops[1]) if loops[0].min() > 0 else (loops[1], loops[0])
    assert polygon_area(V[outer]) > 0  # outer boundary counter-clockwise
    assert polygon_area(V[inner]) < 0  # hole clockwise


def test_closed_surface_has_no_loops():
    assert boundary_loops(TET_SURFACE) == []
    assert boundary_loops(torus()) == []


@settings(max_examples=30, deadline=None)
@given(
    nx=st.integers(1, 6),
    ny=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
)
def test_loop_invariant_under_relabelling(nx, ny, seed):
    rng = np.random.default_rng(seed)
    V, F = grid_disk(nx, ny)
    loop = check_disk(F, V.shape[0])
    perm = rng.permutation(V.shape[0])  # old index -> new index
    F2 = perm[F][rng.permutation(F.shape[0])]
    shift = rng.integers(0, 3, size=F2.shape[0])  # rotate corners: same orientation
    F2 = np.take_along_axis(F2, (np.arange(3) + shift[:, None]) % 3, axis=1)
    loop2 = check_disk(F2, V.shape[0])
    assert same_cycle(loop2, list(perm[loop]))


# ---------------------------------------------------------------- components


def _strip(n=12, twist=True):
    """A closed band of ``n`` quads (two triangles each), its ends glued straight or with a
    half twist (a Moebius strip); ``(V, F)``, faces wound consistently along the band."""
    t = 2 * np.pi * np.arange(n) / n
    V = np.r_[np.c_[np.cos(t), np.sin(t), np.full(n, -0.2)], np.c_[np.cos(t), np.sin(t), np.full(n, 0.2)]]
    F = []
    for k in range(n):
        a, b, c, d = k, k + 1, n + k, n + k + 1
        if k == n - 1:
            b, d = (n, 0) if twist else (0, n)  # the twist: the last quad meets the first upside down
        F += [[a, b, d], [a, d, c]]
    return V, np.array(F)


def test_orientable_tells_a_moebius_strip_from_a_band_wound_inconsistently():
    from geomopt.exact.topology import orientable, same_side_facets

    V, F = _strip(twist=False)
    assert orientable(F) and same_side_facets(F)[0] == 0
    bad = F.copy()
    bad[5] = bad[5, ::-1]  # one face flipped: inconsistent, still orientable
    assert same_side_facets(bad)[0] > 0 and orientable(bad)
    V, M = _strip(twist=True)
    assert same_side_facets(M)[0] > 0 and not orientable(M)
    M2 = M.copy()
    M2[:7] = M2[:7, ::-1]  # flipping faces does not make a Moebius strip orientable
    assert not orientable(M2)
    assert orientable(np.r_[F, M[:0]]) and not orientable(np.r_[F, M + len(V)])  # per component


def test_an_atlas_of_a_non_orientable_surface_is_refused_saying_so():
    from geomopt.atlas import make_atlas

    V, M = _strip(twist=True)
    with pytest.raises(MeshError, match="non-orientable .* cut it into orientable parts"):
        make_atlas(V, M, progress=False)
    V, F = _strip(twist=False)
    F[5] = F[5, ::-1]
    with pytest.raises(MeshError, match=r"inconsistent face orientation: .*fix_winding\)$"):
        make_atlas(V, F, progress=False)


def test_connected_components_labels():
    F = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6]])
    count, labels = connected_components(F, 8)
    assert count == 2
    assert labels.shape == (8,) and labels.dtype == np.int64
    assert len(set(labels[[0, 1, 2, 3]])) == 1
    assert len(set(labels[[4, 5, 6]])) == 1
    assert labels[0] != labels[4]
    assert labels[7] == -1
    assert set(labels[:7]) == {0, 1}


def test_connected_components_of_tets():
    T = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [5, 6, 7, 8]])
    count, labels = connected_components(T, 9)
    assert count == 2
    assert labels[4] == labels[0] != labels[8]


@settings(max_examples=150, deadline=None)
@given(st.integers(1, 40), st.lists(st.tuples(st.integers(0, 39), st.integers(0, 39)), max_size=70),
       st.randoms(use_true_random=False))
def test_graph_components_partition_as_scipy_does(n, edges, rnd):
    """The same partition as SciPy's csgraph on random graphs (isolated nodes, loops, repeated
    edges, long chains numbered in any order)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as scipy_components

    from geomopt.exact.topology import graph_components

    perm = list(range(n))
    rnd.shuffle(perm)
    chain = [(perm[k], perm[k + 1]) for k in range(n - 1) if rnd.random() < 0.7]
    i, j = (np.array(e, np.int64).reshape(-1) for e in zip(*([(a % n, b % n) for a, b in edges] + chain or [(0, 0)])))
    count, labels = graph_components(n, i, j)
    want, ref = scipy_components(coo_matrix((np.ones(i.size), (i, j)), shape=(n, n)).tocsr(), directed=False)
    assert count == want and labels.shape == (n,) and labels.dtype == np.int64
    assert sorted(set(labels.tolist())) == list(range(count))
    assert len(set(zip(labels.tolist(), ref.tolist()))) == count  # one label of ours per component of SciPy's


# ---------------------------------------------------------------- check_disk


def test_check_disk_accepts_grid():
    V, F = grid_disk(4, 4)
    loop = check_disk(F, V.shape[0])
    assert loop.size == 16


def test_check_disk_checks_the_same_faces_once_and_changed_faces_again(monkeypatch):
    """The command asks whether the mesh is a disk, then parameterize asks again: the second
    answer is the first's (a copy), unless the faces changed, even in place."""
    import geomopt.exact.topology as topology

    V, F = grid_disk(5, 3)
    loop = check_disk(F, len(V))
    monkeypatch.setattr(topology, "_check_manifold_faces", lambda *a: pytest.fail("checked twice"))
    again = check_disk(F.copy(), len(V))
    assert np.array_equal(again, loop) and again is not loop
    again[:] = -1  # the caller's copy: the next answer is still the loop
    assert np.array_equal(check_disk(F, len(V)), loop)
    monkeypatch.undo()
    F[0] = F[0, [1, 0, 2]]  # flipped in place: the same array object, other faces
    with pytest.raises(MeshError, match="orientation"):
        check_disk(F, len(V))
    with pytest.raises(MeshError, match="vertices are not used"):
        check_disk(grid_disk(5, 3)[1], len(V) + 1)  # same faces, another vertex count


@pytest.mark.parametrize(
    "name, expected",
    [("camelhead.off", 56), ("bunny_cut.obj", 744)],
)
def test_check_disk_real_meshes(name, expected):
    path = mesh_path(name)
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.load(path, process=False)
    loop = check_disk(np.asarray(mesh.faces), len(mesh.vertices))
    assert loop.size == expected


def test_non_manifold_edge():
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 5], [1, 2, 6]])
    with pytest.raises(MeshError, match=r"2 non-manifold edges"):
        check_disk(F, 7)


def test_inconsistent_orientation():
    _, F = grid_disk(3, 3)
    F = F.copy()
    F[4] = F[4, ::-1]  # an interior face flipped: its 3 edges clash with neighbours
    with pytest.raises(MeshError, match=r"inconsistent face orientation: 3 edges"):
        check_disk(F, 16)


def test_several_components():
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    with pytest.raises(MeshError, match=r"3 connected components"):
        check_disk(F, 9)


def test_closed_surface():
    with pytest.raises(MeshError, match=r"no boundary.*cut it to a disk first"):
        check_disk(TET_SURFACE, 4)


def test_several_boundary_loops():
    V, F = annulus()
    with pytest.raises(MeshError, match=r"2 boundary loops; a disk has exactly one"):
        check_disk(F, V.shape[0])


def test_bow_tie_on_boundary():
    F = np.array([[0, 1, 2], [0, 3, 4]])
    with pytest.raises(MeshError, match=r"1 non-manifold \(bow-tie\) vertices"):
        check_disk(F, 5)


def test_bow_tie_with_two_closed_fans():
    # vertex 0 is surrounded by two closed fans; no boundary edge touches it
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [0, 4, 5], [0, 5, 6], [0, 6, 4]])
    with pytest.raises(MeshError, match=r"1 non-manifold \(bow-tie\) vertices"):
        check_disk(F, 7)


def test_unreferenced_vertices():
    V, F = grid_disk(2, 2)
    with pytest.raises(MeshError, match=r"2 of 11 vertices are not used.*removed"):
        check_disk(F, V.shape[0] + 2)


def test_genus_one_with_one_hole():
    F = torus(6, 5)[1:]  # remove one face: one boundary loop, chi = -1
    with pytest.raises(MeshError, match=r"= -1, not 1: the surface has genus 1"):
        check_disk(F, 30)


def test_face_repeating_a_vertex():
    with pytest.raises(MeshError, match=r"1 of 2 faces use the same vertex twice"):
        check_disk(np.array([[0, 1, 2], [2, 2, 3]]), 4)


@pytest.mark.parametrize(
    "F, n, match",
    [
        (np.zeros((0, 3), dtype=int), 3, "empty"),
        (np.array([[0, 1]]), 3, r"shape \(m, 3\)"),
        (np.array([[0.0, 1.0, 2.0]]), 3, "integer"),
        (np.array([[0, 1, 3]]), 3, r"1 vertex indices >= n_vertices=3"),
        (np.array([[0, -1, 2]]), 3, "negative"),
        (np.array([[0, 1, 2]]), -1, "non-negative integer"),
    ],
)
def test_bad_input(F, n, match):
    with pytest.raises(MeshError, match=match):
        check_disk(F, n)

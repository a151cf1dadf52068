"""Surface and curve smoothing (issue 52): the exact fold certificate, the fold-safe step, every
method's derivatives, boundary modes, curves, volume preservation and tangential relaxation."""

from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from geomopt import ParameterError
from geomopt._runtime.errors import MeshError
from geomopt.exact.normals import corner_signs, normal_agreement
from geomopt.fairing import FairOptions, certify_folds, describe_folds, fair, fairing_energy, safe_step, smoothed
from geomopt.fairing.surface import closest_points, point_triangle, volume

SOLVED = ("implicit", "least_squares", "energy", "tangential")
METHODS = ("laplacian", "taubin", "implicit", "least_squares", "energy", "spectral", "tangential", "relax")


def icosphere(level=2):
    """The unit icosphere (outward faces), subdivided ``level`` times."""
    t = (1.0 + 5 ** 0.5) / 2.0
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    for _ in range(level):
        V, F = _subdivide(V, F)
    return V / np.linalg.norm(V, axis=1, keepdims=True), F


def _subdivide(V, F):
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(edges, axis=0, return_inverse=True)
    mid = len(V) + inv.reshape(3, -1).T
    V = np.vstack([V, (V[uniq[:, 0]] + V[uniq[:, 1]]) / 2])
    a, b, c = F.T
    ab, bc, ca = mid.T
    return V, np.concatenate([np.stack(x, 1) for x in ([a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca])])


def noisy(V, F, sigma, seed=0):
    """``V`` plus Gaussian noise of ``sigma`` mean edge lengths."""
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    h = np.mean(np.linalg.norm(V[e[:, 1]] - V[e[:, 0]], axis=1))
    return V + sigma * h * np.random.default_rng(seed).normal(size=V.shape)


def cap():
    """The icosphere's faces above z = -0.3: a disk with a boundary."""
    V, F = icosphere(2)
    keep = F[V[F].mean(axis=1)[:, 2] > -0.3]
    used = np.unique(keep)
    new = np.full(len(V), -1)
    new[used] = np.arange(len(used))
    return V[used], new[keep]


def circle(n=60, noise=0.0, seed=0):
    """A closed polyline (n, 2) around the unit circle, noisy."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    V = np.stack([np.cos(a), np.sin(a)], 1) + noise * np.random.default_rng(seed).normal(size=(n, 2))
    return V, np.stack([np.arange(n), (np.arange(n) + 1) % n], 1)


# -- the exact certificate ---------------------------------------------------------------------

def _reference_signs(X, S):
    """``corner_signs`` in rational arithmetic (slow, obviously right)."""
    Q = [[Fraction(float(c)) for c in row] for row in X]

    def sub(a, b):
        return [x - y for x, y in zip(a, b)]

    def direction(s):
        if len(s) == 2:
            return sub(Q[s[1]], Q[s[0]])
        u, v = sub(Q[s[1]], Q[s[0]]), sub(Q[s[2]], Q[s[0]])
        return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]

    dirs = [direction(s) for s in S]
    sums = [[Fraction(0)] * len(dirs[0]) for _ in Q]
    for d, s in zip(dirs, S):
        for v in s:
            sums[v] = [a + b for a, b in zip(sums[v], d)]
    out = np.zeros(S.shape, np.int8)
    for f, s in enumerate(S):
        for k, v in enumerate(s):
            dot = sum(a * b for a, b in zip(dirs[f], sums[v]))
            out[f, k] = (dot > 0) - (dot < 0)
    return out


def test_certificate_accepts_a_clean_sphere_and_catches_a_constructed_fold():
    V, F = icosphere(1)
    assert certify_folds(V, F).ok
    # slide vertex 0 along the surface past its neighbour u: the faces beyond u turn over
    X = V.copy()
    u = F[F[:, 0] == 0][0, 1]
    X[0] = X[0] + 1.6 * (X[u] - X[0])
    cert = certify_folds(X, F)
    assert not cert.ok and cert.inverted > 0 and np.any(np.isin(F[cert.folded], 0))
    assert np.array_equal(corner_signs(X, F), _reference_signs(X, F))


def test_the_fold_message_tells_reversed_degenerate_and_perpendicular_apart():
    """A right-angled tetrahedron's faces are perpendicular to the vertex normal at a corner of
    its slanted face (sign 0, nothing turned over); a zero-area face is degenerate; a face
    turned over is reversed: the certificate counts all three as folds, the message names each."""
    T = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    Ft = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    cert = certify_folds(T, Ft)
    assert cert.inverted == 3 and (corner_signs(T, Ft) >= 0).all()
    assert describe_folds(T, Ft, cert).endswith(": 3 perpendicular to the vertex normal at a corner (zero sign: "
                                                "nothing turned over, but not positively oriented, e.g. a "
                                                "right-angled tetrahedron's faces)")
    V, F = icosphere(1)
    X = V.copy()
    a, b, c = F[0]
    X[c] = X[a]  # a zero normal, exactly
    cert = certify_folds(X, F)
    text = describe_folds(X, F, cert)
    on_ac = int(np.count_nonzero(np.isin(F, [a, c]).sum(axis=1) == 2))  # the faces on edge ac: zero area
    assert f"{on_ac} degenerate (zero area)" in text and on_ac == 2
    u = F[F[:, 0] == 0][0, 1]
    Y = V.copy()
    Y[0] = Y[0] + 1.6 * (Y[u] - Y[0])
    cert = certify_folds(Y, F)
    reversed_ = int(np.count_nonzero((corner_signs(Y, F)[cert.folded] < 0).any(axis=1)))
    assert describe_folds(Y, F, cert).startswith(f"{cert.message}: {reversed_} reversed at a corner") and reversed_
    assert describe_folds(V, F, certify_folds(V, F)) == "no folded face (exact)"


def test_fair_says_why_a_clean_tetrahedron_is_not_certified():
    T = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    res = fair(T, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), "taubin")
    assert not res.success and "perpendicular to the vertex normal" in res.message


@pytest.mark.parametrize("seed", range(3))
def test_corner_signs_are_exact_near_degenerate_configurations(seed):
    """Faces nearly perpendicular to their vertex normals, perturbed by a few ulps: every sign
    equals the rational one (the float filter alone gets some of these wrong)."""
    rng = np.random.default_rng(seed)
    # at vertex 0, n_1 = (0, 0, 1) and n_2 = (0, 1, -1): n_1 . (n_1 + n_2) = 0 before the perturbation
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 1, 1]], float)
    F = np.array([[0, 1, 2], [0, 3, 1]])
    signs = set()
    for _ in range(40):
        X = (V + rng.integers(-3, 4, V.shape) * 2.0**-52) * 3.1
        got = corner_signs(X, F)
        assert np.array_equal(got, _reference_signs(X, F))
        signs.add(int(got[0, 0]))
    assert {-1, 1} <= signs and corner_signs(V, F)[0, 0] == 0  # each side of the threshold, and on it
    E = np.array([[0, 1], [1, 2], [2, 3]])  # a polyline folded back at vertex 1
    P = np.array([[0, 0], [1, 0], [0, 0.4], [0, 1.4]], float)  # d_1 . (d_1 + d_2) = 1 - 1 = 0 at vertex 1
    for _ in range(40):
        X = (P + rng.integers(-3, 4, P.shape) * 2.0**-52) * 0.7
        assert np.array_equal(corner_signs(X, E), _reference_signs(X, E))


def test_corner_signs_at_extreme_scales_and_non_finite():
    V, F = icosphere(1)
    X = V.copy()
    X[0] = X[0] + 1.6 * (X[F[F[:, 0] == 0][0, 1]] - X[0])
    want = corner_signs(X, F)
    assert (want <= 0).any()
    for s in (2.0**-1000, 1e-150, 1e200):
        assert np.array_equal(corner_signs(X * s, F), want)
    X[3] = np.nan
    assert (corner_signs(X, F)[np.isin(F, 3).any(axis=1)] == 0).all()


# -- the fold-safe step ------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["spd", "indefinite", "unsymmetric"])
def test_the_host_solve_equals_a_dense_solve(kind):
    """A symmetric positive-definite free block goes to the Cholesky factorization, any other
    (indefinite, unsymmetric) to LU: each equals the dense solve, the held rows kept."""
    from geomopt.fairing.operators import Sparse
    from geomopt.fairing.solve import linear_solve

    rng = np.random.default_rng(6)
    n = 300
    R = (rng.random((n, n)) < 0.02) * rng.normal(size=(n, n))
    K = {"spd": R @ R.T + n * 0.05 * np.eye(n), "indefinite": R + R.T + np.diag(rng.choice([-3.0, 3.0], n)),
         "unsymmetric": R + 10.0 * np.eye(n)}[kind]  # (its lower triangle, mirrored, is positive definite)
    rows, cols = np.nonzero(K)
    A = Sparse(rows, cols, K[rows, cols], n)
    free = rng.random(n) < 0.8
    b, held = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    x = linear_solve(A, b, free, held)
    F, H = np.flatnonzero(free), np.flatnonzero(~free)
    want = np.linalg.solve(K[np.ix_(F, F)], b[F] - K[np.ix_(F, H)] @ held[H])
    assert np.allclose(x[F], want, rtol=0, atol=1e-10 * np.abs(want).max()) and np.array_equal(x[H], held[H])


@pytest.mark.parametrize("corners", [3, 2])
def test_the_edge_table_is_numpys_unique_rows(corners):
    """``Topology``'s edges (its own sort of integer keys) are ``np.unique`` of the sorted
    vertex pairs, each element's edges index them, and the boundary is the edges used once."""
    from geomopt.fairing.operators import Topology

    rng = np.random.default_rng(corners)
    if corners == 3:
        V, F = icosphere(2)
        F = F[rng.random(len(F)) > 0.2]  # holes: edges used once
        pairs = np.stack([F[:, [1, 2]], F[:, [2, 0]], F[:, [0, 1]]], axis=1).reshape(-1, 2)
    else:
        F = np.unique(np.sort(rng.integers(0, 500, size=(900, 2)), axis=1), axis=0)
        F = F[F[:, 0] != F[:, 1]]
        pairs = F
    topo = Topology.of(F, int(F.max()) + 3)
    edges, inverse, counts = np.unique(np.sort(pairs, axis=1), axis=0, return_inverse=True, return_counts=True)
    assert np.array_equal(topo.edges, edges) and np.array_equal(topo.element_edges.ravel(), inverse.ravel())
    if corners == 3:
        assert np.array_equal(topo.boundary, np.unique(edges[counts == 1]))


@pytest.mark.parametrize("dim", [2, 3])
def test_mean_edge_length_is_the_row_form_bitwise(dim):
    """The mean edge length of NumPy vertices (coordinate rows) is the very float of the row form
    that JAX vertices take (``V[b] - V[a]``, then the norm), and equals the JAX value."""
    from geomopt.fairing.operators import Topology, mean_edge_length

    rng = np.random.default_rng(dim)
    V0, F = (icosphere(0) if dim == 3 else circle(12, noise=0.1))
    topo = Topology.of(F, len(V0))
    for _ in range(20):  # (few edges, of comparable coordinates: a change in rounding shows in the mean)
        V = V0 * rng.uniform(0.5, 2.0, size=V0.shape)
        V[F[::7, 1]] = V[F[::7, 0]]  # zero-length edges
        d = V[topo.edges[:, 1]] - V[topo.edges[:, 0]]
        assert mean_edge_length(V, topo) == float(np.mean(np.sqrt(np.sum(d * d, axis=-1))))
    assert mean_edge_length(V, topo) == pytest.approx(float(mean_edge_length(jnp.asarray(V), topo)), rel=1e-15)


def test_local_signs_equal_the_signs_on_all_vertices():
    """The signs of a few faces, taken on the vertices they use only, are those of
    ``corner_signs`` on the whole surface (whose far vertices may be huge or not finite)."""
    from geomopt.fairing.certificate import local_signs

    V, F = icosphere(3)
    X = noisy(V, F, 0.6, seed=2)
    X[5] = [1e30, 0, 0]
    X[7] = np.nan
    far = ~np.isin(F, [5, 7]).any(axis=1)
    folded = np.unique(F[far][(corner_signs(X, F[far]) <= 0).any(axis=1)])
    stars = F[far & np.isin(F, folded[::20]).any(axis=1)]  # whole stars of a few vertices
    assert 3 * len(np.unique(stars)) < len(V) and (corner_signs(X, stars) <= 0).any()
    for sub in (stars, F[far][:100], F):  # stars, a strip, all
        assert np.array_equal(local_signs(X, sub), corner_signs(X, sub))


def test_safe_step_cuts_a_step_that_would_fold_and_never_adds_a_fold():
    V, F = icosphere(2)
    target = V.copy()
    u = F[F[:, 0] == 5][0, 1]
    target[5] = V[5] + 1.6 * (V[u] - V[5])  # past its neighbour: folds faces
    assert not certify_folds(target, F).ok
    X, t = safe_step(V, target, F, np.ones(len(V), bool))
    assert certify_folds(X, F).ok and 0 < t[5] < 1 and not np.array_equal(X[5], V[5])
    assert np.array_equal(np.delete(X, 5, 0), np.delete(V, 5, 0))


def test_safe_step_from_a_folded_start_with_its_certificate_given():
    """``start=certify_folds(X0)`` (the driver has it) steps exactly as when the signs at ``X0``
    are taken again: its folded corners may stay folded, no other may fold."""
    V, F = icosphere(3)
    X0 = noisy(V, F, 0.5, seed=1)
    before = certify_folds(X0, F)
    assert before.inverted > 10
    X1 = X0 + 0.3 * (V - X0) + 0.05 * np.random.default_rng(2).normal(size=V.shape)
    X, t = safe_step(X0, X1, F, np.ones(len(V), bool))
    Xs, ts, cert = safe_step(X0, X1, F, np.ones(len(V), bool), start=before, certify=True)
    assert np.array_equal(X, Xs) and np.array_equal(t, ts) and 0 < np.count_nonzero(t < 1) < len(V)
    again = certify_folds(X, F)  # the certificate the step ended with is the one taken afresh
    assert cert.inverted > 0 and np.array_equal(cert.folded, again.folded)
    assert np.array_equal(cert.corners, again.corners)


def _whole_mesh_safe_step(X0, X1, S, free, halvings=20):
    """The fold-safe step by its definition, every sign taken on every element at every round."""
    allowed = corner_signs(X0, S) <= 0
    may_turn = allowed.any(axis=1) if S.shape[1] == 3 else np.zeros(len(S), bool)
    t, halved = np.where(free, 1.0, 0.0), np.zeros(len(X0), int)
    while True:
        X = np.where(t[:, None] == 1.0, X1, np.where(t[:, None] == 0.0, X0, X0 + t[:, None] * (X1 - X0)))
        bad = (corner_signs(X, S) <= 0) & ~allowed
        if S.shape[1] == 3:
            bad |= ((normal_agreement(X, X0, S) <= 0) & ~may_turn)[:, None]
        if not bad.any():
            return X, t
        centre = np.zeros(len(X0), bool)
        centre[S[bad.nonzero()]] = True
        star = centre[S].any(axis=1) | bad.any(axis=1)
        cut = np.zeros(len(X0), bool)
        cut[S[star]] = True
        cut &= t > 0
        halved[cut] += 1
        t[cut] = np.where(halved[cut] >= halvings, 0.0, t[cut] * 0.5)


@pytest.mark.parametrize("case", ["sphere", "folded", "boundary", "curve"])
def test_safe_step_equals_its_whole_mesh_definition(case):
    """The fold-safe step re-takes the signs only around the vertices each cut moved (through
    the vertex stars): the same vertices and fractions, bitwise, as taking every sign at every
    round, on steps that fold many faces, from folded starts, with held vertices, on curves."""
    rng = np.random.default_rng(len(case))
    if case == "curve":
        V, F = circle(200, noise=0.02, seed=3)
    else:
        V, F = icosphere(3)
    if case == "boundary":
        F = F[V[F].mean(axis=1)[:, 2] < 0.5]
    X0 = noisy(V, F, 0.4, seed=4) if case == "folded" else V
    h = np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))
    X1 = X0 + (0.1 if case == "folded" else 0.4) * h * rng.normal(size=V.shape)  # folds many corners
    free = rng.random(len(V)) > 0.1
    X, t = safe_step(X0, X1, F, free)
    Xr, tr = _whole_mesh_safe_step(X0, X1, F, free)
    assert np.array_equal(X, Xr) and np.array_equal(t, tr)
    assert 10 < np.count_nonzero(free & (t < 1)) < np.count_nonzero(free) - 10  # many cut, many not


def test_recertified_is_the_certificate_taken_afresh():
    """``recertified`` (the driver's output certificate after fold removal) takes the signs
    again only around the moved vertices: the same folded faces and corners as a fresh
    certificate, where the moves fold and unfold faces, and the base itself where nothing moved."""
    from geomopt.fairing.certificate import recertified

    V, F = icosphere(3)
    X0 = noisy(V, F, 0.4, seed=3)
    base = certify_folds(X0, F)
    rng = np.random.default_rng(4)
    for moved in (np.flatnonzero(V[:, 2] > 0.6), rng.choice(len(V), 5, replace=False)):
        X = X0.copy()
        X[moved] = V[moved] + 0.3 * rng.normal(size=(len(moved), 3)) * 0.1
        fresh = recertified(X, F, base, X0)
        again = certify_folds(X, F)
        assert not np.array_equal(again.corners, base.corners) and fresh.elements == len(F)
        assert np.array_equal(fresh.folded, again.folded) and np.array_equal(fresh.corners, again.corners)
    assert recertified(X0.copy(), F, base, X0) is base


@pytest.mark.parametrize("batch", [1 << 15, 7])
def test_shape_measures_are_the_separate_measures(batch, monkeypatch):
    """``shape_measures`` (one gather, in batches of triangles) gives exactly ``volume``, the
    least ``smallest_angles`` and the largest ``aspect_ratios``, whatever the batch size; the
    angle is the least of ``triangle_angles``."""
    from geomopt.fairing import surface
    from geomopt.fairing.surface import aspect_ratios, shape_measures, smallest_angles, triangle_angles

    monkeypatch.setattr(surface, "BATCH", batch)
    V, F = icosphere(2)
    X = noisy(V, F, 0.3, seed=6)
    vol, angle, aspect = shape_measures(X, F)
    assert (vol, angle, aspect) == (volume(X, F), smallest_angles(X, F).min(), aspect_ratios(X, F).max())
    assert angle == pytest.approx(triangle_angles(X, F).min(), abs=1e-9) and 0.5 < vol / (4 * np.pi / 3) < 1
    assert np.isnan(shape_measures(X, F, closed=False)[0]) and shape_measures(X, F, closed=False)[1:] == (angle, aspect)


def _row_major_measures(V, F):
    """The shape measures by the plain row-major NumPy forms (``V[F]``, ``np.cross``,
    ``np.linalg.norm``, ``np.einsum``): ``(smallest angles (m,), aspect ratios (m,), volume)``."""
    P = np.asarray(V, dtype=np.float64)[F]
    edges = [P[:, (k + 1) % 3] - P[:, k] for k in range(3)]
    squared = [np.einsum("ij,ij->i", e, e) for e in edges]
    k = np.argmin(np.stack([squared[(c + 1) % 3] for c in range(3)], axis=1), axis=1)
    rows = np.arange(len(P))
    u, v = P[rows, (k + 1) % 3] - P[rows, k], P[rows, (k + 2) % 3] - P[rows, k]
    angles = np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.sum(u * v, axis=1)))
    area2 = np.linalg.norm(np.cross(edges[0], -edges[2]), axis=1)
    aspect = np.where(area2 > 0, np.maximum.reduce(squared) / area2 * (np.sqrt(3.0) / 2.0), np.inf)
    return angles, aspect, float(np.sum(np.einsum("ij,ij->i", P[:, 0], np.cross(P[:, 1], P[:, 2]))) / 6.0)


def test_shape_measures_are_the_row_major_forms_bitwise():
    """The coordinate-major shape measures (one-dimensional gathers) give the very floats of the
    row-major forms, on random triangles of any scale, with ties, coincident corners and signed
    zeros (``arctan2(0, -0)`` is 180 degrees: the dot product must be +0 as ``np.sum``'s)."""
    from geomopt.fairing.surface import aspect_ratios, smallest_angles

    rng = np.random.default_rng(3)
    for trial in range(24):
        V = rng.normal(size=(40, 3)) * 10.0 ** rng.integers(-6, 6)
        F = rng.integers(0, 40, size=(300, 3))
        if trial % 3 == 0:
            V = np.round(V * 4 / np.abs(V).max()) / 4  # ties and zero coordinates
        if trial % 4 == 1:
            V[F[::5, 1]] = V[F[::5, 0]]  # coincident corners
        if trial % 4 == 2:
            V[:20] = np.copysign(0.0, rng.normal(size=(20, 3)))  # faces of signed zeros
        with np.errstate(all="ignore"):
            angles, aspect, vol = _row_major_measures(V, F)
            assert np.array_equal(smallest_angles(V, F), angles, equal_nan=True)
            assert np.array_equal(aspect_ratios(V, F), aspect, equal_nan=True)
            assert volume(V, F) == vol or (np.isnan(vol) and np.isnan(volume(V, F)))


def test_a_degenerate_start_face_has_a_failing_corner():
    """The fold-safe step lets faces turn that have a failing corner at the start, and counts on
    that to cover the degenerate ones (normal exactly 0, or a corner not finite): each of those
    has a corner sign of 0."""
    V, F = icosphere(2)
    X = V.copy()
    a, b, c = F[0]
    X[c] = X[a] + 0.25 * (X[b] - X[a])  # collinear: a zero normal
    X[F[40, 0]] = np.nan
    degenerate = normal_agreement(X, X, F) <= 0
    assert degenerate.sum() >= 2 and ((corner_signs(X, F) <= 0).any(axis=1) >= degenerate).all()


def test_safe_step_keeps_every_face_within_90_degrees_of_its_input_normal():
    """A rotation by 100 degrees folds nothing (a rigid motion), but turns faces beyond 90
    degrees from their input normals: those steps are cut."""
    V, F = icosphere(2)
    c, s = np.cos(np.radians(100)), np.sin(np.radians(100))
    target = V @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    assert certify_folds(target, F).ok and (normal_agreement(target, V, F) < 0).any()
    X, t = safe_step(V, target, F, np.ones(len(V), bool))
    assert certify_folds(X, F).ok and (normal_agreement(X, V, F) > 0).all() and (t < 1).any() and (t > 0).any()


def test_normal_agreement_is_exact_at_right_angles():
    rng = np.random.default_rng(0)
    F = np.array([[0, 1, 2]])
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)  # normal z
    Y = np.array([[0, 0, 0], [0, 1, 0], [0, 0, 1]], float)  # normal x: exactly 90 degrees
    assert normal_agreement(X, Y, F)[0] == 0
    for _ in range(30):
        Xp = (X + rng.integers(-3, 4, X.shape) * 2.0**-52) * 1.3
        Yp = (Y + rng.integers(-3, 4, Y.shape) * 2.0**-52) * 0.9
        want = _reference_dot(Xp, Yp)
        assert normal_agreement(Xp, Yp, F)[0] == want


def _reference_dot(X, Y):
    def normal(P):
        Q = [[Fraction(float(c)) for c in row] for row in P]
        u = [Q[1][i] - Q[0][i] for i in range(3)]
        v = [Q[2][i] - Q[0][i] for i in range(3)]
        return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    d = sum(a * b for a, b in zip(normal(X), normal(Y)))
    return (d > 0) - (d < 0)


@pytest.mark.parametrize("method", METHODS)
def test_no_method_folds_heavy_noise_and_the_folds_are_removed(method):
    V, F = icosphere(2)
    X0 = noisy(V, F, 0.5)
    before = corner_signs(X0, F) <= 0
    assert before.any()  # the input is folded
    r = fair(X0, F, method)
    after = corner_signs(r.x, F) <= 0
    assert not (after & ~before).any()  # never a fold added
    if method == "relax":  # the crumpled input *is* the surface it keeps to: its folds stay
        assert r.details.distance <= 1e-6 and r.certificate.inverted <= r.details.folded_before
        return
    assert r.success and r.certificate.inverted == 0 and r.details.folded_before > 0


@pytest.mark.parametrize("method", ["taubin", "least_squares"])
def test_dense_folds_are_all_removed(method):
    """Noise of a whole edge length folds more than half the faces of a 5k-face sphere, in
    clusters: fold removal unfolds every one (a fold-safe step alone leaves most of them)."""
    V, F = icosphere(4)
    X0 = noisy(V, F, 1.0)
    assert certify_folds(X0, F).inverted > 2500
    r = fair(X0, F, method)
    assert r.success and r.certificate.inverted == 0 and r.details.removal_rounds > 0


def test_fold_removal_never_ends_with_more_folded_faces():
    """A sliver-thin spike held at its boundary cannot be unfolded; removal returns no more
    folded faces than it was given, and reports those it traded."""
    from geomopt.fairing import remove_folds
    from geomopt.fairing.operators import Topology

    V, F = cap()
    X0 = noisy(V, F, 1.5, seed=3)
    topo = Topology.of(F, len(V))
    free = topo.free_mask("fixed")
    before = certify_folds(X0, F).inverted
    X, rounds = remove_folds(X0, topo, free)
    assert before > 0 and rounds > 0 and certify_folds(X, F).inverted <= before
    assert np.array_equal(X[~free], X0[~free])


def _whole_mesh_removal(X, topo, free, max_rounds=200):
    """Fold removal by its definition (geomopt.fairing.unfold's notes), every count taken on the
    whole mesh: grow, smooth, keep the parts that fold fewer faces near them, else the whole
    region, else nothing."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    S, n = topo.elements, topo.n
    e = topo.edges
    W = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    A = sp.diags(1.0 / np.maximum(np.asarray(W.sum(axis=1)).ravel(), 1)) @ W

    def grow(mask, rings):
        for _ in range(rings):
            mask = mask | ((W @ mask.astype(float)) > 0)
        return mask

    folded_of = lambda Y: (corner_signs(Y, S) <= 0).any(axis=1)
    folded, rings, rounds = folded_of(X), 1, 0
    while folded.any() and rings <= 16 and rounds < max_rounds:
        seed = np.zeros(n, bool)
        seed[S[folded]] = True
        region = grow(seed, rings) & free
        idx, Y, rounds = np.flatnonzero(region), X.copy(), rounds + 1
        for _ in range(3 * rings):
            Y[idx] = 0.5 * (Y[idx] + A[idx] @ Y)
        inner = sp.csr_matrix(W.multiply(np.outer(region, region)))
        inner.eliminate_zeros()  # (csgraph takes stored zeros for edges)
        label = connected_components(inner, directed=False)[1]
        owner = np.where(region, label, -1)
        for _ in range(2):  # a vertex takes the one part among its own and its neighbours'; -2: several
            seen = [set() for _ in range(n)]
            for v in range(n):
                if owner[v] >= 0:
                    seen[v].add(owner[v])
                    for u in W.indices[W.indptr[v]:W.indptr[v + 1]]:
                        seen[u].add(owner[v])
            owner = np.array([-2 if owner[v] == -2 or len(seen[v]) > 1 else (seen[v] or {-1}).pop() for v in range(n)])
        near = owner[S]  # per part: the faces all of whose corners it owns
        better = [p for p in np.unique(label[region]) if
                  folded_of(Y)[(near == p).all(axis=1)].sum() < folded[(near == p).all(axis=1)].sum()]
        Z = np.where((region & np.isin(label, better))[:, None], Y, X)
        for W_ in (Z, Y):
            if folded_of(W_).sum() < folded.sum():
                X, folded, rings = W_, folded_of(W_), max(1, rings - 1)
                break
        else:
            rings += 1
    return X, rounds


@pytest.mark.parametrize("sigma, boundary", [(3.0, "free"), (1.0, "fixed"), (2.0, "fixed")])
def test_fold_removal_equals_its_whole_mesh_definition(sigma, boundary):
    """Fold removal reads only each round's neighbourhood (vertex stars, region-local parts):
    the same vertices, bitwise, and the same rounds as the whole-mesh definition, on surfaces
    folded in many places (several parts per round), with held vertices."""
    from geomopt.fairing import remove_folds
    from geomopt.fairing.operators import Topology

    V, F = icosphere(3)
    if boundary == "fixed":
        F = F[V[F].mean(axis=1)[:, 2] < 0.5]
    X0 = noisy(V, F, sigma, seed=7)
    topo = Topology.of(F, len(V))
    free = topo.free_mask(boundary)
    X, rounds = remove_folds(X0, topo, free)
    Xr, rounds_r = _whole_mesh_removal(X0, topo, free)
    assert certify_folds(X0, F).inverted > 20 and rounds > 2
    assert rounds == rounds_r and np.array_equal(X, Xr)


def test_a_huge_step_is_cut_not_taken():
    """An unstable Taubin filter (mu far below -lam amplifies the noise) folds its target: the
    steps are cut, the output is not folded."""
    V, F = icosphere(2)
    X0 = noisy(V, F, 0.1)
    assert certify_folds(X0, F).ok
    r = fair(X0, F, options=FairOptions(method="taubin", lam=0.9, mu=-1.9, steps=20))
    assert r.success and certify_folds(r.x, F).ok and not np.array_equal(r.x, X0)
    assert not certify_folds(r.details.target, F).ok and r.details.cut > 0


# -- derivatives -------------------------------------------------------------------------------

def _fd_check(f, x, direction, value=None, tol=1e-6):
    """Central difference of ``f`` along ``direction`` against ``value`` (the AD derivative)."""
    eps = 1e-6
    fd = (f(x + eps * direction) - f(x - eps * direction)) / (2 * eps)
    assert abs(fd - value) <= tol * max(1.0, abs(fd)), (fd, value)


@pytest.mark.parametrize("method, laplacian", [("laplacian", "cotangent"), ("taubin", "uniform"),
                                               ("implicit", "cotangent"), ("least_squares", "uniform"),
                                               ("least_squares", "cotangent"), ("energy", "cotangent"),
                                               ("tangential", None)])
@pytest.mark.parametrize("surface", ["closed", "boundary"])
def test_grad_through_the_smoothing_matches_finite_differences_of_re_solves(method, laplacian, surface):
    V, F = icosphere(1) if surface == "closed" else cap()
    V = noisy(V, F, 0.1, seed=3)
    o = FairOptions(method=method, laplacian=laplacian, steps=3 if method != "implicit" else 2)
    c = np.random.default_rng(1).normal(size=V.shape)

    def loss(X):
        return jnp.sum(jnp.sin(smoothed(X, F, o)) * c)

    g = jax.grad(loss)(jnp.asarray(V))
    d = np.random.default_rng(2).normal(size=V.shape)
    _fd_check(lambda X: float(np.sum(np.sin(smoothed(X, F, o)) * c)), V, d, float(np.sum(np.asarray(g) * d)))


@pytest.mark.parametrize("method, field", [("energy", "weight"), ("implicit", "time"), ("laplacian", "lam"),
                                           ("least_squares", "weight"), ("tangential", "weight")])
def test_grad_with_respect_to_the_weights(method, field):
    V, F = cap()
    V = noisy(V, F, 0.1)
    c = np.random.default_rng(1).normal(size=V.shape)
    base = {"weight": 0.3, "time": 0.7, "lam": 0.4}[field]

    def loss(w):
        return jnp.sum(smoothed(jnp.asarray(V), F, FairOptions(method=method, **{field: w})) * c)

    g = float(jax.grad(loss)(jnp.asarray(base)))
    _fd_check(lambda w: float(np.sum(smoothed(V, F, FairOptions(method=method, **{field: w})) * c)), base, 1.0, g)


def test_grad_under_jit():
    V, F = icosphere(1)
    o = FairOptions(method="energy")
    g = jax.jit(jax.grad(lambda X: jnp.sum(smoothed(X, F, o) ** 2)))(jnp.asarray(V))
    assert np.isfinite(np.asarray(g)).all()


@pytest.mark.parametrize("method", ["laplacian", "implicit", "least_squares", "energy", "tangential"])
def test_energy_gradient_matches_finite_differences_and_vanishes_at_the_target(method):
    V, F = icosphere(1)
    V = noisy(V, F, 0.2)
    o = FairOptions(method=method, crease_angle=30.0 if method == "least_squares" else None)
    E = fairing_energy(V, F, o)
    p = noisy(V, F, 0.3, seed=5)
    g = np.asarray(jax.grad(E)(jnp.asarray(p)))
    d = np.random.default_rng(4).normal(size=V.shape)
    _fd_check(lambda q: float(E(q)), p, d, float(np.sum(g * d)))
    if method != "laplacian":  # the solve's target is the energy's minimiser
        target = smoothed(V, F, dataclasses_replace(o, boundary="free"))
        assert np.abs(np.asarray(jax.grad(E)(jnp.asarray(target)))).max() < 1e-9 * max(1.0, np.abs(g).max())


def dataclasses_replace(o, **kw):
    import dataclasses

    return dataclasses.replace(o, **kw)


# -- boundaries, curves, volume, components ----------------------------------------------------

def test_boundary_modes():
    V, F = cap()
    X0 = noisy(V, F, 0.2)
    from geomopt.fairing.operators import Topology

    b = Topology.of(F, len(V)).boundary
    fixed = fair(X0, F, "taubin", options=FairOptions(boundary="fixed")).x
    free = fair(X0, F, "taubin", options=FairOptions(boundary="free")).x
    curve = fair(X0, F, "taubin", options=FairOptions(boundary="curve")).x
    assert np.array_equal(fixed[b], X0[b]) and not np.allclose(free[b], X0[b]) and not np.allclose(curve[b], X0[b])

    def roughness(X):  # the boundary loop's second differences
        from geomopt.exact.topology import boundary_loops

        loop = boundary_loops(F)[0]
        P = X[loop]
        return np.linalg.norm(np.roll(P, 1, 0) + np.roll(P, -1, 0) - 2 * P, axis=1).mean()

    assert roughness(curve) < 0.5 * roughness(X0)


def test_curves_closed_and_open():
    V, E = circle(80, noise=0.02)
    r = fair(V, E, options=FairOptions(method="taubin", steps=50))
    rough = lambda X: np.linalg.norm(np.roll(X, 1, 0) + np.roll(X, -1, 0) - 2 * X, axis=1).mean()  # noqa: E731
    assert r.success and rough(r.x) < 0.3 * rough(V)
    open_ = E[:-1]
    r = fair(V, open_, "laplacian")
    assert r.success and np.array_equal(r.x[[0, 79]], V[[0, 79]])  # the ends held
    r = fair(V, open_, "laplacian", options=FairOptions(boundary="free"))
    assert not np.array_equal(r.x[[0, 79]], V[[0, 79]])
    for method in ("implicit", "energy", "spectral", "least_squares"):
        assert fair(np.c_[V, np.zeros(80)], E, method).success  # 3D curves too


def test_laplacian_steps_shrink_a_curve_and_taubin_does_not():
    V, E = circle(100)
    area = lambda X: 0.5 * np.sum(X[:, 0] * np.roll(X[:, 1], -1) - np.roll(X[:, 0], -1) * X[:, 1])  # noqa: E731
    lap = fair(V, E, options=FairOptions(method="laplacian", steps=50)).x
    tau = fair(V, E, options=FairOptions(method="taubin", steps=50)).x
    assert area(lap) < 0.95 * area(V) and abs(area(tau) - area(V)) < 0.1 * (area(V) - area(lap))


def test_volume_preservation():
    V, F = icosphere(2)
    X0 = noisy(V, F, 0.2)
    shrunk = fair(X0, F, "laplacian")
    kept = fair(X0, F, "laplacian", options=FairOptions(preserve_volume=True))
    v0 = volume(X0, F)
    assert volume(shrunk.x, F) < 0.95 * v0 and abs(volume(kept.x, F) - v0) < 1e-9 * v0 and kept.success
    with pytest.raises(ParameterError, match="closed"):
        fair(*cap(), "laplacian", options=FairOptions(preserve_volume=True))


def test_several_components_are_smoothed_each_on_its_own():
    V, F = icosphere(2)
    Y = noisy(V, F, 0.2)
    r = fair(np.vstack([Y, Y + 4.0]), np.vstack([F, F + len(V)]), "energy")
    one = fair(Y, F, "energy")
    assert r.success and np.allclose(r.x[:len(V)], one.x, atol=1e-12)
    assert np.allclose(r.x[len(V):], one.x + 4.0, atol=1e-12)


def test_least_squares_feature_weights_keep_creases():
    """A cube's edges and corners stay much closer with a crease angle than without."""
    import trimesh

    box = trimesh.creation.box().subdivide().subdivide()
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    X0 = noisy(V, F, 0.05)
    corners = np.flatnonzero((np.abs(V) > 0.49).all(axis=1))
    plain = fair(X0, F, "least_squares").x
    sharp = fair(X0, F, "least_squares", options=FairOptions(crease_angle=45.0)).x
    err = lambda X: np.linalg.norm(X[corners] - V[corners], axis=1).mean()  # noqa: E731
    assert err(sharp) < 0.5 * err(plain)


# -- tangential relaxation ---------------------------------------------------------------------

def test_closest_points_match_brute_force():
    V, F = cap()
    P = np.random.default_rng(0).normal(size=(200, 3)) * 0.8
    Q, face = closest_points(P, V, F)
    for i in range(0, 200, 7):
        all_q = point_triangle(np.repeat(P[i:i + 1], len(F), 0), V[F[:, 0]], V[F[:, 1]], V[F[:, 2]])
        best = np.min(np.linalg.norm(all_q - P[i], axis=1))
        assert abs(np.linalg.norm(Q[i] - P[i]) - best) < 1e-12


def test_closest_points_in_batches_equal_one_batch(monkeypatch):
    """The points are searched in batches of ``CHUNK`` (memory): the same answer as one batch."""
    from geomopt.fairing import surface

    V, F = cap()
    P = np.random.default_rng(1).normal(size=(100, 3)) * 0.8
    Q, face = closest_points(P, V, F)
    monkeypatch.setattr(surface, "CHUNK", 7)
    Q7, face7 = closest_points(P, V, F)
    assert np.array_equal(Q, Q7) and np.array_equal(face, face7)


def _brute_distances(P, V, F):
    """(p,) each point's distance to every face, the least (no search)."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.array([np.linalg.norm(point_triangle(np.repeat(p[None], len(F), 0), A, B, C) - p, axis=1).min()
                     for p in P])


def _awkward_surface():
    """A thin, warped sphere: faces of sizes over about 50x (several radius buckets) and two
    sides 0.04 apart, so a point's nearest vertex is often on the far side of its closest face."""
    V, F = icosphere(3)
    V = V * np.exp(2.0 * V[:, :1]) * [1.0, 1.0, 0.02]
    return V, F


@pytest.mark.parametrize("neighbours", [16, 1])
def test_closest_points_are_exact_on_an_awkward_surface(monkeypatch, neighbours):
    """Both stages of the search (the nearest vertex's faces, then every face within reach, by a
    nearest-neighbour query or, past ``NEIGHBOURS`` centroids, a ball query) find the closest
    face: the distance equals the brute-force one, for points on, near and far from the surface."""
    from geomopt.fairing import surface

    monkeypatch.setattr(surface, "NEIGHBOURS", neighbours)
    V, F = _awkward_surface()
    rng = np.random.default_rng(3)
    on = surface._samples(V, F[rng.choice(len(F), 60)], 3)[::3]
    P = np.concatenate([on, on + 0.03 * rng.normal(size=on.shape), rng.normal(size=(40, 3)) * 3.0])
    Q, face = closest_points(P, V, F)
    got = np.linalg.norm(Q - P, axis=1)
    want = _brute_distances(P, V, F)
    assert np.all(np.abs(got - want) <= 1e-14 * (1 + want))
    back = point_triangle(P, V[F[face, 0]], V[F[face, 1]], V[F[face, 2]])  # Q lies on the face reported
    assert np.allclose(back, Q, atol=1e-14)


@pytest.mark.parametrize("scale", [1e-200, 1e-150, 1e150, 1e200])
def test_point_triangle_is_scale_free(scale):
    """The region tests multiply four coordinate differences: at coordinates near 1e-150 they
    underflow and near 1e+150 overflow unless each row is scaled first; the closest points
    scale with the inputs (relative rounding only), in every region (faces, edges, corners)."""
    rng = np.random.default_rng(5)
    P, A, B, C = (rng.normal(size=(500, 3)) * (2.0 if k == 0 else 1.0) for k in range(4))
    want = point_triangle(P, A, B, C) * scale
    got = point_triangle(P * scale, A * scale, B * scale, C * scale)
    assert np.all(np.abs(got - want) <= 1e-13 * scale)


@pytest.mark.parametrize("scale", [1e-200, 1e200])
def test_closest_points_and_face_distances_are_scale_free(scale):
    """The search's squared distances neither underflow nor overflow at tiny or huge coordinates:
    closest points, face distances and the largest one scale with the inputs."""
    from geomopt.fairing.surface import face_distances, largest_face_distance

    V, F = _awkward_surface()
    rng = np.random.default_rng(6)
    P = rng.normal(size=(100, 3))
    X = V + 1e-3 * rng.normal(size=V.shape)
    Q, face = closest_points(P, V, F)
    Qs, faces = closest_points(P * scale, V * scale, F)
    assert np.all(np.abs(Qs - Q * scale) <= 1e-13 * scale)
    want = face_distances(X, F, V, F)
    assert np.all(np.abs(face_distances(X * scale, F, V * scale, F) - want * scale) <= 1e-13 * scale)
    assert abs(largest_face_distance(X * scale, F, V * scale, F) - want.max() * scale) <= 1e-13 * scale


def test_closest_points_refuse_non_finite_points_and_empty_surfaces():
    """NaN or infinite query points or surface vertices, and a surface without faces, are refused
    with a ParameterError (not a silently wrong point, nor an IndexError deep in the search)."""
    V, F = icosphere(1)
    for P in ([[np.nan, 0.0, 0.0]], [[0.0, np.inf, 0.0]]):
        with pytest.raises(ParameterError, match="finite"):
            closest_points(np.array(P), V, F)
    bad = V.copy()
    bad[F[0, 0]] = np.nan
    with pytest.raises(ParameterError, match="finite"):
        closest_points(V[:3], bad, F)
    with pytest.raises(ParameterError, match="face"):
        closest_points(V[:3], V, np.zeros((0, 3), np.int64))
    assert closest_points(np.zeros((0, 3)), V, F)[0].shape == (0, 3)


def test_face_distances_with_enough_decide_the_tolerance_as_the_exact_ones():
    """``face_distances(..., enough=tol) > tol`` equals the exact decision (a face may get an
    upper bound only when it is within ``tol``), and ``largest_face_distance`` is the exact max."""
    from geomopt.fairing.surface import face_distances, largest_face_distance

    V, F = _awkward_surface()
    rng = np.random.default_rng(4)
    X = V + 1e-3 * rng.normal(size=V.shape) * (rng.random((len(V), 1)) < 0.2)  # a few vertices off
    exact = face_distances(X, F, V, F)
    for tol in (1e-4, 1e-3, 3e-3):
        quick = face_distances(X, F, V, F, enough=tol)
        assert np.array_equal(quick > tol, exact > tol) and 0 < np.count_nonzero(exact > tol) < len(F)
        assert np.array_equal(quick[exact > tol], exact[exact > tol])
    size = 1e-14 * 2 * np.abs(V).max()
    assert exact.max() <= largest_face_distance(X, F, V, F) <= exact.max() + size and exact.max() > 1e-3
    still = face_distances(V, F, V, F).max()  # rounding errors only
    assert still <= largest_face_distance(V, F, V, F) <= still + size


def test_smallest_angles_are_the_least_of_the_three():
    """``smallest_angles`` (the angle opposite the shortest edge only) equals the least of
    ``triangle_angles``, on random, near-equilateral and sliver triangles."""
    from geomopt.fairing.surface import smallest_angles, triangle_angles

    rng = np.random.default_rng(5)
    V = np.concatenate([rng.normal(size=(300, 3)), np.repeat([[0, 0, 0], [1, 0, 0], [0.5, 3 ** 0.5 / 2, 0]], 30, 0)
                        + 1e-9 * rng.normal(size=(90, 3))])
    F = np.concatenate([rng.integers(0, 300, (2000, 3)), np.arange(300, 390).reshape(-1, 3)])
    assert np.allclose(smallest_angles(V, F), triangle_angles(V, F).min(axis=1), rtol=0, atol=1e-9)


def test_relax_keeps_a_real_mesh_on_its_surface():
    """The camel head (folded in places by the certificate, slivers): every face within 1e-6 of
    the input (so only its flat parts move), no fold added, no angle made smaller."""
    import geomopt

    V, F = geomopt.data.load("camelhead")
    before = corner_signs(V, F) <= 0
    r = fair(V, F, "relax", options=FairOptions(steps=10))
    assert before.any() and r.details.distance <= 1e-6 and not ((corner_signs(r.x, F) <= 0) & ~before).any()
    assert r.details.min_angle_after >= r.details.min_angle_before and not np.array_equal(r.x, V)


def test_relax_improves_shapes_and_stays_on_the_input_surface():
    V, F = cap()
    rng = np.random.default_rng(0)
    X0, _ = closest_points(V + 0.2 * np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))
                           * rng.normal(size=V.shape) * [1, 1, 0], V, F)  # irregular, on the surface
    from geomopt.fairing.operators import Topology

    b = Topology.of(F, len(V)).boundary
    assert certify_folds(X0, F).ok
    r = fair(X0, F, "relax", options=FairOptions(steps=20, surface_tolerance=1e-2))
    d = r.details
    assert r.success and d.min_angle_after > d.min_angle_before + 5 and d.aspect_after < d.aspect_before
    assert 1e-6 < d.distance <= 1e-2 and np.array_equal(r.x[b], X0[b])
    r = fair(X0, F, "relax", options=FairOptions(steps=20))  # the default bound: faces within 1e-6
    assert r.success and r.details.distance <= 1e-6 and np.array_equal(r.x[b], X0[b])


def test_relax_on_a_creased_sheet_improves_shapes_within_the_bound():
    """An irregular sheet bent 90 degrees along a crease: flat on each side, so the vertices
    move along it, but the crease and the boundary stay and no face leaves the input by more
    than 1e-6 of the box."""
    g = np.linspace(0.0, 1.0, 13)
    u, v = np.meshgrid(g, g, indexing="ij")
    rng = np.random.default_rng(1)
    inner = (u > 0) & (u < 1) & (v > 0) & (v < 1) & ~np.isclose(u, 0.5)
    u = u + np.where(inner, 0.3 * (g[1] - g[0]) * rng.uniform(-1, 1, u.shape), 0.0)
    v = v + np.where(inner, 0.3 * (g[1] - g[0]) * rng.uniform(-1, 1, v.shape), 0.0)
    u, v = u.ravel(), v.ravel()
    X0 = np.stack([np.minimum(u, 0.5), v, np.maximum(u - 0.5, 0.0)], axis=1)  # bent at u = 0.5
    k = np.arange(12 * 13).reshape(12, 13)[:, :12].ravel()
    F = np.concatenate([np.stack([k, k + 13, k + 1], 1), np.stack([k + 1, k + 13, k + 14], 1)])
    crease = np.flatnonzero(np.isclose(u, 0.5))
    r = fair(X0, F, "relax", options=FairOptions(steps=10, crease_angle=45.0))
    d = r.details
    assert r.success and d.distance <= 1e-6 and d.min_angle_after > d.min_angle_before + 5
    assert np.array_equal(r.x[crease], X0[crease])


# -- options and errors ------------------------------------------------------------------------

def test_bad_options_and_meshes_raise_clear_errors():
    with pytest.raises(ParameterError, match="method"):
        FairOptions(method="bilateral")
    with pytest.raises(ParameterError, match="mu < -lam"):
        FairOptions(method="taubin", lam=0.5, mu=-0.4)
    with pytest.raises(ParameterError, match="weight"):
        FairOptions(weight=0.0)
    with pytest.raises(MeshError, match="triangles"):
        fair(np.zeros((4, 3)), np.zeros((2, 4), int))
    with pytest.raises(ParameterError, match="not differentiable"):
        smoothed(*icosphere(0), FairOptions(method="relax"))
    V, F = icosphere(0)
    for k in range(3):  # a triangle that repeats a vertex, at each pair of corners
        G = F.copy()
        G[5, k] = G[5, (k + 1) % 3]
        with pytest.raises(MeshError, match="repeats a vertex"):
            fair(V, G)
    with pytest.raises(MeshError, match="repeats a vertex"):
        fair(np.zeros((4, 2)), np.array([[0, 1], [2, 2]]))


# -- the command line --------------------------------------------------------------------------

def _write_off(path, V, F):
    with open(path, "w") as fh:
        fh.write(f"OFF\n{len(V)} {len(F)} 0\n")
        fh.writelines(f"{float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in V)
        fh.writelines(f"3 {a} {b} {c}\n" for a, b, c in F)


def test_cli_writes_a_certified_obj_and_exits_by_the_rules(cli, tmp_path):
    import json

    from geomopt import io

    V, F = icosphere(2)
    X0 = noisy(V, F, 0.4)
    _write_off(tmp_path / "in.off", X0, F)
    out = tmp_path / "out.obj"
    code, stdout, _ = cli("fair", tmp_path / "in.off", "-o", out, "--method", "least_squares", "--weight", "0.5",
                          "--json", "--quiet")
    summary = json.loads(stdout)
    W, G = io.read_mesh(out)
    assert code == 0 and np.array_equal(G, F) and certify_folds(W, G).ok and summary["folded_after"] == 0
    assert summary["method"] == "least_squares" and summary["folded_before"] > 0
    # bad input: exit 2, nothing written
    code, _, err = cli("fair", tmp_path / "in.off", "-o", tmp_path / "bad.obj", "--method", "taubin", "--mu", "-0.1")
    assert code == 2 and "mu < -lam" in err and not (tmp_path / "bad.obj").exists()
    with pytest.raises(SystemExit) as usage:  # argparse's refusal
        cli("fair", tmp_path / "in.off", "-o", tmp_path / "bad.obj", "--method", "spectral", "--eigenvectors", "0")
    assert usage.value.code == 2 and not (tmp_path / "bad.obj").exists()


def test_cli_exits_1_and_writes_nothing_when_a_fold_cannot_be_removed(cli, tmp_path):
    """Two triangles folded onto each other, every vertex on the (held) boundary."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.7, 1, 0.01]], float)
    F = np.array([[0, 1, 2], [0, 3, 1]])
    assert not certify_folds(V, F).ok
    _write_off(tmp_path / "in.off", V, F)
    code, _, err = cli("fair", tmp_path / "in.off", "-o", tmp_path / "out.obj")
    assert code == 1 and "not certified" in err and not (tmp_path / "out.obj").exists()
    with pytest.raises(Exception, match="could not all be removed"):
        fair(V, F, throw=True)

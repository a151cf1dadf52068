"""The float filter of :mod:`geomopt.exact.normals`: every sign it reports equals the exact one
(rational arithmetic), on random elements and on near-degenerate ones where float64 alone
gets signs wrong (folded fans whose vertex normal nearly vanishes, backtracking polylines),
at coordinate scales from 1e-200 to 1e+150 and far from the origin."""

from fractions import Fraction

import numpy as np
import pytest

from geomopt.exact.normals import corner_signs, normal_agreement


def _direction(P):
    """The exact direction of an element with corners ``P`` (Fractions): normal or edge vector."""
    if len(P) == 2:
        return [P[1][i] - P[0][i] for i in range(len(P[0]))]
    u = [P[1][i] - P[0][i] for i in range(3)]
    v = [P[2][i] - P[0][i] for i in range(3)]
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def _sign(x):
    return (x > 0) - (x < 0)


def reference_corner_signs(X, S):
    """``corner_signs`` in rational arithmetic (finite ``X`` only)."""
    Q = [[Fraction(float(c)) for c in row] for row in X]
    dirs = [_direction([Q[i] for i in s]) for s in S]
    sums = [[Fraction(0)] * X.shape[1] for _ in Q]
    for s, d in zip(S, dirs):
        for v in s:
            sums[v] = [a + b for a, b in zip(sums[v], d)]
    return np.array([[_sign(sum(a * b for a, b in zip(d, sums[v]))) for v in s] for s, d in zip(S, dirs)], np.int8)


def folded_fans(k, rng, tilt, place=lambda X: X):
    """``k`` disjoint pairs of faces ``(v, a, b)``, ``(v, b, a')`` with ``a'`` within ``tilt``
    (relative) of ``a``: the second face nearly the first turned over, so the vertex normals at
    ``v`` and ``b`` (the sum of the two) nearly vanish and their signs hang on the last bits.
    ``place``: maps the random corners (scaled, moved) before ``a'`` is taken."""
    base = place(rng.normal(size=(k, 3, 3)))
    a2 = base[:, 1] + tilt * rng.normal(size=(k, 3)) * np.abs(base[:, 1])
    X = np.concatenate([base, a2[:, None]], axis=1).reshape(-1, 3)
    o = 4 * np.arange(k)[:, None]
    S = np.concatenate([o + [0, 1, 2], o + [0, 2, 3]])
    return X, S


def backtracking_curves(k, rng, tilt, dim, place=lambda X: X):
    """``k`` disjoint open polylines ``a, b, a'`` with ``a'`` within ``tilt`` of ``a``: the
    tangent at ``b`` nearly vanishes (``place`` as in :func:`folded_fans`)."""
    a, b = place(rng.normal(size=(k, dim))), place(rng.normal(size=(k, dim)))
    a2 = a + tilt * rng.normal(size=(k, dim)) * np.abs(a)
    X = np.stack([a, b, a2], axis=1).reshape(-1, dim)
    o = 3 * np.arange(k)[:, None]
    return X, np.concatenate([o + [0, 1], o + [1, 2]])


CASES = {
    "random triangles": lambda rng, place: (place(rng.normal(size=(60, 3))),
                                            rng.permuted(np.tile(np.arange(60), (3, 40)).T, axis=1)),
    "folded fans": lambda rng, place: folded_fans(80, rng, 1e-16, place),
    "folded fans, tilt 3e-16": lambda rng, place: folded_fans(80, rng, 3e-16, place),
    "folded fans, tilt 1e-12": lambda rng, place: folded_fans(40, rng, 1e-12, place),
    "folded fans, exact fold": lambda rng, place: folded_fans(20, rng, 0.0, place),
    "backtracking curves 2d": lambda rng, place: backtracking_curves(100, rng, 1e-16, 2, place),
    "backtracking curves 3d": lambda rng, place: backtracking_curves(100, rng, 3e-16, 3, place),
}
#: how the coordinates are placed: scaled to the edges of float64's range, or far from the
#: origin (then the differences round)
PLACES = {"unit": lambda X: X, "1e-200": lambda X: X * 1e-200, "1e+150": lambda X: X * 1e150,
          "offset": lambda X: X + 1e4}


@pytest.mark.parametrize("place", sorted(PLACES))
@pytest.mark.parametrize("case", sorted(CASES))
def test_corner_signs_equal_the_rational_signs(case, place):
    X, S = CASES[case](np.random.default_rng(sorted(CASES).index(case)), PLACES[place])
    assert np.isfinite(X).all() and np.abs(X).min() > 0
    assert np.array_equal(corner_signs(X, S), reference_corner_signs(X, S))


def test_the_near_degenerate_cases_need_more_than_float64():
    """The cases above are ones that a float64 evaluation alone gets wrong (so the filter's
    bound is what keeps the signs exact there)."""
    wrong = 0
    for case in ("folded fans", "backtracking curves 2d"):
        X, S = CASES[case](np.random.default_rng(0), PLACES["unit"])
        dirs = np.cross(X[S[:, 1]] - X[S[:, 0]], X[S[:, 2]] - X[S[:, 0]]) if S.shape[1] == 3 else X[S[:, 1]] - X[S[:, 0]]
        sums = np.zeros_like(X)
        for c in range(S.shape[1]):
            np.add.at(sums, S[:, c], dirs)
        naive = np.sign(np.einsum("md,mkd->mk", dirs, sums[S]))
        wrong += np.count_nonzero(naive != reference_corner_signs(X, S))
    assert wrong > 0


@pytest.mark.parametrize("scale", [1.0, 1e-200, 1e150, "offset"])
def test_normal_agreement_equals_the_rational_signs(scale):
    """Pairs of faces at nearly 90 degrees (the second turned by a right angle, then moved in its
    last bits)."""
    rng = np.random.default_rng(7)
    k = 80
    X = rng.normal(size=(k, 3, 3))
    n = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    axis = np.cross(n, rng.normal(size=(k, 3)))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    # a rotation by 90 degrees about an axis in the face's plane: the normal turns a right angle
    Y = (np.cross(axis[:, None], X) + axis[:, None] * np.einsum("kd,kjd->kj", axis, X)[..., None])
    Y = Y * (1 + 1e-15 * rng.normal(size=Y.shape))
    X, Y = X.reshape(-1, 3), Y.reshape(-1, 3)
    X, Y = (X + 1e4, Y + 1e4) if scale == "offset" else (X * scale, Y * scale)
    F = np.arange(3 * k).reshape(-1, 3)
    want = [_sign(sum(a * b for a, b in zip(_direction([[Fraction(float(c)) for c in X[i]] for i in f]),
                                            _direction([[Fraction(float(c)) for c in Y[i]] for i in f]))))
            for f in F]
    assert np.array_equal(normal_agreement(X, Y, F), want)


@pytest.mark.parametrize("place", sorted(PLACES))
@pytest.mark.parametrize("case", ["random triangles", "folded fans", "folded fans, exact fold"])
def test_signs_and_agreement_share_the_first_directions(case, place):
    """``signs_and_agreement`` (one float pass over ``X``'s normals for both) gives the rational
    corner signs of ``X`` and the rational agreement of its normals with ``Y``'s, where ``Y`` is
    ``X`` moved in its last bits (near-degenerate agreement) or turned over."""
    from geomopt.exact.normals import signs_and_agreement

    rng = np.random.default_rng(11)
    X, S = CASES[case](rng, PLACES[place])
    for Y in (X * (1 + 1e-15 * rng.normal(size=X.shape)), X[:, ::-1].copy()):
        signs, agreement = signs_and_agreement(X, Y, S)
        assert np.array_equal(signs, reference_corner_signs(X, S))
        want = [_sign(sum(a * b for a, b in zip(_direction([[Fraction(float(c)) for c in X[i]] for i in f]),
                                                _direction([[Fraction(float(c)) for c in Y[i]] for i in f]))))
                for f in S]
        assert np.array_equal(agreement, want) and np.array_equal(agreement, normal_agreement(X, Y, S))

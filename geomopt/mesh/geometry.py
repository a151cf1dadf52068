"""Batched simplex geometry in JAX, written once: edge matrices and their determinants.

The sign of ``det`` of the edge matrix ``[x1-x0, ..., xd-x0]`` is an element's orientation
(float; :mod:`geomopt.exact.predicates` gives the exact one).

**Cones over the origin.**  Simplices ``S`` (m, d) with only d vertices in d dimensions (a
triangle of a surface mapped to the sphere, :meth:`geomopt.Problem.sphere`) stand for the
simplex ``(0, S[:, 0], ..., S[:, d-1])`` with its apex at the origin: their edge matrix is
``[x_a, x_b, x_c]``, whose determinant is the triangle's orientation about the centre.  So
orientations, the injective search's bound (a cubic in the step) and its float guard need no
special case.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["edge_rows", "det", "dets", "chord_jacobians"]


def edge_rows(S, x):
    """(m, d, d) edge vectors of simplices ``S`` (m, d+1) under ``x`` (n, d), one per row; for
    cones over the origin (``S`` (m, d), see the module notes) the vertex positions themselves."""
    X = x[S]
    if S.shape[1] == x.shape[-1]:
        return X
    return X[:, 1:] - X[:, :1]


def det(M):
    """Determinant of (..., d, d) matrices, d = 2 or 3, by cofactors (vectorises on CPU)."""
    if M.shape[-1] == 2:
        return M[..., 0, 0] * M[..., 1, 1] - M[..., 0, 1] * M[..., 1, 0]
    return (
        M[..., 0, 0] * (M[..., 1, 1] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 1])
        - M[..., 0, 1] * (M[..., 1, 0] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 0])
        + M[..., 0, 2] * (M[..., 1, 0] * M[..., 2, 1] - M[..., 1, 1] * M[..., 2, 0])
    )


def dets(S, x):
    """(m,) orientation determinants of simplices ``S`` under ``x`` (positive = valid)."""
    return det(edge_rows(S, x))


def chord_jacobians(X, Minv):
    """(m, 2, 2) Jacobians of surface triangles mapped onto the unit sphere.

    ``X`` (m, 3, 3): rows are the images ``x_a, x_b, x_c`` of each triangle's corners (any
    nonzero length: each is projected to ``y = x / |x|``); ``Minv`` (m, 2, 2): the inverse
    rest edge matrices in the triangles' local frames.  The chord triangle ``(y_a, y_b, y_c)``
    is projected onto the plane orthogonal to its centroid direction ``n`` (the tangent plane
    of the sphere there), in a frame ``(e1, e2)`` with ``e1 x e2 = n``.  For small triangles
    this is the chord triangle itself up to O(h^2); its determinant has the sign of
    ``det[y_a, y_b, y_c]`` (the orientation about the centre) and vanishes with it, so a
    barrier energy blows up where the injective search stops (a triangle reaching a great
    circle), and every density of 2x2 Jacobians applies unchanged."""
    Y = X / jnp.linalg.norm(X, axis=-1, keepdims=True)
    n = jnp.sum(Y, axis=1)
    n = n / jnp.linalg.norm(n, axis=-1, keepdims=True)
    E = jnp.swapaxes(Y[:, 1:] - Y[:, :1], 1, 2)  # (m, 3, 2) chord edges as columns
    e1 = E[..., 0] - jnp.sum(E[..., 0] * n, axis=-1, keepdims=True) * n
    e1 = e1 / jnp.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = jnp.cross(n, e1)
    frame = jnp.stack([e1, e2], axis=1)  # (m, 2, 3)
    return frame @ E @ Minv

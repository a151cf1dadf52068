"""Batched simplex geometry in JAX, written once: edge matrices and their determinants.

The sign of ``det`` of the edge matrix ``[x1-x0, ..., xd-x0]`` is an element's orientation
(float; :mod:`geomopt.predicates` gives the exact one).
"""

from __future__ import annotations

import jax.numpy as jnp


def edge_rows(S, x):
    """(m, d, d) edge vectors of simplices ``S`` (m, d+1) under ``x`` (n, d), one per row."""
    X = x[S]
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

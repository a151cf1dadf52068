"""The rest mesh as untangling measures it: checked locally injective up front
(:func:`check_rest`), badly shaped 2D rest triangles replaced by equilateral ones
(:func:`badly_shaped`, :func:`equilateral_rest`)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._runtime.errors import MeshError
from ..mesh.problem import Problem
from ..mesh.quality import triangle_areas

__all__ = ["badly_shaped", "equilateral_rest", "equilateral_problem", "check_rest"]


def _aspect_ratio(P):
    """(m,) aspect ratio ``lmax (l1+l2+l3) / (4 sqrt(3) area)`` of triangles P (m, 3, k); 1 = equilateral."""
    l = np.linalg.norm(P[:, [1, 2, 0]] - P, axis=2)
    area = triangle_areas(P)
    with np.errstate(divide="ignore", invalid="ignore"):
        return l.max(1) * l.sum(1) / (4.0 * np.sqrt(3.0) * area)


def badly_shaped(problem: Problem, max_aspect: float | None) -> np.ndarray:
    """(m,) bool: the rest triangles whose aspect ratio is above ``max_aspect``, which
    untangling replaces by equilateral ones (:func:`equilateral_rest`); none in 3D, for
    quads or with ``max_aspect`` None."""
    if max_aspect is None or problem.dim != 2 or problem.elements is not None:
        return np.zeros(problem.n_elements, bool)
    return _aspect_ratio(np.asarray(problem.rest_vertices)[problem.simplices]) > max_aspect


def equilateral_rest(problem: Problem, bad: np.ndarray):
    """``(rest_inv, volumes)`` of ``problem`` with the ``bad`` rest triangles replaced by
    equilateral ones of their mean edge length (as Garanzha et al.'s 2D code does).  NumPy for
    NumPy arrays, else JAX: traceable in the problem's arrays (:func:`geomopt.untangling.implicit.untangle_map`)."""
    arrays = (problem.rest_vertices, problem.rest_inv, problem.volumes)
    xp = np if all(isinstance(a, np.ndarray) for a in arrays) else jnp
    E = problem.rest_vertices[problem.simplices]
    a = xp.mean(xp.linalg.norm(E[:, [1, 2, 0]] - E, axis=2), axis=1)
    Dm = a[:, None, None] * xp.array([[[1.0, 0.5], [0.0, 0.5 * np.sqrt(3.0)]]])
    safe = xp.where(bad[:, None, None], Dm, xp.eye(2)[None])  # no inverse of a degenerate kept triangle
    rest_inv = xp.where(bad[:, None, None], xp.linalg.inv(safe), problem.rest_inv)
    return rest_inv, xp.where(bad, np.sqrt(3.0) / 4.0 * a * a, problem.volumes)


def equilateral_problem(problem: Problem, max_aspect: float) -> Problem:
    """``problem`` with :func:`equilateral_rest` applied to its :func:`badly_shaped` triangles."""
    bad = badly_shaped(problem, max_aspect)
    if not bad.any():
        return problem
    rest_inv, vol = equilateral_rest(problem, bad)
    return dataclasses.replace(problem, rest_inv=rest_inv, volumes=vol)


def check_rest(problem: Problem) -> None:
    """MeshError (one line) when the rest mesh of a triangle (planar) or tet problem is not
    locally injective (exact, :meth:`Problem.certify` of the rest vertices): every element is
    measured against it, and its fold is no fault of the handles or of the start map."""
    if problem.kind not in ("planar", "tet"):
        return
    cert = problem.certify(np.asarray(problem.rest_vertices, dtype=np.float64))
    if not cert.ok:
        raise MeshError(f"the rest mesh itself is not locally injective: {cert.message}; untangling measures every "
                        f"element against the rest mesh, so fix the rest mesh (e.g. rest.vtk, or the 'v' lines)")

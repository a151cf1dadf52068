"""Element quality of a map: sizes relative to the mean and the scaled Jacobian.

Two numbers say how good a flip-free map is, whatever the rest mesh:

* the **size ratio** of an element: its signed area / volume divided by the mean absolute one
  over the mesh (1 everywhere for a uniform mesh; the smallest one is what untangling tends to
  sacrifice);
* the **scaled Jacobian** (Knupp 2000; Verdict's ``scaled_jacobian``): the smallest, over the
  element's corners, of the determinant of its edge vectors at that corner divided by the
  product of their lengths, normalised so that the equilateral triangle / regular tetrahedron
  scores 1.  It lies in [-1, 1] and is negative for an inverted element.

P. Knupp, "Achieving finite element mesh quality via optimization of the Jacobian matrix
norm and associated quantities", Int. J. Numer. Meth. Eng. 48, 2000.
"""

from __future__ import annotations

import numpy as np

__all__ = ["size_ratios", "scaled_jacobians", "element_quality", "quality_summary", "triangle_symmetric_dirichlet",
           "triangle_areas"]

#: the corners' edge vectors: corner i of a simplex and the vertices it is joined to, in an
#: order whose determinant has the simplex's orientation
_CORNERS = {2: ((0, 1, 2), (1, 2, 0), (2, 0, 1)),
            3: ((0, 1, 2, 3), (1, 2, 0, 3), (2, 0, 1, 3), (3, 0, 2, 1))}
_NORMALISE = {2: 2.0 / np.sqrt(3.0), 3: np.sqrt(2.0)}


def _edge_dets(P):
    """(m,) determinants of the edge matrices ``P[:, 1:] - P[:, :1]`` of simplices P (m, d+1, d)."""
    E = P[:, 1:] - P[:, :1]
    if P.shape[2] == 2:
        return E[:, 0, 0] * E[:, 1, 1] - E[:, 0, 1] * E[:, 1, 0]
    return np.einsum("mi,mi->m", E[:, 0], np.cross(E[:, 1], E[:, 2]))


def size_ratios(x, simplices) -> np.ndarray:
    """(m,) signed size of each simplex of ``x`` (n, d) over the mean absolute size."""
    D = _edge_dets(np.asarray(x, np.float64)[np.asarray(simplices)])
    scale = float(np.mean(np.abs(D)))
    return D / scale if scale > 0 else np.full(len(D), np.nan)


def scaled_jacobians(x, simplices, orientation: int = 1) -> np.ndarray:
    """(m,) scaled Jacobian of each simplex (triangles in the plane or tetrahedra): 1 for the
    regular simplex, 0 for a degenerate one, negative for one not oriented as ``orientation``."""
    P = np.asarray(x, np.float64)[np.asarray(simplices)]
    d = P.shape[2]
    best = np.full(len(P), np.inf)
    for order in _CORNERS[d]:
        Q = P[:, order]
        lengths = np.prod(np.linalg.norm(Q[:, 1:] - Q[:, :1], axis=2), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            sj = np.where(lengths > 0, orientation * _edge_dets(Q) / lengths, 0.0)
        best = np.minimum(best, sj)
    return np.clip(best * _NORMALISE[d], -1.0, 1.0)


def element_quality(x, simplices, orientation: int = 1) -> dict:
    """Summary of :func:`size_ratios` and :func:`scaled_jacobians` of ``x`` (n, d) on
    ``simplices`` (m, d+1), counted positive in ``orientation`` (+1, or -1 for simplices listed
    clockwise, as a LIM case may be): ``min_size_ratio``, ``min_scaled_jacobian`` and
    ``mean_scaled_jacobian`` (floats)."""
    sj = scaled_jacobians(x, simplices, orientation)
    return {"min_size_ratio": float(np.min(orientation * size_ratios(x, simplices))),
            "min_scaled_jacobian": float(np.min(sj)), "mean_scaled_jacobian": float(np.mean(sj))}


def quality_summary(problem, x) -> dict:
    """The figures ``geomopt untangle`` reports of a map ``x`` (n, d) of ``problem`` (a
    :class:`~geomopt.Problem` of any kind of element), keyed as
    :meth:`geomopt.mesh.elements.ElementCertificate.summary`: ``elements``, ``invalid`` (elements
    without a positive Jacobian everywhere, exact), ``corner_only`` (hexahedra valid at their
    corners only), ``tests`` (which validity test decided how many elements), ``sj_min``,
    ``sj_mean``, ``sj_below_0`` and ``sj_below_0_2`` (scaled Jacobians: of the quads / hexahedra,
    :func:`geomopt.mesh.elements.scaled_jacobian`, or of the simplices, :func:`scaled_jacobians`)."""
    if problem.elements is not None:
        from .elements import certify_elements

        return certify_elements(x, problem.elements).summary()
    sj = scaled_jacobians(x, problem.simplices)
    return {"elements": len(sj), "invalid": problem.count_inverted(x), "corner_only": 0, "tests": {},
            "sj_min": float(sj.min()), "sj_mean": float(sj.mean()), "sj_below_0": int(np.count_nonzero(sj < 0)),
            "sj_below_0_2": int(np.count_nonzero(sj < 0.2))}


def triangle_areas(P) -> np.ndarray:
    """(m,) unsigned areas of the triangles ``P`` (m, 3, d), in the plane (d = 2) or in space
    (d = 3): half the length of the edges' cross product."""
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    if P.shape[2] == 2:
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def triangle_symmetric_dirichlet(P, Q) -> np.ndarray:
    """(m,) symmetric Dirichlet ``|J|_F^2 + |J^-1|_F^2`` of the affine maps from the triangles
    ``P`` (m, 3, d) onto the triangles ``Q`` (m, 3, d'), in 2D or 3D alike (from the metric
    tensors of the two triangles: ``tr(G^-1 H) + tr(H^-1 G)``); ``inf`` where ``Q`` has no area.
    Orientation is not looked at."""
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    f1, f2 = Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0]
    g11, g12, g22 = np.sum(e1 * e1, 1), np.sum(e1 * e2, 1), np.sum(e2 * e2, 1)
    h11, h12, h22 = np.sum(f1 * f1, 1), np.sum(f1 * f2, 1), np.sum(f2 * f2, 1)
    det_g, det_h = g11 * g22 - g12 * g12, h11 * h22 - h12 * h12  # 4 area^2 each
    tr = g22 * h11 - 2 * g12 * h12 + g11 * h22
    with np.errstate(divide="ignore", invalid="ignore"):
        out = tr / det_g + tr / det_h
    return np.where(det_h > 0, out, np.inf)

"""The figures an atlas is judged by, computed from per-corner UVs alone, so that any atlas
(geomopt's or another tool's) is measured the same way: charts, seams and their 3D length,
area-weighted mean symmetric Dirichlet (4 at an isometry) of the scale-normalised map, the
worst triangle, packing efficiency and mirrored charts; and where the seams run
(:func:`seam_metrics`): how exposed they are and how much they turn."""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from ..exact.topology import unique_edges
from ..mesh.quality import triangle_areas, triangle_symmetric_dirichlet

__all__ = ["AtlasMetrics", "atlas_metrics", "uv_charts", "seam_edges", "face_symmetric_dirichlet",
           "SeamMetrics", "seam_metrics", "seam_turning"]


@dataclasses.dataclass(frozen=True)
class AtlasMetrics:
    """Figures of an atlas (see :func:`atlas_metrics`)."""

    charts: int
    seam_length: float
    mean_symmetric_dirichlet: float
    worst_symmetric_dirichlet: float
    efficiency: float
    mirrored_charts: int


def uv_charts(uv_faces) -> tuple:
    """``(count, chart)``: the charts of an atlas, faces joined by shared UV vertices; ``chart``
    (m,) int64."""
    from scipy.sparse.csgraph import connected_components

    T = np.asarray(uv_faces, dtype=np.int64)
    m, n = len(T), int(T.max()) + 1
    f = np.repeat(np.arange(m), 3)
    graph = sp.coo_matrix((np.ones(3 * m, dtype=np.int8), (f, m + T.ravel())), shape=(m + n, m + n))
    _, label = connected_components(graph.tocsr(), directed=False)
    _, chart = np.unique(label[:m], return_inverse=True)
    return int(chart.max()) + 1, chart.astype(np.int64)


def seam_edges(F, uv_faces) -> np.ndarray:
    """(s, 2) int64 interior edges of the mesh ``F`` (m, 3) whose two faces do not share both
    UV vertices of the edge (``uv_faces`` (m, 3), per-corner UV ids), as sorted vertex pairs."""
    F, T = np.asarray(F, dtype=np.int64), np.asarray(uv_faces, dtype=np.int64)
    E, count, edge_of = unique_edges(F)
    # per half-edge: the UV ids at its start and end, ordered by the mesh vertex ids
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    ta, tb = T.ravel(), np.roll(T, -1, axis=1).ravel()
    lo_uv, hi_uv = np.where(a < b, ta, tb), np.where(a < b, tb, ta)
    e = edge_of.ravel()
    n_uv = int(T.max()) + 1
    key = lo_uv * n_uv + hi_uv
    kinds = np.unique(np.stack([e, key], axis=1), axis=0)
    per_edge = np.bincount(kinds[:, 0], minlength=len(E))
    return E[(count == 2) & (per_edge > 1)]


def face_symmetric_dirichlet(V, F, uv, uv_faces) -> np.ndarray:
    """(m,) symmetric Dirichlet ``|J|_F^2 + |J^-1|_F^2`` of each triangle, the UVs first scaled
    so that their total (unsigned) area equals the 3D area; ``inf`` on a collapsed triangle."""
    V, uv = np.asarray(V, dtype=np.float64), np.asarray(uv, dtype=np.float64)
    P, Q = V[np.asarray(F)], uv[np.asarray(uv_faces)]
    A3, A2 = triangle_areas(P), triangle_areas(Q)
    s = np.sqrt(A3.sum() / A2.sum())
    return np.where(A2 > 0, triangle_symmetric_dirichlet(P, s * Q), np.inf)


def atlas_metrics(V, F, uv, uv_faces) -> AtlasMetrics:
    """The :class:`AtlasMetrics` of per-corner UVs ``uv`` (k, 2), ``uv_faces`` (m, 3) on the
    mesh ``V`` (n, 3), ``F`` (m, 3).  Efficiency is the UV area over the area of the bounding
    square of all UVs; a chart is mirrored when its total signed UV area is negative."""
    V, uv, F, T = (np.asarray(V, dtype=np.float64), np.asarray(uv, dtype=np.float64),
                   np.asarray(F, dtype=np.int64), np.asarray(uv_faces, dtype=np.int64))
    count, chart = uv_charts(T)
    seams = seam_edges(F, T)
    Q = uv[T]
    f1, f2 = Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0]
    signed = 0.5 * (f1[:, 0] * f2[:, 1] - f1[:, 1] * f2[:, 0])
    used = uv[np.unique(T)]
    side = float(np.ptp(used, axis=0).max())
    sd = face_symmetric_dirichlet(V, F, uv, T)
    A3 = triangle_areas(V[F])
    return AtlasMetrics(
        charts=count,
        seam_length=float(np.linalg.norm(V[seams[:, 1]] - V[seams[:, 0]], axis=1).sum()),
        mean_symmetric_dirichlet=float(np.sum(A3 * sd) / A3.sum()),
        worst_symmetric_dirichlet=float(sd.max()),
        efficiency=float(np.abs(signed).sum() / side ** 2) if side > 0 else 0.0,
        mirrored_charts=int(np.count_nonzero(np.bincount(chart, signed, minlength=count) < 0)),
    )


@dataclasses.dataclass(frozen=True)
class SeamMetrics:
    """Where the seams of an atlas run (see :func:`seam_metrics`).

    Attributes
    ----------
    visibility : the seam edges' length-weighted mean ambient visibility over that of all edges
        (1: as exposed as the average edge, a random cut; lower: hidden); nan without seams.
    turning_degrees : mean turning angle where a seam passes through a vertex (0: straight);
        nan where no seam passes through a vertex.
    """

    visibility: float
    turning_degrees: float


def seam_turning(V, seams) -> float:
    """Mean turning angle in degrees at the vertices where exactly two of the ``seams`` (s, 2)
    meet (where a seam passes through): the angle between one seam edge's direction and the
    next's, 0 on a straight seam; nan when there is no such vertex.  Seam ends and branch
    vertices (one or three and more seam edges) do not count."""
    V, S = np.asarray(V, dtype=np.float64), np.asarray(seams, dtype=np.int64).reshape(-1, 2)
    degree = np.bincount(S.ravel(), minlength=len(V))
    ends = S.ravel()
    other = S[:, ::-1].ravel()
    through = degree[ends] == 2
    v, w = ends[through], other[through]
    order = np.argsort(v, kind="stable")
    v, w = v[order].reshape(-1, 2), w[order].reshape(-1, 2)  # each through vertex twice, in a row
    if not len(v):
        return float("nan")
    a = V[v[:, 0]] - V[w[:, 0]]  # arriving from one neighbour
    b = V[w[:, 1]] - V[v[:, 1]]  # leaving to the other
    cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).mean())


def seam_metrics(V, F, seams, rays: int = 96) -> SeamMetrics:
    """The :class:`SeamMetrics` of the ``seams`` (s, 2) (vertex pairs, e.g. :func:`seam_edges`)
    of the mesh ``V`` (n, 3), ``F`` (m, 3).  Visibility: each edge's ambient visibility is the
    fraction of ``rays`` rays from its midpoint over the hemisphere around the mean of its two
    vertices' normals, from ``1e-5`` of the bounding box's diagonal off the surface, that leave
    the mesh (:func:`~geomopt.atlas.visibility.edge_visibility`)."""
    from .visibility import edge_visibility

    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    S = np.sort(np.asarray(seams, dtype=np.int64).reshape(-1, 2), axis=1)
    E, _, _ = unique_edges(F)
    length = np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
    n = len(V)
    on = np.isin(E[:, 0] * n + E[:, 1], S[:, 0] * n + S[:, 1])
    if not on.any():
        return SeamMetrics(float("nan"), float("nan"))
    vis = edge_visibility(V, F, E, rays)
    ratio = (np.sum(length[on] * vis[on]) / length[on].sum()) / (np.sum(length * vis) / length.sum())
    return SeamMetrics(float(ratio), seam_turning(V, S))

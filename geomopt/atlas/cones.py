"""Where a chart needs more cuts: a cheap estimate of the distortion a chart would flatten with,
and greedy cone cuts that relieve it.

A flattening concentrates its area distortion where the surface's Gaussian curvature (the angle
defect ``K``) is.  For a conformal flattening with log length scale ``u`` the discrete Yamabe
equation (Springborn, Schroeder & Pinkall 2008; Ben-Chen, Gotsman & Bunin 2008) gives, to first
order, ``L u = -K`` at interior vertices, ``L`` the positive semi-definite cotangent Laplacian;
with ``u = 0`` on the boundary this is the minimal-area-distortion flattening of boundary first
flattening (Sawhney & Crane 2017).  A conformal map scaling areas by ``s = exp(2 u)`` has symmetric
Dirichlet density ``2 (s + 1 / s)``: the estimate used to rank charts and pick cone vertices, the
vertex of largest ``|u|`` (after the best uniform scale) being where a cut to the seams relieves
the most (the greedy of Sheffer & Hart's Seamster and of Gu, Gortler & Hoppe's geometry images).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.special import logsumexp

from ..mesh.quality import triangle_areas

__all__ = ["angle_defects", "corner_angles", "cotan_laplacian", "log_scale", "scale_estimate", "ChartScale"]


def corner_angles(V, F):
    """(m, 3) interior angle at each corner."""
    P = V[F]
    a = P[:, [1, 2, 0]] - P
    b = P[:, [2, 0, 1]] - P
    cross = np.linalg.norm(np.cross(a, b), axis=2)
    return np.arctan2(cross, np.sum(a * b, axis=2))


def angle_defects(V, F, angles=None) -> np.ndarray:
    """(n,) ``2 pi`` minus the angles around each vertex (the boundary's included: callers use
    interior vertices only); ``angles``: :func:`corner_angles` of ``V``, ``F`` when known."""
    angles = corner_angles(V, F) if angles is None else angles
    return 2 * np.pi - np.bincount(F.ravel(), angles.ravel(), minlength=len(V))


def cotan_laplacian(V, F, angles=None) -> sp.csr_matrix:
    """(n, n) positive semi-definite cotangent Laplacian ``sum w_ij (u_i - u_j)^2 / 2``
    (``angles`` as :func:`angle_defects`)."""
    ang = corner_angles(V, F) if angles is None else angles
    cot = 0.5 / np.tan(np.clip(ang, 1e-8, np.pi - 1e-8))
    # the corner c sees the edge (c + 1, c + 2)
    i = F[:, [1, 2, 0]].ravel()
    j = F[:, [2, 0, 1]].ravel()
    w = cot.ravel()
    n = len(V)
    W = sp.coo_matrix((np.r_[w, w], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    return (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()


def _solve(A, rhs):
    """``A^-1 rhs`` for a Dirichlet block of a cotangent Laplacian (positive definite): a sparse
    Cholesky factorization (armadillo's 42k rows: 0.14 s against SuperLU's 0.22 s), SuperLU
    when round-off leaves it not quite positive definite (many obtuse triangles)."""
    from scipy.sparse.linalg import spsolve

    from ..linalg.linsolve import NotPositiveDefinite, spd_solve

    try:
        return spd_solve(A, rhs)
    except NotPositiveDefinite:
        return spsolve(A.tocsc(), rhs)


def log_scale(V, F, boundary, angles=None) -> np.ndarray:
    """(n,) first-order log length scale ``u`` of the minimal-area-distortion conformal
    flattening (module doc): ``u = 0`` on ``boundary`` (vertex ids); a closed mesh (no boundary)
    spreads its total curvature over the area and gets ``u`` of zero mean.

    Parameters
    ----------
    V : (n, 3) float;  F : (m, 3) int;  boundary : (b,) int vertex ids;  angles : (m, 3) the
        :func:`corner_angles` of ``V``, ``F`` when known (a chart's, gathered from its surface's).
    """
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    angles = corner_angles(V, F) if angles is None else angles
    n = len(V)
    L = cotan_laplacian(V, F, angles)
    K = angle_defects(V, F, angles)
    L = L + 1e-10 * sp.diags(np.asarray(abs(L).sum(axis=1)).ravel())  # obtuse-mesh safety
    u = np.zeros(n)
    if len(boundary) == 0:
        area = np.bincount(F.ravel(), np.repeat(triangle_areas(V[F]) / 3, 3), minlength=n)
        rhs = -(K - area * K.sum() / area.sum())
        free = np.arange(1, n)
        u[free] = _solve(L[free][:, free], rhs[free])
        return u - np.average(u, weights=area)
    free = np.setdiff1d(np.arange(n), boundary)
    if len(free):
        u[free] = _solve(L[free][:, free], -K[free])
    return u


def scale_estimate(V, F, u):
    """The symmetric Dirichlet a conformal map of log scale ``u`` (n,) would have, at its best
    uniform scale.

    Returns
    -------
    mean : float, area-weighted mean density (4 at an isometry).
    vertex_log_area : (n,) log area scale at each vertex after the best uniform scale.
    """
    A = triangle_areas(V[F])
    t = 2 * u[F].mean(axis=1)  # log of each triangle's area scale s
    # c = sqrt(sum A / s / sum A s) minimises sum A (c s + 1 / (c s)); in logs, since the scales of
    # a long chart's conformal map span more than a float's range (a box of 1000 x 1 x 1)
    log_c = 0.5 * (logsumexp(-t, b=A) - logsumexp(t, b=A))
    with np.errstate(over="ignore"):  # a distortion beyond float64's range is inf
        mean = float(np.sum(A * 4 * np.cosh(t + log_c)) / A.sum())  # 2 (c s + 1 / (c s))
    return mean, 2 * u + log_c


class ChartScale:
    """:func:`log_scale` of one chart as cone cuts add to its boundary, with one symbolic analysis
    of its sparse Cholesky factorization: a cut keeps the chart's faces and only fixes more
    vertices at ``u = 0``, so each later Dirichlet system is the first one with those rows and
    columns decoupled (their off-diagonal entries zero, kept in the pattern, and a zero
    right-hand side): the same pattern, factored again numerically with the first analysis (the
    fill-reducing ordering, which costs more than the factorization at 10^5 rows).  The solution
    is the restricted system's (up to rounding).  Another chart's faces, or a vertex freed, are
    analysed afresh.

    Call it as :func:`log_scale`, with the labels of the chart's vertices and faces (input vertex
    and face ids, ``ids`` (n,) and ``faces`` (m,)): an interior vertex keeps its label across cuts
    (a cut splits only the vertices it passes through, which it fixes).
    """

    def __init__(self):
        self._chol = None

    def __call__(self, V, F, boundary, angles, ids, faces) -> np.ndarray:
        free = np.setdiff1d(np.arange(len(V)), boundary)
        if len(boundary) == 0 or len(free) == 0:
            return log_scale(V, F, boundary, angles)
        labels, faces = np.asarray(ids)[free], np.sort(np.asarray(faces))
        u = np.zeros(len(V))
        if self._chol is not None and np.array_equal(faces, self._faces):
            pos = np.minimum(np.searchsorted(self._labels, labels), len(self._labels) - 1)
            if np.array_equal(self._labels[pos], labels):
                x = self._refactored(pos)
                if x is not None:
                    u[free] = x[pos]
                    return u
        return self._analysed(V, F, free, labels, angles, faces)

    def _refactored(self, pos):
        """The solution with only the rows ``pos`` free (the others fixed at 0), or None when
        the factorization fails."""
        from ..linalg.linsolve import NotPositiveDefinite

        fixed = np.ones(len(self._labels), dtype=bool)
        fixed[pos] = False
        data = np.where(fixed[self._rows] | fixed[self._cols], 0.0, self._data)
        keep = self._diag[fixed]
        data[keep] = self._data[keep]  # a decoupled row keeps its diagonal: the system stays definite
        try:
            self._chol.factor(data)
            return self._chol.solve(np.where(fixed, 0.0, self._rhs))
        except NotPositiveDefinite:
            return None

    def _analysed(self, V, F, free, labels, angles, faces):
        from ..linalg.linsolve import NotPositiveDefinite, SparseCholesky

        V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
        angles = corner_angles(V, F) if angles is None else angles
        L = cotan_laplacian(V, F, angles)
        K = angle_defects(V, F, angles)
        L = L + 1e-10 * sp.diags(np.asarray(abs(L).sum(axis=1)).ravel())  # as log_scale
        order = free[np.argsort(labels, kind="stable")]  # the rows by label: found again by search
        lower = sp.tril(L[order][:, order]).tocsc()
        lower.sort_indices()
        u = np.zeros(len(V))
        try:
            chol = SparseCholesky(lower.indptr, lower.indices, ordering="amd" if len(order) < 300_000 else "metis")
            chol.factor(lower.data)
            u[order] = chol.solve(-K[order])
        except NotPositiveDefinite:
            self._chol = None
            u[free] = _solve(L[free][:, free], -K[free])
            return u
        self._chol, self._labels, self._faces, self._rhs = chol, np.sort(labels), faces, -K[order]
        self._data, self._rows = lower.data.copy(), lower.indices
        self._cols = np.repeat(np.arange(len(order)), np.diff(lower.indptr))
        self._diag = np.full(len(order), -1, dtype=np.int64)
        on = self._rows == self._cols
        self._diag[self._cols[on]] = np.flatnonzero(on)
        return u

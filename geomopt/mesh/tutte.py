"""Tutte (barycentric) embeddings of disk meshes onto the unit circle.

The boundary loop is pinned to the unit circle by cumulative arc length and every
interior vertex is placed at a weighted average of its neighbours, which is one
sparse linear solve.  With positive weights and a convex boundary the result has no
flipped triangles (Tutte 1963; Floater, "One-to-one piecewise linear mappings over
triangulations", Math. Comp. 2003), which makes it the standard flip-free starting
point for distortion-minimising parameterization.  :func:`scale_to_area` and
:func:`optimal_scale` size such a start for an energy.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._runtime.errors import MeshError, NotPositiveDefinite, ParameterError
from .._runtime.tracing import refuse_traced
from .._runtime.validate import validate_vertices
from .._runtime.x64 import float64
from ..exact.topology import as_faces, check_disk
from .quality import triangle_areas

__all__ = ["tutte_embedding", "tutte_weights", "weighted_embedding", "scale_to_area", "optimal_scale", "WEIGHTS", "circle_boundary"]

WEIGHTS = ("uniform", "mean_value")


def _as_3d(V: np.ndarray) -> np.ndarray:
    return V if V.shape[1] == 3 else np.pad(V, ((0, 0), (0, 1)))


def _checked_input(V, F, weights):
    """Validated ``(V, F)`` after checking the weights name."""
    if weights not in WEIGHTS:
        raise ParameterError(
            f"unknown Tutte weights {weights!r}; valid: {', '.join(map(repr, WEIGHTS))}"
        )
    V = validate_vertices(V, "V")
    return V, as_faces(F, V.shape[0])


def tutte_weights(V, F, weights: str = "uniform") -> sp.csr_matrix:
    """Positive edge weights of the Tutte embedding, as a sparse matrix.

    Parameters
    ----------
    V : (n, 2) or (n, 3) float array
        Rest vertex positions.
    F : (m, 3) int array
    weights : {"uniform", "mean_value"}
        ``"uniform"``: ``w_ij = 1`` for every edge (symmetric).
        ``"mean_value"``: Floater's ``w_ij = (tan(a/2) + tan(b/2)) / |x_i - x_j|``,
        ``a, b`` the angles at ``x_i`` of the two triangles beside edge ``ij``
        (not symmetric).

    Returns
    -------
    W : (n, n) scipy.sparse.csr_matrix
        ``W[i, j] > 0`` for every edge ``ij``, zero diagonal; rows are not normalised.
    """
    V, F = _checked_input(V, F, weights)
    n = V.shape[0]
    # corner c of face f: vertex i, followed by j and k counter-clockwise; each (m, 3)
    i, j, k = F, np.roll(F, -1, axis=1), np.roll(F, -2, axis=1)
    if weights == "uniform":
        # each undirected edge appears in 1 or 2 faces: count each once per direction
        rows = np.concatenate([i.ravel(), j.ravel()])
        cols = np.concatenate([j.ravel(), i.ravel()])
        W = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
        W.data[:] = 1.0
        return W
    X = _as_3d(V)
    e1, e2 = X[j] - X[i], X[k] - X[i]  # (m, 3, 3): at corner i, the two edges
    l1, l2 = np.linalg.norm(e1, axis=-1), np.linalg.norm(e2, axis=-1)
    sin_part = np.linalg.norm(np.cross(e1, e2), axis=-1)
    cos_part = np.einsum("...d,...d->...", e1, e2)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_half = sin_part / (l1 * l2 + cos_part)  # tan(angle / 2) = sin / (1 + cos)
        w1, w2 = tan_half / l1, tan_half / l2
    if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
        raise MeshError(
            "mean-value weights are undefined: the rest mesh has zero-length edges or "
            "180-degree angles; fix the rest mesh or use weights='uniform'"
        )
    rows = np.concatenate([i.ravel(), i.ravel()])
    cols = np.concatenate([j.ravel(), k.ravel()])
    return sp.csr_matrix((np.concatenate([w1.ravel(), w2.ravel()]), (rows, cols)), shape=(n, n))


def circle_boundary(V: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Boundary positions on the unit circle by cumulative arc length, ``(k, 2)``."""
    seg = np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1)
    if not (seg > 0).all():
        raise MeshError(
            f"{int((seg <= 0).sum())} boundary edges have zero length; "
            "merge the coincident boundary vertices first"
        )
    t = np.concatenate([[0.0], np.cumsum(seg)[:-1]]) / seg.sum()
    theta = 2.0 * np.pi * t
    return np.stack([np.cos(theta), np.sin(theta)], axis=1)


def _as_loop(boundary, n: int) -> np.ndarray:
    loop = np.asarray(boundary)
    if loop.ndim != 1 or loop.dtype.kind not in "iu" or loop.size < 3:
        raise MeshError(
            f"boundary must be a 1D integer array of at least 3 vertex indices, "
            f"got dtype {loop.dtype} shape {loop.shape}"
        )
    loop = loop.astype(np.int64)
    if loop.min() < 0 or loop.max() >= n:
        raise MeshError(f"boundary indices must lie in [0, {n}), got [{loop.min()}, {loop.max()}]")
    if np.unique(loop).size != loop.size:
        raise MeshError("boundary loop repeats a vertex; a disk's boundary is a simple loop")
    return loop


def tutte_embedding(V, F, weights: str = "uniform", boundary=None) -> np.ndarray:
    """Flip-free map of a disk mesh into the unit disk.

    Parameters
    ----------
    V : (n, 3) or (n, 2) float array
        Rest vertex positions.
    F : (m, 3) int array
        Triangles, consistently oriented.
    weights : {"uniform", "mean_value"}
        See :func:`tutte_weights`.
    boundary : (k,) int array, optional
        The boundary loop, in half-edge direction (as :func:`geomopt.exact.topology.boundary_loops`
        returns it).  Given, the disk check is skipped; a reversed loop gives a
        mirrored, negatively oriented map.  By default :func:`~geomopt.exact.topology.check_disk`
        validates the mesh and finds the loop.

    Returns
    -------
    UV : (n, 2) float64 array
        Boundary vertices on the unit circle counter-clockwise, spaced by rest arc
        length; every triangle has positive signed area (up to round-off on
        extremely ill-shaped inputs; check with
        :func:`geomopt.exact.predicates.count_inverted`).

    Raises
    ------
    MeshError
        Not a disk, degenerate rest data, or a singular system.
    ParameterError
        Unknown ``weights``.
    """
    V, F = _checked_input(V, F, weights)
    n = V.shape[0]
    if boundary is None:
        loop = check_disk(F, n)
    else:
        loop = _as_loop(boundary, n)
        unused = n - np.unique(F).size
        if unused:
            raise MeshError(f"{unused} vertices are not used by any face; remove them first")
    return weighted_embedding(tutte_weights(V, F, weights), loop, circle_boundary(V, loop))


def weighted_embedding(W, loop, boundary_positions) -> np.ndarray:
    """(n, 2) every vertex off ``loop`` at the ``W``-weighted average of its neighbours, the
    loop's vertices at ``boundary_positions`` (k, 2): one sparse solve.  ``W`` (n, n) holds
    positive weights on the edges (any, not necessarily symmetric: Floater 2003's theorem makes
    the map flip-free for a convex boundary polygon in loop order)."""
    n = W.shape[0]
    UV = np.zeros((n, 2))
    UV[loop] = boundary_positions
    is_interior = np.ones(n, dtype=bool)
    is_interior[loop] = False
    interior = np.flatnonzero(is_interior)
    if interior.size == 0:
        return UV
    W = sp.csr_matrix(W)
    degree = np.asarray(W.sum(axis=1)).ravel()
    # rows of interior vertices: d_i u_i - sum_j W_ij u_j = 0, boundary terms to the right
    W_int = W[interior]
    A = sp.diags(degree[interior]) - W_int[:, interior]
    rhs = W_int[:, loop] @ UV[loop]
    try:
        UV[interior] = _solve(A, rhs, symmetric=(W != W.T).nnz == 0)
    except (RuntimeError, NotPositiveDefinite) as err:  # "Factor is exactly singular", a zero pivot
        raise MeshError(
            f"Tutte system is singular ({err}); every component must touch the boundary"
        ) from None
    if not np.isfinite(UV).all():
        raise MeshError("Tutte system is singular; every component must touch the boundary")
    return UV


def _solve(A, rhs, symmetric):
    """``A^-1 rhs`` for the Tutte system ``A`` (k, k): a sparse Cholesky factorization where the
    weights are symmetric (``A`` is then a Laplacian's block, positive definite when every
    component touches the boundary: PARDISO where installed, 3x faster than SuperLU, whose
    import also costs 40 ms), else SuperLU."""
    if symmetric:
        from ..linalg.linsolve import spd_solve

        return spd_solve(A, rhs)
    import scipy.sparse.linalg as spla

    return spla.splu(sp.csc_matrix(A)).solve(rhs)


def scale_to_area(UV, V, F) -> np.ndarray:
    """Scale a map about the origin so its total area equals the rest surface area.

    Parameters
    ----------
    UV : (n, 2) float array
        The map; its total signed area must be positive.
    V : (n, 2) or (n, 3) float array
        Rest positions; rest triangle areas are ``|(b - a) x (c - a)| / 2``.
    F : (m, 3) int array

    Returns
    -------
    UV_scaled : (n, 2) float64 array
        ``s * UV`` with ``s = sqrt(rest area / signed map area)``.
    """
    UV = validate_vertices(UV, "UV")
    if UV.shape[1] != 2:
        raise MeshError(f"UV must be an array of shape (n, 2), got shape {UV.shape}")
    V = validate_vertices(V, "V")
    if V.shape[0] != UV.shape[0]:
        raise MeshError(f"UV has {UV.shape[0]} vertices but V has {V.shape[0]}")
    F = as_faces(F, V.shape[0])
    top = float(np.max(np.abs(UV))) if UV.size else 0.0
    if top > 0:  # a power of two first (exact): maps at 1e300 or 1e-310 have an area too
        UV = np.ldexp(UV, -int(np.frexp(top)[1]))
    a, b, c = UV[F[:, 0]], UV[F[:, 1]], UV[F[:, 2]]
    u, v = b - a, c - a
    map_area = 0.5 * float(np.sum(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]))
    rest_area = float(triangle_areas(V[F]).sum())
    if not map_area > 0:
        raise MeshError(
            f"the map's total signed area is {map_area:g}, not positive: "
            "it is degenerate or mirrored, and cannot be scaled to the rest area"
        )
    if not rest_area > 0:
        raise MeshError("the rest mesh has zero total area")
    return UV * np.sqrt(rest_area / map_area)


@float64
def optimal_scale(objective, x, params=None, lo=-4.0, hi=4.0, xtol=1e-7) -> float:
    """The factor ``s`` minimising ``E(s * x)``: a search on ``log s`` in ``[lo, hi]`` from
    ``s = 1`` (:func:`_line_minimum`, about 10-20 energy evaluations), to within ``xtol``.

    For symmetric Dirichlet this is the classic ``(sum|J^-1|^2 / sum|J|^2)^(1/4)``; the search
    makes it work for any energy (an energy that does not change with scale, as MIPS, keeps
    ``s = 1``).  ``x`` (n, d) is assumed centred on the problem's free vertices.
    ``objective`` is an :class:`~geomopt.Objective` (only its ``params``, ``pad_map`` and
    ``value`` are used).
    """
    refuse_traced("optimal_scale (a host search)", "start maps have zero derivative: compute them from concrete "
                  "values", objective, x, params)
    params = objective.params(**(params or {}))
    x = objective.pad_map(np.asarray(x, dtype=np.float64))

    def f(t):
        v = float(objective.value(np.exp(t) * x, params))
        return v if np.isfinite(v) else np.inf

    return float(np.exp(_line_minimum(f, lo, hi, xtol)))


_GOLDEN = (3.0 - 5.0**0.5) / 2.0  # the golden-section fraction of a bracket


def _line_minimum(f, lo, hi, tol):
    """A local minimiser of ``f`` on ``[lo, hi]`` (``lo <= 0 <= hi``) to within ``tol``, found
    from 0.  Downhill steps that double bracket a minimum (or reach a bound); then each step goes
    to the vertex of the parabola through the three lowest points seen when that vertex lies in
    the bracket and moves less than half the step before last (so it converges), else a golden-
    section step into the larger side; no step is shorter than ``tol``.  Written here rather than
    imported: ``scipy.optimize`` costs ~0.15 s to import, more than this search in a whole
    ``geomopt param`` run.  Values equal to rounding end the search (an ``f`` flat in scale)."""
    a, m, b, fa, fm, fb = _downhill_bracket(f, lo, hi)
    nodes = sorted([(fm, m), (fa, a), (fb, b)])  # (value, t), lowest first
    steps = [b - a, b - a]
    while max(m - a, b - m) > 2 * tol and nodes[2][0] - nodes[0][0] > 1e-14 * abs(nodes[0][0]):
        step = _parabola_vertex(nodes) - m
        if not (a < m + step < b and abs(step) < abs(steps[-2]) / 2):
            step = _GOLDEN * (b - m) if b - m > m - a else -_GOLDEN * (m - a)
        step = step if abs(step) >= tol else (tol if b - m > m - a else -tol)
        steps.append(step)
        p = m + step
        fp = f(p)
        if fp < nodes[0][0]:
            a, b = (m, b) if p > m else (a, m)
            m = p
        elif p > m:
            b = p
        else:
            a = p
        nodes = sorted(nodes + [(fp, p)])[:3]
    return m


def _parabola_vertex(nodes):
    """The abscissa of the vertex of the parabola through three ``(value, t)`` points (nan when
    they are collinear)."""
    (f0, x0), (f1, x1), (f2, x2) = nodes
    d1, d2 = (x0 - x1) * (f0 - f2), (x0 - x2) * (f0 - f1)
    den = 2.0 * (d1 - d2)
    return x0 - ((x0 - x1) * d1 - (x0 - x2) * d2) / den if den != 0 else np.nan


def _downhill_bracket(f, lo, hi, step=0.5):
    """``(a, m, b, f(a), f(m), f(b))`` with ``a <= m <= b`` in ``[lo, hi]`` and ``f(m)`` no
    higher than either end: steps from 0 that double while ``f`` falls; ``a = m = b`` at a bound
    where ``f`` still falls."""
    m = min(max(0.0, lo), hi)
    fm = f(m)
    ahead = min(m + step, hi)
    fa = f(ahead)
    way = 1.0 if fa < fm else -1.0
    if way > 0:
        (m, fm), (a, fa) = (ahead, fa), (m, fm)
    else:
        a = ahead
    while True:
        bound = hi if way > 0 else lo
        if m == bound:
            return m, m, m, fm, fm, fm
        b = m + way * min(2.0 * abs(m - a), abs(bound - m))
        fb = f(b)
        if not fb < fm:
            return (a, m, b, fa, fm, fb) if way > 0 else (b, m, a, fb, fm, fa)
        a, fa, m, fm = m, fm, b, fb

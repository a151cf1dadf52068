"""Where :func:`geomopt.untangling.untangle` starts, connected part by connected part.

A mesh may hold several connected parts (no vertex shared): each is its own untangling
problem, and what is right for one is not for another.

* **A part with a handle.**  The given map, or the harmonic extension of its handles
  (:func:`harmonic_start`: one sparse solve with the rest Laplacian on its free vertices, the
  far end of the eps continuation, where the untangling energy's minimiser tends as eps
  grows).  :func:`choose_start` decides per part.
* **A part without a handle** (:func:`hold_free_parts`).  The harmonic extension of no handle
  is a point, and so is the far end of the eps continuation: at the first eps (mean ``det J``
  1, eps 1) the regularised energy of a free part is lowest collapsed (``f(a J) -> 2 lam /
  eps`` as ``a -> 0``, below its value at rest: 2 against 4.3 for a cube in 3D), and the
  inner solves shrink it towards a point; the eps schedule then follows its ``det J ~ 0``
  with one inner iteration per outer one, and the part re-expands only at tiny eps, by a
  stiff solve that may leave it folded (two 4^3 hex blocks, one without a handle: 11 outer
  iterations of collapse, then 1,100 inner iterations to 6 hexahedra folded inside).  The
  minimiser of the untangling energy of a free part at eps -> 0 is its rest shape moved
  rigidly (every ``J`` a rotation), and nothing couples the part to the others, so the part is
  *held*: at its given map when that is certified locally injective (exact predicates), else at
  its rest shape moved by the similarity that best fits the given map (rotation by the
  Kabsch / Umeyama SVD, no reflection, the given map's size), certified too.  A part whose rest
  mesh is not in the map's space (a surface) and whose given map is not locally injective is
  left to the eps loop with one vertex held (the translation gauge, which changes no minimum).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from .._runtime.errors import ParameterError
from ..linalg.linsolve import NotPositiveDefinite, SparseCholesky
from ..exact.predicates import box_scale
from ..mesh.problem import Problem
from ..solvers import rest_laplacian
from ..exact.topology import connected_components

__all__ = ["STARTS", "BOX", "harmonic_start", "choose_start", "hold_free_parts", "HeldParts"]

#: the values of ``UntangleOptions.start`` (see :func:`choose_start`)
STARTS = ("auto", "given", "harmonic")

BOX = 10.0  # the map is scaled to about this size (Garanzha et al.'s code uses 10)


def _parts(problem: Problem):
    """``(count, labels, anchored)``: the connected parts, each vertex's part (-1: unused) and
    (count,) whether a part holds a handle."""
    count, labels = connected_components(problem.simplices, problem.n_vertices)
    anchored = np.zeros(count, bool)
    on = labels[problem.fixed]
    anchored[on[on >= 0]] = True
    return count, labels, anchored


def _in(parts: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(n,) bool: the vertices whose part is marked in ``parts`` (count,) (unused vertices: no)."""
    return (labels >= 0) & parts[np.maximum(labels, 0)]


def harmonic_start(problem: Problem, x0) -> np.ndarray | None:
    """``x0`` (n, d) with the free vertices of every part that has a handle moved to the
    harmonic extension of its handles; None where no part has one.

    The extension minimises the rest Dirichlet energy ``sum_e vol_e |J_e|^2`` (quads and
    hexahedra: over their corner simplices) with the handles at ``problem.fixed_positions``:
    one sparse Cholesky solve with the rest Laplacian (:func:`~geomopt.solvers.rest_laplacian`)
    on those free vertices.  It is the far end of the eps continuation: for ``|det J| << eps``,
    ``chi(det J, eps) ~ eps / 2`` and what is left of the untangling energy is its Dirichlet
    term, so the minimiser tends to this map as eps grows.  Parts without a handle (where the
    extension would be a point) and vertices no element uses keep their ``x0`` rows."""
    x = problem.check_map(x0)
    if not len(problem.simplices) or not len(problem.fixed):
        return None
    _, labels, anchored = _parts(problem)
    free = problem.free_mask & _in(anchored, labels)
    if not free.any():
        return x
    K = rest_laplacian(problem).tocsr()
    try:
        x[free] = SparseCholesky.factored(K[free][:, free]).solve(-(K[free][:, ~free] @ x[~free]))
    except NotPositiveDefinite:  # a rest mesh whose Laplacian is not definite on the free part
        return None
    return x


def _inverted_corners(problem: Problem, x, labels, count) -> np.ndarray:
    """(count,) simplices (quads / hexahedra: corner simplices) of each part with ``det J <= 0``
    in floating point, on ``x`` scaled by a power of two to a box of about :data:`BOX` (exact,
    so that a map at 1e-150 is not counted as collapsed)."""
    bad = ~(problem.signed_volumes(x * box_scale(x, BOX)) > 0)
    return np.bincount(labels[problem.simplices[:, 0]], weights=bad, minlength=count).astype(np.int64)


def choose_start(problem: Problem, x0, start: str = "auto") -> tuple[np.ndarray, str]:
    """``(x, which)``: the map :func:`~geomopt.untangling.untangle`'s eps loop starts from, and
    ``"given"`` (``x0``), ``"harmonic"`` (:func:`harmonic_start` in every part it was taken
    for) or ``"mixed"`` (some parts with inverted corners kept ``x0``), for
    ``UntangleOptions.start`` (:data:`STARTS`).

    ``"harmonic"`` takes the extension in every part with a handle.  ``"auto"`` takes it, for
    quads and hexahedra, in each part with a handle where ``x0`` has an inverted corner and the
    extension has fewer.  On their corner simplices no L-BFGS seed solves the first eps of a
    global tangle and the stiff phase is projected Newton on every corner
    (:func:`~geomopt.untangling.stiff_solver`): the hex rod of 20 x 20 x 240 bent by 180 degrees
    (96,000 hexahedra) ran 24 minutes without finishing from ``x0``; its harmonic extension has
    no inverted corner and certifies after 8 inner iterations.  Simplices keep ``x0`` under
    ``"auto"``: L-BFGS with the Laplacian seed untangles their global tangles at the authors'
    speed or better (benchmarks/README.md), and a map that stays near ``x0`` is kept.  Parts
    without a handle keep ``x0`` here (see :func:`hold_free_parts`)."""
    if start not in STARTS:
        raise ParameterError(f"start must be one of {STARTS}, got {start!r}")
    if start == "given" or (start == "auto" and problem.elements is None):
        return x0, "given"
    count, labels, anchored = _parts(problem)
    given = _inverted_corners(problem, x0, labels, count) if start == "auto" else None
    xh = harmonic_start(problem, x0) if given is None or given[anchored].any() else None
    if xh is None:
        if start == "harmonic":
            raise ParameterError("start='harmonic' needs a handle (the harmonic extension of the handles is "
                                 "undefined without one); use start='given'")
        return x0, "given"
    if start == "harmonic":
        return xh, "harmonic"
    take = anchored & (_inverted_corners(problem, xh, labels, count) < given)
    if not take.any():
        return x0, "given"
    x = np.array(x0, dtype=np.float64, copy=True)
    rows = _in(take, labels)
    x[rows] = xh[rows]
    return x, "harmonic" if take[anchored & (given > 0)].all() else "mixed"


class HeldParts(NamedTuple):
    """What :func:`hold_free_parts` did: ``x`` (n, d) the start with the held parts in place,
    ``held`` (k,) the vertex ids the solve must not move (sorted), and the parts held at their
    ``given`` map, at their ``rest`` shape, and ``pinned`` (one vertex held, the part left to
    the eps loop)."""

    x: np.ndarray
    held: np.ndarray
    given: int = 0
    rest: int = 0
    pinned: int = 0


def _certified(problem: Problem, x, part: np.ndarray) -> bool:
    """Whether ``x`` is locally injective on the elements of the parts marked by the vertex
    mask ``part`` (n,) (exact: :meth:`Problem.certify` of those elements)."""
    keep = part[problem.simplices[:, 0]]
    sub = dataclasses.replace(problem, simplices=problem.simplices[keep],
                              elements=None if problem.elements is None else
                              problem.elements[part[problem.elements[:, 0]]])
    return sub.certify(x).ok


def _similar(R, X) -> np.ndarray:
    """``R`` (k, d) moved by the proper similarity (rotation, uniform scale, translation) that
    best fits ``X`` (k, d): the rotation of Kabsch / Umeyama (SVD, no reflection), the scale
    that gives it ``X``'s spread about its centroid."""
    A, B = R - R.mean(axis=0), X - X.mean(axis=0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    D = np.eye(R.shape[1])
    D[-1, -1] = -1.0 if np.linalg.det(U @ Vt) < 0 else 1.0
    ra, rb = float(np.sum(A * A)), float(np.sum(B * B))
    s = math.sqrt(rb / ra) if ra > 0 and rb > 0 and math.isfinite(rb / ra) else 1.0
    return X.mean(axis=0) + s * (A @ (U @ D @ Vt))


def hold_free_parts(problem: Problem, x) -> HeldParts:
    """The parts of ``problem`` without a handle, held at a certified map (module notes).

    Parameters
    ----------
    problem : the untangling problem;  x : (n, d) the start map (handles in place).

    Returns
    -------
    :class:`HeldParts`; ``held`` empty when every part has a handle.
    """
    x = np.array(x, dtype=np.float64, copy=True)
    count, labels, anchored = _parts(problem)
    free = ~anchored
    if not free.any() or _certified(problem, x, _in(free, labels)):
        return HeldParts(x, np.flatnonzero(_in(free, labels)), int(free.sum()))
    rest = np.asarray(problem.rest_vertices, dtype=np.float64)
    same_space = rest.shape[1] == problem.dim
    held, given, moved, pinned = [], 0, 0, 0
    for p in np.flatnonzero(free):
        part = labels == p
        if _certified(problem, x, part):
            given += 1
        else:
            candidate = x.copy()
            candidate[part] = _similar(rest[part], x[part]) if same_space else x[part]
            if same_space and _certified(problem, candidate, part):
                x, moved = candidate, moved + 1
            else:  # left to the eps loop; its translation pinned
                held.append(np.flatnonzero(part)[:1])
                pinned += 1
                continue
        held.append(np.flatnonzero(part))
    return HeldParts(x, np.sort(np.concatenate(held)), given, moved, pinned)

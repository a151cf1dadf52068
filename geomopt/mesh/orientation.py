"""Whether a start map is oriented as a whole: not mirrored, not collapsed (its total signed
area or volume, exactly rescaled), and why no injective map exists when a fixed boundary
encloses a non-positive total."""

from __future__ import annotations

import math

import numpy as np

from .._runtime.errors import MeshError

__all__ = ["check_initial_orientation", "fixed_total_problem"]


def check_initial_orientation(problem, x0) -> float:
    """Check that a start map is not mirrored or collapsed as a whole; return its signed size.

    A map with every element positively oriented has a positive total signed area (2D) or
    volume (3D); when the handles pin the boundary that total is the same for every map, so a
    start map whose total is negative (mirrored, e.g. a left-handed init for a right-handed
    rest mesh) or zero (collapsed to a point, line or plane) cannot be untangled.  Call this
    before untangling, after any deliberate mirroring.

    Parameters
    ----------
    problem : Problem
    x0 : (n, dim) array_like, the start map.

    Returns
    -------
    float
        The total signed area/volume of ``x0`` (positive; ``inf`` or ``0.0`` where it overflows
        or underflows float64, the test being made on an exactly rescaled copy).

    Raises
    ------
    MeshError
        ``x0`` is invalid (see :meth:`Problem.check_map`) or its total signed area/volume is
        not positive.
    """
    x0 = problem.check_map(x0, "initial map")
    vols, scale = _unit_volumes(problem, x0)
    total = float(vols.sum())  # the sign of x0's own total, which may overflow or underflow
    if not total > 0:
        what = "area" if problem.dim == 2 else "volume"
        state = "negative: it is mirrored" if total < 0 else "zero: it is collapsed"
        raise MeshError(
            f"the initial map's total signed {what} is {total * scale:.6g}, {state} relative to the rest "
            f"mesh, and untangling needs a positive total; mirror the initial map (negate one "
            f"coordinate) or check that the rest and initial meshes belong together"
        )
    return total * scale


def _unit_volumes(problem, x):
    """``(vols, scale)``: the elements' signed sizes under ``x`` scaled by a power of two so
    that its largest coordinate is about 1 (exact: the signs and the ratios are those of
    ``x``'s, and no size overflows for coordinates up to 1e308), and the factor
    ``scale = 2^(d e)`` that gives back ``x``'s own sizes (may be inf or 0)."""
    x = np.asarray(x, dtype=np.float64)
    top = float(np.abs(x).max(initial=0.0))
    e = math.frexp(top)[1] if top > 0 else 0
    return problem.signed_volumes(np.ldexp(x, -e)), 2.0 ** (problem.dim * e) if abs(problem.dim * e) < 1024 else (
        math.inf if e > 0 else 0.0)


def fixed_total_problem(problem, x) -> str | None:
    """Why no injective map exists when every boundary vertex is a handle and ``x``'s total
    signed area/volume is not positive, or None.

    With the whole boundary fixed that total is the same for every map, and an injective map
    (every element positive) needs it positive; with part of the boundary free the free
    vertices can change it, so nothing is said then.
    """
    if not problem.fixed.size:
        return None
    vols, scale = _unit_volumes(problem, x)
    total = math.fsum(vols)
    if total > 1e-12 * float(np.abs(vols).sum()):
        return None
    if not np.isin(problem.boundary_vertices(), problem.fixed).all():
        return None
    what = "mirrored (oriented against the rest mesh)" if total < 0 else "collapsed"
    return (f"the fixed boundary encloses a total signed {'area' if problem.dim == 2 else 'volume'} "
            f"of {total * scale:g}: the map is {what}, and with the whole boundary fixed no map can "
            f"change that total, so none is injective")

"""Surface parameterization: Tutte start, optimal scaling, then a distortion minimisation."""

from __future__ import annotations

import numpy as np

from ._errors import MeshError
from ._objective import Objective
from .problem import Problem
from .solvers import Newton, get_solver, minimize
from .topology import check_disk
from .tutte import tutte_embedding


def optimal_scale(objective: Objective, x, params=None, lo=-4.0, hi=4.0, iters=60) -> float:
    """The factor ``s`` minimising ``E(s * x)``, by golden-section search on ``log s``.

    For symmetric Dirichlet this is the classic ``(sum|J^-1|^2 / sum|J|^2)^(1/4)``; the search
    makes it work for any energy.  ``x`` is assumed centred on the problem's free vertices.
    """
    params = objective.params(**(params or {}))
    x = np.asarray(x)

    def f(t):
        v = float(objective.value(np.exp(t) * x, params))
        return v if np.isfinite(v) else np.inf

    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(iters):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    return float(np.exp(0.5 * (a + b)))


def _to_rest_area(problem: Problem, x0) -> np.ndarray:
    """``x0`` centred and scaled to the rest surface area (when its signed area is positive), so
    that the scale search of :func:`optimal_scale` starts at O(1) Jacobians whatever its units."""
    x0 = x0 - x0.mean(axis=0)
    span = np.abs(x0).max()
    x0 = x0 / span if span > 0 else x0
    area = float(problem.signed_volumes(x0).sum())
    return x0 * np.sqrt(problem.volumes.sum() / area) if area > 0 else x0


def start_map(objective: Objective, x0=None, weights="uniform"):
    """The start map of a free-boundary parameterization, as :func:`parameterize` uses it.

    A Tutte embedding (or ``x0``), centred, scaled to the rest surface area, then scaled by
    :func:`optimal_scale` for the objective's energy.

    Parameters
    ----------
    objective : :class:`~geomopt.Objective` over a 2D-target problem (surface or planar).
    x0 : (n, 2) optional start map instead of Tutte; with a barrier energy it must be flip-free.
        Without ``x0`` the mesh must be a topological disk (:func:`~geomopt.topology.check_disk`).
    weights : Tutte weights, ``"uniform"`` or ``"mean_value"``.

    Returns
    -------
    x : (n, 2) float64 start map;  scale : float, the factor :func:`optimal_scale` applied.

    Raises
    ------
    MeshError : non-disk mesh, invalid ``x0``, or a start map with inverted triangles for a
        barrier energy (infinite there).
    ParameterError : unknown ``weights``.
    """
    problem = objective.problem
    if x0 is None:
        loop = check_disk(problem.input_simplices, problem.n_vertices)
        x0 = tutte_embedding(problem.rest_vertices, problem.input_simplices, weights, boundary=loop)
        source = "the Tutte start map"
    else:
        source = "the start map x0"
    x0 = problem.check_map(x0, "start map x0")
    inverted = problem.count_inverted(x0)
    if inverted and objective.energy.barrier:
        raise MeshError(
            f"{source} has {inverted} inverted or degenerate triangle(s), where the barrier energy "
            f"{objective.energy.name!r} is infinite; give a flip-free start map (omit x0 for a Tutte "
            f"start, or untangle it first) or use an energy without a barrier"
        )
    x0 = _to_rest_area(problem, x0)
    s = optimal_scale(objective, x0)
    return s * x0, s


def parameterize(V, F, energy="symmetric_dirichlet", solver=None, weights="uniform",
                 x0=None, progress=True, throw=False, **energy_params):
    """Flatten a disk-topology surface to the plane with a free boundary, flip-free.

    Parameters
    ----------
    V : (n, 3) float rest vertex positions;  F : (m, 3) int triangles (consistently oriented).
    energy : name or :class:`~geomopt.energies.Energy` (default symmetric Dirichlet).
    solver : a solver object or name (default :class:`~geomopt.solvers.Newton`).
    weights : Tutte weights for the start map, ``"uniform"`` or ``"mean_value"``.
    x0 : (n, 2) optional start map instead of Tutte; with a barrier energy it must be flip-free.
        Without ``x0`` the mesh must be a topological disk (:func:`~geomopt.topology.check_disk`).
    progress, throw : see :func:`~geomopt.solvers.minimize`.

    Returns
    -------
    :class:`~geomopt.solvers.Result` whose ``x`` is the (n, 2) UV map; ``info`` holds the
    start map and the scale applied to it.

    Raises
    ------
    MeshError : invalid or non-disk mesh, invalid start map, or a start map with inverted
        triangles for a barrier energy (infinite there).
    ParameterError : unknown energy/solver/weights name or invalid energy parameter.
    SolveError : only with ``throw=True``, when the result is not converged and flip-free.
    """
    problem = Problem.surface(V, F)
    objective = Objective(problem, energy, **energy_params)
    solver = Newton() if solver is None else get_solver(solver)
    x0, s = start_map(objective, x0, weights)
    result = minimize(objective, x0, solver, progress=progress, throw=throw)
    result.info.update(start=x0, scale=s, problem=problem, objective=objective)
    return result

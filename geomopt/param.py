"""Surface parameterization: Tutte start, optimal scaling, then a distortion minimisation."""

from __future__ import annotations

import numpy as np

from ._objective import Objective
from .problem import Problem
from .solvers import Newton, minimize
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


def parameterize(V, F, energy="symmetric_dirichlet", solver=None, weights="uniform",
                 x0=None, progress=True, throw=False, **energy_params):
    """Flatten a disk-topology surface to the plane with a free boundary, flip-free.

    Parameters
    ----------
    V : (n, 3) float rest vertex positions;  F : (m, 3) int triangles (consistently oriented).
    energy : name or :class:`~geomopt.energies.Energy` (default symmetric Dirichlet).
    solver : a solver object (default :class:`~geomopt.solvers.Newton`).
    weights : Tutte weights for the start map, ``"uniform"`` or ``"mean_value"``.
    x0 : (n, 2) optional start map (must be flip-free) instead of Tutte.
    progress, throw : see :func:`~geomopt.solvers.minimize`.

    Returns
    -------
    :class:`~geomopt.solvers.Result` whose ``x`` is the (n, 2) UV map; ``info`` holds the
    start map and the scale applied to it.
    """
    problem = Problem.surface(V, F)
    objective = Objective(problem, energy, **energy_params)
    if x0 is None:
        x0 = tutte_embedding(problem.rest_vertices, problem.input_simplices, weights=weights)
    x0 = problem.check_map(x0)
    x0 = x0 - x0.mean(axis=0)
    s = optimal_scale(objective, x0)
    result = minimize(objective, s * x0, solver or Newton(), progress=progress, throw=throw)
    result.info.update(start=s * x0, scale=s, problem=problem, objective=objective)
    return result

"""Surface parameterization: Tutte start, optimal scaling, then a distortion minimisation."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._errors import MeshError, ParameterError
from ._objective import Objective
from .problem import Problem
from .solvers import Newton, get_solver, minimize
from .topology import check_disk
from .tutte import tutte_embedding


def optimal_scale(objective: Objective, x, params=None, lo=-4.0, hi=4.0, xtol=1e-7) -> float:
    """The factor ``s`` minimising ``E(s * x)``, by bounded Brent search on ``log s`` in
    ``[lo, hi]`` (:func:`scipy.optimize.minimize_scalar`, about 15-25 evaluations where a
    fixed golden-section search took 62).

    For symmetric Dirichlet this is the classic ``(sum|J^-1|^2 / sum|J|^2)^(1/4)``; the search
    makes it work for any energy.  ``x`` (n, d) is assumed centred on the problem's free
    vertices; ``xtol`` is the tolerance on ``log s``.
    """
    from scipy.optimize import minimize_scalar

    params = objective.params(**(params or {}))
    x = objective.pad_map(np.asarray(x, dtype=np.float64))

    def f(t):
        v = float(objective.value(np.exp(t) * x, params))
        return v if np.isfinite(v) else np.inf

    res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": xtol})
    return float(np.exp(res.x))


def _to_rest_area(problem: Problem, x0) -> np.ndarray:
    """``x0`` centred and scaled to the rest surface area (when its signed area is positive), so
    that the scale search of :func:`optimal_scale` starts at O(1) Jacobians whatever its units."""
    x0 = x0 - x0.mean(axis=0)
    span = np.abs(x0).max()
    x0 = x0 / span if span > 0 else x0
    area = float(problem.signed_volumes(x0).sum())
    return x0 * np.sqrt(problem.volumes.sum() / area) if area > 0 else x0


def _check_misplaced_settings(energy, solver, energy_params):
    """ParameterError for solver settings (``max_steps``, ``rtol``, ``c1``...) passed to
    :func:`parameterize` as energy parameters, saying where they go."""
    from .energies import get_energy
    from .linesearch import InjectiveSearch

    known = get_energy(energy).params
    cls = type(solver).__name__
    for k in energy_params:
        if k in known:
            continue
        if dataclasses.is_dataclass(solver) and k in {f.name for f in dataclasses.fields(solver)}:
            where = f"solver={cls}({k}=...)"
        elif k in {f.name for f in dataclasses.fields(InjectiveSearch)}:
            where = f"solver={cls}(search=InjectiveSearch({k}=...))"
        else:
            continue  # an unknown energy parameter: the energy's own message lists its names
        raise ParameterError(
            f"{k} is a setting of the solver, not a parameter of the energy "
            f"{get_energy(energy).name!r}: pass parameterize(..., {where})")


def mesh_arrays(V, F=None):
    """``(V, F)`` from a vertex array and a face array, or from one mesh object with
    ``.vertices`` and ``.faces`` (a ``trimesh.Trimesh``, ...) given as ``V`` with ``F=None``."""
    if F is None:
        if hasattr(V, "vertices") and hasattr(V, "faces"):
            return np.asarray(V.vertices), np.asarray(V.faces)
        raise ParameterError(f"give the faces F with the vertices, or one mesh object with .vertices and "
                             f".faces (e.g. a trimesh.Trimesh); got {type(V).__name__} and no faces")
    return V, F


def parameterize(V, F=None, energy="symmetric_dirichlet", solver=None, weights="uniform",
                 x0=None, progress=True, throw=False, *, buckets=True, **energy_params):
    """Flatten a disk-topology surface to the plane with a free boundary, flip-free.

    Parameters
    ----------
    V : (n, 3) float rest vertex positions, or a mesh object with ``.vertices`` and ``.faces``
        (a ``trimesh.Trimesh``...) when ``F`` is None.
    F : (m, 3) int triangles (consistently oriented).
    energy : name or :class:`~geomopt.energies.Energy` (default symmetric Dirichlet).
    solver : a solver object or name (default :class:`~geomopt.solvers.Newton`).
    weights : Tutte weights for the start map, ``"uniform"`` or ``"mean_value"``.
    x0 : (n, 2) optional start map instead of Tutte; with a barrier energy it must be flip-free.
        Without ``x0`` the mesh must be a topological disk (:func:`~geomopt.topology.check_disk`).
    progress, throw : see :func:`~geomopt.solvers.minimize`.
    buckets : pad the mesh's arrays to size buckets (default True) so that compiled kernels,
        kept in the persistent compilation cache (:func:`geomopt.set_cache_dir`), serve every
        mesh of the same bucket; the padding changes no result (:mod:`geomopt._padding`).

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
    V, F = mesh_arrays(V, F)
    problem = Problem.surface(V, F)
    solver = Newton() if solver is None else get_solver(solver)
    _check_misplaced_settings(energy, solver, energy_params)
    objective = Objective(problem, energy, buckets=buckets, **energy_params)
    if x0 is None:
        loop = check_disk(problem.input_simplices, problem.n_vertices)
        x0 = tutte_embedding(problem.rest_vertices, problem.input_simplices, weights, boundary=loop)
        source = "the Tutte start map"
    else:
        source = "the start map x0"
    x0 = problem.check_map(x0, "start map x0")
    inverted = problem.count_inverted(x0)
    if inverted and objective.energy.barrier:
        what = (f"{source} has {inverted} inverted or degenerate triangle(s), where the barrier energy "
                f"{objective.energy.name!r} is infinite")
        if source == "the start map x0":
            raise MeshError(f"{what}; give a flip-free start map (omit x0 for a Tutte start, or "
                            f"untangle it first) or use an energy without a barrier")
        other = "mean_value" if weights == "uniform" else "uniform"
        raise MeshError(
            f"{what} (a Tutte map has none in exact arithmetic: these are rounding where its "
            f"triangles crowd, as on very anisotropic or unevenly refined meshes); try {other} "
            f"Tutte weights or an energy without a barrier (e.g. arap), or remesh more evenly"
        )
    x0 = _to_rest_area(problem, x0)
    s = optimal_scale(objective, x0)
    result = minimize(objective, s * x0, solver, progress=progress, throw=throw)
    result.info.update(start=s * x0, scale=s, problem=problem, objective=objective)
    return result

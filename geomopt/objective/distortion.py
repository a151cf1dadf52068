"""How far a map onto the sphere is from keeping shapes and areas (:func:`sphere_distortion`):
the figures :func:`geomopt.sphere_map`'s command reports and its pictures colour by."""

from __future__ import annotations

import numpy as np

from .._runtime.x64 import float64
from ..exact.certify import spherical_areas
from ..mesh.problem import Problem
from .objective import Objective, element_densities

__all__ = ["sphere_distortion"]


@float64
def sphere_distortion(V, F, x) -> dict:
    """Distortion of a map ``x`` (n, 3) of the closed mesh ``V`` (n, 3), ``F`` (m, 3) onto the
    unit sphere (``x`` need not be normalised, nor flip-free).

    Returns
    -------
    dict: ``"symmetric_dirichlet"``, the area-weighted mean symmetric Dirichlet density of the
    chord triangles (:meth:`geomopt.Problem.sphere`; 4 at an isometry); ``"area_ratio"`` (m,),
    each triangle's signed spherical area over its rest area scaled to total ``4 pi`` (1 where
    area is kept), and its ``"area_min"``, ``"area_max"`` and (unweighted) ``"area_mean"``; ``"inverted"``,
    the triangles not positively oriented about the centre (exact).
    """
    problem = Problem.sphere(V, F)
    objective = Objective(problem, "symmetric_dirichlet", buckets=True)  # one kernel per size bucket
    x = np.asarray(x, dtype=np.float64)
    density = np.asarray(element_densities(objective, x))
    ratio = spherical_areas(x, problem.simplices) / problem.volumes
    w = problem.volumes / problem.volumes.sum()
    return {"symmetric_dirichlet": float(np.sum(w * density)), "area_ratio": ratio,
            "area_min": float(ratio.min()), "area_max": float(ratio.max()), "area_mean": float(ratio.mean()),
            "inverted": problem.count_inverted(x)}

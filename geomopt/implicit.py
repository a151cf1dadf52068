"""Deprecated (removed in the next release): :func:`geomopt.minimize`,
:func:`geomopt.parameterize` and :func:`geomopt.untangle` are differentiable themselves (given
traced inputs, ``result.x`` is the optimum as a function of them).  These functions return that
map and warn; the machinery is :mod:`geomopt.objective.adjoint`."""

from __future__ import annotations

import warnings

from .objective.adjoint import DECREMENT_RTOL, AdjointSystem, argmin, gauge_motions

__all__ = ["argmin", "minimize", "parameterize", "untangle", "gauge_motions", "DECREMENT_RTOL", "AdjointSystem"]


def _deprecated(name: str, instead: str) -> None:
    warnings.warn(f"geomopt.implicit.{name} is deprecated and will be removed in the next release: {instead} is "
                  f"differentiable itself (take .x of its result)", DeprecationWarning, stacklevel=3)


def minimize(objective, x0, solver=None, params=None, *, linear_solver: str = "auto"):
    """Deprecated: ``geomopt.minimize(objective, x0, solver, params, adjoint=linear_solver).x``."""
    from .solvers import minimize_map

    _deprecated("minimize", "geomopt.minimize")
    return minimize_map(objective, x0, solver, params, linear_solver)


def parameterize(V, F=None, energy="symmetric_dirichlet", solver=None, weights="uniform", x0=None, *,
                 element_weights=None, linear_solver: str = "auto", **energy_params):
    """Deprecated: ``geomopt.parameterize(V, F, ..., adjoint=linear_solver).x``."""
    from .param import parameterize_map

    _deprecated("parameterize", "geomopt.parameterize")
    return parameterize_map(V, F, energy, solver, weights, x0, element_weights, linear_solver, energy_params)


def untangle(problem, x0, theta=None, *, solver="lbfgs", linear_solver: str = "auto", **options):
    """Deprecated: ``geomopt.untangle(problem, x0, solver, theta=theta, adjoint=linear_solver).x``."""
    from .untangling import UntangleOptions, untangle as forward
    from .untangling.implicit import untangle_map

    _deprecated("untangle", "geomopt.untangle")
    return untangle_map(forward, problem, x0, theta, solver=solver, adjoint=linear_solver, options=UntangleOptions(**options))

"""Untangling as a differentiable function: the final map of :func:`~geomopt.untangling.untangle`
as a function of the problem (rest vertices, handle positions) and ``theta``, by the implicit
function theorem at the polished optimum (:func:`geomopt.objective.adjoint.argmin`).
:func:`~geomopt.untangling.untangle` calls it for traced inputs, handing itself over as the
forward solve (so this module does not import the driver that imports it)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.errors import ParameterError, SolveError
from .._runtime.x64 import float64
from ..energies import garanzha
from ..mesh.geometry import dets
from ..mesh.problem import check_rest_values
from ..objective.adjoint import argmin, host_constant, require_success
from ..objective.objective import Objective
from .options import UntangleOptions
from .rest import badly_shaped, equilateral_rest
from .schedule import final_eps

__all__ = ["untangle_map"]


def untangle_map(untangle, problem, x0, theta=None, *, solver="lbfgs", adjoint: str = "auto", options=None):
    """:func:`~geomopt.untangling.untangle`'s final map as a differentiable function of the
    problem (its rest vertices and handle positions, traced or not) and ``theta``.

    The untangled map minimises Garanzha et al.'s energy at the constant
    :func:`~geomopt.untangling.final_eps` on the rest mesh as untangling normalises it (scaled to
    the map's volume; in 2D, rest triangles above ``max_aspect`` replaced by equilateral ones):
    :func:`~geomopt.untangling.untangle` ends with a Newton polish there (``options.polish``).
    That energy, written in the problem's units and made a function of the rest vertices (the
    normalisation included), is differentiated at the polished map, refined by one exact
    Newton step (:func:`geomopt.objective.adjoint.argmin`): the map returned is the plain call's
    to rounding.  The power-of-two map scale, which triangles were replaced and the start map
    are constants of the solve (zero derivative).

    Parameters
    ----------
    untangle : the forward solve, :func:`geomopt.untangling.untangle` (called on concrete
        arrays, with ``progress=False``).
    problem : :class:`~geomopt.Problem` with handles (possibly built from traced arrays).
    x0 : (n, d) the tangled start.
    theta : shape/area balance in (0, 1) (``lam = theta / (1 - theta)``), may be traced;
        default 1/128 in 2D, 1/2 in 3D.
    solver, options : passed to :func:`geomopt.untangling.untangle` (``options`` an
        :class:`~geomopt.untangling.UntangleOptions` or None; its ``theta`` is replaced).
    adjoint : the linear solver of the adjoint (see :func:`geomopt.minimize`).

    Raises
    ------
    ParameterError
        ``options.polish`` is False (the map is then no optimum to differentiate).
    SolveError
        The untangling did not succeed, or its polish did not reach a tight optimum (under
        ``jax.jit``: as ``jax.errors.JaxRuntimeError`` naming it).
    """
    d = problem.dim
    theta = (1.0 / 128.0 if d == 2 else 0.5) if theta is None else theta
    x0 = jnp.asarray(x0, jnp.float64)
    options = options or UntangleOptions()
    if options.polish is False:
        raise ParameterError("differentiating untangle needs UntangleOptions(polish=True or 'auto'): without the "
                             "polish the map is no optimum of a fixed energy")
    options = dataclasses.replace(options, polish=True)  # 'auto' polishes whatever the size when differentiated
    max_aspect = options.max_aspect
    m = problem.n_elements
    shapes = (jax.ShapeDtypeStruct(x0.shape, jnp.float64), jax.ShapeDtypeStruct((), jnp.float64),
              jax.ShapeDtypeStruct((m,), jnp.bool_))

    @float64
    def untangled(problem, theta, x0):
        problem = check_rest_values(jax.tree_util.tree_map(np.asarray, problem))
        result = untangle(problem, np.asarray(x0), solver=solver, options=dataclasses.replace(options, theta=float(theta)),
                     progress=False)
        require_success(result, "geomopt.untangle")
        if result.details.active_elements and not result.details.polished:
            raise SolveError("geomopt.untangle: the final Newton polish did not converge, so the map is no tight "
                             "optimum to differentiate", result)
        return result.x, np.float64(result.details.map_scale), badly_shaped(problem, max_aspect)

    x1, k, bad = host_constant(untangled, shapes, problem, jnp.asarray(theta, jnp.float64), x0)
    final = _untangle_problem(problem, x0, k, bad, max_aspect)
    lam = theta / (1.0 - theta)
    return argmin(Objective(final, garanzha), {"eps": final_eps(d), "lam": lam}, x1, _polished, adjoint)


def _polished(objective, params, x):
    """The solve of :func:`untangle_map`'s :func:`~geomopt.objective.adjoint.argmin`: the map
    :func:`~geomopt.untangling.untangle` polished already (argmin checks its decrement)."""
    return x, {"objective": objective}


def _untangle_problem(problem, x0, k, bad, max_aspect):
    """The rest geometry of untangling's energy in the problem's units: ``J`` multiplied by
    ``k / s`` (the map scaled by ``k``, the rest by ``s = (map volume / rest volume)^(1/d)``,
    ``x0``'s handle rows at the handle positions), ``bad`` (m,) triangles equilateral with
    their mean edge length.  Traceable in the problem's arrays and in ``k`` and ``bad``."""

    d = problem.dim
    P = problem
    x = x0.at[P.fixed].set(P.fixed_positions) if P.fixed.size else x0
    map_vol = jnp.sum(dets(P.simplices, k * x)) / (2.0 if d == 2 else 6.0)
    rest_vol = jnp.sum(P.volumes)
    s = jnp.where(map_vol > 0, (jnp.abs(map_vol) / rest_vol) ** (1.0 / d), k)
    shaped = max_aspect is not None and d == 2 and P.elements is None  # else bad is all False
    rest_inv, vol = equilateral_rest(P, bad) if shaped else (P.rest_inv, P.volumes)
    return dataclasses.replace(P, rest_inv=rest_inv * (k / s), volumes=vol)

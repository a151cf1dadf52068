"""Surface parameterization: Tutte start, optimal scaling, then a distortion minimisation."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ._runtime.config import Instance, Maybe, OneOf, options_or_default, validate
from ._runtime.errors import MaxStepsWarning, MeshError, ParameterError, SolveError
from ._runtime.tracing import is_traced
from ._runtime.x64 import float64
from .objective.objective import Objective
from .exact.certify import certify_bijective, local_certificate, polygon_crossings, polygon_orientation
from .energies import energy_spec, get_energy
from .mesh.convert import mesh_arrays
from .mesh.problem import Problem
from .bijective import ScaffoldOptions, bijective_parameterize
from .solvers import Newton, Outcome, ParamDetails, Result, RunStats, get_solver, minimize, traced_result
from .solvers._iterate import check_progress
from .exact.topology import check_disk
from .untangling import UntangleOptions, untangle
from .mesh.tutte import WEIGHTS as TUTTE_WEIGHTS, circle_boundary, optimal_scale, tutte_embedding

__all__ = ["parameterize", "parameterize_map", "start_map", "optimal_scale", "projection_map", "repair_map",
           "ParamOptions"]


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
    from .solvers.linesearch import InjectiveSearch

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


@float64
def start_map(objective: Objective, x0=None, weights="uniform", progress=False, loop=None):
    """The start map of a free-boundary parameterization, as :func:`parameterize` uses it.

    A Tutte embedding, the plane projection or a given map; a folded one (other than Tutte, or
    one with branch points) repaired (:func:`repair_map`); then centred, scaled to the rest
    surface area and by :func:`optimal_scale` for the objective's energy.

    Parameters
    ----------
    objective : :class:`~geomopt.Objective` over a 2D-target problem (surface or planar).
    x0 : ``None`` / ``"tutte"``, ``"projection"`` or an (n, 2) array (see :func:`parameterize`).
    weights : Tutte weights, ``"uniform"`` or ``"mean_value"``.
    progress : passed to the repair's untangling.
    loop : the boundary loop as :func:`~geomopt.exact.topology.check_disk` returns it (found when None).

    Returns
    -------
    x : (n, 2) float64 start map;  scale : float, the factor :func:`optimal_scale` applied;
    repaired : the :class:`~geomopt.solvers.Result` of the repair's untangling, or None.  When the
    repair does not certify, ``x`` is None.

    Raises
    ------
    MeshError : non-disk mesh, invalid ``x0``, or a Tutte start with inverted triangles for a
        barrier energy (infinite there).
    ParameterError : unknown ``weights`` or ``x0`` name.
    """
    problem = objective.problem
    repaired = None
    # every start: a free-boundary map is certified as a disk's, so say so before any solving
    loop = check_disk(problem.input_simplices, problem.n_vertices) if loop is None else loop
    if x0 is None or (isinstance(x0, str) and x0 == "tutte"):
        x0 = tutte_embedding(problem.rest_vertices, problem.input_simplices, weights, boundary=loop)
        source = "the Tutte start map"
    elif isinstance(x0, str):
        if x0 != "projection":
            raise ParameterError(f"x0 must be 'tutte', 'projection' or an (n, 2) array, got {x0!r}")
        x0, source = projection_map(problem.rest_vertices, problem.input_simplices), "the projection start map"
    else:
        source = "the start map x0"
    x0 = problem.check_map(x0, "start map x0")
    inverted = problem.count_inverted(x0)
    # a flip-free map can still wind twice around an interior vertex (a branch point), which no
    # flip-free step removes, or overlap around a boundary vertex: repaired like a fold
    if source != "the Tutte start map" and (inverted or not local_certificate(x0, problem.simplices).ok):
        repaired = repair_map(problem, x0, progress=progress)
        if not repaired.success:
            return None, 1.0, repaired
        x0, inverted = repaired.x, 0
    if inverted and objective.energy.barrier:
        what = (f"{source} has {inverted} inverted or degenerate triangle(s), where the barrier energy "
                f"{objective.energy.name!r} is infinite")
        other = "mean_value" if weights == "uniform" else "uniform"
        raise MeshError(
            f"{what} (a Tutte map has none in exact arithmetic: these are rounding where its "
            f"triangles crowd, as on very anisotropic or unevenly refined meshes); try {other} "
            f"Tutte weights or an energy without a barrier (e.g. arap), or remesh more evenly"
        )
    x0 = _to_rest_area(problem, x0)
    s = optimal_scale(objective, x0)
    return s * x0, s, repaired


@dataclasses.dataclass(frozen=True)
class ParamOptions:
    """The settings of :func:`parameterize` (validated: ``bijective="no"`` is refused, not
    taken as true).

    Attributes
    ----------
    weights : Tutte weights of the start map, ``"uniform"`` or ``"mean_value"``.
    bijective : keep the boundary from crossing itself (a scaffold around the mesh, SCAF;
        :func:`geomopt.bijective.bijective_parameterize`), so that the map is globally injective.
        Either way ``certificate`` is the exact global certificate
        (:func:`geomopt.exact.certify.certify_bijective`) and ``result.injectivity`` says
        ``"global"``, ``"local"`` (flip-free but the boundary overlaps itself) or ``"none"``.
    scaffold : :class:`~geomopt.bijective.ScaffoldOptions` of the bijective mode (None: its
        defaults).
    buckets : pad the mesh's arrays to size buckets (default True) so that compiled kernels,
        kept in the persistent compilation cache (:func:`geomopt.set_cache_dir`), serve every
        mesh of the same bucket; the padding changes no result (:mod:`geomopt._runtime.padding`).
    """

    weights: str = "uniform"
    bijective: bool = False
    scaffold: ScaffoldOptions | None = None
    buckets: bool = True

    def __post_init__(self):
        validate(self, weights=OneOf(TUTTE_WEIGHTS), bijective=Instance(bool),
                 scaffold=Maybe(Instance(ScaffoldOptions)), buckets=Instance(bool))


@float64
def parameterize(V, F=None, energy="symmetric_dirichlet", solver=None, *, options: ParamOptions | None = None,
                 x0=None, element_weights=None, progress=True, throw=False, adjoint="auto"):
    """Flatten a disk-topology surface to the plane with a free boundary, flip-free.

    Differentiable: given traced ``V``, ``element_weights`` or energy parameters (under
    ``jax.grad``, ``jvp``, ``jacrev``, ``vmap``, ``jit``) ``result.x`` is the UV map as a function
    of them by the implicit function theorem at the optimum (:func:`geomopt.minimize`); the
    start has zero derivative and the map's gauge (translation, rotation, and scale for a
    scale-invariant energy) is handled as :mod:`geomopt.objective.adjoint` says: use a loss
    invariant under it (areas, angles, distortion).  Not with ``bijective``.

    Parameters
    ----------
    V : (n, 3) float rest vertex positions, or a mesh object with ``.vertices`` and ``.faces``
        (a ``trimesh.Trimesh``...) when ``F`` is None.
    F : (m, 3) int triangles (consistently oriented).
    energy : name or :class:`~geomopt.energies.Energy` (default symmetric Dirichlet), or a pair
        ``(name, {parameter: value})`` whose values may be traced
        (:func:`geomopt.energies.energy_spec`).
    solver : a solver object or name (default :class:`~geomopt.solvers.Newton`).
    options : :class:`ParamOptions` (the Tutte weights of the start, the bijective mode and its
        scaffold, size buckets); None: the defaults.
    x0 : the start map: ``None`` or ``"tutte"`` (default: Tutte embedding; the mesh must be a
        topological disk, :func:`~geomopt.exact.topology.check_disk`), ``"projection"`` (the best-fit
        plane projection, :func:`projection_map`: folded wherever the surface turns over), or an
        (n, 2) array (e.g. a UV map made elsewhere).  A start with folded triangles is first
        repaired (:func:`repair_map`: Garanzha et al.'s regularised energy, eps driven to 0, the
        boundary held on a simple polygon), then the chosen energy is minimised from there.
    progress, throw : see :func:`~geomopt.solvers.minimize`.  A callable sees the minimisation
        only: the repair of a folded start reports (as :func:`~geomopt.untangling.untangle` does)
        only with ``progress=True``.
    element_weights : (m,) positive per-triangle weights of the energy (see
        :class:`~geomopt.Objective`), or None.  Not with ``options.bijective``.
    adjoint : the linear solver of the adjoint on traced inputs (see :func:`geomopt.minimize`).

    Returns
    -------
    :class:`~geomopt.solvers.Result` whose ``x`` is the (n, 2) UV map; ``details``
    (:class:`~geomopt.solvers.ParamDetails`) holds the start map, the scale applied to it and
    the repair of a folded start.

    Raises
    ------
    MeshError : invalid or non-disk mesh, invalid start map, or a start map with inverted
        triangles for a barrier energy (infinite there).
    ParameterError : unknown energy/solver/weights name or invalid energy parameter.
    SolveError : only with ``throw=True``, when the result is not converged and flip-free.

    Examples
    --------
    A tent of four triangles around a raised centre, flattened with a free boundary:

    >>> import geomopt
    >>> V = [[0, 0, 0.5], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
    >>> F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]
    >>> result = geomopt.parameterize(V, F, progress=False)
    >>> result.outcome.name, result.success, result.injectivity, result.x.shape
    ('CONVERGED', True, 'global', (5, 2))
    """
    options = options_or_default(ParamOptions, options, "parameterize")
    energy, energy_params = energy_spec(energy, where="parameterize")
    if is_traced(V, element_weights, energy_params):
        if options.bijective:
            raise ParameterError("parameterize: ParamOptions(bijective=True) is not differentiable (the scaffold is "
                                 "remeshed as the map moves); differentiate the free-boundary map (bijective=False)")
        x = parameterize_map(V, F, energy, solver, options.weights, x0, element_weights, adjoint, energy_params)
        return traced_result(x, solver=solver)
    V, F = mesh_arrays(V, F)
    get_energy(energy).check_scale_aware(energy_params)
    check_progress(progress, "parameterize")
    if options.bijective:
        if isinstance(x0, str) or element_weights is not None:
            raise ParameterError("ParamOptions(bijective=True) starts from the Tutte map or a globally injective x0 "
                                 "array, with no element_weights")
        return bijective_parameterize(V, F, (energy, energy_params), solver, weights=options.weights, x0=x0,
                                      options=options.scaffold, progress=progress, throw=throw)
    problem = Problem.surface(V, F)
    solver = Newton() if solver is None else get_solver(solver)
    _check_misplaced_settings(energy, solver, energy_params)
    objective = Objective(problem, energy, buckets=options.buckets, element_weights=element_weights,
                          **energy_params)
    solver.load_ahead(objective)  # the solver's kernels load on a thread while the start map is built
    loop = check_disk(problem.input_simplices, problem.n_vertices)  # once: start map and certificate
    # untangle's callback has another signature than minimize's: only True goes to the repair
    x0, s, repaired = start_map(objective, x0, options.weights, progress is True, loop)
    if x0 is None:
        return _failed_repair(repaired, problem, objective, throw)
    result = minimize(objective, x0, solver, progress=progress, throw=throw)
    cert = certify_bijective(result.x, problem.input_simplices, loop)
    reason = result.reason
    if result.outcome is Outcome.NOT_INJECTIVE and len(cert.local.boundary_overlaps):
        reason += ("; the free boundary folded over itself there, which the bijective mode prevents "
                   "(ParamOptions(bijective=True), geomopt param --bijective)")
    return dataclasses.replace(result, certificate=cert, reason=reason,
                               details=ParamDetails(start=x0, scale=s, repair=repaired))


def parameterize_map(V, F=None, energy="symmetric_dirichlet", solver=None, weights="uniform", x0=None,
                     element_weights=None, adjoint="auto", energy_params=None):
    """:func:`parameterize`'s map (n, 2) as a differentiable function of ``V``,
    ``element_weights`` and ``energy_params`` (:func:`geomopt.objective.adjoint.argmin`)."""
    import jax.numpy as jnp

    from .objective.adjoint import argmin, require_success

    V, F = mesh_arrays(V, F)
    objective = Objective(Problem.surface(V, F), energy, element_weights=element_weights)
    start = None if x0 is None or isinstance(x0, str) else jnp.asarray(x0, jnp.float64)

    def solve(obj, p, start):
        w = obj.element_weights
        result = parameterize(np.asarray(obj.problem.rest_vertices), F, (energy, p), solver,
                              options=ParamOptions(weights=weights), x0=x0 if start is None else np.asarray(start),
                              progress=False, element_weights=None if w is None else np.asarray(w))
        require_success(result, "geomopt.parameterize")
        return result.x, {"objective": result.objective}

    return argmin(objective, dict(energy_params or {}), start, solve, adjoint)

def _failed_repair(repaired, problem, objective, throw) -> Result:
    """The result of a parameterization whose folded start could not be repaired: the
    repair's map, outcome and certificate."""
    result = Result(repaired.x, repaired.outcome, repaired.certificate,
                    RunStats(seconds=repaired.stats.seconds, setup_seconds=repaired.stats.setup_seconds),
                    problem=problem, objective=objective, reason=repaired.reason,
                    details=ParamDetails(repair=repaired))
    if throw:
        raise SolveError(f"repairing the start map failed: {repaired.message}", result)
    return result


def projection_map(V, F) -> np.ndarray:
    """(n, 2) the projection of a surface onto its best-fit plane (principal axes of ``V``),
    oriented so that most of its area is positively oriented.  Folded wherever the surface
    turns over: a start for :func:`repair_map`.

    Parameters
    ----------
    V : (n, 3) vertices;  F : (m, 3) consistently oriented triangles.
    """
    V = np.asarray(V, dtype=np.float64)
    C = V - V.mean(axis=0)
    _, _, Wt = np.linalg.svd(C, full_matrices=False)
    x = C @ Wt[:2].T
    P = x[np.asarray(F)]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area = np.sum(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return x * [1.0, -1.0] if area < 0 else x


@float64
def repair_map(problem, x0, solver="lbfgs", *, options: UntangleOptions | None = None, progress=True,
               throw: bool = False) -> Result:
    """Repair a folded map: Garanzha et al.'s untangling with the boundary held on a simple
    polygon (the map's own boundary when it is one, else a circle), which is freed afterwards by
    the parameterization.

    Parameters
    ----------
    problem : :class:`~geomopt.Problem` (surface or planar) without fixed vertices, or ``(V, F)``.
    x0 : (n, 2) start map with folds.  A map mirrored as a whole (negative total signed area)
        is mirrored back first (``u -> -u``): a UV map's handedness is free.
    solver : the untangling's solver (see :func:`~geomopt.untangling.untangle`).
    options : :class:`~geomopt.untangling.UntangleOptions` of the untangling (``theta``, the
        shape/area balance, and the rest); None: the defaults.
    progress, throw : see :func:`~geomopt.untangling.untangle`.

    Returns
    -------
    :class:`~geomopt.solvers.Result` of the untangling: ``x`` certified flip-free when ``success``.

    Raises
    ------
    MeshError : not a disk, or a start map collapsed to a line or point.
    SolveError : only with ``throw=True``, when no boundary polygon gives a certified map.
    """
    options = options_or_default(UntangleOptions, options, "repair_map")
    if isinstance(problem, tuple):
        problem = Problem.surface(*problem)
    x0 = problem.check_map(x0, "start map x0")
    total = float(problem.signed_volumes(x0).sum())
    if not (total > 0 or total < 0):
        raise MeshError("the start map's total signed area is zero (collapsed): there is nothing to "
                        "repair from; give a start map that is not collapsed to a line or point")
    if total < 0:
        x0 = x0 * [-1.0, 1.0]
    # untangled with a free boundary, a map can end with every triangle positive around a vertex
    # whose fan winds twice (a branch point), which flip-free steps never remove; with the
    # boundary fixed to a simple counter-clockwise polygon a flip-free map is a bijection onto
    # it.  So the boundary is fixed: where it is, when it is such a polygon, else (or when that
    # fails) on a circle by rest arc length spanning the map's extent, around its centroid.  The
    # parameterization frees it afterwards.
    loop = check_disk(problem.input_simplices, problem.n_vertices)
    boundaries = []
    if len(polygon_crossings(x0[loop])) == 0 and polygon_orientation(x0[loop]) == 1:
        boundaries.append(x0[loop])
    radius = 0.5 * float(np.max(x0.max(axis=0) - x0.min(axis=0)))  # a folded map's area means little
    boundaries.append(x0.mean(axis=0) + radius * circle_boundary(problem.rest_vertices, loop))
    with warnings.catch_warnings():
        if throw:  # the SolveError below says it; no MaxStepsWarning before it
            warnings.simplefilter("ignore", MaxStepsWarning)
        for B in boundaries:
            start = x0.copy()
            start[loop] = B
            res = untangle(problem.with_fixed(loop, B), start, solver=solver, progress=progress, options=options)
            if res.success:
                break
    # the inverted elements of the map given, not of the map with its boundary replaced
    res = dataclasses.replace(res, stats=dataclasses.replace(res.stats, inverted_at_start=problem.count_inverted(x0)))
    if throw and not res.success:
        raise SolveError(f"repair_map failed: {res.message}", res)
    return res

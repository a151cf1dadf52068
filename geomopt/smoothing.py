"""Smoothing of valid quad and hex meshes: Winslow (or any energy) with nothing flipping.

Winslow's method (A. M. Winslow, "Numerical solution of the quasilinear Poisson equation in
a nonuniform triangle mesh", J. Comput. Phys. 1, 1966) places the vertices so that the
*inverse* map, from the mesh to its computational grid, is harmonic.  Its variational form
minimises ``int |J^-1|^2 det J``, the :func:`~geomopt.energies.winslow` density of the map
from the computational element (a square / cube, :meth:`Problem.quads` ``rest="reference"``)
to the mesh; the density is a barrier (infinite at ``det J = 0``), which the finite-difference
form lacks (it folds on hard boundaries: Garanzha et al.'s talk "How to compute locally
invertible maps", 2021).

:func:`smooth` evaluates it at the elements' corners, starts from the given mesh (which must be
valid), keeps the boundary vertices fixed (default) and minimises with a solver whose line
search is injective: no corner can change sign.  The result is certified locally injective
(:meth:`~geomopt.mesh.problem.Problem.certify`: hexahedra inside by
:mod:`geomopt.exact.hexvalid`, no vertex wound twice, no free boundary overlapping itself; the input
is returned otherwise).  The result is compared with the input by the minimum scaled
Jacobian (:func:`geomopt.mesh.elements.scaled_jacobian`): where the minimum makes an element invalid
(hexahedra inside) or worse than the input's worst, the vertices of that element are held at
their input positions and the energy is minimised again from the input with them fixed, until
no element is worse (an element whose vertices are all held keeps its input shape); elements
that got worse than their input shape and are close to falling below the worst are held with
them.  So the
output is always valid with a minimum scaled Jacobian at least the input's, and smooth
elsewhere (the input itself when ``MAX_ROUNDS`` solves do not get there).

:func:`smooth` (also ``geomopt.smooth``) returns the :class:`~geomopt.solvers.Result` every
driver returns, with :class:`SmoothDetails`.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ._runtime.config import Int, Maybe, OneOf, options_or_default, validate
from ._runtime.errors import MaxStepsWarning, MeshError, ParameterError, SolveError
from ._runtime.validate import validate_indices
from .mesh.elements import ELEMENT_KINDS, ElementCertificate, Quality, scaled_jacobian
from .solvers import Details, LocalCertificate, Outcome, Result, RunStats

__all__ = ["SmoothDetails", "SmoothOptions", "smooth", "element_problem", "MAX_ROUNDS", "RISK"]

#: solves before :func:`smooth` gives up and returns its input
MAX_ROUNDS = 8
#: elements that the minimum makes worse than their input shape and that end within this
#: scaled Jacobian of the input's worst are held with the ones below it
RISK = 0.1
#: the :class:`~geomopt.solvers.RunStats` fields summed over :func:`smooth`'s solves
_SUMMED = ("iterations", "evaluations", "seconds", "setup_seconds", "cpu_seconds", "setup_cpu_seconds")


@dataclasses.dataclass(frozen=True)
class SmoothDetails(Details):
    """What :func:`smooth` adds to its :class:`~geomopt.solvers.Result` (``details``).

    The result's ``certificate`` is the exact :class:`~geomopt.solvers.LocalCertificate` of
    ``x`` (elements valid everywhere, no vertex wound twice, no free boundary overlapping
    itself, handles in place); ``stats.outer_iterations`` counts the solves (1 when nothing was
    held), ``stats.iterations`` / ``seconds`` sum them; ``problem`` is the problem solved first
    (its ``elements`` oriented, its handles) and, like ``stats.energy``, in the frame of
    ``x * scale``.

    Attributes
    ----------
    before : :class:`~geomopt.mesh.elements.Quality` of the input.
    after : :class:`~geomopt.mesh.elements.Quality` of ``x``.
    elements : :class:`~geomopt.mesh.elements.ElementCertificate` of ``x`` (exact: which test
        decided each element).
    held : (h,) int64, vertices held at their input positions (beside the fixed ones) because
        the energy minimum made an element around them worse than the input's worst.
    scale : the power of two the input was multiplied by before solving
        (:func:`geomopt.exact.predicates.box_scale`: exact, so that meshes at 1e200 or 1e-150 smooth as
        at size 1).
    improved : ``x`` certified, its minimum scaled Jacobian not lower than the input's, and
        different from the input.
    """

    before: Quality
    after: Quality
    elements: ElementCertificate
    held: np.ndarray
    scale: float = 1.0
    improved: bool = False

    @property
    def message(self) -> str:
        """One line: the minimum and mean scaled Jacobian and the elements below 0.2, before
        and after, and the vertices held."""
        held = f"; {len(self.held)} vertices held where the minimum would be worse" if len(self.held) else ""
        return (f"min scaled Jacobian {self.before.min:.4f} -> {self.after.min:.4f}, mean "
                f"{self.before.mean:.4f} -> {self.after.mean:.4f}, below 0.2: {self.before.below_0_2} -> "
                f"{self.after.below_0_2}{held}")


def element_problem(V, E, fixed=None, rest="reference"):
    """The :class:`~geomopt.Problem` of a quad (``V`` (n, 2)) or hex (``V`` (n, 3)) mesh ``E``
    with ``fixed`` vertices held where ``V`` has them (default: the boundary; an empty array
    frees every vertex)."""
    from .mesh.problem import Problem

    V = np.asarray(V, dtype=np.float64)
    E = np.asarray(E)
    kind = ELEMENT_KINDS.get(E.shape[1]) if E.ndim == 2 else None
    if kind is None or V.ndim != 2 or V.shape[1] != kind.dim:
        raise MeshError(f"smoothing needs quads with 2D vertices or hexahedra with 3D vertices, got elements "
                        f"of shape {E.shape} and vertices of shape {V.shape}")
    problem = Problem.cells(V, E, rest=rest)
    fixed = problem.boundary_vertices() if fixed is None else validate_indices(fixed, len(V), "fixed vertex indices")
    return problem.with_fixed(fixed, V[fixed])


@dataclasses.dataclass(frozen=True)
class SmoothOptions:
    """The settings of :func:`smooth` (validated).

    Attributes
    ----------
    rest : ``"reference"`` (squares / cubes of the mean edge length: Winslow) or ``"mesh"``
        (the input's own elements: then the input is the energy's minimum and nothing moves).
    max_steps : solver iteration limit per solve (default: the solver's).
    max_rounds : solves before giving up and returning the input (see the module notes).
    """

    rest: str = "reference"
    max_steps: int | None = None
    max_rounds: int = MAX_ROUNDS

    def __post_init__(self):
        validate(self, rest=OneOf(("reference", "mesh")), max_steps=Maybe(Int(1)), max_rounds=Int(1))


def smooth(V, E, energy="winslow", solver="newton", *, fixed=None, options: SmoothOptions | None = None,
           progress=False, throw: bool = False) -> Result:
    """Smooth a valid quad or hex mesh without inverting anything or worsening its worst element.

    Parameters
    ----------
    V : (n, 2) quad or (n, 3) hex vertex positions.
    E : (m, 4) quads or (m, 8) hexahedra (VTK order), every element valid on ``V`` (a positive
        Jacobian everywhere).
    energy : an energy name or object (default ``"winslow"``), or a pair ``(name, {parameter:
        value})`` (:func:`geomopt.energies.energy_spec`).
    solver : a solver name or object with an injective search (default projected Newton).
    fixed : vertex ids held in place (default: the boundary vertices).  With none (``[]``) the
        result is moved back to the input's centroid and, for an energy that does not change with
        scale, its size; an energy that falls with the size (Winslow in 3D) is refused then.
    options : :class:`SmoothOptions` (rest shape, iteration limits).
    progress : passed to :func:`~geomopt.solvers.minimize`.
    throw : raise :class:`~geomopt.SolveError` (carrying the result) unless it ``success``
        (converged and certified); False: return it, whatever its outcome.

    Returns
    -------
    :class:`~geomopt.solvers.Result` with :class:`SmoothDetails`: ``x`` locally injective
    (exact) with a minimum scaled Jacobian at least the input's; ``outcome`` the last solve's,
    MAX_STEPS when ``max_rounds`` solves each made an element worse (``x`` is then the input),
    NOT_INJECTIVE when the minimum folds a free boundary over itself (``x`` the input too; the
    reason in ``reason``).

    Raises
    ------
    MeshError
        The mesh is malformed, or ``V`` is not locally injective (an element not valid, a
        vertex wound twice, a boundary fan overlapping itself: untangle it first).
    ParameterError
        The solver's line search is not injective, or an energy or solver is unknown.
    SolveError
        Only with ``throw=True``, when the result is not ``success``.

    Examples
    --------
    A perturbed quad mesh of an annulus sector, smoothed with its boundary fixed:

    >>> from geomopt.mesh import generators
    >>> from geomopt import smooth
    >>> V, Q = generators.sector_mesh(2, 4, perturb=0.4, seed=1)
    >>> result = smooth(V, Q)
    >>> result.details.improved, result.details.after.min > result.details.before.min
    (True, True)
    """
    from .energies import energy_spec, get_energy
    from .exact.predicates import box_scale
    from .solvers import get_solver

    options = options_or_default(SmoothOptions, options, "smooth")
    energy, params = energy_spec(energy, where="smooth")
    V = np.asarray(V, dtype=np.float64)
    scale = box_scale(V) if V.ndim == 2 else 1.0  # exact: at 1e200 or 1e-150 as at 1
    problem = element_problem(V * scale, E, fixed, options.rest)
    V = V * scale
    start = _certified_input(problem, V)
    if not len(problem.fixed):  # nothing holds the size: an energy that falls with it would collapse the mesh
        get_energy(energy).check_scale_aware(params, V.shape[1], "smoothing with no vertex fixed",
                                             "fix the boundary (fixed=None; geomopt smooth --fix boundary) or use a "
                                             "scale-invariant energy (mips)")
    solver = get_solver(solver)
    if not getattr(getattr(solver, "search", None), "injective", True):
        raise ParameterError("smooth needs a solver whose line search is injective (search.injective=True)")
    if options.max_steps is not None:
        solver = dataclasses.replace(solver, max_steps=options.max_steps)
    with warnings.catch_warnings():
        if throw:  # the SolveError below says it; no MaxStepsWarning before it
            warnings.simplefilter("ignore", MaxStepsWarning)
        solves, x, held, outcome, reason = _rounds(problem, V, start, energy, solver, progress, options.max_rounds,
                                                   params)
    if not len(problem.fixed) and x is not V:  # (V itself: no solve kept, nothing to move back)
        x = _in_gauge(x, V, solves[-1].objective)
    local = problem.certify(x)  # elements valid inside, no vertex wound twice, no boundary overlap
    if not local.ok:  # a free boundary folded over itself: the input
        outcome, reason = Outcome.NOT_INJECTIVE, (f"the minimum is not locally injective ({local.message}); the "
                                                  f"input is returned")
        x, held, local = V, np.zeros(0, np.int64), start
    before, after = start.elements.quality, local.elements.quality
    details = SmoothDetails(before, after, local.elements, held, scale,
                            local.ok and after.min >= before.min and not np.array_equal(x, V))
    result = Result(x / scale, outcome, _certificate(local, problem, x), _totals(solves, x), problem=problem,
                    objective=solves[-1].objective, solver=solver, reason=reason, details=details)
    if throw and not result.success:
        raise SolveError(f"smooth failed: {result.message}", result)
    return result


def _rounds(problem, V, start, energy, solver, progress, max_rounds, params):
    """``(solves, x, held, outcome, reason)``: :func:`smooth`'s minimisations from ``V`` (each
    a :class:`~geomopt.solvers.Result`), holding the vertices of the elements the last one made
    worse than the input's worst (``start``: the input's certificate) until none is; after
    ``max_rounds`` solves, the input ``V``, nothing held, MAX_STEPS."""
    from .objective.objective import Objective
    from .solvers import minimize

    E, held, current, solves = problem.elements, np.zeros(0, np.int64), problem, []
    sj_input = scaled_jacobian(V, E)
    for _ in range(max_rounds):
        solves.append(minimize(Objective(current, energy, buckets=True, **params), V, solver=solver,
                               progress=progress))
        x = np.asarray(solves[-1].x, dtype=np.float64)
        worse, at_risk = _worse(x, E, start.elements.quality.min, sj_input)
        if not worse.any():
            return solves, x, held, solves[-1].outcome, solves[-1].reason
        held = np.union1d(held, np.setdiff1d(np.unique(E[worse | at_risk]), problem.fixed))
        both = np.union1d(problem.fixed, held)
        current = problem.with_fixed(both, V[both])
    return solves, V, np.zeros(0, np.int64), Outcome.MAX_STEPS, (
        f"each of {max_rounds} solves made an element worse than the input's worst; the input is returned")


def _in_gauge(x, V, objective):
    """``x`` with nothing held moved back where ``V`` is: translated to its centroid (every energy
    is a function of the Jacobians: free to translate), and scaled to its size where the energy
    does not change with scale (Winslow, MIPS: their minimisers are a similarity class, along which
    a solver may drift until the mesh has shrunk a million times; the elements' shapes, the scaled
    Jacobians, are the same).  ``x`` as it is when it is not finite."""
    if not np.isfinite(x).all():
        return x
    c, c0 = x.mean(axis=0), V.mean(axis=0)
    size, size0 = np.sqrt(np.mean((x - c) ** 2)), np.sqrt(np.mean((V - c0) ** 2))
    moved = x - c + c0
    if not size > 0:
        return moved
    scaled = (x - c) * (size0 / size) + c0
    e, e_scaled = (float(objective.value(objective.prepare_map(y))) for y in (x, scaled))
    return scaled if np.isfinite(e_scaled) and abs(e_scaled - e) <= 1e-9 * max(abs(e), 1.0) else moved


def _certificate(local, problem, x) -> LocalCertificate:
    """The :class:`~geomopt.solvers.LocalCertificate` of ``x`` from its exact ``local`` one and
    the handles of ``problem`` (exact: :func:`geomopt.exact.predicates.differing_rows`)."""
    from .exact.predicates import differing_rows

    return LocalCertificate.of(local, np.count_nonzero(differing_rows(x[problem.fixed], problem.fixed_positions)))


def _totals(solves, x) -> RunStats:
    """The :class:`~geomopt.solvers.RunStats` of :func:`smooth`: the solves' sums, their count as
    ``outer_iterations``, and the last one's energy when ``x`` is its map (else nan)."""
    last = solves[-1].stats
    mine = np.array_equal(x, np.asarray(solves[-1].x, dtype=np.float64))
    return RunStats(**{name: sum(getattr(r.stats, name) for r in solves) for name in _SUMMED},
                    outer_iterations=len(solves), energy=last.energy if mine else float("nan"), volume=last.volume,
                    inverted_at_start=0)


def _certified_input(problem, V):
    """The exact :class:`~geomopt.mesh.elements.ElementLocalCertificate` of the input ``V`` (n, d)
    (:meth:`~geomopt.mesh.problem.Problem.certify`); MeshError unless ``V`` is locally injective."""
    local = problem.certify(V)
    start = local.elements
    if not start.certified:
        raise MeshError(f"{start.invalid} element(s) of the input are not valid (their Jacobian is not positive "
                        f"everywhere; {start.corner_only} only inside); smoothing keeps a valid mesh valid: "
                        f"untangle it first (geomopt untangle)")
    if not local.ok:
        raise MeshError(f"the input mesh is not locally injective: {local.message}; smoothing keeps a locally "
                        f"injective mesh locally injective: untangle it first (geomopt untangle) or repair it")
    return local


def _worse(X, E, floor, sj_input):
    """``(worse, at_risk)``, each (m,) bool: elements invalid under ``X`` (exact) or with a scaled
    Jacobian below ``floor``; and elements worse than their input shape ``sj_input`` (m,) and
    within :data:`RISK` of the floor (held with the worse ones: the next to fall below)."""
    from .mesh.elements import valid_elements

    if not np.isfinite(X).all():
        return np.ones(len(E), bool), np.zeros(len(E), bool)
    sj = scaled_jacobian(X, E)
    return ~valid_elements(X, E) | (sj < floor), (sj < sj_input) & (sj < floor + RISK)

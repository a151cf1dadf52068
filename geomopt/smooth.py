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
search is injective: no corner can change sign.  Hexahedra are then certified inside
(:mod:`geomopt.hexvalid`).  The result is compared with the input by the minimum scaled
Jacobian (:func:`geomopt.elements.scaled_jacobian`): when the minimiser lowers it, the output
is the point of the straight path from the input to the minimiser, among ``1, 1/2, 1/4, ...``
of the way, with the largest minimum scaled Jacobian that is valid and not below the input's;
if there is none the input is returned unchanged (``improved`` False).  So the output is always
valid and its minimum scaled Jacobian never lower than the input's.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ._errors import MeshError, ParameterError
from .elements import ElementCertificate, Quality, certify_elements, quality

__all__ = ["SmoothResult", "smooth", "element_problem"]

#: blends ``input + t (minimiser - input)`` tried when the minimiser lowers the worst element
BLENDS = tuple(0.5**k for k in range(11))


@dataclasses.dataclass(frozen=True)
class SmoothResult:
    """The outcome of :func:`smooth`.

    Attributes
    ----------
    x : (n, d) the smoothed vertices (the input where nothing improved).
    before, after : :class:`~geomopt.elements.Quality` of the input and of ``x``.
    certificate : :class:`~geomopt.elements.ElementCertificate` of ``x`` (exact).
    blend : float, the fraction of the way from the input to the minimiser that ``x`` is at
        (1: the minimiser; 0: the input).
    outcome : the solver's :class:`~geomopt.solvers.Outcome`.
    iterations : int;  seconds : float, the solve.
    problem : the :class:`~geomopt.Problem` solved (its ``elements`` oriented, its handles).
    """

    x: np.ndarray
    before: Quality
    after: Quality
    certificate: ElementCertificate
    blend: float
    outcome: object
    iterations: int
    seconds: float
    problem: object = None

    @property
    def improved(self) -> bool:
        """The output differs from the input: valid, its minimum scaled Jacobian not lower and
        (its minimum or its mean) higher."""
        return self.blend > 0 and (self.after.min > self.before.min or self.after.mean > self.before.mean)

    @property
    def message(self) -> str:
        if self.blend == 0:
            return (f"no smoothing step keeps the minimum scaled Jacobian at or above the input's "
                    f"{self.before.min:.4f}; the input is returned unchanged")
        part = "" if self.blend == 1 else f" ({self.blend:g} of the way to the energy minimum)"
        return (f"min scaled Jacobian {self.before.min:.4f} -> {self.after.min:.4f}, mean "
                f"{self.before.mean:.4f} -> {self.after.mean:.4f}{part}")


def element_problem(V, E, fixed=None, rest="reference"):
    """The :class:`~geomopt.Problem` of a quad (``V`` (n, 2)) or hex (``V`` (n, 3)) mesh ``E``
    with ``fixed`` vertices held where ``V`` has them (default: the boundary; an empty array
    frees every vertex)."""
    from .problem import Problem

    V = np.asarray(V, dtype=np.float64)
    E = np.asarray(E)
    if E.ndim != 2 or E.shape[1] not in (4, 8) or V.ndim != 2 or V.shape[1] != (2 if E.shape[1] == 4 else 3):
        raise MeshError(f"smoothing needs quads with 2D vertices or hexahedra with 3D vertices, got elements "
                        f"of shape {E.shape} and vertices of shape {V.shape}")
    make = Problem.quads if E.shape[1] == 4 else Problem.hexes
    problem = make(V, E, rest=rest)
    fixed = problem.boundary_vertices() if fixed is None else np.asarray(fixed, dtype=np.int64)
    return problem.with_fixed(fixed, V[fixed])


def smooth(V, E, energy="winslow", solver="newton", fixed=None, rest="reference", max_steps=None,
           progress=False, **params) -> SmoothResult:
    """Smooth a valid quad or hex mesh without inverting anything.

    Parameters
    ----------
    V : (n, 2) quad or (n, 3) hex vertex positions;  E : (m, 4) quads or (m, 8) hexahedra (VTK
        order), every element valid on ``V`` (a positive Jacobian everywhere).
    energy : an energy name or object (default ``"winslow"``); ``params`` its parameters.
    solver : a solver name or object with an injective search (default projected Newton).
    fixed : vertex ids held in place (default: the boundary vertices).
    rest : ``"reference"`` (squares / cubes of the mean edge length: Winslow) or ``"mesh"``
        (``V``'s own elements: then ``V`` is the energy's minimum and nothing moves).
    max_steps : solver iteration limit (default: the solver's).
    progress : passed to :func:`~geomopt.solvers.minimize`.

    Returns
    -------
    :class:`SmoothResult`, its ``x`` valid (exact) with a minimum scaled Jacobian at least
    the input's.

    Raises
    ------
    MeshError
        The mesh is malformed, or some element of ``V`` is not valid (untangle it first).
    """
    from ._objective import Objective
    from .solvers import get_solver, minimize

    problem = element_problem(V, E, fixed, rest)
    E = problem.elements
    V = np.asarray(V, dtype=np.float64)
    start = certify_elements(V, E)
    if not start.certified:
        raise MeshError(f"{start.invalid} element(s) of the input are not valid (their Jacobian is not positive "
                        f"everywhere; {start.corner_only} only inside); smoothing keeps a valid mesh valid: "
                        f"untangle it first (geomopt untangle)")
    solver = get_solver(solver)
    if not getattr(getattr(solver, "search", None), "injective", True):
        raise ParameterError("smooth needs a solver whose line search is injective (search.injective=True)")
    if max_steps is not None:
        solver = dataclasses.replace(solver, max_steps=max_steps)
    t0 = time.perf_counter()
    result = minimize(Objective(problem, energy, **params), V, solver=solver, progress=progress)
    seconds = time.perf_counter() - t0
    x, blend = _best_blend(V, np.asarray(result.x, dtype=np.float64), E, start.quality)
    cert = certify_elements(x, E)
    return SmoothResult(x, start.quality, cert.quality, cert, blend, result.outcome,
                        int(result.iterations), seconds, problem)


def _best_blend(V, X, E, before):
    """The point ``V + t (X - V)``, ``t`` in :data:`BLENDS`, that is valid, has a minimum
    scaled Jacobian at least ``before.min`` and the largest such minimum (ties: larger t);
    ``(V, 0.0)`` when none.  ``X`` itself (``t = 1``) when it qualifies."""
    from .elements import valid_elements

    best, best_t, best_q = V, 0.0, before.min
    for t in BLENDS:
        Y = X if t == 1 else V + t * (X - V)
        if not np.isfinite(Y).all() or not valid_elements(Y, E).all():
            continue
        q = quality(Y, E).min
        if q >= before.min and (best_t == 0.0 or q > best_q):
            best, best_t, best_q = Y, t, q
        if t == 1 and q >= before.min:
            break
    return best, best_t

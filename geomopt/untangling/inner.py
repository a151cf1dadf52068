"""The inner solver of the eps loop: :func:`default_solver` by name and size, and the
:func:`stiff_solver` a stalling inner solve continues with."""

from __future__ import annotations

import dataclasses

from .._runtime.errors import ParameterError
from ..solvers import LBFGS, AbstractSolver, Newton
from ..objective.projection import Exact
from ..solvers.linesearch import InjectiveSearch

__all__ = ["LAPLACIAN_FROM", "LOCAL_TANGLE_SHARE", "STIFF_AFTER", "PROBE_PROGRESS", "STIFF_AFTER_NEWTON", "stiff_solver", "default_solver",
           "polish_solver"]


LAPLACIAN_FROM = 50_000  # active elements from which the default L-BFGS uses the Laplacian seed


#: the share of inverted elements at the start from which a tangle counts as local (noise,
#: scattered vertices) and keeps the diagonal seed at any size (see :func:`default_solver`)
LOCAL_TANGLE_SHARE = 0.25


#: inner iterations after which the default L-BFGS continues with the Laplacian seed
STIFF_AFTER = 100


#: a probe of :data:`STIFF_AFTER` iterations that leaves fewer than these fractions of the
#: inverted elements and of the energy it started with is followed by another probe instead of
#: the switch (see :class:`~geomopt.untangling.EpsContinuation`)
PROBE_PROGRESS = (0.9, 0.5)


#: inner iterations after which the default L-BFGS on hexahedra's corners continues with Newton:
#: a Newton iteration costs as much as many L-BFGS ones on corner problems, so the probe is set
#: to cost about ten Newton iterations (measurements: benchmarks/README.md, issue 49 section)
STIFF_AFTER_NEWTON = 1000


def stiff_solver(name: str, dim: int, corners: bool = False) -> AbstractSolver | None:
    """The solver an inner solve of :func:`default_solver` continues with when it has not
    converged after :data:`STIFF_AFTER` iterations (None: no switch).

    ``"lbfgs"``: the Laplacian seed (Sobolev-preconditioned L-BFGS), because an inner solve
    that outlasts the probe with the diagonal seed is a stiff, global one (the first outer
    iteration of a large rotation), where the Laplacian seed's iteration count does not grow
    with the mesh; on local tangles (noise) the diagonal seed converges within the probe, at a
    lower cost per iteration, and is kept.

    ``corners`` in 3D (the corner tetrahedra of hexahedra): Newton (:func:`default_solver`
    ``"newton"``), because no L-BFGS seed solves a stiff corner problem (the first eps solve
    stalls with either seed, each later eps stalls too and the loop never untangles) while
    Newton reaches that eps's minimum with every corner positive.  The switch comes after
    :data:`STIFF_AFTER_NEWTON` L-BFGS iterations.  Any other ``name``: None.  Measurements:
    benchmarks/README.md (issue 49 section)."""
    if str(name).strip().lower() != "lbfgs":
        return None
    if corners and dim == 3:
        return default_solver("newton", dim)
    return dataclasses.replace(default_solver("lbfgs", dim, LAPLACIAN_FROM, corners), precondition="laplacian")


def default_solver(name: str, dim: int, n_elements: int = 0, corners: bool = False,
                   inverted: int = 0) -> AbstractSolver:
    """The inner solver :func:`~geomopt.untangling.untangle` uses for ``"lbfgs"`` or ``"newton"``.

    ``"lbfgs"``: :class:`~geomopt.solvers.LBFGS` (history 10, the injective search without its
    injectivity test) with the M1QN3 diagonal seed below :data:`LAPLACIAN_FROM` elements and the
    Laplacian seed (``precondition="laplacian"``) from there on, because the Laplacian seed's
    host solves cost more than the iterations they save on smaller problems and fewer on larger
    ones.  At most 30000 steps per eps in 2D and on corners, 3000 on tetrahedra.

    A start with at least :data:`LOCAL_TANGLE_SHARE` of its ``n_elements`` ``inverted`` is a
    local tangle and keeps the diagonal seed at any size (simplices only; the stiff switch's
    probe still hands a stalling solve to the Laplacian seed), because global tangles
    (rotations, bends, Tutte stars) invert a thin band of elements and local ones (noise,
    scattered interiors) about half, and on local tangles the diagonal seed's cheaper
    iterations finish first or even (while diagonal steps taken first slow a later Laplacian
    solve of a global tangle).

    ``corners``: the problem's simplices are the corner tetrahedra of hexahedra, which need more
    L-BFGS steps per eps than tets, hence the 2D cap of 30000 (the tets' 3000 stalls).

    ``"newton"``: :class:`~geomopt.solvers.Newton` with the clamped projection, ``rtol=1e-7``,
    at most 100 steps.  Any other name raises :class:`~geomopt.ParameterError`.  Measurements
    behind the threshold and the caps: benchmarks/README.md (issue 49 section)."""
    key = str(name).strip().lower()
    local = not corners and inverted >= LOCAL_TANGLE_SHARE * n_elements > 0
    if key == "lbfgs":
        return LBFGS(history=10, rtol=1e-6, gtol=1e-6, max_steps=30000 if dim == 2 or corners else 3000,
                     search=InjectiveSearch(injective=False, c2=0.9),
                     precondition="laplacian" if n_elements >= LAPLACIAN_FROM and not local else "diagonal")
    if key == "newton":
        return Newton(projection="clamp", rtol=1e-7, max_steps=100,
                      search=InjectiveSearch(injective=False))
    raise ParameterError(f"unknown untangling solver {name!r}; valid: 'lbfgs', 'newton' or a solver object")


def polish_solver() -> Newton:
    """The solver of untangling's final polish (:class:`~geomopt.untangling.EpsContinuation`):
    Newton with its injective search (no element flips back) to a decrement of ``1e-12 |E|``,
    whose last step leaves the map the energy's minimiser to rounding (the tight optimum the
    implicit function theorem differentiates, :func:`geomopt.untangling.implicit.untangle_map`).
    The exact Hessian (no projection; shifted where it does not factor), because the inner
    solves end near the minimum, where it converges quadratically from the first step and a
    projection's clamped first step only adds an iteration.  Its
    search tries no longer step than Newton's (``expand=0``): from there the full step is the
    right one, and each doubling tried costs an energy evaluation."""
    return Newton(rtol=1e-12, max_steps=50, projection=Exact(), search=InjectiveSearch(expand=0))

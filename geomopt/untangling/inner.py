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
#: a Newton iteration costs about a hundred L-BFGS ones there (hex22-rot180, 85k corners: 13
#: Newton iterations took 13 s, compilation included, against 1.8 s for its 182 L-BFGS ones), so the probe is ten
#: Newton iterations' worth
STIFF_AFTER_NEWTON = 1000


def stiff_solver(name: str, dim: int, corners: bool = False) -> AbstractSolver | None:
    """The solver an inner solve of :func:`default_solver` continues with when it has not
    converged after :data:`STIFF_AFTER` iterations (None: no switch).

    ``"lbfgs"``: the Laplacian seed (Sobolev-preconditioned L-BFGS).  An inner solve that
    needs more than a hundred iterations with the diagonal seed is a stiff, global one (the
    first outer iteration of a large rotation): there the Laplacian seed's iteration count
    does not grow with the mesh (disk 12.7k triangles rotated 180 degrees: 1,474 -> 50 inner
    iterations, 2.2 -> 0.2 s; an irregular Delaunay disk 6,855 -> 1,259), while on local
    tangles (noise) the diagonal seed converges within the probe at a third of the cost per
    iteration and is kept.

    ``corners`` in 3D (the corner tetrahedra of hexahedra): Newton (:func:`default_solver`
    ``"newton"``).  No L-BFGS seed solves a stiff corner problem: on the hex rod of 9 x 9 x 108
    bent by 180 degrees (69,984 corners; the tet rod of the same grid untangles in 1,565
    Laplacian-seeded iterations) the first eps solve stalls with the Laplacian seed after 8,437
    iterations at a mean energy of 567 with 26,627 corners inverted (6,304 at the start), with the
    diagonal seed after 15,736 at 72 with 1,137; each later eps then stalls too and the loop never
    untangles.  Newton reaches that eps's minimum (mean energy 4.31, every corner positive) in 73
    iterations.  The switch comes after :data:`STIFF_AFTER_NEWTON` L-BFGS iterations."""
    if str(name).strip().lower() != "lbfgs":
        return None
    if corners and dim == 3:
        return default_solver("newton", dim)
    return dataclasses.replace(default_solver("lbfgs", dim, LAPLACIAN_FROM, corners), precondition="laplacian")


def default_solver(name: str, dim: int, n_elements: int = 0, corners: bool = False,
                   inverted: int = 0) -> AbstractSolver:
    """The inner solver :func:`~geomopt.untangling.untangle` uses for ``"lbfgs"`` or ``"newton"``.

    ``"lbfgs"``: M1QN3 diagonal seed below ``LAPLACIAN_FROM`` elements, the Laplacian seed
    (:class:`~geomopt.solvers.LBFGS` ``precondition="laplacian"``) from there on.  Measured
    (warm seconds, diagonal -> Laplacian): ~1e5 elements: rotated square 104 -> 58, Tutte
    L / star 27 -> 11 / 19 -> 11, bent rod 43 -> 13, twisted cube 12.6 -> 6.1, noisy disk
    1.3 -> 3.0; the LIM armadillo (24k tets) 0.66 -> 1.04 and 2D cases of ~1e4 triangles
    were slower or even with it (its host solves cost more than the iterations they save).

    A start with at least :data:`LOCAL_TANGLE_SHARE` of its ``n_elements`` ``inverted`` is a
    local tangle and keeps the diagonal seed at any size (simplices only; the stiff switch's
    probe still hands a stalling solve to the Laplacian seed).  Global tangles invert a thin
    band: rotations, bends and Tutte stars 0.7-10% of their elements, noise of two edge
    lengths and scattered interiors 47-50%.  Measured at 6e4-1.4e5 elements (2-core box under
    load, same run; inner iterations and seconds, Laplacian -> diagonal): structured disk
    noise 83 / 1.32 -> 93 / 0.66, scattered disk 155 / 3.23 -> 142 / 1.69, Delaunay ball
    noise 562 / 5.65 -> 387 / 3.55, cube noise 108 / 1.14 -> 99 / 1.13, Delaunay disk noise
    925 / 13.3-13.8 -> 1,244 / 13.7-18.2 (even); a disk rotated by 180 degrees needs 739-874
    iterations instead of 296 once ten or more diagonal steps came first.

    ``corners``: the problem's simplices are the corner tetrahedra of hexahedra, which need more
    L-BFGS steps per eps than tets: 30000 as in 2D (a hex rod of 6 x 6 x 72 bent by 180 degrees
    took 9942 in its first outer iteration; capped at 3000 it stalled with 67 hexahedra inverted)."""
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
    The exact Hessian (no projection; shifted where it does not factor): the inner solves end
    near the minimum, where it converges quadratically from the first step (the twisted box of
    10k tets: 2 iterations, against 3 with the adaptive projection's first clamped one).  Its
    search tries no longer step than Newton's (``expand=0``): from there the full step is the
    right one, and each doubling tried costs an energy evaluation."""
    return Newton(rtol=1e-12, max_steps=50, projection=Exact(), search=InjectiveSearch(expand=0))

"""Untangling: Garanzha et al.'s regularised energy with an eps-driving outer loop.

V. Garanzha, I. Kaporin, L. Kudryavtseva, F. Protais, N. Ray, D. Sokolov, "Foldover-free maps
in 50 lines of code", ACM Trans. Graph. 40(4), 2021.

:func:`untangle` (also ``geomopt.untangle``) minimises, with the handles fixed,

    E_eps(x) = sum_e vol_e * ( |J|^2 / chi(det J, eps)^(2/d) + lam (det J^2 + 1) / chi(det J, eps) )

(:data:`geomopt.energies.garanzha`) at fixed ``eps`` with an inner solver, shrinks ``eps``
from the worst determinant after each inner solve, and stops when every element is positively
oriented and the energy settled; then Newton polishes the map at a constant eps
(:func:`final_eps`; ``UntangleOptions(polish=False)`` skips it).
The result is certified exactly: no inverted element, and
around every vertex (2D) or edge and vertex (3D) the elements cover a neighbourhood once or,
on the boundary, without overlapping itself.

One job per module: :mod:`~geomopt.untangling.options` (the settings),
:mod:`~geomopt.untangling.inner` (the inner solver and its stiff switch),
:mod:`~geomopt.untangling.schedule` (the eps schedule), :mod:`~geomopt.untangling.rest` (the rest
mesh as measured), :mod:`~geomopt.untangling.start` (the start, connected part by connected part),
:mod:`~geomopt.untangling.continuation` (the outer loop as a continuation of the one loop, and
the judgement of the final map), :mod:`~geomopt.untangling.driver` (:func:`untangle`).  The
departures from the paper's code and the measurements behind them: ``docs/untangling.md``.
"""

from .continuation import EpsContinuation, UntangleRecord, judged
from .driver import UntangleResult, infeasible, untangle
from .inner import (LAPLACIAN_FROM, LOCAL_TANGLE_SHARE, PROBE_PROGRESS, STIFF_AFTER, STIFF_AFTER_NEWTON, default_solver,
                    polish_solver, stiff_solver)
from .options import POLISH_UP_TO, UntangleOptions
from .rest import badly_shaped, check_rest, equilateral_rest
from .schedule import EPS_FLOOR, START_RATIO, final_eps, next_eps, start_eps
from .start import BOX, STARTS, choose_start, harmonic_start, hold_free_parts

__all__ = ["untangle", "infeasible", "UntangleOptions", "UntangleResult", "UntangleRecord", "EpsContinuation", "judged",
           "default_solver", "stiff_solver", "next_eps", "start_eps", "badly_shaped", "check_rest",
           "equilateral_rest", "STARTS", "BOX", "harmonic_start", "choose_start", "hold_free_parts", "EPS_FLOOR",
           "START_RATIO", "LAPLACIAN_FROM", "LOCAL_TANGLE_SHARE", "STIFF_AFTER", "STIFF_AFTER_NEWTON",
           "PROBE_PROGRESS", "final_eps", "polish_solver", "POLISH_UP_TO"]

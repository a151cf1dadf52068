"""Solvers over one interface (``init / step / terminate / run / with_params``), each a
descent plus the shared :class:`~geomopt.linesearch.InjectiveSearch`, driven by :func:`minimize`.

``SOLVERS`` maps names to factories: ``newton`` (projected Newton), ``lbfgs``, ``slim``
(Rabinovich et al. 2017), ``aqp`` (Kovalsky et al. 2016), ``cm`` (Shtengel et al. 2017, 2D),
and optimistix's ``optx-bfgs``, ``optx-lbfgs``, ``optx-ncg`` (nonlinear CG) through
:class:`~geomopt.solvers.optimistix.Optimistix`.
"""

from .._errors import ParameterError
from ._base import AbstractSolver, Outcome, Progress, Result, State, minimize
from .aqp import AQP
from .lbfgs import LBFGS
from .newton import CM, SLIM, Newton


def _optx(kind):
    def make():
        import optimistix as optx

        from .optimistix import Optimistix

        tol = dict(rtol=1e-10, atol=1e-10)
        solver = {"bfgs": lambda: optx.BFGS(**tol), "lbfgs": lambda: optx.LBFGS(**tol),
                  "ncg": lambda: optx.NonlinearCG(**tol)}[kind]()
        return Optimistix(solver)

    return make


SOLVERS = {
    "newton": Newton, "lbfgs": LBFGS, "slim": SLIM, "aqp": AQP, "cm": CM,
    "optx-bfgs": _optx("bfgs"), "optx-lbfgs": _optx("lbfgs"), "optx-ncg": _optx("ncg"),
}


def get_solver(name_or_solver):
    """A solver object by name (``SOLVERS``), or the object itself."""
    if isinstance(name_or_solver, AbstractSolver):
        return name_or_solver
    if not isinstance(name_or_solver, str):
        raise ParameterError(f"solver must be a name ({', '.join(SOLVERS)}) or a solver object, "
                             f"got {type(name_or_solver).__name__}")
    key = name_or_solver.strip().lower().replace("_", "-")
    if key not in SOLVERS:
        raise ParameterError(f"unknown solver {name_or_solver!r}; valid solvers: {', '.join(SOLVERS)}")
    return SOLVERS[key]()


__all__ = ["SOLVERS", "get_solver", "AbstractSolver", "Outcome", "Progress", "Result", "State",
           "minimize", "Newton", "LBFGS", "SLIM", "AQP", "CM"]

"""Solvers over one interface: ``init / step / terminate`` driven by :func:`minimize`."""

from ._base import AbstractSolver, Outcome, Progress, Result, State, minimize
from .lbfgs import LBFGS
from .newton import Newton

from .._errors import ParameterError

SOLVERS = {"newton": Newton, "lbfgs": LBFGS}


def get_solver(name_or_solver):
    """A solver object by name (``SOLVERS``), or the object itself."""
    if isinstance(name_or_solver, AbstractSolver):
        return name_or_solver
    key = str(name_or_solver).strip().lower()
    if key not in SOLVERS:
        raise ParameterError(f"unknown solver {name_or_solver!r}; valid solvers: {', '.join(sorted(SOLVERS))}")
    return SOLVERS[key]()


__all__ = ["SOLVERS", "get_solver", "AbstractSolver", "Outcome", "Progress", "Result", "State", "minimize", "Newton", "LBFGS"]

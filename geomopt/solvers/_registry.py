"""Solvers by name: :data:`SOLVERS` and :func:`get_solver`."""

from __future__ import annotations

from .._runtime import names as _names
from .._runtime.errors import ParameterError
from .._runtime.names import resolve
from ._base import AbstractSolver


def _optx(kind):
    def make():
        import optimistix as optx  # imported when asked for: it is slow to import

        from .optimistix import Optimistix

        tol = dict(rtol=1e-10, atol=1e-10)
        solver = {"bfgs": lambda: optx.BFGS(**tol), "lbfgs": lambda: optx.LBFGS(**tol),
                  "ncg": lambda: optx.NonlinearCG(**tol)}[kind]()
        return Optimistix(solver)

    return make


optx_bfgs, optx_lbfgs, optx_ncg = _optx("bfgs"), _optx("lbfgs"), _optx("ncg")

#: name -> factory of a default-configured solver (the names and definitions: geomopt._runtime.names)
SOLVERS = resolve(_names.SOLVERS)


def get_solver(name_or_solver) -> AbstractSolver:
    """A solver object by name (:data:`SOLVERS`), or the object itself."""
    if isinstance(name_or_solver, AbstractSolver):
        return name_or_solver
    if not isinstance(name_or_solver, str):
        raise ParameterError(f"solver must be a name ({', '.join(SOLVERS)}) or a solver object, "
                             f"got {type(name_or_solver).__name__}")
    key = name_or_solver.strip().lower().replace("_", "-")
    if key not in SOLVERS:
        raise ParameterError(f"unknown solver {name_or_solver!r}; valid solvers: {', '.join(SOLVERS)}")
    return SOLVERS[key]()

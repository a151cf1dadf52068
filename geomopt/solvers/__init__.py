"""Solvers over one interface: ``init / step / terminate`` driven by :func:`minimize`."""

from ._base import AbstractSolver, Outcome, Progress, Result, State, minimize
from .newton import Newton

__all__ = ["AbstractSolver", "Outcome", "Progress", "Result", "State", "minimize", "Newton"]

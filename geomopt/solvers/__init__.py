"""Solvers over one interface (``init / step / termination / reparam / restart``), each a
descent plus the shared :class:`~geomopt.solvers.linesearch.InjectiveSearch`, driven by the one loop
:func:`iterate` (and :func:`minimize` on top of it).

``SOLVERS`` maps names to factories: ``newton`` (projected Newton), ``lbfgs``, ``slim``
(Rabinovich et al. 2017), ``aqp`` (Kovalsky et al. 2016), ``cm`` (Shtengel et al. 2017, 2D),
and optimistix's ``optx-bfgs``, ``optx-lbfgs``, ``optx-ncg`` (nonlinear CG) through
:class:`~geomopt.solvers.optimistix.Optimistix`.  The element-Hessian projections of the
Newton-type solvers are objects: :class:`Adaptive`, :class:`Clamp`, :class:`Abs`,
:class:`Exact`, :class:`SLIMProxy`, :class:`CMProxy`.
"""

from ..objective.projection import Abs, AbstractProjection, Adaptive, Clamp, CMProxy, Exact, SLIMProxy
from ._base import AbstractSolver, State
from ._iterate import AbstractContinuation, Decision, Final, Progress, iterate, minimize, minimize_map
from ._laplacian import rest_laplacian
from ._registry import SOLVERS, get_solver
from ._result import (Details, ForwardCertificate, LocalCertificate, ParamDetails, Result, ResultCertificate,
                      RunStats, Trace, UntangleDetails, local_certificate, traced_result)
from ._termination import DIVERGENCE_FACTOR, Outcome, Stats, Termination
from .aqp import AQP
from .lbfgs import LBFGS
from .newton import CM, SLIM, AbstractNewton, Newton

__all__ = ["SOLVERS", "get_solver", "AbstractSolver", "AbstractNewton", "State", "Stats", "Termination", "Outcome",
           "DIVERGENCE_FACTOR", "Result", "RunStats", "Trace", "LocalCertificate", "ResultCertificate", "Details",
           "UntangleDetails", "ParamDetails", "local_certificate", "iterate", "minimize", "minimize_map", "Decision", "Final",
           "AbstractContinuation", "Progress", "Newton", "LBFGS", "SLIM", "AQP", "CM", "AbstractProjection",
           "Adaptive", "Clamp", "Abs", "Exact", "SLIMProxy", "CMProxy", "rest_laplacian", "ForwardCertificate",
           "traced_result"]

"""The objective layer: a mesh energy as a pure function of the map with its derivatives
(:mod:`~geomopt.objective.objective`), the element Hessians' PSD projection
(:mod:`~geomopt.objective.projection`), Newton directions by conjugate gradients on the device
(:mod:`~geomopt.objective.cg`), the derivative of a solve (:mod:`~geomopt.objective.adjoint`),
the gauge of free boundaries (:mod:`~geomopt.objective.gauge`) and the distortion of a map onto the
sphere (:mod:`~geomopt.objective.distortion`); the sparse solves they call are
:mod:`geomopt.linalg`, a floor below.  ``geomopt.objective.Objective`` is
:class:`geomopt.objective.objective.Objective` (also ``geomopt.Objective``).  Imports only
the layers below (energies, mesh, linalg, exact, runtime)."""

from .._runtime.lazy import submodules

__all__ = ["cg", "distortion", "gauge", "objective", "projection"]
__getattr__, __dir__ = submodules(__name__, tuple(__all__), {"Objective": "objective"})

"""The objective layer: a mesh energy as a pure function of the map with its derivatives
(:mod:`~geomopt.objective.objective`), the element Hessians' PSD projection
(:mod:`~geomopt.objective.projection`, :mod:`~geomopt.objective.eigh`), sparse linear solves
(:mod:`~geomopt.objective.linsolve`, :mod:`~geomopt.objective.cg`) and the gauge of free
boundaries (:mod:`~geomopt.objective.gauge`).  ``geomopt.objective.Objective`` is
:class:`geomopt.objective.objective.Objective` (also ``geomopt.Objective``).  Imports only
the layers below (energies, mesh, exact, runtime)."""

from .._runtime.lazy import submodules

__all__ = ["cg", "eigh", "gauge", "linsolve", "objective", "projection"]
__getattr__, __dir__ = submodules(__name__, tuple(__all__), {"Objective": "objective"})

"""Mesh problems and element kinds: the rest geometry of a problem (:mod:`~geomopt.mesh.problem`),
element kinds evaluated at their corners (:mod:`~geomopt.mesh.elements`), volume cases from files
(:mod:`~geomopt.mesh.cells`), generated meshes (:mod:`~geomopt.mesh.generators`), Tutte embeddings
(:mod:`~geomopt.mesh.tutte`), the scaffold triangulation of bijective maps
(:mod:`~geomopt.mesh.scaffold`), element frames (:mod:`~geomopt.mesh.geometry`) and quality
(:mod:`~geomopt.mesh.quality`).  Imports only the layers below (exact, io, runtime)."""

from .._runtime.lazy import submodules

__all__ = ["cells", "elements", "generators", "geometry", "problem", "quality", "scaffold", "tutte"]
__getattr__, __dir__ = submodules(__name__, tuple(__all__))

"""Exact predicates and certificates, the bottom layer of geomopt: orientation tests with an
exact fallback (:mod:`~geomopt.exact.predicates`), mesh topology (:mod:`~geomopt.exact.topology`),
vertex and edge stars (:mod:`~geomopt.exact.stars`), hexahedron validity by Bernstein
coefficients (:mod:`~geomopt.exact.hexvalid`) and the certificates built from them
(:mod:`~geomopt.exact.certify`), the polygon tests they rest on (:mod:`~geomopt.exact.polygons`), and points welded by
equal coordinates (:mod:`~geomopt.exact.weld`).
Imports only :mod:`geomopt._runtime`."""

from .._runtime.lazy import submodules

__all__ = ["certify", "hexvalid", "polygons", "predicates", "stars", "topology", "weld"]
__getattr__, __dir__ = submodules(__name__, tuple(__all__))

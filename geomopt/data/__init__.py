"""Meshes bundled with geomopt, for examples, notebooks and tests.

``camelhead``: the camel head of libigl's parameterization tutorials (11,381 vertices, 22,704
triangles, one boundary loop of 56 edges: a disk), from Sorkine & Cohen-Or 2004,
"Least-squares meshes" (see ``SOURCES.md`` in this folder for its provenance and hash).
``3holes``: a closed surface of genus 3 (3,596 vertices, 7,200 triangles), for atlases.

Examples
--------
>>> import geomopt
>>> V, F = geomopt.data.load("camelhead")          # (11381, 3) float64, (22704, 3) int64
>>> path = geomopt.data.path("camelhead")          # the .off file, for the command line
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["MESHES", "path", "load"]

#: bundled mesh name -> file name in this folder
MESHES = {"camelhead": "camelhead.off", "3holes": "3holes.off"}


def path(name: str = "camelhead") -> Path:
    """The file of the bundled mesh ``name`` (one of :data:`MESHES`)."""
    from .._runtime.errors import ParameterError

    if name not in MESHES:
        raise ParameterError(f"no bundled mesh {name!r}; bundled meshes: {', '.join(MESHES)}")
    return Path(__file__).with_name(MESHES[name])


def load(name: str = "camelhead"):
    """The bundled mesh ``name`` as ``(V, F)``: (n, 3) float64 vertices, (m, 3) int64 faces,
    read by :func:`geomopt.io.read_mesh`."""
    from .. import io

    return io.read_mesh(path(name))

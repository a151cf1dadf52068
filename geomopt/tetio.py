"""Tetrahedral meshes in four formats (``.vtk``, ``.vtu``, ``.msh``, ``.mesh``): kept for
existing code; the readers and writers live in :mod:`geomopt.io` (:func:`geomopt.io.read_tets`,
:func:`geomopt.io.write_tets`, :data:`geomopt.io.TET_FORMATS`)."""

from __future__ import annotations

from .io import TET_FORMATS as FORMATS
from .io import read_tets, write_tets

__all__ = ["FORMATS", "read_tets", "write_tets"]

"""Conversions at the library's edges, in plain NumPy: a mesh given as one object into its
arrays (:func:`mesh_arrays`), and a UV map into the unit square texture tools expect
(:func:`unit_square`)."""

from __future__ import annotations

import numpy as np

from .._runtime.errors import ParameterError

__all__ = ["mesh_arrays", "unit_square"]


def unit_square(uv) -> np.ndarray:
    """``uv`` (n, 2) moved and scaled uniformly (aspect kept) so that its bounding box spans
    [0, 1] along its longer side and starts at 0 along both: the range texture tools expect
    (``geomopt param --uv-range unit``, the viewers' checkerboard)."""
    uv = np.asarray(uv, np.float64)
    lo = uv.min(axis=0)
    return (uv - lo) / max(float(np.ptp(uv, axis=0).max()), 1e-300)


def mesh_arrays(V, F=None):
    """``(V, F)`` from a vertex array and a face array, or from one mesh object with
    ``.vertices`` and ``.faces`` (a ``trimesh.Trimesh``, ...) given as ``V`` with ``F=None``."""
    if F is None:
        if hasattr(V, "vertices") and hasattr(V, "faces"):
            return np.asarray(V.vertices), np.asarray(V.faces)
        raise ParameterError(f"give the faces F with the vertices, or one mesh object with .vertices and "
                             f".faces (e.g. a trimesh.Trimesh); got {type(V).__name__} and no faces")
    return V, F

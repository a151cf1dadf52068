"""Tetrahedral meshes in every volume format meshio knows (``.msh``, ``.mesh``, ``.vtu``,
``.vtk``, ...), with the validation of :mod:`geomopt.io`.

:func:`read_tets` returns ``(P (n, 3) float64, T (m, 4) int64)`` checked like
:func:`geomopt.io.read_vtk_tets`; :func:`write_tets` writes atomically (a temporary file
beside the target, renamed on success).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path

import numpy as np

from ._errors import GeomoptError, MeshFormatError
from .io import check_output_path, validate_simplices, validate_vertices

#: the usual tet formats and meshio's name for each (other extensions: meshio's own table)
FORMATS = {".msh": "gmsh", ".mesh": "medit", ".vtu": "vtu", ".vtk": "vtk"}


def _format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in FORMATS:
        return FORMATS[suffix]
    import meshio

    known = meshio.extension_to_filetypes.get(suffix)
    if not known:
        raise MeshFormatError(
            f"{path}: unknown mesh format {suffix or '(no extension)'!r}; use one of "
            f"{', '.join(FORMATS)} or another extension meshio knows")
    return known[0]


def read_tets(path):
    """Read a tetrahedral mesh with meshio.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.msh`` (Gmsh), ``.mesh`` (Medit), ``.vtu``, ``.vtk`` or other meshio file.

    Returns
    -------
    P : (n, 3) float64 point positions.
    T : (m, 4) int64 tetrahedra (0-based), in file order.

    Raises
    ------
    MeshFormatError
        Missing, empty or unreadable file, no points, or no tetrahedra.  Boundary faces,
        edges and points that volume formats carry beside the tets (Gmsh, Medit) are
        ignored; other volume cells (hexahedra, prisms...) are refused.
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a tet.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshFormatError(f"tet mesh {path} does not exist or is not a file")
    if path.stat().st_size == 0:
        raise MeshFormatError(f"tet mesh {path} is empty")
    fmt = _format(path)
    import meshio

    try:
        mesh = meshio.read(str(path), file_format=fmt)
    except (Exception, SystemExit) as exc:  # meshio may sys.exit() on malformed input
        detail = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise MeshFormatError(f"could not read {path} as {fmt} ({detail}); check that the file is "
                              f"complete and of the format its extension says") from exc
    if len(mesh.points) == 0:
        raise MeshFormatError(f"{path} has no points")
    volume = {"tetra10", "hexahedron", "hexahedron20", "wedge", "pyramid", "hexahedron27", "wedge15"}
    others = sorted({c.type for c in mesh.cells if c.type in volume})
    if others:
        raise MeshFormatError(f"{path} contains non-tetrahedral volume cells ({', '.join(others)}); "
                              f"only linear tetrahedral meshes are supported")
    tets = [c.data for c in mesh.cells if c.type == "tetra"]
    if not tets:
        found = sorted({c.type for c in mesh.cells}) or ["none"]
        raise MeshFormatError(f"{path} has no tetrahedra (cells found: {', '.join(found)})")
    P = validate_vertices(mesh.points, f"{path.name}: points", dim=3)
    return P, validate_simplices(np.concatenate(tets), P.shape[0], 4, f"{path.name}: tetrahedra")


def write_tets(path, P, T):
    """Write a tetrahedral mesh with meshio, in the format its extension names, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (``.msh``, ``.mesh``, ``.vtu``, ``.vtk``, ...); its folder must exist.
    P : (n, 3) array_like point positions;  T : (m, 4) integer array_like tetrahedra.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError : invalid ``P`` or ``T``.
    MeshFormatError : unknown extension.
    GeomoptError : ``path`` cannot be written; nothing is left there then.
    """
    path = Path(path)
    P = validate_vertices(P, "P", dim=3)
    T = validate_simplices(T, P.shape[0], 4, "T")
    fmt = _format(path)
    check_output_path(path)
    import meshio

    mesh = meshio.Mesh(P, [("tetra", T)])
    tmp = path.with_name(f".{path.name[:200]}.{secrets.token_hex(6)}.tmp{path.suffix}")
    try:
        meshio.write(str(tmp), mesh, file_format=fmt)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, (OSError, ValueError, TypeError)):
            raise GeomoptError(f"could not write {path} as {fmt} ({exc}); nothing was written") from exc
        raise
    return path

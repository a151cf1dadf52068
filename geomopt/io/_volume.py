"""Volume meshes: tetrahedral meshes in four formats, each read exactly as the file says or refused.

=========  ==========================================  ===========================================
extension  read (:mod:`geomopt.io`)                    written
=========  ==========================================  ===========================================
``.vtk``   legacy VTK, ASCII or binary, up to 5.1      ASCII, ``double`` points
           (:func:`~geomopt.io.read_vtk_tets`)         (:func:`~geomopt.io.write_vtk_tets`)
``.vtu``   VTK XML unstructured grid: ascii, binary,   binary base64, zlib, ``Float64`` (meshio)
           appended (raw/base64), zlib/lzma/lz4
``.msh``   Gmsh ASCII, versions 2.2 and 4.1            Gmsh 4.1 ASCII (meshio)
``.mesh``  Medit ASCII (``MeshVersionFormatted`` 1/2)  Medit ASCII, version 2 (meshio)
=========  ==========================================  ===========================================

Each format has its own parser (``_vtk``, ``_vtu``, ``_gmsh``, ``_medit``; NumPy tokenizes, see
:mod:`geomopt.io._text`), so that a file is read exactly as it declares itself or refused with one
line saying why: every count checked against its data, every cell type known
(:mod:`~geomopt.io._cells`; lower-dimensional cells beside the tets are skipped, other
volume cells refused), every index defined.  meshio's readers are not used: they drop unknown
VTU cell types, keep only the last VTU piece's cells, map a Gmsh node tag 0 to another node and
refuse valid files (MSH 2.2 with mixed tag counts, an empty MSH 4.1 block, a byte-order mark).
Coordinates are read as the file writes them
(decimal text as float64, binary as its declared type); a Medit ``MeshVersionFormatted 1``
ASCII file's coordinates are not rounded to float32.  Binary Gmsh/Medit files are refused.
meshio writes ``.vtu``, ``.msh`` and ``.mesh``; its own messages are never printed.  Any
other extension is refused on reading and writing.

:func:`read_tets` returns ``(P (n, 3) float64, T (m, 4) int64)`` validated like every
geomopt reader; :func:`write_tets` writes atomically (:func:`~geomopt.io.atomic_path`)
with full precision, so ``read_tets`` gives back exactly what was written.
"""

from __future__ import annotations

import contextlib
import warnings
from io import StringIO
from pathlib import Path

import numpy as np

from .._runtime.errors import GeomoptError, MeshFormatError
from .._runtime.validate import validate_simplices, validate_vertices
from ._atomic import atomic_path, check_output_path
from ._cells import KINDS, WORDS, check_kinds, checked_cells, first_kind, select_kind
from ._files import read_input
from ._gmsh import parse_gmsh
from ._medit import parse_medit
from ._obj import read_obj_quads, write_obj_quads
from ._vtk import parse_vtk, write_vtk_cells
from ._vtu import parse_vtu

__all__ = ["TET_FORMATS", "CELL_KINDS", "read_tets", "read_vtk_tets", "write_tets", "read_cells", "write_cells"]

#: The tet-mesh formats geomopt reads and writes: extension -> description.
TET_FORMATS = {
    ".vtk": "legacy VTK",
    ".vtu": "VTK XML unstructured grid",
    ".msh": "Gmsh ASCII 2.2/4.1",
    ".mesh": "Medit ASCII",
}

#: The kinds of cell :func:`read_cells` and :func:`write_cells` handle: name -> (nodes per cell,
#: dimension).  Vertex orders are VTK's (Gmsh and Medit use the same for these).
CELL_KINDS = dict(KINDS)

_PARSERS = {".vtk": parse_vtk, ".vtu": parse_vtu, ".msh": parse_gmsh, ".mesh": parse_medit}


def _supported():
    return ", ".join(f"{ext} ({what})" for ext, what in TET_FORMATS.items())


def _extension(path: Path, doing: str) -> str:
    """``path``'s extension (lower case) if geomopt reads and writes it, else a MeshFormatError."""
    suffix = path.suffix.lower()
    if suffix not in TET_FORMATS:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise MeshFormatError(f"cannot {doing} tet mesh {path}: it has {got}; supported tet-mesh formats: "
                              f"{_supported()}")
    return suffix


@contextlib.contextmanager
def _quiet():
    """Silence what meshio prints (rich console on stderr, ``print``) and warns; yields the text."""
    text = StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        warnings.simplefilter("ignore")
        yield text


def _detail(exc, printed):
    """One line saying what meshio found wrong."""
    causes = [exc, exc.__cause__ or exc.__context__]  # meshio often re-raises a bare ReadError
    words = next((" ".join(str(e).split()) for e in causes if e is not None and not isinstance(e, SystemExit)
                  and str(e).strip()), "")
    words = words or " ".join(printed.getvalue().split())
    return words[:200] or (f"meshio's reader stopped ({type(exc).__name__}, no detail): malformed, "
                           f"truncated or unsupported content")


def read_tets(path):
    """Read a tetrahedral mesh exactly as the file declares it, or refuse it.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.vtk`` (legacy VTK), ``.vtu`` (VTK XML), ``.msh`` (Gmsh ASCII 2.2/4.1) or
        ``.mesh`` (Medit ASCII) file; see the module notes.

    Returns
    -------
    P : numpy.ndarray, shape (n, 3), float64
        Point positions, in file order.
    T : numpy.ndarray, shape (m, 4), int64
        Tetrahedra as 0-based indices into ``P``, in file order.

    Raises
    ------
    MeshFormatError
        Unsupported extension; missing, empty, binary (Gmsh/Medit) or malformed file; a
        count that differs from its data; a section not closed; an unknown cell type; an
        element naming an undefined node; no points or no tetrahedra; other volume cells
        (hexahedra, prisms, quadratic or Lagrange tets...).  Boundary faces, edges and
        points beside the tets are skipped (``.vtk``: refused, as in LIM cases).
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a tet.
    """
    return _read(Path(path), ("tetra",))[:2]


def read_vtk_tets(path):
    """Read a tetrahedral mesh from a legacy VTK unstructured-grid file (any extension), exactly as
    declared: :func:`read_tets` of a ``.vtk`` file (tetrahedra only, as in LIM cases).

    Returns
    -------
    P : numpy.ndarray, shape (n, 3), float64
    T : numpy.ndarray, shape (m, 4), int64
        Tetrahedra, 0-based point indices (VTK cell type 10), in file order.

    Raises
    ------
    As :func:`read_tets`.
    """
    return _read(Path(path), ("tetra",), ".vtk")[:2]


def read_cells(path, kinds=("hexahedron", "quad"), format=None):
    """Read a mesh of one kind of cell -- hexahedra or quads by default -- exactly, or refuse it.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.vtk``, ``.vtu``, ``.msh`` (ASCII 2.2/4.1) or ``.mesh`` (ASCII; ``Dimension 2``
        allowed for quads) file, parsed and checked as :func:`read_tets` does, or an ``.obj``
        file of quads (:func:`~geomopt.io.read_obj_quads`).
    kinds : tuple of str
        :data:`CELL_KINDS` names, by priority.  The first kind the file holds is read; in
        Gmsh, Medit and VTU files cells of lower dimension beside it (boundary quads, lines,
        points) are skipped, any other cell of its dimension or higher refused (mixed
        meshes are not supported).  Legacy VTK files must hold that kind only.
    format : str, optional
        An extension (``".vtk"``...) to read the file as, instead of its own.

    Returns
    -------
    P : numpy.ndarray, shape (n, 3) float64
        Points (quads in the plane: ``z == 0`` as stored; a Medit ``Dimension 2`` file
        gives shape (n, 2)).
    C : numpy.ndarray, shape (m, k) int64
        Cells, 0-based, in file order, vertex order as in VTK.
    kind : str
        The kind read.

    Raises
    ------
    MeshFormatError
        As :func:`read_tets`; also a file with none of ``kinds`` or with mixed cells.
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a cell.
    """
    return _read(Path(path), check_kinds(kinds, "kinds"), format)


def _read(path, kinds, format=None):
    """``(P, C, kind)``: see :func:`read_cells`."""
    ext = (format or path.suffix).lower()
    if ext == ".obj" and "quad" in kinds:
        return read_obj_quads(path) + ("quad",)
    ext = _extension(path.with_suffix(ext), "read")
    path, data = read_input(path, "tet mesh" if kinds == ("tetra",) else "mesh", mapped=ext == ".vtk")
    dims = (2, 3) if "quad" in kinds else (3,)
    found = parse_medit(data, path, dims) if ext == ".mesh" else _PARSERS[ext](data, path)
    kind = first_kind(found, kinds, path) if len(kinds) > 1 else kinds[0]
    C = select_kind(found, kind, path, alone=ext == ".vtk")
    size, dim = KINDS[kind]
    P = validate_vertices(found.points, f"{path.name}: points", dim=3 if dim == 3 else None)
    return P, validate_simplices(C, P.shape[0], size, f"{path.name}: {WORDS[kind][1]}", words=WORDS[kind]), kind


def write_tets(path, P, T):
    """Write a tetrahedral mesh in the format its extension names, atomically, full precision.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.vtk``, ``.vtu``, ``.msh`` (written as Gmsh 4.1 ASCII) or ``.mesh``
        (Medit ASCII) file; its folder must exist.
    P : array_like, shape (n, 3)
        Point positions.
    T : array_like, shape (m, 4), integer
        Tetrahedra, 0-based.

    Returns
    -------
    pathlib.Path
        ``path``.  :func:`read_tets` reads back ``P`` and ``T`` bit for bit.

    Raises
    ------
    MeshFormatError
        Unsupported extension (nothing is created).
    MeshError
        Invalid ``P`` or ``T``.
    GeomoptError
        ``path`` cannot be written; nothing is left there then (an existing file keeps
        its contents).
    """
    return write_cells(path, P, T, "tetra")


def write_cells(path, P, C, kind, format=None):
    """Write a mesh of one :data:`CELL_KINDS` kind in the format its extension names (also
    ``.obj`` for quads), atomically, full precision.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.vtk``, ``.vtu``, ``.msh`` (Gmsh 4.1 ASCII), ``.mesh`` (Medit ASCII), or
        ``.obj`` for quads; its folder must exist.
    P : array_like, shape (n, 3), or (n, 2) for quads (written with ``z = 0``)
    C : array_like, shape (m, k), integer
        Cells, 0-based, VTK's vertex order.
    kind : str
        ``"tetra"``, ``"hexahedron"`` or ``"quad"``.
    format : str, optional
        An extension to write instead of the path's own (e.g. for a temporary file).

    Returns
    -------
    pathlib.Path
        ``path``; :func:`read_cells` (or :func:`read_tets`) reads back ``P`` and ``C`` bit for bit.

    Raises
    ------
    As :func:`write_tets`.
    """
    path = Path(path)
    (kind,) = check_kinds([kind])
    ext = (format or path.suffix).lower()
    if ext == ".obj" and kind == "quad":
        return write_obj_quads(path, P, C)
    ext = _extension(path.with_suffix(ext), "write")
    if ext == ".vtk":
        return write_vtk_cells(path, P, C, kind)
    P, C = checked_cells(P, C, kind)
    what = "tet mesh" if kind == "tetra" else f"{WORDS[kind][0]} mesh"
    check_output_path(path, what=what)
    import meshio

    if ext == ".msh":
        ones = np.ones(len(C), dtype=np.int64)
        mesh = meshio.Mesh(P, [(kind, C)], cell_data={"gmsh:physical": [ones], "gmsh:geometrical": [ones]})
        write = lambda tmp: meshio.gmsh.write(tmp, mesh, fmt_version="4.1", binary=False)  # noqa: E731
    elif ext == ".mesh":
        write = lambda tmp: meshio.medit.write(tmp, meshio.Mesh(P, [(kind, C)]))  # noqa: E731
    else:
        write = lambda tmp: meshio.vtu.write(tmp, meshio.Mesh(P, [(kind, C)]), binary=True)  # noqa: E731
    with atomic_path(path, what) as tmp, _quiet() as printed:
        try:
            write(str(tmp))
        except Exception as exc:  # meshio's WriteError, OSError (disk full), ...
            raise GeomoptError(f"could not write {path} as {TET_FORMATS[ext]} ({_detail(exc, printed)}); "
                               f"nothing was written") from exc
    return path

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

from pathlib import Path

from .._runtime.errors import MeshFormatError
from .._runtime.formats import CELL_FORMATS, extensions, resolve
from .._runtime.validate import validate_simplices, validate_vertices
from ._cells import KINDS, WORDS, check_kinds, first_kind, select_kind
from ._files import read_input

__all__ = ["TET_FORMATS", "CELL_KINDS", "CELL_WORDS", "read_tets", "read_vtk_tets", "write_tets", "read_cells", "write_cells"]

#: The tet-mesh formats geomopt reads and writes: extension -> description (from
#: :data:`geomopt._runtime.formats.CELL_FORMATS`, the one table of cell-mesh formats).
TET_FORMATS = {ext: CELL_FORMATS[ext].description for ext in extensions("tetra")}

#: The kinds of cell :func:`read_cells` and :func:`write_cells` handle: name -> (nodes per cell,
#: dimension).  Vertex orders are VTK's (Gmsh and Medit use the same for these).
CELL_KINDS = dict(KINDS)
#: How messages name each of the :data:`CELL_KINDS`: name -> (singular, plural).
CELL_WORDS = dict(WORDS)


def _format(path: Path, ext: str, kinds: tuple, doing: str):
    """The :class:`~geomopt._runtime.formats.CellFormat` of ``ext`` for a mesh of one of
    ``kinds``, else a MeshFormatError naming the formats that can (read-only ones are refused
    for writing)."""
    fmt = CELL_FORMATS.get(ext)
    if fmt is not None and any(fmt.holds(k) for k in kinds) and (doing == "read" or fmt.write is not None):
        return fmt
    what = "tet mesh" if kinds == ("tetra",) else f"{WORDS[kinds[0]][0]} mesh" if len(kinds) == 1 else "mesh"
    usable = [e for k in kinds for e in extensions(k, writable=doing == "write")]
    supported = ", ".join(f"{e} ({CELL_FORMATS[e].description})" for e in dict.fromkeys(usable))
    if fmt is not None and fmt.write is None and doing == "write":
        got = f"{ext} ({fmt.description}), which geomopt reads but does not write"
    else:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
    raise MeshFormatError(f"cannot {doing} {what} {path}: it has {got}; supported {what.replace(' mesh', '-mesh')} formats: "
                          f"{supported}")


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
    fmt = _format(path, ext, kinds, "read")
    if fmt.whole_file:
        return resolve(fmt.parse)(path) + (next(k for k in kinds if fmt.holds(k)),)
    path, data = read_input(path, "tet mesh" if kinds == ("tetra",) else "mesh", mapped=fmt.mapped)
    parse = resolve(fmt.parse)
    found = parse(data, path, (2, 3) if "quad" in kinds else (3,)) if fmt.planar else parse(data, path)
    kind = first_kind(found, kinds, path) if len(kinds) > 1 else kinds[0]
    C = select_kind(found, kind, path, alone=fmt.one_kind)
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
    return resolve(_format(path, ext, (kind,), "write").write)(path, P, C, kind)

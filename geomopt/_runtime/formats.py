"""The file formats of cell meshes (tetrahedra, hexahedra, quads): one table from which the
readers and writers (:func:`geomopt.io.read_cells`, :func:`geomopt.io.write_cells`), the
extensions every command checks its inputs and outputs against, and the command line's help
are derived.  The table names its functions as ``module:attribute`` and imports nothing, so
that ``geomopt --help`` reads it without importing NumPy.

A new format is its parser (and writer) module plus one row here.  A format without a writer
is read-only: a write to it is refused, never written as another format.
"""

from __future__ import annotations

import dataclasses
import importlib

__all__ = ["CellFormat", "CELL_FORMATS", "PICTURE_EXTENSIONS", "extensions", "listing", "resolve"]

#: Picture formats geomopt writes (matplotlib's own backends, no extra dependency).
PICTURE_EXTENSIONS = (".png", ".pdf", ".svg")


@dataclasses.dataclass(frozen=True)
class CellFormat:
    """One cell-mesh file format.

    Attributes
    ----------
    description : how messages name it (``"legacy VTK"``).
    parse : ``module:attribute`` of ``parse(data, path) -> VolumeCells`` (``parse(data, path,
        dims)`` when ``planar``), the file's bytes parsed exactly or refused; or, with
        ``whole_file``, of ``read(path) -> (P, C)``.
    write : ``module:attribute`` of ``write(path, P, C, kind) -> Path`` (atomic, full
        precision, read back bit for bit), or None: read-only.
    kinds : the cell kinds (:data:`geomopt.io.CELL_KINDS` names) a file holds; None: every kind.
    planar : the file may hold 2D points (``parse`` takes the allowed ``dims``).
    mapped : the parser reads a memory-mapped file (binary arrays straight from the page cache).
    whole_file : ``parse`` reads the path itself, not its bytes.
    one_kind : a file holds cells of one kind only (no boundary cells beside them).
    """

    description: str
    parse: str
    write: str | None
    kinds: tuple | None = None
    planar: bool = False
    mapped: bool = False
    whole_file: bool = False
    one_kind: bool = False

    def holds(self, kind: str) -> bool:
        return self.kinds is None or kind in self.kinds


#: extension -> :class:`CellFormat`, in the order messages and help list them
CELL_FORMATS = {
    ".vtk": CellFormat("legacy VTK", "geomopt.io._vtk:parse_vtk", "geomopt.io._vtk:write_vtk_cells", mapped=True,
                       one_kind=True),
    ".vtu": CellFormat("VTK XML unstructured grid", "geomopt.io._vtu:parse_vtu", "geomopt.io._meshio:write_vtu"),
    ".msh": CellFormat("Gmsh ASCII 2.2/4.1", "geomopt.io._gmsh:parse_gmsh", "geomopt.io._meshio:write_gmsh"),
    ".mesh": CellFormat("Medit ASCII", "geomopt.io._medit:parse_medit", "geomopt.io._meshio:write_medit",
                        planar=True),
    ".obj": CellFormat("Wavefront OBJ of quads", "geomopt.io._obj:read_obj_quads", "geomopt.io._obj:write_obj_cells",
                       kinds=("quad",), whole_file=True),
}


_PLURAL = {"tetra": "tets", "hexahedron": "hexahedra", "quad": "quads"}


def extensions(kind: str | None = None, writable: bool = False, table=None) -> tuple:
    """The extensions of the formats that hold ``kind`` (any kind: None), only those with a
    writer when ``writable``."""
    table = CELL_FORMATS if table is None else table
    return tuple(ext for ext, f in table.items()
                 if (kind is None or f.holds(kind)) and (f.write is not None or not writable))


def listing(table=None) -> str:
    """The extensions for a help text: ``".vtk .vtu .msh .mesh, .obj for quads"``."""
    table = CELL_FORMATS if table is None else table
    every = " ".join(ext for ext, f in table.items() if f.kinds is None)
    some = [f"{ext} for {' and '.join(_PLURAL.get(k, k) for k in f.kinds)}"
            for ext, f in table.items() if f.kinds is not None]
    return ", ".join([every] + some)


def resolve(reference: str):
    """The function a table entry names (``module:attribute``)."""
    module, attribute = reference.split(":")
    return getattr(importlib.import_module(module), attribute)

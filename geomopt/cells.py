"""Quad and hex mesh cases from files: read, untangle or smooth, write a certified file.

A *cell case* is what ``geomopt untangle`` and ``geomopt smooth`` work on when the mesh is made
of quads or hexahedra:

* a mesh file (``.vtk``, ``.vtu``, ``.msh``, ``.mesh``, or ``.obj`` for quads;
  :func:`geomopt.io.read_cells`): the start is the file's points, the rest shapes are
  reference squares / cubes (:meth:`Problem.quads` ``rest="reference"``), the boundary
  vertices are fixed where the file has them;
* a LIM-style case folder: ``rest.vtk`` and ``init.vtk`` holding the same hexahedra (VTK cell
  type 12) or quads (type 9, ``z = 0``), and ``handles.txt`` (0-based vertex ids, one per line;
  absent: the boundary vertices), as the LIM benchmark's 3D cases hold tetrahedra.

:func:`write_certified` writes the result beside the output, reads it back and certifies the
file exactly (locally injective: every element valid everywhere and no vertex or edge wound
twice, :func:`geomopt.elements.element_local_certificate`; handles equal as numbers), and only
then moves it onto the output (:func:`geomopt.io.atomic_path`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._errors import GeomoptError, MeshError, MeshFormatError, SolveError

__all__ = ["CellCase", "CELL_EXTENSIONS", "is_cell_case", "read_cell_case", "cell_problem", "write_certified"]

#: Files a quad / hex mesh is read from and written to (``.obj``: quads only).
CELL_EXTENSIONS = (".vtk", ".vtu", ".msh", ".mesh", ".obj")
_KINDS = ("hexahedron", "quad")


@dataclasses.dataclass(frozen=True, eq=False)
class CellCase:
    """A quad or hex mesh to untangle or smooth.

    Attributes
    ----------
    start : (n, d) start positions (d = 2 for quads in the plane, 3 for hexahedra).
    elements : (m, 4) quads or (m, 8) hexahedra, as the file lists them.
    rest : (n, d) rest positions, or None for reference squares / cubes.
    handles : (k,) fixed vertex ids (default: the boundary).
    path : the file or folder read.
    """

    start: np.ndarray
    elements: np.ndarray
    rest: np.ndarray | None
    handles: np.ndarray
    path: Path

    @property
    def kind(self) -> str:
        return "quad" if self.elements.shape[1] == 4 else "hexahedron"


def _vtk_cell_type(path) -> int | None:
    """The first cell type of a legacy VTK file (a cheap look, no full parse), or None."""
    data = Path(path).read_bytes()
    at = data.rfind(b"CELL_TYPES")
    if at < 0:
        return None
    rest = data[at:].split(b"\n", 1)
    if len(rest) < 2:
        return None
    if b"BINARY" in data[:300].upper():
        return int.from_bytes(rest[1][:4], "big", signed=True) if len(rest[1]) >= 4 else None
    token = rest[1].split(None, 1)
    return int(token[0]) if token and token[0].isdigit() else None


def is_cell_case(path) -> bool:
    """Whether ``path`` is a quad / hex case: a mesh file with a cell extension other than
    ``.obj`` of a LIM 2D case, or a folder whose ``rest.vtk`` holds quads or hexahedra."""
    path = Path(path)
    if path.is_dir():
        rest = path / "rest.vtk"
        return rest.is_file() and _vtk_cell_type(rest) in (9, 12)
    return path.suffix.lower() in CELL_EXTENSIONS


def read_cell_case(path) -> CellCase:
    """Read a quad / hex mesh file or LIM-style case folder (module notes), exactly or refuse it.

    Raises
    ------
    MeshFormatError, MeshError
        As :func:`geomopt.io.read_cells`; a folder whose two meshes differ in points or cells.
    """
    from . import io

    path = Path(path)
    if not path.is_dir():
        try:
            P, E, _ = io.read_cells(path, _KINDS)
        except MeshFormatError as exc:
            _refuse_tets(path, exc)
            raise
        return CellCase(_planar(P, E, path), E, None, _boundary(E, len(P)), path)
    for name in ("rest.vtk", "init.vtk"):
        if not (path / name).is_file():
            raise MeshFormatError(f"quad/hex case {path} has no {name}; a case folder holds rest.vtk and init.vtk "
                                  f"(the same quads or hexahedra) and handles.txt")
    rest, E, _ = io.read_cells(path / "rest.vtk", _KINDS)
    init, E2, _ = io.read_cells(path / "init.vtk", _KINDS)
    if init.shape != rest.shape or not np.array_equal(E, E2):
        raise MeshError(f"{path}: rest.vtk and init.vtk must hold the same points and cells (found {len(rest)} / "
                        f"{len(init)} points, {len(E)} / {len(E2)} cells)")
    handles_file = path / "handles.txt"
    handles = (io.read_vertex_ids(handles_file, len(rest)) if handles_file.exists()
               else _boundary(E, len(rest)))
    return CellCase(_planar(init, E, path / "init.vtk"), E, _planar(rest, E, path / "rest.vtk"), handles, path)


def _refuse_tets(path, exc):
    """Raise a MeshFormatError pointing to the LIM folder layout when ``path``, refused as a
    quad / hex mesh (``exc``), is a tetrahedral mesh."""
    from . import io

    try:
        io.read_cells(path, ("tetra",))
    except GeomoptError:
        return
    raise MeshFormatError(f"{path} is a tetrahedral mesh; untangling tetrahedra needs a LIM case folder "
                          f"(rest.vtk, init.vtk, handles.txt: see README) to give the rest shape beside the "
                          f"tangled map") from exc


def _planar(P, E, path):
    """Quads: (n, 2) when every ``z`` is 0 (a quad surface in 3D is refused); hexahedra: as read."""
    if E.shape[1] == 8:
        return P
    if P.shape[1] == 3 and np.any(P[:, 2] != 0):
        raise MeshError(f"{path}: the quads are not in the plane z = 0; untangling and smoothing take planar "
                        f"quad meshes (a quad surface is flattened with geomopt.Problem.quad_surface)")
    return P[:, :2]


def _boundary(E, n):
    from .elements import boundary_vertices

    return boundary_vertices(E, n)


def cell_problem(case: CellCase, fixed=None):
    """The :class:`~geomopt.Problem` of a case: rest from ``case.rest`` (or reference
    elements), handles ``fixed`` (default ``case.handles``) at their start positions."""
    from .problem import Problem

    make = Problem.quads if case.kind == "quad" else Problem.hexes
    V, rest = (case.start, "reference") if case.rest is None else (case.rest, "mesh")
    fixed = case.handles if fixed is None else np.asarray(fixed, dtype=np.int64)
    return make(V, case.elements, fixed, case.start[fixed], rest=rest)


def write_certified(path, x, case: CellCase, problem, format=None) -> dict:
    """Write map ``x`` (n, d) with the case's cells to ``path`` atomically, certified.

    The file is written beside ``path`` (:func:`geomopt.io.write_cells`), read back, and
    certified exactly: the cells read back are the case's, the map is locally injective
    (:meth:`~geomopt.problem.Problem.certify`: every element valid everywhere,
    oriented as ``problem.elements``, and no vertex or edge wound twice or overlapping) and the
    handles equal ``problem.fixed_positions`` as numbers (:func:`geomopt.predicates.differing_rows`:
    ``-0.0`` is ``0.0``).  Only then is it moved onto ``path``.

    Returns
    -------
    dict with ``certificate`` (:class:`~geomopt.elements.ElementCertificate` of the file),
    ``local_certificate`` (:class:`~geomopt.elements.ElementLocalCertificate`) and ``path``.

    Raises
    ------
    SolveError
        The written file does not certify; nothing is left at ``path`` (the message does not say so:
        the command line adds it).
    """
    from . import io
    from .predicates import differing_rows

    ext = (format or Path(path).suffix).lower()
    with io.atomic_path(path, f"{case.kind} mesh") as tmp:
        io.write_cells(tmp, x, case.elements, case.kind, format=ext)
        back, E, _ = io.read_cells(tmp, (case.kind,), format=ext)
        back = back[:, : x.shape[1]]
        if not np.array_equal(E, case.elements):
            raise SolveError(f"{path}: the cells read back differ from the input's")
        cert = problem.certify(back)  # elements valid everywhere, no branch point, no boundary overlap
        moved = int(np.count_nonzero(differing_rows(back[problem.fixed], problem.fixed_positions)))
        if not cert.ok or moved:
            why = cert.message if not cert.ok else f"{moved} handle(s) moved"
            raise SolveError(f"the written file did not certify ({why})", certificate=cert)
    return {"path": Path(path), "certificate": cert.elements, "local_certificate": cert}

"""Tet, quad and hex mesh cases from files: read, untangle or smooth, write a certified file.

A *cell case* is what ``geomopt untangle`` (one mesh file or a quad / hex case folder) and
``geomopt smooth`` work on; one code path serves every kind of element:

* a mesh file (``.vtk``, ``.vtu``, ``.msh``, ``.mesh``, or ``.obj`` for quads;
  :func:`geomopt.io.read_cells`) of tetrahedra, quads or hexahedra: the start is the file's
  points; the rest shapes are another file's (``rest=``: the same vertex count and the same
  cells) or, for quads and hexahedra without one, reference squares / cubes
  (:meth:`Problem.quads` ``rest="reference"``; tetrahedra need a rest file); the fixed vertices
  are a handles file's (``handles=``, 0-based ids as in a LIM case's ``handles.txt``) or the
  boundary vertices;
* a LIM-style case folder: ``rest.vtk`` and ``init.vtk`` holding the same hexahedra (VTK cell
  type 12) or quads (type 9, ``z = 0``), and ``handles.txt`` (0-based vertex ids, one per line;
  absent: the boundary vertices), as the LIM benchmark's 3D cases hold tetrahedra (tetrahedral
  case folders are :mod:`geomopt.lim`'s).

:func:`write_certified` writes the result beside the output, reads it back and certifies the
file exactly (locally injective: every element valid everywhere and no vertex or edge wound
twice, :meth:`geomopt.Problem.certify`; handles equal as numbers), and only then moves it onto
the output (:func:`geomopt.io.atomic_path`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .._runtime import formats
from .._runtime.errors import GeomoptError, MeshError, MeshFormatError, ParameterError, SolveError
from .elements import ELEMENT_KINDS

__all__ = ["CellCase", "CELL_EXTENSIONS", "UNTANGLE_KINDS", "SMOOTH_KINDS", "is_cell_case", "read_cell_case", "cell_problem", "write_certified",
           "output_extensions", "case_inputs"]

#: Files a tet / quad / hex mesh is read from (:data:`geomopt._runtime.formats.CELL_FORMATS`).
CELL_EXTENSIONS = formats.extensions()
#: The kinds of mesh smoothed (and held in case folders): the element kinds
#: (:data:`~geomopt.mesh.elements.ELEMENT_KINDS`), volume cells first.
SMOOTH_KINDS = tuple(k.word for k in sorted(ELEMENT_KINDS.values(), key=lambda k: -k.dim))
#: The kinds of mesh untangled from one file, by priority (volume cells, tetrahedra, then quads).
UNTANGLE_KINDS = (tuple(k.word for k in ELEMENT_KINDS.values() if k.dim == 3) + ("tetra",)
                  + tuple(k.word for k in ELEMENT_KINDS.values() if k.dim == 2))


@dataclasses.dataclass(frozen=True, eq=False)
class CellCase:
    """A tet, quad or hex mesh to untangle or smooth.

    Attributes
    ----------
    start : (n, d) start positions (d = 2 for quads in the plane, 3 for tetrahedra and hexahedra).
    elements : (m, 4) tetrahedra or quads, or (m, 8) hexahedra, as the file lists them.
    rest : (n, d) rest positions, or None for reference squares / cubes.
    handles : (k,) fixed vertex ids, or None for the boundary vertices.
    path : the file or folder read.
    kind : ``"tetra"``, ``"quad"`` or ``"hexahedron"`` (:data:`geomopt.io.CELL_KINDS`).
    """

    start: np.ndarray
    elements: np.ndarray
    rest: np.ndarray | None
    handles: np.ndarray | None
    path: Path
    kind: str


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
    """Whether ``path`` is a cell case: a mesh file with a cell extension (an ``.obj`` of a LIM
    2D case is a folder, never a file), or a folder whose ``rest.vtk`` holds quads or hexahedra."""
    path = Path(path)
    if path.is_dir():
        rest = path / "rest.vtk"
        return rest.is_file() and _vtk_cell_type(rest) in {k.vtk for k in ELEMENT_KINDS.values()}
    return path.suffix.lower() in formats.extensions()


def output_extensions(kind) -> tuple:
    """The files a case of ``kind`` is written to: the formats of
    :data:`~geomopt._runtime.formats.CELL_FORMATS` that hold ``kind`` and have a writer."""
    return formats.extensions(kind, writable=True)


def case_inputs(path, rest=None, handles=None) -> list:
    """Every file a case reads (as :func:`read_cell_case` is given it), as strings: the mesh file,
    or each file in the case folder, then ``rest`` and ``handles`` when given; no output may be one."""
    path = Path(path)
    inputs = [str(p) for p in path.iterdir()] if path.is_dir() else [str(path)]
    return inputs + [str(p) for p in (rest, handles) if p is not None]


def read_cell_case(path, rest=None, handles=None, kinds=UNTANGLE_KINDS) -> CellCase:
    """Read a tet / quad / hex mesh file or a quad / hex case folder (module notes), exactly or
    refuse it.

    Parameters
    ----------
    path : str or os.PathLike
        The mesh file (the start map) or the case folder.
    rest : str or os.PathLike, optional
        A mesh file of the rest shapes: the same number of vertices and the same cells as
        ``path`` (any format :func:`geomopt.io.read_cells` reads).  Required for tetrahedra;
        without it quads and hexahedra get reference squares / cubes.  Files only.
    handles : str or os.PathLike, optional
        A text file of fixed vertex ids (0-based, :func:`geomopt.io.read_vertex_ids`; empty: no
        fixed vertex); default the boundary vertices.  Files only.
    kinds : tuple of str
        The kinds of cell accepted, by priority (``smooth``: quads and hexahedra).

    Raises
    ------
    MeshFormatError, MeshError
        As :func:`geomopt.io.read_cells`; a rest mesh or case folder whose vertex count or cells
        differ from the start's; a tetrahedral mesh without a rest mesh.
    ParameterError
        ``rest`` or ``handles`` given with a case folder.
    """
    from .. import io

    path = Path(path)
    if path.is_dir():
        if rest is not None or handles is not None:
            raise ParameterError(f"{path} is a case folder, which holds its own rest.vtk and handles.txt; "
                                 f"--rest and --handles go with a single mesh file")
        return _read_folder(path)
    try:
        P, E, kind = io.read_cells(path, kinds)
    except MeshFormatError as exc:
        _refuse_tets(path, exc, kinds)
        raise
    R = None if rest is None else _same_cells(io.read_cells(rest, kinds), P, E, kind, rest, path)
    if R is None and kind == "tetra":
        raise MeshError(f"{path} is a tetrahedral mesh: tetrahedra have no reference shape, so untangling them "
                        f"needs the rest mesh: give it with --rest REST (the same tetrahedra at rest), or use a "
                        f"LIM case folder (rest.vtk, init.vtk, handles.txt)")
    H = None if handles is None else io.read_vertex_ids(handles, len(P))
    return CellCase(_planar(P, kind, path), E, None if R is None else _planar(R, kind, rest), H, path, kind)


def _same_cells(read, P, E, kind, rest, path):
    """The rest points of ``read`` (:func:`geomopt.io.read_cells` of ``rest``), when its vertex
    count, kind and cells are those of the start ``path`` (``P``, ``E``, ``kind``)."""
    R, E2, kind2 = read
    if kind2 != kind or E2.shape != E.shape:
        raise MeshError(f"the rest mesh {rest} holds {len(E2)} {kind2} cells but {path} holds {len(E)} {kind} "
                        f"cells; give a rest mesh with the same cells")
    if len(R) != len(P):
        raise MeshError(f"the rest mesh {rest} has {len(R)} vertices but {path} has {len(P)}; give a rest mesh "
                        f"with the same vertices (same count and order)")
    if not np.array_equal(E2, E):
        first = int(np.flatnonzero((E2 != E).any(axis=1))[0])
        raise MeshError(f"the rest mesh {rest} and {path} have different cells (first difference at cell "
                        f"{first}); give a rest mesh with the same cells in the same order")
    return R


def _read_folder(path):
    """A quad / hex case folder: ``rest.vtk``, ``init.vtk`` and ``handles.txt`` (or the boundary)."""
    from .. import io

    for name in ("rest.vtk", "init.vtk"):
        if not (path / name).is_file():
            raise MeshFormatError(f"quad/hex case {path} has no {name}; a case folder holds rest.vtk and init.vtk "
                                  f"(the same quads or hexahedra) and handles.txt")
    rest, E, kind = io.read_cells(path / "rest.vtk", SMOOTH_KINDS)
    init, E2, _ = io.read_cells(path / "init.vtk", SMOOTH_KINDS)
    if init.shape != rest.shape or not np.array_equal(E, E2):
        raise MeshError(f"{path}: rest.vtk and init.vtk must hold the same points and cells (found {len(rest)} / "
                        f"{len(init)} points, {len(E)} / {len(E2)} cells)")
    handles_file = path / "handles.txt"
    handles = io.read_vertex_ids(handles_file, len(rest)) if handles_file.exists() else None
    return CellCase(_planar(init, kind, path / "init.vtk"), E, _planar(rest, kind, path / "rest.vtk"), handles, path,
                    kind)


def _refuse_tets(path, exc, kinds):
    """Raise a MeshFormatError saying what to do when ``path``, refused as none of ``kinds``
    (``exc``), is a tetrahedral mesh (``smooth``: quads and hexahedra only)."""
    from .. import io

    if "tetra" in kinds:
        return
    try:
        io.read_cells(path, ("tetra",))
    except GeomoptError:
        return
    raise MeshFormatError(f"{path} is a tetrahedral mesh; smoothing takes quad and hex meshes (untangle a tet "
                          f"mesh with geomopt untangle {path.name} --rest REST)") from exc


def _planar(P, kind, path):
    """Quads: (n, 2) when every ``z`` is 0 (a quad surface in 3D is refused); other cells: as read."""
    if kind != "quad" or P.shape[1] == 2:
        return P
    if np.any(P[:, 2] != 0):
        raise MeshError(f"{path}: the quads are not in the plane z = 0; untangling and smoothing take planar "
                        f"quad meshes (a quad surface is flattened with geomopt.Problem.quad_surface)")
    return P[:, :2]


def cell_problem(case: CellCase, fixed=None):
    """The :class:`~geomopt.Problem` of a case: rest from ``case.rest`` (or reference
    squares / cubes), handles ``fixed`` (default ``case.handles``, or the boundary vertices when
    that is None) at their start positions."""
    from .problem import Problem

    if case.kind == "tetra":
        problem = Problem.tets(case.rest, case.elements)
    else:
        V, rest = (case.start, "reference") if case.rest is None else (case.rest, "mesh")
        problem = Problem.cells(V, case.elements, rest=rest)
    fixed = case.handles if fixed is None else np.asarray(fixed, dtype=np.int64)
    fixed = problem.boundary_vertices() if fixed is None else fixed
    return problem.with_fixed(fixed, case.start[fixed])


def write_certified(path, x, case: CellCase, problem, format=None, forced=None) -> dict:
    """Write map ``x`` (n, d) with the case's cells to ``path`` atomically, certified.

    The file is written beside ``path`` (:func:`geomopt.io.write_cells`), read back, and
    certified exactly: the cells read back are the case's, the map is locally injective
    (:meth:`~geomopt.mesh.problem.Problem.certify`: every element valid everywhere,
    oriented as ``problem``'s, and no vertex or edge wound twice or overlapping) and the
    handles equal ``problem.fixed_positions`` as numbers (:func:`geomopt.exact.predicates.differing_rows`:
    ``-0.0`` is ``0.0``).  Only then is it moved onto ``path``.  The one exception is what the
    input's handles alone make overlap, ``forced`` (the result certificate's ``forced``: the
    input's :meth:`~geomopt.Problem.certify_fixed`): failures it lists are reported, not refused.

    Returns
    -------
    dict with ``path``, ``local_certificate`` (the file's exact certificate: a
    :class:`~geomopt.mesh.elements.ElementLocalCertificate` for quads / hexahedra, a
    :class:`~geomopt.exact.certify.LocalCertificate` for tetrahedra), ``certificate`` (quads /
    hexahedra: its :class:`~geomopt.mesh.elements.ElementCertificate`, else None) and ``certified``
    (True when the file is locally injective everywhere, False when only ``forced`` fails).

    Raises
    ------
    SolveError
        The written file does not certify; nothing is left at ``path`` (the message does not say so:
        the command line adds it).
    """
    from .. import io
    from ..exact.predicates import differing_rows

    ext = (format or Path(path).suffix).lower()
    with io.atomic_path(path, f"{case.kind} mesh") as tmp:
        io.write_cells(tmp, x, case.elements, case.kind, format=ext)
        back, E, _ = io.read_cells(tmp, (case.kind,), format=ext)
        back = back[:, : x.shape[1]]
        if not np.array_equal(E, case.elements):
            raise SolveError(f"{path}: the cells read back differ from the input's")
        cert = problem.certify(back)  # elements valid everywhere, no branch point, no boundary overlap
        left = cert if cert.ok or cert.inverted or forced is None else cert.beyond(forced)
        moved = int(np.count_nonzero(differing_rows(back[problem.fixed], problem.fixed_positions)))
        if not left.ok or moved:
            why = left.message if not left.ok else f"{moved} handle(s) moved"
            raise SolveError(f"the written file did not certify ({why})", certificate=left)
    return {"path": Path(path), "certificate": getattr(cert, "elements", None), "local_certificate": cert,
            "certified": cert.ok}

"""The Locally Injective Mappings (LIM) benchmark case layout: one case per folder.

A 2D case holds ``input.obj`` (the rest mesh as ``v`` lines, the start map as one ``vt``
per vertex, faces ``a/a b/b c/c``: :func:`geomopt.io.read_obj_with_uv`) and ``handles.txt``;
a 3D case holds ``rest.vtk`` and ``init.vtk`` (same tetrahedra) and ``handles.txt`` or, when
that is absent, ``handles_derived_boundary.txt``.  A handles file lists 0-based vertex ids
(:func:`geomopt.io.read_vertex_ids`); an empty one means no fixed vertex.

:class:`LimCase` is one case in memory: :meth:`LimCase.read` reads a folder exactly (or
refuses it), :meth:`LimCase.write` writes one so that it reads back bit for bit, and
:meth:`LimCase.cases` finds the case folders under a root.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ._errors import MeshError, MeshFormatError
from .io import (CASE_FILES, atomic_write, read_obj_with_uv, read_vertex_ids, read_vtk_tets, write_obj_with_uv,
                 write_vtk_tets)

__all__ = ["LimCase", "read_lim_case", "lim_case_dim", "lim_cases"]

#: The files that mark a folder as a 2D or a 3D case (output folders never are one: geomopt.io.check_outputs).
_MARKS_2D, _MARKS_3D = CASE_FILES[:1], CASE_FILES[1:]
_HANDLES_3D = ("handles.txt", "handles_derived_boundary.txt")


@dataclasses.dataclass(frozen=True, eq=False)
class LimCase(Mapping):
    """One LIM case: a rest mesh, a start map and the fixed vertices.

    Attributes
    ----------
    dim : {2, 3}
        2: triangles mapped to the plane; 3: tetrahedra mapped to space.
    rest : numpy.ndarray, shape (n, 3), float64
        Rest positions (2D: the ``v`` lines, planar when every ``z`` is 0).
    init : numpy.ndarray, shape (n, dim), float64
        The start map (2D: the ``vt`` lines; 3D: ``init.vtk``'s points).
    simplices : numpy.ndarray, shape (m, dim + 1), int64
        Triangles (2D) or tetrahedra (3D), 0-based, in file order.
    handles : numpy.ndarray, shape (k,), int64
        Fixed vertex ids, in file order; their positions are ``init[handles]``.
    path : pathlib.Path or None
        The case folder (``None`` for a case built in memory).
    handles_file : pathlib.Path or None
        The file the handles came from.

    Notes
    -----
    For code written against the old dict (``read_lim_case``), a case also reads like a
    read-only mapping with the keys ``dim``, ``path``, ``rest``, ``init``, ``faces`` (2D) or
    ``tets`` (3D), ``handles`` and ``handles_file``; use the attributes in new code.
    """

    dim: int
    rest: np.ndarray
    init: np.ndarray
    simplices: np.ndarray
    handles: np.ndarray
    path: Path | None = None
    handles_file: Path | None = None

    def __post_init__(self):
        if self.dim not in (2, 3):
            raise MeshError(f"a LIM case is 2D or 3D, got dim={self.dim!r}")
        init, simplices = np.shape(self.init), np.shape(self.simplices)
        if init != (len(self.rest), self.dim):
            raise MeshError(f"{self.path or 'LIM case'}: init must have shape ({len(self.rest)}, {self.dim}) "
                            f"(one position per rest vertex), got {init}")
        if len(simplices) != 2 or simplices[1] != self.dim + 1:
            raise MeshError(f"{self.path or 'LIM case'}: simplices must have shape (m, {self.dim + 1}), "
                            f"got {simplices}")

    # ------------------------------------------------------------------ reading

    @classmethod
    def read(cls, folder):
        """Read a 2D or 3D case folder exactly as its files say, or refuse it.

        Parameters
        ----------
        folder : str or os.PathLike
            A folder with ``input.obj`` + ``handles.txt`` (2D) or ``rest.vtk`` + ``init.vtk`` +
            a handles file (3D); which one is decided by the file names (:meth:`dim_of`).

        Returns
        -------
        LimCase

        Raises
        ------
        MeshFormatError
            The folder is missing, holds neither kind of case or both, a file is missing
            (named) or malformed (with its line).
        MeshError
            Non-finite values, indices out of range or repeated, the two VTK files of a 3D
            case differ in points or tetrahedra.
        """
        folder = Path(folder)
        return _read_2d(folder) if cls.dim_of(folder) == 2 else _read_3d(folder)

    @staticmethod
    def dim_of(folder):
        """2 or 3: the kind of case in ``folder``, judged by its file names only.

        Raises
        ------
        MeshFormatError
            The folder is missing, holds neither kind of case, or both.
        """
        folder = Path(folder)
        if not folder.is_dir():
            raise MeshFormatError(f"LIM case folder {folder} does not exist or is not a directory")
        is_2d = any((folder / n).exists() for n in _MARKS_2D)
        is_3d = any((folder / n).exists() for n in _MARKS_3D)
        if is_2d and is_3d:
            raise MeshFormatError(
                f"{folder} holds both input.obj (2D case) and rest/init.vtk (3D case); keep one case per folder")
        if not (is_2d or is_3d):
            raise MeshFormatError(f"{folder} is not a LIM case folder: expected input.obj + handles.txt (2D) "
                                  f"or rest.vtk + init.vtk (3D)")
        return 2 if is_2d else 3

    @staticmethod
    def cases(root):
        """All case folders under ``root`` (those holding ``input.obj`` or ``rest.vtk``), sorted.

        Parameters
        ----------
        root : str or os.PathLike
            Folder searched recursively (``root`` itself counts if it is a case).

        Returns
        -------
        list of pathlib.Path
            Case folders, sorted; empty when there are none.

        Raises
        ------
        MeshFormatError
            ``root`` is not an existing directory.
        """
        root = Path(root)
        if not root.is_dir():
            raise MeshFormatError(f"LIM root {root} does not exist or is not a directory")
        found = {p.parent for name in ("input.obj", "rest.vtk") for p in root.rglob(name) if p.is_file()}
        return sorted(found)

    # ------------------------------------------------------------------ writing

    @classmethod
    def from_tangle(cls, tangle):
        """The case of a :class:`~geomopt.generators.Tangle` (its ``x0`` is the start map)."""
        return cls(dim=tangle.dim, rest=np.asarray(tangle.rest), init=np.asarray(tangle.x0),
                   simplices=np.asarray(tangle.simplices), handles=np.asarray(tangle.fixed))

    def write(self, folder):
        """Write the case as a LIM folder that :meth:`read` reads back bit for bit.

        2D: ``input.obj`` (the rest positions as ``v`` lines, with ``z = 0`` when ``rest``
        has 2 columns, the start map as ``vt``) and ``handles.txt``; 3D: ``rest.vtk``,
        ``init.vtk`` and ``handles.txt``.  The folder is created (with its parents) if
        missing; each file is written atomically.

        Parameters
        ----------
        folder : str or os.PathLike
            The case folder.

        Returns
        -------
        pathlib.Path
            ``folder``.
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        if self.dim == 2:
            rest = np.asarray(self.rest, dtype=np.float64)
            if rest.ndim == 2 and rest.shape[1] == 2:
                rest = np.c_[rest, np.zeros(len(rest))]
            write_obj_with_uv(folder / "input.obj", rest, self.simplices, self.init)
        else:
            write_vtk_tets(folder / "rest.vtk", self.rest, self.simplices)
            write_vtk_tets(folder / "init.vtk", self.init, self.simplices)
        ids = "".join(f"{int(h)}\n" for h in np.asarray(self.handles).tolist())
        atomic_write(folder / "handles.txt", lambda fh: fh.write(ids))
        return folder

    # ------------------------------------------------------------------ legacy mapping

    def _legacy(self):
        elements = "faces" if self.dim == 2 else "tets"
        return {"dim": self.dim, "path": self.path, "rest": self.rest, "init": self.init,
                elements: self.simplices, "handles": self.handles, "handles_file": self.handles_file}

    def __getitem__(self, key):
        return self._legacy()[key]

    def __iter__(self):
        return iter(self._legacy())

    def __len__(self):
        return len(self._legacy())

    __eq__ = object.__eq__  # identity, as a dataclass with eq=False (Mapping's would compare arrays)
    __hash__ = object.__hash__


def _read_2d(folder):
    """A 2D case: ``input.obj`` and ``handles.txt``."""
    obj_path, handles_path = folder / "input.obj", folder / "handles.txt"
    for p in (obj_path, handles_path):
        if not p.exists():
            raise MeshFormatError(f"2D LIM case {folder} has no {p.name}; expected input.obj and handles.txt")
    rest, init, faces = read_obj_with_uv(obj_path)
    return LimCase(dim=2, rest=rest, init=init, simplices=faces, handles=read_vertex_ids(handles_path, len(rest)),
                   path=folder, handles_file=handles_path)


def _read_3d(folder):
    """A 3D case: ``rest.vtk``, ``init.vtk`` (same tetrahedra) and a handles file."""
    for name in _MARKS_3D:
        if not (folder / name).exists():
            raise MeshFormatError(f"3D LIM case {folder} has no {name}; expected rest.vtk and init.vtk")
    handles_path = next((folder / n for n in _HANDLES_3D if (folder / n).exists()), None)
    if handles_path is None:
        raise MeshFormatError(f"3D LIM case {folder} has neither handles.txt nor handles_derived_boundary.txt; "
                              f"add the fixed vertex ids (0-based, one per line)")
    rest, tets = read_vtk_tets(folder / "rest.vtk")
    init, tets_init = read_vtk_tets(folder / "init.vtk")
    if init.shape[0] != rest.shape[0]:
        raise MeshError(f"{folder}: rest.vtk has {rest.shape[0]} points but init.vtk has {init.shape[0]}; "
                        f"they must describe the same vertices")
    if tets_init.shape != tets.shape or not np.array_equal(tets_init, tets):
        differ = (f"{tets.shape[0]} vs {tets_init.shape[0]} tets" if tets_init.shape != tets.shape
                  else f"first difference at tet {np.flatnonzero((tets != tets_init).any(axis=1))[0]}")
        raise MeshError(f"{folder}: rest.vtk and init.vtk have different connectivity ({differ}); "
                        f"they must share the same tetrahedra")
    return LimCase(dim=3, rest=rest, init=init, simplices=tets, handles=read_vertex_ids(handles_path, len(rest)),
                   path=folder, handles_file=handles_path)


# ---------------------------------------------------------------------- old names


def read_lim_case(folder):
    """Deprecated: :meth:`LimCase.read`."""
    return LimCase.read(folder)


def lim_case_dim(folder):
    """Deprecated: :meth:`LimCase.dim_of`."""
    return LimCase.dim_of(folder)


def lim_cases(root):
    """Deprecated: :meth:`LimCase.cases`."""
    return LimCase.cases(root)

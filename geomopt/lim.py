"""The Locally Injective Mappings (LIM) benchmark case layout: one case per folder.

A 2D case holds ``input.obj`` (the rest mesh as ``v`` lines, the start map as one ``vt``
per vertex, faces ``a/a b/b c/c``: :func:`geomopt.io.read_obj_with_uv`) and ``handles.txt``;
a 3D case holds ``rest.vtk`` and ``init.vtk`` (same tetrahedra) and ``handles.txt`` or, when
that is absent, ``handles_derived_boundary.txt``.  A handles file lists 0-based vertex ids
(:func:`geomopt.io.read_vertex_ids`); an empty one means no fixed vertex.

:class:`LimCase` is one case in memory: :meth:`LimCase.read` reads a folder exactly (or
refuses it), :meth:`LimCase.write` writes one so that it reads back bit for bit, and
:meth:`LimCase.cases` finds the case folders under a root; :meth:`LimCase.to_problem` is its
untangling problem (:class:`LimProblem`) and :meth:`LimCase.write_certified` writes a solution
in the case's own connectivity and frame, certified on the file read back.
:func:`untangle_case` reads and untangles a case in one call.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ._runtime.errors import MeshError, MeshFormatError, SolveError
from .exact.certify import local_certificate
from .io import (CASE_FILES, atomic_path, atomic_write, read_obj_with_uv, read_vertex_ids, read_vtk_tets,
                 write_obj_with_uv, write_vtk_tets)
from .exact.predicates import differing_rows
from .mesh.orientation import fixed_total_problem
from .mesh.problem import Problem
from .untangling import UntangleOptions, untangle

__all__ = ["LimCase", "LimProblem", "untangle_case", "output_suffix"]


class LimProblem(NamedTuple):
    """A LIM case as an untangling problem (:meth:`LimCase.to_problem`).

    Attributes
    ----------
    problem : :class:`~geomopt.Problem`, handles at their ``init`` positions, mirrored like
        the map.
    x0 : (n, d) the start map in the problem's frame.
    orientation : +1 or -1, the orientation every element must have in the input's own
        connectivity and frame (what :meth:`LimCase.write_certified` certifies).
    mirror : (d,) the exact per-axis sign taking the problem's frame to the input's.
    """

    problem: Problem
    x0: np.ndarray
    orientation: int
    mirror: np.ndarray


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
    For code written against the old dict (of the former ``read_lim_case``), a case also reads
    like a read-only mapping with the keys ``dim``, ``path``, ``rest``, ``init``, ``faces`` (2D)
    or ``tets`` (3D), ``handles`` and ``handles_file``; use the attributes in new code.
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
        """The case of a :class:`~geomopt.mesh.generators.Tangle` (its ``x0`` is the start map)."""
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
            write_obj_with_uv(folder / "input.obj", self._rest_3d(), self.simplices, self.init)
        else:
            write_vtk_tets(folder / "rest.vtk", self.rest, self.simplices)
            write_vtk_tets(folder / "init.vtk", self.init, self.simplices)
        ids = "".join(f"{int(h)}\n" for h in np.asarray(self.handles).tolist())
        atomic_write(folder / "handles.txt", lambda fh: fh.write(ids))
        return folder

    # ------------------------------------------------------------------ solving

    def require_handles(self):
        """Raise MeshError unless the case fixes some vertex (a fixed-boundary untangling
        needs them)."""
        if self.handles.size == 0:
            raise MeshError(f"{self.handles_file or 'the case'} is empty: untangling needs a fixed boundary; list "
                            f"the 0-based ids of the fixed vertices in it, one per line")

    def to_problem(self) -> LimProblem:
        """The untangling problem of the case.

        2D: the rest mesh is the ``v`` lines and the start map the ``vt`` lines.  A planar rest
        mesh (``z == 0`` everywhere) is a :meth:`Problem.planar` problem, whose rest triangles
        must all have the same orientation; any other rest mesh is a surface
        (:meth:`Problem.surface`, each triangle flattened to its own frame), whose triangles
        must be consistently oriented as a surface.  Either way a map with every triangle
        positively oriented then has no fold, which is what the certificate claims.  A start
        map whose orientation is opposite to the rest mesh's (negative total signed area,
        counted in the rest orientation) is mirrored (``u -> -u``, exact) into the problem's
        frame.  3D: :meth:`Problem.tets` (an all-negative rest mesh is handled there).

        Returns
        -------
        :class:`LimProblem` (computed once per case).

        Raises
        ------
        MeshError
            The rest mesh is degenerate or inconsistently oriented (a face listed clockwise
            among counter-clockwise ones), the start map is collapsed (zero total signed area)
            or, in 3D with every boundary vertex a handle, its total signed volume is not
            positive: no map with that boundary can be certified.
        """
        return self._problem

    @functools.cached_property
    def _problem(self) -> LimProblem:
        return _problem_2d(self) if self.dim == 2 else _problem_3d(self)

    def write_certified(self, result, path) -> dict:
        """Write a solution of the case to ``path`` atomically, certified on the file itself.

        2D: OBJ with the case's ``v`` lines, one ``vt`` per vertex (the map) and
        ``f a/a b/b c/c``; 3D: ASCII VTK with the input connectivity; full precision.  The file
        is written beside ``path`` and read back: the map must be locally injective (exact
        predicates, :func:`geomopt.exact.certify.local_certificate`: every element in the case's
        orientation, :meth:`to_problem`'s ``orientation``, and the elements around every
        vertex and edge covering it once) and every handle at its ``init`` position (equal as
        numbers, :func:`geomopt.exact.predicates.differing_rows`).  The one exception is what the input itself fixes: vertices and edges whose every
        element has all its vertices fixed and that overlap in the case's own handle positions
        (:meth:`~geomopt.Problem.certify_fixed`; the same in every map with these handles) are
        reported, not refused.  Only a file that certifies is renamed onto ``path``, so one that
        does not never replaces an older one.

        Parameters
        ----------
        result : a :class:`~geomopt.solvers.Result` (its ``x``) or an (n, d) map, in the
            case's own frame (as :func:`untangle_case` returns it).
        path : the output file (``.obj`` for 2D, ``.vtk`` for 3D).

        Returns
        -------
        dict with ``path``, ``inverted`` and ``handles_moved`` (in the file, both 0),
        ``certified`` (True when the file is locally injective everywhere), ``outcome``
        (``"certified"``, or ``"certified_except_fixed"`` when it fails only where the handles
        make every map fail), ``forced`` (the vertices and edges listed there) and ``message``
        (the first of them, or "").

        Raises
        ------
        SolveError
            The written file did not certify; nothing is left at ``path`` from this call.
        GeomoptError
            ``path`` cannot be written.
        """
        x = np.asarray(getattr(result, "x", result), dtype=np.float64)
        with atomic_path(path) as tmp:
            back = self._written(x, tmp)
            # exact: orientations, and the elements around every vertex and edge
            cert = local_certificate(back, self.simplices, orientation=self.to_problem().orientation)
            moved = int(np.count_nonzero(differing_rows(back[self.handles], self.init[self.handles])))
            left = cert if cert.ok or cert.inverted else cert.beyond(self._forced)
            if not left.ok or moved:
                why = "; ".join(filter(None, [left.message, f"{moved} handle(s) moved" if moved else ""]))
                raise SolveError(f"the written file did not certify: {why}", certificate=cert)
        return {"path": Path(path), "inverted": 0, "handles_moved": 0, "certified": cert.ok,
                "outcome": "certified" if cert.ok else "certified_except_fixed", "forced": cert.failures,
                "message": cert.message}

    @functools.cached_property
    def _forced(self):
        """The input's overlaps that its handles alone make (:meth:`~geomopt.Problem.certify_fixed`
        of the start map, in the problem's frame; vertex ids are the case's)."""
        setup = self.to_problem()
        return setup.problem.certify_fixed(setup.x0)

    def _rest_3d(self) -> np.ndarray:
        """A 2D case's rest positions as OBJ ``v`` lines: (n, 3), ``z = 0`` added to a planar
        (n, 2) rest mesh."""
        rest = np.asarray(self.rest, dtype=np.float64)
        return np.c_[rest, np.zeros(len(rest))] if rest.ndim == 2 and rest.shape[1] == 2 else rest

    def _written(self, x, path) -> np.ndarray:
        """Write the map ``x`` to ``path`` and read it back (connectivity checked)."""
        if self.dim == 2:
            write_obj_with_uv(path, self._rest_3d(), self.simplices, x)
            _, back, _ = read_obj_with_uv(path)
            if len(back) != len(self.rest):
                raise MeshError(f"{path}: read back {len(back)} vt lines, expected {len(self.rest)}")
            return back
        write_vtk_tets(path, x, self.simplices)
        back, T = read_vtk_tets(path)
        if not np.array_equal(T, self.simplices):
            raise MeshError(f"{path}: connectivity read back differs from the input")
        return back

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


def _problem_2d(case) -> LimProblem:
    F, init, rest, H = case.simplices, case.init, np.asarray(case.rest), case.handles
    planar = rest.ndim == 2 and (rest.shape[1] == 2 or (rest.shape[1] == 3 and not np.any(rest[:, 2])))
    base = Problem.planar(rest, F) if planar else Problem.surface(rest, F)
    # planar: the rest triangles may all be clockwise (Problem.planar reversed each one)
    rest_sign = 1 if np.array_equal(base.simplices, base.input_simplices) else -1
    P = init[F]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    total = float(np.sum(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])) / 2.0
    if not (total > 0 or total < 0):
        raise MeshError(
            f"{case.path or 'the case'}: the start map's total signed area is {total:g}: the map is "
            f"collapsed, so no orientation can be certified; give a start map ('vt' lines) whose fixed "
            f"boundary encloses a nonzero area")
    orientation = -1 if total < 0 else 1  # in the input's connectivity and frame
    mirror = np.array([float(orientation * rest_sign), 1.0])
    return LimProblem(base.with_fixed(H, init[H] * mirror), init * mirror, orientation, mirror)


def _problem_3d(case) -> LimProblem:
    problem = Problem.tets(case.rest, case.simplices, case.handles, case.init[case.handles])
    # rest tets all negative in the input order: Problem.tets swapped two vertices of each
    orientation = 1 if np.array_equal(problem.simplices, problem.input_simplices) else -1
    init = np.asarray(case.init, dtype=np.float64)
    why = fixed_total_problem(problem, init)  # in the rest orientation
    if why:
        raise MeshError(f"{case.path or 'the case'}: {why} (Garanzha et al.'s code rejects such input "
                        f"too); check that the rest and initial meshes belong together")
    return LimProblem(problem, init, orientation, np.ones(3))


def untangle_case(case, solver="lbfgs", *, options: UntangleOptions | None = None, progress=True):
    """Untangle a LIM case (:meth:`LimCase.to_problem`, :func:`~geomopt.untangling.untangle`).

    Parameters
    ----------
    case : a :class:`LimCase`, or a case folder (read with :meth:`LimCase.read`).
    solver, options, progress : passed to :func:`~geomopt.untangling.untangle`
        (``options`` an :class:`~geomopt.untangling.UntangleOptions` or None).

    Returns
    -------
    case : the :class:`LimCase` (write a certified result with :meth:`LimCase.write_certified`).
    result : :class:`~geomopt.solvers.Result`, its ``x`` in the case's own frame.
    """
    case = case if isinstance(case, LimCase) else LimCase.read(case)
    setup = case.to_problem()
    result = untangle(setup.problem, setup.x0, solver=solver, progress=progress, options=options)
    if (setup.mirror < 0).any():
        result = dataclasses.replace(result, x=result.x * setup.mirror)  # negation is exact
    return case, result


def output_suffix(dim) -> str:
    """The file a solved case of dimension ``dim`` (:meth:`LimCase.dim_of`) is written to:
    ``".obj"`` in 2D (its ``vt`` lines the map), ``".vtk"`` in 3D."""
    return ".obj" if dim == 2 else ".vtk"


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

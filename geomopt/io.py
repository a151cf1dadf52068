"""Reading and writing meshes, maps and Locally Injective Mappings (LIM) benchmark cases.

Every reader returns plain numpy arrays (coordinates ``float64``, indices ``int64``,
0-based) and never reorders or merges vertices.  Unreadable or malformed files raise
:class:`~geomopt._errors.MeshFormatError`; readable files with bad content (non-finite
coordinates, indices out of range, repeated vertices in an element) raise
:class:`~geomopt._errors.MeshError`.  Every writer writes atomically (see
:func:`atomic_output`) with full float precision (``%.17g`` round-trips ``float64``).

The validators :func:`validate_vertices`, :func:`validate_simplices` and
:func:`validate_indices` are public so that other constructors can reuse them.
"""

from __future__ import annotations

import contextlib
import io
import os
import secrets
import warnings
from pathlib import Path

import numpy as np

from ._errors import GeomoptError, MeshError, MeshFormatError, ParameterError

__all__ = [
    "MESH_EXTENSIONS",
    "atomic_output",
    "atomic_write",
    "check_output_path",
    "validate_vertices",
    "validate_simplices",
    "validate_indices",
    "read_mesh",
    "write_obj_with_uv",
    "read_lim2d",
    "read_vtk_tets",
    "write_vtk_tets",
    "read_lim3d",
    "read_lim_case",
    "lim_case_dim",
    "lim_cases",
]

#: File extensions :func:`read_mesh` accepts (lower case).
MESH_EXTENSIONS = (".obj", ".off", ".ply", ".stl")



def _write_rows(fh, prefix, A):
    """Rows of floats, each number in the shortest form that round-trips (``repr``)."""
    fh.writelines(prefix + " ".join(map(repr, row)) + "\n" for row in np.asarray(A, np.float64).tolist())
_INT64_MAX = np.iinfo(np.int64).max
_SIMPLEX_WORDS = {3: ("triangle", "triangles"), 4: ("tetrahedron", "tetrahedra")}


# --------------------------------------------------------------------------- atomic


@contextlib.contextmanager
def atomic_output(path, mode="w", encoding="utf-8"):
    """Open a temporary file next to ``path`` and move it onto ``path`` on success.

    The data goes to a hidden temporary file in the same directory.  When the
    ``with`` block ends normally the file is flushed, synced and renamed onto
    ``path`` with :func:`os.replace` (atomic on POSIX and Windows).  When the block
    raises, the temporary file is deleted and ``path`` is left untouched: it does
    not appear if it did not exist, and an existing file keeps its old contents.

    Parameters
    ----------
    path : str or os.PathLike
        Target file.  Its directory must exist.
    mode : {"w", "wb"}
        Text or binary mode.  Text mode uses ``encoding`` and ``"\\n"`` line ends.
    encoding : str
        Text encoding (ignored in binary mode).

    Yields
    ------
    file object
        The open temporary file.

    Raises
    ------
    ParameterError
        If ``mode`` is not ``"w"`` or ``"wb"``.
    GeomoptError
        If ``path`` cannot be written (see :func:`check_output_path`), or an ``OSError``
        (disk full, ...) happens while writing; nothing is left at ``path`` then.
    """
    if mode not in ("w", "wb"):
        raise ParameterError(f"atomic_output mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    fd, tmp = _open_temp_next_to(path)
    text_kwargs = {} if mode == "wb" else {"encoding": encoding, "newline": "\n"}
    try:
        with os.fdopen(fd, mode, **text_kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise GeomoptError(f"could not write {path} ({_one_line(exc)}); nothing was written") from exc
        raise


def atomic_write(path, write_fn, mode="w"):
    """Call ``write_fn(fh)`` on a temporary file and move it onto ``path`` on success.

    Parameters
    ----------
    path : str or os.PathLike
        Target file.
    write_fn : callable
        Called once with the open file object; whatever it raises propagates,
        and then no file is left at ``path`` (an existing one is kept as it was).
    mode : {"w", "wb"}
        Text (UTF-8) or binary mode.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    with atomic_output(path, mode) as fh:
        write_fn(fh)
    return Path(path)


def check_output_path(path):
    """Check that ``path`` can be written, before spending time on what goes into it.

    Creates and removes a temporary file beside ``path``, as :func:`atomic_output` will.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    GeomoptError
        ``path`` is a directory, its folder does not exist, or no file can be
        created there (permissions, read-only file system).
    """
    path = Path(path)
    fd, tmp = _open_temp_next_to(path)
    os.close(fd)
    os.unlink(tmp)
    return path


def _open_temp_next_to(path):
    """Create a fresh hidden file beside ``path``; return ``(fd, temp_path)``.

    ``os.open`` with mode 0o666 lets the umask decide the permissions, as for any
    newly created file (``tempfile.mkstemp`` would make it 0o600).  Raises
    :class:`GeomoptError` saying why ``path`` cannot be written.
    """
    if path.is_dir():
        raise GeomoptError(f"output {path} is a directory; give a file name (e.g. {path / 'out.obj'})")
    folder = path.parent
    if not folder.is_dir():
        what = "is not a directory" if folder.exists() else "does not exist"
        raise GeomoptError(f"cannot write {path}: the folder {folder} {what}; create it first")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = path.with_name(f".{path.name[:200]}.{secrets.token_hex(6)}.tmp")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
        except OSError as exc:
            raise GeomoptError(
                f"cannot write {path} ({_one_line(exc)}); check the folder's permissions"
            ) from exc
    raise GeomoptError(f"cannot write {path}: could not create a temporary file next to it")


# ----------------------------------------------------------------------- validation


def _as_array(A, name):
    """``np.asarray`` that turns ragged/odd input into a MeshError."""
    try:
        return np.asarray(A)
    except (ValueError, TypeError) as exc:
        raise MeshError(f"{name} is not a rectangular numeric array ({exc})") from None


def validate_vertices(V, name="vertices", dim=None):
    """Check vertex coordinates and return them as a ``float64`` array.

    Parameters
    ----------
    V : array_like, shape (n, d)
        Vertex positions, real-valued (integer or floating dtype).
    name : str
        What ``V`` is, used at the start of error messages.
    dim : {None, 2, 3}
        Required number of columns ``d``; ``None`` accepts 2 or 3.

    Returns
    -------
    numpy.ndarray, shape (n, d), float64
        A C-contiguous copy (or ``V`` itself when already so).

    Raises
    ------
    MeshError
        Wrong number of dimensions or columns, non-real dtype, no vertices, or
        NaN/infinite coordinates (the message gives the count and first index).
    """
    A = _as_array(V, name)
    widths = (2, 3) if dim is None else (dim,)
    want = " or ".join(f"(n, {w})" for w in widths)
    if A.ndim != 2 or A.shape[1] not in widths:
        raise MeshError(f"{name} must have shape {want}, got shape {A.shape}")
    if A.dtype.kind not in "fiu":
        raise MeshError(f"{name} must hold real numbers, got dtype {A.dtype}")
    if A.shape[0] == 0:
        raise MeshError(f"{name} has no vertices")
    A = np.ascontiguousarray(A, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(A).all(axis=1))
    if bad.size:
        raise MeshError(
            f"{name} has {bad.size} vertices with NaN or infinite coordinates "
            f"(first: vertex {bad[0]}); fix or remove them"
        )
    return A


def validate_simplices(S, n_vertices, k, name="faces"):
    """Check an element (triangle or tetrahedron) index array and return it as ``int64``.

    Parameters
    ----------
    S : array_like, shape (m, k)
        0-based vertex indices of ``m`` elements; must have an integer dtype
        (integer-valued floats are rejected, not rounded).
    n_vertices : int
        Number of vertices ``n``; valid indices are ``0 .. n-1``.
    k : int
        Vertices per element: 3 for triangles, 4 for tetrahedra.
    name : str
        What ``S`` is, used at the start of error messages.

    Returns
    -------
    numpy.ndarray, shape (m, k), int64
        A C-contiguous copy (or ``S`` itself when already so).

    Raises
    ------
    MeshError
        Wrong shape, non-integer dtype, no elements, indices out of range, or an
        element that uses a vertex twice (messages give the count and first element).
    """
    word, words = _SIMPLEX_WORDS.get(k, (f"{k}-vertex element", f"{k}-vertex elements"))
    A = _as_array(S, name)
    if A.ndim != 2 or A.shape[1] != k:
        raise MeshError(f"{name} must have shape (m, {k}) ({words}), got shape {A.shape}")
    if A.dtype.kind not in "iu":
        raise MeshError(
            f"{name} must have an integer dtype, got {A.dtype}; convert it with "
            f".astype(np.int64) after checking the values are whole numbers"
        )
    if A.shape[0] == 0:
        raise MeshError(f"{name} has no {words}")
    bad = np.flatnonzero(((A < 0) | (A >= n_vertices)).any(axis=1))
    if bad.size:
        raise MeshError(
            f"{name} has {bad.size} {words} with vertex indices outside 0..{n_vertices - 1} "
            f"(first: {word} {bad[0]} = {A[bad[0]].tolist()}); indices must be 0-based "
            f"and below the vertex count {n_vertices}"
        )
    A = np.ascontiguousarray(A, dtype=np.int64)
    ordered = np.sort(A, axis=1)
    bad = np.flatnonzero((ordered[:, 1:] == ordered[:, :-1]).any(axis=1))
    if bad.size:
        raise MeshError(
            f"{name} has {bad.size} {words} that use a vertex more than once "
            f"(first: {word} {bad[0]} = {A[bad[0]].tolist()}); remove these degenerate {words}"
        )
    return A


def validate_indices(I, n_vertices, name="handles"):
    """Check a list of distinct vertex indices (e.g. fixed vertices) and return it as ``int64``.

    Parameters
    ----------
    I : array_like, shape (k,)
        0-based vertex indices; integer dtype; may be empty.
    n_vertices : int
        Number of vertices ``n``; valid indices are ``0 .. n-1``.
    name : str
        What ``I`` is, used at the start of error messages.

    Returns
    -------
    numpy.ndarray, shape (k,), int64
        The indices in their given order.

    Raises
    ------
    MeshError
        Not 1-D, non-integer dtype, out of range, or repeated indices.
    """
    A = _as_array(I, name)
    if A.ndim != 1:
        raise MeshError(f"{name} must be a 1-D array of vertex indices, got shape {A.shape}")
    if A.size == 0:
        return np.zeros(0, dtype=np.int64)
    if A.dtype.kind not in "iu":
        raise MeshError(f"{name} must have an integer dtype, got {A.dtype}")
    bad = np.flatnonzero((A < 0) | (A >= n_vertices))
    if bad.size:
        raise MeshError(
            f"{name} has {bad.size} indices outside 0..{n_vertices - 1} "
            f"(first: entry {bad[0]} = {A[bad[0]]}); indices must be 0-based vertex ids"
        )
    A = np.ascontiguousarray(A, dtype=np.int64)
    values, counts = np.unique(A, return_counts=True)
    repeated = values[counts > 1]
    if repeated.size:
        raise MeshError(
            f"{name} lists {repeated.size} vertices more than once "
            f"(first: vertex {repeated[0]}); each vertex may appear only once"
        )
    return A


# ---------------------------------------------------------------- file helpers


def _existing_file(path, what):
    """Return ``Path(path)`` after checking it is an existing file (emptiness not checked)."""
    path = Path(path)
    try:
        exists = path.exists()
    except OSError as exc:  # e.g. a name too long for the file system
        raise MeshFormatError(f"{what} {path} cannot be accessed ({_one_line(exc)}); check the path") from exc
    if not exists:
        raise MeshFormatError(f"{what} {path} does not exist; check the path")
    if path.is_dir():
        raise MeshFormatError(f"{what} {path} is a directory, not a file; pass the file inside it")
    return path


def _check_not_empty(path, what):
    if path.stat().st_size == 0:
        raise MeshFormatError(f"{what} {path} is empty (0 bytes); re-export or re-download it")


def _read_bytes(path, what):
    """The bytes of an existing file; an unreadable one gives a MeshFormatError."""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise MeshFormatError(
            f"cannot read {what} {path} ({_one_line(exc)}); check its permissions"
        ) from exc


def _read_text(path, what):
    """Read a small text file; reject missing, empty and binary (NUL-containing) files."""
    path = _existing_file(path, what)
    _check_not_empty(path, what)
    data = _read_bytes(path, what)
    if b"\x00" in data:
        raise MeshFormatError(f"{what} {path} is a binary file; a text file is expected")
    return data.decode("utf-8", errors="replace")


def _one_line(exc):
    """An exception as ``Type: message`` on one short line."""
    text = " ".join(str(exc).split()) or "(no message)"
    return f"{type(exc).__name__}: {text[:200]}"


# -------------------------------------------------------------------- read_mesh


def read_mesh(path):
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file, keeping vertex order.

    Uses ``trimesh.load(path, process=False, maintain_order=True)``: ``process=False``
    stops vertex merging and unreferenced-vertex removal, ``maintain_order=True``
    stops the OBJ loader from splitting or reordering vertices by texture/normal
    index.  The result has exactly the file's vertices (``v`` lines for OBJ), in
    file order, unreferenced ones included.  OBJ/OFF text that is not UTF-8 is
    decoded as Latin-1.  Polygons are fan-triangulated by trimesh.
    STL files store every triangle separately, so their vertices come back unshared.
    An OBJ with several materials loads as one sub-mesh per material over the same
    vertex list; their faces are concatenated (grouped by material).

    Parameters
    ----------
    path : str or os.PathLike
        Mesh file with extension ``.obj``, ``.off``, ``.ply`` or ``.stl``.

    Returns
    -------
    V : numpy.ndarray, shape (n, 3), float64
        Vertex positions.
    F : numpy.ndarray, shape (m, 3), int64
        Triangles, 0-based vertex indices.

    Raises
    ------
    MeshFormatError
        Missing, directory, empty, unsupported extension, unparseable, several
        separate meshes, or no triangle faces.
    MeshError
        NaN/infinite coordinates, face indices out of range, repeated vertices in a face.
    """
    path = _existing_file(path, "mesh file")
    ext = path.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise MeshFormatError(
            f"mesh file {path} has unsupported extension {path.suffix!r}; supported: "
            f"{', '.join(MESH_EXTENSIONS)} (convert it, e.g. with meshio or MeshLab)"
        )
    _check_not_empty(path, "mesh file")
    data = _read_bytes(path, "mesh file")
    import trimesh

    source = path
    if ext in (".obj", ".off"):  # trimesh needs the optional charset_normalizer for non-UTF-8 text
        try:
            data.decode("utf-8")
        except UnicodeDecodeError:
            source = io.StringIO(data.decode("latin-1"))
    try:
        with warnings.catch_warnings():  # trimesh's texture bookkeeping warns on odd 'vt' use
            warnings.simplefilter("ignore", RuntimeWarning)
            loaded = trimesh.load(source, file_type=ext[1:], process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises anything on bad input
        raise MeshFormatError(
            f"could not read {path} as {ext[1:].upper()} ({_one_line(exc)}); "
            + ("a face probably refers to a vertex that does not exist" if isinstance(exc, IndexError)
               else "check that it is a valid triangle mesh file")
        ) from exc
    V, F = _trimesh_arrays(loaded, path, trimesh)
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    F = validate_simplices(F, V.shape[0], 3, f"{path.name}: faces")
    return V, F


def _trimesh_arrays(loaded, path, trimesh):
    """``(V, F)`` of what ``trimesh.load`` returned, or a MeshFormatError saying why not."""
    if isinstance(loaded, trimesh.Scene):
        parts = list(loaded.geometry.values())
        if not parts:
            raise MeshFormatError(
                f"{path} contains no mesh (no vertices or triangles found); "
                f"is it really a {path.suffix} mesh file?"
            )
        shared = all(
            isinstance(p, trimesh.Trimesh)
            and np.array_equal(p.vertices, parts[0].vertices, equal_nan=True)
            for p in parts
        )
        if len(parts) > 1 and not shared:
            raise MeshFormatError(
                f"{path} contains {len(parts)} separate meshes; merge them into one mesh "
                f"(one vertex list) before reading it"
            )
        if len(parts) > 1:
            faces = np.concatenate([np.asarray(p.faces) for p in parts])
            return np.array(parts[0].vertices, dtype=np.float64), faces
        loaded = parts[0]
    faces = getattr(loaded, "faces", None)
    if faces is None or len(faces) == 0:
        raise MeshFormatError(
            f"{path} has no triangle faces ({type(loaded).__name__} with only points or "
            f"lines); a triangle mesh is required"
        )
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshFormatError(
            f"{path} has non-triangle faces (shape {faces.shape}) that were not "
            f"triangulated; triangulate the mesh first"
        )
    return np.array(loaded.vertices, dtype=np.float64), faces


# ------------------------------------------------------------------- OBJ with UV


def write_obj_with_uv(path, V, F, UV):
    """Write a mesh and a per-vertex map as OBJ: ``v`` lines, one ``vt`` per vertex, ``f a/a b/b c/c``.

    This is the LIM 2D ``input.obj`` layout, so :func:`read_lim2d` reads it back
    exactly.  Numbers are written in their shortest exact (round-trip) form.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    V : array_like, shape (n, 3)
        Vertex positions (``v`` lines, in this order).
    F : array_like, shape (m, 3), integer
        Triangles, 0-based (written 1-based).
    UV : array_like, shape (n, 2)
        Map / texture coordinates, one per vertex (``vt`` lines).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Invalid ``V``, ``F`` or ``UV``, or ``UV`` not one row per vertex.
    """
    V = validate_vertices(V, "V", dim=3)
    UV = validate_vertices(UV, "UV", dim=2)
    if UV.shape[0] != V.shape[0]:
        raise MeshError(f"UV has {UV.shape[0]} rows but V has {V.shape[0]}; give one UV per vertex")
    F = validate_simplices(F, V.shape[0], 3, "F")

    def write(fh):
        _write_rows(fh, "v ", V)
        _write_rows(fh, "vt ", UV)
        np.savetxt(fh, np.repeat(F + 1, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")

    return atomic_write(path, write)


# ------------------------------------------------------------------------ LIM 2D


def read_lim2d(folder):
    """Read a 2D LIM benchmark case: ``input.obj`` (rest + initial map) and ``handles.txt``.

    ``input.obj`` is parsed by hand: ``v x y z`` (rest mesh), ``vt u v`` (initial
    map, exactly one per vertex in the same order), ``f`` lines with 3 corners
    written ``a``, ``a/a``, ``a/a/n`` or ``a//n`` (1-based; a texture index must
    equal its vertex index).  Other lines (comments, ``vn``, ``g``, ...) are ignored.
    ``handles.txt`` holds 0-based vertex ids separated by whitespace (any line
    ends); an empty file means no fixed vertex.

    Parameters
    ----------
    folder : str or os.PathLike
        Case folder.

    Returns
    -------
    dict
        ``rest`` (n, 3) float64, ``init`` (n, 2) float64, ``faces`` (m, 3) int64,
        ``handles`` (k,) int64 (file order), ``handles_file`` Path.

    Raises
    ------
    MeshFormatError
        Missing file (named), malformed number (with line number), non-triangle or
        relative (negative) face, ``vt`` count differing from ``v`` count, texture
        index differing from vertex index.
    MeshError
        Non-finite values, face indices out of range, repeated vertices in a face,
        handles out of range or repeated.
    """
    folder = Path(folder)
    obj_path, handles_path = folder / "input.obj", folder / "handles.txt"
    for p in (obj_path, handles_path):
        if not p.exists():
            raise MeshFormatError(f"2D LIM case {folder} has no {p.name}; expected input.obj and handles.txt")
    rest, init, faces = _parse_lim_obj(obj_path)
    n = rest.shape[0]
    return {
        "rest": validate_vertices(rest, f"{obj_path}: 'v' positions", dim=3),
        "init": validate_vertices(init, f"{obj_path}: 'vt' positions", dim=2),
        "faces": validate_simplices(faces, n, 3, f"{obj_path}: faces"),
        "handles": _read_handles(handles_path, n),
        "handles_file": handles_path,
    }


def _parse_lim_obj(path):
    """Parse ``v``/``vt``/``f`` lines; return ``(rest (n,3), init (n',2), faces (m,3))`` unvalidated."""
    text = _read_text(path, "OBJ file")
    V, UV, F = [], [], []
    for lineno, line in enumerate(text.split("\n"), start=1):
        tokens = line.split()
        if not tokens:
            continue
        key = tokens[0]
        if key == "v":
            V.append(_parse_floats(tokens, 3, path, lineno, "v x y z"))
        elif key == "vt":
            UV.append(_parse_floats(tokens, 2, path, lineno, "vt u v"))
        elif key == "f":
            F.append(_parse_face(tokens, path, lineno))
    if not V:
        raise MeshFormatError(f"{path} has no 'v' lines; it is not a LIM input.obj")
    if not F:
        raise MeshFormatError(f"{path} has no 'f' lines; a triangle mesh is required")
    if len(UV) != len(V):
        raise MeshFormatError(
            f"{path} has {len(V)} 'v' lines but {len(UV)} 'vt' lines; a LIM input.obj "
            f"needs exactly one 'vt' (initial map position) per vertex"
        )
    return np.array(V), np.array(UV), np.array(F, dtype=np.int64) - 1


def _parse_floats(tokens, count, path, lineno, expected):
    if len(tokens) < count + 1:
        raise MeshFormatError(
            f"{path}, line {lineno}: '{tokens[0]}' line has {len(tokens) - 1} numbers; expected '{expected}'"
        )
    try:
        return [float(t) for t in tokens[1 : count + 1]]
    except ValueError:
        raise MeshFormatError(
            f"{path}, line {lineno}: cannot parse {' '.join(tokens[1:count + 1])!r} as numbers; "
            f"expected '{expected}'"
        ) from None


def _parse_face(tokens, path, lineno):
    """1-based vertex indices of an ``f`` line with exactly three corners."""
    corners = tokens[1:]
    if len(corners) != 3:
        raise MeshFormatError(
            f"{path}, line {lineno}: face has {len(corners)} corners; only triangles are "
            f"supported (triangulate the mesh first)"
        )
    face = []
    for corner in corners:
        parts = corner.split("/")
        try:
            if len(parts) > 3:
                raise ValueError
            ids = [int(p) for p in parts[:2] if p != ""]
        except ValueError:
            raise MeshFormatError(
                f"{path}, line {lineno}: cannot parse face corner {corner!r}; expected 'a', 'a/a' or 'a/a/n'"
            ) from None
        if len(ids) == 0 or parts[0] == "":
            raise MeshFormatError(f"{path}, line {lineno}: face corner {corner!r} has no vertex index")
        if min(ids) <= 0:
            raise MeshFormatError(
                f"{path}, line {lineno}: face corner {corner!r} has a zero or negative (relative) index; "
                f"OBJ indices must be 1-based and absolute (re-export without relative indices)"
            )
        if max(ids) > _INT64_MAX:
            raise MeshFormatError(
                f"{path}, line {lineno}: face corner {corner!r} has an index too large to be valid"
            )
        if len(ids) == 2 and ids[1] != ids[0]:
            raise MeshFormatError(
                f"{path}, line {lineno}: face corner {corner!r} uses texture index {ids[1]} for "
                f"vertex {ids[0]}; a LIM input.obj needs texture index == vertex index"
            )
        face.append(ids[0])
    return face


def _read_handles(path, n_vertices):
    """0-based vertex ids from a whitespace-separated text file; empty file -> no handles."""
    path = _existing_file(path, "handles file")
    data = _read_bytes(path, "handles file")
    if b"\x00" in data:
        raise MeshFormatError(
            f"handles file {path} is a binary file; expected 0-based vertex ids, one per line"
        )
    ids = []
    for lineno, line in enumerate(data.decode("utf-8", errors="replace").split("\n"), start=1):
        for token in line.split():
            try:
                ids.append(int(token))
                if abs(ids[-1]) > _INT64_MAX:
                    raise ValueError
            except ValueError:
                raise MeshFormatError(
                    f"{path}, line {lineno}: cannot parse {token!r} as a vertex index; "
                    f"expected 0-based integers, one per line"
                ) from None
    return validate_indices(np.array(ids, dtype=np.int64), n_vertices, f"{path}: handles")


# ------------------------------------------------------------------------ VTK


def read_vtk_tets(path):
    """Read a tetrahedral mesh from a legacy VTK unstructured-grid file (via meshio).

    Points declared ``float`` are read as float32 (then widened), as VTK does;
    files written by :func:`write_vtk_tets` declare ``double`` and round-trip exactly.

    Parameters
    ----------
    path : str or os.PathLike
        ``.vtk`` file (legacy format, ASCII or binary, version 4.2 or 5.1).

    Returns
    -------
    P : numpy.ndarray, shape (n, 3), float64
        Point positions.
    T : numpy.ndarray, shape (m, 4), int64
        Tetrahedra, 0-based point indices (VTK cell type 10), in file order.

    Raises
    ------
    MeshFormatError
        Missing, directory, empty, unparseable, no points, no cells, or cells
        other than tetrahedra (the message lists the cell types found).
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a tet.
    """
    path = _existing_file(path, "VTK file")
    _check_not_empty(path, "VTK file")
    import meshio.vtk  # meshio.read() would print and sys.exit() on some errors

    try:
        mesh = meshio.vtk.read(str(path))
    except Exception as exc:  # meshio raises ReadError, ValueError, UnicodeError, ...
        raise MeshFormatError(
            f"could not read {path} as a legacy VTK unstructured grid ({_one_line(exc)}); "
            f"check that it is a complete legacy .vtk file"
        ) from exc
    if len(mesh.points) == 0:
        raise MeshFormatError(f"VTK file {path} has no points")
    if not mesh.cells:
        raise MeshFormatError(f"VTK file {path} has no cells; a tetrahedral mesh is required")
    others = sorted({c.type for c in mesh.cells if c.type != "tetra"})
    if others:
        raise MeshFormatError(
            f"VTK file {path} contains non-tetrahedral cells ({', '.join(others)}); only "
            f"tetrahedral meshes (VTK cell type 10) are supported"
        )
    P = validate_vertices(mesh.points, f"{path.name}: points", dim=3)
    T = np.concatenate([c.data for c in mesh.cells])
    return P, validate_simplices(T, P.shape[0], 4, f"{path.name}: tetrahedra")


def write_vtk_tets(path, P, T):
    """Write a tetrahedral mesh as an ASCII legacy VTK unstructured grid, full precision.

    Points are written as ``double`` with ``%.17g`` so :func:`read_vtk_tets` reads
    them back bit for bit.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.vtk`` file.
    P : array_like, shape (n, 3)
        Point positions.
    T : array_like, shape (m, 4), integer
        Tetrahedra, 0-based.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Invalid ``P`` or ``T``.
    """
    P = validate_vertices(P, "P", dim=3)
    T = validate_simplices(T, P.shape[0], 4, "T")
    m = T.shape[0]

    def write(fh):
        fh.write("# vtk DataFile Version 2.0\nwritten by geomopt\nASCII\nDATASET UNSTRUCTURED_GRID\n")
        fh.write(f"POINTS {P.shape[0]} double\n")
        _write_rows(fh, "", P)
        fh.write(f"CELLS {m} {5 * m}\n")
        np.savetxt(fh, T, fmt="4 %d %d %d %d")
        fh.write(f"CELL_TYPES {m}\n")
        fh.write("10\n" * m)

    return atomic_write(path, write)


# ------------------------------------------------------------------------ LIM 3D


def read_lim3d(folder):
    """Read a 3D LIM benchmark case: ``rest.vtk``, ``init.vtk`` and the fixed vertices.

    The fixed vertices come from ``handles.txt`` or, when that is absent, from
    ``handles_derived_boundary.txt`` (format as in :func:`read_lim2d`).

    Parameters
    ----------
    folder : str or os.PathLike
        Case folder.

    Returns
    -------
    dict
        ``rest`` (n, 3) float64, ``init`` (n, 3) float64, ``tets`` (m, 4) int64,
        ``handles`` (k,) int64, ``handles_file`` Path (which file they came from).

    Raises
    ------
    MeshFormatError
        A file is missing (named) or unreadable (see :func:`read_vtk_tets`).
    MeshError
        The two VTK files differ in point count or connectivity, bad handles.
    """
    folder = Path(folder)
    for name in ("rest.vtk", "init.vtk"):
        if not (folder / name).exists():
            raise MeshFormatError(f"3D LIM case {folder} has no {name}; expected rest.vtk and init.vtk")
    handles_path = next(
        (folder / n for n in ("handles.txt", "handles_derived_boundary.txt") if (folder / n).exists()),
        None,
    )
    if handles_path is None:
        raise MeshFormatError(
            f"3D LIM case {folder} has neither handles.txt nor handles_derived_boundary.txt; "
            f"add the fixed vertex ids (0-based, one per line)"
        )
    rest, tets = read_vtk_tets(folder / "rest.vtk")
    init, tets_init = read_vtk_tets(folder / "init.vtk")
    if init.shape[0] != rest.shape[0]:
        raise MeshError(
            f"{folder}: rest.vtk has {rest.shape[0]} points but init.vtk has {init.shape[0]}; "
            f"they must describe the same vertices"
        )
    if tets_init.shape != tets.shape or not np.array_equal(tets_init, tets):
        differ = (
            f"{tets.shape[0]} vs {tets_init.shape[0]} tets"
            if tets_init.shape != tets.shape
            else f"first difference at tet {np.flatnonzero((tets != tets_init).any(axis=1))[0]}"
        )
        raise MeshError(
            f"{folder}: rest.vtk and init.vtk have different connectivity ({differ}); "
            f"they must share the same tetrahedra"
        )
    return {
        "rest": rest,
        "init": init,
        "tets": tets,
        "handles": _read_handles(handles_path, rest.shape[0]),
        "handles_file": handles_path,
    }


# ---------------------------------------------------------------------- cases


def read_lim_case(folder):
    """Read a 2D or 3D LIM case, deciding by which files the folder holds (:func:`lim_case_dim`).

    Parameters
    ----------
    folder : str or os.PathLike
        A folder with ``input.obj`` (2D) or ``rest.vtk``/``init.vtk`` (3D).

    Returns
    -------
    dict
        The reader's dict (:func:`read_lim2d` or :func:`read_lim3d`) plus ``dim``
        (2 or 3) and ``path`` (the folder).

    Raises
    ------
    MeshFormatError
        The folder is missing, holds neither kind of case, or both.
    """
    folder = Path(folder)
    dim = lim_case_dim(folder)
    case = read_lim2d(folder) if dim == 2 else read_lim3d(folder)
    return {"dim": dim, "path": folder, **case}


def lim_case_dim(folder):
    """2 or 3: the kind of LIM case in ``folder``, judged by its file names only.

    Raises
    ------
    MeshFormatError
        The folder is missing, holds neither kind of case, or both.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise MeshFormatError(f"LIM case folder {folder} does not exist or is not a directory")
    is_2d = (folder / "input.obj").exists()
    is_3d = (folder / "rest.vtk").exists() or (folder / "init.vtk").exists()
    if is_2d and is_3d:
        raise MeshFormatError(
            f"{folder} holds both input.obj (2D case) and rest/init.vtk (3D case); keep one case per folder"
        )
    if not (is_2d or is_3d):
        raise MeshFormatError(
            f"{folder} is not a LIM case folder: expected input.obj + handles.txt (2D) "
            f"or rest.vtk + init.vtk (3D)"
        )
    return 2 if is_2d else 3


def lim_cases(root):
    """All LIM case folders under ``root`` (those holding ``input.obj`` or ``rest.vtk``), sorted.

    Parameters
    ----------
    root : str or os.PathLike
        Folder to search recursively (``root`` itself counts if it is a case).

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

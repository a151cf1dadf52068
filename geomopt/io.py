"""Reading and writing meshes, maps and Locally Injective Mappings (LIM) benchmark cases.

Every reader returns plain numpy arrays (coordinates ``float64``, indices ``int64``,
0-based) holding exactly what the file says: vertices in file order, never reordered
or merged (except the documented welding of STL corners), and every count, number and
index checked against the file's own header.  Unreadable or malformed files raise
:class:`~geomopt._errors.MeshFormatError` naming the problem (and the line, where there
is one); readable files with bad content (non-finite coordinates, indices out of range,
repeated vertices in an element) raise :class:`~geomopt._errors.MeshError`.

Text conventions shared by every text reader: a UTF-8 byte-order mark at the very start
of a file is skipped (the rest is read exactly); UTF-16/32 text is refused; line ends
may be LF or CRLF (a lone CR is refused); numbers must be plain decimal ASCII
(``1``, ``-2.5``, ``1e-3``, ``nan``/``inf`` are read, then non-finite coordinates are
refused as content); Python-only spellings such as ``1_0``, ``+1`` (for indices),
``0x10`` or non-ASCII digits are refused.

Every writer writes atomically (see :func:`atomic_output`) with full float precision
(the shortest decimal that round-trips ``float64``, or binary ``float64``).  Output paths
must be regular files or not exist (:func:`check_output_path`).

The validators :func:`validate_vertices`, :func:`validate_simplices` and
:func:`validate_indices` are public so that other constructors can reuse them.
"""

from __future__ import annotations

import contextlib
import errno
import gc
import os
import re
import secrets
import signal
import stat
import struct
from pathlib import Path

import numpy as np

from ._errors import GeomoptError, MeshError, MeshFormatError, ParameterError

__all__ = [
    "MESH_EXTENSIONS",
    "UV_MESH_EXTENSIONS",
    "atomic_output",
    "atomic_path",
    "atomic_write",
    "check_output_path",
    "validate_vertices",
    "validate_simplices",
    "validate_indices",
    "read_mesh",
    "read_obj_uv",
    "write_mesh_with_uv",
    "write_obj_with_uv",
    "write_ply_with_uv",
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

#: File extensions :func:`write_mesh_with_uv` writes (formats that carry one map coordinate per vertex).
UV_MESH_EXTENSIONS = (".obj", ".ply")


def _write_rows(fh, prefix, A):
    """Rows of floats, each number in the shortest form that round-trips (``repr``)."""
    fh.writelines(prefix + " ".join(map(repr, row)) + "\n" for row in np.asarray(A, np.float64).tolist())


_INT64_MAX = np.iinfo(np.int64).max
_SIMPLEX_WORDS = {3: ("triangle", "triangles"), 4: ("tetrahedron", "tetrahedra")}


# --------------------------------------------------------------------------- atomic

_DEFERRED_SIGNALS = {getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)}


def _block_signals():
    """Hold SIGINT/SIGTERM/SIGHUP back; return the previous mask for :func:`_unblock_signals`.

    Used around creating and deleting the temporary file, so that a signal handler that
    raises (the command line installs one) cannot fire between creating the file and
    registering its cleanup, nor interrupt the cleanup itself.  ``None`` where signals
    cannot be blocked (Windows).
    """
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, _DEFERRED_SIGNALS)


def _unblock_signals(old):
    """Restore the mask saved by :func:`_block_signals`; a signal held back is delivered now."""
    if old is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _file_kind(mode):
    """What a ``st_mode`` describes, in words."""
    for test, word in ((stat.S_ISDIR, "a directory"), (stat.S_ISLNK, "a symbolic link"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return word
    return "not a regular file"


def _temp_path(path):
    """A fresh hidden name beside ``path``: ``.<name>.<12 hex digits>.tmp``, at most 218 bytes.

    The name is shortened (by whole characters) to 200 bytes so that the temporary name
    fits any file system that takes ``path``'s own name.
    """
    name = path.name
    while len(os.fsencode(name)) > 200:
        name = name[:-1]
    return path.with_name(f".{name}.{secrets.token_hex(6)}.tmp")


def _output_problem(path, what, extensions=None):
    """Why ``path`` cannot be an output file, or ``None``; creates nothing.

    ``extensions`` (as in :func:`check_output_path`) picks the example file name that a
    message suggests; without it the example keeps ``path``'s own extension.

    An output must be a regular file or not exist; its folder must exist and be writable;
    its name (and the temporary name beside it) must fit the file system.
    """
    text = os.fspath(path)
    example = "out" + (extensions[0] if extensions else (Path(text).suffix or ".obj"))
    if text == "" or text.endswith(("/", os.sep)):
        return f"{what} {text!r} names a folder; give a file name (e.g. {os.path.join(text or '.', example)})"
    path = Path(path)
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        mode = None
    except NotADirectoryError:
        return f"cannot write {what} {path}: the folder {path.parent} is not a directory"
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return (f"{what} {path} has a name too long for the file system "
                    f"({len(os.fsencode(path.name))} bytes); choose a shorter name")
        return f"cannot access {what} {path} ({_one_line(exc)}); check the path"
    if mode is not None and stat.S_ISDIR(mode):
        return f"{what} {path} is a directory; give a file name (e.g. {path / example})"
    if mode is not None and not stat.S_ISREG(mode):
        return (f"{what} {path} is {_file_kind(mode)}, not a regular file; geomopt replaces its output "
                f"files, so give the path of a regular file or of one that does not exist yet")
    folder = path.parent
    try:
        folder_mode = os.stat(folder).st_mode
    except FileNotFoundError:
        return f"cannot write {what} {path}: the folder {folder} does not exist; create it first"
    except OSError as exc:
        return f"cannot write {what} {path}: the folder {folder} cannot be accessed ({_one_line(exc)})"
    if not stat.S_ISDIR(folder_mode):
        return f"cannot write {what} {path}: the folder {folder} is not a directory"
    try:
        os.lstat(_temp_path(path))
    except FileNotFoundError:
        pass
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return (f"{what} {path} has a name too long for the file system "
                    f"({len(os.fsencode(path.name))} bytes with its temporary file); choose a shorter name")
        return f"cannot write {what} {path} ({_one_line(exc)})"
    if not _can_create_in(folder):
        rdonly = getattr(os, "ST_RDONLY", 0)
        with contextlib.suppress(OSError, AttributeError):
            if os.statvfs(folder).f_flag & rdonly:
                return f"cannot write {what} {path}: the folder {folder} is on a read-only file system"
        return f"cannot write {what} {path}: no permission to create files in {folder}; check its permissions"
    return None


def _can_create_in(folder):
    """Whether this process may create files in ``folder`` (``access(2)``, so nothing is created)."""
    kwargs = {"effective_ids": True} if os.access in os.supports_effective_ids else {}
    return os.access(folder, os.W_OK | os.X_OK, **kwargs)


def check_output_path(path, extensions=None, what="output"):
    """Check that ``path`` can be written, before spending time on what goes into it.

    Nothing is created, changed or removed.  An output must be a regular file or not
    exist: a directory, symbolic link, device, FIFO or socket is refused, because the
    writers replace the output (:func:`atomic_output`) and must not replace those.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    extensions : sequence of str, optional
        Allowed extensions, lower case with the dot (e.g. ``(".obj", ".ply")``); the
        comparison ignores case.  ``None`` allows any.
    what : str
        What the output is, used at the start of error messages (e.g. ``"--png picture"``).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    GeomoptError
        The extension is not allowed, or ``path`` is not a regular file, names a folder,
        its folder does not exist or is not writable (permissions, read-only file system),
        or its name is too long for the file system.
    """
    problem = _output_problem(path, what, extensions)
    if problem:
        raise GeomoptError(problem)
    path = Path(path)
    if extensions is not None and path.suffix.lower() not in extensions:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise GeomoptError(f"{what} {path} has {got}; supported: {', '.join(extensions)}")
    return path


@contextlib.contextmanager
def atomic_path(path, what="output"):
    """A temporary path beside ``path`` that is moved onto ``path`` when the block succeeds.

    The temporary file is created empty (so the name is reserved) in the same folder,
    hidden (``.<name>.<random>.tmp``).  When the ``with`` block ends normally it is
    renamed onto ``path`` with :func:`os.replace` (atomic on POSIX and Windows).  When the
    block raises (including ``KeyboardInterrupt`` and the exception the command line
    raises for SIGTERM/SIGHUP) the temporary file is deleted and ``path`` is left
    untouched.  Use it for writers that open a file by name; :func:`atomic_output`
    gives an open file instead.

    Parameters
    ----------
    path : str or os.PathLike
        Target file; must pass :func:`check_output_path` (checked again before the rename).
    what : str
        What the output is, for error messages.

    Yields
    ------
    pathlib.Path
        The temporary file's path.

    Raises
    ------
    GeomoptError
        ``path`` cannot be written (see :func:`check_output_path`), or an ``OSError``
        (disk full, ...) happens; nothing is left at ``path`` then.
    """
    path = Path(path)
    held, tmp = _block_signals(), None
    try:
        tmp = _create_temp_next_to(path, what)
        # from here on, a signal held back while the file was created lands inside this
        # try block, where the cleanup below sees it
        _unblock_signals(held)
        held = None
        yield tmp
        problem = _output_problem(path, what)  # it may have changed while we wrote
        if problem:
            raise GeomoptError(problem)
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            again = _block_signals() if held is None else None
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            _unblock_signals(again)
        if isinstance(exc, OSError):
            raise GeomoptError(f"could not write {path} ({_one_line(exc)}); nothing was written") from exc
        raise
    finally:
        _unblock_signals(held)


@contextlib.contextmanager
def atomic_output(path, mode="w", encoding="utf-8"):
    """Open a temporary file next to ``path`` and move it onto ``path`` on success.

    The data goes to a hidden temporary file in the same directory (:func:`atomic_path`).
    When the ``with`` block ends normally the file is flushed, synced and renamed onto
    ``path``.  When the block raises, the temporary file is deleted and ``path`` is left
    untouched: it does not appear if it did not exist, and an existing file keeps its old
    contents.  The command line turns SIGTERM and SIGHUP into an exception, so that a
    terminated run leaves no temporary file either.

    Parameters
    ----------
    path : str or os.PathLike
        Target file: a regular file or a name that does not exist, in an existing folder.
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
    text_kwargs = {} if mode == "wb" else {"encoding": encoding, "newline": "\n"}
    with atomic_path(path) as tmp:
        with open(tmp, mode, **text_kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())


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


def _create_temp_next_to(path, what):
    """Create a fresh, empty hidden file beside ``path`` and return its path.

    ``os.open`` with mode 0o666 lets the umask decide the permissions, as for any
    newly created file (``tempfile.mkstemp`` would make it 0o600).  Raises
    :class:`GeomoptError` saying why ``path`` cannot be written.
    """
    problem = _output_problem(path, what)
    if problem:
        raise GeomoptError(problem)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = _temp_path(path)
        try:
            os.close(os.open(tmp, flags, 0o666))
            return tmp
        except FileExistsError:
            continue
        except OSError as exc:
            raise GeomoptError(
                f"cannot write {path} ({_one_line(exc)}); check the folder's permissions"
            ) from exc
    raise GeomoptError(f"cannot write {path}: could not create a temporary file next to it")


# ----------------------------------------------------------------------- validation


def _as_array(A, name):
    """``np.asarray`` that turns ragged/odd input into a MeshError (a traced JAX value into a
    ParameterError saying what can be traced)."""
    from ._tracing import refuse_traced

    refuse_traced(f"{name}: this check", "connectivity and indices must be concrete (close over them); "
                  "rest vertices and handle positions may be traced in Problem.planar/surface/tets, and "
                  "solves are differentiated with geomopt.implicit", A)
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
    """Return ``Path(path)`` after checking it is an existing regular file (emptiness not checked)."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise MeshFormatError(f"{what} {path} does not exist; check the path") from None
    except OSError as exc:  # e.g. a name too long for the file system
        raise MeshFormatError(f"{what} {path} cannot be accessed ({_one_line(exc)}); check the path") from exc
    if stat.S_ISDIR(mode):
        raise MeshFormatError(f"{what} {path} is a directory, not a file; pass the file inside it")
    if not stat.S_ISREG(mode):
        raise MeshFormatError(f"{what} {path} is {_file_kind(mode)}, not a regular file; pass a mesh file")
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


def _one_line(exc):
    """An exception as ``Type: message`` on one short line."""
    text = " ".join(str(exc).split()) or "(no message)"
    return f"{type(exc).__name__}: {text[:200]}"


# ------------------------------------------------------------------ text parsing

_UTF8_BOM = b"\xef\xbb\xbf"
_OTHER_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
               (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"))
#: A decimal number as C's strtod reads it (no '_', no hex, ASCII digits only), or nan/inf.
_FLOAT_RE = re.compile(rb"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?i:nan|inf|infinity))")
#: A decimal integer: ASCII digits with an optional minus sign (no '+', no '_').
_INT_RE = re.compile(rb"-?[0-9]+")


def _show(token):
    """A token (bytes) as printable text for a message."""
    text = token.decode("utf-8", errors="backslashreplace")
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _text_data(data, path, what):
    """``data`` with a leading UTF-8 byte-order mark removed; refuse what is not LF/CRLF ASCII-ish text.

    Refuses UTF-16/32 text (by its byte-order mark), NUL bytes (a binary file), a
    byte-order mark anywhere but at the start, and carriage returns not followed by a
    line feed.  CRLF line ends become LF.  Returns bytes.
    """
    for bom, name in _OTHER_BOMS:
        if data.startswith(bom):
            raise MeshFormatError(f"{what} {path} is {name} text (it starts with a {name} byte-order mark); "
                                  f"save it as UTF-8 or ASCII")
    if data.startswith(_UTF8_BOM):
        data = data[len(_UTF8_BOM):]
    if b"\x00" in data:
        raise MeshFormatError(f"{what} {path} is a binary file (it contains NUL bytes); a text file is expected")
    at = data.find(_UTF8_BOM)
    if at >= 0:
        lineno = data.count(b"\n", 0, at) + 1
        raise MeshFormatError(f"{path}, line {lineno}: a byte-order mark (U+FEFF) in the middle of the "
                              f"file; remove it (only one at the very start is allowed)")
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n")
        at = data.find(b"\r")
        if at >= 0:
            lineno = data.count(b"\n", 0, at) + 1
            raise MeshFormatError(f"{path}, line {lineno}: a carriage return (CR) not followed by a line "
                                  f"feed; convert the file to LF or CRLF line ends")
    return data


def _number_problem(token, kind):
    """Why ``token`` (bytes) is not a valid ``kind`` ('number' or 'integer'), in words."""
    hint = ""
    if _UTF8_BOM in token:
        hint = " (it contains a byte-order mark, U+FEFF)"
    elif b"_" in token:
        hint = " (underscores are not allowed in numbers)"
    elif kind == "integer" and _FLOAT_RE.fullmatch(token):
        hint = " (an integer is required)"
    elif any(b > 127 for b in token):
        hint = " (it contains non-ASCII characters)"
    example = "e.g. 0, 7 or 12" if kind == "integer" else "e.g. 1, -2.5 or 1e-3"
    return f"cannot read {_show(token)} as {'an integer' if kind == 'integer' else 'a number'}{hint}; " \
           f"expected a plain decimal {kind} ({example})"


def _first_bad(tokens, regex):
    """Index of the first token not fully matching ``regex``, or ``None``."""
    if all(map(regex.fullmatch, tokens)):
        return None
    return next(i for i, t in enumerate(tokens) if not regex.fullmatch(t))


def _floats(tokens, where):
    """``float64`` array of decimal tokens (bytes); ``where(i)`` locates token ``i`` for a message.

    Python's ``float`` (which numpy applies to bytes) reads exactly the syntax of ``_FLOAT_RE``
    plus underscores between digits, so tokens without ``_`` that it accepts are valid; the
    token-by-token check runs only to name a bad token.
    """
    if not tokens:
        return np.zeros(0)
    if b"_" not in b"".join(tokens):
        with contextlib.suppress(ValueError):
            return np.array(tokens, dtype=np.float64)
    bad = _first_bad(tokens, _FLOAT_RE)
    raise MeshFormatError(f"{where(bad)}: {_number_problem(tokens[bad], 'number')}")


def _ints(tokens, where):
    """``int64`` array of decimal integer tokens (bytes); refuses other syntax and values beyond int64.

    As in :func:`_floats`: Python's ``int`` reads ``_INT_RE`` plus ``+`` signs and underscores,
    so those two are excluded first and the token-by-token check names a bad token.
    """
    if not tokens:
        return np.zeros(0, dtype=np.int64)
    values = _plain_ints(tokens, b"".join(tokens))
    if values is not None:
        return values
    bad = _first_bad(tokens, _INT_RE)
    if bad is not None:
        raise MeshFormatError(f"{where(bad)}: {_number_problem(tokens[bad], 'integer')}")
    bad = next(i for i, t in enumerate(tokens) if abs(int(t)) > _INT64_MAX)
    raise MeshFormatError(f"{where(bad)}: the integer {_show(tokens[bad])} is too large")


def _plain_ints(tokens, joined):
    """``int64`` array of ``tokens`` if all are plain decimal integers within int64, else ``None``.

    ``joined`` is the tokens concatenated (with or without separators); Python's ``int`` reads
    exactly ``_INT_RE`` once ``+`` and ``_`` are ruled out.
    """
    if b"_" in joined or b"+" in joined:
        return None
    try:
        return np.array(tokens, dtype=np.int64)
    except (ValueError, OverflowError):
        return None


@contextlib.contextmanager
def _gc_paused():
    """Pause the cyclic garbage collector while a parser builds many small lists of tokens.

    Those containers trigger collections that traverse every tracked object in the process
    (JAX's included): measured 3x slower parsing of an 11k-vertex OFF file without this.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _rows(lines, comment=b"#"):
    """Non-blank lines as ``(line number, tokens)``; text from ``comment`` to the line end is dropped."""
    if comment is not None:
        lines = [line.split(comment, 1)[0] if comment in line else line for line in lines]
    return [(lineno, tokens) for lineno, tokens in enumerate(map(bytes.split, lines), 1) if tokens]


# -------------------------------------------------------------------- read_mesh


def read_mesh(path):
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file, exactly as the file says it.

    Each format is parsed here (no third-party loader), strictly:

    * **OBJ**: ``v x y z`` lines (an optional ``w`` or ``r g b`` after the position is
      checked as numbers and ignored), ``f`` lines with corners ``a``, ``a/t``, ``a/t/n``
      or ``a//n`` (1-based; negative indices count back from the last ``v`` line before
      the face, as the format defines).  Polygons are fan-triangulated: a face
      ``a b c d ...`` gives ``(a, b, c), (a, c, d), ...``; a polygon whose fan would fold
      (non-convex or twisted) is refused.  Attribute and grouping
      statements (``vt``, ``vn``, ``g``, ``o``, ``s``, ``usemtl``, ``mtllib``, ``l``, ``p``,
      ...) are ignored; free-form geometry and unknown statements are refused.  ``#``
      starts a comment; a line ending in ``\\`` continues on the next.
    * **OFF** (``OFF``, ``COFF``, ``NOFF``, ``STOFF`` ...): the header's vertex and face
      counts must match the body exactly (one vertex or face per line); a face line
      ``k i1 .. ik`` may end with up to 4 colour numbers.  Polygons are fan-triangulated.
    * **PLY** (ASCII, binary little- and big-endian): the header is validated (format,
      element counts, property types); the body must hold exactly the declared elements
      (ASCII: one element per line; binary: the exact byte count).  Vertices come from
      ``x y z`` of element ``vertex`` (``float`` properties are float32, as declared),
      faces from the list ``vertex_indices`` (or ``vertex_index``) of element ``face``,
      fan-triangulated.  Other elements and properties are read past and ignored.
    * **STL** (ASCII or binary): STL stores every triangle with its own three corners, so
      corners with equal coordinates (-0.0 = 0.0) are **welded** into one vertex (numbered in
      order of first appearance); without welding no STL mesh is connected.  Binary STL
      stores float32.  A file holding several ``solid`` blocks is refused.

    The text conventions (byte-order mark, line ends, number syntax) are in the module
    notes.  Degenerate content is left to :func:`validate_vertices` and
    :func:`validate_simplices`.

    Parameters
    ----------
    path : str or os.PathLike
        Mesh file with extension ``.obj``, ``.off``, ``.ply`` or ``.stl`` (any case).

    Returns
    -------
    V : numpy.ndarray, shape (n, 3), float64
        Vertex positions, in file order (unreferenced vertices included).
    F : numpy.ndarray, shape (m, 3), int64
        Triangles, 0-based vertex indices, in file order.

    Raises
    ------
    MeshFormatError
        Missing, not a regular file, empty, unsupported extension, malformed (the message
        names the problem and, for text, the line), counts that differ from the header,
        or no triangle faces.
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
    reader = {".obj": _read_obj, ".off": _read_off, ".ply": _read_ply, ".stl": _read_stl}[ext]
    with _gc_paused():
        V, F = reader(data, path)
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    F = validate_simplices(F, V.shape[0], 3, f"{path.name}: faces")
    return V, F


def _fan(indices, counts, V=None, path=None):
    """Fan-triangulate polygons given as flat corner ``indices`` (int64) and per-polygon ``counts`` (>= 3).

    Returns (sum(counts - 2), 3) int64: polygon ``c0 c1 .. ck`` gives ``(c0, ci, ci+1)``.  With
    the vertex positions ``V``, a polygon whose fan folds (a fan triangle facing against the
    polygon's Newell normal: a non-convex or twisted polygon) is refused, because the triangles
    would not tile the polygon.
    """
    counts = np.asarray(counts, dtype=np.int64)
    if counts.size and (counts == 3).all():
        return indices.reshape(-1, 3)
    starts = np.cumsum(counts) - counts
    ntri = counts - 2
    first = np.repeat(starts, ntri)
    local = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    F = np.stack([indices[first], indices[first + local + 1], indices[first + local + 2]], axis=1)
    if V is not None and indices.size and 0 <= indices.min() and indices.max() < len(V):
        _check_fans(np.asarray(V, np.float64), indices, counts, F, np.repeat(np.arange(counts.size), ntri), path)
    return F


def _check_fans(V, indices, counts, F, owner, path):
    """Refuse polygons (``counts > 3``) whose fan triangles ``F`` (polygon ``owner``) fold."""
    P = np.zeros((V.shape[0], 3))
    P[:, :V.shape[1]] = V
    poly = np.repeat(np.arange(counts.size), counts)
    nxt = np.arange(indices.size) + 1
    nxt[np.cumsum(counts) - 1] = np.cumsum(counts) - counts  # each polygon closes on its first corner
    normal = np.zeros((counts.size, 3))
    np.add.at(normal, poly, np.cross(P[indices], P[indices[nxt]]))  # Newell's normal (twice the area)
    tri = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    bad = (np.einsum("ij,ij->i", tri, normal[owner]) <= 0) & (counts[owner] > 3)
    if bad.any():
        k = int(owner[np.flatnonzero(bad)[0]])
        raise MeshFormatError(
            f"{path}: face {k + 1} is a polygon of {counts[k]} corners that is not convex (or is twisted): "
            f"cutting it into a fan of triangles folds it; triangulate the mesh before reading it")


# ------------------------------------------------------------------------- OBJ

#: OBJ statements that carry no vertex position or face: read past.
_OBJ_IGNORED = frozenset(b"vt vn vp g o s mg usemtl mtllib usemap maplib lod bevel c_interp d_interp "
                         b"shadow_obj trace_obj ctech stech l p".split())
#: OBJ free-form geometry statements: refused.
_OBJ_FREEFORM = frozenset(b"cstype deg bmat step curv curv2 surf parm trim hole scrv sp end con".split())
#: One face corner: ``a``, ``a/t``, ``a//n`` or ``a/t/n``.
_CORNER = rb"(-?[0-9]+)(?:/(-?[0-9]+)|//-?[0-9]+|/(-?[0-9]+)/-?[0-9]+)?"
_CORNER_RE = re.compile(_CORNER)
#: Space-separated corners (the ``f`` corners of a file joined by single spaces).
_CORNERS_RE = re.compile(_CORNER + rb"(?: " + _CORNER + rb")*")
_CORNER_FIND_RE = re.compile(rb"(?:^| )" + _CORNER)
#: First two bytes of the lines whose first word is known without splitting them.
_OBJ_HEADS = {b"v ": b"v", b"v\t": b"v", b"f ": b"f", b"f\t": b"f", b"": b""}


def _parse_obj(data, path, with_uv=False):
    """Parse the ``v``, ``f`` (and, with ``with_uv``, ``vt``) statements of an OBJ file.

    Returns a dict: ``v`` (n, 3) float64 positions; ``corners`` (c,) int64 0-based vertex
    index of each face corner (relative indices resolved); ``texcoords`` (c,) int64 0-based
    texture index of each corner or -1 where the corner has none; ``counts`` (f,) corners
    per face; ``lines`` (f,) line number of each face; and with ``with_uv`` ``vt`` (k, 2)
    float64.  Raises MeshFormatError naming the line of any malformed statement.
    """
    text = _text_data(data, path, "OBJ file")
    lines = text.split(b"\n")
    if b"\\\n" in text or text.endswith(b"\\"):
        lines = _join_continued(lines)
    lines = [line.split(b"#", 1)[0] if b"#" in line else line for line in lines]
    # the first word of every line (b"" for a blank one); 'v ' and 'f ' lines are recognised by
    # their first two bytes, any other line is split
    keys = [_OBJ_HEADS.get(line[:2]) or (line.split(None, 1) or [b""])[0] for line in lines]
    strange = set(keys) - _OBJ_IGNORED - {b"v", b"f", b"vt", b""}
    if strange:
        lineno, key = next((i + 1, k) for i, k in enumerate(keys) if k in strange)
        if key in _OBJ_FREEFORM:
            raise MeshFormatError(f"{path}, line {lineno}: free-form geometry ({_show(key)}) is not "
                                  f"supported; export the surface as polygons")
        raise MeshFormatError(f"{path}, line {lineno}: unknown OBJ statement {_show(key)}; "
                              f"is it really an OBJ file?")
    v_at = [i for i, k in enumerate(keys) if k == b"v"]
    f_at = [i for i, k in enumerate(keys) if k == b"f"]
    numbers = _statement_words(lines, v_at, b"v", 3)  # the common 'v x y z' lines all at once
    if numbers is not None:
        V = _floats(numbers, lambda i: f"{path}, line {v_at[i // 3] + 1}").reshape(-1, 3)
    else:
        V = _obj_numbers([(i + 1, lines[i].split()) for i in v_at], path, "v", (3, 4, 6),
                         "x y z (optionally w, or r g b)")[:, :3]
    out = {"v": V}
    if with_uv:
        vt_rows = [(i + 1, lines[i].split()) for i, k in enumerate(keys) if k == b"vt"]
        out["vt"] = _obj_numbers(vt_rows, path, "vt", (2, 3), "u v (optionally w)")[:, :2]
    seen = np.searchsorted(np.array(v_at, dtype=np.int64), np.array(f_at, dtype=np.int64))  # 'v' lines before
    face_lines = np.array(f_at, dtype=np.int64) + 1
    corners = _statement_words(lines, f_at, b"f", 3)  # triangles all at once
    if corners is not None:
        counts = np.full(len(f_at), 3, dtype=np.int64)
    else:
        rows = [lines[i].split() for i in f_at]
        counts = np.array([len(t) - 1 for t in rows], dtype=np.int64)
        short = np.flatnonzero(counts < 3)
        if short.size:
            raise MeshFormatError(f"{path}, line {face_lines[short[0]]}: face has {counts[short[0]]} "
                                  f"corner(s); a face needs at least 3")
        corners = [c for t in rows for c in t[1:]]
    out.update(_obj_faces(corners, counts, face_lines, seen, len(v_at), path))
    return out


def _statement_words(lines, at, key, width):
    """The words after ``key`` of ``lines[i] for i in at`` if every one has exactly ``width``, else ``None``.

    One split of the joined lines: with ``n`` lines, ``n * (width + 1)`` words of which exactly
    ``n`` are ``key``, all at multiples of ``width + 1``, means every line has ``width`` words
    after its ``key`` (a line of another length would put a ``key`` off that grid).
    """
    words = b"\n".join([lines[i] for i in at]).split()
    n, step = len(at), width + 1
    if len(words) != n * step or words.count(key) != n or words[0::step].count(key) != n:
        return None
    del words[0::step]
    return words


def _join_continued(lines):
    """Join lines ending in a backslash with the next; keep the numbering (blank placeholders)."""
    out, held = [], []
    for line in lines:
        if line.endswith(b"\\"):
            held.append(line[:-1])
            out.append(b"")
            continue
        if held:
            out[len(out) - len(held)] = b" ".join(held + [line])
            held = []
            out.append(b"")
        else:
            out.append(line)
    if held:
        out[len(out) - len(held)] = b" ".join(held)
    return out


def _obj_numbers(rows, path, key, allowed, expected):
    """(len(rows), min(allowed)) float64 from ``key`` statements with ``allowed`` numbers each."""
    width = min(allowed)
    if not rows:
        return np.zeros((0, width))
    sizes = [len(t) - 1 for _, t in rows]
    for (lineno, _), size in zip(rows, sizes):
        if size not in allowed:
            raise MeshFormatError(f"{path}, line {lineno}: '{key}' line has {size} numbers; expected "
                                  f"'{key} {expected}'")
    flat = [x for _, t in rows for x in t[1:]]
    starts = np.cumsum([0] + sizes)

    def where(i):
        return f"{path}, line {rows[int(np.searchsorted(starts, i, side='right')) - 1][0]}"

    values = _floats(flat, where)
    if len(set(sizes)) == 1:
        return values.reshape(len(rows), -1)[:, :width]
    return np.stack([values[s:s + width] for s in starts[:-1]])


def _obj_faces(corners, counts, face_lines, seen, n_vertices, path):
    """Vertex and texture indices of face corners; see :func:`_parse_obj`.

    ``corners`` are the corner tokens of all faces in order, ``counts`` (f,) corners per
    face, ``face_lines`` (f,) their line numbers, ``seen`` (f,) the number of ``v`` lines
    before each face (for relative indices), ``n_vertices`` the number of ``v`` lines.
    """
    empty = np.zeros(0, dtype=np.int64)
    if not counts.size:
        return {"corners": empty, "texcoords": empty, "counts": empty, "lines": empty}
    line_of = np.repeat(face_lines, counts)
    joined = b" ".join(corners)

    def where(i):
        return f"{path}, line {line_of[i]}"

    raw = None if b"/" in joined else _plain_ints(corners, joined)  # the common case: 'f a b c'
    has_tex = np.zeros(len(corners), dtype=bool)
    if raw is None:
        if _CORNERS_RE.fullmatch(joined) is None:
            i = _first_bad(corners, _CORNER_RE)
            raise MeshFormatError(f"{path}, line {line_of[i]}: cannot read face corner {_show(corners[i])}; "
                                  f"expected 'a', 'a/t', 'a//n' or 'a/t/n' with whole numbers (1-based)")
        groups = _CORNER_FIND_RE.findall(joined)
        raw = _ints([g[0] for g in groups], where)
        texts = [g[1] or g[2] for g in groups]
        has_tex = np.array([t != b"" for t in texts], dtype=bool)
    tex = np.zeros(len(corners), dtype=np.int64)
    if has_tex.any():
        present = np.flatnonzero(has_tex)
        tex[present] = _ints([texts[i] for i in present], lambda i: where(present[i]))
        if (tex[present] == 0).any():
            i = int(present[np.flatnonzero(tex[present] == 0)[0]])
            raise MeshFormatError(f"{path}, line {line_of[i]}: face corner {_show(corners[i])} has texture "
                                  f"index 0 (OBJ indices start at 1)")
    seen = np.repeat(seen, counts)
    index = np.where(raw > 0, raw - 1, seen + raw)
    for bad, why in (
        (raw == 0, "index 0 (OBJ indices start at 1)"),
        ((raw < 0) & (index < 0), "a relative (negative) index reaching before the first vertex"),
        (raw > n_vertices, f"a vertex beyond the file's {n_vertices} 'v' lines"),
    ):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            error = MeshError if raw[i] > n_vertices else MeshFormatError
            raise error(f"{path}, line {line_of[i]}: face corner {_show(corners[i])} refers to {why}")
    tex = np.where(~has_tex, -1, np.where(tex > 0, tex - 1, -2))  # -1: none; -2: relative
    return {"corners": index, "texcoords": tex, "counts": counts, "lines": face_lines}


def _read_obj(data, path):
    """``(V, F)`` of an OBJ file (polygons fan-triangulated); see :func:`read_mesh`."""
    obj = _parse_obj(data, path)
    if not obj["v"].shape[0] and not obj["counts"].size:
        raise MeshFormatError(f"{path} contains no mesh (no 'v' or 'f' lines); is it really an OBJ file?")
    if not obj["counts"].size:
        raise MeshFormatError(f"{path} has no triangle faces (no 'f' lines); a triangle mesh is required")
    return obj["v"], _fan(obj["corners"], obj["counts"], obj["v"], path)


def read_obj_uv(path):
    """Read an OBJ mesh and its UV map (``vt``) as one map position per vertex.

    The file is read as :func:`read_mesh` reads it; the UV of a vertex is the ``vt`` of its
    face corners, which must all carry a texture index and agree on the vertex's position
    bit for bit (one ``vt`` per vertex, or per corner where they agree).  A map cut along
    seams (a vertex with two different UVs) is refused: it is not a map of this mesh.

    Returns
    -------
    V : (n, 3) float64;  F : (m, 3) int64;  UV : (n, 2) float64.

    Raises
    ------
    MeshFormatError
        No ``vt`` lines, a corner without a texture index, a relative or out-of-range
        texture index, a vertex used by no face, or a vertex with two different UVs.
    """
    path = _existing_file(path, "OBJ file")
    if path.suffix.lower() != ".obj":
        raise MeshFormatError(f"{path}: a UV start map is read from an OBJ file's 'vt' lines; got "
                              f"{path.suffix!r}")
    _check_not_empty(path, "OBJ file")
    with _gc_paused():
        obj = _parse_obj(_read_bytes(path, "OBJ file"), path, with_uv=True)
    if not obj["counts"].size:
        raise MeshFormatError(f"{path} has no triangle faces (no 'f' lines); a triangle mesh is required")
    V, vt, corner, tex = obj["v"], obj["vt"], obj["corners"], obj["texcoords"]
    if not vt.shape[0]:
        raise MeshFormatError(f"{path} has no 'vt' lines: it carries no UV map to start from")
    lines = np.repeat(obj["lines"], obj["counts"])
    for bad, why in ((tex == -1, "has no texture index (write corners as 'a/t')"),
                     (tex == -2, "has a relative (negative) texture index"),
                     (tex >= vt.shape[0], f"refers to a 'vt' beyond the file's {vt.shape[0]}")):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise MeshFormatError(f"{path}, line {lines[i]}: a face corner {why}")
    UV = np.full((V.shape[0], 2), np.nan)
    UV[corner] = vt[tex]
    differ = np.flatnonzero((vt[tex].view(np.uint64) != UV[corner].view(np.uint64)).any(axis=1))
    if differ.size:
        v = int(corner[differ[0]])
        raise MeshFormatError(
            f"{path}: vertex {v + 1} has two different UVs (line {lines[differ[0]]}; {np.unique(corner[differ]).size} "
            f"vertices in all): the UV map is cut along seams, so it is not one map of this mesh; "
            f"weld the seams or start from --init tutte / projection")
    unused = np.flatnonzero(np.isnan(UV[:, 0]))
    if unused.size:
        raise MeshFormatError(f"{path}: {unused.size} vertices are used by no face (first: {unused[0] + 1}); "
                              f"remove unreferenced vertices")
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    F = validate_simplices(_fan(corner, obj["counts"], V, path), V.shape[0], 3, f"{path.name}: faces")
    return V, F, validate_vertices(UV, f"{path.name}: UV map", dim=2)


# ------------------------------------------------------------------------- OFF

_OFF_KEYWORD_RE = re.compile(rb"(ST)?(C)?(N)?(4)?(n)?OFF")


def _read_off(data, path):
    """``(V, F)`` of an ASCII OFF file whose counts match its body; see :func:`read_mesh`."""
    rows = _rows(_text_data(data, path, "OFF file").split(b"\n"))
    if not rows:
        raise MeshFormatError(f"{path} contains no mesh (only comments or blank lines)")
    lineno, tokens = rows[0]
    keyword = _OFF_KEYWORD_RE.fullmatch(tokens[0])
    if keyword is None:
        raise MeshFormatError(f"{path}, line {lineno}: an OFF file must start with the keyword 'OFF' "
                              f"(or COFF, NOFF, STOFF ...), found {_show(tokens[0])}")
    st, colour, normal, four, ndim = keyword.groups()
    if four or ndim:
        raise MeshFormatError(f"{path}: {_show(tokens[0])} files (4D or n-dimensional vertices) are not "
                              f"supported; a 3D triangle mesh is required")
    rest, at = tokens[1:], 1
    if rest and rest[0].upper() == b"BINARY":
        raise MeshFormatError(f"{path}: binary OFF is not supported; save it as ASCII OFF, OBJ or PLY")
    if not rest:  # the counts are on the next line
        if len(rows) < 2:
            raise MeshFormatError(f"{path} ends after the OFF keyword; the vertex and face counts are missing")
        lineno, rest = rows[1]
        at = 2
    if len(rest) not in (2, 3):
        raise MeshFormatError(f"{path}, line {lineno}: expected the counts 'vertices faces edges', found "
                              f"{len(rest)} values")
    nv, nf = (int(x) for x in _ints(rest, lambda i: f"{path}, line {lineno}")[:2])
    if nv < 0 or nf < 0:
        raise MeshFormatError(f"{path}, line {lineno}: negative vertex or face count")
    vrows, frows = rows[at:at + nv], rows[at + nv:at + nv + nf]
    if len(vrows) < nv or len(frows) < nf:
        raise MeshFormatError(
            f"{path}: the header (line {lineno}) declares {nv} vertices and {nf} faces, but the file ends "
            f"after {len(vrows)} vertex line(s) and {len(frows)} face line(s); fix the counts or the "
            f"truncated file")
    if len(rows) > at + nv + nf:
        extra = rows[at + nv + nf][0]
        raise MeshFormatError(
            f"{path}: the header (line {lineno}) declares {nv} vertices and {nf} faces, but the file holds "
            f"more (line {extra}); fix the counts (an extra face would otherwise be dropped)")
    if nf == 0:
        raise MeshFormatError(f"{path} has no triangle faces (the header declares 0 faces)")
    widths = {3 + (3 if normal else 0) + c + (2 if st else 0) for c in ((3, 4) if colour else (0,))}
    expected = " or ".join(map(str, sorted(widths)))
    V = _off_vertices(vrows, widths, expected, path)
    return V, _off_faces(frows, path, V)


def _off_vertices(rows, widths, expected, path):
    for lineno, tokens in rows:
        if len(tokens) not in widths:
            raise MeshFormatError(f"{path}, line {lineno}: vertex line has {len(tokens)} numbers; expected "
                                  f"{expected} (one vertex per line, as the header declares)")
    flat = [x for _, t in rows for x in t[:3]]
    return _floats(flat, lambda i: f"{path}, line {rows[i // 3][0]}").reshape(-1, 3)


def _off_faces(rows, path, V=None):
    sizes = [len(t) for _, t in rows]
    heads = _ints([t[0] for _, t in rows], lambda i: f"{path}, line {rows[i][0]}")
    for (lineno, tokens), k, size in zip(rows, heads.tolist(), sizes):
        if k < 3:
            raise MeshFormatError(f"{path}, line {lineno}: face with {k} vertices; a face needs at least 3")
        if not k + 1 <= size <= k + 5:
            raise MeshFormatError(
                f"{path}, line {lineno}: face line declares {k} vertices but holds {size - 1} values; "
                f"expected {k} indices and at most 4 colour numbers")
    corners = [x for (_, t), k in zip(rows, heads.tolist()) for x in t[1:k + 1]]
    owner = np.repeat(np.arange(len(rows)), heads)
    index = _ints(corners, lambda i: f"{path}, line {rows[owner[i]][0]}")
    colours = [x for (_, t), k in zip(rows, heads.tolist()) for x in t[k + 1:]]
    if colours:
        owner = np.repeat(np.arange(len(rows)), np.array(sizes) - 1 - heads)
        _floats(colours, lambda i: f"{path}, line {rows[owner[i]][0]} (face colour)")
    return _fan(index, heads, V, path)


# ------------------------------------------------------------------------- PLY

_PLY_TYPES = {b"char": "i1", b"int8": "i1", b"uchar": "u1", b"uint8": "u1", b"short": "i2", b"int16": "i2",
              b"ushort": "u2", b"uint16": "u2", b"int": "i4", b"int32": "i4", b"uint": "u4", b"uint32": "u4",
              b"float": "f4", b"float32": "f4", b"double": "f8", b"float64": "f8"}
_PLY_FORMATS = {b"ascii": None, b"binary_little_endian": "<", b"binary_big_endian": ">"}


def _ply_header(data, path):
    """Parse a PLY header: ``(byte order or None for ASCII, elements, body offset)``.

    ``elements`` is a list of ``(name, count, properties, lineno)``; a property is
    ``(name, dtype)`` or ``(name, count dtype, item dtype)`` for a list (dtypes as numpy
    codes without byte order).
    """
    if data.startswith(_UTF8_BOM):
        data = data[len(_UTF8_BOM):]
        skipped = len(_UTF8_BOM)
    else:
        skipped = 0
    if not data.startswith((b"ply\n", b"ply\r\n")):
        raise MeshFormatError(f"{path} does not start with the line 'ply'; it is not a PLY file")
    end = re.search(rb"(?m)^end_header[ \t]*\r?(?:\n|\Z)", data)
    if end is None:
        raise MeshFormatError(f"{path}: the PLY header has no 'end_header' line; the file is truncated "
                              f"or not PLY")
    order, elements, names = "missing", [], set()
    for lineno, line in enumerate(data[:end.start()].split(b"\n")[1:], 2):
        tokens = line.split()
        if not tokens or tokens[0] in (b"comment", b"obj_info"):
            continue
        key = tokens[0]
        if key == b"format":
            if len(tokens) != 3 or tokens[1] not in _PLY_FORMATS or tokens[2] != b"1.0":
                raise MeshFormatError(f"{path}, line {lineno}: unsupported PLY format line {_show(line.strip())}; "
                                      f"expected 'format ascii|binary_little_endian|binary_big_endian 1.0'")
            order = _PLY_FORMATS[tokens[1]]
        elif key == b"element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise MeshFormatError(f"{path}, line {lineno}: malformed element line {_show(line.strip())}; "
                                      f"expected 'element NAME COUNT'")
            if tokens[1] in names:
                raise MeshFormatError(f"{path}, line {lineno}: element {_show(tokens[1])} is declared twice")
            names.add(tokens[1])
            elements.append((tokens[1], int(tokens[2]), [], lineno))
        elif key == b"property":
            if not elements:
                raise MeshFormatError(f"{path}, line {lineno}: property declared before any element")
            props = elements[-1][2]
            if len(tokens) == 3 and tokens[1] in _PLY_TYPES:
                prop = (tokens[2], _PLY_TYPES[tokens[1]])
            elif (len(tokens) == 5 and tokens[1] == b"list" and tokens[2] in _PLY_TYPES
                  and tokens[3] in _PLY_TYPES and _PLY_TYPES[tokens[2]][0] in "iu"):
                prop = (tokens[4], _PLY_TYPES[tokens[2]], _PLY_TYPES[tokens[3]])
            else:
                raise MeshFormatError(
                    f"{path}, line {lineno}: malformed or unsupported property line {_show(line.strip())}; "
                    f"expected 'property TYPE NAME' or 'property list COUNT_TYPE ITEM_TYPE NAME' "
                    f"(types: {', '.join(t.decode() for t in _PLY_TYPES)}; a list count must be an integer type)")
            if any(p[0] == prop[0] for p in props):
                raise MeshFormatError(f"{path}, line {lineno}: property {_show(prop[0])} is declared twice")
            props.append(prop)
        else:
            raise MeshFormatError(f"{path}, line {lineno}: unknown PLY header line {_show(line.strip())}")
    if order == "missing":
        raise MeshFormatError(f"{path}: the PLY header has no 'format' line")
    return order, elements, skipped + end.end()


def _read_ply(data, path):
    """``(V, F)`` of an ASCII or binary PLY file, its body checked against the header; see :func:`read_mesh`."""
    order, elements, offset = _ply_header(data, path)
    found = {}
    body = data[offset:]
    if order is None:
        if b"\x00" in body or _UTF8_BOM in body:
            raise MeshFormatError(f"{path}: the header says 'format ascii' but the body holds binary data "
                                  f"(NUL bytes or a byte-order mark)")
        rows = _rows(_text_data(body, path, "PLY file").split(b"\n"), comment=None)
        header_lines = data[:offset].count(b"\n")
        rows = [(lineno + header_lines, tokens) for lineno, tokens in rows]
        at = 0
        for name, count, props, _ in elements:
            found[name] = _ply_ascii_element(rows[at:at + count], name, count, props, path)
            at += count
        if len(rows) > at:
            raise MeshFormatError(f"{path}, line {rows[at][0]}: the PLY body holds more lines than the header "
                                  f"declares ({sum(e[1] for e in elements)} element lines); fix the counts")
    else:
        at = 0
        for name, count, props, _ in elements:
            found[name], at = _ply_binary_element(body, at, name, count, props, order, path)
        if at != len(body):
            raise MeshFormatError(f"{path}: the binary PLY body is {len(body) - at} bytes longer than the "
                                  f"header's elements; fix the counts (or the file has trailing data)")
    return _ply_mesh(found, elements, path)


def _ply_ascii_element(rows, name, count, props, path):
    """Columns of ``count`` ASCII element lines: ``{property: array}`` (lists: ``(counts, flat items)``)."""
    what = f"element {_show(name)}"
    if len(rows) < count:
        raise MeshFormatError(f"{path}: the header declares {count} {what} lines but the body ends after "
                              f"{len(rows)}; the file is truncated or the count is wrong")
    if not rows:
        return {}
    if len(props) == 1 and len(props[0]) == 3 and all(len(t) == 4 and t[0] == b"3" for _, t in rows):
        name_, count_code, item_code = props[0]  # the common case: triangles only
        items = [x for _, t in rows for x in t[1:]]
        return {name_: (np.full(len(rows), 3, dtype=np.int64),
                        _ply_ascii_values(items, item_code, [r for r in rows for _ in range(3)], path))}
    if not any(len(p) == 3 for p in props):
        width = len(props)
        for lineno, tokens in rows:
            if len(tokens) != width:
                raise MeshFormatError(f"{path}, line {lineno}: {what} line has {len(tokens)} values; the "
                                      f"header declares {width} properties")
        table = [[t[j] for _, t in rows] for j in range(width)]
        return {p[0]: _ply_ascii_values(col, p[1], rows, path) for p, col in zip(props, table)}
    columns = {p[0]: [] for p in props}
    lists = {p[0]: [] for p in props if len(p) == 3}
    for lineno, tokens in rows:
        j = 0
        for p in props:
            if len(p) == 3:
                if j >= len(tokens) or not _INT_RE.fullmatch(tokens[j]):
                    raise MeshFormatError(f"{path}, line {lineno}: {what} line is missing the count of "
                                          f"list {_show(p[0])} (or it is not an integer)")
                k = int(tokens[j])
                if k < 0 or j + 1 + k > len(tokens):
                    raise MeshFormatError(f"{path}, line {lineno}: list {_show(p[0])} declares {k} items but "
                                          f"the line holds {max(len(tokens) - j - 1, 0)} more values")
                columns[p[0]].append(tokens[j])
                lists[p[0]].extend(tokens[j + 1:j + 1 + k])
                j += 1 + k
            else:
                if j >= len(tokens):
                    raise MeshFormatError(f"{path}, line {lineno}: {what} line has too few values for its "
                                          f"properties")
                columns[p[0]].append(tokens[j])
                j += 1
        if j != len(tokens):
            raise MeshFormatError(f"{path}, line {lineno}: {what} line has {len(tokens) - j} value(s) more than "
                                  f"its properties declare")
    out = {}
    for p in props:
        if len(p) == 3:
            counts = _ply_ascii_values(columns[p[0]], p[1], None, path)
            out[p[0]] = (counts, _ply_ascii_values(lists[p[0]], p[2], None, path))
        else:
            out[p[0]] = _ply_ascii_values(columns[p[0]], p[1], None, path)
    return out


def _ply_ascii_values(tokens, code, rows, path):
    """Tokens of one declared PLY type as an array of that type (range-checked for integers)."""
    def where(i):
        return f"{path}, line {rows[i][0]}" if rows is not None else f"{path} (PLY body)"

    if code[0] == "f":
        values = _floats(tokens, where)
        with np.errstate(over="ignore"):
            narrow = values.astype(code)  # 'float' properties are float32, as declared
        bad = np.flatnonzero(np.isfinite(values) & ~np.isfinite(narrow))
        if bad.size:
            raise MeshFormatError(f"{where(int(bad[0]))}: the value {_show(tokens[bad[0]])} does not fit the "
                                  f"declared type {np.dtype(code).name}")
        return narrow
    values = _ints(tokens, where)
    info = np.iinfo(code)
    bad = np.flatnonzero((values < info.min) | (values > info.max))
    if bad.size:
        raise MeshFormatError(f"{where(int(bad[0]))}: the value {values[bad[0]]} does not fit the declared "
                              f"type {np.dtype(code).name}")
    return values.astype(code)


def _ply_binary_element(body, at, name, count, props, order, path):
    """Decode ``count`` binary records of an element starting at byte ``at``; return (columns, end)."""
    what = f"element {_show(name)}"

    def short(needed):
        return MeshFormatError(f"{path}: the binary PLY body ends inside {what} (needs at least {needed} more "
                               f"bytes, {len(body) - at} left); the file is truncated or the count is wrong")

    fields = [(p[0].decode("latin-1"), order + p[1]) for p in props if len(p) == 2]
    if all(len(p) == 2 for p in props):
        dtype = np.dtype(fields)
        need = count * dtype.itemsize
        if at + need > len(body):
            raise short(need)
        rec = np.frombuffer(body, dtype, count, at)
        return {p[0]: rec[p[0].decode("latin-1")] for p in props}, at + need
    # records with lists: try "every list has the length of the first record's", else walk record by record
    if count == 0:
        return {}, at
    lengths, pos = [], at
    for p in props:
        size = np.dtype(p[1]).itemsize
        if len(p) == 3:
            if pos + size > len(body):
                raise short(pos + size - at)
            k = int(np.frombuffer(body, order + p[1], 1, pos)[0])
            lengths.append(k)
            pos += size + max(k, 0) * np.dtype(p[2]).itemsize
        else:
            pos += size
    layout, li = [], 0
    for j, p in enumerate(props):
        if len(p) == 3:
            layout += [(f"n{j}", order + p[1]), (f"l{j}", order + p[2], (max(lengths[li], 0),))]
            li += 1
        else:
            layout.append((f"s{j}", order + p[1]))
    dtype = np.dtype(layout)
    if min(lengths) >= 0 and at + count * dtype.itemsize <= len(body):
        rec = np.frombuffer(body, dtype, count, at)
        uniform = all((rec[f"n{j}"] == rec[f"n{j}"][0]).all() for j, p in enumerate(props) if len(p) == 3)
        if uniform:
            out = {}
            for j, p in enumerate(props):
                if len(p) == 3:
                    out[p[0]] = (rec[f"n{j}"].astype(np.int64), rec[f"l{j}"].reshape(-1))
                else:
                    out[p[0]] = rec[f"s{j}"]
            return out, at + count * dtype.itemsize
    columns = {p[0]: [] for p in props}
    items = {p[0]: [] for p in props if len(p) == 3}
    pos = at
    for _ in range(count):
        for p in props:
            size = np.dtype(p[1]).itemsize
            if pos + size > len(body):
                raise short(pos + size - at)
            value = np.frombuffer(body, order + p[1], 1, pos)[0]
            pos += size
            columns[p[0]].append(value)
            if len(p) == 3:
                k = int(value)
                if k < 0:
                    raise MeshFormatError(f"{path}: list {_show(p[0])} of {what} has a negative length {k}")
                isize = np.dtype(p[2]).itemsize
                if pos + k * isize > len(body):
                    raise short(pos + k * isize - at)
                items[p[0]].append(np.frombuffer(body, order + p[2], k, pos))
                pos += k * isize
    out = {}
    for p in props:
        column = np.array(columns[p[0]], dtype=p[1])
        if len(p) == 3:
            flat = np.concatenate(items[p[0]]) if items[p[0]] else np.zeros(0, p[2])
            out[p[0]] = (column.astype(np.int64), flat)
        else:
            out[p[0]] = column
    return out, pos


def _ply_mesh(found, elements, path):
    """``(V, F)`` from the decoded PLY elements ``vertex`` (x, y, z) and ``face`` (vertex_indices)."""
    declared = {e[0]: e for e in elements}
    if b"vertex" not in declared:
        raise MeshFormatError(f"{path} has no 'vertex' element; it holds no mesh")
    vprops = {p[0]: p for p in declared[b"vertex"][2]}
    for axis in (b"x", b"y", b"z"):
        if axis not in vprops or len(vprops[axis]) == 3:
            raise MeshFormatError(f"{path}: element 'vertex' has no scalar property {axis.decode()!r}; "
                                  f"vertex positions x, y, z are required")
    nv = declared[b"vertex"][1]
    V = (np.stack([np.asarray(found[b"vertex"][a], dtype=np.float64) for a in (b"x", b"y", b"z")], axis=1)
         if nv else np.zeros((0, 3)))
    if b"face" not in declared or declared[b"face"][1] == 0:
        raise MeshFormatError(f"{path} has no triangle faces (no 'face' elements); a triangle mesh is required")
    fprops = {p[0]: p for p in declared[b"face"][2]}
    key = next((k for k in (b"vertex_indices", b"vertex_index") if k in fprops), None)
    if key is None or len(fprops[key]) != 3 or fprops[key][2][0] not in "iu":
        raise MeshFormatError(f"{path}: element 'face' has no integer list property 'vertex_indices' "
                              f"(or 'vertex_index')")
    counts, flat = found[b"face"][key]
    if (counts < 3).any():
        i = int(np.flatnonzero(counts < 3)[0])
        raise MeshFormatError(f"{path}: face {i} has {counts[i]} vertices; a face needs at least 3 (in a "
                              f"binary file this is also what element counts that do not match the body give)")
    return V, _fan(flat.astype(np.int64), counts, V, path)


# ------------------------------------------------------------------------- STL

_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def _read_stl(data, path):
    """``(V, F)`` of an ASCII or binary STL file, corners welded by equal coordinates."""
    binary_size = 84 + 50 * int.from_bytes(data[80:84], "little") if len(data) >= 84 else None
    text = data.removeprefix(_UTF8_BOM)
    looks_ascii = text.lstrip()[:5].lower() == b"solid" and not any(
        b < 9 or 13 < b < 32 or b == 127 for b in text[:1000])
    if len(data) == binary_size and not looks_ascii:
        count = (len(data) - 84) // 50
        if count == 0:
            raise MeshFormatError(f"{path} is a binary STL with 0 triangles; a triangle mesh is required")
        corners = np.frombuffer(data, _STL_RECORD, count, 84)["corners"].reshape(-1, 3)
        return _weld(corners.astype(np.float64))
    if looks_ascii:
        return _weld(_stl_ascii_corners(data, path))
    # many binary STL headers begin with 'solid' too: then it is the binary bytes that rule out ASCII
    not_ascii = ("it starts with 'solid' but holds binary bytes" if text.lstrip()[:5].lower() == b"solid"
                 else "it does not start with 'solid'")
    if binary_size is None:
        raise MeshFormatError(f"{path} is too short ({len(data)} bytes) for a binary STL and is not ASCII STL "
                              f"({not_ascii}); it is not an STL file")
    raise MeshFormatError(
        f"{path} is not ASCII STL ({not_ascii}) and not a valid binary STL: its header "
        f"declares {(binary_size - 84) // 50} triangles = {binary_size} bytes, but the file has {len(data)} "
        f"bytes (truncated, or trailing data)")


def _stl_ascii_corners(data, path):
    """(3m, 3) float64 corner positions of an ASCII STL with exactly one solid."""
    lines = _text_data(data, path, "STL file").split(b"\n")
    rows = [(i, line.split()) for i, line in enumerate(lines, 1) if line.strip()]
    first, tokens = rows[0]
    if tokens[0].lower() != b"solid":
        raise MeshFormatError(f"{path}, line {first}: an ASCII STL must start with 'solid'")
    ends = [j for j, (_, t) in enumerate(rows) if t[0].lower() == b"endsolid"]
    if not ends:
        raise MeshFormatError(f"{path}: no 'endsolid' line; the file is truncated")
    end = ends[0]
    if end + 1 < len(rows):
        lineno, t = rows[end + 1]
        if t[0].lower() == b"solid":
            solids = sum(r[1][0].lower() == b"solid" for r in rows)
            raise MeshFormatError(f"{path} contains {solids} separate meshes ('solid' blocks, the second at line "
                                  f"{lineno}); merge them into one solid before reading it")
        raise MeshFormatError(f"{path}, line {lineno}: data after 'endsolid'; remove it")
    body = rows[1:end]
    pattern = ((b"facet", b"normal", 3), (b"outer", b"loop", 0), (b"vertex", None, 3), (b"vertex", None, 3),
               (b"vertex", None, 3), (b"endloop", None, 0), (b"endfacet", None, 0))
    for j, (lineno, t) in enumerate(body):
        key, word, numbers = pattern[j % 7]
        head = [key] if word is None else [key, word]
        if [x.lower() for x in t[:len(head)]] != head or len(t) != len(head) + numbers:
            raise MeshFormatError(f"{path}, line {lineno}: expected '{b' '.join(head).decode()}"
                                  f"{' x y z' if numbers else ''}', found {_show(b' '.join(t))}")
    if len(body) % 7:
        raise MeshFormatError(f"{path}, line {rows[end][0]}: 'endsolid' inside an unfinished facet; the file is "
                              f"truncated")
    if not body:
        raise MeshFormatError(f"{path} has no facets; a triangle mesh is required")
    normals = [x for _, t in body[0::7] for x in t[2:]]
    _floats(normals, lambda i: f"{path}, line {body[7 * (i // 3)][0]}")
    verts = [r for j, r in enumerate(body) if j % 7 in (2, 3, 4)]
    flat = [x for _, t in verts for x in t[1:]]
    return _floats(flat, lambda i: f"{path}, line {verts[i // 3][0]}").reshape(-1, 3)


def _weld(corners):
    """Merge corners with equal coordinates (-0.0 = +0.0): ``(V (n, 3), F (m, 3))``, vertices in
    first-seen order with the first corner's exact bits."""
    corners = np.ascontiguousarray(corners, dtype=np.float64)
    equal = corners + 0.0  # -0.0 + 0.0 = +0.0: equal corners weld; a vertex keeps its first corner's bits
    keys = equal.view(np.dtype((np.void, corners.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return corners[first[order]], rank[inverse.ravel()].reshape(-1, 3).astype(np.int64)


# ------------------------------------------------------------------- mesh with UV


def _mesh_with_uv(V, F, UV):
    """Validated ``(V (n,3), F (m,3), UV (n,2))`` for the writers."""
    V = validate_vertices(V, "V", dim=3)
    UV = validate_vertices(UV, "UV", dim=2)
    if UV.shape[0] != V.shape[0]:
        raise MeshError(f"UV has {UV.shape[0]} rows but V has {V.shape[0]}; give one UV per vertex")
    return V, validate_simplices(F, V.shape[0], 3, "F"), UV


def write_mesh_with_uv(path, V, F, UV, format=None):
    """Write a mesh and a per-vertex map in the format ``path``'s extension names (see :data:`UV_MESH_EXTENSIONS`).

    ``.obj``: :func:`write_obj_with_uv`; ``.ply``: :func:`write_ply_with_uv`.  Both keep
    every ``float64`` bit.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file, ``.obj`` or ``.ply`` (any case) unless ``format`` is given.
    V : array_like, shape (n, 3)
        Vertex positions.
    F : array_like, shape (m, 3), integer
        Triangles, 0-based.
    UV : array_like, shape (n, 2)
        Map coordinates, one per vertex.
    format : {None, "obj", "ply"}
        The format, when ``path``'s extension does not say it (e.g. a temporary file from
        :func:`atomic_path`).  Case is ignored.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    GeomoptError
        Another extension or format (the message lists the supported ones), or ``path``
        cannot be written.
    MeshError
        Invalid ``V``, ``F`` or ``UV``.
    """
    if format is None:
        path = check_output_path(path, UV_MESH_EXTENSIONS)
        format = path.suffix[1:]
    writers = {"obj": write_obj_with_uv, "ply": write_ply_with_uv}
    if format.lower() not in writers:
        raise GeomoptError(f"cannot write a mesh with a map as {format!r}; supported: {', '.join(writers)}")
    return writers[format.lower()](path, V, F, UV)


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
    V, F, UV = _mesh_with_uv(V, F, UV)

    def write(fh):
        _write_rows(fh, "v ", V)
        _write_rows(fh, "vt ", UV)
        np.savetxt(fh, np.repeat(F + 1, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")

    return atomic_write(path, write)


def write_ply_with_uv(path, V, F, UV):
    """Write a mesh and a per-vertex map as binary little-endian PLY, all coordinates ``float64``.

    Element ``vertex`` has the ``double`` properties ``x y z u v`` (the map as the texture
    coordinates ``u v``, which MeshLab, Blender and trimesh read); element ``face`` has
    ``list uchar int vertex_indices``.  Every bit round-trips (:func:`read_mesh` reads
    ``x y z`` back exactly).  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    V : array_like, shape (n, 3)
        Vertex positions.
    F : array_like, shape (m, 3), integer
        Triangles, 0-based; ``n`` must be below 2**31 (the indices are ``int``).
    UV : array_like, shape (n, 2)
        Map coordinates, one per vertex.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Invalid ``V``, ``F`` or ``UV``, or too many vertices for 32-bit indices.
    """
    V, F, UV = _mesh_with_uv(V, F, UV)
    if V.shape[0] >= 2**31:
        raise MeshError(f"{V.shape[0]} vertices do not fit PLY's 32-bit indices; write OBJ instead")
    vertex = np.empty(V.shape[0], np.dtype([(c, "<f8") for c in "xyzuv"]))
    for j, c in enumerate("xyz"):
        vertex[c] = V[:, j]
    vertex["u"], vertex["v"] = UV[:, 0], UV[:, 1]
    face = np.empty(F.shape[0], np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    face["n"], face["i"] = 3, F
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by geomopt: positions x y z, map u v\n"
        f"element vertex {V.shape[0]}\n" + "".join(f"property double {c}\n" for c in "xyzuv")
        + f"element face {F.shape[0]}\nproperty list uchar int vertex_indices\nend_header\n"
    )

    def write(fh):
        fh.write(header.encode("ascii"))
        fh.write(vertex.tobytes())
        fh.write(face.tobytes())

    return atomic_write(path, write, mode="wb")


# ------------------------------------------------------------------------ LIM 2D


def read_lim2d(folder):
    """Read a 2D LIM benchmark case: ``input.obj`` (rest + initial map) and ``handles.txt``.

    ``input.obj`` is read as in :func:`read_mesh` (same statements, numbers and text
    conventions), plus: exactly one ``vt u v`` (initial map) per ``v`` line, in the same
    order; ``f`` lines with exactly 3 corners ``a``, ``a/a``, ``a/a/n`` or ``a//n``
    (1-based, absolute: a texture index must equal its vertex index).
    ``handles.txt`` holds 0-based vertex ids (plain decimal integers) separated by
    whitespace (any line ends); an empty file means no fixed vertex.

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
        Missing file (named), malformed statement or number (with line number),
        non-triangle or relative (negative) face, ``vt`` count differing from ``v`` count,
        texture index differing from vertex index, malformed handle id.
    MeshError
        Non-finite values, face indices out of range, repeated vertices in a face,
        handles out of range or repeated.
    """
    folder = Path(folder)
    obj_path, handles_path = folder / "input.obj", folder / "handles.txt"
    for p in (obj_path, handles_path):
        if not p.exists():
            raise MeshFormatError(f"2D LIM case {folder} has no {p.name}; expected input.obj and handles.txt")
    rest, init, faces = parse_lim_obj(obj_path)
    n = rest.shape[0]
    return {
        "rest": validate_vertices(rest, f"{obj_path}: 'v' positions", dim=3),
        "init": validate_vertices(init, f"{obj_path}: 'vt' positions", dim=2),
        "faces": validate_simplices(faces, n, 3, f"{obj_path}: faces"),
        "handles": _read_handles(handles_path, n),
        "handles_file": handles_path,
    }


def parse_lim_obj(path):
    """A LIM ``input.obj``: ``(rest (n, 3), init (n, 2), faces (m, 3))`` as read, not yet validated."""
    path = _existing_file(path, "OBJ file")
    _check_not_empty(path, "OBJ file")
    with _gc_paused():
        obj = _parse_obj(_read_bytes(path, "OBJ file"), path, with_uv=True)
    V, UV, counts, lines = obj["v"], obj["vt"], obj["counts"], obj["lines"]
    if not V.shape[0]:
        raise MeshFormatError(f"{path} has no 'v' lines; it is not a LIM input.obj")
    if not counts.size:
        raise MeshFormatError(f"{path} has no 'f' lines; a triangle mesh is required")
    if (counts != 3).any():
        i = int(np.flatnonzero(counts != 3)[0])
        raise MeshFormatError(f"{path}, line {lines[i]}: face has {counts[i]} corners; only triangles are "
                              f"supported (triangulate the mesh first)")
    face_lines = np.repeat(lines, 3)
    raw = obj["corners"]
    tex = obj["texcoords"]
    if (tex == -2).any():
        i = int(np.flatnonzero(tex == -2)[0])
        raise MeshFormatError(f"{path}, line {face_lines[i]}: a relative (negative) texture index; a LIM "
                              f"input.obj needs texture index == vertex index")
    bad = np.flatnonzero((tex >= 0) & (tex != raw))
    if bad.size:
        i = int(bad[0])
        raise MeshFormatError(f"{path}, line {face_lines[i]}: face corner uses texture index {tex[i] + 1} for "
                              f"vertex {raw[i] + 1}; a LIM input.obj needs texture index == vertex index")
    if UV.shape[0] != V.shape[0]:
        raise MeshFormatError(
            f"{path} has {V.shape[0]} 'v' lines but {UV.shape[0]} 'vt' lines; a LIM input.obj "
            f"needs exactly one 'vt' (initial map position) per vertex"
        )
    return V, UV, raw.reshape(-1, 3)


def _read_handles(path, n_vertices):
    """0-based vertex ids from a whitespace-separated text file; empty file -> no handles."""
    path = _existing_file(path, "handles file")
    data = _text_data(_read_bytes(path, "handles file"), path, "handles file")
    rows = _rows(data.split(b"\n"), comment=None)
    tokens = [t for _, ts in rows for t in ts]
    owner = [lineno for lineno, ts in rows for _ in ts]

    def where(i):
        return f"{path}, line {owner[i]}"

    bad = _first_bad(tokens, _INT_RE)
    if bad is not None:
        raise MeshFormatError(f"{where(bad)}: {_number_problem(tokens[bad], 'integer')}; a handles file holds "
                              f"0-based vertex ids, one per line")
    ids = _ints(tokens, where)
    return validate_indices(ids, n_vertices, f"{path}: handles")


# ------------------------------------------------------------------------ VTK (public)


def read_vtk_tets(path):
    """Read a tetrahedral mesh from a legacy VTK unstructured-grid file, exactly as declared.

    Parsed here (ASCII or binary, file versions up to 5.1 with ``OFFSETS``/``CONNECTIVITY``):
    the counts of ``POINTS``, ``CELLS`` and ``CELL_TYPES`` must match their data and each
    other; ``METADATA`` and dataset ``FIELD`` blocks are skipped; ``POINT_DATA`` /
    ``CELL_DATA`` sections after the cells are ignored.  Points declared ``float`` are
    float32 (then widened), as VTK reads them; files written by :func:`write_vtk_tets`
    declare ``double`` and round-trip exactly.  Keywords (``POINTS``, ``cells``...) and type
    names are case-insensitive, as in VTK's own reader.  Text conventions as in the module notes.

    Parameters
    ----------
    path : str or os.PathLike
        ``.vtk`` file (legacy format).

    Returns
    -------
    P : numpy.ndarray, shape (n, 3), float64
        Point positions.
    T : numpy.ndarray, shape (m, 4), int64
        Tetrahedra, 0-based point indices (VTK cell type 10), in file order.

    Raises
    ------
    MeshFormatError
        Missing, not a regular file, empty, malformed, counts that differ from the data, no
        points, no cells, or cells other than tetrahedra (the message lists the types found).
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a tet.
    """
    path = _existing_file(path, "VTK file")
    _check_not_empty(path, "VTK file")
    with _gc_paused():
        P, types, sizes, conn = _parse_vtk(_read_bytes(path, "VTK file"), path)
    if len(P) == 0:
        raise MeshFormatError(f"VTK file {path} has no points")
    if types.size == 0:
        raise MeshFormatError(f"VTK file {path} has no cells; a tetrahedral mesh is required")
    others = sorted({_VTK_CELL_NAMES.get(int(t), f"type {int(t)}") for t in np.unique(types[types != 10])})
    if others:
        raise MeshFormatError(
            f"VTK file {path} contains non-tetrahedral cells ({', '.join(others)}); only "
            f"tetrahedral meshes (VTK cell type 10) are supported"
        )
    if (np.asarray(sizes) != 4).any():
        i = int(np.flatnonzero(np.asarray(sizes) != 4)[0])
        raise MeshFormatError(f"VTK file {path}: cell {i} is a tetrahedron (type 10) with {sizes[i]} points")
    P = validate_vertices(P, f"{path.name}: points", dim=3)
    return P, validate_simplices(conn.reshape(-1, 4), P.shape[0], 4, f"{path.name}: tetrahedra")


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


# ------------------------------------------------------------------------ VTK

_VTK_TYPES = {b"UNSIGNED_CHAR": "u1", b"CHAR": "i1", b"UNSIGNED_SHORT": "u2", b"SHORT": "i2",
              b"UNSIGNED_INT": "u4", b"INT": "i4", b"UNSIGNED_LONG": "u8", b"LONG": "i8", b"FLOAT": "f4",
              b"DOUBLE": "f8", b"VTKTYPEINT64": "i8", b"VTKTYPEUINT64": "u8", b"VTKIDTYPE": "i8"}
_VTK_CELL_NAMES = {1: "vertex", 2: "polyvertex", 3: "line", 4: "polyline", 5: "triangle", 6: "triangle strip",
                   7: "polygon", 8: "pixel", 9: "quad", 10: "tetra", 11: "voxel", 12: "hexahedron",
                   13: "wedge", 14: "pyramid"}
_VTK_ATTRIBUTES = (b"POINT_DATA", b"CELL_DATA")


class _VtkCursor:
    """Reads a legacy VTK file section by section: keyword lines, then ASCII tokens or binary blocks."""

    def __init__(self, data, binary, path):
        self.data, self.pos, self.binary, self.path = data, 0, binary, path

    def line(self):
        """Tokens of the next non-blank line (``[]`` at the end of the file)."""
        while self.pos < len(self.data):
            end = self.data.find(b"\n", self.pos)
            end = len(self.data) if end < 0 else end
            tokens = self.data[self.pos:end].split()
            self.pos = end + 1
            if tokens:
                return tokens
        return []

    def peek(self):
        pos, tokens = self.pos, self.line()
        self.pos = pos
        return tokens

    def values(self, count, code, section):
        """``count`` values of numpy type ``code`` (ASCII tokens or big-endian binary)."""
        if self.binary:
            size = count * np.dtype(code).itemsize
            if self.pos + size > len(self.data):
                raise MeshFormatError(f"{self.path}: the file ends inside the {section} section (it declares "
                                      f"{count} values, {size} bytes); the file is truncated or a count is wrong")
            out = np.frombuffer(self.data, ">" + code, count, self.pos).astype(code)
            self.pos += size
            return out
        parts = self.data[self.pos:].split(None, count)
        tokens = parts[:count]
        if len(tokens) < count:
            raise MeshFormatError(f"{self.path}: the {section} section declares {count} values but the file "
                                  f"ends after {len(tokens)}; the file is truncated or a count is wrong")
        self.pos = len(self.data) - (len(parts[count]) if len(parts) > count else 0)
        regex = _FLOAT_RE if code[0] == "f" else _INT_RE
        bad = _first_bad(tokens, regex)
        if bad is not None and re.fullmatch(rb"[A-Za-z_]{2,}", tokens[bad]):  # the next section's keyword
            raise MeshFormatError(f"{self.path}: the {section} section declares {count} values but "
                                  f"{_show(tokens[bad])} follows after {bad}; fix the count")
        where = lambda i: f"{self.path}, {section} section, value {i + 1}"  # noqa: E731
        if code[0] == "f":
            values = _floats(tokens, where)
            with np.errstate(over="ignore"):
                return values.astype(code)
        values = _ints(tokens, where)
        info = np.iinfo(code)
        if values.size and (values.min() < info.min or values.max() > info.max):
            raise MeshFormatError(f"{self.path}: a value of the {section} section does not fit its type "
                                  f"{np.dtype(code).name}")
        return values

    def expect_keyword(self, after):
        """The next line must start a section (not more values of the previous one)."""
        tokens = self.peek()
        if tokens and (_FLOAT_RE.fullmatch(tokens[0]) or _INT_RE.fullmatch(tokens[0])):
            raise MeshFormatError(f"{self.path}: more values follow the {after} section than it declares; "
                                  f"fix the count")


def _vtk_keyword(tokens):
    """A line's first token in upper case (``None`` for no tokens): VTK's own reader compares
    keywords case-insensitively (vtkDataReader lower-cases each keyword before comparing)."""
    return tokens[0].upper() if tokens else None


def _vtk_type(token, cursor, section):
    code = _VTK_TYPES.get(token.upper())
    if code is None:
        raise MeshFormatError(f"{cursor.path}: the {section} section has unsupported data type {_show(token)}")
    return code


def _vtk_count(tokens, i, cursor, section):
    if len(tokens) <= i or not tokens[i].isdigit():
        raise MeshFormatError(f"{cursor.path}: malformed {section} line {_show(b' '.join(tokens))}; expected "
                              f"a count")
    return int(tokens[i])


def _vtk_skip_optional(cursor):
    """Skip METADATA blocks (to the next blank line) and dataset FIELD data."""
    while True:
        tokens = cursor.peek()
        if _vtk_keyword(tokens) == b"METADATA":
            cursor.line()
            while cursor.pos < len(cursor.data):
                end = cursor.data.find(b"\n", cursor.pos)
                end = len(cursor.data) if end < 0 else end
                blank = not cursor.data[cursor.pos:end].strip()
                cursor.pos = end + 1
                if blank:
                    break
        elif _vtk_keyword(tokens) == b"FIELD":
            cursor.line()
            for _ in range(_vtk_count(tokens, 2, cursor, "FIELD")):
                array = cursor.line()
                if len(array) != 4 or not (array[1].isdigit() and array[2].isdigit()):
                    raise MeshFormatError(f"{cursor.path}: malformed FIELD array line "
                                          f"{_show(b' '.join(array))}")
                code = _vtk_type(array[3], cursor, "FIELD")
                cursor.values(int(array[1]) * int(array[2]), code, "FIELD")
        else:
            return


def _parse_vtk(data, path):
    """``(points (n, 3) float64, cell types (c,), cells list-of-arrays or (c, 4) int64)`` of a legacy VTK file."""
    data = data.removeprefix(_UTF8_BOM)
    head = data.split(b"\n", 3)
    if len(head) < 4 or not head[0].strip().lower().startswith(b"# vtk datafile version"):
        raise MeshFormatError(f"{path} does not start with '# vtk DataFile Version ...'; it is not a legacy "
                              f"VTK file")
    mode = head[2].strip().upper()
    if mode not in (b"ASCII", b"BINARY"):
        raise MeshFormatError(f"{path}, line 3: expected ASCII or BINARY, found {_show(head[2].strip())}")
    binary = mode == b"BINARY"
    body = head[3]
    if not binary:
        body = _text_data(body, path, "VTK file")
    cursor = _VtkCursor(body, binary, path)
    tokens = cursor.line()
    if [t.upper() for t in tokens] != [b"DATASET", b"UNSTRUCTURED_GRID"]:
        found = _show(b" ".join(tokens)) if tokens else "nothing"
        raise MeshFormatError(f"{path}: expected 'DATASET UNSTRUCTURED_GRID', found {found}; only unstructured "
                              f"grids (tetrahedral meshes) are supported")
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != b"POINTS" or len(tokens) != 3:
        raise MeshFormatError(f"{path}: expected 'POINTS n type', found "
                              f"{_show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    n = _vtk_count(tokens, 1, cursor, "POINTS")
    points = cursor.values(3 * n, _vtk_type(tokens[2], cursor, "POINTS"), "POINTS").astype(np.float64)
    cursor.expect_keyword("POINTS")
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != b"CELLS" or len(tokens) != 3:
        raise MeshFormatError(f"{path}: expected 'CELLS' after the points, found "
                              f"{_show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    a, b = _vtk_count(tokens, 1, cursor, "CELLS"), _vtk_count(tokens, 2, cursor, "CELLS")
    if _vtk_keyword(cursor.peek()) == b"OFFSETS":  # version 5: offsets + connectivity
        t = cursor.line()
        offsets = cursor.values(a, _vtk_type(t[1] if len(t) > 1 else b"?", cursor, "OFFSETS"), "OFFSETS")
        cursor.expect_keyword("OFFSETS")
        t = cursor.line()
        if _vtk_keyword(t) != b"CONNECTIVITY" or len(t) != 2:
            raise MeshFormatError(f"{path}: expected 'CONNECTIVITY type' after OFFSETS")
        conn = cursor.values(b, _vtk_type(t[1], cursor, "CONNECTIVITY"), "CONNECTIVITY").astype(np.int64)
        offsets = offsets.astype(np.int64)
        if a == 0 or offsets[0] != 0 or offsets[-1] != b or (np.diff(offsets) < 0).any():
            raise MeshFormatError(f"{path}: the OFFSETS must rise from 0 to the connectivity size {b}")
        sizes = np.diff(offsets)
    else:
        flat = cursor.values(b, "i4", "CELLS").astype(np.int64)
        sizes, conn, pos = [], [], 0
        if a and b == 5 * a and (flat[0::5] == 4).all():
            sizes, conn = np.full(a, 4), flat.reshape(a, 5)[:, 1:].ravel()
        else:
            for _ in range(a):
                if pos >= b or flat[pos] < 0 or pos + 1 + flat[pos] > b:
                    raise MeshFormatError(f"{path}: the CELLS section declares {a} cells in {b} values, but "
                                          f"its cell sizes do not add up to that")
                sizes.append(int(flat[pos]))
                conn.append(flat[pos + 1:pos + 1 + flat[pos]])
                pos += 1 + flat[pos]
            if pos != b:
                raise MeshFormatError(f"{path}: the CELLS section declares {a} cells in {b} values, but the "
                                      f"cells use {pos}; fix the counts")
            sizes = np.array(sizes, dtype=np.int64)
            conn = np.concatenate(conn) if conn else np.zeros(0, dtype=np.int64)
        a += 1  # as many offsets as cells + 1, like version 5
    cells = a - 1
    cursor.expect_keyword("CELLS")
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != b"CELL_TYPES":
        raise MeshFormatError(f"{path}: expected 'CELL_TYPES' after the cells, found "
                              f"{_show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    m = _vtk_count(tokens, 1, cursor, "CELL_TYPES")
    if m != cells:
        raise MeshFormatError(f"{path}: CELLS declares {cells} cells but CELL_TYPES declares {m}; fix the counts")
    types = cursor.values(m, "i4", "CELL_TYPES")
    cursor.expect_keyword("CELL_TYPES")
    _vtk_skip_optional(cursor)
    tokens = cursor.peek()
    if tokens and tokens[0].upper() not in _VTK_ATTRIBUTES:
        raise MeshFormatError(f"{path}: unexpected {_show(b' '.join(tokens))} after the cell types; only "
                              f"POINT_DATA / CELL_DATA / FIELD sections may follow")
    return points.reshape(-1, 3), types, sizes, conn


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

"""Atomic output and path safety: every file geomopt writes goes through here.

An output must be a regular file or not exist (:func:`check_output_path`); it is written to
a hidden temporary file beside it and renamed onto it only when complete
(:func:`atomic_path`, :func:`atomic_output`, :func:`atomic_write`), so an interrupted or
failed write never leaves a partial file or destroys an older one.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import signal
import stat
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: temporaries are not locked, stale ones not removed
    fcntl = None

from .._runtime.errors import GeomoptError, ParameterError
from .._runtime.interrupt import raise_pending
from ._files import file_kind, one_line

__all__ = ["check_output_path", "atomic_path", "atomic_output", "atomic_write", "check_outputs", "create_output_folder",
           "CASE_FILES"]

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



def _temp_path(path):
    """A fresh hidden name beside ``path``: ``.<name>.<12 hex digits>.tmp``, at most 218 bytes.

    The name is shortened (by whole characters) to 200 bytes so that the temporary name
    fits any file system that takes ``path``'s own name.
    """
    return path.with_name(f".{_temp_stem(path)}.{secrets.token_hex(6)}.tmp")


def _temp_stem(path):
    """``path``'s name, shortened by whole characters to at most 200 bytes."""
    name = path.name
    while len(os.fsencode(name)) > 200:
        name = name[:-1]
    return name


def _lock(fd, wait):
    """Take an exclusive lock on the open temporary file ``fd`` (released when it is closed,
    or by the kernel when the process dies), waiting for it or not; ``False`` when not taken."""
    if fcntl is None:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except OSError:
        return False
    return True


def _remove_stale_temporaries(path):
    """Delete the temporary files of ``path`` (``.<name>.<12 hex>.tmp``, and the temporaries of
    those) that no live writer holds.

    A writer keeps its temporary file locked (:func:`_lock`) until it is renamed or deleted;
    a process killed by SIGKILL leaves its temporary behind, unlocked: that one is removed
    here, the next time the same output is written.  Anything else of such a name (a file
    that cannot be opened or locked, a link, a folder, a FIFO) is left alone.
    """
    if fcntl is None:
        return
    # a writer that writes to another atomic path's temporary makes temporaries of temporaries
    pattern = re.compile(r"\.+" + re.escape(_temp_stem(path)) + r"(?:\.[0-9a-f]{12}\.tmp)+")
    try:
        names = [n for n in os.listdir(path.parent or ".") if pattern.fullmatch(n)]
    except OSError:
        return
    for name in names:
        stale = path.with_name(name)
        try:  # never follow a link, never wait on a FIFO
            fd = os.open(stale, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
        except OSError:
            continue
        try:
            st = os.fstat(fd)
            if stat.S_ISREG(st.st_mode) and _lock(fd, wait=False) and os.path.samestat(st, os.lstat(stale)):
                os.unlink(stale)
        except OSError:
            pass
        finally:
            os.close(fd)


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
            return _too_long(what, path)
        return f"cannot access {what} {path} ({one_line(exc)}); check the path"
    if mode is not None and stat.S_ISDIR(mode):
        return f"{what} {path} is a directory; give a file name (e.g. {path / example})"
    if mode is not None and not stat.S_ISREG(mode):
        return (f"{what} {path} is {file_kind(mode)}, not a regular file; geomopt replaces its output "
                f"files, so give the path of a regular file or of one that does not exist yet")
    folder = path.parent
    try:
        folder_mode = os.stat(folder).st_mode
    except FileNotFoundError:
        return f"cannot write {what} {path}: the folder {folder} does not exist; create it first"
    except OSError as exc:
        return f"cannot write {what} {path}: the folder {folder} cannot be accessed ({one_line(exc)})"
    if not stat.S_ISDIR(folder_mode):
        return f"cannot write {what} {path}: the folder {folder} is not a directory"
    try:
        os.lstat(_temp_path(path))
    except FileNotFoundError:
        pass
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return _too_long(what, path, " with its temporary file")
        return f"cannot write {what} {path} ({one_line(exc)})"
    if not _can_create_in(folder):
        rdonly = getattr(os, "ST_RDONLY", 0)
        with contextlib.suppress(OSError, AttributeError):
            if os.statvfs(folder).f_flag & rdonly:
                return f"cannot write {what} {path}: the folder {folder} is on a read-only file system"
        return f"cannot write {what} {path}: no permission to create files in {folder}; check its permissions"
    return None


def _too_long(what, path, beside=""):
    return (f"{what} {path} has a name too long for the file system ({len(os.fsencode(path.name))} bytes{beside}); "
            f"choose a shorter name")


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
    ParameterError
        The extension is not allowed (a ``ValueError`` too).
    GeomoptError
        ``path`` is not a regular file, names a folder,
        its folder does not exist or is not writable (permissions, read-only file system),
        or its name is too long for the file system.
    """
    problem = _output_problem(path, what, extensions)
    if problem:
        raise GeomoptError(problem)
    path = Path(path)
    if extensions is not None and path.suffix.lower() not in extensions:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise ParameterError(f"{what} {path} has {got}; supported: {', '.join(extensions)}")
    return path


@contextlib.contextmanager
def atomic_path(path, what="output"):
    """A temporary path beside ``path`` that is moved onto ``path`` when the block succeeds.

    The temporary file is created empty (so the name is reserved) in the same folder,
    hidden (``.<name>.<random>.tmp``).  When the ``with`` block ends normally it is
    renamed onto ``path`` with :func:`os.replace` (atomic on POSIX and Windows).  When the
    block raises (including ``KeyboardInterrupt`` and the exception the command line
    raises for SIGTERM/SIGHUP) the temporary file is deleted and ``path`` is left
    untouched, and so it is when an interrupt was recorded and swallowed on the way
    (:func:`geomopt._runtime.interrupt.raise_pending`).  Use it for writers that open a
    file by name; :func:`atomic_output` gives an open file instead.

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
    held, tmp, fd = _block_signals(), None, None
    try:
        tmp, fd = _create_temp_next_to(path, what)
        # from here on, a signal held back while the file was created lands inside this
        # try block, where the cleanup below sees it
        _unblock_signals(held)
        held = None
        yield tmp
        problem = _output_problem(path, what)  # it may have changed while we wrote
        if problem:
            raise GeomoptError(problem)
        held = _block_signals()
        raise_pending()  # an interrupt swallowed on the way (a GC callback's) still stops the rename
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            again = _block_signals() if held is None else None
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            _unblock_signals(again)
        if isinstance(exc, OSError):
            raise GeomoptError(f"could not write {path} ({one_line(exc)}); nothing was written") from exc
        raise
    finally:
        if fd is not None:
            os.close(fd)  # releases the lock: the file is renamed or deleted by now
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
    """Create a fresh, empty hidden file beside ``path``, locked; return its path and open descriptor.

    Stale temporaries of the same output (left by a killed process) are removed first
    (:func:`_remove_stale_temporaries`).  ``os.open`` with mode 0o666 lets the umask decide
    the permissions, as for any newly created file (``tempfile.mkstemp`` would make it
    0o600).  Raises :class:`GeomoptError` saying why ``path`` cannot be written.
    """
    problem = _output_problem(path, what)
    if problem:
        raise GeomoptError(problem)
    _remove_stale_temporaries(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = _temp_path(path)
        try:
            fd = os.open(tmp, flags, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise GeomoptError(
                f"cannot write {path} ({one_line(exc)}); check the folder's permissions"
            ) from exc
        _lock(fd, wait=True)  # a cleaner holds it only while it checks and deletes it
        with contextlib.suppress(OSError):  # ... which it may have done between open and lock
            if os.path.samestat(os.fstat(fd), os.lstat(tmp)):
                return tmp, fd
        os.close(fd)
    raise GeomoptError(f"cannot write {path}: could not create a temporary file next to it")


# ------------------------------------------------------------------ a command's outputs

#: The files that make a folder a LIM benchmark case (:class:`geomopt.lim.LimCase`): a folder
#: holding one is input data, never an output folder.
CASE_FILES = ("input.obj", "rest.vtk", "init.vtk")


def check_outputs(files, inputs=(), folder=None):
    """Check a command's outputs before any work: writable, distinct, none of them an input.

    The one check every writing command makes (``param``, ``untangle``, ``compare``,
    ``demo``, ``smooth``, and :func:`geomopt.compare` / :func:`geomopt.experiments.batch.run_batch`).
    Nothing is created, changed or removed.  The rules:

    * each output file passes :func:`check_output_path` (a regular file or absent, in an
      existing writable folder, or in ``folder`` when that is still to be created);
    * no output file is, or would replace, an input file (same file by device and inode:
      symbolic and hard links, ``./a.obj`` and ``a.obj`` alike); the files directly inside an
      input folder are inputs;
    * no two outputs are the same file;
    * ``folder``, the output folder a command was given, is an existing folder or is created
      later by :func:`create_output_folder` *without its parents*: its parent must exist
      (geomopt never creates folders it was not asked for).  It must not be an input folder,
      nor a LIM case folder (one holding :data:`CASE_FILES`).

    Parameters
    ----------
    files : iterable
        The files the command will write, derived names included: each a path, a pair
        ``(what, path)`` or a triple ``(what, path, extensions)``; ``what`` names it in
        messages (default ``"output"``), ``extensions`` as in :func:`check_output_path`.
    inputs : iterable of str or os.PathLike
        Every file and folder the command reads (missing ones are ignored).
    folder : str or os.PathLike, optional
        The output folder the command was given.

    Returns
    -------
    list of pathlib.Path
        The output files, in order.

    Raises
    ------
    GeomoptError
        One line saying which rule an output breaks and what to do.
    """
    pending = _check_output_folder(Path(folder), inputs) if folder is not None else None
    given = _input_files(inputs)
    seen, out = {}, []
    for item in files:
        what, path, extensions = ("output", item, None) if isinstance(item, (str, os.PathLike)) else \
            (*item, None) if len(item) == 2 else tuple(item)
        path = Path(path)
        source = given.get(_identity(path))
        if source is not None:
            raise GeomoptError(f"{what} {path} is the input file {source}: writing it would replace your input; "
                               f"give the output another name or folder")
        key = os.path.join(os.path.realpath(os.path.dirname(os.path.abspath(path))), path.name)
        if key in seen:
            raise GeomoptError(f"{what} {path} is the same file as the {seen[key]}; give different file names")
        seen[key] = what
        if pending is not None and os.path.abspath(path.parent) == pending:
            _check_new_name(path, extensions, what)
        else:
            check_output_path(path, extensions, what)
        out.append(path)
    return out


def create_output_folder(folder):
    """Create the output folder ``folder`` if it is missing (not its parents); return it.

    Call it when the first output is about to be written, after :func:`check_outputs`,
    so that a command that stops before writing leaves nothing behind.

    Raises
    ------
    GeomoptError
        The folder cannot be created (its parent is missing or not writable...).
    """
    folder = Path(folder)
    try:
        folder.mkdir(exist_ok=True)
    except OSError as exc:
        raise GeomoptError(f"cannot create the output folder {folder} ({one_line(exc)}); give a folder "
                           f"whose parent exists and is writable") from exc
    return folder


def _check_output_folder(folder, inputs):
    """Refuse ``folder`` as an output folder (see :func:`check_outputs`); return its absolute path
    when it is still to be created, else ``None``."""
    try:
        mode = os.stat(folder).st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = None
    except OSError as exc:
        raise GeomoptError(f"cannot use the output folder {folder} ({one_line(exc)})") from exc
    if mode is None:
        parent = folder.absolute().parent
        if not parent.is_dir():
            why = "is not a folder" if parent.exists() else "does not exist; create it first"
            raise GeomoptError(f"cannot create the output folder {folder}: its parent {parent} {why} "
                               f"(geomopt creates the output folder, never its parents)")
        if not _can_create_in(parent):
            raise GeomoptError(f"cannot create the output folder {folder}: no permission to create it in {parent}")
        return os.path.abspath(folder)
    if not stat.S_ISDIR(mode):
        kind = "a file" if stat.S_ISREG(mode) else file_kind(mode)
        raise GeomoptError(f"cannot create the output folder {folder}: it exists and is not a folder ({kind}); "
                           f"give a folder path")
    for source in inputs:
        with contextlib.suppress(OSError):
            if os.path.isdir(source) and os.path.samefile(source, folder):
                raise GeomoptError(f"output folder {folder} is the input folder {source}: outputs would be mixed "
                                   f"with your input; give another output folder")
    marks = [name for name in CASE_FILES if os.path.lexists(folder / name)]
    if marks:
        raise GeomoptError(f"output folder {folder} is a LIM case folder (it holds {marks[0]}): writing there "
                           f"would replace a case's input or mix outputs with it; give an output folder outside "
                           f"the case folders")
    if not _can_create_in(folder):
        raise GeomoptError(f"cannot write into the output folder {folder}; check its permissions")
    return None


def _check_new_name(path, extensions, what):
    """The checks :func:`check_output_path` can make of a file in a folder still to be created."""
    if extensions is not None and path.suffix.lower() not in extensions:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise GeomoptError(f"{what} {path} has {got}; supported: {', '.join(extensions)}")
    try:
        limit = os.pathconf(path.absolute().parent.parent, "PC_NAME_MAX")
    except (OSError, ValueError):  # no such limit here
        return
    if max(len(os.fsencode(path.name)), len(os.fsencode(_temp_path(path).name))) > limit:
        raise GeomoptError(_too_long(what, path))


def _input_files(inputs):
    """``{(device, inode): path}`` of every input file and every file directly in an input folder."""
    found = {}
    for source in inputs:
        source = Path(source)
        entries = [source]
        if source.is_dir():
            with contextlib.suppress(OSError):
                entries = list(source.iterdir())
        for entry in entries:
            ident = _identity(entry)
            if ident is not None and os.path.isfile(entry):
                found.setdefault(ident, entry)
    return found


def _identity(path):
    """``(device, inode)`` of the file ``path`` names (links followed), or ``None``."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino

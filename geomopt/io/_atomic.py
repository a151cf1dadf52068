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
import secrets
import signal
import stat
from pathlib import Path

from .._errors import GeomoptError, ParameterError
from ._files import file_kind, one_line

__all__ = ["check_output_path", "atomic_path", "atomic_output", "atomic_write"]

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
            return (f"{what} {path} has a name too long for the file system "
                    f"({len(os.fsencode(path.name))} bytes with its temporary file); choose a shorter name")
        return f"cannot write {what} {path} ({one_line(exc)})"
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
            raise GeomoptError(f"could not write {path} ({one_line(exc)}); nothing was written") from exc
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
                f"cannot write {path} ({one_line(exc)}); check the folder's permissions"
            ) from exc
    raise GeomoptError(f"cannot write {path}: could not create a temporary file next to it")


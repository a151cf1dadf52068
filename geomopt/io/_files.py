"""Files on disk: what a path is, and the bytes of an existing input file."""

from __future__ import annotations

import contextlib
import mmap
import os
import stat
from pathlib import Path

from .._runtime.errors import MeshFormatError

__all__ = ["file_kind", "existing_file", "read_input", "one_line"]


def file_kind(mode):
    """What a ``st_mode`` describes, in words."""
    for test, word in ((stat.S_ISDIR, "a directory"), (stat.S_ISLNK, "a symbolic link"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return word
    return "not a regular file"



# ---------------------------------------------------------------- file helpers


def existing_file(path, what):
    """Return ``Path(path)`` after checking it is an existing regular file (emptiness not checked)."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise MeshFormatError(f"{what} {path} does not exist; check the path") from None
    except OSError as exc:  # e.g. a name too long for the file system
        raise MeshFormatError(f"{what} {path} cannot be accessed ({one_line(exc)}); check the path") from exc
    if stat.S_ISDIR(mode):
        raise MeshFormatError(f"{what} {path} is a directory, not a file; pass the file inside it")
    if not stat.S_ISREG(mode):
        raise MeshFormatError(f"{what} {path} is {file_kind(mode)}, not a regular file; pass a mesh file")
    return path


def read_input(path, what, empty_ok=False, mapped=False):
    """``(Path, bytes)`` of the input file ``path`` (:func:`existing_file`), not empty unless ``empty_ok``;
    an empty or unreadable one gives a MeshFormatError naming ``what``.  ``mapped``: the file
    memory-mapped (read-only ``mmap``, where the system allows it) instead of copied into bytes,
    for a parser that slices, ``find``s and ``np.frombuffer``s it: a binary file's arrays are then
    converted straight from the page cache (48 MB of binary VTK: 0.015 s instead of 0.07 s)."""
    path = existing_file(path, what)
    size = path.stat().st_size
    if not empty_ok and size == 0:
        raise MeshFormatError(f"{what} {path} is empty (0 bytes); re-export or re-download it")
    if mapped and size:
        with contextlib.suppress(OSError, ValueError), open(path, "rb") as fh:  # else: read it
            return path, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return path, path.read_bytes()
    except OSError as exc:
        raise MeshFormatError(f"cannot read {what} {path} ({one_line(exc)}); check its permissions") from exc


def one_line(exc):
    """An exception as ``Type: message`` on one short line."""
    text = " ".join(str(exc).split()) or "(no message)"
    return f"{type(exc).__name__}: {text[:200]}"

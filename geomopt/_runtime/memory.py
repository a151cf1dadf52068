"""Hand the C heap's free memory back to the system (:func:`release_free_memory`).

A Newton step at 10^6 elements frees hundreds of MB of temporaries on several threads (XLA's
kernels, PARDISO's solves, NumPy's copies).  glibc's allocator keeps what is freed in per-thread
arenas, and chunks below its (dynamic, up to 32 MB) mmap threshold in the heap, so the next kernel
on another thread takes fresh pages: resident memory grows step after step although the live data
do not.  Measured at 10^6 triangles (swirled grid, clamp, 5 iterations): peak resident 2.66 GB
without, 2.41 GB with ``malloc_trim`` between the phases of each step."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

__all__ = ["release_free_memory"]


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None (another C library: musl, macOS, Windows)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def release_free_memory() -> bool:
    """Return the free pages of every malloc arena to the system (glibc ``malloc_trim(0)``).
    Nothing live is touched.  True when memory was released, False when none was or the C
    library has no such call."""
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False

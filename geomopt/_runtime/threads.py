"""Threads: one BLAS thread while geomopt's solve loop runs (:func:`single_blas_thread`), and
work started ahead of need on a thread (:func:`ahead`).

A solve interleaves XLA's kernels (which use every core) with NumPy and SciPy calls on the host
(gradient norms, dot products of the Newton and CG steps, certificates).  NumPy's OpenBLAS
starts a thread per core for a vector of 10,000 or more values and keeps them spinning after the
call, on the cores XLA needs for the next kernel, which slows the solve (measurements:
benchmarks/README.md, issue 49 section).
:func:`single_blas_thread` limits every loaded BLAS (OpenBLAS, MKL, BLIS, Accelerate:
``threadpoolctl``) to one thread for the loop and restores the caller's settings after it;
nothing else in the process is changed.  Finding the loaded libraries scans the process's
shared objects, a cost not negligible beside a small chart's solve in an atlas: it is done again only
when modules were imported since.

Work ahead on a thread pays only for problems of :data:`AHEAD_FROM` unknowns or more: below
that the thread's start and join cost more than the work it overlaps.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

__all__ = ["AHEAD_FROM", "single_blas_thread", "ahead", "usable_cores"]

#: unknowns from which set-up work is done ahead on a thread (module doc)
AHEAD_FROM = 4096

_lock = threading.Lock()
# solves running in this process; the limiter they share; the libraries found, and the number
# of modules imported when they were looked for
_state = {"users": 0, "limits": None, "controller": None, "modules": -1}


def _controller():
    """threadpoolctl's view of the loaded BLAS libraries, looked for again when modules were
    imported since the last look (a module's import is what loads a library)."""
    if _state["modules"] != len(sys.modules):
        from threadpoolctl import ThreadpoolController

        _state["controller"], _state["modules"] = ThreadpoolController(), len(sys.modules)
    return _state["controller"]


@contextlib.contextmanager
def single_blas_thread():
    """Context: the loaded BLAS libraries run on one thread inside it.  The limit is the
    process's (BLAS thread pools are): the first of overlapping uses (nested, or solves on
    several threads) sets it and the last one out restores the settings found before the first."""
    with _lock:
        if _state["users"] == 0:
            _state["limits"] = _controller().limit(limits=1, user_api="blas")
        _state["users"] += 1
    try:
        yield
    finally:
        with _lock:
            _state["users"] -= 1
            if _state["users"] == 0:
                _state["limits"].restore_original_limits()
                _state["limits"] = None


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the platform tells it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def ahead(work) -> threading.Thread:
    """Start ``work()`` on a thread in JAX's 64-bit mode and return the thread: work done
    ahead of need (loading or compiling kernels while the caller builds a start map), whose
    results the caller finds where it would have made them.  Best effort: an exception there is
    dropped, and the caller's own call (which waits for the work already under way, see
    :class:`geomopt._runtime.programs.Program`) raises it in its place.  Not a daemon thread:
    a process that ends while it compiles (the caller failed on a bad mesh, the script caught
    that and exited) waits for it; a daemon thread inside XLA's compiler at interpreter
    shutdown aborted the process (exit 134)."""
    from .x64 import float64

    def run():
        try:
            float64(work)()
        except Exception:  # noqa: BLE001 -- the caller's own call raises it
            pass

    thread = threading.Thread(target=run, name="geomopt-ahead")
    thread.start()
    return thread

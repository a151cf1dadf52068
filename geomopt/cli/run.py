"""The ``geomopt`` process: :func:`main` parses the command line, runs the command with SIGINT,
SIGTERM and SIGHUP recorded and raised as interrupts (:mod:`geomopt._runtime.interrupt`: one
swallowed where Python ignores exceptions still ends the run), geomopt's warnings gathered, and every failure turned into
one line and an exit status, then prints the ``--json`` summary; :func:`entry` is the console
command, which exits quickly once the command has finished."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import sys
import threading
import time
import warnings

from .._runtime.log import attach_stderr
from .common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail, report
from .parser import UsageError, build_parser

__all__ = ["main", "entry"]


def main(argv=None) -> int:
    from .._runtime import interrupt

    with interrupt.handled():  # from the start: an interrupt during parsing or the summary too
        try:
            return _main(argv)
        except KeyboardInterrupt as exc:
            return _interrupted(exc)


def _interrupted(exc) -> int:
    """Say which signal ended the run; its exit status (128 + the signal number)."""
    signum = getattr(exc, "signum", signal.SIGINT)
    print(f"geomopt: interrupted by {signal.Signals(signum).name}; unfinished outputs were removed",
          file=sys.stderr, flush=True)
    return 128 + signum


def _main(argv) -> int:
    t0 = time.perf_counter()
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    try:
        args = build_parser().parse_args(argv)
    except UsageError as exc:  # one line, exit status 2, and the JSON summary if asked
        print(f"{exc.parser.prog}: error: {exc} (see '{exc.parser.prog} --help')", file=sys.stderr, flush=True)
        if "--json" in argv:
            command = next((a for a in argv if not a.startswith("-")), None)
            print(json.dumps({"command": command, "success": False, "exit_status": EXIT_USAGE,
                              "error": f"usage: {exc}", "wall_seconds": round(time.perf_counter() - t0, 4)}),
                  flush=True)
        raise SystemExit(EXIT_USAGE) from None  # as argparse itself exits
    args.summary = {"command": args.command, "success": False}
    from .._runtime.timing import Split

    args.timing = Split()
    code = EXIT_FAILED
    try:
        with attach_stderr(logging.WARNING if getattr(args, "quiet", False) else logging.DEBUG):
            code = _run(args)  # the library's progress records are the command's lines on stderr
        return code
    finally:
        if args.json:
            from ..experiments.manifest import SCHEMA_VERSION, versions

            report(args, exit_status=code, success=code == EXIT_OK,
                   wall_seconds=round(time.perf_counter() - t0, 4), timing=args.timing.summary(),
                   schema_version=SCHEMA_VERSION,
                   versions=versions())
            print(json.dumps(args.summary, default=_json_default), flush=True)


def entry() -> None:
    """The ``geomopt`` console command and ``python -m geomopt``: :func:`main`, then a quick exit.

    Interpreter shutdown tears down JAX's CPU client and caches (~0.1-0.2 s, nothing kept); once
    the command has finished, its files are closed and renamed into place and only daemon threads
    remain, so the process flushes its output, waits for JAX's dispatched effects and ends there.
    Under a profiler, tracer or coverage tool (which report at exit) it exits normally.
    """
    code = main()
    if _observed() or any(t.is_alive() and not t.daemon for t in threading.enumerate()
                          if t is not threading.main_thread()):
        sys.exit(code)
    if "jax" in sys.modules:
        import jax

        jax.effects_barrier()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


def _observed() -> bool:
    """Whether a profiler, tracer or coverage tool watches this process (it reports at exit)."""
    monitoring = getattr(sys, "monitoring", None)  # Python 3.12+
    tools = monitoring is not None and any(monitoring.get_tool(i) for i in range(6))
    return sys.getprofile() is not None or sys.gettrace() is not None or bool(tools)


def _json_default(value):
    """NumPy scalars and arrays, paths and other objects in --json output."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


class _Warnings:
    """``warnings.showwarning`` that keeps geomopt's warnings (other warnings go to ``show``)
    to be printed as one ``geomopt: warning: ...`` line each (even with --quiet, as errors
    are) when the command succeeds: a failure's one error line already says why."""

    def __init__(self, show):
        self.show, self.messages = show, []

    def __call__(self, message, category, filename, lineno, file=None, text=None):
        from .._runtime.errors import GeomoptWarning

        if not issubclass(category, GeomoptWarning):
            return self.show(message, category, filename, lineno, file, text)
        if str(message) not in self.messages:
            self.messages.append(str(message))

    def print(self):
        for message in self.messages:
            print(f"geomopt: warning: {message}", file=sys.stderr, flush=True)


def _run(args) -> int:
    from .._runtime import interrupt
    from .._runtime.errors import GeomoptWarning

    if args.json:
        from .._runtime.cache import cache_stats

        cache_stats()  # count persistent-cache hits and misses from here on
    try:
        with warnings.catch_warnings():
            if not args.debug:  # errors are one line: no NumPy RuntimeWarning (overflow, 0/0...) on stderr
                warnings.simplefilter("ignore", RuntimeWarning)
            warnings.simplefilter("always", GeomoptWarning)  # each run's own, deduplicated by _Warnings
            warnings.showwarning = said = _Warnings(warnings.showwarning)
            code = args.func(args)
            interrupt.raise_pending()  # a swallowed interrupt ends the run even when nothing was written
            if code == EXIT_OK:
                said.print()
            return code
    except KeyboardInterrupt as exc:  # SIGINT, SIGTERM or SIGHUP (main's interrupt.handled)
        return _interrupted(exc)
    except Exception as exc:
        if interrupt.pending() is not None:  # an interrupt that a library turned into its own error
            return _interrupted(interrupt.Interrupted(interrupt.pending()))
        if args.debug:
            raise
        return _failed(args, exc)


def _failed(args, exc) -> int:
    """Print and report the error ``exc`` that ended a command; its exit status."""
    from .._runtime.errors import GeomoptError, SolveError

    if isinstance(exc, SolveError):
        report(args, error=str(exc))
        return fail(str(exc))
    if isinstance(exc, GeomoptError):
        report(args, error=str(exc))
        print(f"geomopt: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    # an internal error: one line unless --debug
    report(args, error=f"internal error: {type(exc).__name__}: {exc}")
    print(f"geomopt: internal error: {type(exc).__name__}: {exc} (rerun with --debug and "
          f"report it)", file=sys.stderr)
    return EXIT_FAILED

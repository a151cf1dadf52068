"""What every command of the command line shares: the exit statuses, the progress log and the
failure line on stderr, the ``--json`` summary's fields, the check of the outputs before any
work, and the timing split of a solve.  Light to import: the library is imported lazily, so
that ``geomopt --help`` stays fast."""

from __future__ import annotations

import sys
import time

__all__ = ["EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_EXCEPT_FIXED", "log", "fail", "report", "make_solver",
           "output_paths", "cell_output", "quality_line", "cache_summary", "timed_solve"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
#: ``untangle``: the map was written, certified wherever a free vertex reaches, but the handles
#: alone make it overlap where every element has all its vertices fixed (``certified_except_fixed``)
EXIT_EXCEPT_FIXED = 3


def log(args, *msg):
    """A progress or summary line on stderr, unless ``--quiet``."""
    if not args.quiet:
        print(*msg, file=sys.stderr, flush=True)


def fail(message) -> int:
    """Report a result that is not certified (printed even with --quiet); exit status 1."""
    print(f"geomopt: error: {message}; nothing written", file=sys.stderr, flush=True)
    return EXIT_FAILED


def report(args, **fields):
    """Add ``fields`` to the --json summary."""
    args.summary.update(fields)


def make_solver(name, max_steps=None):
    """The solver named ``name`` (:func:`geomopt.solvers.get_solver`), with ``--max-steps`` when given."""
    import dataclasses

    from .. import solvers

    found = solvers.get_solver(name)
    return found if max_steps is None else dataclasses.replace(found, max_steps=max_steps)


def output_paths(output, extensions, pictures=(), inputs=(), folder=None):
    """Check every output before any work (:func:`geomopt.io.check_outputs`): ``-o`` (``extensions``)
    and ``pictures`` (``(what, path)``, derived names included), in ``folder`` when the command was
    given an output folder.  Returns the output path."""
    from .. import io
    from .._runtime.formats import PICTURE_EXTENSIONS

    files = [("-o output", output, extensions)] + [(what, p, PICTURE_EXTENSIONS) for what, p in pictures]
    return io.check_outputs(files, inputs, folder)[0]


def cell_output(args, case, inputs, pictures=()):
    """Check ``-o`` (and ``pictures``) for a tet / quad / hex case (:data:`geomopt.mesh.cells.CELL_EXTENSIONS`,
    ``.obj`` for quads only)."""
    from ..mesh.cells import output_extensions

    output_paths(args.output, output_extensions(case.kind), pictures, inputs)


def quality_line(q):
    """One line of scaled-Jacobian figures: a :func:`geomopt.mesh.quality.quality_summary` or a
    :class:`geomopt.mesh.elements.Quality`."""
    q = q if isinstance(q, dict) else {f"sj_{k}": v for k, v in q.as_dict().items()}
    return (f"min scaled Jacobian {q['sj_min']:.4f}, mean {q['sj_mean']:.4f}, {q['sj_below_0']} below 0, "
            f"{q['sj_below_0_2']} below 0.2")


def cache_summary() -> dict:
    """The persistent compilation cache's folder, hits and misses, for the --json summary."""
    from .._runtime.cache import cache_stats

    st = cache_stats()
    return {"cache_dir": st["dir"], "cache_hits": st["hits"], "cache_misses": st["misses"]}


def timed_solve(split, solve):
    """``solve()``'s value (a Result, or a tuple ending with one), its wall time split into
    JAX's compilation, the solve loop (``stats.seconds``), the final certificate and the rest
    (set-up)."""
    from .._runtime.timing import compile_seconds

    t, compiled = time.perf_counter(), compile_seconds()
    out = solve()
    compiled = compile_seconds() - compiled
    st = (out[-1] if isinstance(out, tuple) else out).stats
    split.add("compile", compiled)
    split.add("solve", st.seconds)
    split.add("certify", st.certify_seconds)
    split.add("setup", time.perf_counter() - t - st.seconds - st.certify_seconds - compiled)
    return out

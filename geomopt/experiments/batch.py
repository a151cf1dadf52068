"""Batches of untangling cases: Dask sweeps and ``summary.csv``.

:func:`~geomopt.untangling.untangle` compiles its kernels for the array shapes of each mesh
(seconds per shape, while a small case then solves in hundredths of a second).  Batches solve
with ``bucket=True``: each case is padded to its size bucket (``Objective(buckets=True)``,
:mod:`geomopt._runtime.padding`) so that every case of the same bucket runs the same compiled program,
in one process (the in-memory JIT cache) or across processes and Dask workers (JAX's
persistent compilation cache); each bucket's first case runs alone, the others of its bucket
after it.  The padding changes no certificate and, up to the order of floating-point sums, no
result.

:func:`run_batch` solves many LIM case folders, serially or on Dask distributed (a local
cluster of worker processes, or an existing scheduler), writing ``<case folder name>.obj``
(2D) or ``.vtk`` (3D) per certified case and ``summary.csv`` (one row per case, in input
order); a case that cannot be read, solved or certified is a row saying why and never stops
the others.
"""

from __future__ import annotations

import csv
import io as _stdio
import time
from pathlib import Path

from .._runtime.errors import GeomoptError, ParameterError
from .._runtime.padding import bucket_sizes
from .._runtime.threads import usable_cores
from ..mesh.cells import cell_problem, is_cell_case, read_cell_case, write_certified
from ..lim import LimCase, output_suffix, untangle_case
from ..solvers import Outcome

__all__ = ["SUMMARY_COLUMNS", "EXCEPT_FIXED", "batch_cases", "dask_available", "default_workers", "solve_case",
           "run_batch", "tally", "write_summary"]

#: what to install for batches on Dask (``distributed`` is an extra, not a dependency)
DASK_EXTRA = 'pip install "geomopt[batch]"'


def dask_available() -> bool:
    """Whether Dask's ``distributed`` (the ``[batch]`` extra) can be imported here."""
    import importlib.util

    return importlib.util.find_spec("distributed") is not None


# --------------------------------------------------------------------- one case


#: the columns of ``summary.csv``, one row per case
SUMMARY_COLUMNS = ("case", "dim", "vertices", "elements", "inverted_before", "inverted_after",
                   "outer_iterations", "inner_iterations", "seconds", "certified", "outcome", "output", "message")

#: ``certified`` of a case written but not certified everywhere: its handles alone make it overlap
#: where every element has all its vertices fixed (outcome ``certified_except_fixed``)
EXCEPT_FIXED = "except_fixed"


def solve_case(folder, outdir, solver="lbfgs", bucket=True, start="auto"):
    """Read a LIM case folder, untangle it, write ``outdir/<folder name>.obj`` (2D) or ``.vtk``
    (3D) if it certifies (:meth:`geomopt.lim.LimCase.write_certified`), and return its summary row.
    A quad / hex case folder (``rest.vtk`` and ``init.vtk`` of VTK cell type 9 / 12,
    :mod:`geomopt.mesh.cells`) is written to ``outdir/<folder name>.vtk``.

    Never raises on a bad case (``Exception``): an unreadable, malformed, unsolvable or
    uncertified case gives a row with ``certified = "no"``, the reason in ``message`` and no
    file.  A LIM case certified wherever a free vertex reaches but overlapping where its handles
    fix every element (outcome ``certified_except_fixed``) is written, with ``certified =``
    :data:`EXCEPT_FIXED` and the overlap in ``message``.  Interrupts (``KeyboardInterrupt``)
    propagate.

    Parameters
    ----------
    folder : a case folder (:meth:`geomopt.lim.LimCase.read`).
    outdir : the output folder (must exist).
    solver : inner solver name for :func:`geomopt.untangling.untangle`.
    bucket : pad to a size bucket (:mod:`geomopt._runtime.padding`), so that cases of similar sizes
        share compiled kernels.
    start : where untangling starts (``UntangleOptions.start``: ``"auto"``, ``"given"``,
        ``"harmonic"``).

    Returns
    -------
    dict with the keys of :data:`SUMMARY_COLUMNS` (strings and ints).
    """
    t0 = time.perf_counter()
    folder = Path(folder)
    row = dict.fromkeys(SUMMARY_COLUMNS, "")
    row.update(case=folder.name, certified="no")
    try:
        (_solve_cell_case if is_cell_case(folder) else _solve_lim_case)(folder, outdir, solver, bucket, row, start)
    except GeomoptError as exc:
        row["message"] = str(exc)
    except Exception as exc:  # noqa: BLE001 -- one broken case must not stop the batch
        row["message"] = f"internal error: {type(exc).__name__}: {exc}"
    row["seconds"] = f"{time.perf_counter() - t0:.3f}"
    return row


def _solve_lim_case(folder, outdir, solver, bucket, row, start="auto"):
    """A LIM case (triangles or tetrahedra) into ``row``; its map written if it certifies."""
    case = LimCase.read(folder)
    case.require_handles()
    row.update(dim=case.dim, vertices=len(case.rest), elements=len(case.simplices))
    from ..untangling import UntangleOptions

    case, res = untangle_case(case, solver=solver, options=UntangleOptions(bucket=bucket, start=start),
                              progress=False)
    _solved(row, res)
    if res.success or res.outcome is Outcome.CERTIFIED_EXCEPT_FIXED:
        output = Path(outdir) / (folder.name + output_suffix(case.dim))
        check = case.write_certified(res, output)
        row.update(inverted_after=check["inverted"], certified="yes" if check["certified"] else EXCEPT_FIXED,
                   output=output.name, message=res.message if not check["certified"] else "")


def _solve_cell_case(folder, outdir, solver, bucket, row, start="auto"):
    """A quad / hex case folder (:mod:`geomopt.mesh.cells`) into ``row``, solved and written as
    ``geomopt untangle FOLDER -o <name>.vtk`` does (``bucket`` does not apply)."""
    from ..untangling import UntangleOptions, untangle

    case = read_cell_case(folder)
    problem = cell_problem(case)
    row.update(dim=problem.dim, vertices=len(case.start), elements=len(case.elements))
    res = untangle(problem, case.start, solver=solver, progress=False, options=UntangleOptions(start=start))
    _solved(row, res)
    if res.success:
        output = Path(outdir) / (folder.name + ".vtk")
        check = write_certified(output, res.x, case, problem)
        row.update(inverted_after=check["certificate"].invalid, certified="yes", output=output.name)


def _solved(row, res):
    row.update(inverted_before=res.stats.inverted_at_start, inverted_after=res.certificate.inverted,
               outer_iterations=res.stats.outer_iterations, inner_iterations=res.stats.iterations,
               outcome=res.outcome.value)
    if not res.success:
        row["message"] = f"not certified: {res.message}"


def _solve_cases(folders, outdir, solver, bucket, settings=None, after=None, start="auto"):
    """:func:`solve_case` for each folder in turn (one Dask task), under the client's JAX
    ``settings`` (:func:`jax_settings`); ``after`` is the result of the task this one waited
    for (unused)."""
    if settings:
        _apply_jax_settings(settings)
    return [solve_case(f, outdir, solver, bucket, start) for f in folders]


# --------------------------------------------------------------------- many cases


def batch_cases(paths):
    """The case folders named by ``paths``: each a LIM case folder, or a folder searched for
    case folders (:meth:`geomopt.lim.LimCase.cases`, sorted); in the order given.

    Raises
    ------
    ParameterError
        A path does not exist, holds no case, or two cases share a folder name (their outputs
        ``<name>.obj`` would collide).
    """
    found = []
    for p in map(Path, paths):
        if not p.is_dir():
            raise ParameterError(f"{p} is not a folder; give LIM case folders or folders holding them")
        cases = LimCase.cases(p)
        if not cases:
            raise ParameterError(f"{p} holds no LIM case folder (input.obj + handles.txt, or rest.vtk + "
                                 f"init.vtk)")
        found.extend(cases)
    seen = {}
    for c in found:
        if c.name in seen and seen[c.name] != c.resolve():
            raise ParameterError(f"cases {seen[c.name]} and {c} have the same folder name, so both would "
                                 f"be written to {c.name}.obj/.vtk; rename one or run them separately")
        seen[c.name] = c.resolve()
    unique = {c.resolve(): c for c in found}  # a case named twice is solved once
    return list(unique.values())


def default_workers(n_cases) -> int:
    """Worker processes for ``n_cases`` cases when none are asked for: one per CPU core this
    process may run on, at most one per case."""
    return min(usable_cores(), n_cases)


def tally(rows) -> tuple:
    """``(certified, certified_except_fixed, not_certified)``: how many summary rows (:func:`solve_case`)
    are certified (``"yes"``), written but certified only except where the handles fix them
    (:data:`EXCEPT_FIXED`), and neither (nothing written)."""
    except_fixed = sum(row["certified"] == EXCEPT_FIXED for row in rows)
    failed = sum(row["certified"] not in ("yes", EXCEPT_FIXED) for row in rows)
    return len(rows) - failed - except_fixed, except_fixed, failed


def write_summary(path, rows):
    """Write ``rows`` (dicts with :data:`SUMMARY_COLUMNS`) as CSV to ``path``, atomically."""
    from .. import io

    buf = _stdio.StringIO()
    writer = csv.DictWriter(buf, SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    io.atomic_write(path, lambda fh: fh.write(buf.getvalue()))
    return Path(path)


def run_batch(cases, outdir, solver="lbfgs", workers=1, scheduler=None, bucket=True, report=None,
              chunk=None, start="auto"):
    """Untangle many LIM cases and write their outputs and ``outdir/summary.csv``.

    Parameters
    ----------
    cases : sequence of case folders (see :func:`batch_cases`).
    outdir : output folder, created if missing (not its parents) once the run can start; it
        must not be a case folder (:func:`geomopt.io.check_outputs`).
    solver : inner solver name (:func:`geomopt.untangling.untangle`).
    workers : 1: solve in this process, one case after another; N > 1: on a local Dask
        cluster of N single-threaded worker processes.
    scheduler : address of an existing Dask scheduler (``workers`` is then ignored); its
        workers must import geomopt and see ``cases`` and ``outdir`` at the same paths.
    bucket : pad cases to size buckets (:mod:`geomopt._runtime.padding`; the default), so that each
        bucket compiles once.  The serial and the Dask runs write the same files, bit for bit.
    report : optional callable ``(row, done, total)`` called as each case finishes.
    chunk : cases per Dask task (default: about 8 tasks per worker, at most 16 cases each).
    start : where each untangling starts (``UntangleOptions.start``).

    Returns
    -------
    list of summary rows (dicts), in the order of ``cases``.

    An interrupt (``KeyboardInterrupt``: Ctrl-C, or SIGTERM/SIGHUP under the command line)
    still writes ``summary.csv``: the cases that finished, a "not solved: the batch was
    interrupted" row for each other one (certified, statistics lost, for one whose output this
    batch wrote before its row arrived); then it propagates.
    """
    from .. import io
    from .._runtime import interrupt

    cases = [Path(c) for c in cases]
    outdir = Path(outdir)
    summary = outdir / "summary.csv"
    io.check_outputs([("summary", summary, (".csv",))] + [outdir / (c.name + ext) for c in cases
                                                          for ext in (".obj", ".vtk")], cases, outdir)
    rows = [None] * len(cases)  # filled as cases finish
    started = time.time()
    try:
        if (scheduler is not None or workers > 1) and not dask_available():
            raise ParameterError(f"batches on several workers or a scheduler run on Dask, which is not "
                                 f"installed: {DASK_EXTRA}, or pass workers=1 (--workers 1)")
        if scheduler is None and workers <= 1:
            io.create_output_folder(outdir)  # nothing is created before the run can start
            for i, c in enumerate(cases):
                rows[i] = solve_case(c, outdir, solver, bucket, start)
                if report:
                    report(rows[i], i + 1, len(cases))
        else:
            _run_dask(cases, outdir, solver, bucket, workers, scheduler, report, chunk, rows, start)
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM/SIGHUP from the command line: say what finished
        if outdir.is_dir():
            with interrupt.deliberate():  # written although the interrupt is recorded
                write_summary(summary, [row or _interrupted_row(c, outdir, started) for row, c in zip(rows, cases)])
        raise
    write_summary(summary, rows)
    return rows


# --------------------------------------------------------------------- Dask

#: JAX settings copied from this process to every Dask task's worker, so that workers compute
#: the same numbers (x64) and share the persistent compilation cache
JAX_SETTINGS = ("jax_enable_x64", "jax_numpy_rank_promotion", "jax_enable_compilation_cache",
                "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
                "jax_persistent_cache_min_entry_size_bytes")


def jax_settings():
    """This process's :data:`JAX_SETTINGS`, as a dict for :func:`_apply_jax_settings`."""
    import jax

    return {k: getattr(jax.config, k) for k in JAX_SETTINGS}


def _apply_jax_settings(settings):
    """Apply ``settings`` (from :func:`jax_settings` in the client) in a worker; later calls
    find them in place.  A worker whose persistent cache was already opened elsewhere (an
    existing scheduler's worker that ran other work) reopens it in the client's folder."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    # importing this module ran geomopt's package configuration already (x64 on, the cache)
    changed = [k for k, v in settings.items() if v is not None and getattr(jax.config, k) != v]
    for key in changed:
        jax.config.update(key, settings[key])
    if any("cache" in key for key in changed):
        compilation_cache.reset_cache()  # the next compilation opens the client's folder


def _bucket_hint(folder):
    """``(dim, vertices, elements)`` bucket of a case from its files' raw counts (``v`` / ``f``
    lines, VTK ``POINTS`` / ``CELLS``), without parsing them; None when they do not say."""
    try:
        if (folder / "input.obj").is_file():
            data = b"\n" + (folder / "input.obj").read_bytes()
            return (2,) + (bucket_sizes(data.count(b"\nv "), data.count(b"\nf "), 2) or (0, 0))
        data = (folder / "rest.vtk").read_bytes()
        counts = []
        for word in (b"POINTS ", b"CELLS "):
            at = data.index(word) + len(word)
            counts.append(int(data[at:data.index(b" ", at)]))
        return (3,) + (bucket_sizes(counts[0], counts[1], 3) or (0, 0))
    except (OSError, ValueError):
        return None


def _tasks(cases, size):
    """Cases grouped by size bucket and cut into tasks of at most ``size`` cases, as
    ``[(first, rest)]`` per bucket: ``first`` is a one-case task that compiles the bucket,
    ``rest`` the tasks that should wait for it (then they load it from the persistent cache)."""
    groups = {}
    for i, c in enumerate(cases):
        groups.setdefault(_bucket_hint(c), []).append(i)
    out = []
    for key, idx in sorted(groups.items(), key=lambda kv: (kv[0] is None, kv[0] or ())):
        if key is None or key[1] == 0:  # unreadable, or not padded: no shared compilation
            out.append((None, [idx[i:i + size] for i in range(0, len(idx), size)]))
        else:
            out.append((idx[:1], [idx[i:i + size] for i in range(1, len(idx), size)]))
    return out


def _run_dask(cases, outdir, solver, bucket, workers, scheduler, report, chunk, rows, start="auto"):
    """Solve ``cases`` on Dask, filling ``rows`` (one per case) as they finish."""
    import contextlib
    import logging
    import uuid

    from distributed import Client, LocalCluster, as_completed

    from .. import io

    with contextlib.ExitStack() as stack:
        if scheduler is None:
            cluster = stack.enter_context(LocalCluster(
                n_workers=int(workers), threads_per_worker=1, processes=True, dashboard_address=":0",
                silence_logs=logging.ERROR))
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(scheduler, timeout=10))
            except (OSError, TimeoutError, ValueError) as exc:  # ValueError: not an address
                raise GeomoptError(f"cannot reach the Dask scheduler at {scheduler} ({exc}); check the "
                                   f"address (e.g. tcp://host:8786) or drop --scheduler to use a local "
                                   f"cluster") from exc
        io.create_output_folder(outdir)  # the run can start: nothing was created before
        settings = jax_settings()
        n_workers = max(1, len(client.scheduler_info(n_workers=-1)["workers"]))
        size = chunk or max(1, min(16, -(-len(cases) // (8 * n_workers))))
        run_id = uuid.uuid4().hex[:12]
        futures = {}

        def submit(group, after=None, priority=0):
            fut = client.submit(_solve_cases, [str(cases[i]) for i in group], str(outdir), solver, bucket,
                                settings, after, start, pure=False, priority=priority,
                                key=f"geomopt-batch-{run_id}-{len(futures)}")
            futures[fut] = (group, after is not None)
            return fut

        # each bucket's first case runs first, alone: the other tasks of its bucket wait for it
        # and then find its compiled kernels in the persistent cache (or in the worker's memory)
        plan = _tasks(cases, size)
        firsts = [submit(first, priority=1) if first else None for first, _ in plan]
        for (_, rest), first in zip(plan, firsts):
            for group in rest:
                submit(group, after=first)
        done = 0
        pending = as_completed(list(futures))
        for fut in pending:
            group, waited = futures[fut]
            try:
                got = fut.result()
            except Exception as exc:  # noqa: BLE001 -- a worker died: its cases are rows
                if waited:  # perhaps the task it waited for killed its worker: run it on its own
                    pending.add(submit(group))
                    continue
                got = [_failed_row(cases[i], f"the worker solving it failed: {type(exc).__name__}: {exc}")
                       for i in group]
            for i, row in zip(group, got):
                rows[i] = row
                done += 1
                if report:
                    report(row, done, len(cases))
    return rows


def _interrupted_row(folder, outdir, started):
    """The row of a case whose own row did not arrive before an interrupt: "not solved", or,
    when its output was written during this batch (only a certified file is ever written,
    :func:`solve_case`; a Dask worker may have written it before its row reached the client),
    certified with its statistics lost."""
    for ext in (".obj", ".vtk"):
        out = Path(outdir) / (Path(folder).name + ext)
        try:
            written = out.stat().st_mtime >= started
        except OSError:
            continue
        if written:
            row = _failed_row(folder, "the batch was interrupted after this case's certified output was "
                                      "written; its statistics were lost (summary incomplete)")
            row.update(certified="yes", output=out.name)
            return row
    return _failed_row(folder, "not solved: the batch was interrupted before this case finished "
                               "(summary incomplete)")


def _failed_row(folder, message):
    row = dict.fromkeys(SUMMARY_COLUMNS, "")
    row.update(case=Path(folder).name, certified="no", message=message)
    return row

"""``geomopt untangle``: one LIM case folder to one file, one tet / quad / hex mesh file or
quad / hex case folder to one file (:mod:`geomopt.mesh.cells`), or a batch of case folders to
an output folder (:mod:`geomopt.experiments.batch`).  Reads, calls the untangling, prints, and
writes only what certifies."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

from .common import (EXIT_EXCEPT_FIXED, EXIT_FAILED, EXIT_OK, cache_summary, cell_output, fail, log, output_paths,
                     quality_line, report, timed_solve)

__all__ = ["cmd_untangle"]


def cmd_untangle(args) -> int:
    """One case to one file (``-o OUT.obj|OUT.vtk``), or a batch to a folder (``-o OUTDIR``)."""
    from .._runtime.errors import ParameterError
    from ..mesh.cells import is_cell_case

    if len(args.case) == 1 and is_cell_case(args.case[0]):
        return _untangle_mesh(args)
    if args.rest is not None or args.handles is not None:
        raise ParameterError(f"--rest and --handles go with one mesh file (geomopt untangle TANGLED --rest REST "
                             f"-o OUT); {args.case[0] if len(args.case) == 1 else 'a batch'} "
                             f"{'holds its own rest mesh and handles' if len(args.case) == 1 else 'cannot take them'}")

    out = Path(args.output)
    to_file = out.suffix.lower() in (".obj", ".vtk") or (out.exists() and not out.is_dir())
    if to_file and not args.output.endswith(("/", os.sep)):
        if len(args.case) > 1:
            raise ParameterError(f"{len(args.case)} case folders need an output folder: -o must name a folder "
                                 f"(each case is written to it as <case>.obj/.vtk), got {args.output}")
        return _untangle_one(args, args.case[0])
    return _untangle_batch(args)


def _untangle_one(args, folder) -> int:
    from .._runtime.errors import ParameterError
    from .._runtime.timing import compile_seconds
    from ..lim import LimCase, output_suffix, untangle_case
    from ..mesh.quality import element_quality
    from ..untangling import UntangleOptions

    split = args.timing
    split.mark_imported()
    compile_seconds()  # starts counting JAX's compilation
    want = output_suffix(LimCase.dim_of(folder))
    if Path(args.output).suffix.lower() != want:
        raise ParameterError(f"{folder} is a {'2D' if want == '.obj' else '3D'} case: the output "
                             f"must be a {want} file, got {args.output}")
    output_paths(args.output, (want,), [("--png picture", args.png)] if args.png else [], [folder])
    with split.phase("read"):
        case = LimCase.read(folder)
        case.require_handles()
    case, res = timed_solve(split, lambda: untangle_case(case, solver=args.solver, progress=not args.quiet,
                                                         options=UntangleOptions(bucket=True, start=args.start)))
    st = res.stats
    with split.phase("certify"):
        quality = element_quality(res.x, case.simplices, case.to_problem().orientation)
    log(args, f"elements {res.problem.n_elements}  outer iterations {st.outer_iterations}  "
              f"seconds {st.seconds:.2f}  compile seconds {st.setup_seconds:.2f}  "
              f"inverted {res.certificate.inverted}  certified {'yes' if res.success else 'no'}")
    log(args, f"quality: smallest size / mean {quality['min_size_ratio']:.4g}, scaled Jacobian min "
              f"{quality['min_scaled_jacobian']:.4g} mean {quality['mean_scaled_jacobian']:.4g}")
    report(args, case=str(folder), output=str(args.output), dim=case.dim, vertices=len(res.x),
           elements=res.problem.n_elements, inverted_before=st.inverted_at_start, inverted=res.certificate.inverted,
           outer_iterations=st.outer_iterations, inner_iterations=st.iterations,
           evaluations=st.evaluations, solve_seconds=round(st.seconds, 4),
           setup_seconds=round(st.setup_seconds, 4), handles_moved=res.certificate.handles_moved,
           start=getattr(res.details, "start", None), min_det_rel=res.min_det_rel, outcome=res.outcome.value,
           certified=bool(res.success), message=res.message, forced_overlaps=_forced_overlaps(res), **quality,
           **cache_summary())
    orientation = case.to_problem().orientation  # the input's own connectivity and frame
    return _written_untangled(args, res, lambda: case.write_certified(res, args.output),
                              lambda png, fmt: _save_untangle_figure(png, case.init, res.x, case.simplices,
                                                                     orientation, str(case.path or ""), fmt))


def _written_untangled(args, res, write, picture) -> int:
    """The exit status of an untangled case, its file written by ``write()`` (certified on the file)
    and its ``--png`` by ``picture(file, format)`` only when the map is certified, or certified except
    where the input's handles alone make it overlap (exit 3, said even with --quiet)."""
    from .. import io
    from ..solvers import Outcome

    except_fixed = res.outcome is Outcome.CERTIFIED_EXCEPT_FIXED
    if not (res.success or except_fixed):
        return fail(f"not certified: {res.message}")
    # written beside the output and certified there: a file that does not certify never replaces it
    with contextlib.ExitStack() as outputs:  # the picture lands only with a certified output
        if args.png:
            picture(outputs.enter_context(io.atomic_output(args.png, "wb")), Path(args.png).suffix[1:].lower())
        with args.timing.phase("write"):
            write()
    if except_fixed:  # written, and said even with --quiet: the input's handles make it overlap
        print(f"geomopt: warning: {args.output} written but not certified everywhere: {res.message}",
              file=sys.stderr, flush=True)
        return EXIT_EXCEPT_FIXED
    return EXIT_OK


def _forced_overlaps(res) -> int:
    """Vertices and edges where the handles alone make every map overlap (the input's
    ``Problem.certify_fixed``), as the result's certificate lists them."""
    forced = getattr(res.certificate, "forced", None)
    return 0 if forced is None else forced.failures


def _untangle_mesh(args) -> int:
    """One tet / quad / hex mesh file (rest shapes from ``--rest`` or reference squares / cubes,
    handles from ``--handles`` or the boundary) or quad / hex case folder (:mod:`geomopt.mesh.cells`)
    to one certified file: one path for every kind of element."""
    from .._runtime.errors import ParameterError
    from .._runtime.timing import compile_seconds
    from ..io import CELL_WORDS
    from ..mesh.cells import case_inputs, cell_problem, read_cell_case, write_certified
    from ..mesh.quality import quality_summary
    from ..untangling import UntangleOptions, untangle

    path = Path(args.case[0])
    inputs = case_inputs(path, args.rest, args.handles)
    split = args.timing
    split.mark_imported()
    compile_seconds()  # starts counting JAX's compilation
    with split.phase("read"):
        case = read_cell_case(path, rest=args.rest, handles=args.handles)  # -o's check needs the kind
    if args.png and case.kind != "tetra":
        raise ParameterError("--png draws triangle and tet cases only; leave it out for a quad/hex case")
    cell_output(args, case, inputs, [("--png picture", args.png)] if args.png else [])
    with split.phase("setup"):
        problem = cell_problem(case)
        _refuse_infeasible(problem, case)
        before = quality_summary(problem, case.start)
    res = timed_solve(split, lambda: untangle(problem, case.start, solver=args.solver, progress=not args.quiet,
                                                    options=UntangleOptions(start=args.start)))
    with split.phase("certify"):
        after = quality_summary(problem, res.x)
    words = CELL_WORDS[case.kind][1]
    log(args, f"{len(case.elements)} {words}: before {quality_line(before)}, {before['invalid']} invalid")
    tests = f" ({after['corner_only']} only inside); tests {after['tests']}" if after["tests"] else ""
    log(args, f"after  {quality_line(after)}, {after['invalid']} invalid{tests}; outer iterations "
              f"{res.stats.outer_iterations}, "
              f"{res.stats.seconds:.2f} s from the {getattr(res.details, 'start', 'given')} map, certified "
              f"{'yes' if res.success else 'no'}")
    report(args, case=str(path), rest=args.rest, handles_file=args.handles, output=str(args.output), dim=problem.dim,
           vertices=len(res.x), elements=len(case.elements), kind=case.kind, inverted_before=before["invalid"],
           inverted=res.certificate.inverted, outer_iterations=res.stats.outer_iterations,
           inner_iterations=res.stats.iterations, evaluations=res.stats.evaluations,
           solve_seconds=round(res.stats.seconds, 4), setup_seconds=round(res.stats.setup_seconds, 4),
           fixed_vertices=len(problem.fixed), handles_moved=res.certificate.handles_moved,
           start=getattr(res.details, "start", None), min_det_rel=res.min_det_rel, outcome=res.outcome.value,
           certified=bool(res.success), message=res.message, forced_overlaps=_forced_overlaps(res),
           min_size_ratio=res.min_det_rel, min_scaled_jacobian=after["sj_min"],
           mean_scaled_jacobian=after["sj_mean"], before=before, after=after, **cache_summary())
    forced = getattr(res.certificate, "forced", None)
    return _written_untangled(args, res, lambda: write_certified(args.output, res.x, case, problem, forced=forced),
                              lambda png, fmt: _save_untangle_figure(png, case.start, res.x, problem.simplices,
                                                                     1, str(path), fmt))


def _refuse_infeasible(problem, case) -> None:
    """Bad input (exit 2) when no map with these handles can be injective
    (:func:`geomopt.untangling.infeasible`), decided before solving; blamed on the rest mesh when
    it was read negatively oriented (a mirror image of the tangled mesh)."""
    import numpy as np

    from .._runtime.errors import MeshError
    from ..mesh.orientation import fixed_total_problem
    from ..untangling import infeasible

    why = infeasible(problem, case.start)
    if why is None:
        return
    reversed_rest = not np.array_equal(problem.simplices if problem.elements is None else problem.elements,
                                       case.elements)  # read negatively oriented: the elements were reversed
    if case.rest is not None and reversed_rest and fixed_total_problem(problem, case.start):
        raise MeshError(f"the rest mesh's {len(case.elements)} elements are negatively oriented, and the "
                        f"handles of the tangled mesh enclose a positive volume: the rest mesh is a mirror "
                        f"image of the tangled one; give the rest mesh unmirrored (negate one coordinate)")
    raise MeshError(why)


def _untangle_batch(args) -> int:
    from ..experiments.batch import (DASK_EXTRA, EXCEPT_FIXED, batch_cases, dask_available, default_workers,
                                     run_batch, tally)

    cases = batch_cases(args.case)
    workers = args.workers or default_workers(len(cases))
    if args.workers is None and args.scheduler is None and workers > 1 and not dask_available():
        print(f"geomopt: solving the cases one after another in this process (Dask is not installed; "
              f"{DASK_EXTRA} to use {workers} worker processes)", file=sys.stderr, flush=True)
        workers = 1
    where = (f"the Dask scheduler at {args.scheduler}" if args.scheduler else
             f"{workers} local worker process(es)" if workers > 1 else "this process")
    log(args, f"{len(cases)} case(s) to {args.output}, on {where}")

    def say(row, done, total):
        status = {"yes": "certified", EXCEPT_FIXED: f"written, certified except where the handles fix it: "
                  f"{row['message']}"}.get(row["certified"], f"not certified: {row['message']}")
        log(args, f"[{done}/{total}] {row['case']}: {status} ({row['seconds']} s)")

    rows = run_batch(cases, args.output, solver=args.solver, workers=workers, scheduler=args.scheduler,
                     report=say, start=args.start)
    certified, except_fixed, failed = tally(rows)
    summary = Path(args.output) / "summary.csv"
    report(args, output=str(args.output), summary=str(summary), workers=workers, scheduler=args.scheduler,
           cases=len(rows), certified=certified, certified_except_fixed=except_fixed,
           not_certified=failed, rows=rows, **cache_summary())
    if failed:
        print(f"geomopt: {failed} of {len(rows)} case(s) not certified (no output written for them); "
              f"see {summary}", file=sys.stderr, flush=True)
        return EXIT_FAILED
    if except_fixed:
        print(f"geomopt: warning: {except_fixed} of {len(rows)} case(s) written but not certified everywhere: "
              f"their handles alone make them overlap (certified = {EXCEPT_FIXED}); see {summary}",
              file=sys.stderr, flush=True)
        return EXIT_EXCEPT_FIXED
    log(args, f"all {len(rows)} case(s) certified; summary in {summary}")
    return EXIT_OK


def _save_untangle_figure(png, start, x, S, orientation, title, format=None):
    """Start and result maps with the elements ``S`` (triangles or tetrahedra) not oriented as
    ``orientation`` (+1 or -1; exact predicate) marked."""
    from .. import plot
    from ..exact.predicates import simplex_orientations

    bad = [simplex_orientations(m, S) != orientation for m in (start, x)]
    plot.save_untangle_figure(png, start, x, S, *bad, title=title, format=format)

"""``geomopt smooth``: a valid quad / hex mesh smoothed (:func:`geomopt.smoothing.smooth`) and
written as a certified file (:func:`geomopt.mesh.cells.write_certified`) only when no element
got worse than the input's worst."""

from __future__ import annotations

from .common import EXIT_OK, cache_summary, cell_output, fail, log, quality_line, report

__all__ = ["cmd_smooth"]


def cmd_smooth(args) -> int:
    """Smooth a valid quad / hex mesh (:func:`geomopt.smooth`) into a certified file."""
    from ..mesh.cells import SMOOTH_KINDS, read_cell_case, write_certified
    from ..smoothing import SmoothOptions, smooth

    split = args.timing
    split.mark_imported()
    with split.phase("read"):
        case = read_cell_case(args.input, kinds=SMOOTH_KINDS)
    cell_output(args, case, [args.input])
    fixed = None if args.fix == "boundary" else []
    with split.phase("solve"):  # smooth's rounds, each solved and certified
        res = smooth(case.start, case.elements, energy=args.energy, solver=args.solver, fixed=fixed,
                     options=SmoothOptions(max_steps=args.max_steps), progress=not args.quiet)
    d, st = res.details, res.stats
    seconds = st.seconds + st.setup_seconds  # every solve, set-up included
    log(args, f"{len(case.elements)} {case.kind} elements: before {quality_line(d.before)}")
    log(args, f"after  {quality_line(d.after)}; tests {d.elements.summary()['tests']}; "
              f"{st.iterations} iterations, {seconds:.2f} s")
    report(args, input=str(args.input), output=str(args.output), elements=len(case.elements), kind=case.kind,
           before=d.before.as_dict(), after=d.after.as_dict(), held=len(d.held), rounds=st.outer_iterations,
           improved=d.improved, outcome=res.outcome.value, iterations=st.iterations,
           solve_seconds=round(seconds, 4), message=d.message, **cache_summary())
    if not d.improved:
        return fail(f"not improved (no smoothing keeps every element at least as good as the input's worst): "
                    f"{d.message}" + (f"; {res.reason}" if res.reason else ""))
    handles = res.problem.fixed, res.problem.fixed_positions / d.scale  # in the file's frame (exact: a power of 2)
    with split.phase("write"):
        write_certified(args.output, res.x, case, res.problem.with_fixed(*handles))
    return EXIT_OK

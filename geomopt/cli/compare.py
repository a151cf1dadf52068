"""``geomopt compare``: several solvers from the same start on one mesh or several
(:mod:`geomopt.experiments.comparison`); prints the report and which solver failed, and
reports the files written."""

from __future__ import annotations

import sys
from pathlib import Path

from .common import log, report

__all__ = ["cmd_compare"]


def cmd_compare(args) -> int:
    """Every solver from the same start map, on one mesh or several: traces, summary, LaTeX
    table, manifest, maps and the convergence figure in -o (see geomopt.experiments.comparison).

    Exit status 0 only when every solver converged to a certified map and no iterate had an
    inverted element; else 1, after writing every file, with one line naming each solver and why."""
    from ..experiments.comparison import ComparisonSet, compare, compare_meshes, exit_status
    from ..experiments.options import CompareOptions

    options = CompareOptions(weights=args.weights, max_seconds=args.max_seconds, max_steps=args.max_steps,
                             reference=args.reference, repeat=args.repeat,
                             tolerances=_floats(args.tolerances, "--tolerances"), formats=_names(args.format),
                             log_x=args.log_x, clock=args.clock, warmup=args.warmup, layout=args.layout,
                             font_size=args.font_size)
    run = dict(energy=args.energy, solvers=args.solvers, options=options, out=args.output, progress=not args.quiet)
    res = compare(args.mesh[0], **run) if len(args.mesh) == 1 else compare_meshes(args.mesh, **run)
    log(args, res.report())
    files = res.output_names(options.formats)
    log(args, f"wrote {', '.join(files)} in {args.output}")
    items = res.comparisons if isinstance(res, ComparisonSet) else {Path(args.mesh[0]).name: res}
    report(args, output=str(args.output), files=files, repeat=args.repeat, tolerances=options.tolerances,
           meshes=[{"mesh": key, "label": c.label, "elements": c.objective.problem.n_elements,
                    "energy_name": c.objective.energy.name, "rest_area": c.area,
                    "reference": {"source": c.reference.source, "energy": c.reference.energy,
                                  "mean_energy": c.reference_mean_energy},
                    "solvers": c.summary_rows()} for key, c in items.items()])
    code = exit_status(res)
    if code:
        bad = [f"{key}: {row['solver']} ({row['outcome']}{'' if row['certified'] else ', not certified'})"
               for key, c in items.items() for row in c.summary_rows()
               if row["outcome"] != "converged" or not row["certified"]]
        print(f"geomopt: error: not every solver converged with a certified map: {'; '.join(bad)}; files written",
              file=sys.stderr, flush=True)
    return code


def _names(text):
    return tuple(s.strip().lower() for s in text.split(",") if s.strip())


def _floats(text, option):
    from .._runtime.errors import ParameterError

    try:
        return tuple(float(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise ParameterError(f"{option} takes comma-separated numbers (e.g. 1e-2,1e-4,1e-6), got {text!r}") from None

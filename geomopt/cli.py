"""Command line: geomopt param, geomopt untangle, geomopt smooth, geomopt demo.

Every failure on bad input (unreadable or invalid mesh, unknown name, invalid value, output
that cannot be written) prints one line ``geomopt: error: ...`` and exits with status 2 (no
traceback unless ``--debug``); a solve that does not end converged and flip-free (exact
predicate) exits with status 1 and writes nothing; status 0 means the certified result was
written.  Every output path (derived ones included) is checked before the input is read: it
must be a regular file or not exist.  Outputs are written atomically, all of them or none; an
interrupt (SIGINT, SIGTERM, SIGHUP) removes the unfinished temporary files and exits with
status 128 + the signal number.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import sys
import time
from pathlib import Path

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2

#: Picture formats ``--png`` writes (matplotlib's own backends, no extra dependency).
PICTURE_EXTENSIONS = (".png", ".pdf", ".svg")


def _log(args, *msg):
    if not args.quiet:
        print(*msg, file=sys.stderr, flush=True)


def _solver(name):
    from . import solvers

    return solvers.get_solver(name)


def _fail(message) -> int:
    """Report a result that is not certified (printed even with --quiet); exit status 1."""
    print(f"geomopt: error: {message}; nothing written", file=sys.stderr, flush=True)
    return EXIT_FAILED


class _Interrupted(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C so that unfinished outputs are cleaned up."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


def _raise_interrupted(signum, frame):
    raise _Interrupted(signum)


@contextlib.contextmanager
def _signals_raise():
    """While the block runs, SIGTERM and SIGHUP raise :class:`_Interrupted` (SIGINT already raises
    KeyboardInterrupt), so the atomic writers delete their temporary files; restored afterwards."""
    previous = {}
    for name in ("SIGTERM", "SIGHUP"):
        signum = getattr(signal, name, None)
        if signum is None:
            continue
        try:
            previous[signum] = signal.signal(signum, _raise_interrupted)
        except ValueError:  # not the main thread: leave the handlers alone
            break
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _output_paths(output, extensions, pictures=(), inputs=()):
    """Check every output before any work: ``-o`` (``extensions``) and ``pictures`` (with their
    derived names); they must be distinct and none may be one of the ``inputs`` (writing it would
    replace what the user asked to read).  Returns the output path."""
    from . import io
    from ._errors import GeomoptError

    named = [("-o output", output)] + [(what, p) for what, p in pictures]
    seen = {}
    for what, p in named:
        for source in inputs:
            if os.path.isfile(p) and os.path.isfile(source) and os.path.samefile(p, source):
                raise GeomoptError(f"{what} {p} is the input file {source}: writing it would replace your "
                                   "input; give the output another name")
        key = os.path.join(os.path.realpath(os.path.dirname(os.path.abspath(p))), os.path.basename(p))
        if key in seen:
            raise GeomoptError(f"{what} {p} is the same file as the {seen[key]}; give different file names")
        seen[key] = what
    out = io.check_output_path(output, extensions, "output")
    for what, p in pictures:
        io.check_output_path(p, PICTURE_EXTENSIONS, what)
    return out


def cmd_param(args) -> int:
    from . import io
    from ._errors import MeshError
    from .energies import get_energy
    from .param import parameterize

    energy = get_energy(args.energy)
    solver = _solver(args.solver)
    if args.max_steps is not None:
        import dataclasses

        solver = dataclasses.replace(solver, max_steps=args.max_steps)
    pictures = []
    if args.png:
        pictures = [("--png picture", args.png), ("convergence picture", str(_convergence_path(args.png)))]
    _output_paths(args.output, io.UV_MESH_EXTENSIONS, pictures, [args.input])  # before reading or solving
    if args.init == "uv":
        V, F, x0 = io.read_obj_uv(args.input)
        start = "its own UV start map"
    else:
        V, F = io.read_mesh(args.input)
        x0 = None if args.init == "tutte" else args.init
        start = f"{args.weights} Tutte start" if args.init == "tutte" else "plane projection start"
    _log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; energy {energy.name}, "
               f"solver {args.solver}, {start}")
    if Path(args.input).suffix.lower() == ".stl":
        _log(args, f"{args.input}: STL stores every triangle's corners separately; welded the "
                   f"{3 * len(F)} corners with bit-identical coordinates into {len(V)} vertices")
    try:
        res = parameterize(V, F, energy=energy, solver=solver, weights=args.weights, x0=x0,
                           progress=not args.quiet, bijective=args.bijective)
    except MeshError as exc:
        raise _for_the_command_line(exc, args) from exc
    rep = res.info.get("repair")
    if rep is not None:
        _log(args, f"repaired the start map's {rep.initially_inverted} folded triangle(s), boundary held: "
                   f"{rep.outer_iterations} outer iterations, {rep.seconds:.2f} s, "
                   f"{'certified' if rep.success else 'not certified: ' + rep.message}")
    if rep is not None and not rep.success:
        return _fail(f"the start map could not be repaired: {rep.message}")
    mean = res.energy / res.info["objective"].total_volume
    _log(args, f"faces {len(F)}  iterations {res.iterations}  seconds {res.seconds:.2f}  "
               f"compile seconds {res.setup_seconds:.2f}  energy {mean:.10g}  flips {res.inverted}  "
               f"injective {res.injectivity}  outcome {res.outcome.value}")
    _report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F),
            energy_name=energy.name, solver=args.solver, iterations=res.iterations,
            solve_seconds=round(res.seconds, 4), setup_seconds=round(res.setup_seconds, 4),
            energy=res.energy, mean_energy=mean, flips=res.inverted, injectivity=res.injectivity,
            boundary_crossings=_boundary_crossings(res),
            outcome=res.outcome.value, message=res.message, **_cache_summary())
    if not res.success:
        return _fail(f"not certified: {res.message}")
    if res.injectivity == "local":
        _warn_overlap(res, args)
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            _save_param_figures(res, V, F, args.png, outputs, args.solver)
        io.write_mesh_with_uv(outputs.enter_context(io.atomic_path(args.output)), V, F, res.x,
                              format=Path(args.output).suffix[1:])
    return EXIT_OK


def _warn_overlap(res, args):
    """Say (even with --quiet) that a flip-free UV map is not a bijection: its boundary overlaps
    itself, so two parts of the surface share UV coordinates; and what to do about it."""
    count = _boundary_crossings(res)
    print(f"geomopt: warning: the UV map is only locally injective (no flipped triangle), not "
          f"globally: its boundary crosses itself"
          f"{'' if count is None else f' ({count} crossing boundary edge pair(s))'}, so parts of "
          f"the surface overlap in UV; rerun with --bijective for a map certified globally "
          f"injective", file=sys.stderr, flush=True)


def _boundary_crossings(res):
    """Crossing boundary edge pairs by the result's global certificate, None without one."""
    cert = res.info.get("certificate")
    return None if cert is None else len(cert.crossings)


def _for_the_command_line(exc, args):
    """A library message that names an API the command line does not offer, reworded."""
    from ._errors import MeshError

    found = re.match(r"the Tutte start map has (\d+) inverted or degenerate triangle\(s\)", str(exc))
    if found is None:
        return exc
    return MeshError(
        f"the {args.weights} Tutte start map of {args.input} has {found.group(1)} inverted or degenerate "
        f"triangle(s) (rounding on badly shaped triangles), where the barrier energy {args.energy!r} is "
        f"infinite; try --weights {'uniform' if args.weights != 'uniform' else 'mean_value'}, an energy "
        f"without a barrier, or remesh the input")


def _convergence_path(png):
    """The convergence picture saved beside the ``--png`` layout: ``<stem>_convergence<suffix>``."""
    base = Path(png)
    return base.with_name(base.stem + "_convergence" + base.suffix)


def _cache_summary() -> dict:
    from ._cache import cache_stats

    st = cache_stats()
    return {"cache_dir": st["dir"], "cache_hits": st["hits"], "cache_misses": st["misses"]}


def _save_param_figures(res, V, F, png, outputs, solver_name):
    """Render the layout and convergence pictures into atomic temporaries registered on ``outputs``."""
    import numpy as np

    from . import io, plot
    from ._objective import element_densities

    obj = res.info["objective"]
    dens = np.asarray(element_densities(obj, res.x))
    base, conv = Path(png), _convergence_path(png)
    plot.save_param_figure(outputs.enter_context(io.atomic_output(base, "wb")), V, F, res.x,
                           np.log10(np.maximum(dens / obj.energy.value_at_rest(2), 1.0))
                           if obj.energy.value_at_rest(2) else dens,
                           title=f"UV layout, {obj.energy.name} (log10 of density / isometric value)",
                           label="log10 distortion", format=base.suffix[1:].lower())
    plot.save_convergence(outputs.enter_context(io.atomic_output(conv, "wb")),
                          {solver_name: (res.time_history, res.energy_history)},
                          title=f"convergence ({len(F)} faces)", format=conv.suffix[1:].lower())
    return base, conv


def cmd_untangle(args) -> int:
    """One case to one file (``-o OUT.obj|OUT.vtk``), or a batch to a folder (``-o OUTDIR``)."""
    from ._errors import ParameterError
    from .cells import is_cell_case

    if len(args.case) == 1 and is_cell_case(args.case[0]):
        return _untangle_cells(args)

    out = Path(args.output)
    to_file = out.suffix.lower() in (".obj", ".vtk") or (out.exists() and not out.is_dir())
    if to_file and not args.output.endswith(("/", os.sep)):
        if len(args.case) > 1:
            raise ParameterError(f"{len(args.case)} case folders need an output folder: -o must name a folder "
                                 f"(each case is written to it as <case>.obj/.vtk), got {args.output}")
        return _untangle_one(args, args.case[0])
    return _untangle_batch(args)


def _untangle_one(args, folder) -> int:
    from . import io
    from ._errors import ParameterError
    from .batch import check_handles, write_certified
    from .lim import LimCase
    from .untangle import untangle_case

    want = ".obj" if LimCase.dim_of(folder) == 2 else ".vtk"
    if Path(args.output).suffix.lower() != want:
        raise ParameterError(f"{folder} is a {'2D' if want == '.obj' else '3D'} case: the output "
                             f"must be a {want} file, got {args.output}")
    _output_paths(args.output, (want,), [("--png picture", args.png)] if args.png else [],
                  [str(p) for p in Path(folder).iterdir()])
    case = LimCase.read(folder)
    check_handles(case)
    case, res = untangle_case(case, solver=args.solver, progress=not args.quiet, bucket=True)
    _log(args, f"elements {res.info.get('elements', '?')}  outer iterations {res.outer_iterations}  "
               f"seconds {res.seconds:.2f}  compile seconds {res.setup_seconds:.2f}  "
               f"inverted {res.inverted}  certified {'yes' if res.success else 'no'}")
    _report(args, case=str(folder), output=str(args.output), elements=res.info.get("elements"),
            outer_iterations=res.outer_iterations, solve_seconds=round(res.seconds, 4),
            setup_seconds=round(res.setup_seconds, 4), inverted=res.inverted, certified=bool(res.success),
            message=res.message, **_cache_summary())
    if not res.success:
        return _fail(f"not certified: {res.message}")
    # written beside the output and certified there: a file that does not certify never replaces it
    with contextlib.ExitStack() as outputs:  # the picture lands only with a certified output
        if args.png:
            _save_untangle_figure(case, res, outputs.enter_context(io.atomic_output(args.png, "wb")),
                                  Path(args.png).suffix[1:].lower())
        write_certified(case, res, args.output)
    return EXIT_OK


def _cell_output(args, case, inputs):
    """Check ``-o`` for a quad / hex case (:data:`geomopt.cells.CELL_EXTENSIONS`, ``.obj`` for quads)."""
    from .cells import CELL_EXTENSIONS

    allowed = CELL_EXTENSIONS if case.kind == "quad" else tuple(e for e in CELL_EXTENSIONS if e != ".obj")
    _output_paths(args.output, allowed, [], inputs)


def _quality_line(q):
    return (f"min scaled Jacobian {q.min:.4f}, mean {q.mean:.4f}, {q.below_0} below 0, "
            f"{q.below_0_2} below 0.2")


def _untangle_cells(args) -> int:
    """A quad / hex mesh file or case folder (:mod:`geomopt.cells`) to one certified file."""
    from .cells import cell_problem, read_cell_case, write_certified
    from .elements import certify_elements
    from .untangle import untangle

    path = Path(args.case[0])
    inputs = [str(p) for p in path.iterdir()] if path.is_dir() else [str(path)]
    if args.png:
        from ._errors import ParameterError

        raise ParameterError("--png draws triangle and tet cases only; leave it out for a quad/hex case")
    case = read_cell_case(path)  # the output check needs the cell kind; reading writes nothing
    _cell_output(args, case, inputs)
    problem = cell_problem(case)
    before = certify_elements(case.start, problem.elements)
    res = untangle(problem, case.start, solver=args.solver, progress=not args.quiet)
    after = certify_elements(res.x, problem.elements)
    _log(args, f"{len(case.elements)} {case.kind} elements: before {_quality_line(before.quality)}, "
               f"{before.invalid} invalid")
    _log(args, f"after  {_quality_line(after.quality)}, {after.invalid} invalid ({after.corner_only} only inside); "
               f"tests {after.summary()['tests']}; outer iterations {res.outer_iterations}, "
               f"{res.seconds:.2f} s, certified {'yes' if res.success else 'no'}")
    _report(args, case=str(path), output=str(args.output), elements=len(case.elements), kind=case.kind,
            outer_iterations=res.outer_iterations, solve_seconds=round(res.seconds, 4),
            setup_seconds=round(res.setup_seconds, 4), inverted=res.inverted, certified=bool(res.success),
            message=res.message, before=before.summary(), after=after.summary(), **_cache_summary())
    if not res.success:
        return _fail(f"not certified: {res.message}")
    write_certified(args.output, res.x, case, problem)
    return EXIT_OK


def cmd_smooth(args) -> int:
    """Smooth a valid quad / hex mesh (:func:`geomopt.smooth.smooth`) into a certified file."""
    from .cells import read_cell_case, write_certified
    from .smooth import smooth

    case = read_cell_case(args.input)
    _cell_output(args, case, [args.input])
    fixed = None if args.fix == "boundary" else []
    res = smooth(case.start, case.elements, energy=args.energy, solver=args.solver, fixed=fixed,
                 max_steps=args.max_steps, progress=not args.quiet)
    _log(args, f"{len(case.elements)} {case.kind} elements: before {_quality_line(res.before)}")
    _log(args, f"after  {_quality_line(res.after)}; tests {res.certificate.summary()['tests']}; "
               f"{res.iterations} iterations, {res.seconds:.2f} s")
    _report(args, input=str(args.input), output=str(args.output), elements=len(case.elements), kind=case.kind,
            before=res.before.as_dict(), after=res.after.as_dict(), held=len(res.held), rounds=res.rounds,
            improved=res.improved, iterations=res.iterations, solve_seconds=round(res.seconds, 4),
            message=res.message, **_cache_summary())
    if not res.improved:
        return _fail(f"not improved (no smoothing keeps every element at least as good as the input's worst): "
                     f"{res.message}")
    write_certified(args.output, res.x, case, res.problem)
    return EXIT_OK


def _untangle_batch(args) -> int:
    from .batch import batch_cases, run_batch

    cases = batch_cases(args.case)
    workers = args.workers or min(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                  else (os.cpu_count() or 1), len(cases))
    where = (f"the Dask scheduler at {args.scheduler}" if args.scheduler else
             f"{workers} local worker process(es)" if workers > 1 else "this process")
    _log(args, f"{len(cases)} case(s) to {args.output}, on {where}")

    def report(row, done, total):
        status = "certified" if row["certified"] == "yes" else f"not certified: {row['message']}"
        _log(args, f"[{done}/{total}] {row['case']}: {status} ({row['seconds']} s)")

    rows = run_batch(cases, args.output, solver=args.solver, workers=workers, scheduler=args.scheduler,
                     report=report)
    failed = sum(row["certified"] != "yes" for row in rows)
    summary = Path(args.output) / "summary.csv"
    if failed:
        print(f"geomopt: {failed} of {len(rows)} case(s) not certified (no output written for them); "
              f"see {summary}", file=sys.stderr, flush=True)
        return EXIT_FAILED
    _log(args, f"all {len(rows)} case(s) certified; summary in {summary}")
    return EXIT_OK


def _save_untangle_figure(case, res, png, format=None):
    """Start and result with inverted elements (exact predicate, in the orientation the
    output must have) marked."""
    from . import plot
    from .predicates import simplex_orientations

    S = case["faces"] if case["dim"] == 2 else case["tets"]
    start = case["init"][:, :2] if case["dim"] == 2 else case["init"]
    bad = [simplex_orientations(x, S) != case["orientation"] for x in (start, res.x)]
    plot.save_untangle_figure(png, start, res.x, S, *bad, title=str(case.get("path", "")), format=format)


def cmd_demo(args) -> int:
    """Parameterize the bundled camelhead and write OBJ + UV picture + convergence plot."""
    from ._errors import GeomoptError

    out = Path(args.output)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise GeomoptError(f"cannot create the output folder {out} ({exc.strerror}); "
                           f"give a folder path") from exc
    data = Path(__file__).with_name("data") / "camelhead.off"
    ns = argparse.Namespace(input=str(data), output=str(out / "camelhead_uv.obj"),
                            energy="symmetric_dirichlet", solver="newton", weights="uniform", init="tutte", bijective=False,
                            max_steps=None, quiet=args.quiet, png=str(out / "camelhead_uv.png"),
                            json=args.json, summary=args.summary)
    code = cmd_param(ns)
    if code == EXIT_OK and not args.json:  # --json: stdout holds only the summary
        print(f"wrote {out / 'camelhead_uv.obj'}, {out / 'camelhead_uv.png'}, "
              f"{out / 'camelhead_uv_convergence.png'}")
    return code


def cmd_compare(args) -> int:
    """Every solver from the same start map; CSV traces, summary, maps and a plot in --out."""
    from ._compare import compare

    res = compare(args.mesh, solvers=args.solvers, energy=args.energy, weights=args.weights,
                  max_seconds=args.max_seconds, max_steps=args.max_steps, out=args.out,
                  progress=not args.quiet)
    _log(args, res.report())
    _log(args, f"wrote {', '.join(res.output_names())} in {args.out}")
    folded = [name for name, r in res.results.items() if r.info["flips_history"].max() > 0]
    if folded:
        print(f"geomopt: error: inverted elements during the solve of {', '.join(folded)} (see the "
              f"flips column of {Path(args.out) / 'history.csv'}); files written", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _positive_int(text) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def build_parser():
    from . import __version__
    from ._names import ENERGIES, SOLVERS

    p = argparse.ArgumentParser(
        prog="geomopt", description="Locally injective (foldover-free) maps of triangle and tet meshes.",
        epilog=f"energies: {', '.join(ENERGIES)}. solvers: {', '.join(SOLVERS)}. Compiled code is "
               f"cached in $GEOMOPT_CACHE_DIR (default ~/.cache/geomopt/jax; 'off' disables it). "
               f"Run 'geomopt COMMAND --help' for a command's options.")
    p.add_argument("--version", action="version", version=f"geomopt {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp):
        sp.add_argument("--quiet", action="store_true", help="no progress or summary output")
        sp.add_argument("--json", action="store_true",
                        help="print a one-line JSON summary on stdout (also on failure)")
        sp.add_argument("--debug", action="store_true", help="show tracebacks on errors")

    sp = sub.add_parser("param", help="parameterize a disk-topology surface (free boundary)")
    sp.add_argument("input", help="triangle mesh (OBJ/OFF/PLY/STL), one boundary loop")
    sp.add_argument("-o", "--output", required=True,
                    help="output .obj (one vt per vertex) or .ply (binary, double x y z u v)")
    sp.add_argument("--energy", default="symmetric_dirichlet", metavar="NAME",
                    help=f"one of {', '.join(ENERGIES)} (default symmetric_dirichlet)")
    sp.add_argument("--solver", default="newton", metavar="NAME",
                    help=f"one of {', '.join(SOLVERS)} (default newton)")
    sp.add_argument("--weights", default="uniform", choices=["uniform", "mean_value"],
                    help="Tutte weights of the start map")
    sp.add_argument("--init", default="tutte", choices=["tutte", "projection", "uv"],
                    help="start map: Tutte embedding (default), the best-fit plane projection, or the "
                         "input OBJ's own vt map; a start with folded triangles is first repaired with a "
                         "free boundary (Garanzha et al.'s untangling)")
    sp.add_argument("--bijective", action="store_true",
                    help="keep the boundary from crossing itself (a scaffold around the mesh): a globally "
                         "injective map, certified exactly")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit (>= 1)")
    sp.add_argument("--png", default=None,
                    help="also save the UV map (checkerboard on the surface beside the distortion layout; "
                         ".png, .pdf or .svg) and a <name>_convergence plot")
    common(sp)
    sp.set_defaults(func=cmd_param)

    sp = sub.add_parser("untangle", help="untangle LIM benchmark cases (fixed handles) or a quad/hex mesh")
    sp.add_argument("case", nargs="+",
                    help="case folder (input.obj + handles.txt in 2D, rest.vtk + init.vtk in 3D, with "
                         "triangles, tets, quads or hexahedra), or several, or folders holding case "
                         "folders; or one quad/hex mesh file (.vtk .vtu .msh .mesh, .obj for quads), "
                         "untangled with its boundary fixed and squares/cubes as rest shapes")
    sp.add_argument("-o", "--output", required=True,
                    help="one case: output OBJ (2D) or VTK (3D), any quad/hex mesh format for a quad/hex "
                         "case; otherwise an output folder, which gets <case folder name>.obj/.vtk per "
                         "certified case and summary.csv")
    sp.add_argument("--solver", default="lbfgs", choices=["lbfgs", "newton"],
                    help="inner solver (default lbfgs, measured fastest for untangling)")
    sp.add_argument("--png", default=None,
                    help="also save a picture of the start and the result, inverted elements in red")
    where = sp.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_positive_int, default=None,
                       help="batch: solve on a local Dask cluster of N worker processes (default: one "
                            "per CPU core; 1 solves in this process)")
    where.add_argument("--scheduler", default=None,
                       help="batch: solve on the workers of an existing Dask scheduler (e.g. "
                            "tcp://host:8786); they must see the case and output folders at the same paths")
    common(sp)
    sp.set_defaults(func=cmd_untangle)

    sp = sub.add_parser("smooth", help="smooth a valid quad/hex mesh (Winslow), never making an element worse "
                                       "than the input's worst")
    sp.add_argument("input", help="quad or hex mesh (.vtk .vtu .msh .mesh, .obj for quads), every element valid")
    sp.add_argument("-o", "--output", required=True, help="output mesh, same cells (any of the input formats)")
    sp.add_argument("--energy", default="winslow", metavar="NAME",
                    help=f"one of {', '.join(ENERGIES)} (default winslow: the inverse-harmonic map)")
    sp.add_argument("--solver", default="newton", metavar="NAME",
                    help=f"one of {', '.join(SOLVERS)} (default newton); its line search keeps every corner positive")
    sp.add_argument("--fix", default="boundary", choices=["boundary", "none"],
                    help="vertices held in place (default: the boundary)")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit (>= 1)")
    common(sp)
    sp.set_defaults(func=cmd_smooth)

    sp = sub.add_parser("compare", help="run several solvers from the same start, write traces and a plot")
    sp.add_argument("mesh", help="disk-topology mesh (free boundary, Tutte start) or a LIM case folder "
                                 "(fixed handles, its flip-free map as the start)")
    sp.add_argument("--out", required=True, help="output folder: history.csv, summary.csv, <solver>.obj "
                                                 "(.vtk for tets), convergence.png")
    sp.add_argument("--solvers", default=None,
                    help="comma-separated solver names (default newton,lbfgs,slim,aqp,cm; cm only in 2D)")
    sp.add_argument("--energy", default="symmetric_dirichlet", help="energy name (default symmetric_dirichlet)")
    sp.add_argument("--weights", default="uniform", choices=["uniform", "mean_value"],
                    help="Tutte weights of the free-boundary start map")
    sp.add_argument("--max-seconds", type=float, default=None,
                    help="stop each solver after this many seconds of solve time (setup excluded)")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit of every solver")
    common(sp)
    sp.set_defaults(func=cmd_compare)

    sp = sub.add_parser("demo", help="parameterize the bundled camelhead, write OBJ and PNGs")
    sp.add_argument("-o", "--output", default="out", help="output folder (default ./out)")
    common(sp)
    sp.set_defaults(func=cmd_demo)
    return p


def _report(args, **fields):
    """Add ``fields`` to the --json summary."""
    args.summary.update(fields)


def main(argv=None) -> int:
    t0 = time.perf_counter()
    parser = build_parser()
    args = parser.parse_args(argv)
    args.summary = {"command": args.command, "success": False}
    code = EXIT_FAILED
    try:
        code = _run(args)
        return code
    finally:
        if args.json:
            _report(args, exit_status=code, success=code == EXIT_OK,
                    wall_seconds=round(time.perf_counter() - t0, 4))
            print(json.dumps(args.summary), flush=True)


def _run(args) -> int:
    from ._errors import GeomoptError, SolveError

    if args.json:
        from ._cache import cache_stats

        cache_stats()  # count persistent-cache hits and misses from here on
    try:
        with _signals_raise():
            return args.func(args)
    except SolveError as exc:
        if args.debug:
            raise
        _report(args, error=str(exc))
        return _fail(str(exc))
    except GeomoptError as exc:
        if args.debug:
            raise
        _report(args, error=str(exc))
        print(f"geomopt: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP through _signals_raise
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"geomopt: interrupted by {signal.Signals(signum).name}; unfinished outputs were removed",
              file=sys.stderr)
        return 128 + signum
    except Exception as exc:  # an internal error: one line unless --debug
        if args.debug:
            raise
        _report(args, error=f"internal error: {type(exc).__name__}: {exc}")
        print(f"geomopt: internal error: {type(exc).__name__}: {exc} (rerun with --debug and "
              f"report it)", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())

"""Command line: geomopt param, geomopt untangle, geomopt demo.

Every failure on bad input (unreadable or invalid mesh, unknown name, invalid value, output
that cannot be written) prints one line ``geomopt: error: ...`` and exits with status 2 (no
traceback unless ``--debug``); a solve that does not end converged and flip-free (exact
predicate) exits with status 1 and writes nothing; status 0 means the certified result was
written.  Output paths are checked before solving and written atomically.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


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


def cmd_param(args) -> int:
    from . import io
    from .energies import get_energy
    from .param import parameterize

    energy = get_energy(args.energy)
    solver = _solver(args.solver)
    if args.max_steps is not None:
        import dataclasses

        solver = dataclasses.replace(solver, max_steps=args.max_steps)
    for path in [args.output] + ([args.png] if args.png else []):
        io.check_output_path(path)  # before the solve, not after
    V, F = io.read_mesh(args.input)
    _log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; energy {energy.name}, "
               f"solver {args.solver}, {args.weights} Tutte start")
    res = parameterize(V, F, energy=energy, solver=solver, weights=args.weights,
                       progress=not args.quiet)
    mean = res.energy / res.info["objective"].total_volume
    _log(args, f"faces {len(F)}  iterations {res.iterations}  seconds {res.seconds:.2f}  "
               f"compile seconds {res.setup_seconds:.2f}  energy {mean:.10g}  flips {res.inverted}  "
               f"outcome {res.outcome.value}")
    _report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F),
            energy_name=energy.name, solver=args.solver, iterations=res.iterations,
            solve_seconds=round(res.seconds, 4), setup_seconds=round(res.setup_seconds, 4),
            energy=res.energy, mean_energy=mean, flips=res.inverted, outcome=res.outcome.value,
            message=res.message, **_cache_summary())
    if not res.success:
        return _fail(f"not certified: {res.message}")
    if args.png:
        _save_param_figures(res, V, F, args.png)
    io.write_obj_with_uv(args.output, V, F, res.x)
    return EXIT_OK


def _cache_summary() -> dict:
    from ._cache import cache_stats

    st = cache_stats()
    return {"cache_dir": st["dir"], "cache_hits": st["hits"], "cache_misses": st["misses"]}


def _save_param_figures(res, V, F, png):
    import numpy as np

    from . import plot

    obj = res.info["objective"]
    from ._objective import element_densities

    dens = np.asarray(element_densities(obj, res.x))
    base = Path(png)
    plot.save_param_figure(base, V, F, res.x, np.log10(np.maximum(dens / obj.energy.value_at_rest(2), 1.0))
                           if obj.energy.value_at_rest(2) else dens,
                           title=f"UV layout, {obj.energy.name} (log10 of density / isometric value)",
                           label="log10 distortion")
    conv = base.with_name(base.stem + "_convergence" + base.suffix)
    plot.save_convergence(conv, {"projected Newton": (res.time_history, res.energy_history)},
                          title=f"convergence ({len(F)} faces)")
    return base, conv


def cmd_untangle(args) -> int:
    from . import io
    from ._errors import ParameterError
    from .untangle import untangle_case, write_untangle_result

    want = ".obj" if io.lim_case_dim(args.case) == 2 else ".vtk"
    if Path(args.output).suffix.lower() != want:
        raise ParameterError(f"{args.case} is a {'2D' if want == '.obj' else '3D'} case: the output "
                             f"must be a {want} file, got {args.output}")
    for path in [args.output] + ([args.png] if args.png else []):
        io.check_output_path(path)
    case, res = untangle_case(args.case, solver=args.solver, progress=not args.quiet)
    _log(args, f"elements {res.info.get('elements', '?')}  outer iterations {res.outer_iterations}  "
               f"seconds {res.seconds:.2f}  compile seconds {res.setup_seconds:.2f}  "
               f"inverted {res.inverted}  certified {'yes' if res.success else 'no'}")
    _report(args, case=str(args.case), output=str(args.output), elements=res.info.get("elements"),
            outer_iterations=res.outer_iterations, solve_seconds=round(res.seconds, 4),
            setup_seconds=round(res.setup_seconds, 4), inverted=res.inverted, certified=bool(res.success),
            message=res.message, **_cache_summary())
    if not res.success:
        return _fail(f"not certified: {res.message}")
    check = write_untangle_result(case, res, args.output)
    if not check["certified"]:
        Path(args.output).unlink(missing_ok=True)
        return _fail(f"the written file did not certify ({check['inverted']} inverted element(s), "
                     f"{check['handles_moved']} handle(s) moved)")
    if args.png:
        _save_untangle_figure(case, res, args.png)
    return EXIT_OK


def _save_untangle_figure(case, res, png):
    """Start and result with inverted elements (exact predicate, in the orientation the
    output must have) marked."""
    from . import plot
    from .predicates import simplex_orientations

    S = case["faces"] if case["dim"] == 2 else case["tets"]
    start = case["init"][:, :2] if case["dim"] == 2 else case["init"]
    bad = [simplex_orientations(x, S) != case["orientation"] for x in (start, res.x)]
    plot.save_untangle_figure(png, start, res.x, S, *bad, title=str(case.get("path", "")))


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
                            energy="symmetric_dirichlet", solver="newton", weights="uniform",
                            max_steps=None, quiet=args.quiet, png=str(out / "camelhead_uv.png"),
                            json=args.json, summary=args.summary)
    code = cmd_param(ns)
    if code == EXIT_OK and not args.json:  # --json: stdout holds only the summary
        print(f"wrote {out / 'camelhead_uv.obj'}, {out / 'camelhead_uv.png'}, "
              f"{out / 'camelhead_uv_convergence.png'}")
    return code


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
    sp.add_argument("-o", "--output", required=True, help="output OBJ with one vt per vertex")
    sp.add_argument("--energy", default="symmetric_dirichlet", metavar="NAME",
                    help=f"one of {', '.join(ENERGIES)} (default symmetric_dirichlet)")
    sp.add_argument("--solver", default="newton", metavar="NAME",
                    help=f"one of {', '.join(SOLVERS)} (default newton)")
    sp.add_argument("--weights", default="uniform", choices=["uniform", "mean_value"],
                    help="Tutte weights of the start map")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit (>= 1)")
    sp.add_argument("--png", default=None, help="also save the UV map (checkerboard on the surface beside "
                                                "the layout) and a _convergence plot")
    common(sp)
    sp.set_defaults(func=cmd_param)

    sp = sub.add_parser("untangle", help="untangle a LIM benchmark case (fixed handles)")
    sp.add_argument("case", help="case folder: input.obj + handles.txt (2D) or rest.vtk + init.vtk (3D)")
    sp.add_argument("-o", "--output", required=True, help="output OBJ (2D) or VTK (3D)")
    sp.add_argument("--solver", default="lbfgs", choices=["lbfgs", "newton"],
                    help="inner solver (default lbfgs, measured fastest for untangling)")
    sp.add_argument("--png", default=None,
                    help="also save a picture of the start and the result, inverted elements in red")
    common(sp)
    sp.set_defaults(func=cmd_untangle)

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
    except KeyboardInterrupt:
        print("geomopt: interrupted; no output written", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal error: one line unless --debug
        if args.debug:
            raise
        _report(args, error=f"internal error: {type(exc).__name__}: {exc}")
        print(f"geomopt: internal error: {type(exc).__name__}: {exc} (rerun with --debug and "
              f"report it)", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())

"""Command line: geomopt param, geomopt untangle, geomopt smooth, geomopt compare, geomopt demo.

Every failure on bad input (unreadable or invalid mesh, unknown name, invalid value, output
that cannot be written, a command line argparse refuses) prints one line ``geomopt: error:
...`` and exits with status 2 (no traceback and no NumPy warning unless ``--debug``; with
``--json`` the JSON summary is printed too); a solve that does not end converged and flip-free (exact
predicate) exits with status 1 and writes nothing; status 0 means the certified result was
written.  Every output path (derived ones included) is checked before the input is read, by
:func:`geomopt.io.check_outputs`: it must be a regular file or not exist, and no output may be an
input (a command creates or replaces nothing but its named outputs; an output folder is created,
never its parents).  Outputs are written atomically, all of them or none; an
interrupt (SIGINT, SIGTERM, SIGHUP) removes the unfinished temporary files and exits with
status 128 + the signal number (a batch first writes the summary of what finished).
``compare`` writes all its files and exits 0 only when every solver converged certified, else 1.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

__all__ = [
    "main", "build_parser", "cmd_param", "cmd_untangle", "cmd_compare", "cmd_demo", "EXIT_OK",
    "EXIT_FAILED", "EXIT_USAGE", "EXIT_EXCEPT_FIXED", "PICTURE_EXTENSIONS",
]

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
#: ``untangle``: the map was written, certified wherever a free vertex reaches, but the handles
#: alone make it overlap where every element has all its vertices fixed (``certified_except_fixed``)
EXIT_EXCEPT_FIXED = 3

#: Picture formats ``--png`` writes (matplotlib's own backends, no extra dependency).
from .._save import PICTURE_EXTENSIONS  # noqa: E402


def _log(args, *msg):
    if not args.quiet:
        print(*msg, file=sys.stderr, flush=True)


def _solver(name):
    from .. import solvers

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


def _output_paths(output, extensions, pictures=(), inputs=(), folder=None):
    """Check every output before any work (:func:`geomopt.io.check_outputs`): ``-o`` (``extensions``)
    and ``pictures`` (``(what, path)``, derived names included), in ``folder`` when the command was
    given an output folder.  Returns the output path."""
    from .. import io

    files = [("-o output", output, extensions)] + [(what, p, PICTURE_EXTENSIONS) for what, p in pictures]
    return io.check_outputs(files, inputs, folder)[0]


def _param_input(args):
    """``(V, F, x0, start)`` of ``geomopt param``: the mesh, the start map (an array, None for
    Tutte's or ``"projection"``) and how the log names it."""
    from .. import io

    if args.init == "uv":
        V, F, x0 = io.read_obj_uv(args.input)
        return V, F, x0, "its own UV start map"
    V, F = io.read_mesh(args.input)
    if args.init == "tutte":
        return V, F, None, f"{args.weights} Tutte start"
    return V, F, args.init, "plane projection start"


def cmd_param(args) -> int:
    from .. import io
    from .._runtime.errors import MeshError, ParameterError
    from .._runtime.timing import compile_seconds
    from ..energies import get_energy
    from ..param import parameterize

    split = args.timing
    split.mark_imported()
    compile_seconds()  # starts counting JAX's compilation
    if args.sphere:
        return _param_sphere(args)
    energy = get_energy(args.energy)
    solver = _solver(args.solver)
    if args.max_steps is not None:
        import dataclasses

        solver = dataclasses.replace(solver, max_steps=args.max_steps)
    pictures = []
    if args.png:
        pictures = [("--png picture", args.png), ("convergence picture", str(_convergence_path(args.png)))]
    folder = getattr(args, "folder", None)  # demo: the output folder, created only to write into it
    if args.bijective and args.init == "projection":
        raise ParameterError("--bijective starts from the Tutte map (--init tutte, the default) or from a globally "
                             "injective --init uv map, not from --init projection; drop one of the two options")
    _output_paths(args.output, io.UV_MESH_EXTENSIONS, pictures, [args.input], folder)  # before reading or solving
    with split.phase("read"):
        V, F, x0, start = _param_input(args)
    _log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; energy {energy.name}, "
               f"solver {args.solver}, {start}")
    if Path(args.input).suffix.lower() == ".stl":
        _log(args, f"{args.input}: STL stores every triangle's corners separately; welded the "
                   f"{3 * len(F)} corners with bit-identical coordinates into {len(V)} vertices")
    from .atlas import is_disk, param_atlas

    if args.atlas or not is_disk(F, len(V)):  # closed, several boundary loops or components: charts
        return param_atlas(args, V, F, energy, solver, _log, _report, _fail)
    t_solve, compiled = time.perf_counter(), compile_seconds()
    try:
        res = parameterize(V, F, energy=energy, solver=solver, weights=args.weights, x0=x0,
                           progress=not args.quiet, bijective=args.bijective)
    except MeshError as exc:
        raise _for_the_command_line(exc, args) from exc
    # setup: everything in parameterize but the solve and JAX's compilation (start map, scaling,
    # patterns, analysis, the exact certificate)
    compiled = compile_seconds() - compiled
    split.add("compile", compiled)
    split.add("solve", res.stats.seconds)
    split.add("setup", time.perf_counter() - t_solve - res.stats.seconds - compiled)
    rep = res.details.repair if res.details is not None else None
    if rep is not None:
        _log(args, f"repaired the start map's {rep.stats.inverted_at_start} folded triangle(s), boundary held: "
                   f"{rep.stats.outer_iterations} outer iterations, {rep.stats.seconds:.2f} s, "
                   f"{'certified' if rep.success else 'not certified: ' + rep.message}")
    if rep is not None and not rep.success:
        return _fail(f"the start map could not be repaired: {rep.message}")
    mean, st = res.mean_energy, res.stats
    _log(args, f"faces {len(F)}  iterations {st.iterations}  seconds {st.seconds:.2f}  "
               f"compile seconds {st.setup_seconds:.2f}  energy {res.energy:.10g}  mean energy {mean:.10g}  "
               f"flips {res.certificate.inverted}  injective {res.injectivity}  outcome {res.outcome.value}")
    _report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F),
            energy_name=energy.name, solver=args.solver, iterations=st.iterations,
            solve_seconds=round(st.seconds, 4), setup_seconds=round(st.setup_seconds, 4),
            energy=res.energy, mean_energy=mean, flips=res.certificate.inverted, injectivity=res.injectivity,
            boundary_crossings=_boundary_crossings(res), uv_range=args.uv_range,
            outcome=res.outcome.value, message=res.message, **_cache_summary())
    if not res.success:
        return _fail(f"not certified: {res.message}")
    if res.injectivity == "local":
        _warn_overlap(res, args)
    if folder is not None:
        io.create_output_folder(folder)
    uv = _unit_square(res.x) if args.uv_range == "unit" else res.x
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            with split.phase("figures"):
                _save_param_figures(res, V, F, uv, args.png, outputs, args)
        with split.phase("write"):
            io.write_mesh_with_uv(outputs.enter_context(io.atomic_path(args.output)), V, F, uv,
                                  format=Path(args.output).suffix[1:])
    return EXIT_OK


def _param_sphere(args) -> int:
    """``geomopt param --sphere``: a closed genus-0 mesh onto the unit sphere, certified
    (:func:`geomopt.sphere.sphere_map`); the OBJ keeps the faces, its vertices on the sphere."""
    import dataclasses
    import math

    from .. import io, plot
    from .._runtime.errors import ParameterError
    from ..sphere import default_solver, sphere_distortion, sphere_map

    if args.bijective or args.init != "tutte" or args.uv_range != "raw":
        raise ParameterError("--sphere makes its own certified start and writes vertices, not UVs: leave out "
                             "--bijective, --init and --uv-range")
    # newton is the parser's default: the sphere's default L-BFGS then
    solver = default_solver() if args.solver == "newton" else _solver(args.solver)
    if args.max_steps is not None:
        solver = dataclasses.replace(solver, max_steps=args.max_steps)
    pictures = [("--png picture", args.png)] if args.png else []
    _output_paths(args.output, (".obj",), pictures, [args.input], getattr(args, "folder", None))
    with args.timing.phase("read"):
        V, F = io.read_mesh(args.input)
    _log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; onto the sphere, energy {args.energy}, L-BFGS")
    res = sphere_map(V, F, energy=args.energy, solver=solver, progress=not args.quiet, weights=args.weights)
    st, cert, dist = res.stats, res.certificate, sphere_distortion(V, F, res.x)
    _log(args, f"faces {len(F)}  iterations {st.iterations}  seconds {st.seconds:.2f}  mean energy "
               f"{res.mean_energy:.10g}  area ratio {dist['area_min']:.3g}..{dist['area_max']:.3g}  flips "
               f"{cert.inverted}  spherical area {cert.area:.12g} (4 pi = {4 * math.pi:.12g})  outcome {res.outcome.value}")
    _report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F), sphere=True,
            energy_name=args.energy, iterations=st.iterations, solve_seconds=round(st.seconds, 4),
            mean_energy=res.mean_energy, flips=cert.inverted, spherical_area=cert.area, degree=cert.degree,
            area_ratio_min=dist["area_min"], area_ratio_max=dist["area_max"], injectivity=res.injectivity,
            outcome=res.outcome.value, message=res.message)
    if not res.success:
        return _fail(f"not certified: {res.message}")
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            title = (f"{Path(args.input).name}: {len(F)} triangles onto the sphere, {args.energy}, mean energy "
                     f"{res.mean_energy:.6g}, certified bijective")
            plot.save_sphere_figure(outputs.enter_context(io.atomic_output(args.png, "wb")), V, F, res.x,
                                    title=title, format=Path(args.png).suffix[1:].lower())
        with args.timing.phase("write"):
            io.write_obj(outputs.enter_context(io.atomic_path(args.output)), res.x, F)
    return EXIT_OK


def _unit_square(uv):
    """``uv`` (n, 2) moved and scaled uniformly (aspect kept) so that its bounding box spans
    [0, 1] along its longer side and starts at 0 along both: the range texture tools expect."""
    import numpy as np

    lo = uv.min(axis=0)
    return (uv - lo) / max(float(np.ptp(uv, axis=0).max()), 1e-300)


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
    crossings = getattr(res.certificate, "crossings", None)
    return None if crossings is None else len(crossings)


def _for_the_command_line(exc, args):
    """A library message that names an API the command line does not offer, reworded."""
    from .._runtime.errors import MeshError

    unfit = re.match(r"the start map x0 is not globally injective (\(.*\)); omit", str(exc))
    if unfit is not None:
        return MeshError(
            f"the UV map of {args.input} (--init uv) is not globally injective {unfit.group(1)}, and --bijective "
            f"starts from one that is; drop --bijective (a folded start is then repaired first) or start from "
            f"--init tutte")
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
    from .._runtime.cache import cache_stats

    st = cache_stats()
    return {"cache_dir": st["dir"], "cache_hits": st["hits"], "cache_misses": st["misses"]}


def _save_param_figures(res, V, F, uv, png, outputs, args):
    """Render the layout and convergence pictures into atomic temporaries registered on ``outputs``."""
    from .. import io, plot
    from .._save import save_param_picture

    obj = res.objective
    base, conv = Path(png), _convergence_path(png)
    title = (f"{Path(args.input).name}: {len(F)} triangles, {obj.energy.name} by {args.solver}, "
             f"{res.stats.iterations} iterations, mean energy {res.energy / obj.total_volume:.8g}, "
             f"injective {res.injectivity}")
    save_param_picture(outputs.enter_context(io.atomic_output(base, "wb")), res, V, F, uv, title,
                       base.suffix[1:].lower())
    vol = obj.total_volume
    plot.save_convergence(outputs.enter_context(io.atomic_output(conv, "wb")),
                          {args.solver: (res.trace.seconds, res.trace.energy / vol, res.trace.grad_norm / vol)},
                          ylabel=f"mean {obj.energy.name} energy", title=title, format=conv.suffix[1:].lower())
    return base, conv


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
    from ..lim import LimCase, untangle_case
    from ..mesh.quality import element_quality

    split = args.timing
    split.mark_imported()
    compile_seconds()  # starts counting JAX's compilation
    want = ".obj" if LimCase.dim_of(folder) == 2 else ".vtk"
    if Path(args.output).suffix.lower() != want:
        raise ParameterError(f"{folder} is a {'2D' if want == '.obj' else '3D'} case: the output "
                             f"must be a {want} file, got {args.output}")
    _output_paths(args.output, (want,), [("--png picture", args.png)] if args.png else [], [folder])
    with split.phase("read"):
        case = LimCase.read(folder)
        case.require_handles()
    case, res = _timed_solve(split, lambda: untangle_case(case, solver=args.solver, progress=not args.quiet,
                                                          bucket=True, start=args.start))
    st = res.stats
    with split.phase("certify"):
        quality = element_quality(res.x, case.simplices, case.to_problem().orientation)
    _log(args, f"elements {res.problem.n_elements}  outer iterations {st.outer_iterations}  "
               f"seconds {st.seconds:.2f}  compile seconds {st.setup_seconds:.2f}  "
               f"inverted {res.certificate.inverted}  certified {'yes' if res.success else 'no'}")
    _log(args, f"quality: smallest size / mean {quality['min_size_ratio']:.4g}, scaled Jacobian min "
               f"{quality['min_scaled_jacobian']:.4g} mean {quality['mean_scaled_jacobian']:.4g}")
    _report(args, case=str(folder), output=str(args.output), dim=case.dim, vertices=len(res.x),
            elements=res.problem.n_elements, inverted_before=st.inverted_at_start, inverted=res.certificate.inverted,
            outer_iterations=st.outer_iterations, inner_iterations=st.iterations,
            evaluations=st.evaluations, solve_seconds=round(st.seconds, 4),
            setup_seconds=round(st.setup_seconds, 4), handles_moved=res.certificate.handles_moved,
            start=getattr(res.details, "start", None), min_det_rel=res.min_det_rel, outcome=res.outcome.value,
            certified=bool(res.success), message=res.message, forced_overlaps=_forced_overlaps(res), **quality,
            **_cache_summary())
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
        return _fail(f"not certified: {res.message}")
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


def _cell_output(args, case, inputs, pictures=()):
    """Check ``-o`` (and ``pictures``) for a tet / quad / hex case (:data:`geomopt.mesh.cells.CELL_EXTENSIONS`,
    ``.obj`` for quads only)."""
    from ..mesh.cells import CELL_EXTENSIONS

    allowed = CELL_EXTENSIONS if case.kind == "quad" else tuple(e for e in CELL_EXTENSIONS if e != ".obj")
    _output_paths(args.output, allowed, pictures, inputs)


def _quality_line(q):
    """One line of scaled-Jacobian figures: a :func:`geomopt.mesh.quality.quality_summary` or a
    :class:`geomopt.mesh.elements.Quality`."""
    q = q if isinstance(q, dict) else {f"sj_{k}": v for k, v in q.as_dict().items()}
    return (f"min scaled Jacobian {q['sj_min']:.4f}, mean {q['sj_mean']:.4f}, {q['sj_below_0']} below 0, "
            f"{q['sj_below_0_2']} below 0.2")


def _untangle_mesh(args) -> int:
    """One tet / quad / hex mesh file (rest shapes from ``--rest`` or reference squares / cubes,
    handles from ``--handles`` or the boundary) or quad / hex case folder (:mod:`geomopt.mesh.cells`)
    to one certified file: one path for every kind of element."""
    from .._runtime.errors import ParameterError
    from .._runtime.timing import compile_seconds
    from ..mesh.cells import cell_problem, read_cell_case, write_certified
    from ..mesh.quality import quality_summary
    from ..untangling import untangle

    path = Path(args.case[0])
    inputs = [str(p) for p in path.iterdir()] if path.is_dir() else [str(path)]
    inputs += [str(p) for p in (args.rest, args.handles) if p is not None]
    split = args.timing
    split.mark_imported()
    compile_seconds()  # starts counting JAX's compilation
    with split.phase("read"):
        case = read_cell_case(path, rest=args.rest, handles=args.handles)  # -o's check needs the kind
    if args.png and case.kind != "tetra":
        raise ParameterError("--png draws triangle and tet cases only; leave it out for a quad/hex case")
    _cell_output(args, case, inputs, [("--png picture", args.png)] if args.png else [])
    with split.phase("setup"):
        problem = cell_problem(case)
        before = quality_summary(problem, case.start)
    res = _timed_solve(split, lambda: untangle(problem, case.start, solver=args.solver, progress=not args.quiet,
                                                     start=args.start))
    with split.phase("certify"):
        after = quality_summary(problem, res.x)
    words = {"tetra": "tetrahedra", "quad": "quads", "hexahedron": "hexahedra"}[case.kind]
    _log(args, f"{len(case.elements)} {words}: before {_quality_line(before)}, {before['invalid']} invalid")
    tests = f" ({after['corner_only']} only inside); tests {after['tests']}" if after["tests"] else ""
    _log(args, f"after  {_quality_line(after)}, {after['invalid']} invalid{tests}; outer iterations "
               f"{res.stats.outer_iterations}, "
               f"{res.stats.seconds:.2f} s from the {getattr(res.details, 'start', 'given')} map, certified "
               f"{'yes' if res.success else 'no'}")
    _report(args, case=str(path), rest=args.rest, handles_file=args.handles, output=str(args.output), dim=problem.dim,
            vertices=len(res.x), elements=len(case.elements), kind=case.kind, inverted_before=before["invalid"],
            inverted=res.certificate.inverted, outer_iterations=res.stats.outer_iterations,
            inner_iterations=res.stats.iterations, evaluations=res.stats.evaluations,
            solve_seconds=round(res.stats.seconds, 4), setup_seconds=round(res.stats.setup_seconds, 4),
            fixed_vertices=len(problem.fixed), handles_moved=res.certificate.handles_moved,
            start=getattr(res.details, "start", None), min_det_rel=res.min_det_rel, outcome=res.outcome.value,
            certified=bool(res.success), message=res.message, forced_overlaps=_forced_overlaps(res),
            min_size_ratio=res.min_det_rel, min_scaled_jacobian=after["sj_min"],
            mean_scaled_jacobian=after["sj_mean"], before=before, after=after, **_cache_summary())
    forced = getattr(res.certificate, "forced", None)
    return _written_untangled(args, res, lambda: write_certified(args.output, res.x, case, problem, forced=forced),
                              lambda png, fmt: _save_untangle_figure(png, case.start, res.x, problem.simplices,
                                                                     1, str(path), fmt))


def _timed_solve(split, solve):
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


def cmd_smooth(args) -> int:
    """Smooth a valid quad / hex mesh (:func:`geomopt.smooth`) into a certified file."""
    from ..mesh.cells import SMOOTH_KINDS, read_cell_case, write_certified
    from ..smoothing import smooth

    split = args.timing
    split.mark_imported()
    with split.phase("read"):
        case = read_cell_case(args.input, kinds=SMOOTH_KINDS)
    _cell_output(args, case, [args.input])
    fixed = None if args.fix == "boundary" else []
    with split.phase("solve"):  # smooth's rounds, each solved and certified
        res = smooth(case.start, case.elements, energy=args.energy, solver=args.solver, fixed=fixed,
                     max_steps=args.max_steps, progress=not args.quiet)
    d, st = res.details, res.stats
    seconds = st.seconds + st.setup_seconds  # every solve, set-up included
    _log(args, f"{len(case.elements)} {case.kind} elements: before {_quality_line(d.before)}")
    _log(args, f"after  {_quality_line(d.after)}; tests {d.elements.summary()['tests']}; "
               f"{st.iterations} iterations, {seconds:.2f} s")
    _report(args, input=str(args.input), output=str(args.output), elements=len(case.elements), kind=case.kind,
            before=d.before.as_dict(), after=d.after.as_dict(), held=len(d.held), rounds=st.outer_iterations,
            improved=d.improved, outcome=res.outcome.value, iterations=st.iterations,
            solve_seconds=round(seconds, 4), message=d.message, **_cache_summary())
    if not d.improved:
        return _fail(f"not improved (no smoothing keeps every element at least as good as the input's worst): "
                     f"{d.message}" + (f"; {res.reason}" if res.reason else ""))
    handles = res.problem.fixed, res.problem.fixed_positions / d.scale  # in the file's frame (exact: a power of 2)
    with split.phase("write"):
        write_certified(args.output, res.x, case, res.problem.with_fixed(*handles))
    return EXIT_OK


def _untangle_batch(args) -> int:
    from ..experiments.batch import DASK_EXTRA, EXCEPT_FIXED, batch_cases, dask_available, run_batch

    cases = batch_cases(args.case)
    workers = args.workers or min(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                  else (os.cpu_count() or 1), len(cases))
    if args.workers is None and args.scheduler is None and workers > 1 and not dask_available():
        print(f"geomopt: solving the cases one after another in this process (Dask is not installed; "
              f"{DASK_EXTRA} to use {workers} worker processes)", file=sys.stderr, flush=True)
        workers = 1
    where = (f"the Dask scheduler at {args.scheduler}" if args.scheduler else
             f"{workers} local worker process(es)" if workers > 1 else "this process")
    _log(args, f"{len(cases)} case(s) to {args.output}, on {where}")

    def report(row, done, total):
        status = {"yes": "certified", EXCEPT_FIXED: f"written, certified except where the handles fix it: "
                  f"{row['message']}"}.get(row["certified"], f"not certified: {row['message']}")
        _log(args, f"[{done}/{total}] {row['case']}: {status} ({row['seconds']} s)")

    rows = run_batch(cases, args.output, solver=args.solver, workers=workers, scheduler=args.scheduler,
                     report=report, start=args.start)
    except_fixed = sum(row["certified"] == EXCEPT_FIXED for row in rows)
    failed = sum(row["certified"] not in ("yes", EXCEPT_FIXED) for row in rows)
    summary = Path(args.output) / "summary.csv"
    _report(args, output=str(args.output), summary=str(summary), workers=workers, scheduler=args.scheduler,
            cases=len(rows), certified=len(rows) - failed - except_fixed, certified_except_fixed=except_fixed,
            not_certified=failed, rows=rows, **_cache_summary())
    if failed:
        print(f"geomopt: {failed} of {len(rows)} case(s) not certified (no output written for them); "
              f"see {summary}", file=sys.stderr, flush=True)
        return EXIT_FAILED
    if except_fixed:
        print(f"geomopt: warning: {except_fixed} of {len(rows)} case(s) written but not certified everywhere: "
              f"their handles alone make them overlap (certified = {EXCEPT_FIXED}); see {summary}",
              file=sys.stderr, flush=True)
        return EXIT_EXCEPT_FIXED
    _log(args, f"all {len(rows)} case(s) certified; summary in {summary}")
    return EXIT_OK


def _save_untangle_figure(png, start, x, S, orientation, title, format=None):
    """Start and result maps with the elements ``S`` (triangles or tetrahedra) not oriented as
    ``orientation`` (+1 or -1; exact predicate) marked."""
    from .. import plot
    from ..exact.predicates import simplex_orientations

    bad = [simplex_orientations(m, S) != orientation for m in (start, x)]
    plot.save_untangle_figure(png, start, x, S, *bad, title=title, format=format)


def cmd_demo(args) -> int:
    """Parameterize the bundled camelhead and write OBJ + UV picture + convergence plot."""
    out = Path(args.output)
    from ..data import path as bundled

    data = bundled("camelhead")
    ns = argparse.Namespace(input=str(data), output=str(out / "camelhead_uv.obj"), folder=out,
                            energy="symmetric_dirichlet", solver="newton", weights="uniform", init="tutte", bijective=False,
                            max_steps=None, quiet=args.quiet, png=str(out / "camelhead_uv.png"), atlas=False, sphere=False, margin=0.005,
                            uv_range="raw", json=args.json, summary=args.summary, timing=args.timing)
    code = cmd_param(ns)
    if code == EXIT_OK and not args.json:  # --json: stdout holds only the summary
        print(f"wrote {out / 'camelhead_uv.obj'}, {out / 'camelhead_uv.png'}, "
              f"{out / 'camelhead_uv_convergence.png'}")
    return code


def cmd_compare(args) -> int:
    """Every solver from the same start map, on one mesh or several: traces, summary, LaTeX
    table, manifest, maps and the convergence figure in -o (see geomopt.experiments.comparison).

    Exit status 0 only when every solver converged to a certified map and no iterate had an
    inverted element; else 1, after writing every file, with one line naming each solver and why."""
    from ..experiments.comparison import ComparisonSet, compare, compare_meshes, exit_status

    options = dict(solvers=args.solvers, energy=args.energy, weights=args.weights, max_seconds=args.max_seconds,
                   max_steps=args.max_steps, reference=args.reference, repeat=args.repeat,
                   tolerances=_floats(args.tolerances, "--tolerances"), formats=_names(args.format),
                   log_x=args.log_x, progress=not args.quiet, clock=args.clock, warmup=args.warmup,
                   layout=args.layout, font_size=args.font_size)
    if len(args.mesh) == 1:
        res = compare(args.mesh[0], out=args.output, **options)
    else:
        res = compare_meshes(args.mesh, out=args.output, **options)
    _log(args, res.report())
    files = res.output_names(options["formats"])
    _log(args, f"wrote {', '.join(files)} in {args.output}")
    items = res.comparisons if isinstance(res, ComparisonSet) else {Path(args.mesh[0]).name: res}
    _report(args, output=str(args.output), files=files, repeat=args.repeat, tolerances=options["tolerances"],
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


def _margin(text) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value < 0.25:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 0.25), got {text!r}")
    return value


def _positive_int(text) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def build_parser():
    from .._version import __version__
    from .._runtime.names import ENERGIES, SOLVERS

    p = _Parser(
        prog="geomopt", description="Locally injective (foldover-free) maps of triangle, tet, quad and hex meshes.",
        epilog=f"energies: {', '.join(ENERGIES)}. solvers: {', '.join(SOLVERS)}. Compiled code is "
               f"cached in $GEOMOPT_CACHE_DIR (default ~/.cache/geomopt/jax; 'off' disables it). "
               f"Run 'geomopt COMMAND --help' for a command's options.")
    p.add_argument("--version", action="version", version=f"geomopt {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    _add_param(sub)
    _add_untangle(sub)
    _add_smooth(sub)
    _add_compare(sub)
    _add_demo(sub)
    return p


def _common_options(sp):
    """Options every command takes."""
    sp.add_argument("--quiet", action="store_true", help="no progress or summary output")
    sp.add_argument("--json", action="store_true",
                    help="print a one-line JSON summary on stdout (also on failure)")
    sp.add_argument("--debug", action="store_true", help="show tracebacks on errors")


def _add_param(sub):
    """The ``param`` command's options."""
    from .._runtime.names import ENERGIES, SOLVERS

    sp = sub.add_parser("param", help="parameterize a surface: a disk with a free boundary, any other "
                                      "surface as a certified atlas")
    sp.add_argument("input", help="triangle mesh (OBJ/OFF/PLY/STL): a disk, or any edge-manifold surface "
                                  "(an atlas)")
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
    sp.add_argument("--atlas", action="store_true",
                    help="cut into charts and pack them (a texture atlas) even when the mesh is a disk; a "
                         "mesh that is not a disk (closed, several boundary loops or components) always is")
    sp.add_argument("--margin", type=_margin, default=0.005,
                    help="atlas: gap between packed charts, a fraction of the unit square (default 0.005)")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit (>= 1)")
    sp.add_argument("--uv-range", default="raw", choices=["raw", "unit"],
                    help="UVs written as solved (raw, the default: a map of about the surface's own "
                         "size) or moved and scaled uniformly into the unit square (unit; the energy "
                         "reported is the raw map's)")
    sp.add_argument("--png", default=None,
                    help="also save the UV map (checkerboard on the surface beside the distortion layout; "
                         ".png, .pdf or .svg) and a <name>_convergence plot")
    sp.add_argument("--sphere", action="store_true",
                    help="map a closed genus-0 mesh onto the unit sphere instead (L-BFGS, certified bijective): "
                         "-o writes an .obj with the same faces, its vertices on the sphere")
    _common_options(sp)
    sp.set_defaults(func=cmd_param)


def _add_untangle(sub):
    """The ``untangle`` command's options."""
    sp = sub.add_parser("untangle", help="untangle LIM benchmark cases (fixed handles) or a tet/quad/hex mesh")
    sp.add_argument("case", nargs="+",
                    help="case folder (input.obj + handles.txt in 2D, rest.vtk + init.vtk in 3D, with "
                         "triangles, tets, quads or hexahedra), or several, or folders holding case "
                         "folders; or one tangled tet/quad/hex mesh file (.vtk .vtu .msh .mesh, .obj for "
                         "quads), untangled with its boundary fixed (or --handles) and the rest shapes of "
                         "--rest (quads/hexahedra without it: squares/cubes)")
    sp.add_argument("-o", "--output", required=True,
                    help="one case: output OBJ (2D) or VTK (3D), any tet/quad/hex mesh format for a mesh "
                         "file or quad/hex case; otherwise an output folder, which gets <case folder "
                         "name>.obj/.vtk per certified case and summary.csv")
    sp.add_argument("--rest", default=None, metavar="REST",
                    help="one mesh file: its rest mesh, a file with the same vertices and cells (required "
                         "for tets)")
    sp.add_argument("--handles", default=None, metavar="FILE",
                    help="one mesh file: the fixed vertices, 0-based ids one per line as a LIM case's "
                         "handles.txt (default: the boundary vertices)")
    sp.add_argument("--solver", default="lbfgs", choices=["lbfgs", "newton"],
                    help="inner solver (default lbfgs, measured fastest for untangling)")
    sp.add_argument("--start", default="auto", choices=["auto", "given", "harmonic"],
                    help="where untangling starts: the given map, the harmonic extension of the handles "
                         "(its free vertices moved), or auto (default: the harmonic extension for quads and "
                         "hexahedra when it has fewer inverted corners, else the given map)")
    sp.add_argument("--png", default=None,
                    help="also save a picture of the start and the result, inverted elements in red")
    where = sp.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_positive_int, default=None,
                       help="batch: solve on a local Dask cluster of N worker processes (default: one "
                            "per CPU core; 1 solves in this process)")
    where.add_argument("--scheduler", default=None,
                       help="batch: solve on the workers of an existing Dask scheduler (e.g. "
                            "tcp://host:8786); they must see the case and output folders at the same paths")
    _common_options(sp)
    sp.set_defaults(func=cmd_untangle)


def _add_smooth(sub):
    """The ``smooth`` command's options."""
    from .._runtime.names import ENERGIES, SOLVERS

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
    _common_options(sp)
    sp.set_defaults(func=cmd_smooth)


def _add_compare(sub):
    """The ``compare`` command's options."""
    sp = sub.add_parser("compare", help="run several solvers from the same start on one or more meshes: "
                                         "traces, table, manifest and a figure")
    sp.add_argument("mesh", nargs="+", help="disk-topology mesh (free boundary, Tutte start) or a LIM case folder "
                                            "(fixed handles, its flip-free map as the start); several: one "
                                            "sub-folder each plus a combined table and figure")
    sp.add_argument("-o", "--output", "--out", dest="output", required=True,
                    help="output folder: history.csv, summary.csv, table.tex, manifest.json, <solver>.obj "
                         "(.vtk for tets), convergence.<format>")
    sp.add_argument("--solvers", default=None,
                    help="comma-separated solver names (default newton,lbfgs,slim,aqp,cm; cm only in 2D; "
                         "optx-lbfgs, optx-bfgs, optx-ncg on request)")
    sp.add_argument("--energy", default="symmetric_dirichlet", help="energy name (default symmetric_dirichlet)")
    sp.add_argument("--weights", default="uniform", choices=["uniform", "mean_value"],
                    help="Tutte weights of the free-boundary start map")
    sp.add_argument("--reference", default="auto",
                    help="what gaps are measured to: auto (a tight Newton solve, the default), best (the "
                         "lowest energy any solver reached) or a mean energy")
    sp.add_argument("--repeat", type=_positive_int, default=1, help="runs per solver; times are medians")
    sp.add_argument("--tolerances", default="1e-2,1e-4,1e-6",
                    help="relative gaps the table reports iterations and seconds to (default 1e-2,1e-4,1e-6)")
    sp.add_argument("--max-seconds", type=float, default=None,
                    help="stop each solver after this many seconds of solve time (setup excluded, on --clock)")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit of every solver")
    sp.add_argument("--clock", default="wall", choices=["wall", "cpu"],
                    help="seconds used by --max-seconds, the figure's time axis, table.tex and the median run: "
                         "wall (elapsed, the default) or cpu (process CPU time, all threads summed: steadier "
                         "on a loaded machine); both are always in the CSV files")
    sp.add_argument("--no-warmup", dest="warmup", action="store_false",
                    help="time each solver's first, cold run (default: one untimed warm-up run per solver "
                         "first, so that lazy compilation is not solve time)")
    sp.add_argument("--format", default="png",
                    help="figure formats, comma-separated: png, pdf, svg, eps, ps (default png; PDF and "
                         "PostScript embed TrueType fonts)")
    sp.add_argument("--log-x", action="store_true", help="log scale on the seconds and iteration axes")
    sp.add_argument("--layout", default="wide", choices=["wide", "column"],
                    help="figure: three panels per mesh, 15 in wide (default), or column: the gap against "
                         "seconds alone, 3.4 in wide (one paper column)")
    sp.add_argument("--font-size", type=float, default=None,
                    help="figure font size in points (default 10 wide, 8 column)")
    _common_options(sp)
    sp.set_defaults(func=cmd_compare)


def _add_demo(sub):
    """The ``demo`` command's options."""
    sp = sub.add_parser("demo", help="parameterize the bundled camelhead, write OBJ and PNGs")
    sp.add_argument("-o", "--output", default="out", help="output folder (default ./out)")
    _common_options(sp)
    sp.set_defaults(func=cmd_demo)


def _report(args, **fields):
    """Add ``fields`` to the --json summary."""
    args.summary.update(fields)


class _UsageError(Exception):
    """A command line argparse refuses (raised instead of argparse's own exit)."""

    def __init__(self, parser, message):
        super().__init__(message)
        self.parser = parser


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is raised, so that ``--json`` can still print its JSON."""

    def error(self, message):
        raise _UsageError(self, message)


def main(argv=None) -> int:
    t0 = time.perf_counter()
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    try:
        args = build_parser().parse_args(argv)
    except _UsageError as exc:  # one line, exit status 2, and the JSON summary if asked
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
        code = _run(args)
        return code
    finally:
        if args.json:
            from ..experiments.manifest import SCHEMA_VERSION, versions

            _report(args, exit_status=code, success=code == EXIT_OK,
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
    from .._runtime.errors import GeomoptError, GeomoptWarning, SolveError

    if args.json:
        from .._runtime.cache import cache_stats

        cache_stats()  # count persistent-cache hits and misses from here on
    try:
        with _signals_raise(), warnings.catch_warnings():
            if not args.debug:  # errors are one line: no NumPy RuntimeWarning (overflow, 0/0...) on stderr
                warnings.simplefilter("ignore", RuntimeWarning)
            warnings.simplefilter("always", GeomoptWarning)  # each run's own, deduplicated by _Warnings
            warnings.showwarning = said = _Warnings(warnings.showwarning)
            code = args.func(args)
            if code == EXIT_OK:
                said.print()
            return code
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

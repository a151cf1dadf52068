"""``geomopt param`` (a disk, an atlas through :mod:`~geomopt.cli.atlas`, or ``--sphere``) and ``geomopt demo``
(``param`` on the bundled camelhead): read, call :func:`geomopt.parameterize` /
:func:`geomopt.sphere.sphere_map`, print, and write the certified map with its pictures."""

from __future__ import annotations

import argparse
import contextlib
import functools
import re
import sys
import time
from pathlib import Path

from .common import EXIT_OK, cache_summary, fail, log, make_solver, output_paths, report, timed_solve

__all__ = ["cmd_param", "cmd_demo", "convergence_path"]


def _param_input(args):
    """``(V, F, x0, start, faces)`` of ``geomopt param``: the mesh, the start map (an array, None
    for Tutte's or ``"projection"``), how the log names it, and an OBJ's own faces (polygons, as
    :func:`geomopt.io.read_obj_polygons` reads them; else ``F``)."""
    from .. import io

    if args.init == "uv":
        V, F, x0 = io.read_obj_uv(args.input)
        return V, F, x0, "its own UV start map", F
    from .atlas import read_surface

    V, F, faces = read_surface(args.input)
    if args.init == "tutte":
        return V, F, None, f"{args.weights} Tutte start", faces
    return V, F, args.init, "plane projection start", faces


def cmd_param(args) -> int:
    """Parameterize a surface: a disk with a free boundary (or bounded by a scaffold with
    ``--bijective``), any other surface (or with ``--atlas``) as an atlas, or with ``--sphere``
    a closed genus-0 mesh onto the sphere."""
    from .. import io
    from .._runtime.errors import ParameterError
    from .._runtime.timing import compile_seconds
    from ..energies import get_energy
    from ..param import ParamOptions, parameterize

    split = args.timing
    split.mark_imported()
    compile_seconds()  # starts counting JAX's compilation
    inputs = args.input if isinstance(args.input, (list, tuple)) else [args.input]
    if len(inputs) > 1:
        from .atlas import param_atlases

        return param_atlases(args, inputs, get_energy(args.energy), make_solver(args.solver, args.max_steps))
    args.input = inputs[0]
    if args.padding is not None and args.resolution is None:
        raise ParameterError("--padding (texels) goes with --resolution N, the texture's side in texels; give both")
    if args.sphere:
        return _param_sphere(args)
    if getattr(args, "pole", None) is not None:
        raise ParameterError("--pole goes with --sphere (the vertex a sphere map's start puts at the south pole); "
                             "leave it out for a map into the plane")
    energy = get_energy(args.energy)
    solver = make_solver(args.solver, args.max_steps)
    pictures = []
    if args.png:
        pictures = [("--png picture", args.png), ("convergence picture", str(convergence_path(args.png)))]
    folder = getattr(args, "folder", None)  # demo: the output folder, created only to write into it
    if args.bijective and args.init == "projection":
        raise ParameterError("--bijective starts from the Tutte map (--init tutte, the default) or from a globally "
                             "injective --init uv map, not from --init projection; drop one of the two options")
    output_paths(args.output, io.UV_MESH_EXTENSIONS, pictures, [args.input], folder)  # before reading or solving
    with split.phase("read"):
        V, F, x0, start, faces = _param_input(args)
    log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; energy {energy.name}, "
              f"solver {args.solver}, {start}")
    if Path(args.input).suffix.lower() == ".stl":
        log(args, f"{args.input}: STL stores every triangle's corners separately; welded the "
                  f"{3 * len(F)} corners with bit-identical coordinates into {len(V)} vertices")
    from .atlas import is_disk, param_atlas

    if args.atlas or args.resolution is not None or not is_disk(F, len(V)):  # closed, holes, components: charts
        return param_atlas(args, V, F, faces, energy, solver)
    options = ParamOptions(weights=args.weights, bijective=args.bijective)
    solve = functools.partial(parameterize, V, F, energy=energy, solver=solver, options=options, x0=x0,
                              progress=not args.quiet)
    return _param_disk(args, V, F, energy, solve, folder)


def _param_disk(args, V, F, energy, solve, folder) -> int:
    """A disk's UV map: ``solve()`` (:func:`geomopt.parameterize`), reported, and written with its
    pictures when certified."""
    from .. import io
    from .._runtime.errors import MeshError
    from .._runtime.memory import release_free_memory
    from .._runtime.timing import compile_seconds
    from ..mesh.convert import unit_square

    split = args.timing
    t_solve, compiled = time.perf_counter(), compile_seconds()
    try:
        res = solve()
    except MeshError as exc:
        raise _for_the_command_line(exc, args) from exc
    # setup: everything in parameterize but the solve and JAX's compilation (start map, scaling,
    # patterns, analysis, the exact certificate)
    compiled = compile_seconds() - compiled
    split.add("compile", compiled)
    split.add("solve", res.stats.seconds)
    split.add("setup", time.perf_counter() - t_solve - res.stats.seconds - compiled)
    if res.objective is not None:  # solving is over: PARDISO's analysis and factor (1.5 GB at 10^6
        res.objective.release_factorizations()  # triangles) are not held under the outputs' writing
        release_free_memory()
    rep = res.details.repair if res.details is not None else None
    if rep is not None:
        log(args, f"repaired the start map's {rep.stats.inverted_at_start} folded triangle(s), boundary held: "
                  f"{rep.stats.outer_iterations} outer iterations, {rep.stats.seconds:.2f} s, "
                  f"{'certified' if rep.success else 'not certified: ' + rep.message}")
    if rep is not None and not rep.success:
        return fail(f"the start map could not be repaired: {rep.message}")
    _report_disk(args, V, F, energy, res)
    if not res.success:
        return fail(f"not certified: {res.message}")
    if res.injectivity == "local":
        _warn_overlap(res, args)
    if folder is not None:
        io.create_output_folder(folder)
    uv = unit_square(res.x) if args.uv_range == "unit" else res.x
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            with split.phase("figures"):
                _save_param_figures(res, V, F, uv, args.png, outputs, args)
        with split.phase("write"):
            io.write_mesh_with_uv(outputs.enter_context(io.atomic_path(args.output)), V, F, uv,
                                  format=Path(args.output).suffix[1:])
    return EXIT_OK


def _report_disk(args, V, F, energy, res):
    """The summary line and the --json fields of a disk's solve."""
    mean, st = res.mean_energy, res.stats
    log(args, f"faces {len(F)}  iterations {st.iterations}  seconds {st.seconds:.2f}  "
              f"compile seconds {st.setup_seconds:.2f}  energy {res.energy:.10g}  mean energy {mean:.10g}  "
              f"flips {res.certificate.inverted}  injective {res.injectivity}  outcome {res.outcome.value}")
    report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F),
           energy_name=energy.name, solver=args.solver, iterations=st.iterations,
           solve_seconds=round(st.seconds, 4), setup_seconds=round(st.setup_seconds, 4),
           energy=res.energy, mean_energy=mean, flips=res.certificate.inverted, injectivity=res.injectivity,
           boundary_crossings=_boundary_crossings(res), uv_range=args.uv_range,
           outcome=res.outcome.value, message=res.message, **cache_summary())


def _param_sphere(args) -> int:
    """``geomopt param --sphere``: a closed genus-0 mesh onto the unit sphere, certified
    (:func:`geomopt.sphere.sphere_map`); the OBJ keeps the faces, its vertices on the sphere."""
    import math

    from .. import io, plot
    from .._runtime.errors import ParameterError
    from ..objective.distortion import sphere_distortion
    from ..sphere import SphereOptions, default_solver, sphere_map

    if (args.bijective or args.atlas or args.init != "tutte" or args.uv_range != "raw" or args.margin is not None
            or args.resolution is not None or args.padding is not None):
        raise ParameterError("--sphere makes its own certified start and writes vertices, not UVs or charts: "
                             "leave out --bijective, --atlas, --margin, --resolution, --padding, --init and "
                             "--uv-range")
    # newton is the parser's default: the sphere's default L-BFGS then
    solver = make_solver(default_solver() if args.solver == "newton" else args.solver, args.max_steps)
    pictures = [("--png picture", args.png)] if args.png else []
    output_paths(args.output, (".obj",), pictures, [args.input], getattr(args, "folder", None))
    with args.timing.phase("read"):
        V, F = io.read_mesh(args.input)
    if args.pole is not None and args.pole >= len(V):
        raise ParameterError(f"--pole {args.pole}: {args.input} has {len(V)} vertices, 0-based ids 0 to {len(V) - 1}")
    log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; onto the sphere, energy {args.energy}, L-BFGS")
    res = timed_solve(args.timing, lambda: sphere_map(V, F, energy=args.energy, solver=solver, progress=not args.quiet,
                                                      options=SphereOptions(weights=args.weights, pole=args.pole)))
    st, cert, dist = res.stats, res.certificate, sphere_distortion(V, F, res.x)
    log(args, f"faces {len(F)}  iterations {st.iterations}  seconds {st.seconds:.2f}  mean energy "
              f"{res.mean_energy:.10g}  area ratio {dist['area_min']:.3g}..{dist['area_max']:.3g}  flips "
              f"{cert.inverted}  spherical area {cert.area:.12g} (4 pi = {4 * math.pi:.12g})  outcome {res.outcome.value}")
    report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F), sphere=True,
           energy_name=args.energy, pole=res.details.pole, iterations=st.iterations, solve_seconds=round(st.seconds, 4),
           mean_energy=res.mean_energy, flips=cert.inverted, spherical_area=cert.area, degree=cert.degree,
           area_ratio_min=dist["area_min"], area_ratio_max=dist["area_max"], injectivity=res.injectivity,
           outcome=res.outcome.value, message=res.message, **cache_summary())
    if not res.success:
        return fail(f"not certified: {res.message}")
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            title = (f"{Path(args.input).name}: {len(F)} triangles onto the sphere, {args.energy}, mean energy "
                     f"{res.mean_energy:.6g}, certified bijective")
            with args.timing.phase("figures"):
                plot.save_sphere_figure(outputs.enter_context(io.atomic_output(args.png, "wb")), V, F, res.x,
                                        title=title, format=Path(args.png).suffix[1:].lower())
        with args.timing.phase("write"):
            io.write_obj(outputs.enter_context(io.atomic_path(args.output)), res.x, F)
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


def convergence_path(png):
    """The convergence picture saved beside the ``--png`` layout: ``<stem>_convergence<suffix>``."""
    base = Path(png)
    return base.with_name(base.stem + "_convergence" + base.suffix)


def _save_param_figures(res, V, F, uv, png, outputs, args):
    """Render the layout and convergence pictures into atomic temporaries registered on ``outputs``."""
    from .. import io, plot
    from ..plot._save import save_param_picture

    obj = res.objective
    base, conv = Path(png), convergence_path(png)
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


def cmd_demo(args) -> int:
    """Parameterize the bundled camelhead and write OBJ + UV picture + convergence plot."""
    out = Path(args.output)
    from ..data import path as bundled

    data = bundled("camelhead")
    ns = argparse.Namespace(input=str(data), output=str(out / "camelhead_uv.obj"), folder=out,
                            energy="symmetric_dirichlet", solver="newton", weights="uniform", init="tutte", bijective=False,
                            max_steps=None, quiet=args.quiet, png=str(out / "camelhead_uv.png"), atlas=False, sphere=False, pole=None, margin=None,
                            resolution=None, padding=None,
                            uv_range="raw", json=args.json, summary=args.summary, timing=args.timing)
    code = cmd_param(ns)
    if code == EXIT_OK and not args.json:  # --json: stdout holds only the summary
        print(f"wrote {out / 'camelhead_uv.obj'}, {out / 'camelhead_uv.png'}, "
              f"{out / 'camelhead_uv_convergence.png'}")
    return code

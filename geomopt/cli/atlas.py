"""``geomopt param`` on a surface that is not a disk (or with ``--atlas`` or ``--resolution``), or
on several meshes: make a certified atlas, write it as OBJ (the input's ``v`` lines and face
order, one ``vt`` per chart corner, ``f v/vt ...`` with an OBJ input's own polygons) and, with
``--png``, its picture.  Several meshes share one atlas and get one OBJ each in the ``-o`` folder."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from .._runtime.errors import MeshError, ParameterError
from ..exact.topology import check_disk
from .common import EXIT_OK, cache_summary, fail, log, report

__all__ = ["is_disk", "param_atlas", "param_atlases", "read_surface"]


def is_disk(F, n_vertices) -> bool:
    """Whether the mesh is a topological disk (:func:`geomopt.exact.topology.check_disk` passes)."""
    try:
        check_disk(F, n_vertices)
    except MeshError:
        return False
    return True


def read_surface(path):
    """``(V, F, faces)``: the mesh file's vertices, its triangles (polygons fan-triangulated, as
    :func:`geomopt.io.read_mesh` reads them) and its own faces (an OBJ's polygons,
    :func:`geomopt.io.read_obj_polygons`; ``F`` for the other formats)."""
    import numpy as np

    from .. import io

    if Path(path).suffix.lower() != ".obj":
        V, F = io.read_mesh(path)
        return V, F, F
    V, faces = io.read_obj_polygons(path)
    if isinstance(faces, np.ndarray) and faces.shape[1] == 3:
        return V, faces, faces
    counts = [faces.shape[1]] * len(faces) if isinstance(faces, np.ndarray) else [len(f) for f in faces]
    corners = faces.reshape(-1) if isinstance(faces, np.ndarray) else np.concatenate(faces)
    return V, io.fan_triangulate(corners, np.asarray(counts, dtype=np.int64)), faces


def _check_atlas_args(args):
    if args.init != "tutte":
        raise ParameterError(f"an atlas flattens each chart from its own Tutte map; drop --init {args.init}")
    if args.bijective or args.uv_range != "raw":
        raise ParameterError("an atlas is packed into the unit square and certified whole: drop --bijective and "
                             "--uv-range")


def param_atlas(args, V, F, faces, energy, solver) -> int:
    """The atlas branch of ``geomopt param`` on one mesh (``args`` as the command parsed them;
    ``faces`` the file's own, :func:`read_surface`).  Returns the exit status."""
    from .. import io
    from ..plot._save import write_atlas_part
    from ..atlas.build import make_atlas

    if Path(args.output).suffix.lower() != ".obj":
        raise ParameterError(f"an atlas (UVs per chart corner) is written as .obj, got {args.output}; "
                             f"name an .obj output")
    _check_atlas_args(args)
    options = _options(args)
    said = io.nonmanifold_edge_in_file(args.input, F)  # in the file's terms (make_atlas speaks of F's rows)
    if said:
        raise MeshError(said)
    why = "--atlas" if args.atlas else "--resolution" if args.resolution is not None else "not a disk"
    log(args, f"{args.input}: {why}: cutting it into charts")
    result = make_atlas(V, faces, energy=energy, solver=solver, progress=_progress(args), options=options)
    code = _report(args, result, [args.input], energy)
    if code != EXIT_OK:
        return code
    folder = getattr(args, "folder", None)
    if folder is not None:
        io.create_output_folder(folder)
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            with args.timing.phase("figures"):
                _save_picture(result, Path(args.input).name, args, outputs)
        with args.timing.phase("write"):
            write_atlas_part(outputs.enter_context(io.atomic_path(args.output)), result.details.part(result.x))
    return EXIT_OK


def param_atlases(args, inputs, energy, solver) -> int:
    """``geomopt param A B ... -o DIR``: one atlas shared by every mesh, ``DIR/<input name>.obj``
    for each (and ``--png`` of them all).  Returns the exit status."""
    from .. import io
    from .._runtime.formats import PICTURE_EXTENSIONS
    from ..plot._save import write_atlas_part
    from ..atlas.build import make_atlas

    if args.sphere:
        raise ParameterError("--sphere maps one mesh; give one input")
    _check_atlas_args(args)
    options = _options(args)
    folder = Path(args.output)
    if folder.suffix.lower() in io.MESH_EXTENSIONS:
        raise ParameterError(f"with several inputs -o names a folder (one .obj per input in it), got {folder}")
    names = [Path(p).stem + ".obj" for p in inputs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ParameterError(f"two inputs would both be written as {twice[0]} in {folder}: rename one")
    outputs = [folder / n for n in names]
    files = [(f"output for {p}", o, (".obj",)) for p, o in zip(inputs, outputs)]
    files += [("--png picture", args.png, PICTURE_EXTENSIONS)] if args.png else []
    io.check_outputs(files, inputs, folder)
    meshes = []
    with args.timing.phase("read"):
        for p in inputs:
            V, F, faces = read_surface(p)
            said = io.nonmanifold_edge_in_file(p, F)
            if said:
                raise MeshError(said)
            meshes.append((V, faces))
            log(args, f"{p}: {len(V)} vertices, {len(F)} triangles")
    log(args, f"{len(inputs)} meshes: cutting them into charts of one atlas; energy {energy.name}, solver {args.solver}")
    result = make_atlas(meshes, energy=energy, solver=solver, progress=_progress(args), options=options)
    code = _report(args, result, inputs, energy)
    if code != EXIT_OK:
        return code
    io.create_output_folder(folder)
    with contextlib.ExitStack() as stack:  # every file is renamed into place only when all are written
        if args.png:
            with args.timing.phase("figures"):
                _save_picture(result, f"{len(inputs)} meshes", args, stack)
        with args.timing.phase("write"):
            for i, o in enumerate(outputs):
                write_atlas_part(stack.enter_context(io.atomic_path(o)), result.details.part(result.x, i))
    return EXIT_OK


def _options(args):
    """The :class:`~geomopt.atlas.AtlasOptions` the command line sets (the others: defaults)."""
    from ..atlas.build import AtlasOptions

    given = {"margin": args.margin, "up": getattr(args, "up", None), "resolution": getattr(args, "resolution", None),
             "padding": getattr(args, "padding", None)}
    return AtlasOptions(**{name: value for name, value in given.items() if value is not None})


def _report(args, result, inputs, energy) -> int:
    """The summary line, the --json fields and the warnings of an atlas; the exit status so far."""
    d, m = result.details, result.details.metrics
    log(args, f"atlas: charts {m.charts}  seam length {m.seam_length:.6g}  mean symmetric Dirichlet "
              f"{m.mean_symmetric_dirichlet:.6g}  worst {m.worst_symmetric_dirichlet:.6g}  efficiency "
              f"{m.efficiency:.4f}  mirrored {m.mirrored_charts}  margin {d.margin:.6g}  seconds {d.seconds:.2f}  "
              f"{'certified' if result.success else 'not certified'}")
    one = len(inputs) == 1
    report(args, input=str(inputs[0]) if one else [str(p) for p in inputs], output=str(args.output),
           vertices=len(d.vertices), faces=len(d.faces), energy_name=energy.name, solver=args.solver, atlas=True,
           charts=m.charts, seam_length=m.seam_length, mean_symmetric_dirichlet=m.mean_symmetric_dirichlet,
           worst_symmetric_dirichlet=m.worst_symmetric_dirichlet, efficiency=m.efficiency,
           mirrored_charts=m.mirrored_charts, margin=d.margin, resolution=getattr(args, "resolution", None),
           certified=result.success, seconds=round(d.seconds, 4), message=result.message, **cache_summary())
    if not result.success:
        return fail(f"atlas not certified: {result.message}")
    if len(d.pinched):  # said even with --quiet, in the file's own numbering
        mesh = int(sum(d.vertex_offsets[1:] <= d.pinched[0]))
        base = 1 if Path(inputs[mesh]).suffix.lower() == ".obj" else 0
        print(f"geomopt: warning: {len(d.pinched)} pinched vertex(es) (their faces form several fans) "
              f"split, one copy per fan; first: vertex {int(d.pinched[0] - d.vertex_offsets[mesh]) + base} of "
              f"{inputs[mesh]}", file=sys.stderr, flush=True)
    crossed = d.split_polygons()
    if len(crossed):
        mesh = int(sum(d.face_offsets[1:] <= crossed[0]))
        print(f"geomopt: warning: a seam crosses {len(crossed)} polygon(s), written as their fan triangles; "
              f"first: face {int(crossed[0] - d.face_offsets[mesh]) + 1} of {inputs[mesh]}", file=sys.stderr,
              flush=True)
    return EXIT_OK


def _progress(args):
    """The atlas's progress: its lines through the command's logger (unless ``--quiet``), and its
    stages' seconds into the ``--json`` timing split: ``cut`` until the seam graph is made,
    ``flatten`` until the last chart is flattened or split (the last stage before packing), and
    ``pack`` (packing splits, packing, the exact certificate and the metrics) until it is packed."""
    import time

    t = {"stage": time.perf_counter(), "flattened": None}  # the stage's start; the last flattening event

    def say(stage, info):
        now = time.perf_counter()
        if stage == "cut":
            args.timing.add("cut", now - t["stage"])
            t["stage"] = now
        elif stage == "packed":
            end = t["flattened"] or t["stage"]
            args.timing.add("flatten", end - t["stage"])
            args.timing.add("pack", now - end)
            t["stage"] = now
        elif stage != "split to pack":  # a chart flattened, the charts flattened, a split, cuts taken back
            t["flattened"] = now  # (a split to pack is packing's)
        if not args.quiet:
            log(args, f"atlas {stage}: " + ", ".join(f"{k} {v:.6g}" if isinstance(v, float) else f"{k} {v}"
                                                     for k, v in info.items()))
    return say


def _save_picture(result, name, args, outputs):
    from .. import io
    from ..plot._save import save_atlas_picture

    base = Path(args.png)
    save_atlas_picture(outputs.enter_context(io.atomic_output(base, "wb")), result, name, base.suffix[1:].lower())

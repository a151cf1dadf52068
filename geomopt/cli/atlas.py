"""``geomopt param`` on a surface that is not a disk (or with ``--atlas``): make a certified
atlas, write it as OBJ (the input's ``v`` lines and face order, one ``vt`` per chart corner,
``f v/vt ...``) and, with ``--png``, its picture."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from .._runtime.errors import MeshError, ParameterError
from ..exact.topology import check_disk
from .common import EXIT_OK, cache_summary, fail, log, report

__all__ = ["is_disk", "param_atlas"]


def is_disk(F, n_vertices) -> bool:
    """Whether the mesh is a topological disk (:func:`geomopt.exact.topology.check_disk` passes)."""
    try:
        check_disk(F, n_vertices)
    except MeshError:
        return False
    return True


def param_atlas(args, V, F, energy, solver) -> int:
    """The atlas branch of ``geomopt param`` (``args`` as the command parsed them).  Returns the
    exit status."""
    from .. import io
    from ..atlas.build import AtlasOptions, make_atlas

    if Path(args.output).suffix.lower() != ".obj":
        raise ParameterError(f"an atlas (UVs per chart corner) is written as .obj, got {args.output}; "
                             f"name an .obj output")
    if args.init != "tutte":
        raise ParameterError(f"an atlas flattens each chart from its own Tutte map; drop --init {args.init}")
    said = io.nonmanifold_edge_in_file(args.input, F)  # in the file's terms (make_atlas speaks of F's rows)
    if said:
        raise MeshError(said)
    log(args, f"{args.input}: {'--atlas' if args.atlas else 'not a disk'}: cutting it into charts")
    atlas = make_atlas(V, F, energy=energy, solver=solver, progress=_progress(args),
                       options=AtlasOptions(**_atlas_settings(args)))
    m = atlas.metrics
    log(args, f"atlas: charts {m.charts}  seam length {m.seam_length:.6g}  mean symmetric Dirichlet "
              f"{m.mean_symmetric_dirichlet:.6g}  worst {m.worst_symmetric_dirichlet:.6g}  efficiency "
              f"{m.efficiency:.4f}  mirrored {m.mirrored_charts}  seconds {atlas.seconds:.2f}  "
              f"{'certified' if atlas.success else 'not certified'}")
    report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F),
           energy_name=energy.name, solver=args.solver, atlas=True, charts=m.charts, seam_length=m.seam_length,
           mean_symmetric_dirichlet=m.mean_symmetric_dirichlet, worst_symmetric_dirichlet=m.worst_symmetric_dirichlet,
           efficiency=m.efficiency, mirrored_charts=m.mirrored_charts, certified=atlas.success,
           seconds=round(atlas.seconds, 4), message=atlas.message, **cache_summary())
    if not atlas.success:
        return fail(f"atlas not certified: {atlas.message}")
    if len(atlas.pinched):  # said even with --quiet, in the file's own numbering
        base = 1 if Path(args.input).suffix.lower() == ".obj" else 0
        print(f"geomopt: warning: {len(atlas.pinched)} pinched vertex(es) (their faces form several fans) "
              f"split, one copy per fan; first: vertex {int(atlas.pinched[0]) + base} of {args.input}",
              file=sys.stderr, flush=True)
    folder = getattr(args, "folder", None)
    if folder is not None:
        io.create_output_folder(folder)
    with contextlib.ExitStack() as outputs:  # every file is renamed into place only when all are written
        if args.png:
            with args.timing.phase("figures"):
                _save_picture(atlas, V, F, args, outputs)
        with args.timing.phase("write"):
            io.write_mesh_with_uv(outputs.enter_context(io.atomic_path(args.output)), V, F, atlas.uv,
                                  format="obj", uv_faces=atlas.uv_faces)
    return EXIT_OK


def _atlas_settings(args) -> dict:
    """The :class:`~geomopt.atlas.AtlasOptions` fields the command line sets (the others: defaults)."""
    given = {"margin": args.margin, "up": getattr(args, "up", None)}
    return {name: value for name, value in given.items() if value is not None}


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


def _save_picture(atlas, V, F, args, outputs):
    from .. import io, plot

    base = Path(args.png)
    m = atlas.metrics
    title = (f"{Path(args.input).name}: {len(F)} triangles, {m.charts} charts, seam length {m.seam_length:.4g}, "
             f"mean symmetric Dirichlet {m.mean_symmetric_dirichlet:.4g}, efficiency {m.efficiency:.3f}, certified")
    plot.save_atlas_figure(outputs.enter_context(io.atomic_output(base, "wb")), V, F, atlas.uv, atlas.uv_faces,
                           atlas.chart, atlas.seams, title=title, format=base.suffix[1:].lower())

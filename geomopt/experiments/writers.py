"""The files of a comparison (:mod:`geomopt.experiments.comparison`): CSV tables, the LaTeX
table, the manifest, each solver's map and the convergence figures, every file checked before
any work (none replaces an input) and written atomically."""

from __future__ import annotations

import csv
import io as _io
import json
import os
import time
from pathlib import Path

import numpy as np

from . import manifest as _manifest
from .. import io
from ..mesh.elements import kind_of
from .options import HISTORY_COLUMNS, summary_columns

__all__ = ["common_names", "output_names", "set_output_names", "input_files", "prepare_folder", "write_csv",
           "write_common", "write_maps", "write_comparison", "write_set", "write_combined"]


def write_comparison(comparison, out, formats=("png",), log_x=False, extra=None, *, layout="wide",
                     font_size=None) -> dict:
    """:meth:`geomopt.experiments.comparison.Comparison.write`: its files into
    the folder ``out``; dict file kind -> pathlib.Path."""
    c = comparison
    out = prepare_folder(out, c.output_names(formats))
    paths = {"history": out / "history.csv", "summary": out / "summary.csv"}
    write_csv(paths["history"], HISTORY_COLUMNS, c.history_rows())
    columns = summary_columns(c.tolerances)
    write_csv(paths["summary"], columns, [[row[k] for k in columns] for row in c.summary_rows()])
    paths.update(write_maps(c, out))
    paths.update(write_common(out, {c.label: c}, formats, extra, dict(log_x=log_x, layout=layout,
                                                                      font_size=font_size)))
    return paths


def write_maps(comparison, out) -> dict:
    """Each solver's final map into ``out``: OBJ with UVs (2D), VTK tets (3D), the cells for
    quads (OBJ) and hexahedra (VTK); dict solver name -> path."""
    problem, paths = comparison.objective.problem, {}
    V = np.asarray(problem.rest_vertices, np.float64)
    for name, r in comparison.results.items():
        x = np.asarray(r.x) * comparison.mirror  # negation is exact
        if problem.elements is not None:  # quads (.obj) / hexahedra (.vtk): the cells themselves
            kind = kind_of(problem.elements)
            paths[name] = io.write_cells(out / f"{name}{kind.map_file}", x, problem.elements, kind.word)
        elif problem.dim == 2:
            V3 = V if V.shape[1] == 3 else np.c_[V, np.zeros(len(V))]
            paths[name] = io.write_obj_with_uv(out / f"{name}.obj", V3, problem.input_simplices, x)
        else:
            paths[name] = io.write_vtk_tets(out / f"{name}.vtk", x, problem.input_simplices)
    return paths


def set_output_names(comparisons, formats=("png",)) -> list:
    """The file names :meth:`geomopt.experiments.comparison.ComparisonSet.write`
    writes."""
    names = common_names(formats)
    for key, c in comparisons.comparisons.items():
        names += [f"{key}/{n}" for n in c.output_names(formats)]
    return names


def write_set(comparisons, out, formats=("png",), log_x=False, extra=None, **figure) -> dict:
    """Each comparison into ``out/<mesh name>/``, then :func:`write_combined`."""
    out = prepare_folder(out, common_names(formats))
    paths = {key: c.write(out / key, formats, log_x, **figure) for key, c in comparisons.comparisons.items()}
    return {**paths, **write_combined(comparisons, out, formats, log_x, extra, **figure)}


def write_combined(comparisons, out, formats=("png",), log_x=False, extra=None, *, layout="wide",
                   font_size=None) -> dict:
    """Over all comparisons of a set: ``summary.csv`` (with a ``mesh`` column), ``table.tex``,
    ``manifest.json`` and ``convergence.<format>`` (one row of panels per mesh) in ``out``."""
    out = prepare_folder(out, common_names(formats))
    tolerances = next(iter(comparisons.comparisons.values())).tolerances
    columns = ("mesh",) + summary_columns(tolerances)
    paths = {"summary": out / "summary.csv"}
    write_csv(paths["summary"], columns, [[row[c] for c in columns] for row in comparisons.summary_rows()])
    by_label = {c.label: c for c in comparisons.comparisons.values()}
    paths.update(write_common(out, by_label, formats, extra, dict(log_x=log_x, layout=layout, font_size=font_size)))
    return paths


def common_names(formats):
    return ["summary.csv", "table.tex", "manifest.json"] + [f"convergence.{f}" for f in formats]


def output_names(names, dim, formats=("png",)):
    ext = ".obj" if dim == 2 else ".vtk"
    return ["history.csv"] + common_names(formats) + [n + ext for n in names]


def input_files(meshes):
    """The input files among ``meshes`` (paths; arrays and trimesh objects are not files)."""
    return [m for m in meshes if isinstance(m, (str, os.PathLike))]


def prepare_folder(out, names, inputs=(), create=True) -> Path:
    """Check every file in ``names`` (relative to the folder ``out``) before any work with
    :func:`geomopt.io.check_outputs` (none replaces an input, ``out``'s parent exists), then
    create ``out`` unless ``create`` is False."""
    out = Path(out)
    io.check_outputs([out / n for n in names], inputs, folder=out)
    return io.create_output_folder(out) if create else out


def write_csv(path, columns, rows):
    def cell(v):
        return "" if v is None else repr(float(v)) if isinstance(v, float) else v

    def write(fh):
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        w.writerows([cell(v) for v in row] for row in rows)

    return io.atomic_write(path, write)


def write_common(out, comparisons: dict, formats, extra, figure) -> dict:
    """``table.tex``, ``manifest.json`` and ``convergence.<format>`` (``figure``: the keyword
    arguments of :func:`~geomopt.experiments.report.comparison_figure`) of ``comparisons``
    (label -> :class:`Comparison`) into ``out``."""
    from .report import comparison_figure, latex_table, save_figure

    paths = {"table": io.atomic_write(out / "table.tex", lambda fh: fh.write(latex_table(comparisons)))}
    manifest = {"schema_version": _manifest.SCHEMA_VERSION, "kind": "geomopt.compare",
                "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "versions": _manifest.versions(), "environment": _manifest.environment(),
                "comparisons": {label: c.manifest() for label, c in comparisons.items()},
                "figure": {"formats": list(formats), **figure}, **(extra or {})}
    paths["manifest"] = io.atomic_write(out / "manifest.json",
                                        lambda fh: fh.write(json.dumps(manifest, indent=1, default=str) + "\n"))
    fig = comparison_figure(comparisons, **figure)
    for fmt in formats:
        buf = _io.BytesIO()
        save_figure(fig, buf, fmt)
        paths[f"convergence.{fmt}"] = io.atomic_write(out / f"convergence.{fmt}",
                                                      lambda fh, data=buf.getvalue(): fh.write(data), mode="wb")
    return paths

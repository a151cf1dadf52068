"""Writing a solve's map file and picture: :func:`geomopt.save` (also :meth:`geomopt.Result.save`),
and the pictures ``geomopt param --png`` shares with it.

What is written depends on what the result's :class:`~geomopt.Problem` maps
(:data:`MAP_FILES`): a triangle mesh with its per-vertex UV map (``.obj`` / ``.ply``, the
rest vertices as positions, :func:`geomopt.io.write_mesh_with_uv`, as ``geomopt param`` and a
2D LIM case write them), a sphere map as the mesh on the sphere (``.obj``, as ``geomopt param
--sphere``), a tet / quad / hex map as the mapped mesh (:func:`geomopt.io.write_cells`, as
``geomopt untangle`` writes a mesh file).  Every file is written in full precision and
atomically, the map and the picture together or neither (:func:`geomopt.io.atomic_path`).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from .._runtime.formats import PICTURE_EXTENSIONS, extensions
from ..mesh.elements import ELEMENT_KINDS

__all__ = ["MAP_FILES", "save", "save_param_picture", "write_atlas_part", "save_atlas_picture"]

#: ``Problem.kind`` -> the map file extensions :func:`save` writes for it (an element kind's: the
#: writable formats of the format table that hold it).
MAP_FILES = {
    "surface": (".obj", ".ply"), "planar": (".obj", ".ply"), "sphere": (".obj",),
    "tet": extensions("tetra", writable=True),
    **{k.problem_kind: extensions(k.word, writable=True) for k in ELEMENT_KINDS.values()},
}
_DRAWN = ("surface", "planar", "sphere")  # kinds whose result alone makes a picture


def save(result, path, png=None, *, inputs=()):
    """Write ``result``'s map to ``path`` and, with ``png``, its picture: both atomically, both
    or neither (also :meth:`geomopt.Result.save`).

    A surface or planar triangle map is written as the mesh with one UV per vertex (``.obj`` or
    ``.ply``, :func:`geomopt.io.write_mesh_with_uv`), a sphere map as the mesh on the sphere
    (``.obj``), a tet / quad / hex map as the mapped mesh (``.vtk``, ``.vtu``, ``.msh``,
    ``.mesh``; ``.obj`` for quads), as the command line writes them (:data:`MAP_FILES`); full
    precision.  The map is written as it is, certified or not (check ``result.success`` first).

    Parameters
    ----------
    result : :class:`~geomopt.solvers.Result`
        A result that knows its mesh (``result.problem``).
    path : str or os.PathLike
        The map file; its extension is one of :data:`MAP_FILES` for the problem's kind.
    png : str or os.PathLike, optional
        The picture (``.png``, ``.pdf`` or ``.svg``): triangle maps as ``geomopt param --png``
        draws them (a checkerboard through the map on the rest surface beside the layout,
        coloured by the energy density over its isometric value, or by the conformal
        distortion without an energy), sphere maps as ``param --sphere --png``.
    inputs : iterable of str or os.PathLike
        Files neither output may replace (e.g. the mesh file the result was solved on).

    Returns
    -------
    tuple of pathlib.Path
        The files written: ``(path,)`` or ``(path, png)``.

    Raises
    ------
    ParameterError
        The result does not know its mesh, its kind of map has no file (a quad surface) or no
        picture (tets, quads, hexahedra: draw them with :func:`geomopt.plot.save_untangle_figure`,
        which needs the start map too), or an extension is not one of those above; nothing is
        written.
    GeomoptError
        An output is not writable, is the other output, or is one of ``inputs``
        (:func:`geomopt.io.check_outputs`); nothing is written then.

    Examples
    --------
    >>> import geomopt
    >>> V = [[0, 0, 0], [1, 0, 0], [1, 1, 0.2], [0, 1, 0]]
    >>> result = geomopt.parameterize(V, [[0, 1, 2], [0, 2, 3]], progress=False)
    >>> [str(p) for p in geomopt.save(result, "square.obj", png="square.png")]
    ['square.obj', 'square.png']
    >>> geomopt.io.read_obj_uv("square.obj")[2].shape
    (4, 2)
    """
    from .. import io
    from .._runtime.errors import ParameterError

    if _is_atlas(result):
        return _save_atlas(result, path, png, inputs)
    problem = getattr(result, "problem", None)
    if problem is None:
        raise ParameterError("this Result does not know its mesh (result.problem is None), so geomopt.save cannot "
                             "write it; write result.x with geomopt.io (e.g. write_mesh_with_uv)")
    kind = problem.kind
    if kind not in MAP_FILES:
        raise ParameterError(f"geomopt.save writes {', '.join(MAP_FILES)} maps, not a {kind} map; write "
                             f"result.x (n, {problem.dim}) yourself")
    if png is not None and kind not in _DRAWN:
        raise ParameterError(f"geomopt.save draws triangle and sphere maps only; a {kind} map's picture needs its "
                             f"start map too: geomopt.plot.save_untangle_figure(path, start, result.x, ...)")
    files = [("geomopt.save path", path, MAP_FILES[kind])]
    files += [("geomopt.save png", png, PICTURE_EXTENSIONS)] if png is not None else []
    io.check_outputs(files, inputs)
    with contextlib.ExitStack() as outputs:  # both renamed into place only when both are written
        if png is not None:
            _picture(result, outputs.enter_context(io.atomic_output(png, "wb")), Path(png).suffix[1:].lower())
        _write_map(result, outputs.enter_context(io.atomic_path(path)), Path(path).suffix.lower())
    return (Path(path),) if png is None else (Path(path), Path(png))


def _is_atlas(result) -> bool:
    """Whether ``result`` is :func:`~geomopt.make_atlas`'s (its module is loaded if so)."""
    import sys

    build = sys.modules.get("geomopt.atlas.build")
    return build is not None and isinstance(getattr(result, "details", None), build.AtlasDetails)


def _save_atlas(result, path, png, inputs):
    """An atlas as OBJ (one ``vt`` per chart corner, the input's polygons; every mesh of a shared
    atlas in one file: write one each with :meth:`~geomopt.atlas.AtlasDetails.part`) and its picture."""
    from .. import io

    files = [("geomopt.save path", path, (".obj",))]
    files += [("geomopt.save png", png, PICTURE_EXTENSIONS)] if png is not None else []
    io.check_outputs(files, inputs)
    with contextlib.ExitStack() as outputs:
        if png is not None:
            save_atlas_picture(outputs.enter_context(io.atomic_output(png, "wb")), result, "",
                               Path(png).suffix[1:].lower())
        write_atlas_part(outputs.enter_context(io.atomic_path(path)), result.details.part(result.x))
    return (Path(path),) if png is None else (Path(path), Path(png))


def write_atlas_part(path, part):
    """An :class:`~geomopt.atlas.AtlasPart` as OBJ: ``f v/vt`` lines of triangles, or of each
    face's own corners (:func:`geomopt.io.write_obj_polygons_with_uv`)."""
    import numpy as np

    from .. import io

    if isinstance(part.faces, np.ndarray):
        return io.write_obj_with_uv(path, part.V, part.faces, part.uv, part.uv_faces)
    return io.write_obj_polygons_with_uv(path, part.V, part.faces, part.uv, part.uv_faces)


def save_atlas_picture(target, result, name="", format=None):
    """:func:`geomopt.plot.save_atlas_figure` of an atlas result (every mesh), titled with its
    figures (``name``: what it is of, e.g. the file read)."""
    from ._figures import save_atlas_figure

    d, m = result.details, result.details.metrics
    title = (f"{name + ': ' if name else ''}{len(d.faces)} triangles, {m.charts} charts, seam length "
             f"{m.seam_length:.4g}, mean symmetric Dirichlet {m.mean_symmetric_dirichlet:.4g}, efficiency "
             f"{m.efficiency:.3f}, {'certified' if result.success else 'not certified'}")
    save_atlas_figure(target, d.vertices, d.faces, result.x, d.uv_faces, d.chart, d.seams, title=title,
                           format=format)


def _write_map(result, tmp, ext):
    """The map of ``result`` into the temporary file ``tmp`` in the format of extension ``ext``."""
    import numpy as np

    from .. import io
    from ..mesh.elements import kind_of

    problem, x = result.problem, np.asarray(result.x, dtype=np.float64)
    if problem.kind in ("surface", "planar"):
        io.write_mesh_with_uv(tmp, _rest_3d(problem), problem.input_simplices, x, format=ext[1:])
    elif problem.kind == "sphere":
        io.write_obj(tmp, x, problem.input_simplices)
    elif problem.kind == "tet":
        io.write_cells(tmp, x, problem.input_simplices, "tetra", format=ext)
    else:
        io.write_cells(tmp, x, problem.elements, kind_of(problem.elements).word, format=ext)


def _rest_3d(problem):
    """The rest vertices as (n, 3) positions (a planar problem's with ``z = 0``)."""
    import numpy as np

    V = np.asarray(problem.rest_vertices, dtype=np.float64)
    return np.c_[V, np.zeros(len(V))] if V.shape[1] == 2 else V


def _picture(result, target, format):
    """The picture of a triangle or sphere map into the open binary file ``target``."""
    from ._figures import save_sphere_figure

    problem = result.problem
    V, F = _rest_3d(problem), problem.input_simplices
    if problem.kind == "sphere":
        save_sphere_figure(target, V, F, result.x, title=f"{len(F)} triangles onto the sphere, mean energy "
                                f"{result.mean_energy:.6g}, injective {result.injectivity}", format=format)
        return
    solver = type(result.solver).__name__ if result.solver is not None else "a solver"
    title = (f"{len(F)} triangles by {solver}, {result.stats.iterations} iterations, mean energy "
             f"{result.mean_energy:.8g}, injective {result.injectivity}")
    save_param_picture(target, result, V, F, result.x, title, format)


def save_param_picture(target, result, V, F, uv, title, format=None):
    """:func:`geomopt.plot.save_param_figure` of the UV map ``uv`` (n, 2) of the surface ``V``
    (n, 3), ``F`` (m, 3), coloured by ``result``'s energy density over its isometric value
    (log10) or, when the result's objective is not one of its own problem (untangling minimises
    on a rescaled copy), by the conformal distortion (log10)."""
    import numpy as np

    from ._figures import distortion, save_param_figure

    obj = result.objective
    if obj is None or obj.problem is not result.problem:
        values = np.log10(distortion(result.problem, result.x)["conformal"])
        label = "log10 conformal distortion"
    else:
        from ..objective.objective import element_densities

        dens = np.asarray(element_densities(obj, result.x))
        rest = obj.energy.value_at_rest(2)
        values = np.log10(np.maximum(dens / rest, 1.0)) if rest else dens
        label = "log10(density / its isometric value)" if rest else f"{obj.energy.name} density"
    save_param_figure(target, V, F, uv, values, title=title, label=label, format=format)

"""Interactive viewers: a map drawn by polyscope or pyvista (:func:`show`), or screenshot off-screen.

The picture is what :mod:`geomopt.plot` draws, by a real renderer: a parameterization as a
checkerboard through its UV map on the 3D surface; any other map (planar, on the sphere,
tetrahedra, quads, hexahedra) as the mapped mesh with each element coloured by its conformal
distortion ``sigma_max / sigma_min`` (viridis, log scale) and the inverted ones in red (exact
predicates).  Neither viewer is a dependency: ``pip install "geomopt[view]"``.

On a machine without a display, ``screenshot=PATH`` renders off-screen (polyscope's EGL
backend, VTK's EGL / OSMesa render window) and saves the picture; without it a window opens.
"""

from __future__ import annotations

import math
import os
import sys
from typing import NamedTuple

import numpy as np

from .._runtime.errors import ParameterError
from ..mesh.elements import ELEMENT_KINDS, kind_named
from ._render import CHECKER_COLORS, camera_rotation

__all__ = ["show", "scene", "camera", "inverted_rgb", "Scene", "BACKENDS", "VIEW_EXTRA"]

#: the viewers :func:`show` draws with, in the order it tries them
BACKENDS = ("polyscope", "pyvista")
VIEW_EXTRA = 'pip install "geomopt[view]"'
#: elements drawn with their edges at most (more edges would hide the colours)
EDGES_UP_TO = 20_000
BASE_RGB = (0.55, 0.70, 0.90)
#: the viewers' default vertical fields of view, degrees
FOV = {"polyscope": 45.0, "pyvista": 30.0}


class Scene(NamedTuple):
    """What :func:`show` draws, whatever the viewer.

    points : (n, 3) positions drawn;  cells : (m, k) faces (k = 3, 4) or cells (k = 4: tets when
    ``volume``, k = 8: hexahedra, VTK order);  volume : bool;  uv : (n, 2) in the unit square,
    the checkerboard's coordinates, or None;  colors : (m, 3) RGB in [0, 1] per cell or None
    (one colour);  bad : (m,) bool, the inverted cells (drawn again, opaque, over a translucent
    mesh);  planar : seen from +z (a map in the plane)."""

    points: np.ndarray
    cells: np.ndarray
    volume: bool
    uv: np.ndarray | None = None
    colors: np.ndarray | None = None
    bad: np.ndarray | None = None
    planar: bool = False

    @property
    def edges(self) -> bool:
        """Draw the cells' edges: not over a checkerboard, nor on more than :data:`EDGES_UP_TO` cells."""
        return self.uv is None and len(self.cells) <= EDGES_UP_TO


def _mesh_cells(mesh):
    """``(V, cells, volume)`` of a mesh object: ``.vertices`` / ``.faces`` (trimesh), a
    meshio.Mesh (its hexahedra, tetrahedra, quads or triangles, in that preference) or a pair."""
    if hasattr(mesh, "points") and hasattr(mesh, "cells_dict"):
        volumes = [k.word for k in ELEMENT_KINDS.values() if k.dim == 3]
        surfaces = [k.word for k in ELEMENT_KINDS.values() if k.dim == 2]
        for name, volume in [(n, True) for n in volumes + ["tetra"]] + [(n, False) for n in surfaces + ["triangle"]]:
            if name in mesh.cells_dict:
                return np.asarray(mesh.points), np.asarray(mesh.cells_dict[name]), volume
        raise ParameterError(f"show: the meshio mesh has no {', '.join(volumes + ['tetra'] + surfaces)} or triangle cells "
                             f"(it has {', '.join(mesh.cells_dict) or 'none'})")
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        V, C = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        V, C = np.asarray(mesh[0]), np.asarray(mesh[1])
    else:
        raise ParameterError(f"show draws a geomopt Result, a mesh object with .vertices and .faces, a "
                             f"meshio.Mesh or a (vertices, cells) pair; got {type(mesh).__name__}")
    arities = sorted({3, 4} | set(ELEMENT_KINDS))
    if V.ndim != 2 or V.shape[1] not in (2, 3) or C.ndim != 2 or C.shape[1] not in arities:
        raise ParameterError(f"show: vertices must be (n, 2) or (n, 3) and cells (m, k) with k one of "
                             f"{', '.join(map(str, arities))}; got {V.shape} and {C.shape}")
    if C.shape[1] == 4 and V.shape[1] == 3:  # tetrahedra, or the quads of a surface
        return V, C, _is_tets(V, C)
    return V, C, C.shape[1] != 3 and ELEMENT_KINDS[C.shape[1]].dim == 3


def _is_tets(V, C):
    """Four-vertex cells in 3D are tetrahedra unless they are flat (quads of a surface)."""
    E = V[C[:, 1:]] - V[C[:, :1]]
    vol = np.abs(np.linalg.det(E))
    size = np.linalg.norm(E, axis=2).max(axis=1) ** 3
    return bool(np.all(vol > 1e-9 * size))


def _as_3d(V):
    V = np.asarray(V, np.float64)
    return V if V.shape[1] == 3 else np.c_[V, np.zeros(len(V))]


def inverted_rgb():
    """:data:`geomopt.plot.INVERTED` as RGB in [0, 1]."""
    from matplotlib.colors import to_rgb

    from ._figures import INVERTED

    return to_rgb(INVERTED)


def _distortion_colors(problem, x):
    """(m, 3) RGB per element of ``problem`` under ``x``: viridis over ``log2`` of its conformal
    distortion (the worst corner of a quad / hexahedron), 0 to at least 1 (ratio 2); and (m,)
    bool, the inverted elements (exact predicates), red."""
    from matplotlib import colormaps

    from ..mesh.elements import valid_elements
    from ..exact.predicates import cone_orientations, simplex_orientations
    from ._figures import distortion

    x = np.asarray(x, np.float64)
    k = 1 if problem.elements is None else problem.simplices.shape[0] // problem.elements.shape[0]
    conformal = distortion(problem, x)["conformal"].reshape(-1, k).max(axis=1)
    if problem.elements is not None:
        bad = ~valid_elements(x, problem.elements)
    elif problem.kind == "sphere":
        bad = cone_orientations(x, problem.simplices) != 1
    else:
        bad = simplex_orientations(x, problem.simplices) != 1
    level = np.log2(np.where(np.isfinite(conformal), conformal, 1.0))
    top = max(1.0, float(np.percentile(level[~bad], 99))) if (~bad).any() else 1.0
    rgb = colormaps["viridis"](np.clip(level / top, 0.0, 1.0))[:, :3]
    rgb[bad] = inverted_rgb()
    return rgb, bad


def scene(obj, uv=None) -> Scene:
    """The :class:`Scene` of a :class:`~geomopt.solvers.Result` or a mesh (see :func:`show`)."""
    from ..mesh.convert import unit_square

    problem = getattr(obj, "problem", None)
    if problem is None or not hasattr(obj, "x"):
        if uv is not None and np.asarray(uv).shape[-1:] != (2,):
            raise ParameterError(f"show: uv must be (n, 2), got shape {np.asarray(uv).shape}")
        V, C, volume = _mesh_cells(obj)
        if uv is not None and (volume or len(uv) != len(V)):
            raise ParameterError(f"show: uv must have one row per vertex of a surface ({len(V)} rows), "
                                 f"got {len(uv)}" + (" for a volume mesh" if volume else ""))
        return Scene(_as_3d(V), C, volume, None if uv is None else unit_square(uv), planar=V.shape[1] == 2)
    if uv is not None:
        raise ParameterError("show: uv= is for a mesh; a Result draws its own map")
    x = np.asarray(obj.x, np.float64)
    cells = problem.input_simplices if problem.elements is None else problem.elements
    if problem.kind in ("surface", "quad_surface"):
        return Scene(_as_3d(problem.rest_vertices), cells, False, unit_square(x))
    rgb, bad = _distortion_colors(problem, x)
    if problem.kind == "sphere":
        x = x / np.linalg.norm(x, axis=1, keepdims=True)
    kind = kind_named(problem.kind)
    volume = problem.kind == "tet" or (kind is not None and kind.dim == 3)
    return Scene(_as_3d(x), cells, volume, None, rgb, bad, planar=problem.dim == 2)


def camera(points, view, up, planar, fov=45.0, aspect=1.0):
    """``(position, target, up_vector)`` of a perspective camera with a vertical field of view
    ``fov`` (degrees) and a picture ``aspect`` (width / height) seeing ``points`` (n, 3) whole
    from ``view`` = (elevation, azimuth) about the world axis ``up``, or from +z with y up for a
    map in the plane."""
    if planar:
        R = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    else:
        R = camera_rotation(view[0], view[1], up)  # rows: right, up, towards the viewer
    P = points @ R.T
    lo, hi = P.min(axis=0), P.max(axis=0)
    mid = (lo + hi) / 2
    half = max(float(hi[1] - lo[1]) / 2, float(hi[0] - lo[0]) / 2 / aspect, 1e-300)
    distance = 1.15 * half / math.tan(math.radians(fov) / 2) + (hi[2] - lo[2]) / 2
    target = mid @ R
    return target + R[2] * distance, target, R[1]


def _headless():
    """True on Linux without an X or Wayland display (an off-screen render needs screenshot=)."""
    return sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _backend(name):
    """The viewer module ``name`` (or the first of :data:`BACKENDS` that imports)."""
    import importlib

    if name is not None and name not in BACKENDS:
        raise ParameterError(f"show: backend must be one of {', '.join(map(repr, BACKENDS))} or None, got {name!r}")
    for candidate in (name,) if name else BACKENDS:
        try:
            return candidate, importlib.import_module(candidate)
        except ImportError:
            continue
    wanted = name or "polyscope or pyvista"
    raise ParameterError(f"geomopt.plot.show needs {wanted}, which is not installed: {VIEW_EXTRA} "
                         f"(or pip install {name or 'polyscope'})")


def _save(image, path):
    """Write the RGB image (h, w, 3) uint8 to ``path`` atomically (format from the extension)."""
    from pathlib import Path

    from PIL import Image

    from ..io import atomic_output

    fmt = {"jpg": "JPEG", "jpeg": "JPEG"}.get(Path(path).suffix[1:].lower(), "PNG")
    with atomic_output(path, "wb") as fh:
        Image.fromarray(image).save(fh, format=fmt)


def show(obj, uv=None, *, backend=None, screenshot=None, size=(800, 800), view=(15.0, 30.0), up="y",
         checks=20):
    """Draw a map (or a mesh) in polyscope or pyvista, or save a picture of it.

    Parameters
    ----------
    obj : a :class:`~geomopt.solvers.Result` (its problem and map ``x``), or a mesh: an object
        with ``.vertices`` and ``.faces`` (``trimesh.Trimesh``), a ``meshio.Mesh``, or a
        ``(vertices, cells)`` pair.
    uv : (n, 2) UV map of a surface mesh, drawn as a checkerboard on it (a Result draws its own).
    backend : ``"polyscope"``, ``"pyvista"`` or None (the first of them installed).
    screenshot : path (``.png``, ``.jpg``): render off-screen and save the picture there instead
        of opening a window (what a machine without a display can do).
    size : (width, height) of the window or picture in pixels.
    view : (elevation, azimuth) in degrees about the world axis ``up`` (as
        :func:`geomopt.plot.param_figure`); maps in the plane are seen from above.
    up : ``"x"``, ``"y"`` or ``"z"``.
    checks : the checkerboard has ``checks`` x ``checks`` squares over the UV map's bounding square.

    Returns
    -------
    The picture, an (height, width, 3) uint8 array, when ``screenshot`` is given; else None
    once the window is closed.

    What is drawn: a parameterization (surface problems), the checkerboard through its UV map
    on the 3D surface; any other map, the mapped mesh, each element coloured by its conformal
    distortion (viridis over ``log2(sigma_max / sigma_min)``, 0 to its 99th percentile or at
    least 1) and inverted elements red; when some are inverted a volume mesh is translucent
    and they are drawn opaque.

    Raises
    ------
    ParameterError : neither viewer installed (the message names the ``[view]`` extra), no
        display and no ``screenshot``, or an input it cannot draw.

    Examples
    --------
    >>> from geomopt import parameterize, plot
    >>> res = parameterize(V, F, progress=False)  # doctest: +SKIP
    >>> plot.show(res)  # a window  # doctest: +SKIP
    >>> picture = plot.show(res, screenshot="map.png", size=(640, 480))  # off-screen  # doctest: +SKIP
    >>> picture.shape  # doctest: +SKIP
    (480, 640, 3)
    """
    s = scene(obj, uv)
    size = _settings(size, up, checks)
    name, module = _backend(backend)
    if screenshot is None and _headless():
        raise ParameterError("show: there is no display to open a window on (DISPLAY is not set); pass "
                             "screenshot='view.png' to render off-screen and save the picture")
    cam = camera(s.points, view, up, s.planar, FOV[name], size[0] / size[1])
    draw = _polyscope if name == "polyscope" else _pyvista
    image = draw(module, s, size, cam, up, checks, screenshot is not None)
    if screenshot is not None:
        _save(image, screenshot)
    return image


def _settings(size, up, checks):
    """``size`` as a pair of ints, after checking it, ``up`` and ``checks``."""
    if not (np.shape(size) == (2,) and all(float(v).is_integer() and v > 0 for v in size)):
        raise ParameterError(f"show: size must be (width, height) in pixels, positive ints; got {size!r}")
    if up not in ("x", "y", "z"):
        raise ParameterError(f"show: up must be 'x', 'y' or 'z', got {up!r}")
    if isinstance(checks, bool) or not isinstance(checks, (int, np.integer)) or checks < 1:
        raise ParameterError(f"show: checks must be an int >= 1, got {checks!r}")
    return int(size[0]), int(size[1])


def _checker_image(checks, px=16):
    """(checks px, checks px, 3) uint8 checkerboard texture in geomopt's colours."""
    k = np.arange(checks * px) // px
    odd = (k[:, None] + k[None, :]) % 2 == 1
    rgb = np.where(odd[..., None], CHECKER_COLORS[1], CHECKER_COLORS[0])
    return (rgb * 255).round().astype(np.uint8)


def _polyscope(ps, s, size, cam, up, checks, offscreen):
    if _EGLContext.lost and ps.is_initialized():
        ps.shutdown()  # its context is gone (see _EGLContext): start again
        _EGLContext.lost = False
    if not ps.is_initialized():
        ps.set_use_prefs_file(False)  # no .polyscope.ini in the working directory
        ps.set_allow_headless_backends(True)
        ps.set_verbosity(0)
        ps.set_window_size(*size)
        ps.init()
    ps.remove_all_structures()
    ps.set_window_size(*size)
    ps.set_ground_plane_mode("none")  # a shadow doubles the cost of a software-rendered frame
    ps.set_up_dir(f"{up}_up" if not s.planar else "y_up")
    edges = 1.0 if s.edges else 0.0
    if s.volume:
        kw = _polyscope_cells(s.cells)
        m = ps.register_volume_mesh("map", s.points, edge_width=edges, **kw)
    else:
        m = ps.register_surface_mesh("map", s.points, s.cells, edge_width=edges, smooth_shade=s.uv is not None)
    where = "cells" if s.volume else "faces"
    if s.uv is not None:
        m.add_parameterization_quantity("uv checkerboard", s.uv, coords_type="unit", viz_style="checker",
                                        checker_size=1.0 / checks, checker_colors=CHECKER_COLORS, enabled=True)
    elif s.colors is not None:
        m.add_color_quantity("distortion (red: inverted)", s.colors, defined_on=where, enabled=True)
    else:
        m.set_color(BASE_RGB)
    translucent = s.volume and s.bad is not None and s.bad.any()
    ps.set_transparency_mode("pretty" if translucent else "none")
    if translucent:
        m.set_transparency(0.3)
        kw = _polyscope_cells(s.cells[s.bad])
        ps.register_volume_mesh("inverted", s.points, color=inverted_rgb(), **kw)
    ps.look_at_dir(*cam)
    if not offscreen:
        ps.show()
        return None
    return np.ascontiguousarray(ps.screenshot_to_buffer(transparent_bg=False)[..., :3])


def _polyscope_cells(cells) -> dict:
    """Volume cells (m, k) as polyscope's ``register_volume_mesh`` keyword: ``tets`` (VTK 10),
    ``hexes`` (VTK 12, same vertex order); polyscope draws no other volume cell."""
    vtk = _vtk_type(cells)
    if vtk not in (10, 12):
        raise ParameterError(f"show: polyscope draws tetrahedra and hexahedra, not {ELEMENT_KINDS[cells.shape[1]].words}; "
                             f"pass backend=\"pyvista\"")
    return {"tets" if vtk == 10 else "hexes": cells}


def _vtk_type(cells) -> int:
    """The VTK cell type of volume cells (m, k): a tetrahedron's (10) or the element kind's."""
    return 10 if cells.shape[1] == 4 else ELEMENT_KINDS[cells.shape[1]].vtk


def _pv_mesh(pv, s):
    """The scene's cells as a pyvista dataset (PolyData for faces, UnstructuredGrid for cells)."""
    if s.volume:
        return pv.UnstructuredGrid({pv.CellType(_vtk_type(s.cells)): s.cells}, s.points)
    k = s.cells.shape[1]
    return pv.PolyData(s.points, np.c_[np.full(len(s.cells), k), s.cells].ravel())


class _EGLContext:
    """Keep polyscope's off-screen (EGL) context across a VTK render: VTK makes its own context
    current to draw, and polyscope's calls assume theirs stays current, so the one current on
    entry is made current again on exit.  VTK's first EGL window re-initialises the display,
    which destroys polyscope's context: then :attr:`lost` is set, and polyscope restarts."""

    lost = False

    def __enter__(self):
        import ctypes

        try:
            self.egl = egl = ctypes.CDLL("libEGL.so.1")
        except OSError:  # no EGL: nothing to keep
            self.egl = None
            return self
        for name in ("eglGetCurrentDisplay", "eglGetCurrentSurface", "eglGetCurrentContext"):
            getattr(egl, name).restype = ctypes.c_void_p
        egl.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
        self.current = (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(0x3059),  # EGL_DRAW
                        egl.eglGetCurrentSurface(0x305A), egl.eglGetCurrentContext())  # EGL_READ
        return self

    def __exit__(self, *exc):
        if self.egl is not None and self.current[3] and not self.egl.eglMakeCurrent(*self.current):
            self.egl.eglMakeCurrent(self.current[0], None, None, None)  # none current: nothing to corrupt
            _EGLContext.lost = True


def _pyvista(pv, s, size, cam, up, checks, offscreen):
    with _EGLContext():
        return _pyvista_draw(pv, s, size, cam, up, checks, offscreen)


def _pyvista_draw(pv, s, size, cam, up, checks, offscreen):
    if offscreen and _headless():
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # no X server to try
    mesh = _pv_mesh(pv, s)
    plotter = _offscreen_plotter(pv, size) if offscreen else pv.Plotter(window_size=list(size))
    translucent = s.volume and s.bad is not None and s.bad.any()
    kw = {"render": False, "reset_camera": False}  # the camera is set below, then one render
    if s.uv is not None:
        mesh.active_texture_coordinates = s.uv
        plotter.add_mesh(mesh, texture=pv.Texture(_checker_image(checks)), smooth_shading=True, **kw)
    elif s.colors is not None:
        mesh.cell_data["distortion"] = (s.colors * 255).round().astype(np.uint8)
        plotter.add_mesh(mesh, scalars="distortion", rgb=True, show_edges=s.edges, opacity=0.3 if translucent else 1.0,
                         **kw)
    else:
        plotter.add_mesh(mesh, color=BASE_RGB, show_edges=s.edges, **kw)
    if translucent:
        plotter.add_mesh(mesh.extract_cells(np.flatnonzero(s.bad)), color=inverted_rgb(), **kw)
    plotter.camera_position = [tuple(cam[0]), tuple(cam[1]), tuple(cam[2])]
    plotter.reset_camera_clipping_range()
    if not offscreen:
        plotter.show()
        return None
    plotter.render()  # a reused plotter's screenshot is its last render
    image = plotter.screenshot(return_img=True)
    plotter.clear_actors()  # the lights stay
    return np.ascontiguousarray(image[..., :3])


_plotters = {}  # (width, height) -> the off-screen pyvista Plotter kept for later screenshots


def _offscreen_plotter(pv, size):
    """An off-screen pyvista Plotter of ``size``, made once per process and size: a new one
    costs a render context (0.5-0.7 s on a software renderer), later frames reuse it."""
    if size not in _plotters:
        _plotters[size] = pv.Plotter(off_screen=True, window_size=list(size))
    return _plotters[size]

"""The command line's grammar: the ``argparse`` parser of every command, its option
validators, and :class:`UsageError`, raised instead of argparse's own exit so that ``--json``
can still print its summary.  Importing it imports no JAX (``geomopt --help`` stays fast)."""

from __future__ import annotations

import argparse

from .._runtime import formats

from .compare import cmd_compare
from .fair import cmd_fair
from .param import cmd_demo, cmd_param
from .smooth import cmd_smooth
from .untangle import cmd_untangle

__all__ = ["build_parser", "UsageError"]


class UsageError(Exception):
    """A command line argparse refuses (raised instead of argparse's own exit)."""

    def __init__(self, parser, message):
        super().__init__(message)
        self.parser = parser


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is raised, so that ``--json`` can still print its JSON."""

    def error(self, message):
        raise UsageError(self, message)


def _margin(text) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value < 0.25:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 0.25), got {text!r}")
    return value


def _texels(text) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number of texels >= 0, got {text!r}")
    return value


def _positive_int(text) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def _vertex_id(text) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a 0-based vertex id (a whole number >= 0), got {text!r}")
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
    _add_fair(sub)
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
    sp.add_argument("input", nargs="+",
                    help="triangle mesh (OBJ/OFF/PLY/STL; convex polygons are cut into fans of triangles): a "
                         "disk, or any edge-manifold surface (an atlas, whose OBJ keeps an OBJ input's polygons, "
                         "one vt per corner); several meshes make one atlas that they share")
    sp.add_argument("-o", "--output", required=True,
                    help="output .obj (one vt per vertex, or per chart corner for an atlas) or .ply (binary, "
                         "double x y z u v); with several inputs a folder, which gets <input name>.obj for each")
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
    sp.add_argument("--margin", type=_margin, default=None,
                    help="atlas: gap between packed charts, a fraction of the unit square in [0, 0.25) (default "
                         "0.005); k charts fit only below 1 / (ceil(sqrt k) - 1), a wider margin is refused")
    sp.add_argument("--resolution", type=_positive_int, default=None, metavar="N",
                    help="atlas for an N x N texture (implies --atlas): charts at least --padding texels apart "
                         "and half of it inside the square's edges; not with --margin")
    sp.add_argument("--padding", type=_texels, default=None, metavar="P",
                    help="with --resolution: texels between any two charts, for bilinear filtering and mip "
                         "levels (default 2; below N / 5)")
    sp.add_argument("--up", default=None, choices=["x", "y", "z", "-x", "-y", "-z"],
                    help="atlas: the axis that points up (--up=-y for a negative one); seams prefer the "
                         "underside (default: none; seams always prefer occluded places and creases)")
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
                         "-o writes an .obj with the same (triangle) faces, its vertices on the sphere")
    sp.add_argument("--pole", type=_vertex_id, default=None, metavar="N",
                    help="--sphere: the vertex the start puts at the south pole, a 0-based id as in a handles "
                         "file (default: one of highest degree, then others when its start does not certify)")
    _common_options(sp)
    sp.set_defaults(func=cmd_param)


def _add_untangle(sub):
    """The ``untangle`` command's options."""
    sp = sub.add_parser("untangle", help="untangle LIM benchmark cases (fixed handles) or a tet/quad/hex mesh")
    sp.add_argument("case", nargs="+",
                    help="case folder (input.obj + handles.txt in 2D, rest.vtk + init.vtk in 3D, with "
                         "triangles, tets, quads or hexahedra), or several, or folders holding case "
                         "folders; or one tangled tet/quad/hex mesh file (" + formats.listing() + "), "
                         "untangled with its boundary fixed (or --handles) and the rest shapes of "
                         "--rest (quads/hexahedra without it: squares/cubes)")
    sp.add_argument("-o", "--output", required=True,
                    help="one case: output OBJ (2D) or VTK (3D), any tet/quad/hex mesh format for a mesh "
                         "file or quad/hex case (its cells of the kind untangled only: boundary cells, physical "
                         "groups, point and cell data are not written); otherwise an output folder, which gets "
                         "<case folder name>.obj/.vtk per certified case and summary.csv")
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
                         "hexahedra when it has fewer inverted corners, else the given map, and the harmonic extension "
                         "again when the given map stalls)")
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
    sp.add_argument("input", help=f"quad or hex mesh ({formats.listing()}), every element valid")
    sp.add_argument("-o", "--output", required=True,
                    help="output mesh (any of the input formats): the input's points moved, its quads or "
                         "hexahedra only (boundary cells, physical groups, point and cell data are not written)")
    sp.add_argument("--energy", default="winslow", metavar="NAME",
                    help=f"one of {', '.join(ENERGIES)} (default winslow: the inverse-harmonic map)")
    sp.add_argument("--solver", default="newton", metavar="NAME",
                    help=f"one of {', '.join(SOLVERS)} (default newton); its line search keeps every corner positive")
    sp.add_argument("--fix", default="boundary", choices=["boundary", "none"],
                    help="vertices held in place (default: the boundary)")
    sp.add_argument("--max-steps", type=_positive_int, default=None, help="iteration limit (>= 1)")
    _common_options(sp)
    sp.set_defaults(func=cmd_smooth)


def _add_fair(sub):
    """The ``fair`` command's options (defaults: :class:`geomopt.fairing.FairOptions`'s)."""
    from ..fairing.options import BOUNDARIES, METHODS

    sp = sub.add_parser("fair", help="smooth a triangle surface (Laplacian, Taubin, implicit fairing, least "
                                     "squares, spectral, tangential...) with no face ever folded")
    sp.add_argument("input", help="triangle mesh (OBJ/OFF/PLY/STL): closed, with boundary or several components")
    sp.add_argument("-o", "--output", required=True, help="output .obj, the same faces (polygons fan-triangulated)")
    sp.add_argument("--method", default="taubin", choices=METHODS, help="smoothing method (default taubin)")
    sp.add_argument("--laplacian", default=None, choices=["uniform", "cotangent"],
                    help="Laplacian weights (default: the method's; cotangent weights are clamped to be >= 0)")
    sp.add_argument("--steps", type=_positive_int, default=None, help="explicit / implicit / relaxation steps")
    sp.add_argument("--lam", type=float, default=None, help="step factor of laplacian and taubin (0 < lam <= 1)")
    sp.add_argument("--mu", type=float, default=None, help="taubin's second factor (mu < -lam)")
    sp.add_argument("--time", type=float, default=None, help="implicit: time in mean edge lengths squared")
    sp.add_argument("--weight", type=float, default=None,
                    help="least_squares / energy / tangential: the data term's weight (> 0)")
    sp.add_argument("--eigenvectors", type=_positive_int, default=None, help="spectral: basis size")
    sp.add_argument("--boundary", default="fixed", choices=BOUNDARIES,
                    help="boundary vertices held (default), moved freely, or smoothed as curves first")
    sp.add_argument("--crease-angle", type=float, default=None,
                    help="degrees: sharper edges are features (least_squares fits them, relax holds them)")
    sp.add_argument("--preserve-volume", action="store_true", help="closed surfaces: keep the enclosed volume")
    _common_options(sp)
    sp.set_defaults(func=cmd_fair)


def _add_compare(sub):
    """The ``compare`` command's options."""
    from .._runtime.names import COMPARED, SOLVERS

    sp = sub.add_parser("compare", help="run several solvers from the same start on one or more meshes: "
                                         "traces, table, manifest and a figure")
    sp.add_argument("mesh", nargs="+", help="disk-topology mesh (free boundary, Tutte start) or a LIM case folder "
                                            "(fixed handles, its flip-free map as the start); several: one "
                                            "sub-folder each plus a combined table and figure")
    sp.add_argument("-o", "--output", "--out", dest="output", required=True,
                    help="output folder: history.csv, summary.csv, table.tex, manifest.json, <solver>.obj "
                         "(.vtk for tets), convergence.<format>")
    sp.add_argument("--solvers", default=None,
                    help=f"comma-separated solver names (default {','.join(COMPARED)}; cm only in 2D; "
                         f"{', '.join(s for s in SOLVERS if s not in COMPARED)} on request)")
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
                    help="time each solver's first, cold run (default: a few untimed warm-up iterations per "
                         "solver first, so that lazy compilation is not solve time)")
    sp.add_argument("--format", default="png",
                    help="figure formats, comma-separated: png, pdf, svg, eps, ps (default png; PDF and "
                         "PostScript embed TrueType fonts)")
    sp.add_argument("--log-x", action="store_true", help="log scale on the seconds and iteration axes")
    sp.add_argument("--layout", default="wide", choices=["wide", "column"],
                    help="figure: three panels per mesh, 15 in wide (default), or column: the gap against "
                         "seconds alone, 3.4 in wide (one paper column)")
    sp.add_argument("--font-size", type=float, default=None,
                    help="figure font size in points (default 10 wide, 8 column; at most 16 wide, 10 column)")
    _common_options(sp)
    sp.set_defaults(func=cmd_compare)


def _add_demo(sub):
    """The ``demo`` command's options."""
    sp = sub.add_parser("demo", help="parameterize the bundled camelhead, write OBJ and PNGs")
    sp.add_argument("-o", "--output", default="out", help="output folder (default ./out)")
    _common_options(sp)
    sp.set_defaults(func=cmd_demo)

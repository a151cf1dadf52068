"""The cell-mesh formats meshio writes (``.vtu``, ``.msh``, ``.mesh``): each a writer of the
format table (:mod:`geomopt._runtime.formats`), ``write(path, P, C, kind)``, atomic, full
precision, meshio's own messages never printed.  (Reading is geomopt's own: see
:mod:`geomopt.io._volume`.)"""

from __future__ import annotations

import contextlib
import warnings
from io import StringIO
from pathlib import Path

import numpy as np

from .._runtime.errors import GeomoptError
from ._atomic import atomic_path, check_output_path
from ._cells import WORDS, checked_cells

__all__ = ["write_vtu", "write_gmsh", "write_medit"]


@contextlib.contextmanager
def _quiet():
    """Silence what meshio prints (rich console on stderr, ``print``) and warns; yields the text."""
    text = StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        warnings.simplefilter("ignore")
        yield text


def _detail(exc, printed):
    """One line saying what meshio found wrong."""
    causes = [exc, exc.__cause__ or exc.__context__]  # meshio often re-raises a bare error
    words = next((" ".join(str(e).split()) for e in causes if e is not None and not isinstance(e, SystemExit)
                  and str(e).strip()), "")
    words = words or " ".join(printed.getvalue().split())
    return words[:200] or f"meshio's writer stopped ({type(exc).__name__}, no detail)"


def _write(path, P, C, kind, described, write):
    """Check and write with ``write(tmp, meshio.Mesh)`` into a temporary file renamed to ``path``."""
    path = Path(path)
    P, C = checked_cells(P, C, kind)
    what = "tet mesh" if kind == "tetra" else f"{WORDS[kind][0]} mesh"
    check_output_path(path, what=what)
    import meshio

    with atomic_path(path, what) as tmp, _quiet() as printed:
        try:
            write(str(tmp), meshio, P, C)
        except Exception as exc:  # meshio's WriteError, OSError (disk full), ...
            raise GeomoptError(f"could not write {path} as {described} ({_detail(exc, printed)}); "
                               f"nothing was written") from exc
    return path


def write_vtu(path, P, C, kind):
    """VTK XML unstructured grid: binary base64, zlib, ``Float64``."""
    return _write(path, P, C, kind, "VTK XML unstructured grid",
                  lambda tmp, meshio, P, C: meshio.vtu.write(tmp, meshio.Mesh(P, [(kind, C)]), binary=True))


def write_gmsh(path, P, C, kind):
    """Gmsh 4.1 ASCII, every element in physical and geometrical entity 1."""
    def write(tmp, meshio, P, C):
        ones = np.ones(len(C), dtype=np.int64)
        mesh = meshio.Mesh(P, [(kind, C)], cell_data={"gmsh:physical": [ones], "gmsh:geometrical": [ones]})
        meshio.gmsh.write(tmp, mesh, fmt_version="4.1", binary=False)

    return _write(path, P, C, kind, "Gmsh ASCII 4.1", write)


def write_medit(path, P, C, kind):
    """Medit ASCII, version 2."""
    return _write(path, P, C, kind, "Medit ASCII",
                  lambda tmp, meshio, P, C: meshio.medit.write(tmp, meshio.Mesh(P, [(kind, C)])))

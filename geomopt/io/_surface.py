"""Surface meshes: one table of formats (OBJ, OFF, PLY, STL; one module each) for reading, and
one for writing a mesh with its map (OBJ, PLY)."""

from __future__ import annotations

from .._runtime.errors import GeomoptError, MeshFormatError
from .._runtime.validate import validate_simplices, validate_vertices
from ._atomic import check_output_path
from ._files import existing_file, read_input
from ._obj import parse_obj, read_obj, write_obj_with_uv
from ._off import read_off
from ._ply import read_ply, write_ply_with_uv
from ._stl import read_stl

__all__ = ["MESH_EXTENSIONS", "UV_MESH_EXTENSIONS", "read_mesh", "write_mesh_with_uv", "nonmanifold_edge_in_file"]

#: The surface readers: extension -> ``reader(bytes, path) -> (V, F)``.
_READERS = {".obj": read_obj, ".off": read_off, ".ply": read_ply, ".stl": read_stl}
#: The writers of a mesh with a per-vertex map: format -> ``writer(path, V, F, UV)``.
_UV_WRITERS = {"obj": write_obj_with_uv, "ply": write_ply_with_uv}

#: File extensions :func:`read_mesh` accepts (lower case).
MESH_EXTENSIONS = tuple(_READERS)

#: File extensions :func:`write_mesh_with_uv` writes (formats that carry one map coordinate per vertex).
UV_MESH_EXTENSIONS = tuple(f".{f}" for f in _UV_WRITERS)


def read_mesh(path):
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file, exactly as the file says it.

    Each format has its own module (``_obj``, ``_off``, ``_ply``, ``_stl``); NumPy parses the
    numbers (whole sections at once) and geomopt checks what the file declares, strictly:

    * **OBJ**: ``v x y z`` lines (an optional ``w`` or ``r g b`` after the position is
      checked as numbers and ignored), ``f`` lines with corners ``a``, ``a/t``, ``a/t/n``
      or ``a//n`` (1-based; negative indices count back from the last ``v`` line before
      the face, as the format defines).  Polygons are fan-triangulated: a face
      ``a b c d ...`` gives ``(a, b, c), (a, c, d), ...``; a polygon whose fan would fold
      (non-convex or twisted) is refused.  Attribute and grouping
      statements (``vt``, ``vn``, ``g``, ``o``, ``s``, ``usemtl``, ``mtllib``, ``l``, ``p``,
      ...) are ignored; free-form geometry and unknown statements are refused.  ``#``
      starts a comment; a line ending in ``\\`` continues on the next.
    * **OFF** (``OFF``, ``COFF``, ``NOFF``, ``STOFF`` ...): the header's vertex and face
      counts must match the body exactly (one vertex per line); a face is ``k i1 .. ik`` and
      up to 4 colour numbers to the end of its last index's line (one face per line, or, as
      Geomview's free format allows, its numbers across lines).  Polygons are fan-triangulated.
    * **PLY** (ASCII, binary little- and big-endian): the header is validated (format,
      element counts, property types); the body must hold exactly the declared elements
      (ASCII: one element per line; binary: the exact byte count).  Vertices come from
      ``x y z`` of element ``vertex`` (``float`` properties are float32, as declared),
      faces from the list ``vertex_indices`` (or ``vertex_index``) of element ``face``,
      fan-triangulated.  Other elements and properties are read past and ignored.
    * **STL** (ASCII or binary): STL stores every triangle with its own three corners, so
      corners with equal coordinates (-0.0 = 0.0) are **welded** into one vertex (numbered in
      order of first appearance); without welding no STL mesh is connected.  Binary STL
      stores float32.  A file holding several ``solid`` blocks is refused.

    The text conventions (byte-order mark, line ends, number syntax) are in the module
    notes.  Degenerate content is left to :func:`validate_vertices` and
    :func:`validate_simplices`.

    Parameters
    ----------
    path : str or os.PathLike
        Mesh file with extension ``.obj``, ``.off``, ``.ply`` or ``.stl`` (any case).

    Returns
    -------
    V : numpy.ndarray, shape (n, 3), float64
        Vertex positions, in file order (unreferenced vertices included).
    F : numpy.ndarray, shape (m, 3), int64
        Triangles, 0-based vertex indices, in file order.

    Raises
    ------
    MeshFormatError
        Missing, not a regular file, empty, unsupported extension, malformed (the message
        names the problem and, for text, the line), counts that differ from the header,
        or no triangle faces.
    MeshError
        NaN/infinite coordinates, face indices out of range, repeated vertices in a face.
    """
    path = existing_file(path, "mesh file")
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise MeshFormatError(
            f"mesh file {path} has unsupported extension {path.suffix!r}; supported: "
            f"{', '.join(MESH_EXTENSIONS)} (convert it, e.g. with meshio or MeshLab)"
        )
    path, data = read_input(path, "mesh file")
    V, F = reader(data, path)
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    return V, validate_simplices(F, V.shape[0], 3, f"{path.name}: faces")


def write_mesh_with_uv(path, V, F, UV, format=None, uv_faces=None):
    """Write a mesh and a per-vertex map in the format ``path``'s extension names (see :data:`UV_MESH_EXTENSIONS`).

    ``.obj``: :func:`~geomopt.io.write_obj_with_uv`; ``.ply``: :func:`~geomopt.io.write_ply_with_uv`.
    Both keep every ``float64`` bit.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file, ``.obj`` or ``.ply`` (any case) unless ``format`` is given.
    V : array_like, shape (n, 3)
        Vertex positions.
    F : array_like, shape (m, 3), integer
        Triangles, 0-based.
    UV : array_like, shape (n, 2)
        Map coordinates, one per vertex.
    format : {None, "obj", "ply"}
        The format, when ``path``'s extension does not say it (e.g. a temporary file from
        :func:`atomic_path`).  Case is ignored.
    uv_faces : None, or (m, 3) int the UV row of each face corner (an atlas: ``UV`` (k, 2) then
        holds one row per chart corner); OBJ only.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    GeomoptError
        Another extension or format (the message lists the supported ones), or ``path``
        cannot be written.
    MeshError
        Invalid ``V``, ``F`` or ``UV``.
    """
    if format is None:
        path = check_output_path(path, UV_MESH_EXTENSIONS)
        format = path.suffix[1:]
    if format.lower() not in _UV_WRITERS:
        raise GeomoptError(f"cannot write a mesh with a map as {format!r}; supported: {', '.join(_UV_WRITERS)}")
    if uv_faces is not None:
        if format.lower() != "obj":
            raise GeomoptError(f"an atlas (UVs per chart corner) is written as .obj, not {format!r}: "
                               f"PLY holds one UV per vertex")
        return write_obj_with_uv(path, V, F, UV, uv_faces)
    return _UV_WRITERS[format.lower()](path, V, F, UV)


def nonmanifold_edge_in_file(path, F) -> str | None:
    """Why the OBJ file ``path`` (read by :func:`read_mesh` into the triangles ``F`` (m, 3)) is
    not edge-manifold, in the file's own terms, or None (manifold, or not an OBJ file).

    Names the first edge of more than two triangles by its 1-based vertices and the lines of
    the faces around it, and says when it is no edge of the file but a diagonal that
    fan-triangulating a polygon added."""
    import numpy as np

    from ..exact.topology import unique_edges

    path = existing_file(path, "mesh file")
    E, count, _ = unique_edges(F)
    bad = np.flatnonzero(count > 2)
    if path.suffix.lower() != ".obj" or not bad.size:
        return None
    obj = parse_obj(read_input(path, "mesh file")[1], path)
    counts, lines, corners = obj["counts"], obj["lines"], obj["corners"]
    a, b = (int(i) for i in E[bad[0]])
    owner = np.repeat(np.arange(counts.size), counts - 2)  # the polygon of each fan triangle
    polygons = np.unique(owner[((F == a) | (F == b)).sum(axis=1) == 2])
    starts = np.cumsum(counts) - counts
    diagonal = [k for k in polygons.tolist() if not _is_side(corners[starts[k]:starts[k] + counts[k]], a, b)]
    named = [str(int(lines[k])) for k in polygons[:5]] + (["..."] if len(polygons) > 5 else [])
    said = ", ".join(named[:-1]) + " and " + named[-1] if len(named) > 1 else named[0]
    why = (f"; it is no edge of the file but the diagonal that fan-triangulating the {int(counts[diagonal[0]])}-gon "
           f"of line {int(lines[diagonal[0]])} adds: triangulate that polygon along its other diagonal"
           if diagonal else "")
    return (f"{path}: {bad.size} non-manifold edges (in more than two faces); first: the edge of vertices "
            f"{a + 1} and {b + 1}, in the faces of lines {said}{why}; a surface map needs an edge-manifold "
            f"mesh: split or remove the extra faces")


def _is_side(polygon, a, b) -> bool:
    """Whether ``a``-``b`` is a side of the closed polygon of corners ``polygon``."""
    nxt = list(polygon[1:]) + [polygon[0]]
    return any({int(p), int(q)} == {a, b} for p, q in zip(polygon, nxt))

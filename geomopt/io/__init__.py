"""Reading and writing meshes and maps: surface meshes, tetrahedral meshes, atomic output.

Every reader returns plain numpy arrays (coordinates ``float64``, indices ``int64``,
0-based) holding exactly what the file says: vertices in file order, never reordered
or merged (except the documented welding of STL corners), and every count, number and
index checked against the file's own header.  Unreadable or malformed files raise
:class:`~geomopt._runtime.errors.MeshFormatError` naming the problem (and the line, where there
is one); readable files with bad content (non-finite coordinates, indices out of range,
repeated vertices in an element) raise :class:`~geomopt._runtime.errors.MeshError`.

Text conventions shared by every text reader: a UTF-8 byte-order mark at the very start
of a file is skipped (the rest is read exactly); UTF-16/32 text is refused; line ends
may be LF or CRLF (a lone CR is refused); numbers must be plain decimal ASCII
(``1``, ``-2.5``, ``1e-3``, ``nan``/``inf`` are read, then non-finite coordinates are
refused as content); Python-only spellings such as ``1_0``, ``+1`` (for indices),
``0x10`` or non-ASCII digits are refused.  NumPy parses the numbers (whole sections at once,
``np.fromstring`` for text and ``np.frombuffer`` for binary); geomopt checks the rest and, only
when a section does not parse, looks for the token at fault to name it and its line.

Every writer writes atomically (see :func:`atomic_output`) with full float precision
(the shortest decimal that round-trips ``float64``, or binary ``float64``).  Output paths
must be regular files or not exist (:func:`check_output_path`).

The validators :func:`validate_vertices`, :func:`validate_simplices` and
:func:`validate_indices` (defined in :mod:`geomopt._runtime.validate`) are re-exported here.  The LIM
benchmark case layout is :mod:`geomopt.lim`.

One module per job: ``_files`` (what a path is), ``_atomic`` (atomic output, path safety and
a command's outputs: :func:`check_outputs`), ``_text`` (tokenizing: NumPy over whole sections),
``_surface`` (the table of surface formats: :func:`read_mesh`, :func:`write_mesh_with_uv`) over one
module per format (``_obj``, ``_off``, ``_ply``, ``_stl``; ``_faces`` holds what they share),
``_volume`` (the table of volume formats: :func:`read_tets`, :func:`write_tets`,
:func:`read_cells`, :func:`write_cells`) over one parser per format (``_vtk``, ``_vtu``, ``_gmsh``,
``_medit``) and the cell-type tables they share (``_cells``); this package only re-exports.
"""

from .._runtime.validate import validate_indices, validate_simplices, validate_vertices
from ._atomic import (CASE_FILES, atomic_output, atomic_path, atomic_write, check_output_path, check_outputs,
                      create_output_folder)
from ._faces import fan as fan_triangulate
from ._obj import (read_obj_polygons, read_obj_quads, read_obj_uv, read_obj_with_uv, write_obj,
                   write_obj_polygons_with_uv, write_obj_quads, write_obj_with_uv)
from ._ply import write_ply_with_uv
from ._surface import MESH_EXTENSIONS, UV_MESH_EXTENSIONS, nonmanifold_edge_in_file, read_mesh, write_mesh_with_uv
from ._text import read_vertex_ids
from ._volume import CELL_KINDS, CELL_WORDS, TET_FORMATS, read_cells, read_tets, read_vtk_tets, write_cells, write_tets
from ._vtk import write_vtk_tets

__all__ = [
    "MESH_EXTENSIONS",
    "UV_MESH_EXTENSIONS",
    "TET_FORMATS",
    "CELL_KINDS",
    "CELL_WORDS",
    "read_cells",
    "write_cells",
    "atomic_output",
    "atomic_path",
    "atomic_write",
    "check_output_path",
    "check_outputs",
    "create_output_folder",
    "CASE_FILES",
    "validate_vertices",
    "validate_simplices",
    "validate_indices",
    "read_mesh",
    "read_obj_polygons",
    "fan_triangulate",
    "read_obj_uv",
    "read_obj_quads",
    "write_obj",
    "write_obj_quads",
    "read_obj_with_uv",
    "read_vertex_ids",
    "write_mesh_with_uv",
    "write_obj_with_uv",
    "write_obj_polygons_with_uv",
    "write_ply_with_uv",
    "read_vtk_tets",
    "write_vtk_tets",
    "read_tets",
    "write_tets",
]

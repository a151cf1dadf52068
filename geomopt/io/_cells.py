"""Cell types of the volume formats, and the kinds of cell the readers return.

Every volume reader (legacy VTK, VTK XML, Gmsh, Medit) names each cell of a file by the
tables below: a name, a dimension and, where the type fixes it, a node count.  A cell type
outside its format's table is refused (never dropped).  :data:`KINDS` lists the cells that
are returned as arrays; **adding a kind is one entry there** (its name as the format tables
spell it, its node count and dimension), provided its node order is the same in every format, as it is
for linear tetrahedra, hexahedra and quadrilaterals.
"""

from __future__ import annotations

import numpy as np

from .._runtime.errors import MeshFormatError, ParameterError
from .._runtime.validate import validate_simplices, validate_vertices

__all__ = ["KINDS", "WORDS", "VTK_CELLS", "GMSH_CELLS", "MEDIT_SECTIONS", "VTK_NODES", "GMSH_NODES", "VolumeCells",
           "vtk_blocks", "select_kind", "first_kind", "code_of", "check_kinds", "nodes_of", "checked_cells"]

#: The cells the readers return: name -> (nodes per cell, dimension).
KINDS = {"tetra": (4, 3), "hexahedron": (8, 3), "quad": (4, 2)}

#: How messages name each of the :data:`KINDS`: singular, plural.
WORDS = {"tetra": ("tetrahedron", "tetrahedra"), "hexahedron": ("hexahedron", "hexahedra"), "quad": ("quad", "quads")}

#: Every VTK cell type (vtkCellType.h): code -> (name, dimension, nodes or None when the cell says).
VTK_CELLS = {
    0: ("empty cell", 0, 0), 1: ("vertex", 0, 1), 2: ("polyvertex", 0, None), 3: ("line", 1, 2),
    4: ("polyline", 1, None), 5: ("triangle", 2, 3), 6: ("triangle strip", 2, None), 7: ("polygon", 2, None),
    8: ("pixel", 2, 4), 9: ("quad", 2, 4), 10: ("tetra", 3, 4), 11: ("voxel", 3, 8), 12: ("hexahedron", 3, 8),
    13: ("wedge", 3, 6), 14: ("pyramid", 3, 5), 15: ("pentagonal prism", 3, 10), 16: ("hexagonal prism", 3, 12),
    21: ("quadratic edge", 1, 3), 22: ("quadratic triangle", 2, 6), 23: ("quadratic quad", 2, 8),
    24: ("quadratic tetra", 3, 10), 25: ("quadratic hexahedron", 3, 20), 26: ("quadratic wedge", 3, 15),
    27: ("quadratic pyramid", 3, 13), 28: ("biquadratic quad", 2, 9), 29: ("triquadratic hexahedron", 3, 27),
    30: ("quadratic linear quad", 2, 6), 31: ("quadratic linear wedge", 3, 12),
    32: ("biquadratic quadratic wedge", 3, 18), 33: ("biquadratic quadratic hexahedron", 3, 24),
    34: ("biquadratic triangle", 2, 7), 35: ("cubic line", 1, 4), 36: ("quadratic polygon", 2, None),
    37: ("triquadratic pyramid", 3, 19), 41: ("convex point set", 3, None), 42: ("polyhedron", 3, None),
    51: ("parametric curve", 1, None), 52: ("parametric surface", 2, None),
    53: ("parametric tri surface", 2, None), 54: ("parametric quad surface", 2, None),
    55: ("parametric tetra region", 3, None), 56: ("parametric hex region", 3, None),
    60: ("higher-order edge", 1, None), 61: ("higher-order triangle", 2, None), 62: ("higher-order quad", 2, None),
    63: ("higher-order polygon", 2, None), 64: ("higher-order tetrahedron", 3, None),
    65: ("higher-order wedge", 3, None), 66: ("higher-order pyramid", 3, None),
    67: ("higher-order hexahedron", 3, None), 68: ("Lagrange curve", 1, None), 69: ("Lagrange triangle", 2, None),
    70: ("Lagrange quadrilateral", 2, None), 71: ("Lagrange tetrahedron", 3, None),
    72: ("Lagrange hexahedron", 3, None), 73: ("Lagrange wedge", 3, None), 74: ("Lagrange pyramid", 3, None),
    75: ("Bezier curve", 1, None), 76: ("Bezier triangle", 2, None), 77: ("Bezier quadrilateral", 2, None),
    78: ("Bezier tetrahedron", 3, None), 79: ("Bezier hexahedron", 3, None), 80: ("Bezier wedge", 3, None),
    81: ("Bezier pyramid", 3, None),
}

#: Gmsh element types a mesh may hold: code -> (name, dimension, nodes).
GMSH_CELLS = {
    15: ("vertex", 0, 1), 1: ("line", 1, 2), 8: ("line3", 1, 3), 2: ("triangle", 2, 3), 9: ("triangle6", 2, 6),
    3: ("quad", 2, 4), 16: ("quad8", 2, 8), 10: ("quad9", 2, 9), 4: ("tetra", 3, 4), 11: ("tetra10", 3, 10),
    5: ("hexahedron", 3, 8), 17: ("hexahedron20", 3, 20), 12: ("hexahedron27", 3, 27), 6: ("wedge", 3, 6),
    18: ("wedge15", 3, 15), 13: ("wedge18", 3, 18), 7: ("pyramid", 3, 5), 19: ("pyramid13", 3, 13),
    14: ("pyramid14", 3, 14),
}

#: Medit ASCII sections: name -> (values per entry, leading 1-based vertex indices, cell name or
#: None, dimension).  Values ``None``: the space dimension + 1 (vertices); ``"dim"``: the dimension.
MEDIT_SECTIONS = {
    "Vertices": (None, 0, None, 0), "Edges": (3, 2, "line", 1), "Triangles": (4, 3, "triangle", 2),
    "Quadrilaterals": (5, 4, "quad", 2), "Tetrahedra": (5, 4, "tetra", 3), "Prisms": (7, 6, "wedge", 3),
    "Pyramids": (6, 5, "pyramid", 3), "Hexahedra": (9, 8, "hexahedron", 3), "Hexaedra": (9, 8, "hexahedron", 3),
    "Corners": (1, 1, None, 0), "RequiredVertices": (1, 1, None, 0), "Ridges": (1, 0, None, 0),
    "NormalAtVertices": (2, 0, None, 0), "TangentAtVertices": (2, 0, None, 0), "Normals": ("dim", 0, None, 0),
    "Tangents": ("dim", 0, None, 0),
}


def _nodes(table):
    nodes = np.full(max(table) + 1, -2)
    nodes[list(table)] = [-1 if k is None else k for _, _, k in table.values()]
    return nodes


#: Points per cell of each VTK / Gmsh type code (:func:`nodes_of`): -1 where the cell says, -2 for no such type.
VTK_NODES, GMSH_NODES = _nodes(VTK_CELLS), _nodes(GMSH_CELLS)


def nodes_of(nodes, codes):
    """Points per cell of each type code in ``codes`` (int array) by a table ``nodes``
    (:data:`VTK_NODES`, :data:`GMSH_NODES`): -1 where the cell says, -2 for a code not in the table."""
    known = (codes >= 0) & (codes < len(nodes))
    return np.where(known, nodes[np.where(known, codes, 0)], -2)


def checked_cells(P, C, kind):
    """Validated ``(P (n, 3) float64, C (m, k) int64)`` of a mesh of ``kind`` for a writer (2D points
    get ``z = 0``); a MeshError names ``P`` and ``T`` (tets) or the kind's plural."""
    size, dim = KINDS[kind]
    P = validate_vertices(P, "P", dim=3 if dim == 3 else None)
    P = np.column_stack([P, np.zeros(len(P))]) if P.shape[1] == 2 else P
    return P, validate_simplices(C, P.shape[0], size, "T" if kind == "tetra" else WORDS[kind][1], words=WORDS[kind])


class VolumeCells:
    """What a volume reader found: points and cells by name, in file order.

    Attributes
    ----------
    points : numpy.ndarray, shape (n, 3), float64
    cells : list of (str, int, numpy.ndarray or None)
        One entry per block of cells of one type, in file order: the type's name, its
        dimension, and for the :data:`KINDS` its ``(m, nodes)`` int64 0-based indices.
    """

    def __init__(self, points, cells):
        self.points, self.cells = points, cells


def check_kinds(kinds, what="kind"):
    """``kinds`` (a name or names) as a tuple of :data:`KINDS` names, else a one-line
    :class:`~geomopt.ParameterError` naming the valid ones (``"hex"`` is not one)."""
    kinds = tuple(kinds) if isinstance(kinds, (list, tuple)) else (kinds,)
    unknown = [k for k in kinds if not isinstance(k, str) or k not in KINDS]
    if unknown or not kinds:
        raise ParameterError(f"unknown cell {what} {unknown[0] if unknown else kinds!r}; valid: "
                             f"{', '.join(map(repr, KINDS))}")
    return kinds


def first_kind(found, kinds, path):
    """The first of ``kinds`` (:data:`KINDS` names, by priority) that ``found`` holds.

    Raises
    ------
    MeshFormatError
        No points; none of ``kinds`` (the cells found named).
    """
    if len(found.points) == 0:
        raise MeshFormatError(f"{path} has no points")
    present = {name for name, _, _ in found.cells}
    kind = next((k for k in kinds if k in present), None)
    if not present:
        raise MeshFormatError(f"{path} has no cells; a mesh of {' or '.join(WORDS[k][1] for k in kinds)} is required")
    if kind is None:
        names = sorted(present) or ["none"]
        wanted = " or ".join(WORDS[k][1] for k in kinds)
        raise MeshFormatError(f"{path} has no {wanted} (cells found: {', '.join(names)})")
    return kind


def code_of(table, kind):
    """``kind``'s code in a format's cell table (:data:`VTK_CELLS`, :data:`GMSH_CELLS`)."""
    return next(code for code, (name, _, nodes) in table.items() if name == kind and nodes == KINDS[kind][0])


def _refuse_mixed_kinds(found, kind, others, path):
    """MeshFormatError naming the counts when ``found`` holds ``kind`` beside other element kinds
    geomopt reads (:data:`KINDS`): a mixed mesh, not a mesh of the wrong kind."""
    count = {k: sum(len(c) for name, _, c in found.cells if name == k) for k in KINDS if k == kind or k in others}
    mixed = [k for k in count if count[k]]
    if len(mixed) < 2:
        return
    said = " and ".join(f"{count[k]} {WORDS[k][count[k] != 1]}" for k in mixed)
    raise MeshFormatError(f"{path} mixes {said}; geomopt maps one kind of element per mesh: write each "
                          f"kind to its own file, or split every element into one kind (e.g. hexahedra into tetrahedra)")


def select_kind(found, kind, path, alone=False):
    """The ``(m, nodes)`` cells of ``kind`` (:data:`KINDS`) in file order; lower-dimensional cells
    beside them are skipped (refused too with ``alone``), other cells of its dimension or higher
    refused (no mixed meshes).

    Raises
    ------
    MeshFormatError
        No points; other cells of ``kind``'s dimension or higher (named); no cell of ``kind``
        (the cells found named); points in 2D (Medit ``Dimension 2``) for a volume kind.
    """
    if len(found.points) == 0:
        raise MeshFormatError(f"{path} has no points")
    dim = KINDS[kind][1]
    others = sorted({name for name, d, _ in found.cells if (d >= dim or alone) and name != kind})
    _refuse_mixed_kinds(found, kind, others, path)
    if others:
        raise MeshFormatError(f"{path} contains non-tetrahedral {'' if alone else 'volume '}cells "
                              f"({', '.join(others)}); only linear "
                              f"{kind} meshes are supported" if kind == "tetra" else
                              f"{path} contains cells other than {WORDS[kind][1]} ({', '.join(others)}); only "
                              f"meshes of linear {WORDS[kind][1]} are supported (no mixed meshes)")
    if dim == 3 and found.points.shape[1] != 3:
        raise MeshFormatError(f"{path}: Dimension {found.points.shape[1]}; a volume mesh needs Dimension 3")
    first_kind(found, (kind,), path)
    blocks = [c for name, _, c in found.cells if name == kind]
    return (blocks[0] if len(blocks) == 1 else np.concatenate(blocks)).astype(np.int64, copy=False)


def vtk_blocks(types, offsets, conn, n, where):
    """The cells of VTK's ``types`` (c,), ``offsets`` (c,: where each cell's points end in ``conn``)
    and connectivity ``conn`` (indices of ``n`` points) as :class:`VolumeCells` blocks, one per type
    in order of first appearance; refuses an unknown type, offsets that do not rise or do not use
    the whole connectivity, a cell whose size is not its type's, an index outside ``0..n-1`` (unless
    ``n`` is None: then an index out of range is left to the validators, a MeshError)."""
    nodes = int(nodes_of(VTK_NODES, types[:1])[0])
    uniform = (nodes > 0 and len(conn) == nodes * len(types) and (types == types[0]).all()
               and (offsets == np.arange(nodes, len(conn) + 1, nodes)).all())  # one type of fixed size, in order
    sizes = None if uniform else _checked_sizes(types, offsets, conn, where)
    if n is not None and conn.size and (conn.min() < 0 or conn.max() >= n):
        v = int(conn[(conn < 0) | (conn >= n)][0])
        raise MeshFormatError(f"{where}: connectivity names point index {v}, outside the piece's points 0..{n - 1}")
    if uniform:
        name, dim, _ = VTK_CELLS[int(types[0])]
        return [(name, dim, conn.reshape(-1, nodes).astype(np.int64, copy=False) if name in KINDS else None)]
    cells, starts = [], offsets - sizes
    codes, first = np.unique(types, return_index=True)
    for t in codes[np.argsort(first)].tolist():  # each type once, in order of first appearance
        name, dim, nodes = VTK_CELLS[t]
        block = conn[starts[types == t][:, None] + np.arange(nodes)].astype(np.int64) if name in KINDS else None
        cells.append((name, dim, block))
    return cells


def _checked_sizes(types, offsets, conn, where):
    """The points of each cell, refusing an unknown type, offsets that do not rise or do not use the
    whole connectivity, and a cell whose size is not its type's."""
    fixed = nodes_of(VTK_NODES, types)  # points per cell of the type, -1: the cell says, -2: no type
    unknown = np.flatnonzero(fixed == -2)
    if unknown.size:
        raise MeshFormatError(f"{where}: cell {unknown[0]} has unknown VTK cell type {types[unknown[0]]}")
    sizes = np.diff(np.r_[0, offsets])
    if ((sizes <= 0) & (types != 0)).any() or (sizes < 0).any():  # type 0, an empty cell, has no points
        i = int(np.flatnonzero(((sizes <= 0) & (types != 0)) | (sizes < 0))[0])
        raise MeshFormatError(f"{where}: cell {i} has no points (offsets must rise: offset {i} is "
                              f"{offsets[i]}, the one before {offsets[i - 1] if i else 0})")
    if offsets[-1] != len(conn):
        raise MeshFormatError(f"{where}: connectivity holds {len(conn)} values but the offsets use {offsets[-1]}")
    bad = np.flatnonzero((fixed >= 0) & (sizes != fixed))
    if bad.size:
        i = int(bad[0])
        raise MeshFormatError(f"{where}: cell {i} is a {VTK_CELLS[int(types[i])][0]} with {sizes[i]} points, "
                              f"expected {fixed[i]}")
    return sizes

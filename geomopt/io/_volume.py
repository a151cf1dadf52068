"""Volume meshes: tetrahedral meshes in four formats, each read exactly as the file says or refused.

=========  ==========================================  ===========================================
extension  read                                        written
=========  ==========================================  ===========================================
``.vtk``   legacy VTK, ASCII or binary                 ASCII, ``double`` points
           (:func:`read_vtk_tets`)                     (:func:`write_vtk_tets`)          
``.vtu``   VTK XML unstructured grid (meshio)          binary base64, zlib, ``Float64`` (meshio)
``.msh``   Gmsh ASCII, versions 2.2 and 4.1            Gmsh 4.1 ASCII (meshio)
``.mesh``  Medit ASCII (``MeshVersionFormatted`` 1/2)  Medit ASCII, version 2 (meshio)
           (version 1: single-precision coordinates)
=========  ==========================================  ===========================================

Gmsh and Medit files are checked here, line by line, before meshio reads their numbers:
every section must hold exactly the number of entries its count declares, every section
must be closed (``$EndNodes``, ``End``...), every element must name defined nodes (Gmsh
node tags need not be contiguous; they are mapped to 0-based indices in file order).
Binary Gmsh/Medit files are refused (they cannot be checked this way).  meshio's own
messages are never printed: its errors become one :class:`MeshFormatError`.  Any other
extension is refused on reading and writing.

:func:`read_tets` returns ``(P (n, 3) float64, T (m, 4) int64)`` validated like every
geomopt reader; :func:`write_tets` writes atomically (:func:`~geomopt.io.atomic_path`)
with full precision, so ``read_tets`` gives back exactly what was written.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import stat
import warnings
from io import StringIO
from pathlib import Path

import numpy as np

from .._errors import GeomoptError, MeshFormatError
from .._validate import validate_simplices, validate_vertices
from ._atomic import atomic_path, atomic_write, check_output_path
from ._surface import read_obj_quads, write_obj_quads
from ._files import check_not_empty, existing_file, read_bytes
from ._text import FLOAT_RE, INT_RE, UTF8_BOM, first_bad, floats, gc_paused, ints, show, text_data, write_rows

__all__ = ["TET_FORMATS", "CELL_KINDS", "CellKind", "read_tets", "write_tets", "read_vtk_tets", "write_vtk_tets",
           "read_cells", "write_cells"]

#: The volume-mesh formats geomopt reads and writes: extension -> description.
TET_FORMATS = {
    ".vtk": "legacy VTK",
    ".vtu": "VTK XML unstructured grid",
    ".msh": "Gmsh ASCII 2.2/4.1",
    ".mesh": "Medit ASCII",
}


@dataclasses.dataclass(frozen=True)
class CellKind:
    """One kind of cell and its codes in each format (one table entry per kind)."""

    name: str  # meshio's cell type name
    word: str  # singular and plural, for messages
    words: str
    size: int  # vertices per cell
    vtk: int  # VTK cell type
    gmsh: int  # Gmsh element type
    medit: tuple  # Medit section name(s)
    dim: int  # topological dimension


#: The cell kinds geomopt reads and writes: tetrahedra (:func:`read_tets`), quads and
#: hexahedra (:func:`read_cells`).  Vertex orders are VTK's (Gmsh and Medit use the same for these).
CELL_KINDS = {c.name: c for c in (
    CellKind("tetra", "tetrahedron", "tetrahedra", 4, 10, 4, ("Tetrahedra",), 3),
    CellKind("hexahedron", "hexahedron", "hexahedra", 8, 12, 5, ("Hexahedra", "Hexaedra"), 3),
    CellKind("quad", "quad", "quads", 4, 9, 3, ("Quadrilaterals",), 2),
)}

#: Nodes per Gmsh element type, for the types a volume mesh may carry beside its tets.
_GMSH_NODES = {15: 1, 1: 2, 2: 3, 3: 4, 4: 4, 5: 8, 6: 6, 7: 5,
               8: 3, 9: 6, 10: 9, 11: 10, 12: 27, 13: 18, 14: 14, 16: 8, 17: 20, 18: 15, 19: 13}

#: Medit sections meshio reads: name -> values per entry (``None``: the dimension + 1 for
#: vertices, the dimension for vectors), and how many of them are 1-based vertex indices.
_MEDIT_SECTIONS = {
    "Vertices": (None, 0), "Edges": (3, 2), "Triangles": (4, 3), "Quadrilaterals": (5, 4),
    "Tetrahedra": (5, 4), "Prisms": (7, 6), "Pyramids": (6, 5), "Hexahedra": (9, 8), "Hexaedra": (9, 8),
    "Corners": (1, 1), "RequiredVertices": (1, 1), "Ridges": (1, 0), "NormalAtVertices": (2, 0),
    "TangentAtVertices": (2, 0), "Normals": ("dim", 0), "Tangents": ("dim", 0),
}
_VOLUME_CELLS = {"tetra10", "hexahedron", "hexahedron20", "hexahedron27", "wedge", "wedge15", "wedge18",
                 "pyramid", "pyramid13", "pyramid14"}


def _supported():
    return ", ".join(f"{ext} ({what})" for ext, what in TET_FORMATS.items())


def _extension(path: Path, doing: str) -> str:
    """``path``'s extension (lower case) if geomopt reads and writes it, else a MeshFormatError."""
    suffix = path.suffix.lower()
    if suffix not in TET_FORMATS:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise MeshFormatError(f"cannot {doing} tet mesh {path}: it has {got}; supported tet-mesh formats: "
                              f"{_supported()}")
    return suffix


@contextlib.contextmanager
def _quiet():
    """Silence what meshio prints (rich console on stderr, ``print``) and warns; yields the text."""
    text = StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        warnings.simplefilter("ignore")
        yield text


def _detail(exc, printed):
    """One line saying what meshio found wrong."""
    causes = [exc, exc.__cause__ or exc.__context__]  # meshio often re-raises a bare ReadError
    words = next((" ".join(str(e).split()) for e in causes if e is not None and not isinstance(e, SystemExit)
                  and str(e).strip()), "")
    words = words or " ".join(printed.getvalue().split())
    return words[:200] or (f"meshio's reader stopped ({type(exc).__name__}, no detail): malformed, "
                           f"truncated or unsupported content")


# ------------------------------------------------------------------------ VTK (public)


def read_vtk_tets(path):
    """Read a tetrahedral mesh from a legacy VTK unstructured-grid file, exactly as declared.

    Parsed here (ASCII or binary, file versions up to 5.1 with ``OFFSETS``/``CONNECTIVITY``):
    the counts of ``POINTS``, ``CELLS`` and ``CELL_TYPES`` must match their data and each
    other; ``METADATA`` and dataset ``FIELD`` blocks are skipped; ``POINT_DATA`` /
    ``CELL_DATA`` sections after the cells are ignored.  Points declared ``float`` are
    float32 (then widened), as VTK reads them; files written by :func:`write_vtk_tets`
    declare ``double`` and round-trip exactly.  Keywords (``POINTS``, ``cells``...) and type
    names are case-insensitive, as in VTK's own reader.  Text conventions as in the module notes.

    Parameters
    ----------
    path : str or os.PathLike
        ``.vtk`` file (legacy format).

    Returns
    -------
    P : numpy.ndarray, shape (n, 3), float64
        Point positions.
    T : numpy.ndarray, shape (m, 4), int64
        Tetrahedra, 0-based point indices (VTK cell type 10), in file order.

    Raises
    ------
    MeshFormatError
        Missing, not a regular file, empty, malformed, counts that differ from the data, no
        points, no cells, or cells other than tetrahedra (the message lists the types found).
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a tet.
    """
    return _read_vtk(path, ("tetra",))[:2]


def _read_vtk(path, kinds):
    """``(P (n, 3), C (m, k), kind name)`` of a legacy VTK file whose cells are all of one of
    ``kinds`` (:data:`CELL_KINDS` names); see :func:`read_vtk_tets`."""
    path = existing_file(path, "VTK file")
    check_not_empty(path, "VTK file")
    with gc_paused():
        P, types, sizes, conn = _parse_vtk(read_bytes(path, "VTK file"), path)
    wanted = " or ".join(CELL_KINDS[k].words for k in kinds)
    if len(P) == 0:
        raise MeshFormatError(f"VTK file {path} has no points")
    if types.size == 0:
        raise MeshFormatError(f"VTK file {path} has no cells; a mesh of {wanted} is required")
    present = [CELL_KINDS[k] for k in kinds if (types == CELL_KINDS[k].vtk).any()]
    kind = present[0] if len(present) == 1 else CELL_KINDS[kinds[0]]
    others = sorted({_VTK_CELL_NAMES.get(int(t), f"type {int(t)}") for t in np.unique(types[types != kind.vtk])})
    if others:
        codes = " or ".join(f"{CELL_KINDS[k].vtk}" for k in kinds)
        raise MeshFormatError(f"VTK file {path} contains {_others(kind, others)}; only meshes of {wanted} "
                              f"(VTK cell type {codes}) are supported")
    if (np.asarray(sizes) != kind.size).any():
        i = int(np.flatnonzero(np.asarray(sizes) != kind.size)[0])
        raise MeshFormatError(f"VTK file {path}: cell {i} is of type {kind.vtk} ({kind.words}) with {sizes[i]} points")
    P = validate_vertices(P, f"{path.name}: points", dim=3)
    C = validate_simplices(conn.reshape(-1, kind.size), P.shape[0], kind.size, f"{path.name}: {kind.words}",
                           words=(kind.word, kind.words))
    return P, C, kind.name


def write_vtk_tets(path, P, T):
    """Write a tetrahedral mesh as an ASCII legacy VTK unstructured grid, full precision.

    Points are written as ``double`` with ``%.17g`` so :func:`read_vtk_tets` reads
    them back bit for bit.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.vtk`` file.
    P : array_like, shape (n, 3)
        Point positions.
    T : array_like, shape (m, 4), integer
        Tetrahedra, 0-based.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Invalid ``P`` or ``T``.
    """
    return _write_vtk(path, P, T, CELL_KINDS["tetra"])


def _write_vtk(path, P, C, kind):
    P = validate_vertices(P, "P", dim=3)
    C = validate_simplices(C, P.shape[0], kind.size, kind.words, words=(kind.word, kind.words))
    m, k = C.shape

    def write(fh):
        fh.write("# vtk DataFile Version 2.0\nwritten by geomopt\nASCII\nDATASET UNSTRUCTURED_GRID\n")
        fh.write(f"POINTS {P.shape[0]} double\n")
        write_rows(fh, "", P)
        fh.write(f"CELLS {m} {(k + 1) * m}\n")
        np.savetxt(fh, C, fmt=f"{k}" + " %d" * k)
        fh.write(f"CELL_TYPES {m}\n")
        fh.write(f"{kind.vtk}\n" * m)

    return atomic_write(path, write)


# ------------------------------------------------------------------------ VTK

_VTK_TYPES = {b"UNSIGNED_CHAR": "u1", b"CHAR": "i1", b"UNSIGNED_SHORT": "u2", b"SHORT": "i2",
              b"UNSIGNED_INT": "u4", b"INT": "i4", b"UNSIGNED_LONG": "u8", b"LONG": "i8", b"FLOAT": "f4",
              b"DOUBLE": "f8", b"VTKTYPEINT64": "i8", b"VTKTYPEUINT64": "u8", b"VTKIDTYPE": "i8"}
_VTK_CELL_NAMES = {1: "vertex", 2: "polyvertex", 3: "line", 4: "polyline", 5: "triangle", 6: "triangle strip",
                   7: "polygon", 8: "pixel", 9: "quad", 10: "tetra", 11: "voxel", 12: "hexahedron",
                   13: "wedge", 14: "pyramid"}
_VTK_ATTRIBUTES = (b"POINT_DATA", b"CELL_DATA")


class _VtkCursor:
    """Reads a legacy VTK file section by section: keyword lines, then ASCII tokens or binary blocks."""

    def __init__(self, data, binary, path):
        self.data, self.pos, self.binary, self.path = data, 0, binary, path

    def line(self):
        """Tokens of the next non-blank line (``[]`` at the end of the file)."""
        while self.pos < len(self.data):
            end = self.data.find(b"\n", self.pos)
            end = len(self.data) if end < 0 else end
            tokens = self.data[self.pos:end].split()
            self.pos = end + 1
            if tokens:
                return tokens
        return []

    def peek(self):
        pos, tokens = self.pos, self.line()
        self.pos = pos
        return tokens

    def values(self, count, code, section):
        """``count`` values of numpy type ``code`` (ASCII tokens or big-endian binary)."""
        if self.binary:
            size = count * np.dtype(code).itemsize
            if self.pos + size > len(self.data):
                raise MeshFormatError(f"{self.path}: the file ends inside the {section} section (it declares "
                                      f"{count} values, {size} bytes); the file is truncated or a count is wrong")
            out = np.frombuffer(self.data, ">" + code, count, self.pos).astype(code)
            self.pos += size
            return out
        parts = self.data[self.pos:].split(None, count)
        tokens = parts[:count]
        if len(tokens) < count:
            raise MeshFormatError(f"{self.path}: the {section} section declares {count} values but the file "
                                  f"ends after {len(tokens)}; the file is truncated or a count is wrong")
        self.pos = len(self.data) - (len(parts[count]) if len(parts) > count else 0)
        regex = FLOAT_RE if code[0] == "f" else INT_RE
        bad = first_bad(tokens, regex)
        if bad is not None and re.fullmatch(rb"[A-Za-z_]{2,}", tokens[bad]):  # the next section's keyword
            raise MeshFormatError(f"{self.path}: the {section} section declares {count} values but "
                                  f"{show(tokens[bad])} follows after {bad}; fix the count")
        where = lambda i: f"{self.path}, {section} section, value {i + 1}"  # noqa: E731
        if code[0] == "f":
            values = floats(tokens, where)
            with np.errstate(over="ignore"):
                return values.astype(code)
        values = ints(tokens, where)
        info = np.iinfo(code)
        if values.size and (values.min() < info.min or values.max() > info.max):
            raise MeshFormatError(f"{self.path}: a value of the {section} section does not fit its type "
                                  f"{np.dtype(code).name}")
        return values

    def expect_keyword(self, after):
        """The next line must start a section (not more values of the previous one)."""
        tokens = self.peek()
        if tokens and (FLOAT_RE.fullmatch(tokens[0]) or INT_RE.fullmatch(tokens[0])):
            raise MeshFormatError(f"{self.path}: more values follow the {after} section than it declares; "
                                  f"fix the count")


def _vtk_keyword(tokens):
    """A line's first token in upper case (``None`` for no tokens): VTK's own reader compares
    keywords case-insensitively (vtkDataReader lower-cases each keyword before comparing)."""
    return tokens[0].upper() if tokens else None


def _vtk_type(token, cursor, section):
    code = _VTK_TYPES.get(token.upper())
    if code is None:
        raise MeshFormatError(f"{cursor.path}: the {section} section has unsupported data type {show(token)}")
    return code


def _vtk_count(tokens, i, cursor, section):
    if len(tokens) <= i or not tokens[i].isdigit():
        raise MeshFormatError(f"{cursor.path}: malformed {section} line {show(b' '.join(tokens))}; expected "
                              f"a count")
    return int(tokens[i])


def _vtk_skip_optional(cursor):
    """Skip METADATA blocks (to the next blank line) and dataset FIELD data."""
    while True:
        tokens = cursor.peek()
        if _vtk_keyword(tokens) == b"METADATA":
            cursor.line()
            while cursor.pos < len(cursor.data):
                end = cursor.data.find(b"\n", cursor.pos)
                end = len(cursor.data) if end < 0 else end
                blank = not cursor.data[cursor.pos:end].strip()
                cursor.pos = end + 1
                if blank:
                    break
        elif _vtk_keyword(tokens) == b"FIELD":
            cursor.line()
            for _ in range(_vtk_count(tokens, 2, cursor, "FIELD")):
                array = cursor.line()
                if len(array) != 4 or not (array[1].isdigit() and array[2].isdigit()):
                    raise MeshFormatError(f"{cursor.path}: malformed FIELD array line "
                                          f"{show(b' '.join(array))}")
                code = _vtk_type(array[3], cursor, "FIELD")
                cursor.values(int(array[1]) * int(array[2]), code, "FIELD")
        else:
            return


def _parse_vtk(data, path):
    """``(points (n, 3) float64, cell types (c,), cells list-of-arrays or (c, 4) int64)`` of a legacy VTK file."""
    data = data.removeprefix(UTF8_BOM)
    head = data.split(b"\n", 3)
    if len(head) < 4 or not head[0].strip().lower().startswith(b"# vtk datafile version"):
        raise MeshFormatError(f"{path} does not start with '# vtk DataFile Version ...'; it is not a legacy "
                              f"VTK file")
    mode = head[2].strip().upper()
    if mode not in (b"ASCII", b"BINARY"):
        raise MeshFormatError(f"{path}, line 3: expected ASCII or BINARY, found {show(head[2].strip())}")
    binary = mode == b"BINARY"
    body = head[3]
    if not binary:
        body = text_data(body, path, "VTK file")
    cursor = _VtkCursor(body, binary, path)
    tokens = cursor.line()
    if [t.upper() for t in tokens] != [b"DATASET", b"UNSTRUCTURED_GRID"]:
        found = show(b" ".join(tokens)) if tokens else "nothing"
        raise MeshFormatError(f"{path}: expected 'DATASET UNSTRUCTURED_GRID', found {found}; only unstructured "
                              f"grids (tetrahedral meshes) are supported")
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != b"POINTS" or len(tokens) != 3:
        raise MeshFormatError(f"{path}: expected 'POINTS n type', found "
                              f"{show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    n = _vtk_count(tokens, 1, cursor, "POINTS")
    points = cursor.values(3 * n, _vtk_type(tokens[2], cursor, "POINTS"), "POINTS").astype(np.float64)
    cursor.expect_keyword("POINTS")
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != b"CELLS" or len(tokens) != 3:
        raise MeshFormatError(f"{path}: expected 'CELLS' after the points, found "
                              f"{show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    a, b = _vtk_count(tokens, 1, cursor, "CELLS"), _vtk_count(tokens, 2, cursor, "CELLS")
    if _vtk_keyword(cursor.peek()) == b"OFFSETS":  # version 5: offsets + connectivity
        t = cursor.line()
        offsets = cursor.values(a, _vtk_type(t[1] if len(t) > 1 else b"?", cursor, "OFFSETS"), "OFFSETS")
        cursor.expect_keyword("OFFSETS")
        t = cursor.line()
        if _vtk_keyword(t) != b"CONNECTIVITY" or len(t) != 2:
            raise MeshFormatError(f"{path}: expected 'CONNECTIVITY type' after OFFSETS")
        conn = cursor.values(b, _vtk_type(t[1], cursor, "CONNECTIVITY"), "CONNECTIVITY").astype(np.int64)
        offsets = offsets.astype(np.int64)
        if a == 0 or offsets[0] != 0 or offsets[-1] != b or (np.diff(offsets) < 0).any():
            raise MeshFormatError(f"{path}: the OFFSETS must rise from 0 to the connectivity size {b}")
        sizes = np.diff(offsets)
    else:
        flat = cursor.values(b, "i4", "CELLS").astype(np.int64)
        sizes, conn, pos = [], [], 0
        if a and b == 5 * a and (flat[0::5] == 4).all():
            sizes, conn = np.full(a, 4), flat.reshape(a, 5)[:, 1:].ravel()
        else:
            for _ in range(a):
                if pos >= b or flat[pos] < 0 or pos + 1 + flat[pos] > b:
                    raise MeshFormatError(f"{path}: the CELLS section declares {a} cells in {b} values, but "
                                          f"its cell sizes do not add up to that")
                sizes.append(int(flat[pos]))
                conn.append(flat[pos + 1:pos + 1 + flat[pos]])
                pos += 1 + flat[pos]
            if pos != b:
                raise MeshFormatError(f"{path}: the CELLS section declares {a} cells in {b} values, but the "
                                      f"cells use {pos}; fix the counts")
            sizes = np.array(sizes, dtype=np.int64)
            conn = np.concatenate(conn) if conn else np.zeros(0, dtype=np.int64)
        a += 1  # as many offsets as cells + 1, like version 5
    cells = a - 1
    cursor.expect_keyword("CELLS")
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != b"CELL_TYPES":
        raise MeshFormatError(f"{path}: expected 'CELL_TYPES' after the cells, found "
                              f"{show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    m = _vtk_count(tokens, 1, cursor, "CELL_TYPES")
    if m != cells:
        raise MeshFormatError(f"{path}: CELLS declares {cells} cells but CELL_TYPES declares {m}; fix the counts")
    types = cursor.values(m, "i4", "CELL_TYPES")
    cursor.expect_keyword("CELL_TYPES")
    _vtk_skip_optional(cursor)
    tokens = cursor.peek()
    if tokens and tokens[0].upper() not in _VTK_ATTRIBUTES:
        raise MeshFormatError(f"{path}: unexpected {show(b' '.join(tokens))} after the cell types; only "
                              f"POINT_DATA / CELL_DATA / FIELD sections may follow")
    return points.reshape(-1, 3), types, sizes, conn


# ------------------------------------------------------------------------ checks


class _Rows:
    """The non-blank lines of an ASCII mesh file, split into tokens in a few passes (no list per line).

    Row ``r`` (a non-blank line) is file line ``lineno[r]`` and holds the tokens
    ``tokens[start[r]:start[r] + count[r]]`` (bytes); ``first[r]`` is its first token.
    """

    def __init__(self, data, path, what):
        if b"\x00" in data:
            raise MeshFormatError(f"{what} file {path} contains NUL bytes: it is a binary file; only ASCII "
                                  f"{what} files are supported (re-export it as ASCII)")
        if not data.isascii():
            at = next(i for i, b in enumerate(data) if b > 127)
            line = data.count(b"\n", 0, at) + 1
            raise MeshFormatError(f"{path}, line {line}: a non-ASCII byte; {what} files are ASCII text")
        raw = np.frombuffer(data, np.uint8)
        space = np.isin(raw, np.frombuffer(b" \t\n\r\x0b\x0c", np.uint8))  # what bytes.split() splits on
        begins = ~space
        begins[1:] &= space[:-1]
        line = np.cumsum(raw == 10) - (raw == 10)
        per_line = np.bincount(line[begins], minlength=int(line[-1]) + 1)
        self.path = path
        self.lineno = np.flatnonzero(per_line) + 1
        self.count = per_line[per_line > 0]
        self.start = np.concatenate([[0], np.cumsum(self.count)[:-1]]).astype(np.int64)
        self.tokens = data.split()
        self.first = [self.tokens[s] for s in self.start.tolist()]

    def __len__(self):
        return len(self.count)

    def at(self, r):
        """Line ``r``'s tokens as text, for messages."""
        return b" ".join(self.tokens[self.start[r]:self.start[r] + self.count[r]]).decode()[:60]

    def width(self, a, b, width, what):
        """Rows ``a:b`` must hold ``width`` tokens each."""
        bad = np.flatnonzero(self.count[a:b] != width)
        if bad.size:
            r = a + int(bad[0])
            raise MeshFormatError(f"{self.path}, line {self.lineno[r]}: the {what} entry has {self.count[r]} "
                                  f"values, expected {width}")

    def ints(self, a, b, what, column=None):
        """Integers of rows ``a:b`` (all their tokens, or token ``column`` of each), int64."""
        if b <= a:
            return np.zeros(0, dtype=np.int64)
        if column is None:
            toks = self.tokens[self.start[a]:self.start[b - 1] + self.count[b - 1]]
        else:
            toks = [self.tokens[s + column] for s in self.start[a:b].tolist()]
        if b"".join(toks).replace(b"-", b"").isdigit():
            with contextlib.suppress(ValueError, OverflowError):
                return np.array(toks, dtype=np.int64)
        for r in range(a, b):  # find the culprit for the message
            row = self.tokens[self.start[r]:self.start[r] + self.count[r]]
            for t in (row if column is None else row[column:column + 1]):
                if not (t.replace(b"-", b"", t.startswith(b"-")).isdigit() and abs(int(t)) < 2**63):
                    raise MeshFormatError(f"{self.path}, line {self.lineno[r]}: expected an integer ({what}), "
                                          f"found {t.decode()[:40]!r}")
        raise AssertionError("unreachable")

    def numbers(self, a, b, what):
        """Rows ``a:b`` must hold plain decimal numbers (meshio then reads their values)."""
        if b <= a:
            return
        toks = self.tokens[self.start[a]:self.start[b - 1] + self.count[b - 1]]
        if not b"".join(toks).translate(None, b"0123456789+-.eE"):
            return  # only number characters: meshio reads them or refuses them
        for r in range(a, b):
            for t in self.tokens[self.start[r]:self.start[r] + self.count[r]]:
                if not FLOAT_RE.fullmatch(t):
                    raise MeshFormatError(f"{self.path}, line {self.lineno[r]}: expected a number ({what}), "
                                          f"found {t.decode()[:40]!r}")


def _counted(rows, a, held, count, section):
    """Section ``section`` opened on row ``a`` declares ``count`` entries and holds ``held``."""
    if held != count:
        fix = "fix the count" if held > count else "the file is truncated or the count is wrong"
        raise MeshFormatError(f"{rows.path}: section {section} (line {rows.lineno[a]}) declares {count} entries "
                              f"but holds {held}; {fix}")


def _gmsh_sections(rows):
    """``{name: [(a, b)]}``: the body rows ``a:b`` of each ``$name`` ... ``$Endname`` section."""
    marks = [r for r, t in enumerate(rows.first) if t[:1] == b"$"] + [len(rows)]
    sections, expect = {}, 0
    for k in range(0, len(marks) - 1, 2):
        r, end = marks[k], marks[k + 1]
        if r != expect or rows.first[r].startswith(b"$End"):
            bad = expect if r != expect else r
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[bad]}: {rows.at(bad)!r} outside a section; "
                                  f"expected a section start such as $Nodes")
        name = rows.first[r][1:].decode()
        if end == len(rows) or rows.first[end] != f"$End{name}".encode():
            found = f"{rows.first[end].decode()!r} on line {rows.lineno[end]}" if end < len(rows) else \
                "the end of the file"
            raise MeshFormatError(f"{rows.path}: section ${name} (line {rows.lineno[r]}) is not closed by "
                                  f"$End{name} (found {found}); the file is truncated or malformed")
        sections.setdefault(name, []).append((r + 1, end))
        expect = end + 1
    if expect != len(rows):
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[expect]}: {rows.at(expect)!r} outside a section; "
                              f"expected a section start such as $Nodes")
    return sections


def _gmsh_nodes_per_element(types, rows, a):
    """Nodes of each Gmsh element type in ``types`` (refuses unknown types)."""
    table = np.full(max(_GMSH_NODES) + 1, -1)
    table[list(_GMSH_NODES)] = list(_GMSH_NODES.values())
    known = (types >= 0) & (types < len(table))
    nodes = np.where(known, table[np.where(known, types, 0)], -1)
    if (nodes < 0).any():
        i = int(np.flatnonzero(nodes < 0)[0])
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[a + i]}: unsupported Gmsh element type "
                              f"{types[i]}; a mesh of tetrahedra (type 4), hexahedra (5) or quads (3) is expected")
    return nodes


def _check_gmsh(data, path):
    """Check a Gmsh ASCII 2.2 or 4.1 file's structure; return ``(node count, {element type: count})``."""
    head = data[:200].split(b"\n")
    if head[0].strip() != b"$MeshFormat" or len(head) < 2:
        raise MeshFormatError(f"{path} does not start with $MeshFormat; it is not a Gmsh file")
    fmt = head[1].split()
    if len(fmt) != 3 or fmt[0] not in (b"2.2", b"4.1"):
        raise MeshFormatError(f"{path}, line 2: Gmsh format version {fmt[0].decode(errors='replace')!r} is "
                              f"not supported; use MSH 2.2 or 4.1 (ASCII)" if fmt else
                              f"{path}, line 2: missing Gmsh format version")
    if fmt[1] != b"0":
        raise MeshFormatError(f"{path} is a binary Gmsh file; only ASCII .msh files are read exactly "
                              f"(re-save it from Gmsh as ASCII, e.g. `gmsh in.msh -save -format msh41 -bin 0`)")
    rows = _Rows(data, path, "Gmsh")
    sections = _gmsh_sections(rows)
    for name in ("Nodes", "Elements"):
        if len(sections.get(name, ())) != 1:
            raise MeshFormatError(f"{path} has {len(sections.get(name, ()))} ${name} sections; exactly one "
                                  f"is required")
        a, b = sections[name][0]
        if a == b:
            raise MeshFormatError(f"{path}: section ${name} (line {rows.lineno[a - 1]}) is empty")
    read = _gmsh22 if fmt[0] == b"2.2" else _gmsh41
    tags, nodes, counts = read(rows, sections["Nodes"][0], sections["Elements"][0])
    if len(np.unique(tags)) != len(tags):
        raise MeshFormatError(f"{path}: a node tag is defined twice in $Nodes; tags must be unique")
    undefined = ~np.isin(nodes, tags)
    if undefined.any():
        raise MeshFormatError(f"{path}: an element refers to node tag {int(nodes[undefined][0])}, which "
                              f"$Nodes does not define")
    return len(tags), counts


def _gmsh22(rows, nodes, elems):
    """Node tags, every element's node tags (flat) and ``{element type: count}`` of MSH 2.2 sections."""
    (a, b), (c, d) = nodes, elems
    rows.width(a, a + 1, 1, "$Nodes count")
    _counted(rows, a - 1, b - a - 1, int(rows.ints(a, a + 1, "node count")[0]), "$Nodes")
    rows.width(a + 1, b, 4, "$Nodes")
    rows.numbers(a + 1, b, "$Nodes")
    tags = rows.ints(a + 1, b, "node tag", column=0)
    rows.width(c, c + 1, 1, "$Elements count")
    _counted(rows, c - 1, d - c - 1, int(rows.ints(c, c + 1, "element count")[0]), "$Elements")
    short = np.flatnonzero(rows.count[c + 1:d] < 3)
    if short.size:
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[c + 1 + short[0]]}: an element needs at least 3 "
                              f"values (tag, type, number of tags)")
    values = rows.ints(c + 1, d, "element")
    at = rows.start[c + 1:d] - rows.start[c + 1]
    types, ntags = values[at + 1], values[at + 2]
    width = 3 + ntags + _gmsh_nodes_per_element(types, rows, c + 1)
    bad = np.flatnonzero(rows.count[c + 1:d] != width)
    if bad.size:
        i = int(bad[0])
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[c + 1 + i]}: an element of type {types[i]} with "
                              f"{ntags[i]} tags needs {width[i]} values, found {rows.count[c + 1 + i]}")
    first_node = np.repeat(at + 3 + ntags, rows.count[c + 1:d])  # per value: where its row's nodes begin
    nodes = values[np.arange(len(values)) >= first_node]
    kinds, counts = np.unique(types, return_counts=True)
    return tags, nodes, dict(zip(kinds.tolist(), counts.tolist()))


def _gmsh41(rows, nodes, elems):
    """Node tags, every element's node tags (flat) and ``{element type: count}`` of MSH 4.1 sections."""
    (a, b), (c, d) = nodes, elems

    def header(r, what):
        rows.width(r, r + 1, 4, what)
        return rows.ints(r, r + 1, what).tolist()

    def blocks(first, stop, nblocks, what, size):
        r = first + 1
        for _ in range(nblocks):
            if r >= stop:
                raise MeshFormatError(f"{rows.path}: {what} (line {rows.lineno[first - 1]}) declares {nblocks} "
                                      f"blocks but holds fewer")
            block = header(r, f"{what} block header")
            n = block[3]
            if r + 1 + size(n) > stop:
                raise MeshFormatError(f"{rows.path}: a {what} block (line {rows.lineno[r]}) declares {n} "
                                      f"entries but the section ends first")
            yield r + 1, block
            r += 1 + size(n)
        if r != stop:
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[r]}: {what} (line {rows.lineno[first - 1]}) "
                                  f"holds more blocks than the {nblocks} it declares; fix the counts")

    nblocks, total, lo, hi = header(a, "$Nodes header")
    tags = []
    for r, (dim, _, parametric, n) in blocks(a, b, nblocks, "$Nodes", lambda n: 2 * n):
        rows.width(r, r + n, 1, "$Nodes tag")
        rows.width(r + n, r + 2 * n, 3 + (dim if parametric else 0), "$Nodes coordinate")
        rows.numbers(r + n, r + 2 * n, "$Nodes coordinate")
        tags.append(rows.ints(r, r + n, "node tag"))
    tags = np.concatenate(tags) if tags else np.zeros(0, dtype=np.int64)
    if len(tags) != total:
        raise MeshFormatError(f"{rows.path}: section $Nodes (line {rows.lineno[a - 1]}) declares {total} nodes "
                              f"but its blocks hold {len(tags)}; fix the counts")
    if tags.size and (tags.min(), tags.max()) != (lo, hi):
        raise MeshFormatError(f"{rows.path}: section $Nodes (line {rows.lineno[a - 1]}) holds node tags "
                              f"{tags.min()}..{tags.max()} but its header says {lo}..{hi}; fix the header")
    nblocks, total, _, _ = header(c, "$Elements header")
    count, nodes, counts = 0, [], {}
    for r, (_, _, gtype, n) in blocks(c, d, nblocks, "$Elements", lambda n: n):
        if n:
            width = 1 + int(_gmsh_nodes_per_element(np.array([gtype]), rows, r - 1)[0])
            rows.width(r, r + n, width, f"type-{gtype} element")
            nodes.append(rows.ints(r, r + n, "element").reshape(n, width)[:, 1:])
            counts[gtype] = counts.get(gtype, 0) + n
        count += n
    if count != total:
        raise MeshFormatError(f"{rows.path}: section $Elements (line {rows.lineno[c - 1]}) declares {total} "
                              f"elements but its blocks hold {count}; fix the counts")
    nodes = np.concatenate([x.ravel() for x in nodes]) if nodes else np.zeros(0, dtype=np.int64)
    return tags, nodes, counts


def _check_medit(data, path, dims=(3,)):
    """Check a Medit ASCII file's structure (``Dimension`` one of ``dims``); return ``(vertex
    count, {section: count}, dimension)``."""
    rows = _Rows(re.sub(rb"(?m)^[ \t]*#[^\n]*", b"", data), path, "Medit")  # comment lines, kept as blank
    keyword = np.array([t[:1].isalpha() and t.lower() not in (b"nan", b"inf", b"infinity") for t in rows.first],
                       dtype=bool)
    if not len(rows) or rows.first[0] != b"MeshVersionFormatted":
        raise MeshFormatError(f"{path} does not start with MeshVersionFormatted; it is not an ASCII Medit file")
    r, version, dim, counts, last = 0, None, None, {}, None
    while r < len(rows):
        key, line = rows.first[r].decode(), rows.lineno[r]
        if not keyword[r]:
            raise MeshFormatError(f"{path}, line {line}: section {last[0]} (line {last[1]}) declares {last[2]} "
                                  f"entries but more follow; fix the count")
        if key in ("MeshVersionFormatted", "Dimension"):
            on_next = rows.count[r] == 1 and r + 1 < len(rows) and rows.count[r + 1] == 1 and not keyword[r + 1]
            if rows.count[r] != 2 and not on_next:
                raise MeshFormatError(f"{path}, line {line}: {key} needs one integer")
            value = int(rows.ints(r + on_next, r + on_next + 1, key, column=0 if on_next else 1)[0])
            if key == "MeshVersionFormatted" and value not in (1, 2):
                raise MeshFormatError(f"{path}, line {line}: MeshVersionFormatted {value} is not supported (1 or 2)")
            if key == "Dimension" and value not in dims:
                raise MeshFormatError(f"{path}, line {line}: Dimension {value}; a "
                                      f"{'tetrahedral mesh' if dims == (3,) else 'mesh'} needs Dimension "
                                      f"{' or '.join(map(str, dims))}")
            version, dim = (value, dim) if key == "MeshVersionFormatted" else (version, value)
            r += 1 + on_next
            continue
        if key == "End":
            if r != len(rows) - 1:
                raise MeshFormatError(f"{path}, line {rows.lineno[r + 1]}: text after End")
            break
        if key not in _MEDIT_SECTIONS:
            raise MeshFormatError(f"{path}, line {line}: unsupported Medit section {key!r}; supported: "
                                  f"{', '.join(_MEDIT_SECTIONS)}, End")
        if rows.count[r] != 1 or r + 1 >= len(rows) or rows.count[r + 1] != 1:
            raise MeshFormatError(f"{path}, line {line}: expected {key} alone on its line and its count alone "
                                  f"on the next")
        if dim is None or version is None:
            raise MeshFormatError(f"{path}, line {line}: {key} before MeshVersionFormatted and Dimension")
        n = int(rows.ints(r + 1, r + 2, f"{key} count")[0])
        width, indices = _MEDIT_SECTIONS[key]
        width = dim + 1 if width is None else dim if width == "dim" else width
        a, b = r + 2, min(r + 2 + n, len(rows))
        inside = np.flatnonzero(keyword[a:b])
        _counted(rows, r, int(inside[0]) if inside.size else b - a, n, key)
        rows.width(a, b, width, key)
        rows.numbers(a, b, key)
        counts[key], last = n, (key, line, n)
        if indices and n:
            if "Vertices" not in counts:
                raise MeshFormatError(f"{path}, line {line}: {key} before Vertices")
            ref = rows.ints(a, b, f"{key} entry").reshape(n, width)[:, :indices]
            nv = counts["Vertices"]
            bad = (ref < 1) | (ref > nv)
            if bad.any():
                i = int(np.flatnonzero(bad.any(axis=1))[0])
                raise MeshFormatError(f"{path}, line {rows.lineno[a + i]}: {key} entry {i + 1} refers to vertex "
                                      f"{int(ref[i][bad[i]][0])}; Medit vertices are numbered 1..{nv}")
        r = b
    else:
        raise MeshFormatError(f"{path} has no End keyword; the file is truncated")
    if "Vertices" not in counts:
        raise MeshFormatError(f"{path} has no Vertices section")
    return counts["Vertices"], counts, dim


# ---------------------------------------------------------------------- reading


def _existing(path):
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise MeshFormatError(f"tet mesh {path} does not exist or cannot be accessed ({exc.strerror}); "
                              f"check the path") from None
    if not stat.S_ISREG(mode):
        raise MeshFormatError(f"tet mesh {path} is not a regular file; pass a mesh file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshFormatError(f"cannot read tet mesh {path} ({exc.strerror}); check its permissions") from None
    if not data:
        raise MeshFormatError(f"tet mesh {path} is empty (0 bytes)")
    return data


def read_tets(path):
    """Read a tetrahedral mesh exactly as the file declares it, or refuse it.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.vtk`` (legacy VTK), ``.vtu`` (VTK XML), ``.msh`` (Gmsh ASCII 2.2/4.1) or
        ``.mesh`` (Medit ASCII) file; see the module notes.

    Returns
    -------
    P : numpy.ndarray, shape (n, 3), float64
        Point positions, in file order.
    T : numpy.ndarray, shape (m, 4), int64
        Tetrahedra as 0-based indices into ``P``, in file order.

    Raises
    ------
    MeshFormatError
        Unsupported extension; missing, empty, binary (Gmsh/Medit) or malformed file; a
        count that differs from its data; a section not closed; an element naming an
        undefined node; no points or no tetrahedra; other volume cells (hexahedra,
        prisms, quadratic tets...).  Boundary faces, edges and points beside the tets are
        ignored.
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a tet.
    """
    return _read_cells(Path(path), ("tetra",))


def read_cells(path, kinds=("hexahedron", "quad"), format=None):
    """Read a mesh of one kind of cell -- hexahedra or quads by default -- exactly, or refuse it.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.vtk``, ``.vtu``, ``.msh`` (ASCII 2.2/4.1) or ``.mesh`` (ASCII) file, read and
        checked as :func:`read_tets` reads tetrahedral ones, or an ``.obj`` file of quads
        (:func:`~geomopt.io.read_obj_quads`).
    kinds : tuple of :data:`CELL_KINDS` names, by priority.  The first kind the file holds is
        read; in Gmsh, Medit and VTU files cells of lower dimension beside it (boundary quads,
        lines, points) are ignored, any other cell of its dimension or higher is refused
        (mixed meshes are not supported).  Legacy VTK files must hold that kind only.
    format : an extension (``".vtk"``...) to read the file as, instead of its own.

    Returns
    -------
    P : (n, 3) float64 points (quads in the plane: ``z == 0`` as stored; a Medit
        ``Dimension 2`` file gives (n, 2)).
    C : (m, k) int64 cells, 0-based, in file order, vertex order as in VTK.
    kind : str, the kind read.

    Raises
    ------
    MeshFormatError
        As :func:`read_tets`; also a file with none of ``kinds`` or with mixed cells.
    MeshError
        Non-finite coordinates, indices out of range, repeated vertices in a cell.
    """
    return _read_cells(Path(path), tuple(kinds), with_kind=True, format=format)


def _read_cells(path, kinds, with_kind=False, format=None):
    ext = (format or path.suffix).lower()
    if ext == ".obj" and "quad" in kinds:
        return read_obj_quads(path) + (("quad",) if with_kind else ())
    ext = _extension(path.with_suffix(ext), "read")
    if ext == ".vtk":
        P, C, kind = _read_vtk(path, kinds)
        return (P, C, kind) if with_kind else (P, C)
    data = _existing(path)
    dims = tuple(sorted({CELL_KINDS[k].dim for k in kinds} | {3}))
    declared = (_check_gmsh(data, path) if ext == ".msh" else _check_medit(data, path, dims) if ext == ".mesh"
                else None)
    import meshio

    reader = {".msh": meshio.gmsh.read, ".mesh": meshio.medit.read, ".vtu": meshio.vtu.read}[ext]
    with _quiet() as printed:
        try:
            mesh = reader(str(path))
        except (Exception, SystemExit) as exc:
            raise MeshFormatError(f"could not read {path} as {TET_FORMATS[ext]}: {_detail(exc, printed)}; check "
                                  f"that the file is complete and of the format its extension says") from None
    if len(mesh.points) == 0:
        raise MeshFormatError(f"{path} has no points")
    kind = _cell_kind(mesh, kinds, path)
    C = np.concatenate([c.data for c in mesh.cells if c.type == kind.name])
    if declared is not None:
        count = (declared[1].get(kind.gmsh, 0) if ext == ".msh" else
                 sum(declared[1].get(name, 0) for name in kind.medit))
        if (declared[0], count) != (len(mesh.points), len(C)):
            raise MeshFormatError(f"{path}: the file declares {declared[0]} points and {count} {kind.words} but "
                                  f"meshio read {len(mesh.points)} and {len(C)}; the file is malformed")
        if ext == ".mesh" and kind.dim == 3 and declared[2] != 3:
            raise MeshFormatError(f"{path}: Dimension {declared[2]}; a mesh of {kind.words} needs Dimension 3")
    P = np.asarray(mesh.points, dtype=np.float64)
    P = validate_vertices(P, f"{path.name}: points", dim=3 if kind.dim == 3 else None)
    C = validate_simplices(C, P.shape[0], kind.size, f"{path.name}: {kind.words}", words=(kind.word, kind.words))
    return (P, C, kind.name) if with_kind else (P, C)


def _others(kind, others, volume=""):
    """``non-tetrahedral cells (a, b)`` / ``cells other than quads (a, b)``, for messages."""
    what = f"non-tetrahedral {volume}cells" if kind.name == "tetra" else f"cells other than {kind.words}"
    return f"{what} ({', '.join(others)})"


def _cell_kind(mesh, kinds, path):
    """The first of ``kinds`` that meshio's ``mesh`` holds; refuses other cells of its dimension
    or higher (lower-dimensional ones are a boundary and ignored)."""
    found = sorted({c.type for c in mesh.cells})
    kind = next((CELL_KINDS[k] for k in kinds if any(c.type == k for c in mesh.cells)), None)
    wanted = " or ".join(CELL_KINDS[k].words for k in kinds)
    if kind is None:
        raise MeshFormatError(f"{path} has no {wanted} (cells found: {', '.join(found) or 'none'})")
    flat = {"vertex", "line", "line3"}
    higher = _VOLUME_CELLS | {"tetra"} | ({"triangle", "triangle6", "quad8", "quad9", "quad", "polygon"} - {kind.name}
                                           if kind.dim == 2 else set())
    others = sorted({t for t in found if t != kind.name and t in higher and t not in flat})
    if others:
        raise MeshFormatError(f"{path} contains {_others(kind, others, 'volume ')}; only meshes of one kind of "
                              f"cell, linear {kind.words}, are supported")
    return kind


# ---------------------------------------------------------------------- writing


def write_tets(path, P, T):
    """Write a tetrahedral mesh in the format its extension names, atomically, full precision.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.vtk``, ``.vtu``, ``.msh`` (written as Gmsh 4.1 ASCII) or ``.mesh``
        (Medit ASCII) file; its folder must exist.
    P : array_like, shape (n, 3)
        Point positions.
    T : array_like, shape (m, 4), integer
        Tetrahedra, 0-based.

    Returns
    -------
    pathlib.Path
        ``path``.  :func:`read_tets` reads back ``P`` and ``T`` bit for bit.

    Raises
    ------
    MeshFormatError
        Unsupported extension (nothing is created).
    MeshError
        Invalid ``P`` or ``T``.
    GeomoptError
        ``path`` cannot be written; nothing is left there then (an existing file keeps
        its contents).
    """
    return write_cells(path, P, T, "tetra")


def write_cells(path, P, C, kind, format=None):
    """Write a mesh of one :data:`CELL_KINDS` kind (``"tetra"``, ``"hexahedron"``, ``"quad"``) in
    the format its extension names (also ``.obj`` for quads), atomically, full precision; :func:`read_cells` (or
    :func:`read_tets`) reads back ``P`` and ``C`` bit for bit (2D points of quads are written
    with ``z = 0``); ``format`` an extension to write instead of the path's own (e.g. for a
    temporary file).  Raises as :func:`write_tets`."""
    path = Path(path)
    ext = (format or path.suffix).lower()
    if ext == ".obj" and kind == "quad":
        return write_obj_quads(path, P, C)
    ext = _extension(path.with_suffix(ext), "write")
    kind = CELL_KINDS[kind]
    P = validate_vertices(P, "P", dim=None if kind.dim == 2 else 3)
    if P.shape[1] == 2:
        P = np.column_stack([P, np.zeros(len(P))])
    C = validate_simplices(C, P.shape[0], kind.size, kind.words, words=(kind.word, kind.words))
    if ext == ".vtk":
        return _write_vtk(path, P, C, kind)
    check_output_path(path, what=f"{kind.word} mesh")
    import meshio

    mesh = meshio.Mesh(P, [(kind.name, C)])
    if ext == ".msh":
        ones = np.ones(len(C), dtype=np.int64)
        mesh = meshio.Mesh(P, [(kind.name, C)], cell_data={"gmsh:physical": [ones], "gmsh:geometrical": [ones]})
        write = lambda tmp: meshio.gmsh.write(tmp, mesh, fmt_version="4.1", binary=False)  # noqa: E731
    elif ext == ".mesh":
        write = lambda tmp: meshio.medit.write(tmp, mesh)  # noqa: E731
    else:
        write = lambda tmp: meshio.vtu.write(tmp, mesh, binary=True)  # noqa: E731
    with atomic_path(path, f"{kind.word} mesh") as tmp, _quiet() as printed:
        try:
            write(str(tmp))
        except Exception as exc:  # meshio's WriteError, OSError (disk full), ...
            raise GeomoptError(f"could not write {path} as {TET_FORMATS[ext]} ({_detail(exc, printed)}); "
                               f"nothing was written") from exc
    return path

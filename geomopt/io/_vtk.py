"""Legacy VTK unstructured grids (``.vtk``), ASCII or binary, read exactly as declared or refused.

File versions up to 5.1 (``OFFSETS``/``CONNECTIVITY``): the counts of ``POINTS``, ``CELLS``
and ``CELL_TYPES`` must match their data and each other; ``METADATA`` and dataset ``FIELD``
blocks are skipped; ``POINT_DATA`` / ``CELL_DATA`` sections after the cells are ignored.
Keywords and type names are case-insensitive, as in VTK's own reader.  Points declared
``float`` are float32 (then widened), as VTK reads them.  ASCII numbers are parsed by NumPy
(:mod:`geomopt.io._text`), binary blocks by ``np.frombuffer``; the cells are checked as VTU's
(:func:`~geomopt.io._cells.vtk_blocks`).
"""

from __future__ import annotations

import re

import numpy as np

from .._runtime.errors import MeshFormatError
from ._atomic import atomic_write
from ._cells import VTK_CELLS, VolumeCells, checked_cells, code_of, vtk_blocks
from ._text import FLOAT_RE, INT_RE, UTF8_BOM, Tokens, fits, parse, show, text_data, write_int_rows, write_rows

__all__ = ["parse_vtk", "write_vtk_tets", "write_vtk_cells"]

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
    return write_vtk_cells(path, P, T, "tetra")


def write_vtk_cells(path, P, C, kind):
    """Write a mesh of one :data:`~geomopt.io._cells.KINDS` kind as an ASCII legacy VTK
    unstructured grid, full precision, atomic; as :func:`write_vtk_tets` otherwise.

    Parameters
    ----------
    path : str or os.PathLike
    P : array_like, shape (n, 3), or (n, 2) for quads (written with ``z = 0``)
    C : array_like, shape (m, k), integer, 0-based, VTK's vertex order
    kind : str
        ``"tetra"``, ``"hexahedron"`` or ``"quad"``.

    Returns
    -------
    pathlib.Path
    """
    P, C = checked_cells(P, C, kind)
    (m, size), code = C.shape, code_of(VTK_CELLS, kind)

    def write(fh):
        fh.write("# vtk DataFile Version 2.0\nwritten by geomopt\nASCII\nDATASET UNSTRUCTURED_GRID\n")
        fh.write(f"POINTS {P.shape[0]} double\n")
        write_rows(fh, "", P)
        fh.write(f"CELLS {m} {(size + 1) * m}\n")
        write_int_rows(fh, f"{size}" + " %d" * size, C)
        fh.write(f"CELL_TYPES {m}\n")
        fh.write(f"{code}\n" * m)

    return atomic_write(path, write)


# ------------------------------------------------------------------------ VTK

_VTK_TYPES = {b"UNSIGNED_CHAR": "u1", b"CHAR": "i1", b"UNSIGNED_SHORT": "u2", b"SHORT": "i2",
              b"UNSIGNED_INT": "u4", b"INT": "i4", b"UNSIGNED_LONG": "u8", b"LONG": "i8", b"FLOAT": "f4",
              b"DOUBLE": "f8", b"VTKIDTYPE": "i8", b"VTKTYPEINT8": "i1", b"VTKTYPEUINT8": "u1",
              b"VTKTYPEINT16": "i2", b"VTKTYPEUINT16": "u2", b"VTKTYPEINT32": "i4", b"VTKTYPEUINT32": "u4",
              b"VTKTYPEINT64": "i8", b"VTKTYPEUINT64": "u8", b"VTKTYPEFLOAT32": "f4", b"VTKTYPEFLOAT64": "f8"}
_VTK_ATTRIBUTES = (b"POINT_DATA", b"CELL_DATA")
#: The start of a line whose first token begins with a letter: a keyword (or a value such as nan).
_NEXT_KEYWORD = re.compile(rb"\n[ \t]*[A-Za-z]")


class _VtkCursor:
    """Reads a legacy VTK file section by section: keyword lines, then ASCII numbers (parsed by
    NumPy, :class:`~geomopt.io._text.Tokens`) or binary blocks (``np.frombuffer``)."""

    def __init__(self, data, binary_start, path):
        """``data`` from byte ``binary_start`` in a binary file; ``None``: all of ``data``, ASCII text
        from the file's line 4."""
        self.data, self.pos, self.binary, self.path = data, binary_start or 0, binary_start is not None, path
        self.tokens = None  # ASCII: built when a section does not parse whole, to name the culprit

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

    def view(self, count, code, section):
        """A binary file's next ``count`` big-endian values of numpy type ``code``, as a read-only
        view of the file's bytes (no copy: the caller converts what it keeps, once)."""
        size = count * np.dtype(code).itemsize
        if self.pos + size > len(self.data):
            raise MeshFormatError(f"{self.path}: the file ends inside the {section} section (it declares "
                                  f"{count} values, {size} bytes); the file is truncated or a count is wrong")
        out = np.frombuffer(self.data, ">" + code, count, self.pos)
        self.pos += size
        return out

    def values(self, count, code, section):
        """``count`` values of numpy type ``code`` (ASCII tokens or big-endian binary)."""
        if self.binary:
            return self.view(count, code, section).astype(code)  # native byte order
        dtype = np.float64 if code[0] == "f" else np.int64
        found = _NEXT_KEYWORD.search(self.data, self.pos)  # the section's values end where a line starts a word
        end = found.start() + 1 if found else len(self.data)
        values = parse(self.data[self.pos:end], dtype)
        if values is None or len(values) != count:  # not exactly the declared values: find out why, token by token
            values, end = self._located(count, dtype, section)
        self.pos = end
        if code[0] == "f":
            with np.errstate(over="ignore"):
                return values.astype(code)
        return fits(values, code, f"{self.path}, {section} section")

    def _located(self, count, dtype, section):
        """``(count values, where they end)`` from the tokens at ``pos``, or a refusal naming the culprit."""
        if self.tokens is None:
            self.tokens = Tokens(self.data, self.path, line=4)
        tokens = self.tokens
        t = int(np.searchsorted(tokens.start, self.pos))
        if len(tokens) - t < count:
            raise MeshFormatError(f"{self.path}: the {section} section declares {count} values but the file "
                                  f"ends after {len(tokens) - t}; the file is truncated or a count is wrong")
        values = parse(self.data[tokens.start[t]:tokens.end[t + count - 1]], dtype) if count else np.zeros(0, dtype)
        if values is None or len(values) != count:
            bad = tokens.first_bad(np.arange(t, t + count), dtype)
            if re.fullmatch(rb"[A-Za-z_]{2,}", tokens.text(bad)):  # the next section came too early
                raise MeshFormatError(f"{self.path}: the {section} section declares {count} values but "
                                      f"{show(tokens.text(bad))} follows after {bad - t}; fix the count")
            tokens.refuse(bad, dtype, where=lambda i: f"{self.path}, {section} section, value {i - t + 1}")
        return values, int(tokens.end[t + count - 1]) if count else self.pos

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


def _vtk_section(cursor, keyword, expected, width=None):
    """The tokens of the next section's line (after METADATA / FIELD blocks), which must start with
    ``keyword`` (and hold ``width`` tokens); else a refusal saying ``expected`` and what was found."""
    _vtk_skip_optional(cursor)
    tokens = cursor.line()
    if _vtk_keyword(tokens) != keyword or (width is not None and len(tokens) != width):
        raise MeshFormatError(f"{cursor.path}: expected {expected}, found "
                              f"{show(b' '.join(tokens)) if tokens else 'the end of the file'}")
    return tokens


def parse_vtk(data, path):
    """The points and cells of a legacy VTK unstructured grid (bytes ``data``).

    Returns
    -------
    VolumeCells
    """
    skip = len(UTF8_BOM) if data[:len(UTF8_BOM)] == UTF8_BOM else 0  # bytes or a mapped file: no copy
    head = data[skip:skip + 4096].split(b"\n", 3)
    if len(head) < 4 or not head[0].strip().lower().startswith(b"# vtk datafile version"):
        raise MeshFormatError(f"{path} does not start with '# vtk DataFile Version ...'; it is not a legacy "
                              f"VTK file")
    mode = head[2].strip().upper()
    if mode not in (b"ASCII", b"BINARY"):
        raise MeshFormatError(f"{path}, line 3: expected ASCII or BINARY, found {show(head[2].strip())}")
    binary, start = mode == b"BINARY", skip + sum(len(line) + 1 for line in head[:3])
    cursor = _VtkCursor(data, start, path) if binary else _VtkCursor(text_data(data[start:], path, "VTK file"), None,
                                                                      path)
    tokens = cursor.line()
    if [t.upper() for t in tokens] != [b"DATASET", b"UNSTRUCTURED_GRID"]:
        found = show(b" ".join(tokens)) if tokens else "nothing"
        raise MeshFormatError(f"{path}: expected 'DATASET UNSTRUCTURED_GRID', found {found}; only unstructured "
                              f"grids (tetrahedral meshes) are supported")
    tokens = _vtk_section(cursor, b"POINTS", "'POINTS n type'", 3)
    n = _vtk_count(tokens, 1, cursor, "POINTS")
    points = cursor.values(3 * n, _vtk_type(tokens[2], cursor, "POINTS"), "POINTS").astype(np.float64, copy=False)
    cursor.expect_keyword("POINTS")
    tokens = _vtk_section(cursor, b"CELLS", "'CELLS' after the points", 3)
    a, b = _vtk_count(tokens, 1, cursor, "CELLS"), _vtk_count(tokens, 2, cursor, "CELLS")
    version5 = _vtk_keyword(cursor.peek()) == b"OFFSETS"
    offsets, conn = _vtk_cells(cursor, a, b, path)
    a += 0 if version5 else 1  # as many offsets as cells + 1, like version 5
    cells = a - 1
    cursor.expect_keyword("CELLS")
    tokens = _vtk_section(cursor, b"CELL_TYPES", "'CELL_TYPES' after the cells")
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
    cells = vtk_blocks(types, offsets, conn, None, str(path)) if m else []  # indices: MeshError, as content
    return VolumeCells(points.reshape(-1, 3), cells)



def _vtk_cells(cursor, a, b, path):
    """``(offsets (c,): where each cell ends in the connectivity, connectivity (b,))`` of a CELLS
    section declaring ``a`` cells in ``b`` values:
    version 5's OFFSETS + CONNECTIVITY, or the classic ``size i0 i1 ...`` rows."""
    if _vtk_keyword(cursor.peek()) == b"OFFSETS":  # version 5: offsets + connectivity
        t = cursor.line()
        offsets = cursor.values(a, _vtk_type(t[1] if len(t) > 1 else b"?", cursor, "OFFSETS"), "OFFSETS")
        cursor.expect_keyword("OFFSETS")
        t = cursor.line()
        if _vtk_keyword(t) != b"CONNECTIVITY" or len(t) != 2:
            raise MeshFormatError(f"{path}: expected 'CONNECTIVITY type' after OFFSETS")
        conn = cursor.values(b, _vtk_type(t[1], cursor, "CONNECTIVITY"), "CONNECTIVITY").astype(np.int64, copy=False)
        offsets = offsets.astype(np.int64, copy=False)
        if a == 0 or offsets[0] != 0 or offsets[-1] != b:
            raise MeshFormatError(f"{path}: the OFFSETS must rise from 0 to the connectivity size {b}")
        return offsets[1:], conn  # that they rise is checked with the cell types
    flat = cursor.view(b, "i4", "CELLS") if cursor.binary else cursor.values(b, "i4", "CELLS")
    k = b // a - 1 if a and b % a == 0 else -1  # one cell size throughout (tets, hexes, ...)?
    if k >= 0 and (flat[0::k + 1] == k).all():  # byte order, width and the sizes' removal in one copy
        return np.arange(1, a + 1) * k, flat.reshape(a, k + 1)[:, 1:].astype(np.int64).ravel()
    flat = flat.astype(np.int64)
    sizes, conn, pos = [], [], 0
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
    conn = np.concatenate(conn) if conn else np.zeros(0, dtype=np.int64)
    return np.cumsum(np.array(sizes, dtype=np.int64)), conn

"""OFF surface meshes, ASCII, read exactly as the header says (the rules: :func:`geomopt.io.read_mesh`);
numbers parsed by NumPy over whole sections (:mod:`geomopt.io._text`)."""

from __future__ import annotations

import re

import numpy as np

from .._runtime.errors import MeshFormatError
from ._faces import fan
from ._text import Tokens, ranges, show, text_data, uncomment

__all__ = ["read_off"]

_KEYWORD_RE = re.compile(rb"(ST)?(C)?(N)?(4)?(n)?OFF")


def read_off(data, path):
    """``(V, F)`` of an ASCII OFF file whose counts match its body; see :func:`geomopt.io.read_mesh`."""
    tokens = Tokens(uncomment(text_data(data, path, "OFF file")), path)
    rows = tokens.rows()
    if not len(rows):
        raise MeshFormatError(f"{path} contains no mesh (only comments or blank lines)")
    keyword = _KEYWORD_RE.fullmatch(rows.key(0))
    if keyword is None:
        raise MeshFormatError(f"{path}, line {rows.lineno[0]}: an OFF file must start with the keyword 'OFF' "
                              f"(or COFF, NOFF, STOFF ...), found {show(rows.key(0))}")
    st, colour, normal, four, ndim = keyword.groups()
    if four or ndim:
        raise MeshFormatError(f"{path}: {show(rows.key(0))} files (4D or n-dimensional vertices) are not "
                              f"supported; a 3D triangle mesh is required")
    if rows.count[0] > 1 and tokens.text(rows.first[0] + 1).upper() == b"BINARY":
        raise MeshFormatError(f"{path}: binary OFF is not supported; save it as ASCII OFF, OBJ or PLY")
    at, t0, n = (1, 1, rows.count[0] - 1) if rows.count[0] > 1 else (2, None, None)
    if at == 2:
        if len(rows) < 2:
            raise MeshFormatError(f"{path} ends after the OFF keyword; the vertex and face counts are missing")
        t0, n = 0, rows.count[1]
    lineno = rows.lineno[at - 1]
    if n not in (2, 3):
        raise MeshFormatError(f"{path}, line {lineno}: expected the counts 'vertices faces edges', found {n} values")
    first = rows.first[at - 1] + t0
    nv, nf = (int(x) for x in tokens.numbers(first, first + n, np.int64)[:2])
    if nv < 0 or nf < 0:
        raise MeshFormatError(f"{path}, line {lineno}: negative vertex or face count")
    held = len(rows) - at
    widths = sorted({3 + (3 if normal else 0) + c + (2 if st else 0) for c in ((3, 4) if colour else (0,))})
    if held > nv + nf:  # more lines than records: faces written across lines, or records the header omits
        F = _faces_across_lines(rows, at + nv, nf)
        if F is not None:
            V = _vertices(rows, at, at + nv, widths)
            return V, fan(*F, V, path)
    if held != nv + nf:
        raise MeshFormatError(
            f"{path}: the header (line {lineno}) declares {nv} vertices and {nf} faces, but the file "
            + (f"holds more (line {rows.lineno[at + nv + nf]}); fix the counts (an extra face would otherwise be "
               f"dropped)" if held > nv + nf else
               f"ends after {min(held, nv)} vertex line(s) and {max(held - nv, 0)} face line(s); fix the counts or "
               f"the truncated file"))
    if nf == 0:
        raise MeshFormatError(f"{path} has no triangle faces (the header declares 0 faces)")
    V = _vertices(rows, at, at + nv, widths)
    return V, _faces(rows, at + nv, at + nv + nf, V)


def _vertices(rows, a, b, widths):
    """(b - a, 3) float64 positions of the vertex rows ``a:b`` (each holding one of ``widths`` numbers)."""
    bad = np.flatnonzero(~np.isin(rows.count[a:b], widths))
    if bad.size:
        r = a + int(bad[0])
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[r]}: vertex line has {rows.count[r]} numbers; "
                              f"expected {' or '.join(map(str, widths))} (one vertex per line, as the header declares)")
    values = rows.floats(a, b, None)
    at = rows.first[a:b] - rows.first[a]
    return values[at[:, None] + np.arange(3)]


def _faces(rows, a, b, V):
    """Triangles of the face rows ``a:b`` (``k i1 .. ik`` and up to 4 colour numbers), fan-triangulated."""
    tokens, first, count = rows.tokens, rows.first[a:b], rows.count[a:b]
    k = rows.ints(a, b, None, column=0)
    for bad, why in ((k < 3, lambda r: f"face with {k[r]} vertices; a face needs at least 3"),
                     ((count < k + 1) | (count > k + 5),
                      lambda r: f"face line declares {k[r]} vertices but holds {count[r] - 1} values; expected "
                                f"{k[r]} indices and at most 4 colour numbers")):
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[a + r]}: {why(r)}")
    index = tokens.numbers_at(ranges(first + 1, k), np.int64)
    extra = count - 1 - k
    if extra.any():  # colours: checked as numbers, then ignored
        tokens.numbers_at(ranges(first + 1 + k, extra), np.float64,
                          where=lambda t: f"{rows.path}, line {tokens.lineno(t)} (face colour)")
    return fan(index, k, V, rows.path)


def _faces_across_lines(rows, a, nf):
    """``(indices, counts)`` of ``nf`` faces read as Geomview defines OFF (free format: a face is
    ``k`` and ``k`` indices wherever the lines break, then up to 4 colour numbers to the end of
    the line of its last index) from row ``a`` on, when that reads every number after the
    vertices exactly; None otherwise (the line-per-face reading's refusal then stands)."""
    t0 = rows.first[a]
    values = rows.tokens.numbers(t0, rows.first[-1] + rows.count[-1], np.float64)
    row_end = (np.repeat(rows.first[a:] + rows.count[a:], rows.count[a:]) - t0).tolist()
    whole = np.isfinite(values) & (values == np.round(values))
    starts, counts, pos = [], [], 0
    for _ in range(nf):
        if pos >= len(values) or not whole[pos] or values[pos] < 3 or pos + values[pos] >= len(values):
            return None
        k = int(values[pos])
        end = row_end[pos + k]
        if end - (pos + k + 1) > 4 or not whole[pos + 1:pos + k + 1].all():
            return None
        starts.append(pos + 1)
        counts.append(k)
        pos = end
    if pos != len(values):
        return None
    return values[ranges(starts, counts)].astype(np.int64), np.array(counts, dtype=np.int64)

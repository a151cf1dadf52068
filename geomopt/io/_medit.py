"""Medit ASCII meshes (``.mesh``, ``MeshVersionFormatted`` 1 or 2), read exactly or refused.

Every section must hold exactly the entries its count declares, with the declared number of
values each; element indices are 1-based and within the vertex count; the file ends with
``End``.  Coordinates are read as the decimals the file holds, in float64, whatever the
version (version 1 means single precision only in binary Medit files, which are refused).
Sections outside :data:`~geomopt.io._cells.MEDIT_SECTIONS` are refused.
"""

from __future__ import annotations

import re

import numpy as np

from .._runtime.errors import MeshFormatError
from ._cells import KINDS, MEDIT_SECTIONS, VolumeCells
from ._text import UTF8_BOM, ascii_rows

__all__ = ["parse_medit"]

_NOT_KEYWORDS = (b"nan", b"inf", b"infinity")
#: Sections of real numbers; every other section holds integers.
_REAL = ("Vertices", "Normals", "Tangents")


def parse_medit(data, path, dims=(3,)):
    """The points and cells of a Medit ASCII file (bytes ``data``) whose ``Dimension`` is one of
    ``dims`` (2 only for quad meshes in the plane).

    Returns
    -------
    VolumeCells
        ``points`` of shape (n, Dimension).
    """
    data = data.removeprefix(UTF8_BOM)
    if b"#" in data:
        data = re.sub(rb"(?m)^[ \t]*#[^\n]*", b"", data)  # comment lines, kept as blank
    rows = ascii_rows(data, path, "Medit")
    keyword = (rows.head | 32 >= ord("a")) & (rows.head | 32 <= ord("z"))
    for r in np.flatnonzero(keyword & np.isin(rows.head | 32, list(b"ni"))).tolist():
        keyword[r] = rows.key(r).lower() not in _NOT_KEYWORDS
    if not len(rows) or rows.key(0) != b"MeshVersionFormatted":
        raise MeshFormatError(f"{path} does not start with MeshVersionFormatted; it is not an ASCII Medit file")
    r, header, points, cells, last, seen = 0, {}, None, [], None, {}
    while r < len(rows):
        key, line = rows.key(r).decode(), rows.lineno[r]
        if not keyword[r]:
            if last is None:
                raise MeshFormatError(f"{path}, line {line}: expected a section keyword (such as Vertices), "
                                      f"found {rows.at(r)!r}")
            raise MeshFormatError(f"{path}, line {line}: section {last[0]} (line {last[1]}) declares {last[2]} "
                                  f"entries but more follow; fix the count")
        if key in ("MeshVersionFormatted", "Dimension"):
            r = _header(rows, r, keyword, header, dims)
            continue
        if key == "End":
            if r != len(rows) - 1:
                raise MeshFormatError(f"{path}, line {rows.lineno[r + 1]}: text after End")
            break
        a, b = _section(rows, r, keyword, header)
        if key in seen:
            raise MeshFormatError(f"{path}, line {line}: a second {key} section (the first is on line {seen[key]}); "
                                  f"a Medit file holds each section once")
        seen[key], last = line, (key, line, b - a)
        _, indices, name, dim = MEDIT_SECTIONS[key]
        if key in _REAL:
            values = rows.floats(a, b, key).reshape(b - a, -1)
            points = values[:, :header["Dimension"]] if key == "Vertices" else points
        elif indices and b > a:
            cells.append((name or key, dim, _indices(rows, a, b, key, indices, points)))
        else:
            rows.ints(a, b, f"{key} entry")
        r = b
    else:
        raise MeshFormatError(f"{path} has no End keyword; the file is truncated")
    if points is None:
        raise MeshFormatError(f"{path} has no Vertices section")
    return VolumeCells(points, [(name, dim, ref if name in KINDS else None) for name, dim, ref in cells
                                if dim > 0])


def _header(rows, r, keyword, header, dims):
    """Read ``MeshVersionFormatted`` or ``Dimension`` (its value on the same or the next line)."""
    key, line = rows.key(r).decode(), rows.lineno[r]
    on_next = rows.count[r] == 1 and r + 1 < len(rows) and rows.count[r + 1] == 1 and not keyword[r + 1]
    if rows.count[r] != 2 and not on_next:
        raise MeshFormatError(f"{rows.path}, line {line}: {key} needs one integer")
    value = int(rows.ints(r + on_next, r + on_next + 1, key, column=0 if on_next else 1)[0])
    if key == "MeshVersionFormatted" and value not in (1, 2):
        raise MeshFormatError(f"{rows.path}, line {line}: MeshVersionFormatted {value} is not supported (1 or 2)")
    if key == "Dimension" and value not in dims:
        raise MeshFormatError(f"{rows.path}, line {line}: Dimension {value}; a "
                              f"{'volume mesh' if dims == (3,) else 'mesh'} needs Dimension "
                              f"{' or '.join(map(str, dims))}")
    header[key] = value
    return r + 1 + on_next


def _section(rows, r, keyword, header):
    """Rows ``a:b`` of the section opened on row ``r``: its count and widths checked."""
    key, line = rows.key(r).decode(), rows.lineno[r]
    if key not in MEDIT_SECTIONS:
        raise MeshFormatError(f"{rows.path}, line {line}: unsupported Medit section {key!r}; supported: "
                              f"{', '.join(MEDIT_SECTIONS)}, End")
    if rows.count[r] != 1 or r + 1 >= len(rows) or rows.count[r + 1] != 1:
        raise MeshFormatError(f"{rows.path}, line {line}: expected {key} alone on its line and its count alone "
                              f"on the next")
    if len(header) < 2:
        raise MeshFormatError(f"{rows.path}, line {line}: {key} before MeshVersionFormatted and Dimension")
    n = int(rows.ints(r + 1, r + 2, f"{key} count")[0])
    dim = header["Dimension"]
    width = MEDIT_SECTIONS[key][0]
    width = dim + 1 if width is None else dim if width == "dim" else width
    a, b = r + 2, min(r + 2 + max(n, 0), len(rows))
    inside = np.flatnonzero(keyword[a:b])
    rows.counted(r, int(inside[0]) if inside.size else b - a, n, key)
    rows.width(a, b, width, key)
    return a, b


def _indices(rows, a, b, key, indices, points):
    """The 0-based vertex indices of section ``key``'s entries on rows ``a:b``."""
    if points is None:
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[a - 2]}: {key} before Vertices")
    ref = rows.ints(a, b, f"{key} entry").reshape(b - a, -1)[:, :indices]
    nv = len(points)
    bad = (ref < 1) | (ref > nv)
    if bad.any():
        i = int(np.flatnonzero(bad.any(axis=1))[0])
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[a + i]}: {key} entry {i + 1} refers to vertex "
                              f"{int(ref[i][bad[i]][0])}; Medit vertices are numbered 1..{nv}")
    return ref - 1

"""STL surface meshes, ASCII or binary, corners with equal coordinates welded into vertices (the
rules: :func:`geomopt.io.read_mesh`).  Binary STL is read by ``np.frombuffer``; an ASCII file must
hold exactly one ``solid`` of ``facet normal`` / ``outer loop`` / 3 ``vertex`` / ``endloop`` /
``endfacet`` blocks (keywords in any case).
"""

from __future__ import annotations

import numpy as np

from .._runtime.errors import MeshFormatError
from ..exact.weld import weld
from ._text import UTF8_BOM, Tokens, ranges, show, text_data

__all__ = ["read_stl"]

_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
#: The 7 lines of an ASCII facet: keywords and the count of numbers after them.
_FACET = ((b"facet normal", 3), (b"outer loop", 0), (b"vertex", 3), (b"vertex", 3), (b"vertex", 3),
          (b"endloop", 0), (b"endfacet", 0))


def read_stl(data, path):
    """``(V, F)`` of an ASCII or binary STL file, corners welded by equal coordinates."""
    binary_size = 84 + 50 * int.from_bytes(data[80:84], "little") if len(data) >= 84 else None
    text = data.removeprefix(UTF8_BOM)
    looks_ascii = text.lstrip()[:5].lower() == b"solid" and not any(
        b < 9 or 13 < b < 32 or b == 127 for b in text[:1000])
    if len(data) == binary_size and not looks_ascii:
        count = (len(data) - 84) // 50
        if count == 0:
            raise MeshFormatError(f"{path} is a binary STL with 0 triangles; a triangle mesh is required")
        return weld(np.frombuffer(data, _RECORD, count, 84)["corners"].reshape(-1, 3).astype(np.float64))
    if looks_ascii:
        return weld(_ascii_corners(data, path))
    # many binary STL headers begin with 'solid' too: then it is the binary bytes that rule out ASCII
    not_ascii = ("it starts with 'solid' but holds binary bytes" if text.lstrip()[:5].lower() == b"solid"
                 else "it does not start with 'solid'")
    if binary_size is None:
        raise MeshFormatError(f"{path} is too short ({len(data)} bytes) for a binary STL and is not ASCII STL "
                              f"({not_ascii}); it is not an STL file")
    raise MeshFormatError(
        f"{path} is not ASCII STL ({not_ascii}) and not a valid binary STL: its header "
        f"declares {(binary_size - 84) // 50} triangles = {binary_size} bytes, but the file has {len(data)} "
        f"bytes (truncated, or trailing data)")


def _ascii_corners(data, path):
    """(3m, 3) float64 corner positions of an ASCII STL with exactly one solid."""
    tokens = Tokens(text_data(data, path, "STL file"), path)
    rows, lower = tokens.rows(), tokens.data.lower()
    if not _is(rows, lower, 0, b"solid"):
        raise MeshFormatError(f"{path}, line {rows.lineno[0]}: an ASCII STL must start with 'solid'")
    end = next((r for r in np.flatnonzero(rows.head | 32 == ord("e")).tolist() if _is(rows, lower, r, b"endsolid")),
               None)
    if end is None:
        raise MeshFormatError(f"{path}: no 'endsolid' line; the file is truncated")
    if end + 1 < len(rows):
        if _is(rows, lower, end + 1, b"solid"):
            solids = sum(_is(rows, lower, r, b"solid") for r in range(len(rows)))
            raise MeshFormatError(f"{path} contains {solids} separate meshes ('solid' blocks, the second at line "
                                  f"{rows.lineno[end + 1]}); merge them into one solid before reading it")
        raise MeshFormatError(f"{path}, line {rows.lineno[end + 1]}: data after 'endsolid'; remove it")
    slot = np.arange(end - 1) % 7
    ok = np.ones(end - 1, dtype=bool)
    for j, (keywords, numbers) in enumerate(_FACET):
        at = np.flatnonzero(slot == j)
        ok[at] = rows.count[1 + at] == len(keywords.split()) + numbers
        for w, word in enumerate(keywords.split()):
            ok[at] &= _words_are(tokens, lower, rows.first[1 + at] + w, word)
    if not ok.all():
        r = int(np.flatnonzero(~ok)[0])
        keywords, numbers = _FACET[r % 7]
        raise MeshFormatError(f"{path}, line {rows.lineno[1 + r]}: expected '{keywords.decode()}"
                              f"{' x y z' if numbers else ''}', found {show(rows.at(1 + r).encode())}")
    if (end - 1) % 7:
        raise MeshFormatError(f"{path}, line {rows.lineno[end]}: 'endsolid' inside an unfinished facet; the file "
                              f"is truncated")
    if end == 1:
        raise MeshFormatError(f"{path} has no facets; a triangle mesh is required")
    facets = 1 + 7 * np.arange((end - 1) // 7)
    tokens.numbers_at(ranges(rows.first[facets] + 2, np.full(len(facets), 3)), np.float64)  # normals: numbers
    corners = np.sort(np.concatenate([facets + 2, facets + 3, facets + 4]))
    return tokens.numbers_at(ranges(rows.first[corners] + 1, np.full(len(corners), 3)), np.float64).reshape(-1, 3)


def _is(rows, lower, r, word):
    """Row ``r``'s first token is ``word`` (any case)."""
    t = rows.tokens
    return lower[t.start[rows.first[r]]:t.end[rows.first[r]]] == word


def _words_are(tokens, lower, index, word):
    """Which of the tokens ``index`` are ``word`` (lower case bytes), in any case (vectorised)."""
    index = np.minimum(index, len(tokens) - 1)
    ok = tokens.end[index] - tokens.start[index] == len(word)
    raw = np.frombuffer(lower, np.uint8)
    for i, byte in enumerate(word):
        ok &= raw[np.minimum(tokens.start[index] + i, len(raw) - 1)] == byte
    return ok

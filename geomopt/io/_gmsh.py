"""Gmsh ASCII meshes (MSH 2.2 and 4.1), read exactly as the file declares them or refused.

Every section must hold exactly the entries its count declares and be closed (``$EndNodes``
...); node tags are positive and unique, in any order and with gaps (they are mapped to
0-based indices in file order); every element names defined nodes; element types outside
:data:`~geomopt.io._cells.GMSH_CELLS` are refused.  Sections other than ``$MeshFormat``,
``$Nodes`` and ``$Elements`` (``$PhysicalNames``, ``$Entities``, data) are read past.
"""

from __future__ import annotations

import numpy as np

from .._runtime.errors import MeshFormatError
from ._cells import GMSH_CELLS, GMSH_NODES, KINDS, VolumeCells, nodes_of
from ._text import UTF8_BOM, ascii_rows

__all__ = ["parse_gmsh"]


def parse_gmsh(data, path):
    """The points and cells of a Gmsh ASCII 2.2 or 4.1 file (bytes ``data``).

    Returns
    -------
    VolumeCells
    """
    data = data.removeprefix(UTF8_BOM)
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
    rows = ascii_rows(data, path, "Gmsh")
    sections = _sections(rows)
    for name in ("Nodes", "Elements"):
        if len(sections.get(name, ())) != 1:
            raise MeshFormatError(f"{path} has {len(sections.get(name, ()))} ${name} sections; exactly one "
                                  f"is required")
        a, b = sections[name][0]
        if a == b:
            raise MeshFormatError(f"{path}: section ${name} (line {rows.lineno[a - 1]}) is empty")
    read = _gmsh22 if fmt[0] == b"2.2" else _gmsh41
    tags, points, blocks = read(rows, sections["Nodes"][0], sections["Elements"][0])
    return VolumeCells(points, _cells(rows, tags, blocks))


def _sections(rows):
    """``{name: [(a, b)]}``: the body rows ``a:b`` of each ``$name`` ... ``$Endname`` section."""
    marks = np.flatnonzero(rows.head == ord("$")).tolist() + [len(rows)]
    sections, expect = {}, 0
    for k in range(0, len(marks) - 1, 2):
        r, end = marks[k], marks[k + 1]
        if r != expect or rows.key(r).startswith(b"$End"):
            bad = expect if r != expect else r
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[bad]}: {rows.at(bad)!r} outside a section; "
                                  f"expected a section start such as $Nodes")
        name = rows.key(r)[1:].decode()
        if end == len(rows) or rows.key(end) != f"$End{name}".encode():
            found = f"{rows.key(end).decode()!r} on line {rows.lineno[end]}" if end < len(rows) else \
                "the end of the file"
            raise MeshFormatError(f"{rows.path}: section ${name} (line {rows.lineno[r]}) is not closed by "
                                  f"$End{name} (found {found}); the file is truncated or malformed")
        sections.setdefault(name, []).append((r + 1, end))
        expect = end + 1
    if expect != len(rows):
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[expect]}: {rows.at(expect)!r} outside a section; "
                              f"expected a section start such as $Nodes")
    return sections


def _nodes_per_element(types, rows, first):
    """Nodes of each Gmsh element type in ``types`` (row ``first + i`` for messages; refuses unknown types)."""
    nodes = nodes_of(GMSH_NODES, types)
    if (nodes < 0).any():
        i = int(np.flatnonzero(nodes < 0)[0])
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[first + i]}: unsupported Gmsh element type "
                              f"{types[i]}; supported: {', '.join(map(str, sorted(GMSH_CELLS)))}")
    return nodes


def _tags(rows, a, b, column):
    """Node tags on rows ``a:b`` (token ``column``): positive integers."""
    tags = rows.ints(a, b, "node tag", column=column)
    bad = np.flatnonzero(tags < 1)
    if bad.size:
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[a + int(bad[0])]}: node tag {tags[bad[0]]}; Gmsh "
                              f"node tags start at 1 (a 0-based export? add 1 to every node tag)")
    return tags


def _gmsh22(rows, nodes, elems):
    """Node tags, ``(n, 3)`` points and ``[(type, (m, k) node tags, first row)]`` of MSH 2.2 sections."""
    (a, b), (c, d) = nodes, elems
    rows.width(a, a + 1, 1, "$Nodes count")
    rows.counted(a - 1, b - a - 1, int(rows.ints(a, a + 1, "node count")[0]), "$Nodes")
    rows.width(a + 1, b, 4, "$Nodes")
    points = rows.floats(a + 1, b, "$Nodes").reshape(-1, 4)[:, 1:]
    tags = _tags(rows, a + 1, b, 0)
    rows.width(c, c + 1, 1, "$Elements count")
    rows.counted(c - 1, d - c - 1, int(rows.ints(c, c + 1, "element count")[0]), "$Elements")
    short = np.flatnonzero(rows.count[c + 1:d] < 3)
    if short.size:
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[c + 1 + short[0]]}: an element needs at least 3 "
                              f"values (tag, type, number of tags)")
    values = rows.ints(c + 1, d, "element")
    at = rows.first[c + 1:d] - rows.first[c + 1]
    types, ntags = values[at + 1], values[at + 2]
    per = _nodes_per_element(types, rows, c + 1)
    width = 3 + ntags + per
    bad = np.flatnonzero((rows.count[c + 1:d] != width) | (ntags < 0))
    if bad.size:
        i = int(bad[0])
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[c + 1 + i]}: an element of type {types[i]} with "
                              f"{ntags[i]} tags needs {width[i]} values, found {rows.count[c + 1 + i]}")
    ends = at + rows.count[c + 1:d]
    blocks = []
    for t in dict.fromkeys(types.tolist()):  # each type once, in order of first appearance
        rows_of = np.flatnonzero(types == t)
        k = int(per[rows_of[0]])
        blocks.append((t, values[ends[rows_of][:, None] - k + np.arange(k)], c + 1 + int(rows_of[0])))
    return tags, points, blocks


def _gmsh41(rows, nodes, elems):
    """Node tags, ``(n, 3)`` points and ``[(type, (m, k) node tags, first row)]`` of MSH 4.1 sections."""
    (a, b), (c, d) = nodes, elems

    def header(r, what):
        rows.width(r, r + 1, 4, what)
        return rows.ints(r, r + 1, what).tolist()

    nblocks, total, lo, hi = header(a, "$Nodes header")
    tags, points = [], []
    for r, (dim, _, parametric, n) in _blocks(rows, a, b, nblocks, "$Nodes", header, 2):
        rows.width(r, r + n, 1, "$Nodes tag")
        width = 3 + (dim if parametric else 0)
        rows.width(r + n, r + 2 * n, width, "$Nodes coordinate")
        points.append(rows.floats(r + n, r + 2 * n, "$Nodes coordinate").reshape(n, width)[:, :3])
        tags.append(_tags(rows, r, r + n, 0))
    tags = np.concatenate(tags) if tags else np.zeros(0, dtype=np.int64)
    if len(tags) != total:
        raise MeshFormatError(f"{rows.path}: section $Nodes (line {rows.lineno[a - 1]}) declares {total} nodes "
                              f"but its blocks hold {len(tags)}; fix the counts")
    if tags.size and (tags.min(), tags.max()) != (lo, hi):
        raise MeshFormatError(f"{rows.path}: section $Nodes (line {rows.lineno[a - 1]}) holds node tags "
                              f"{tags.min()}..{tags.max()} but its header says {lo}..{hi}; fix the header")
    nblocks, total, _, _ = header(c, "$Elements header")
    count, blocks = 0, []
    for r, (_, _, gtype, n) in _blocks(rows, c, d, nblocks, "$Elements", header, 1):
        k = int(_nodes_per_element(np.array([gtype]), rows, r - 1)[0])
        rows.width(r, r + n, 1 + k, f"type-{gtype} element")
        if n:
            blocks.append((gtype, rows.ints(r, r + n, "element").reshape(n, 1 + k)[:, 1:], r))
        count += n
    if count != total:
        raise MeshFormatError(f"{rows.path}: section $Elements (line {rows.lineno[c - 1]}) declares {total} "
                              f"elements but its blocks hold {count}; fix the counts")
    points = np.concatenate(points) if points else np.zeros((0, 3))
    return tags, points, blocks


def _blocks(rows, first, stop, nblocks, what, header, rows_per_entry):
    """``(first body row, header)`` of each of the ``nblocks`` blocks of a 4.1 section."""
    r = first + 1
    for _ in range(nblocks):
        if r >= stop:
            raise MeshFormatError(f"{rows.path}: {what} (line {rows.lineno[first - 1]}) declares {nblocks} "
                                  f"blocks but holds fewer")
        block = header(r, f"{what} block header")
        n = block[3]
        if n < 0 or r + 1 + rows_per_entry * n > stop:
            raise MeshFormatError(f"{rows.path}: a {what} block (line {rows.lineno[r]}) declares {n} "
                                  f"entries but the section ends first")
        yield r + 1, block
        r += 1 + rows_per_entry * n
    if r != stop:
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[r]}: {what} (line {rows.lineno[first - 1]}) "
                              f"holds more blocks than the {nblocks} it declares; fix the counts")


def _cells(rows, tags, blocks):
    """Element blocks as cells named by :data:`GMSH_CELLS`, node tags mapped to 0-based indices."""
    order = np.argsort(tags, kind="stable")
    ordered = tags[order]
    if (ordered[1:] == ordered[:-1]).any():
        raise MeshFormatError(f"{rows.path}: a node tag is defined twice in $Nodes; tags must be unique")
    cells = []
    for gtype, node_tags, _ in blocks:
        at = np.minimum(np.searchsorted(ordered, node_tags), len(ordered) - 1)
        undefined = ordered[at] != node_tags if len(ordered) else np.ones(node_tags.shape, dtype=bool)
        if undefined.any():
            raise MeshFormatError(f"{rows.path}: an element refers to node tag {int(node_tags[undefined][0])}, "
                                  f"which $Nodes does not define")
        name, dim, _ = GMSH_CELLS[gtype]
        cells.append((name, dim, order[at] if name in KINDS else None))
    return cells

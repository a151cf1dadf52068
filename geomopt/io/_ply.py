"""PLY surface meshes (ASCII, binary little- and big-endian), read exactly as the header declares
(the rules: :func:`geomopt.io.read_mesh`).

Binary bodies are decoded by ``np.frombuffer`` with one structured dtype per element (a Python walk
only for lists of varying length); ASCII bodies by NumPy's number parser, one call per element (an
element whose properties are all integers is parsed as integers, strictly; one mixing integer and
real properties is parsed as reals and its integer values must be whole).
"""

from __future__ import annotations

import re

import numpy as np

from .._runtime.errors import MeshError, MeshFormatError
from ._atomic import atomic_write
from ._faces import fan, mesh_with_uv
from ._text import UTF8_BOM, Tokens, ranges, show, text_data

__all__ = ["read_ply", "write_ply_with_uv"]

_TYPES = {b"char": "i1", b"int8": "i1", b"uchar": "u1", b"uint8": "u1", b"short": "i2", b"int16": "i2",
          b"ushort": "u2", b"uint16": "u2", b"int": "i4", b"int32": "i4", b"uint": "u4", b"uint32": "u4",
          b"float": "f4", b"float32": "f4", b"double": "f8", b"float64": "f8"}
_FORMATS = {b"ascii": None, b"binary_little_endian": "<", b"binary_big_endian": ">"}


def read_ply(data, path):
    """``(V, F)`` of an ASCII or binary PLY file, its body checked against the header; see
    :func:`geomopt.io.read_mesh`."""
    order, elements, offset = _header(data, path)
    found = {}
    if order is None:
        body = data[offset:]
        if b"\x00" in body or UTF8_BOM in body:
            raise MeshFormatError(f"{path}: the header says 'format ascii' but the body holds binary data "
                                  f"(NUL bytes or a byte-order mark)")
        rows = Tokens(text_data(body, path, "PLY file"), path, line=data[:offset].count(b"\n") + 1).rows()
        at = 0
        for name, count, props, _ in elements:
            found[name] = _ascii_element(rows, at, count, name, props)
            at += count
        if len(rows) > at:
            raise MeshFormatError(f"{path}, line {rows.lineno[at]}: the PLY body holds more lines than the header "
                                  f"declares ({sum(e[1] for e in elements)} element lines); fix the counts")
    else:
        at = offset
        for name, count, props, _ in elements:
            found[name], at = _binary_element(data, at, name, count, props, order, path)
        if at != len(data):
            raise MeshFormatError(f"{path}: the binary PLY body is {len(data) - at} bytes longer than the "
                                  f"header's elements; fix the counts (or the file has trailing data)")
    return _mesh(found, elements, path)


def _header(data, path):
    """Parse a PLY header: ``(byte order or None for ASCII, elements, body offset)``.

    ``elements`` is a list of ``(name, count, properties, lineno)``; a property is
    ``(name, dtype)`` or ``(name, count dtype, item dtype)`` for a list (dtypes as numpy
    codes without byte order).
    """
    skipped = len(UTF8_BOM) if data.startswith(UTF8_BOM) else 0
    data = data[skipped:]
    if not data.startswith((b"ply\n", b"ply\r\n")):
        raise MeshFormatError(f"{path} does not start with the line 'ply'; it is not a PLY file")
    end = re.search(rb"(?m)^end_header[ \t]*\r?(?:\n|\Z)", data)
    if end is None:
        raise MeshFormatError(f"{path}: the PLY header has no 'end_header' line; the file is truncated or not PLY")
    order, elements = "missing", []
    for lineno, line in enumerate(data[:end.start()].split(b"\n")[1:], 2):
        tokens, where = line.split(), f"{path}, line {lineno}"
        if not tokens or tokens[0] in (b"comment", b"obj_info"):
            continue
        if tokens[0] == b"format":
            if len(tokens) != 3 or tokens[1] not in _FORMATS or tokens[2] != b"1.0":
                raise MeshFormatError(f"{where}: unsupported PLY format line {show(line.strip())}; expected "
                                      f"'format ascii|binary_little_endian|binary_big_endian 1.0'")
            order = _FORMATS[tokens[1]]
        elif tokens[0] == b"element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise MeshFormatError(f"{where}: malformed element line {show(line.strip())}; expected "
                                      f"'element NAME COUNT'")
            if any(e[0] == tokens[1] for e in elements):
                raise MeshFormatError(f"{where}: element {show(tokens[1])} is declared twice")
            elements.append((tokens[1], int(tokens[2]), [], lineno))
        elif tokens[0] == b"property":
            _property(tokens, line, elements, where)
        else:
            raise MeshFormatError(f"{where}: unknown PLY header line {show(line.strip())}")
    if order == "missing":
        raise MeshFormatError(f"{path}: the PLY header has no 'format' line")
    return order, elements, skipped + end.end()


def _property(tokens, line, elements, where):
    """Add the property declared by ``tokens`` to the last element."""
    if not elements:
        raise MeshFormatError(f"{where}: property declared before any element")
    props = elements[-1][2]
    if len(tokens) == 3 and tokens[1] in _TYPES:
        prop = (tokens[2], _TYPES[tokens[1]])
    elif (len(tokens) == 5 and tokens[1] == b"list" and tokens[2] in _TYPES and tokens[3] in _TYPES
          and _TYPES[tokens[2]][0] in "iu"):
        prop = (tokens[4], _TYPES[tokens[2]], _TYPES[tokens[3]])
    else:
        raise MeshFormatError(
            f"{where}: malformed or unsupported property line {show(line.strip())}; expected 'property TYPE NAME' "
            f"or 'property list COUNT_TYPE ITEM_TYPE NAME' (types: {', '.join(t.decode() for t in _TYPES)}; a "
            f"list count must be an integer type)")
    if any(p[0] == prop[0] for p in props):
        raise MeshFormatError(f"{where}: property {show(prop[0])} is declared twice")
    props.append(prop)


def _ascii_element(rows, a, count, name, props):
    """Columns of the ``count`` element lines from row ``a``: ``{property: array}`` (lists:
    ``(counts, flat items)``), every line holding exactly what its properties take."""
    what, path = f"element {show(name)}", rows.path
    if len(rows) - a < count:
        raise MeshFormatError(f"{path}: the header declares {count} {what} lines but the body ends after "
                              f"{len(rows) - a}; the file is truncated or the count is wrong")
    if not count:
        return {}
    b = a + count
    integer = all(np.dtype(code).kind in "iu" for p in props for code in p[1:])
    try:
        values = rows.ints(a, b, None) if integer else rows.floats(a, b, None)
    except MeshFormatError:
        _list_count_at_fault(rows, a, b, props, what, np.int64 if integer else np.float64)
        raise
    pos = rows.first[a:b] - rows.first[a]
    stop = pos + rows.count[a:b]
    out = {}

    def refuse(bad, message):
        r = int(np.flatnonzero(bad)[0])
        raise MeshFormatError(f"{path}, line {rows.lineno[a + r]}: {message(r)}")

    for p in props:
        if (pos >= stop).any():
            refuse(pos >= stop, lambda r: f"{what} line has {rows.count[a + r]} values; too few for its properties"
                   + (f" (the count of list {show(p[0])} is missing)" if len(p) == 3 else ""))
        head = _typed(values[pos], p[1], lambda i: rows.lineno[a + i], path)
        if len(p) == 2:
            out[p[0]], pos = head, pos + 1
            continue
        k = head.astype(np.int64)
        if ((k < 0) | (pos + 1 + k > stop)).any():
            refuse((k < 0) | (pos + 1 + k > stop), lambda r: f"list {show(p[0])} declares {k[r]} items but the "
                                                              f"line holds {stop[r] - pos[r] - 1} more values")
        ends = np.cumsum(k)
        items = _typed(values[ranges(pos + 1, k)], p[2],
                       lambda i: rows.lineno[a + int(np.searchsorted(ends, i, side="right"))], path)
        out[p[0]], pos = (k, items), pos + 1 + k
    if (pos != stop).any():
        refuse(pos != stop, lambda r: f"{what} line has {rows.count[a + r]} values; its properties take "
                                      f"{pos[r] - stop[r] + rows.count[a + r]}")
    return out


def _list_count_at_fault(rows, a, b, props, what, dtype):
    """If the first token of rows ``a:b`` that is not a ``dtype`` number is where a list's count
    belongs, refuse it as such (the line is then likely not an element of this kind)."""
    tokens = rows.tokens
    bad = tokens.first_bad(np.arange(rows.first[a], rows.first[b - 1] + rows.count[b - 1]), dtype)
    r = int(np.searchsorted(rows.first, bad, side="right")) - 1
    j = rows.first[r]
    for p in props:
        if j == bad and len(p) == 3:
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[r]}: {what} line is missing the count of list "
                                  f"{show(p[0])} (or it is not an integer)")
        if j >= bad:
            return
        j += 1 + (int(float(tokens.text(j))) if len(p) == 3 else 0)


def _typed(values, code, lineno, path):
    """``values`` (float64 or int64) as the declared PLY type ``code``, or a refusal naming the line
    (``lineno(i)``) of the first value that type cannot hold exactly."""
    if code[0] == "f":
        with np.errstate(over="ignore"):
            narrow = values.astype(code)  # 'float' properties are float32, as declared
        bad = np.isfinite(values) & ~np.isfinite(narrow)
    else:
        info = np.iinfo(code)
        bad = (values < info.min) | (values > info.max) | (values != np.floor(values))
        narrow = values
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise MeshFormatError(f"{path}, line {lineno(i)}: the value {values[i]} does not fit the declared type "
                              f"{np.dtype(code).name}")
    return narrow.astype(code)


def _binary_element(body, at, name, count, props, order, path):
    """Decode ``count`` binary records of an element starting at byte ``at`` of ``body``; return
    ``(columns, end)`` (lists: ``(counts, items)``, items (count, k) when every list has k)."""
    what = f"element {show(name)}"

    def short(needed):
        return MeshFormatError(f"{path}: the binary PLY body ends inside {what} (needs at least {needed} more "
                               f"bytes, {len(body) - at} left); the file is truncated or the count is wrong")

    if count == 0:
        return {}, at
    # every list as long as the first record's: one structured dtype for all records
    layout, pos = [], at
    for j, p in enumerate(props):
        layout.append((f"s{j}", order + p[1]))
        if pos + np.dtype(p[1]).itemsize > len(body):
            raise short(pos + np.dtype(p[1]).itemsize - at)
        if len(p) == 3:
            k = max(int(np.frombuffer(body, order + p[1], 1, pos)[0]), 0)
            layout.append((f"l{j}", order + p[2], (k,)))
            pos += k * np.dtype(p[2]).itemsize
        pos += np.dtype(p[1]).itemsize
    dtype = np.dtype(layout)
    if at + count * dtype.itemsize <= len(body):
        rec = np.frombuffer(body, dtype, count, at)
        heads = [rec[f"s{j}"] for j, p in enumerate(props) if len(p) == 3]
        if all((h == h[0]).all() and h[0] >= 0 for h in heads):
            return ({p[0]: (rec[f"s{j}"].astype(np.int64), rec[f"l{j}"]) if len(p) == 3 else rec[f"s{j}"]
                     for j, p in enumerate(props)}, at + count * dtype.itemsize)
    if all(len(p) == 2 for p in props):
        raise short(count * dtype.itemsize)
    return _binary_records(body, at, count, props, order, short, what, path)


def _binary_records(body, at, count, props, order, short, what, path):
    """Records whose lists vary in length, walked one by one; ``(columns, end)``."""
    columns = {p[0]: [] for p in props}
    items = {p[0]: [] for p in props if len(p) == 3}
    pos = at
    for _ in range(count):
        for p in props:
            size = np.dtype(p[1]).itemsize
            if pos + size > len(body):
                raise short(pos + size - at)
            value = np.frombuffer(body, order + p[1], 1, pos)[0]
            pos += size
            columns[p[0]].append(value)
            if len(p) == 3:
                k, isize = int(value), np.dtype(p[2]).itemsize
                if k < 0:
                    raise MeshFormatError(f"{path}: list {show(p[0])} of {what} has a negative length {k}")
                if pos + k * isize > len(body):
                    raise short(pos + k * isize - at)
                items[p[0]].append(np.frombuffer(body, order + p[2], k, pos))
                pos += k * isize
    out = {p[0]: np.array(columns[p[0]], dtype=p[1]) for p in props}
    for p in props:
        if len(p) == 3:
            out[p[0]] = (out[p[0]].astype(np.int64), np.concatenate(items[p[0]]) if items[p[0]] else np.zeros(0, p[2]))
    return out, pos


def _mesh(found, elements, path):
    """``(V, F)`` from the decoded PLY elements ``vertex`` (x, y, z) and ``face`` (vertex_indices)."""
    declared = {e[0]: e for e in elements}
    if b"vertex" not in declared:
        raise MeshFormatError(f"{path} has no 'vertex' element; it holds no mesh")
    vprops = {p[0]: p for p in declared[b"vertex"][2]}
    for axis in (b"x", b"y", b"z"):
        if axis not in vprops or len(vprops[axis]) == 3:
            raise MeshFormatError(f"{path}: element 'vertex' has no scalar property {axis.decode()!r}; "
                                  f"vertex positions x, y, z are required")
    V = np.zeros((declared[b"vertex"][1], 3))
    for j, axis in enumerate((b"x", b"y", b"z")):
        if len(V):
            V[:, j] = found[b"vertex"][axis]
    if b"face" not in declared or declared[b"face"][1] == 0:
        raise MeshFormatError(f"{path} has no triangle faces (no 'face' elements); a triangle mesh is required")
    fprops = {p[0]: p for p in declared[b"face"][2]}
    key = next((k for k in (b"vertex_indices", b"vertex_index") if k in fprops), None)
    if key is None or len(fprops[key]) != 3 or fprops[key][2][0] not in "iu":
        raise MeshFormatError(f"{path}: element 'face' has no integer list property 'vertex_indices' "
                              f"(or 'vertex_index')")
    counts, flat = found[b"face"][key]
    if (counts < 3).any():
        i = int(np.flatnonzero(counts < 3)[0])
        raise MeshFormatError(f"{path}: face {i} has {counts[i]} vertices; a face needs at least 3 (in a "
                              f"binary file this is also what element counts that do not match the body give)")
    return V, fan(flat.astype(np.int64).reshape(-1), counts, V, path)  # one copy of a binary file's (m, k) view


def write_ply_with_uv(path, V, F, UV):
    """Write a mesh and a per-vertex map as binary little-endian PLY, all coordinates ``float64``.

    Element ``vertex`` has the ``double`` properties ``x y z u v`` (the map as the texture
    coordinates ``u v``, which MeshLab, Blender and trimesh read); element ``face`` has
    ``list uchar int vertex_indices``.  Every bit round-trips (:func:`~geomopt.io.read_mesh` reads
    ``x y z`` back exactly).  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    V : array_like, shape (n, 3)
        Vertex positions.
    F : array_like, shape (m, 3), integer
        Triangles, 0-based; ``n`` must be below 2**31 (the indices are ``int``).
    UV : array_like, shape (n, 2)
        Map coordinates, one per vertex.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Invalid ``V``, ``F`` or ``UV``, or too many vertices for 32-bit indices.
    """
    V, F, UV = mesh_with_uv(V, F, UV)
    if V.shape[0] >= 2**31:
        raise MeshError(f"{V.shape[0]} vertices do not fit PLY's 32-bit indices; write OBJ instead")
    vertex = np.empty(V.shape[0], np.dtype([(c, "<f8") for c in "xyzuv"]))
    for j, c in enumerate("xyz"):
        vertex[c] = V[:, j]
    vertex["u"], vertex["v"] = UV[:, 0], UV[:, 1]
    face = np.empty(F.shape[0], np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    face["n"], face["i"] = 3, F
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by geomopt: positions x y z, map u v\n"
        f"element vertex {V.shape[0]}\n" + "".join(f"property double {c}\n" for c in "xyzuv")
        + f"element face {F.shape[0]}\nproperty list uchar int vertex_indices\nend_header\n"
    )

    def write(fh):
        fh.write(header.encode("ascii"))
        fh.write(vertex.tobytes())
        fh.write(face.tobytes())

    return atomic_write(path, write, mode="wb")

"""VTK XML unstructured grids (``.vtu``), read exactly as the file declares them or refused.

Parsed here (the XML with the standard library): ``ascii``, inline ``binary`` (base64) and
``appended`` (``raw`` or ``base64``) data arrays, uncompressed or compressed
(``vtkZLibDataCompressor``, ``vtkLZMADataCompressor``; ``vtkLZ4DataCompressor`` when the
``lz4`` package is installed), ``UInt32``/``UInt64`` headers, either byte order, several
``Piece`` elements.  Each piece's arrays must hold exactly what its ``NumberOfPoints`` /
``NumberOfCells`` declare; cell offsets must rise, each cell holding as many points as its
type has, and use the whole connectivity; every point index must exist; every cell type must
be a VTK type (:data:`~geomopt.io._cells.VTK_CELLS`).  Point and cell data are read past.
"""

from __future__ import annotations

import base64
import binascii
import lzma
import re
import zlib
from xml.etree import ElementTree

import numpy as np

from .._runtime.errors import MeshFormatError
from ._cells import VolumeCells, vtk_blocks
from ._text import UTF8_BOM, Tokens, fits

__all__ = ["parse_vtu"]

_TYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
          "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8"}
_VERSIONS = ("0.1", "1.0", "2.0", "2.1", "2.2")
_APPENDED = re.compile(rb"<AppendedData\b[^>]*>")


class _File:
    """The file-wide settings every data array is decoded with."""

    def __init__(self, root, appended, path):
        self.path = path
        order = root.get("byte_order", "LittleEndian")
        if order not in ("LittleEndian", "BigEndian"):
            raise MeshFormatError(f"{path}: unknown byte_order {order!r} (LittleEndian or BigEndian)")
        self.order = "<" if order == "LittleEndian" else ">"
        header = root.get("header_type", "UInt32")
        if header not in ("UInt32", "UInt64"):
            raise MeshFormatError(f"{path}: unsupported header_type {header!r} (UInt32 or UInt64)")
        self.header = np.dtype(self.order + _TYPES[header])
        self.decompress = _decompressor(root.get("compressor"), path)
        self.appended = appended  # (bytes, encoding) or None


def parse_vtu(data, path):
    """The points and cells of a VTK XML unstructured grid (bytes ``data``).

    Returns
    -------
    VolumeCells
    """
    root, appended = _xml(data.removeprefix(UTF8_BOM), path)
    if root.tag != "VTKFile":
        raise MeshFormatError(f"{path}: the root element is <{root.tag}>, not <VTKFile>; it is not a VTK XML file")
    if root.get("type") != "UnstructuredGrid":
        raise MeshFormatError(f"{path}: VTKFile type {root.get('type')!r} is not an unstructured grid; only "
                              f"UnstructuredGrid .vtu files hold volume meshes")
    if root.get("version", "0.1") not in _VERSIONS:
        raise MeshFormatError(f"{path}: VTK XML file version {root.get('version')!r} is not supported "
                              f"({', '.join(_VERSIONS)})")
    file = _File(root, appended, path)
    grids = [c for c in root if c.tag == "UnstructuredGrid"]
    if len(grids) != 1 or any(c.tag not in ("UnstructuredGrid", "AppendedData") for c in root):
        raise MeshFormatError(f"{path}: a VTKFile must hold one <UnstructuredGrid> (and optionally "
                              f"<AppendedData>)")
    pieces = [c for c in grids[0] if c.tag == "Piece"]
    strange = [c.tag for c in grids[0] if c.tag not in ("Piece", "FieldData")]
    if strange or not pieces:
        raise MeshFormatError(f"{path}: <UnstructuredGrid> holds " + (f"an unexpected <{strange[0]}>"
                              if strange else "no <Piece>"))
    points, cells, base = [], [], 0
    for number, piece in enumerate(pieces, 1):
        P, C = _piece(piece, file, f"{path}, Piece {number}")
        points.append(P)
        cells += [(name, dim, None if c is None else c + base) for name, dim, c in C]
        base += len(P)
    return VolumeCells(np.concatenate(points), cells)


def _xml(data, path):
    """The XML tree and the appended data ``(bytes, encoding)`` (or ``None``)."""
    found = _APPENDED.search(data)
    appended = None
    if found is not None:
        tag = found.group()
        encoding = re.search(rb'encoding\s*=\s*"([^"]*)"', tag)
        encoding = encoding.group(1).decode(errors="replace") if encoding else "?"
        if encoding not in ("raw", "base64"):
            raise MeshFormatError(f"{path}: <AppendedData> encoding {encoding!r} is not supported (raw or base64)")
        end = data.rfind(b"</AppendedData>")
        body = data[found.end():end] if end > found.end() else b""
        start = body.find(b"_")
        if end < 0 or start < 0 or body[:start].strip():
            raise MeshFormatError(f"{path}: <AppendedData> must start with '_' and end with </AppendedData>; "
                                  f"the file is truncated or malformed")
        body = body[start + 1:]
        if encoding == "base64":
            body = b"".join(body.split())
        elif body.endswith(b"\n"):  # VTK ends the raw data with a line end before the closing tag
            body = body[:-1]
        appended = (body, encoding)
        data = data[:found.end()] + data[end:]
    try:
        return ElementTree.fromstring(data), appended
    except ElementTree.ParseError as exc:
        raise MeshFormatError(f"{path}: malformed XML ({exc}); the file is truncated or is not a VTK XML "
                              f"file") from None


def _decompressor(name, path):
    if name is None:
        return None
    if name == "vtkZLibDataCompressor":
        return lambda raw, size: zlib.decompress(raw)
    if name == "vtkLZMADataCompressor":
        return lambda raw, size: lzma.decompress(raw)
    if name == "vtkLZ4DataCompressor":
        try:
            import lz4.block
        except ImportError:
            raise MeshFormatError(f"{path} is compressed with LZ4, which needs the lz4 package (pip install lz4); "
                                  f"or re-save it with zlib or no compression") from None
        return lambda raw, size: lz4.block.decompress(raw, uncompressed_size=size)
    raise MeshFormatError(f"{path}: unknown compressor {name!r} (vtkZLibDataCompressor, vtkLZMADataCompressor, "
                          f"vtkLZ4DataCompressor)")


def _piece(piece, file, where):
    """``(points (n, 3), cells)`` of one ``Piece``, every count checked."""
    n, m = (_count(piece, key, where) for key in ("NumberOfPoints", "NumberOfCells"))
    children = {}
    for child in piece:
        if child.tag not in ("Points", "Cells", "PointData", "CellData"):
            raise MeshFormatError(f"{where}: unexpected <{child.tag}> in a Piece")
        if child.tag in children:
            raise MeshFormatError(f"{where}: two <{child.tag}> elements")
        children[child.tag] = child
    if "Points" not in children or len(children["Points"]) != 1:
        raise MeshFormatError(f"{where}: <Points> must hold exactly one DataArray")
    points = _array(children["Points"][0], file, f"{where}, Points", 3 * n, real=True, components=3)
    arrays = {}
    for a in children.get("Cells", ()):
        if a.tag != "DataArray":
            raise MeshFormatError(f"{where}: unexpected <{a.tag}> in <Cells>")
        if a.get("Name") in arrays:
            raise MeshFormatError(f"{where}: <Cells> holds two DataArrays named {a.get('Name')!r}")
        arrays[a.get("Name")] = a
    if m and not {"connectivity", "offsets", "types"} <= set(arrays):
        raise MeshFormatError(f"{where}: <Cells> needs the DataArrays connectivity, offsets and types")
    if not m:
        return points.reshape(n, 3), []
    types = _array(arrays["types"], file, f"{where}, types", m)
    offsets = _array(arrays["offsets"], file, f"{where}, offsets", m)
    conn = _array(arrays["connectivity"], file, f"{where}, connectivity", None)
    return points.reshape(n, 3), vtk_blocks(types, offsets, conn, n, where)


def _count(piece, key, where):
    text = piece.get(key, "")
    if not text.strip().isdigit():
        raise MeshFormatError(f"{where}: {key}={text!r}; a whole number >= 0 is required")
    return int(text)


def _array(element, file, where, expected, real=False, components=1):
    """The values of a ``DataArray`` (flat, int64 or float64), exactly ``expected`` of them when given."""
    if element.tag != "DataArray":
        raise MeshFormatError(f"{where}: expected a <DataArray>, found <{element.tag}>")
    kind = element.get("type")
    if kind not in _TYPES:
        raise MeshFormatError(f"{where}: unsupported data type {kind!r} ({', '.join(_TYPES)})")
    code = _TYPES[kind]
    if not real and code[0] == "f":
        raise MeshFormatError(f"{where}: indices stored as {kind}; an integer type is required")
    if (element.get("NumberOfComponents") or "1").strip() != str(components):
        raise MeshFormatError(f"{where}: the DataArray has {element.get('NumberOfComponents')} components, "
                              f"expected {components} components")
    fmt = element.get("format", "ascii")
    if fmt == "ascii":
        values = _ascii(element.text or "", code, where)
    elif fmt == "binary":
        text = "".join((element.text or "").split()).encode()
        raw, used = _base64(text, 0, file, where)
        if used != len(text):
            raise MeshFormatError(f"{where}: the binary data holds more than its header declares")
        values = _values(raw, code, file, where)
    elif fmt == "appended":
        values = _values(_appended(element, file, where), code, file, where)
    else:
        raise MeshFormatError(f"{where}: unknown DataArray format {fmt!r} (ascii, binary, appended)")
    if expected is not None and len(values) != expected:
        raise MeshFormatError(f"{where.split(', ', 1)[0]}: {where.rsplit(', ', 1)[1]} holds {len(values)} values, "
                              f"expected {expected}")
    if real and code[0] != "f" and values.size and np.abs(values.astype(np.float64)).max() > 2.0**53:
        raise MeshFormatError(f"{where}: integer coordinates beyond 2**53 cannot be read exactly as float64; "
                              f"store them as Float64")
    return values.astype(np.float64 if real else np.int64)


def _ascii(text, code, where):
    tokens = Tokens(text.encode(), where)
    dtype = np.float64 if code[0] == "f" else np.int64
    return fits(tokens.numbers(0, len(tokens), dtype, where=lambda t: where), code, where)


def _values(raw, code, file, where):
    dtype = np.dtype(file.order + code)
    if len(raw) % dtype.itemsize:
        raise MeshFormatError(f"{where}: {len(raw)} bytes is not a whole number of {dtype.name} values")
    return np.frombuffer(raw, dtype)


def _appended(element, file, where):
    if file.appended is None:
        raise MeshFormatError(f"{where}: the DataArray is appended but the file has no <AppendedData>")
    text = element.get("offset", "")
    if not text.strip().isdigit():
        raise MeshFormatError(f"{where}: offset={text!r}; a whole number >= 0 is required")
    data, encoding = file.appended
    at = int(text)
    if encoding == "base64":
        return _base64(data, at, file, where)[0]
    return _raw(data, at, file, where)


def _raw(data, at, file, where):
    """One array's bytes from raw appended ``data`` at byte ``at`` (header, then the data)."""
    h = file.header.itemsize
    items = _header_items(data[at:at + h], file, "appended", where)
    header, size = _header(_take(data, at, items * h, where), file)
    return _inflate(header, _take(data, at + items * h, size, where), file, where)


def _base64(text, at, file, where):
    """One array's bytes from base64 ``text`` at character ``at``, and where its characters end.

    VTK encodes the header and the data separately; some writers encode them together: a
    header chunk ending in ``=`` padding means the former.
    """
    h = file.header.itemsize
    hb = _header_items(_decode(text[at:at + _chars(h)], where)[:h], file, "binary", where) * h
    if at + _chars(hb) > len(text):
        raise MeshFormatError(f"{where}: the binary data ends inside this array's header; the file is truncated")
    chunk = text[at:at + _chars(hb)]
    header, size = _header(_decode(chunk, where)[:hb], file)
    if b"=" in chunk:  # header and data encoded separately
        start, end = at + _chars(hb), at + _chars(hb) + _chars(size)
        raw = _decode(text[start:end], where)
    else:
        end = at + _chars(hb + size)
        raw = _decode(text[at:end], where)[hb:]
    if len(raw) < size or end > len(text):
        raise MeshFormatError(f"{where}: the binary data ends before the {size} bytes its header declares; the "
                              f"file is truncated")
    return _inflate(header, raw[:size], file, where), end


def _header_items(first, file, what, where):
    """How many integers an array's header holds (1, or 3 + its blocks when compressed), from its first
    ``file.header`` bytes ``first``; refuses a header cut short (``what``: the data, for the message)."""
    if len(first) < file.header.itemsize:
        raise MeshFormatError(f"{where}: the {what} data ends inside this array's header; the file is truncated")
    return 1 if file.decompress is None else 3 + int(np.frombuffer(first, file.header)[0])


def _header(raw, file):
    """``(header (int64), data bytes it declares)`` of an array's header bytes ``raw``."""
    header = np.frombuffer(raw, file.header).astype(np.int64)
    return header, int(header[0]) if file.decompress is None else int(header[3:].sum())


def _chars(nbytes):
    return -(-nbytes // 3) * 4


def _decode(text, where):
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise MeshFormatError(f"{where}: the binary data is not valid base64") from None


def _take(data, at, size, where):
    if at + size > len(data):
        raise MeshFormatError(f"{where}: the appended data ends inside this array ({size} bytes declared); the "
                              f"file is truncated")
    return data[at:at + size]


def _inflate(header, raw, file, where):
    """The array's data: ``raw`` itself, or its blocks decompressed and checked against the header."""
    if file.decompress is None:
        return raw
    nblocks, block, last = (int(v) for v in header[:3])
    sizes = header[3:]
    out, at = [], 0
    for k, size in enumerate(sizes.tolist()):
        want = last if (k == nblocks - 1 and last) else block
        try:
            part = file.decompress(raw[at:at + size], want)
        except Exception:  # noqa: BLE001 -- zlib.error, lzma.LZMAError, ...: corrupt data
            raise MeshFormatError(f"{where}: compressed block {k + 1} cannot be decompressed; the file is "
                                  f"corrupt") from None
        if len(part) != want:
            raise MeshFormatError(f"{where}: compressed block {k + 1} holds {len(part)} bytes, its header says "
                                  f"{want}")
        out.append(part)
        at += size
    return b"".join(out)

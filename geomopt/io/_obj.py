"""OBJ meshes: ``v`` / ``vt`` / ``f`` statements read exactly as the file says, and written.

The statements read, ignored and refused are listed in :func:`geomopt.io.read_mesh`.  Lines are
classified and their numbers parsed by NumPy over whole sections (:mod:`geomopt.io._text`); face
corners of one regular form (all ``a``, all ``a/t``, all ``a/t/n`` or ``a//n``) are parsed at once,
any other mix corner by corner.
"""

from __future__ import annotations

import re

import numpy as np

from .._runtime.errors import MeshError, MeshFormatError
from .._runtime.validate import validate_simplices, validate_vertices
from ._atomic import atomic_write
from ._faces import fan, mesh_with_uv
from ._files import existing_file, read_input
from ._text import Tokens, gc_paused, ints, parse, ranges, show, text_data, uncomment, write_int_rows, write_rows

__all__ = ["read_obj", "parse_obj", "read_obj_polygons", "read_obj_quads", "write_obj_cells", "read_obj_uv", "read_obj_with_uv", "write_obj",
           "write_obj_quads", "write_obj_with_uv", "write_obj_polygons_with_uv"]

#: OBJ statements that carry no vertex position or face: read past.
_IGNORED = frozenset(b"vt vn vp g o s mg usemtl mtllib usemap maplib lod bevel c_interp d_interp "
                     b"shadow_obj trace_obj ctech stech l p".split())
#: OBJ free-form geometry statements: refused.
_FREEFORM = frozenset(b"cstype deg bmat step curv curv2 surf parm trim hole scrv sp end con".split())
#: One face corner: ``a``, ``a/t``, ``a//n`` or ``a/t/n``.
_CORNER_RE = re.compile(rb"(-?[0-9]+)(?:/(-?[0-9]+)|//-?[0-9]+|/(-?[0-9]+)/-?[0-9]+)?")
#: A texture index 0 (invalid) in a corner.
_ZERO_TEXTURE = re.compile(rb"(?<=[0-9])/-?0+(?=/|\s|$)")
_V, _VT, _F = 1, 2, 3


def read_obj(data, path, obj=None):
    """``(V, F)`` of an OBJ file (polygons fan-triangulated); see :func:`geomopt.io.read_mesh`
    (``obj``: the file already parsed by :func:`parse_obj`)."""
    obj = parse_obj(data, path) if obj is None else obj
    if not obj["v"].shape[0] and not obj["counts"].size:
        raise MeshFormatError(f"{path} contains no mesh (no 'v' or 'f' lines); is it really an OBJ file?")
    if not obj["counts"].size:
        raise MeshFormatError(f"{path} has no triangle faces (no 'f' lines); a triangle mesh is required")
    return obj["v"], fan(obj["corners"], obj["counts"], obj["v"], path)


def parse_obj(data, path, with_uv=False):
    """Parse the ``v``, ``f`` (and, with ``with_uv``, ``vt``) statements of an OBJ file.

    Returns a dict: ``v`` (n, 3) float64 positions; ``corners`` (c,) int64 0-based vertex
    index of each face corner (relative indices resolved); ``texcoords`` (c,) int64 0-based
    texture index of each corner, -1 where the corner has none, -2 where it is relative;
    ``counts`` (f,) corners per face; ``lines`` (f,) line number of each face; and with
    ``with_uv`` ``vt`` (k, 2) float64.  Raises MeshFormatError naming the line of any malformed
    statement.
    """
    text = uncomment(text_data(data, path, "OBJ file"))
    if b"\\\n" in text or text.endswith(b"\\"):
        text = b"\n".join(_join_continued(text.split(b"\n")))
    rows = Tokens(text, path).rows()
    kind = _statements(rows)
    v_rows, f_rows = np.flatnonzero(kind == _V), np.flatnonzero(kind == _F)
    out = {"v": _numbers(rows, v_rows, "v", (3, 4, 6), "x y z (optionally w, or r g b)")[0]}
    if with_uv:
        vt_rows = np.flatnonzero(kind == _VT)
        out["vt"], w = _numbers(rows, vt_rows, "vt", (2, 3), "u v (optionally w)")
        if (w != 0).any():  # a non-planar map: dropping w would read it inexactly
            r = vt_rows[np.flatnonzero(w != 0)[0]]
            raise MeshFormatError(f"{path}, line {rows.lineno[r]}: 'vt' line has a third coordinate w = "
                                  f"{show(rows.tokens.text(rows.first[r] + 3))}; a planar map needs 'vt u v' "
                                  f"(or w = 0)")
    counts = rows.count[f_rows] - 1
    short = np.flatnonzero(counts < 3)
    if short.size:
        raise MeshFormatError(f"{path}, line {rows.lineno[f_rows[short[0]]]}: face has {counts[short[0]]} "
                              f"corner(s); a face needs at least 3")
    seen = np.searchsorted(v_rows, f_rows)  # the 'v' lines before each face
    out.update(_faces(rows.tokens, ranges(rows.first[f_rows] + 1, counts), counts, rows.lineno[f_rows], seen,
                      len(v_rows), path))
    return out


def _statements(rows):
    """The statement of every row: ``_V``, ``_VT``, ``_F`` or 0 (read past); refuses unknown ones."""
    tokens = rows.tokens
    start = tokens.start[rows.first]
    length = tokens.end[rows.first] - start
    raw = np.frombuffer(tokens.data, np.uint8)
    second = raw[np.minimum(start + 1, len(raw) - 1)]
    v = rows.head == ord("v")
    kind = np.where(v & (length == 1), _V, 0)
    kind[v & (length == 2) & (second == ord("t"))] = _VT
    kind[(rows.head == ord("f")) & (length == 1)] = _F
    known = (kind > 0) | (v & (length == 2) & (second == ord("n")))
    for r in np.flatnonzero(~known).tolist():
        key = rows.key(r)
        if key in _FREEFORM:
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[r]}: free-form geometry ({show(key)}) is not "
                                  f"supported; export the surface as polygons")
        if key not in _IGNORED:
            raise MeshFormatError(f"{rows.path}, line {rows.lineno[r]}: unknown OBJ statement {show(key)}; "
                                  f"is it really an OBJ file?")
    return kind


def _numbers(rows, at, key, allowed, expected):
    """``(positions (len(at), min(allowed)) float64, the number after them or 0)`` of the ``key``
    statements on rows ``at``, each with ``allowed`` numbers."""
    n = rows.count[at] - 1
    bad = np.flatnonzero(~np.isin(n, allowed))
    if bad.size:
        raise MeshFormatError(f"{rows.path}, line {rows.lineno[at[bad[0]]]}: '{key}' line has {n[bad[0]]} "
                              f"numbers; expected '{key} {expected}'")
    values = rows.tokens.numbers_at(ranges(rows.first[at] + 1, n), np.float64)
    first, width = np.cumsum(n) - n, min(allowed)
    after = values[np.minimum(first + width, len(values) - 1)] if len(values) else values
    return values[first[:, None] + np.arange(width)], np.where(n > width, after, 0.0)


def _join_continued(lines):
    """Join lines ending in a backslash with the next; keep the numbering (blank placeholders)."""
    out, held = [], []
    for line in lines:
        if line.endswith(b"\\"):
            held.append(line[:-1])
            out.append(b"")
            continue
        if held:
            out[len(out) - len(held)] = b" ".join(held + [line])
            held = []
            out.append(b"")
        else:
            out.append(line)
    if held:
        out[len(out) - len(held)] = b" ".join(held)
    return out


def _faces(tokens, index, counts, face_lines, seen, n_vertices, path):
    """Vertex and texture indices of the face corners (tokens ``index``); see :func:`parse_obj`.

    ``counts`` (f,) corners per face, ``face_lines`` (f,) their line numbers, ``seen`` (f,) the
    number of ``v`` lines before each face (for relative indices), ``n_vertices`` the number of
    ``v`` lines.
    """
    empty = np.zeros(0, dtype=np.int64)
    if not counts.size:
        return {"corners": empty, "texcoords": empty, "counts": empty, "lines": empty}
    line_of = np.repeat(face_lines, counts)
    regular = _regular_corners(tokens.gather(index), len(index))
    if regular is not None:
        raw, tex, has_tex = regular
    else:
        with gc_paused():
            raw, tex, has_tex = _each_corner([tokens.text(t) for t in index.tolist()], line_of, path)
    zero = np.flatnonzero(has_tex & (tex == 0))
    if zero.size:
        i = int(zero[0])
        raise MeshFormatError(f"{path}, line {line_of[i]}: face corner {show(tokens.text(index[i]))} has texture "
                              f"index 0 (OBJ indices start at 1)")
    seen = np.repeat(seen, counts)
    corner = np.where(raw > 0, raw - 1, seen + raw)
    for bad, why in (
        (raw == 0, "index 0 (OBJ indices start at 1)"),
        ((raw < 0) & (corner < 0), "a relative (negative) index reaching before the first vertex"),
        (raw > n_vertices, f"a vertex beyond the file's {n_vertices} 'v' lines"),
    ):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            error = MeshError if raw[i] > n_vertices else MeshFormatError
            raise error(f"{path}, line {line_of[i]}: face corner {show(tokens.text(index[i]))} refers to {why}")
    tex = np.where(~has_tex, -1, np.where(tex > 0, tex - 1, -2))  # -1: none; -2: relative
    return {"corners": corner, "texcoords": tex, "counts": counts, "lines": face_lines}


def _regular_corners(text, count):
    """``(vertex, texture, has texture)`` indices of ``count`` whitespace-separated corners (``text``)
    if all have one form, ``a``, ``a/t``, ``a/t/n`` or ``a//n`` (texture index 0 where absent), and
    every index is a plain integer; else ``None`` (the corners are then read one by one)."""
    slashes = text.count(b"/")
    k = slashes // count
    if slashes % count or k > 2 or (b"//" in text and (k != 2 or _ZERO_TEXTURE.search(text))):
        return None
    if k:
        b = np.frombuffer(text, np.uint8)
        space = (b == 32) | ((b - 9) <= 4)
        separator = b[(b == 47) | (space & np.r_[True, ~space[:-1]])] == 47  # '/', or a run of whitespace
        if len(separator) != count * (k + 1) - 1 or \
                not (np.r_[separator, False].reshape(count, k + 1) == (np.arange(k + 1) < k)).all():
            return None
    values = parse(text.replace(b"//", b"/0/").replace(b"/", b" "), np.int64)
    if values is None or len(values) != count * (k + 1):
        return None
    values = values.reshape(count, k + 1)
    tex = values[:, 1] if k else np.zeros(count, dtype=np.int64)
    return values[:, 0], tex, (tex != 0) if b"//" in text else np.full(count, k > 0)


def _each_corner(corners, line_of, path):
    """``(vertex, texture, has texture)`` indices of the corner tokens ``corners``, one by one."""
    matches = [_CORNER_RE.fullmatch(c) for c in corners]
    bad = next((i for i, m in enumerate(matches) if m is None), None)
    if bad is not None:
        raise MeshFormatError(f"{path}, line {line_of[bad]}: cannot read face corner {show(corners[bad])}; "
                              f"expected 'a', 'a/t', 'a//n' or 'a/t/n' with whole numbers (1-based)")
    groups = [m.groups() for m in matches]
    raw = ints([g[0] for g in groups], lambda i: f"{path}, line {line_of[i]}")
    texts = [g[1] or g[2] for g in groups]
    has_tex = np.array([t is not None for t in texts], dtype=bool)
    tex = np.zeros(len(corners), dtype=np.int64)
    present = np.flatnonzero(has_tex)
    tex[present] = ints([texts[i] for i in present], lambda i: f"{path}, line {line_of[present[i]]}")
    return raw, tex, has_tex


def _read(path, with_uv=False):
    """:func:`parse_obj` of the OBJ file at ``path`` (checked to exist, not empty)."""
    path, data = read_input(path, "OBJ file")
    return path, parse_obj(data, path, with_uv=with_uv)


def read_obj_quads(path):
    """Read a quad mesh from an OBJ file: ``v`` and ``f`` lines as :func:`~geomopt.io.read_mesh` reads
    them, every face with exactly four corners (kept as quads, not triangulated).

    Returns
    -------
    V : (n, 3) float64;  Q : (m, 4) int64 quads, 0-based, in file order.

    Raises
    ------
    MeshFormatError
        As :func:`~geomopt.io.read_mesh`, or a face that is not a quad (mixed triangles and quads
        are not supported: split or merge them first).
    MeshError
        Non-finite coordinates, indices out of range, a quad repeating a vertex.
    """
    path, obj = _read(path)
    counts = obj["counts"]
    if not counts.size:
        raise MeshFormatError(f"{path} has no faces (no 'f' lines); a quad mesh is required")
    bad = np.flatnonzero(counts != 4)
    if bad.size:
        raise MeshFormatError(f"{path}, line {obj['lines'][bad[0]]}: a face with {counts[bad[0]]} corners; every "
                              f"face of a quad mesh has 4 ({bad.size} do not; mixed meshes are not supported)")
    V = validate_vertices(obj["v"], f"{path.name}: vertices", dim=3)
    Q = validate_simplices(obj["corners"].reshape(-1, 4), V.shape[0], 4, f"{path.name}: quads",
                           words=("quad", "quads"))
    return V, Q


def read_obj_polygons(path):
    """Read an OBJ surface keeping its faces as the file gives them: triangles, quads and larger
    polygons, mixed (``v`` and ``f`` lines as :func:`~geomopt.io.read_mesh` reads them).

    Returns
    -------
    V : (n, 3) float64;  faces : each face's 0-based corners in file order: an (m, k) int64
    array when every face has ``k`` corners (a triangle or quad mesh), else a list of (k_j,)
    int64 arrays.  ``fan_triangulate(corners, counts)`` of their corners and counts gives
    :func:`~geomopt.io.read_mesh`'s triangles.

    Raises
    ------
    MeshFormatError, MeshError
        As :func:`~geomopt.io.read_mesh` (a non-convex polygon, whose fan folds, included).
    """
    path, obj = _read(path)
    V, F = read_obj(b"", path, obj)
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    validate_simplices(F, V.shape[0], 3, f"{path.name}: faces")
    counts = obj["counts"]
    if (counts == counts[0]).all():
        return V, obj["corners"].reshape(-1, int(counts[0]))
    return V, np.split(obj["corners"], np.cumsum(counts)[:-1])


def read_obj_uv(path):
    """Read an OBJ mesh and its UV map (``vt``) as one map position per vertex.

    The file is read as :func:`~geomopt.io.read_mesh` reads it; the UV of a vertex is the ``vt``
    of its face corners, which must all carry a texture index and agree on the vertex's position
    bit for bit (one ``vt`` per vertex, or per corner where they agree).  A map cut along
    seams (a vertex with two different UVs) is refused: it is not a map of this mesh.

    Returns
    -------
    V : (n, 3) float64;  F : (m, 3) int64;  UV : (n, 2) float64.

    Raises
    ------
    MeshFormatError
        No ``vt`` lines, a corner without a texture index, a relative or out-of-range
        texture index, a vertex used by no face, or a vertex with two different UVs.
    """
    path = existing_file(path, "OBJ file")
    if path.suffix.lower() != ".obj":
        raise MeshFormatError(f"{path}: a UV start map is read from an OBJ file's 'vt' lines; got "
                              f"{path.suffix!r}")
    path, obj = _read(path, with_uv=True)
    if not obj["counts"].size:
        raise MeshFormatError(f"{path} has no triangle faces (no 'f' lines); a triangle mesh is required")
    V, vt, corner, tex = obj["v"], obj["vt"], obj["corners"], obj["texcoords"]
    if not vt.shape[0]:
        raise MeshFormatError(f"{path} has no 'vt' lines: it carries no UV map to start from")
    lines = np.repeat(obj["lines"], obj["counts"])
    for bad, why in ((tex == -1, "has no texture index (write corners as 'a/t')"),
                     (tex == -2, "has a relative (negative) texture index"),
                     (tex >= vt.shape[0], f"refers to a 'vt' beyond the file's {vt.shape[0]}")):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise MeshFormatError(f"{path}, line {lines[i]}: a face corner {why}")
    UV = np.zeros((V.shape[0], 2))
    UV[corner] = vt[tex]
    used = np.zeros(V.shape[0], dtype=bool)
    used[corner] = True
    differ = np.flatnonzero((vt[tex].view(np.uint64) != UV[corner].view(np.uint64)).any(axis=1))
    if differ.size:
        v = int(corner[differ[0]])
        raise MeshFormatError(
            f"{path}: vertex {v + 1} has two different UVs (line {lines[differ[0]]}; {np.unique(corner[differ]).size} "
            f"vertices in all): the UV map is cut along seams, so it is not one map of this mesh; "
            f"weld the seams or start from --init tutte / projection")
    unused = np.flatnonzero(~used)
    if unused.size:
        raise MeshFormatError(f"{path}: {unused.size} vertices are used by no face (first: {unused[0] + 1}); "
                              f"remove unreferenced vertices")
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    F = validate_simplices(fan(corner, obj["counts"], V, path), V.shape[0], 3, f"{path.name}: faces")
    return V, F, validate_vertices(UV, f"{path.name}: UV map", dim=2)


def read_obj_with_uv(path):
    """Read the OBJ layout :func:`write_obj_with_uv` writes: one ``vt`` per ``v``, faces ``a/a b/b c/c``.

    This is the LIM 2D ``input.obj`` layout.  The statements, numbers and text conventions
    are those of :func:`~geomopt.io.read_mesh`, plus: exactly one ``vt u v`` per ``v`` line, in the
    same order; ``f`` lines with exactly 3 corners ``a``, ``a/a``, ``a/a/n`` or ``a//n`` (1-based,
    absolute: a texture index must equal its vertex index).

    Parameters
    ----------
    path : str or os.PathLike
        The OBJ file.

    Returns
    -------
    V : numpy.ndarray, shape (n, 3), float64
        The ``v`` positions, in file order.
    UV : numpy.ndarray, shape (n, 2), float64
        The ``vt`` positions: one map position per vertex.
    F : numpy.ndarray, shape (m, 3), int64
        Triangles, 0-based.

    Raises
    ------
    MeshFormatError
        Malformed statement or number (with line number), non-triangle or relative
        (negative) face, ``vt`` count differing from ``v`` count, texture index differing
        from vertex index.
    MeshError
        Non-finite values, face indices out of range, repeated vertices in a face.
    """
    path, obj = _read(path, with_uv=True)
    V, UV, counts, lines = obj["v"], obj["vt"], obj["counts"], obj["lines"]
    if not V.shape[0]:
        raise MeshFormatError(f"{path} has no 'v' lines; it is not a LIM input.obj")
    if not counts.size:
        raise MeshFormatError(f"{path} has no 'f' lines; a triangle mesh is required")
    if (counts != 3).any():
        i = int(np.flatnonzero(counts != 3)[0])
        raise MeshFormatError(f"{path}, line {lines[i]}: face has {counts[i]} corners; only triangles are "
                              f"supported (triangulate the mesh first)")
    face_lines, raw, tex = np.repeat(lines, 3), obj["corners"], obj["texcoords"]
    if (tex == -2).any():
        i = int(np.flatnonzero(tex == -2)[0])
        raise MeshFormatError(f"{path}, line {face_lines[i]}: a relative (negative) texture index; a LIM "
                              f"input.obj needs texture index == vertex index")
    bad = np.flatnonzero((tex >= 0) & (tex != raw))
    if bad.size:
        i = int(bad[0])
        raise MeshFormatError(f"{path}, line {face_lines[i]}: face corner uses texture index {tex[i] + 1} for "
                              f"vertex {raw[i] + 1}; a LIM input.obj needs texture index == vertex index")
    if UV.shape[0] != V.shape[0]:
        raise MeshFormatError(
            f"{path} has {V.shape[0]} 'v' lines but {UV.shape[0]} 'vt' lines; a LIM input.obj "
            f"needs exactly one 'vt' (initial map position) per vertex"
        )
    return (validate_vertices(V, f"{path}: 'v' positions", dim=3),
            validate_vertices(UV, f"{path}: 'vt' positions", dim=2),
            validate_simplices(raw.reshape(-1, 3), V.shape[0], 3, f"{path}: faces"))


def write_obj(path, V, F):
    """Write a triangle mesh as OBJ (``v x y z``, ``f a b c``), full precision, atomic;
    :func:`~geomopt.io.read_mesh` reads it back bit for bit."""
    V = validate_vertices(V, "V", dim=3)
    F = validate_simplices(F, V.shape[0], 3, "F")

    def write(fh):
        write_rows(fh, "v ", V)
        write_int_rows(fh, "f %d %d %d", F + 1)

    return atomic_write(path, write)


def write_obj_quads(path, V, Q):
    """Write a quad mesh as OBJ (``v x y z`` with ``z = 0`` for 2D vertices, ``f a b c d``),
    full precision, atomic; :func:`read_obj_quads` reads it back bit for bit."""
    V = validate_vertices(V, "V")
    V = np.column_stack([V, np.zeros(len(V))]) if V.shape[1] == 2 else V
    Q = validate_simplices(Q, V.shape[0], 4, "Q", words=("quad", "quads"))

    def write(fh):
        write_rows(fh, "v ", V)
        write_int_rows(fh, "f %d %d %d %d", Q + 1)

    return atomic_write(path, write)


def write_obj_cells(path, V, C, kind):
    """:func:`write_obj_quads` as a writer of the cell-format table (``kind`` is ``"quad"``)."""
    return write_obj_quads(path, V, C)


def write_obj_polygons_with_uv(path, V, faces, UV, uv_faces):
    """Write an atlas of a polygon mesh as OBJ: ``v`` lines, one ``vt`` per UV row, and one
    ``f a/ta b/tb ...`` line per face with as many corners as it has.  Atomic.

    Parameters
    ----------
    V : (n, 3) vertex positions.
    faces : list of (k_j,) int 0-based corner vertices of each face (k_j >= 3).
    UV : (k, 2) texture coordinates.
    uv_faces : list of (k_j,) int the UV row of each face corner.
    """
    V = validate_vertices(V, "V", dim=3)
    UV = validate_vertices(UV, "UV", dim=2)
    counts = np.array([len(f) for f in faces], dtype=np.int64)
    if len(uv_faces) != len(faces) or any(len(t) != k for t, k in zip(uv_faces, counts)):
        raise MeshError("uv_faces must give one UV row per corner of every face")
    corners = np.concatenate([np.asarray(f, dtype=np.int64) for f in faces])
    texture = np.concatenate([np.asarray(t, dtype=np.int64) for t in uv_faces])
    for name, I, n in (("faces", corners, len(V)), ("uv_faces", texture, len(UV))):
        if I.size and (I.min() < 0 or I.max() >= n):
            raise MeshError(f"{name} index rows outside 0..{n - 1}")

    def write(fh):
        write_rows(fh, "v ", V)
        write_rows(fh, "vt ", UV)
        fmt = "".join("f" + " %d/%d" * k + "\n" for k in counts.tolist())
        fh.write(fmt % tuple(np.stack([corners + 1, texture + 1], axis=1).ravel().tolist()))

    return atomic_write(path, write)


def write_obj_with_uv(path, V, F, UV, uv_faces=None):
    """Write a mesh and a per-vertex map as OBJ: ``v`` lines, one ``vt`` per vertex, ``f a/a b/b c/c``;
    or, with ``uv_faces``, an atlas: one ``vt`` per UV row and ``f a/ta b/tb c/tc``.

    This is the LIM 2D ``input.obj`` layout, so :func:`read_obj_with_uv` reads it back
    exactly.  Numbers are written in their shortest exact (round-trip) form.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    V : array_like, shape (n, 3)
        Vertex positions (``v`` lines, in this order).
    F : array_like, shape (m, 3), integer
        Triangles, 0-based (written 1-based).
    UV : array_like, shape (n, 2) or, with ``uv_faces``, (k, 2)
        Map / texture coordinates, one per vertex (``vt`` lines), or one per UV row.
    uv_faces : None or array_like, shape (m, 3), integer
        The UV row of each face corner (0-based), for a map cut along seams (an atlas).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Invalid ``V``, ``F``, ``UV`` or ``uv_faces``, or ``UV`` not one row per vertex
        (without ``uv_faces``).
    """
    if uv_faces is None:
        V, F, UV = mesh_with_uv(V, F, UV)
        T = F
    else:
        V, F, UV, T = mesh_with_uv(V, F, UV, uv_faces)

    def write(fh):
        write_rows(fh, "v ", V)
        write_rows(fh, "vt ", UV)
        write_int_rows(fh, "f %d/%d %d/%d %d/%d", np.stack([F + 1, T + 1], axis=2).reshape(-1, 6))

    return atomic_write(path, write)

"""Surface meshes: OBJ, OFF, PLY and STL read exactly as the file says; meshes with a UV map written.

Every reader returns plain numpy arrays (coordinates ``float64``, indices ``int64``,
0-based) holding exactly what the file says (see :func:`read_mesh`); the writers keep every
``float64`` bit and write atomically (:mod:`geomopt.io._atomic`).
"""

from __future__ import annotations

import re

import numpy as np

from .._errors import GeomoptError, MeshError, MeshFormatError
from .._validate import validate_simplices, validate_vertices
from ._atomic import atomic_write, check_output_path
from ._files import check_not_empty, existing_file, read_bytes
from ._text import (INT_RE, UTF8_BOM, first_bad, floats, gc_paused, ints, plain_ints, show, text_data, text_rows,
                    write_int_rows, write_rows)

__all__ = ["MESH_EXTENSIONS", "UV_MESH_EXTENSIONS", "read_mesh", "read_obj_uv", "read_obj_with_uv",
           "write_mesh_with_uv", "write_obj_with_uv", "write_ply_with_uv", "read_obj_quads", "write_obj_quads"]

#: File extensions :func:`read_mesh` accepts (lower case).
MESH_EXTENSIONS = (".obj", ".off", ".ply", ".stl")

#: File extensions :func:`write_mesh_with_uv` writes (formats that carry one map coordinate per vertex).
UV_MESH_EXTENSIONS = (".obj", ".ply")


# -------------------------------------------------------------------- read_mesh


def read_mesh(path):
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file, exactly as the file says it.

    Each format is parsed here (no third-party loader), strictly:

    * **OBJ**: ``v x y z`` lines (an optional ``w`` or ``r g b`` after the position is
      checked as numbers and ignored), ``f`` lines with corners ``a``, ``a/t``, ``a/t/n``
      or ``a//n`` (1-based; negative indices count back from the last ``v`` line before
      the face, as the format defines).  Polygons are fan-triangulated: a face
      ``a b c d ...`` gives ``(a, b, c), (a, c, d), ...``; a polygon whose fan would fold
      (non-convex or twisted) is refused.  Attribute and grouping
      statements (``vt``, ``vn``, ``g``, ``o``, ``s``, ``usemtl``, ``mtllib``, ``l``, ``p``,
      ...) are ignored; free-form geometry and unknown statements are refused.  ``#``
      starts a comment; a line ending in ``\\`` continues on the next.
    * **OFF** (``OFF``, ``COFF``, ``NOFF``, ``STOFF`` ...): the header's vertex and face
      counts must match the body exactly (one vertex or face per line); a face line
      ``k i1 .. ik`` may end with up to 4 colour numbers.  Polygons are fan-triangulated.
    * **PLY** (ASCII, binary little- and big-endian): the header is validated (format,
      element counts, property types); the body must hold exactly the declared elements
      (ASCII: one element per line; binary: the exact byte count).  Vertices come from
      ``x y z`` of element ``vertex`` (``float`` properties are float32, as declared),
      faces from the list ``vertex_indices`` (or ``vertex_index``) of element ``face``,
      fan-triangulated.  Other elements and properties are read past and ignored.
    * **STL** (ASCII or binary): STL stores every triangle with its own three corners, so
      corners with equal coordinates (-0.0 = 0.0) are **welded** into one vertex (numbered in
      order of first appearance); without welding no STL mesh is connected.  Binary STL
      stores float32.  A file holding several ``solid`` blocks is refused.

    The text conventions (byte-order mark, line ends, number syntax) are in the module
    notes.  Degenerate content is left to :func:`validate_vertices` and
    :func:`validate_simplices`.

    Parameters
    ----------
    path : str or os.PathLike
        Mesh file with extension ``.obj``, ``.off``, ``.ply`` or ``.stl`` (any case).

    Returns
    -------
    V : numpy.ndarray, shape (n, 3), float64
        Vertex positions, in file order (unreferenced vertices included).
    F : numpy.ndarray, shape (m, 3), int64
        Triangles, 0-based vertex indices, in file order.

    Raises
    ------
    MeshFormatError
        Missing, not a regular file, empty, unsupported extension, malformed (the message
        names the problem and, for text, the line), counts that differ from the header,
        or no triangle faces.
    MeshError
        NaN/infinite coordinates, face indices out of range, repeated vertices in a face.
    """
    path = existing_file(path, "mesh file")
    ext = path.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise MeshFormatError(
            f"mesh file {path} has unsupported extension {path.suffix!r}; supported: "
            f"{', '.join(MESH_EXTENSIONS)} (convert it, e.g. with meshio or MeshLab)"
        )
    check_not_empty(path, "mesh file")
    data = read_bytes(path, "mesh file")
    reader = {".obj": _read_obj, ".off": _read_off, ".ply": _read_ply, ".stl": _read_stl}[ext]
    with gc_paused():
        V, F = reader(data, path)
    V = validate_vertices(V, f"{path.name}: vertices", dim=3)
    F = validate_simplices(F, V.shape[0], 3, f"{path.name}: faces")
    return V, F


def _fan(indices, counts, V=None, path=None):
    """Fan-triangulate polygons given as flat corner ``indices`` (int64) and per-polygon ``counts`` (>= 3).

    Returns (sum(counts - 2), 3) int64: polygon ``c0 c1 .. ck`` gives ``(c0, ci, ci+1)``.  With
    the vertex positions ``V``, a polygon whose fan folds (a fan triangle facing against the
    polygon's Newell normal: a non-convex or twisted polygon) is refused, because the triangles
    would not tile the polygon.
    """
    counts = np.asarray(counts, dtype=np.int64)
    if counts.size and (counts == 3).all():
        return indices.reshape(-1, 3)
    starts = np.cumsum(counts) - counts
    ntri = counts - 2
    first = np.repeat(starts, ntri)
    local = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    F = np.stack([indices[first], indices[first + local + 1], indices[first + local + 2]], axis=1)
    if V is not None and indices.size and 0 <= indices.min() and indices.max() < len(V):
        _check_fans(np.asarray(V, np.float64), indices, counts, F, np.repeat(np.arange(counts.size), ntri), path)
    return F


def _check_fans(V, indices, counts, F, owner, path):
    """Refuse polygons (``counts > 3``) whose fan triangles ``F`` (polygon ``owner``) fold."""
    P = np.zeros((V.shape[0], 3))
    P[:, :V.shape[1]] = V
    poly = np.repeat(np.arange(counts.size), counts)
    nxt = np.arange(indices.size) + 1
    nxt[np.cumsum(counts) - 1] = np.cumsum(counts) - counts  # each polygon closes on its first corner
    normal = np.zeros((counts.size, 3))
    np.add.at(normal, poly, np.cross(P[indices], P[indices[nxt]]))  # Newell's normal (twice the area)
    tri = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    bad = (np.einsum("ij,ij->i", tri, normal[owner]) <= 0) & (counts[owner] > 3)
    if bad.any():
        k = int(owner[np.flatnonzero(bad)[0]])
        raise MeshFormatError(
            f"{path}: face {k + 1} is a polygon of {counts[k]} corners that is not convex (or is twisted): "
            f"cutting it into a fan of triangles folds it; triangulate the mesh before reading it")


# ------------------------------------------------------------------------- OBJ

#: OBJ statements that carry no vertex position or face: read past.
_OBJ_IGNORED = frozenset(b"vt vn vp g o s mg usemtl mtllib usemap maplib lod bevel c_interp d_interp "
                         b"shadow_obj trace_obj ctech stech l p".split())
#: OBJ free-form geometry statements: refused.
_OBJ_FREEFORM = frozenset(b"cstype deg bmat step curv curv2 surf parm trim hole scrv sp end con".split())
#: One face corner: ``a``, ``a/t``, ``a//n`` or ``a/t/n``.
_CORNER = rb"(-?[0-9]+)(?:/(-?[0-9]+)|//-?[0-9]+|/(-?[0-9]+)/-?[0-9]+)?"
_CORNER_RE = re.compile(_CORNER)
#: Space-separated corners (the ``f`` corners of a file joined by single spaces).
_CORNERS_RE = re.compile(_CORNER + rb"(?: " + _CORNER + rb")*")
_CORNER_FIND_RE = re.compile(rb"(?:^| )" + _CORNER)
#: First two (three) bytes of the lines whose first word is known without splitting them.
_OBJ_HEADS = {b"v ": b"v", b"v\t": b"v", b"f ": b"f", b"f\t": b"f", b"": b""}
_OBJ_HEADS3 = {b"vt ": b"vt", b"vt\t": b"vt"}


def _parse_obj(data, path, with_uv=False):
    """Parse the ``v``, ``f`` (and, with ``with_uv``, ``vt``) statements of an OBJ file.

    Returns a dict: ``v`` (n, 3) float64 positions; ``corners`` (c,) int64 0-based vertex
    index of each face corner (relative indices resolved); ``texcoords`` (c,) int64 0-based
    texture index of each corner or -1 where the corner has none; ``counts`` (f,) corners
    per face; ``lines`` (f,) line number of each face; and with ``with_uv`` ``vt`` (k, 2)
    float64.  Raises MeshFormatError naming the line of any malformed statement.
    """
    text = text_data(data, path, "OBJ file")
    lines = text.split(b"\n")
    if b"\\\n" in text or text.endswith(b"\\"):
        lines = _join_continued(lines)
    if b"#" in text:
        lines = [line.split(b"#", 1)[0] if b"#" in line else line for line in lines]
    # the first word of every line (b"" for a blank one); 'v ', 'f ' and 'vt ' lines are
    # recognised by their first bytes, any other line is split
    keys = [_OBJ_HEADS.get(line[:2]) or _OBJ_HEADS3.get(line[:3]) or (line.split(None, 1) or [b""])[0]
            for line in lines]
    strange = set(keys) - _OBJ_IGNORED - {b"v", b"f", b"vt", b""}
    if strange:
        lineno, key = next((i + 1, k) for i, k in enumerate(keys) if k in strange)
        if key in _OBJ_FREEFORM:
            raise MeshFormatError(f"{path}, line {lineno}: free-form geometry ({show(key)}) is not "
                                  f"supported; export the surface as polygons")
        raise MeshFormatError(f"{path}, line {lineno}: unknown OBJ statement {show(key)}; "
                              f"is it really an OBJ file?")
    v_at = [i for i, k in enumerate(keys) if k == b"v"]
    f_at = [i for i, k in enumerate(keys) if k == b"f"]
    numbers = _statement_words(lines, v_at, b"v", 3)  # the common 'v x y z' lines all at once
    if numbers is not None:
        V = floats(numbers, lambda i: f"{path}, line {v_at[i // 3] + 1}").reshape(-1, 3)
    else:
        V = _obj_numbers([(i + 1, lines[i].split()) for i in v_at], path, "v", (3, 4, 6),
                         "x y z (optionally w, or r g b)")[:, :3]
    out = {"v": V}
    if with_uv:
        vt_at = [i for i, k in enumerate(keys) if k == b"vt"]
        numbers = _statement_words(lines, vt_at, b"vt", 2)  # the common 'vt u v' lines all at once
        if numbers is not None:
            out["vt"] = floats(numbers, lambda i: f"{path}, line {vt_at[i // 2] + 1}").reshape(-1, 2)
        else:
            rows = [(i + 1, lines[i].split()) for i in vt_at]
            out["vt"] = _obj_numbers(rows, path, "vt", (2, 3), "u v (optionally w)")[:, :2]
            _planar_vt(rows, path)
    seen = np.searchsorted(np.array(v_at, dtype=np.int64), np.array(f_at, dtype=np.int64))  # 'v' lines before
    face_lines = np.array(f_at, dtype=np.int64) + 1
    corners = _statement_words(lines, f_at, b"f", 3)  # triangles all at once
    if corners is not None:
        counts = np.full(len(f_at), 3, dtype=np.int64)
    else:
        rows = [lines[i].split() for i in f_at]
        counts = np.array([len(t) - 1 for t in rows], dtype=np.int64)
        short = np.flatnonzero(counts < 3)
        if short.size:
            raise MeshFormatError(f"{path}, line {face_lines[short[0]]}: face has {counts[short[0]]} "
                                  f"corner(s); a face needs at least 3")
        corners = [c for t in rows for c in t[1:]]
    out.update(_obj_faces(corners, counts, face_lines, seen, len(v_at), path))
    return out


def _planar_vt(rows, path):
    """Refuse a ``vt u v w`` line (valid numbers) whose ``w`` is not 0: the map it belongs to
    is planar, and dropping ``w`` would read it inexactly."""
    for lineno, words in rows:
        if len(words) == 4 and float(words[3]) != 0.0:
            raise MeshFormatError(f"{path}, line {lineno}: 'vt' line has a third coordinate w = "
                                  f"{show(words[3])}; a planar map needs 'vt u v' (or w = 0)")


def _statement_words(lines, at, key, width):
    """The words after ``key`` of ``lines[i] for i in at`` if every one has exactly ``width``, else ``None``.

    One split of the joined lines: with ``n`` lines, ``n * (width + 1)`` words of which exactly
    ``n`` are ``key``, all at multiples of ``width + 1``, means every line has ``width`` words
    after its ``key`` (a line of another length would put a ``key`` off that grid).
    """
    words = b"\n".join([lines[i] for i in at]).split()
    n, step = len(at), width + 1
    if len(words) != n * step or words.count(key) != n or words[0::step].count(key) != n:
        return None
    del words[0::step]
    return words


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


def _obj_numbers(rows, path, key, allowed, expected):
    """(len(rows), min(allowed)) float64 from ``key`` statements with ``allowed`` numbers each."""
    width = min(allowed)
    if not rows:
        return np.zeros((0, width))
    sizes = [len(t) - 1 for _, t in rows]
    for (lineno, _), size in zip(rows, sizes):
        if size not in allowed:
            raise MeshFormatError(f"{path}, line {lineno}: '{key}' line has {size} numbers; expected "
                                  f"'{key} {expected}'")
    flat = [x for _, t in rows for x in t[1:]]
    starts = np.cumsum([0] + sizes)

    def where(i):
        return f"{path}, line {rows[int(np.searchsorted(starts, i, side='right')) - 1][0]}"

    values = floats(flat, where)
    if len(set(sizes)) == 1:
        return values.reshape(len(rows), -1)[:, :width]
    return np.stack([values[s:s + width] for s in starts[:-1]])


def _obj_faces(corners, counts, face_lines, seen, n_vertices, path):
    """Vertex and texture indices of face corners; see :func:`_parse_obj`.

    ``corners`` are the corner tokens of all faces in order, ``counts`` (f,) corners per
    face, ``face_lines`` (f,) their line numbers, ``seen`` (f,) the number of ``v`` lines
    before each face (for relative indices), ``n_vertices`` the number of ``v`` lines.
    """
    empty = np.zeros(0, dtype=np.int64)
    if not counts.size:
        return {"corners": empty, "texcoords": empty, "counts": empty, "lines": empty}
    line_of = np.repeat(face_lines, counts)
    joined = b" ".join(corners)

    def where(i):
        return f"{path}, line {line_of[i]}"

    raw = None if b"/" in joined else plain_ints(corners, joined)  # the common case: 'f a b c'
    has_tex = np.zeros(len(corners), dtype=bool)
    pairs = None if raw is not None else _slash_pairs(joined, len(corners))  # the next: 'f a/t b/t c/t'
    if pairs is not None:
        raw, texts = pairs[0::2], pairs[1::2]
        has_tex[:] = True
    elif raw is None:
        if _CORNERS_RE.fullmatch(joined) is None:
            i = first_bad(corners, _CORNER_RE)
            raise MeshFormatError(f"{path}, line {line_of[i]}: cannot read face corner {show(corners[i])}; "
                                  f"expected 'a', 'a/t', 'a//n' or 'a/t/n' with whole numbers (1-based)")
        groups = _CORNER_FIND_RE.findall(joined)
        raw = ints([g[0] for g in groups], where)
        texts = [g[1] or g[2] for g in groups]
        has_tex = np.array([t != b"" for t in texts], dtype=bool)
    tex = np.zeros(len(corners), dtype=np.int64)
    if pairs is not None:
        tex = texts
    elif has_tex.any():
        present = np.flatnonzero(has_tex)
        tex[present] = ints([texts[i] for i in present], lambda i: where(present[i]))
    zero = np.flatnonzero(has_tex & (tex == 0))
    if zero.size:
        i = int(zero[0])
        raise MeshFormatError(f"{path}, line {line_of[i]}: face corner {show(corners[i])} has texture "
                              f"index 0 (OBJ indices start at 1)")
    seen = np.repeat(seen, counts)
    index = np.where(raw > 0, raw - 1, seen + raw)
    for bad, why in (
        (raw == 0, "index 0 (OBJ indices start at 1)"),
        ((raw < 0) & (index < 0), "a relative (negative) index reaching before the first vertex"),
        (raw > n_vertices, f"a vertex beyond the file's {n_vertices} 'v' lines"),
    ):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            error = MeshError if raw[i] > n_vertices else MeshFormatError
            raise error(f"{path}, line {line_of[i]}: face corner {show(corners[i])} refers to {why}")
    tex = np.where(~has_tex, -1, np.where(tex > 0, tex - 1, -2))  # -1: none; -2: relative
    return {"corners": index, "texcoords": tex, "counts": counts, "lines": face_lines}


def _slash_pairs(joined, count):
    """The ``2 * count`` integers of ``count`` space-separated ``a/t`` corners (``joined``), or
    ``None`` unless every corner is exactly two plain integers around one slash.

    The separators in order must alternate ``/``, space, ``/``, ..., ``/``: then every corner
    has one slash, and :func:`plain_ints` checks that every piece between them is an integer.
    """
    chars = np.frombuffer(joined, dtype=np.uint8)
    separators = chars[(chars == ord(" ")) | (chars == ord("/"))]
    if len(separators) != 2 * count - 1 or (separators[0::2] != ord("/")).any() or \
            (separators[1::2] != ord(" ")).any():
        return None
    pieces = joined.replace(b"/", b" ").split(b" ")
    return plain_ints(pieces, joined.replace(b"/", b""))


def _read_obj(data, path):
    """``(V, F)`` of an OBJ file (polygons fan-triangulated); see :func:`read_mesh`."""
    obj = _parse_obj(data, path)
    if not obj["v"].shape[0] and not obj["counts"].size:
        raise MeshFormatError(f"{path} contains no mesh (no 'v' or 'f' lines); is it really an OBJ file?")
    if not obj["counts"].size:
        raise MeshFormatError(f"{path} has no triangle faces (no 'f' lines); a triangle mesh is required")
    return obj["v"], _fan(obj["corners"], obj["counts"], obj["v"], path)


def read_obj_quads(path):
    """Read a quad mesh from an OBJ file: ``v`` and ``f`` lines as :func:`read_mesh` reads them,
    every face with exactly four corners (kept as quads, not triangulated).

    Returns
    -------
    V : (n, 3) float64;  Q : (m, 4) int64 quads, 0-based, in file order.

    Raises
    ------
    MeshFormatError
        As :func:`read_mesh`, or a face that is not a quad (mixed triangles and quads are not
        supported: split or merge them first).
    MeshError
        Non-finite coordinates, indices out of range, a quad repeating a vertex.
    """
    path = existing_file(path, "OBJ file")
    check_not_empty(path, "OBJ file")
    with gc_paused():
        obj = _parse_obj(read_bytes(path, "OBJ file"), path)
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


def write_obj(path, V, F):
    """Write a triangle mesh as OBJ (``v x y z``, ``f a b c``), full precision, atomic;
    :func:`read_mesh` reads it back bit for bit."""
    V = validate_vertices(V, "V", dim=3)
    F = validate_simplices(F, V.shape[0], 3, "F")

    def write(fh):
        write_rows(fh, "v ", V)
        write_int_rows(fh, "f %d %d %d", F + 1)

    return atomic_write(path, write)


def read_obj_uv(path):
    """Read an OBJ mesh and its UV map (``vt``) as one map position per vertex.

    The file is read as :func:`read_mesh` reads it; the UV of a vertex is the ``vt`` of its
    face corners, which must all carry a texture index and agree on the vertex's position
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
    check_not_empty(path, "OBJ file")
    with gc_paused():
        obj = _parse_obj(read_bytes(path, "OBJ file"), path, with_uv=True)
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
    F = validate_simplices(_fan(corner, obj["counts"], V, path), V.shape[0], 3, f"{path.name}: faces")
    return V, F, validate_vertices(UV, f"{path.name}: UV map", dim=2)


# ------------------------------------------------------------------------- OFF

_OFF_KEYWORD_RE = re.compile(rb"(ST)?(C)?(N)?(4)?(n)?OFF")


def _read_off(data, path):
    """``(V, F)`` of an ASCII OFF file whose counts match its body; see :func:`read_mesh`."""
    rows = text_rows(text_data(data, path, "OFF file").split(b"\n"))
    if not rows:
        raise MeshFormatError(f"{path} contains no mesh (only comments or blank lines)")
    lineno, tokens = rows[0]
    keyword = _OFF_KEYWORD_RE.fullmatch(tokens[0])
    if keyword is None:
        raise MeshFormatError(f"{path}, line {lineno}: an OFF file must start with the keyword 'OFF' "
                              f"(or COFF, NOFF, STOFF ...), found {show(tokens[0])}")
    st, colour, normal, four, ndim = keyword.groups()
    if four or ndim:
        raise MeshFormatError(f"{path}: {show(tokens[0])} files (4D or n-dimensional vertices) are not "
                              f"supported; a 3D triangle mesh is required")
    rest, at = tokens[1:], 1
    if rest and rest[0].upper() == b"BINARY":
        raise MeshFormatError(f"{path}: binary OFF is not supported; save it as ASCII OFF, OBJ or PLY")
    if not rest:  # the counts are on the next line
        if len(rows) < 2:
            raise MeshFormatError(f"{path} ends after the OFF keyword; the vertex and face counts are missing")
        lineno, rest = rows[1]
        at = 2
    if len(rest) not in (2, 3):
        raise MeshFormatError(f"{path}, line {lineno}: expected the counts 'vertices faces edges', found "
                              f"{len(rest)} values")
    nv, nf = (int(x) for x in ints(rest, lambda i: f"{path}, line {lineno}")[:2])
    if nv < 0 or nf < 0:
        raise MeshFormatError(f"{path}, line {lineno}: negative vertex or face count")
    vrows, frows = rows[at:at + nv], rows[at + nv:at + nv + nf]
    if len(vrows) < nv or len(frows) < nf:
        raise MeshFormatError(
            f"{path}: the header (line {lineno}) declares {nv} vertices and {nf} faces, but the file ends "
            f"after {len(vrows)} vertex line(s) and {len(frows)} face line(s); fix the counts or the "
            f"truncated file")
    if len(rows) > at + nv + nf:
        extra = rows[at + nv + nf][0]
        raise MeshFormatError(
            f"{path}: the header (line {lineno}) declares {nv} vertices and {nf} faces, but the file holds "
            f"more (line {extra}); fix the counts (an extra face would otherwise be dropped)")
    if nf == 0:
        raise MeshFormatError(f"{path} has no triangle faces (the header declares 0 faces)")
    widths = {3 + (3 if normal else 0) + c + (2 if st else 0) for c in ((3, 4) if colour else (0,))}
    expected = " or ".join(map(str, sorted(widths)))
    V = _off_vertices(vrows, widths, expected, path)
    return V, _off_faces(frows, path, V)


def _off_vertices(rows, widths, expected, path):
    for lineno, tokens in rows:
        if len(tokens) not in widths:
            raise MeshFormatError(f"{path}, line {lineno}: vertex line has {len(tokens)} numbers; expected "
                                  f"{expected} (one vertex per line, as the header declares)")
    flat = [x for _, t in rows for x in t[:3]]
    return floats(flat, lambda i: f"{path}, line {rows[i // 3][0]}").reshape(-1, 3)


def _off_faces(rows, path, V=None):
    sizes = [len(t) for _, t in rows]
    heads = ints([t[0] for _, t in rows], lambda i: f"{path}, line {rows[i][0]}")
    for (lineno, tokens), k, size in zip(rows, heads.tolist(), sizes):
        if k < 3:
            raise MeshFormatError(f"{path}, line {lineno}: face with {k} vertices; a face needs at least 3")
        if not k + 1 <= size <= k + 5:
            raise MeshFormatError(
                f"{path}, line {lineno}: face line declares {k} vertices but holds {size - 1} values; "
                f"expected {k} indices and at most 4 colour numbers")
    corners = [x for (_, t), k in zip(rows, heads.tolist()) for x in t[1:k + 1]]
    owner = np.repeat(np.arange(len(rows)), heads)
    index = ints(corners, lambda i: f"{path}, line {rows[owner[i]][0]}")
    colours = [x for (_, t), k in zip(rows, heads.tolist()) for x in t[k + 1:]]
    if colours:
        owner = np.repeat(np.arange(len(rows)), np.array(sizes) - 1 - heads)
        floats(colours, lambda i: f"{path}, line {rows[owner[i]][0]} (face colour)")
    return _fan(index, heads, V, path)


# ------------------------------------------------------------------------- PLY

_PLY_TYPES = {b"char": "i1", b"int8": "i1", b"uchar": "u1", b"uint8": "u1", b"short": "i2", b"int16": "i2",
              b"ushort": "u2", b"uint16": "u2", b"int": "i4", b"int32": "i4", b"uint": "u4", b"uint32": "u4",
              b"float": "f4", b"float32": "f4", b"double": "f8", b"float64": "f8"}
_PLY_FORMATS = {b"ascii": None, b"binary_little_endian": "<", b"binary_big_endian": ">"}


def _ply_header(data, path):
    """Parse a PLY header: ``(byte order or None for ASCII, elements, body offset)``.

    ``elements`` is a list of ``(name, count, properties, lineno)``; a property is
    ``(name, dtype)`` or ``(name, count dtype, item dtype)`` for a list (dtypes as numpy
    codes without byte order).
    """
    if data.startswith(UTF8_BOM):
        data = data[len(UTF8_BOM):]
        skipped = len(UTF8_BOM)
    else:
        skipped = 0
    if not data.startswith((b"ply\n", b"ply\r\n")):
        raise MeshFormatError(f"{path} does not start with the line 'ply'; it is not a PLY file")
    end = re.search(rb"(?m)^end_header[ \t]*\r?(?:\n|\Z)", data)
    if end is None:
        raise MeshFormatError(f"{path}: the PLY header has no 'end_header' line; the file is truncated "
                              f"or not PLY")
    order, elements, names = "missing", [], set()
    for lineno, line in enumerate(data[:end.start()].split(b"\n")[1:], 2):
        tokens = line.split()
        if not tokens or tokens[0] in (b"comment", b"obj_info"):
            continue
        key = tokens[0]
        if key == b"format":
            if len(tokens) != 3 or tokens[1] not in _PLY_FORMATS or tokens[2] != b"1.0":
                raise MeshFormatError(f"{path}, line {lineno}: unsupported PLY format line {show(line.strip())}; "
                                      f"expected 'format ascii|binary_little_endian|binary_big_endian 1.0'")
            order = _PLY_FORMATS[tokens[1]]
        elif key == b"element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise MeshFormatError(f"{path}, line {lineno}: malformed element line {show(line.strip())}; "
                                      f"expected 'element NAME COUNT'")
            if tokens[1] in names:
                raise MeshFormatError(f"{path}, line {lineno}: element {show(tokens[1])} is declared twice")
            names.add(tokens[1])
            elements.append((tokens[1], int(tokens[2]), [], lineno))
        elif key == b"property":
            if not elements:
                raise MeshFormatError(f"{path}, line {lineno}: property declared before any element")
            props = elements[-1][2]
            if len(tokens) == 3 and tokens[1] in _PLY_TYPES:
                prop = (tokens[2], _PLY_TYPES[tokens[1]])
            elif (len(tokens) == 5 and tokens[1] == b"list" and tokens[2] in _PLY_TYPES
                  and tokens[3] in _PLY_TYPES and _PLY_TYPES[tokens[2]][0] in "iu"):
                prop = (tokens[4], _PLY_TYPES[tokens[2]], _PLY_TYPES[tokens[3]])
            else:
                raise MeshFormatError(
                    f"{path}, line {lineno}: malformed or unsupported property line {show(line.strip())}; "
                    f"expected 'property TYPE NAME' or 'property list COUNT_TYPE ITEM_TYPE NAME' "
                    f"(types: {', '.join(t.decode() for t in _PLY_TYPES)}; a list count must be an integer type)")
            if any(p[0] == prop[0] for p in props):
                raise MeshFormatError(f"{path}, line {lineno}: property {show(prop[0])} is declared twice")
            props.append(prop)
        else:
            raise MeshFormatError(f"{path}, line {lineno}: unknown PLY header line {show(line.strip())}")
    if order == "missing":
        raise MeshFormatError(f"{path}: the PLY header has no 'format' line")
    return order, elements, skipped + end.end()


def _read_ply(data, path):
    """``(V, F)`` of an ASCII or binary PLY file, its body checked against the header; see :func:`read_mesh`."""
    order, elements, offset = _ply_header(data, path)
    found = {}
    body = data[offset:]
    if order is None:
        if b"\x00" in body or UTF8_BOM in body:
            raise MeshFormatError(f"{path}: the header says 'format ascii' but the body holds binary data "
                                  f"(NUL bytes or a byte-order mark)")
        rows = text_rows(text_data(body, path, "PLY file").split(b"\n"), comment=None)
        header_lines = data[:offset].count(b"\n")
        rows = [(lineno + header_lines, tokens) for lineno, tokens in rows]
        at = 0
        for name, count, props, _ in elements:
            found[name] = _ply_ascii_element(rows[at:at + count], name, count, props, path)
            at += count
        if len(rows) > at:
            raise MeshFormatError(f"{path}, line {rows[at][0]}: the PLY body holds more lines than the header "
                                  f"declares ({sum(e[1] for e in elements)} element lines); fix the counts")
    else:
        at = 0
        for name, count, props, _ in elements:
            found[name], at = _ply_binary_element(body, at, name, count, props, order, path)
        if at != len(body):
            raise MeshFormatError(f"{path}: the binary PLY body is {len(body) - at} bytes longer than the "
                                  f"header's elements; fix the counts (or the file has trailing data)")
    return _ply_mesh(found, elements, path)


def _ply_ascii_element(rows, name, count, props, path):
    """Columns of ``count`` ASCII element lines: ``{property: array}`` (lists: ``(counts, flat items)``)."""
    what = f"element {show(name)}"
    if len(rows) < count:
        raise MeshFormatError(f"{path}: the header declares {count} {what} lines but the body ends after "
                              f"{len(rows)}; the file is truncated or the count is wrong")
    if not rows:
        return {}
    if len(props) == 1 and len(props[0]) == 3 and all(len(t) == 4 and t[0] == b"3" for _, t in rows):
        name_, count_code, item_code = props[0]  # the common case: triangles only
        items = [x for _, t in rows for x in t[1:]]
        return {name_: (np.full(len(rows), 3, dtype=np.int64),
                        _ply_ascii_values(items, item_code, [r for r in rows for _ in range(3)], path))}
    if not any(len(p) == 3 for p in props):
        width = len(props)
        for lineno, tokens in rows:
            if len(tokens) != width:
                raise MeshFormatError(f"{path}, line {lineno}: {what} line has {len(tokens)} values; the "
                                      f"header declares {width} properties")
        table = [[t[j] for _, t in rows] for j in range(width)]
        return {p[0]: _ply_ascii_values(col, p[1], rows, path) for p, col in zip(props, table)}
    columns = {p[0]: [] for p in props}
    lists = {p[0]: [] for p in props if len(p) == 3}
    for lineno, tokens in rows:
        j = 0
        for p in props:
            if len(p) == 3:
                if j >= len(tokens) or not INT_RE.fullmatch(tokens[j]):
                    raise MeshFormatError(f"{path}, line {lineno}: {what} line is missing the count of "
                                          f"list {show(p[0])} (or it is not an integer)")
                k = int(tokens[j])
                if k < 0 or j + 1 + k > len(tokens):
                    raise MeshFormatError(f"{path}, line {lineno}: list {show(p[0])} declares {k} items but "
                                          f"the line holds {max(len(tokens) - j - 1, 0)} more values")
                columns[p[0]].append(tokens[j])
                lists[p[0]].extend(tokens[j + 1:j + 1 + k])
                j += 1 + k
            else:
                if j >= len(tokens):
                    raise MeshFormatError(f"{path}, line {lineno}: {what} line has too few values for its "
                                          f"properties")
                columns[p[0]].append(tokens[j])
                j += 1
        if j != len(tokens):
            raise MeshFormatError(f"{path}, line {lineno}: {what} line has {len(tokens) - j} value(s) more than "
                                  f"its properties declare")
    out = {}
    for p in props:
        if len(p) == 3:
            counts = _ply_ascii_values(columns[p[0]], p[1], None, path)
            out[p[0]] = (counts, _ply_ascii_values(lists[p[0]], p[2], None, path))
        else:
            out[p[0]] = _ply_ascii_values(columns[p[0]], p[1], None, path)
    return out


def _ply_ascii_values(tokens, code, rows, path):
    """Tokens of one declared PLY type as an array of that type (range-checked for integers)."""
    def where(i):
        return f"{path}, line {rows[i][0]}" if rows is not None else f"{path} (PLY body)"

    if code[0] == "f":
        values = floats(tokens, where)
        with np.errstate(over="ignore"):
            narrow = values.astype(code)  # 'float' properties are float32, as declared
        bad = np.flatnonzero(np.isfinite(values) & ~np.isfinite(narrow))
        if bad.size:
            raise MeshFormatError(f"{where(int(bad[0]))}: the value {show(tokens[bad[0]])} does not fit the "
                                  f"declared type {np.dtype(code).name}")
        return narrow
    values = ints(tokens, where)
    info = np.iinfo(code)
    bad = np.flatnonzero((values < info.min) | (values > info.max))
    if bad.size:
        raise MeshFormatError(f"{where(int(bad[0]))}: the value {values[bad[0]]} does not fit the declared "
                              f"type {np.dtype(code).name}")
    return values.astype(code)


def _ply_binary_element(body, at, name, count, props, order, path):
    """Decode ``count`` binary records of an element starting at byte ``at``; return (columns, end)."""
    what = f"element {show(name)}"

    def short(needed):
        return MeshFormatError(f"{path}: the binary PLY body ends inside {what} (needs at least {needed} more "
                               f"bytes, {len(body) - at} left); the file is truncated or the count is wrong")

    fields = [(p[0].decode("latin-1"), order + p[1]) for p in props if len(p) == 2]
    if all(len(p) == 2 for p in props):
        dtype = np.dtype(fields)
        need = count * dtype.itemsize
        if at + need > len(body):
            raise short(need)
        rec = np.frombuffer(body, dtype, count, at)
        return {p[0]: rec[p[0].decode("latin-1")] for p in props}, at + need
    # records with lists: try "every list has the length of the first record's", else walk record by record
    if count == 0:
        return {}, at
    lengths, pos = [], at
    for p in props:
        size = np.dtype(p[1]).itemsize
        if len(p) == 3:
            if pos + size > len(body):
                raise short(pos + size - at)
            k = int(np.frombuffer(body, order + p[1], 1, pos)[0])
            lengths.append(k)
            pos += size + max(k, 0) * np.dtype(p[2]).itemsize
        else:
            pos += size
    layout, li = [], 0
    for j, p in enumerate(props):
        if len(p) == 3:
            layout += [(f"n{j}", order + p[1]), (f"l{j}", order + p[2], (max(lengths[li], 0),))]
            li += 1
        else:
            layout.append((f"s{j}", order + p[1]))
    dtype = np.dtype(layout)
    if min(lengths) >= 0 and at + count * dtype.itemsize <= len(body):
        rec = np.frombuffer(body, dtype, count, at)
        uniform = all((rec[f"n{j}"] == rec[f"n{j}"][0]).all() for j, p in enumerate(props) if len(p) == 3)
        if uniform:
            out = {}
            for j, p in enumerate(props):
                if len(p) == 3:
                    out[p[0]] = (rec[f"n{j}"].astype(np.int64), rec[f"l{j}"].reshape(-1))
                else:
                    out[p[0]] = rec[f"s{j}"]
            return out, at + count * dtype.itemsize
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
                k = int(value)
                if k < 0:
                    raise MeshFormatError(f"{path}: list {show(p[0])} of {what} has a negative length {k}")
                isize = np.dtype(p[2]).itemsize
                if pos + k * isize > len(body):
                    raise short(pos + k * isize - at)
                items[p[0]].append(np.frombuffer(body, order + p[2], k, pos))
                pos += k * isize
    out = {}
    for p in props:
        column = np.array(columns[p[0]], dtype=p[1])
        if len(p) == 3:
            flat = np.concatenate(items[p[0]]) if items[p[0]] else np.zeros(0, p[2])
            out[p[0]] = (column.astype(np.int64), flat)
        else:
            out[p[0]] = column
    return out, pos


def _ply_mesh(found, elements, path):
    """``(V, F)`` from the decoded PLY elements ``vertex`` (x, y, z) and ``face`` (vertex_indices)."""
    declared = {e[0]: e for e in elements}
    if b"vertex" not in declared:
        raise MeshFormatError(f"{path} has no 'vertex' element; it holds no mesh")
    vprops = {p[0]: p for p in declared[b"vertex"][2]}
    for axis in (b"x", b"y", b"z"):
        if axis not in vprops or len(vprops[axis]) == 3:
            raise MeshFormatError(f"{path}: element 'vertex' has no scalar property {axis.decode()!r}; "
                                  f"vertex positions x, y, z are required")
    nv = declared[b"vertex"][1]
    V = (np.stack([np.asarray(found[b"vertex"][a], dtype=np.float64) for a in (b"x", b"y", b"z")], axis=1)
         if nv else np.zeros((0, 3)))
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
    return V, _fan(flat.astype(np.int64), counts, V, path)


# ------------------------------------------------------------------------- STL

_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def _read_stl(data, path):
    """``(V, F)`` of an ASCII or binary STL file, corners welded by equal coordinates."""
    binary_size = 84 + 50 * int.from_bytes(data[80:84], "little") if len(data) >= 84 else None
    text = data.removeprefix(UTF8_BOM)
    looks_ascii = text.lstrip()[:5].lower() == b"solid" and not any(
        b < 9 or 13 < b < 32 or b == 127 for b in text[:1000])
    if len(data) == binary_size and not looks_ascii:
        count = (len(data) - 84) // 50
        if count == 0:
            raise MeshFormatError(f"{path} is a binary STL with 0 triangles; a triangle mesh is required")
        corners = np.frombuffer(data, _STL_RECORD, count, 84)["corners"].reshape(-1, 3)
        return _weld(corners.astype(np.float64))
    if looks_ascii:
        return _weld(_stl_ascii_corners(data, path))
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


def _stl_ascii_corners(data, path):
    """(3m, 3) float64 corner positions of an ASCII STL with exactly one solid."""
    lines = text_data(data, path, "STL file").split(b"\n")
    rows = [(i, line.split()) for i, line in enumerate(lines, 1) if line.strip()]
    first, tokens = rows[0]
    if tokens[0].lower() != b"solid":
        raise MeshFormatError(f"{path}, line {first}: an ASCII STL must start with 'solid'")
    ends = [j for j, (_, t) in enumerate(rows) if t[0].lower() == b"endsolid"]
    if not ends:
        raise MeshFormatError(f"{path}: no 'endsolid' line; the file is truncated")
    end = ends[0]
    if end + 1 < len(rows):
        lineno, t = rows[end + 1]
        if t[0].lower() == b"solid":
            solids = sum(r[1][0].lower() == b"solid" for r in rows)
            raise MeshFormatError(f"{path} contains {solids} separate meshes ('solid' blocks, the second at line "
                                  f"{lineno}); merge them into one solid before reading it")
        raise MeshFormatError(f"{path}, line {lineno}: data after 'endsolid'; remove it")
    body = rows[1:end]
    pattern = ((b"facet", b"normal", 3), (b"outer", b"loop", 0), (b"vertex", None, 3), (b"vertex", None, 3),
               (b"vertex", None, 3), (b"endloop", None, 0), (b"endfacet", None, 0))
    for j, (lineno, t) in enumerate(body):
        key, word, numbers = pattern[j % 7]
        head = [key] if word is None else [key, word]
        if [x.lower() for x in t[:len(head)]] != head or len(t) != len(head) + numbers:
            raise MeshFormatError(f"{path}, line {lineno}: expected '{b' '.join(head).decode()}"
                                  f"{' x y z' if numbers else ''}', found {show(b' '.join(t))}")
    if len(body) % 7:
        raise MeshFormatError(f"{path}, line {rows[end][0]}: 'endsolid' inside an unfinished facet; the file is "
                              f"truncated")
    if not body:
        raise MeshFormatError(f"{path} has no facets; a triangle mesh is required")
    normals = [x for _, t in body[0::7] for x in t[2:]]
    floats(normals, lambda i: f"{path}, line {body[7 * (i // 3)][0]}")
    verts = [r for j, r in enumerate(body) if j % 7 in (2, 3, 4)]
    flat = [x for _, t in verts for x in t[1:]]
    return floats(flat, lambda i: f"{path}, line {verts[i // 3][0]}").reshape(-1, 3)


def _weld(corners):
    """Merge corners with equal coordinates (-0.0 = +0.0): ``(V (n, 3), F (m, 3))``, vertices in
    first-seen order with the first corner's exact bits."""
    corners = np.ascontiguousarray(corners, dtype=np.float64)
    equal = corners + 0.0  # -0.0 + 0.0 = +0.0: equal corners weld; a vertex keeps its first corner's bits
    keys = equal.view(np.dtype((np.void, corners.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return corners[first[order]], rank[inverse.ravel()].reshape(-1, 3).astype(np.int64)


def read_obj_with_uv(path):
    """Read the OBJ layout :func:`write_obj_with_uv` writes: one ``vt`` per ``v``, faces ``a/a b/b c/c``.

    This is the LIM 2D ``input.obj`` layout.  The statements, numbers and text conventions
    are those of :func:`read_mesh`, plus: exactly one ``vt u v`` per ``v`` line, in the same
    order; ``f`` lines with exactly 3 corners ``a``, ``a/a``, ``a/a/n`` or ``a//n`` (1-based,
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
    path = existing_file(path, "OBJ file")
    check_not_empty(path, "OBJ file")
    with gc_paused():
        obj = _parse_obj(read_bytes(path, "OBJ file"), path, with_uv=True)
    V, UV, counts, lines = obj["v"], obj["vt"], obj["counts"], obj["lines"]
    if not V.shape[0]:
        raise MeshFormatError(f"{path} has no 'v' lines; it is not a LIM input.obj")
    if not counts.size:
        raise MeshFormatError(f"{path} has no 'f' lines; a triangle mesh is required")
    if (counts != 3).any():
        i = int(np.flatnonzero(counts != 3)[0])
        raise MeshFormatError(f"{path}, line {lines[i]}: face has {counts[i]} corners; only triangles are "
                              f"supported (triangulate the mesh first)")
    face_lines = np.repeat(lines, 3)
    raw = obj["corners"]
    tex = obj["texcoords"]
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


# ------------------------------------------------------------------- mesh with UV


def _mesh_with_uv(V, F, UV, uv_faces=None):
    """Validated ``(V (n,3), F (m,3), UV (n,2))`` for the writers; with ``uv_faces`` (m, 3),
    ``(V, F, UV (k, 2), uv_faces)``: one UV row per face corner group (an atlas)."""
    V = validate_vertices(V, "V", dim=3)
    UV = validate_vertices(UV, "UV", dim=2)
    if uv_faces is not None:
        F = validate_simplices(F, V.shape[0], 3, "F")
        T = validate_simplices(uv_faces, UV.shape[0], 3, "uv_faces")
        if T.shape != F.shape:
            raise MeshError(f"uv_faces has {T.shape[0]} rows but F has {F.shape[0]}; give one UV triangle per face")
        return V, F, UV, T
    if UV.shape[0] != V.shape[0]:
        raise MeshError(f"UV has {UV.shape[0]} rows but V has {V.shape[0]}; give one UV per vertex")
    return V, validate_simplices(F, V.shape[0], 3, "F"), UV


def write_mesh_with_uv(path, V, F, UV, format=None, uv_faces=None):
    """Write a mesh and a per-vertex map in the format ``path``'s extension names (see :data:`UV_MESH_EXTENSIONS`).

    ``.obj``: :func:`write_obj_with_uv`; ``.ply``: :func:`write_ply_with_uv`.  Both keep
    every ``float64`` bit.  Atomic.

    Parameters
    ----------
    path : str or os.PathLike
        Output file, ``.obj`` or ``.ply`` (any case) unless ``format`` is given.
    V : array_like, shape (n, 3)
        Vertex positions.
    F : array_like, shape (m, 3), integer
        Triangles, 0-based.
    UV : array_like, shape (n, 2)
        Map coordinates, one per vertex.
    format : {None, "obj", "ply"}
        The format, when ``path``'s extension does not say it (e.g. a temporary file from
        :func:`atomic_path`).  Case is ignored.
    uv_faces : None, or (m, 3) int the UV row of each face corner (an atlas: ``UV`` (k, 2) then
        holds one row per chart corner); OBJ only.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    GeomoptError
        Another extension or format (the message lists the supported ones), or ``path``
        cannot be written.
    MeshError
        Invalid ``V``, ``F`` or ``UV``.
    """
    if format is None:
        path = check_output_path(path, UV_MESH_EXTENSIONS)
        format = path.suffix[1:]
    writers = {"obj": write_obj_with_uv, "ply": write_ply_with_uv}
    if format.lower() not in writers:
        raise GeomoptError(f"cannot write a mesh with a map as {format!r}; supported: {', '.join(writers)}")
    if uv_faces is not None:
        if format.lower() != "obj":
            raise GeomoptError(f"an atlas (UVs per chart corner) is written as .obj, not {format!r}: "
                               f"PLY holds one UV per vertex")
        return write_obj_with_uv(path, V, F, UV, uv_faces)
    return writers[format.lower()](path, V, F, UV)


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
        V, F, UV = _mesh_with_uv(V, F, UV)
        T = F
    else:
        V, F, UV, T = _mesh_with_uv(V, F, UV, uv_faces)

    def write(fh):
        write_rows(fh, "v ", V)
        write_rows(fh, "vt ", UV)
        write_int_rows(fh, "f %d/%d %d/%d %d/%d", np.stack([F + 1, T + 1], axis=2).reshape(-1, 6))

    return atomic_write(path, write)


def write_ply_with_uv(path, V, F, UV):
    """Write a mesh and a per-vertex map as binary little-endian PLY, all coordinates ``float64``.

    Element ``vertex`` has the ``double`` properties ``x y z u v`` (the map as the texture
    coordinates ``u v``, which MeshLab, Blender and trimesh read); element ``face`` has
    ``list uchar int vertex_indices``.  Every bit round-trips (:func:`read_mesh` reads
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
    V, F, UV = _mesh_with_uv(V, F, UV)
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


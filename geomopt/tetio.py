"""Tetrahedral meshes in four formats, each read exactly as the file says or refused.

=========  ==========================================  ===========================================
extension  read                                        written
=========  ==========================================  ===========================================
``.vtk``   legacy VTK, ASCII or binary                 ASCII, ``double`` points
           (:func:`geomopt.io.read_vtk_tets`)          (:func:`geomopt.io.write_vtk_tets`)
``.vtu``   VTK XML unstructured grid (meshio)          binary base64, zlib, ``Float64`` (meshio)
``.msh``   Gmsh ASCII, versions 2.2 and 4.1            Gmsh 4.1 ASCII (meshio)
``.mesh``  Medit ASCII (``MeshVersionFormatted`` 1/2)  Medit ASCII, version 2 (meshio)
=========  ==========================================  ===========================================

Gmsh and Medit files are checked here, line by line, before meshio reads their numbers:
every section must hold exactly the number of entries its count declares, every section
must be closed (``$EndNodes``, ``End``...), every element must name defined nodes (Gmsh
node tags need not be contiguous; they are mapped to 0-based indices in file order).
Binary Gmsh/Medit files are refused (they cannot be checked this way).  meshio's own
messages are never printed: its errors become one :class:`MeshFormatError`.  Any other
extension is refused on reading and writing.

:func:`read_tets` returns ``(P (n, 3) float64, T (m, 4) int64)`` validated like every
geomopt reader; :func:`write_tets` writes atomically (:func:`geomopt.io.atomic_path`)
with full precision, so ``read_tets`` gives back exactly what was written.
"""

from __future__ import annotations

import contextlib
import os
import stat
import warnings
from io import StringIO
from pathlib import Path

import numpy as np

from ._errors import GeomoptError, MeshFormatError
from .io import (atomic_path, check_output_path, read_vtk_tets, validate_simplices, validate_vertices,
                 write_vtk_tets)

#: The tet-mesh formats geomopt reads and writes: extension -> description.
FORMATS = {
    ".vtk": "legacy VTK",
    ".vtu": "VTK XML unstructured grid",
    ".msh": "Gmsh ASCII 2.2/4.1",
    ".mesh": "Medit ASCII",
}

#: Nodes per Gmsh element type, for the types a volume mesh may carry beside its tets.
_GMSH_NODES = {15: 1, 1: 2, 2: 3, 3: 4, 4: 4, 5: 8, 6: 6, 7: 5,
               8: 3, 9: 6, 10: 9, 11: 10, 12: 27, 13: 18, 14: 14, 16: 8, 17: 20, 18: 15, 19: 13}
_GMSH_TET = 4

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
    return ", ".join(f"{ext} ({what})" for ext, what in FORMATS.items())


def _extension(path: Path, doing: str) -> str:
    """``path``'s extension (lower case) if geomopt reads and writes it, else a MeshFormatError."""
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
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


# ------------------------------------------------------------------------ checks


def _lines(data, path, what):
    """``[(line number, tokens)]`` of the non-blank lines of an ASCII mesh file."""
    if b"\x00" in data:
        raise MeshFormatError(f"{what} {path} contains NUL bytes: it is a binary file; only ASCII "
                              f"{what} files are supported (re-export as ASCII)")
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise MeshFormatError(f"{path}, line {line}: a non-ASCII byte; {what} files are ASCII text") from None
    return [(i, toks) for i, toks in enumerate((line.split() for line in text.split("\n")), 1) if toks]


def _int(token, path, lineno, what):
    try:
        value = int(token)
    except ValueError:
        raise MeshFormatError(f"{path}, line {lineno}: expected an integer ({what}), found {token!r}") from None
    return value


def _gmsh_sections(rows, path):
    """``{name: [(first line, body rows)]}`` of a Gmsh file; each ``$X`` must be closed by ``$EndX``."""
    sections, i = {}, 0
    while i < len(rows):
        lineno, toks = rows[i]
        if not toks[0].startswith("$") or toks[0].startswith("$End"):
            raise MeshFormatError(f"{path}, line {lineno}: {' '.join(toks)[:60]!r} outside a section; "
                                  f"expected a section start such as $Nodes")
        name, start = toks[0][1:], i + 1
        i = start
        while i < len(rows) and not rows[i][1][0].startswith("$"):
            i += 1
        if i == len(rows) or rows[i][1][0] != f"$End{name}":
            found = f"{rows[i][1][0]!r} on line {rows[i][0]}" if i < len(rows) else "the end of the file"
            raise MeshFormatError(f"{path}: section ${name} (line {lineno}) is not closed by $End{name} "
                                  f"(found {found}); the file is truncated or malformed")
        sections.setdefault(name, []).append((lineno, rows[start:i]))
        i += 1
    return sections


def _check_width(rows, width, path, section):
    """Every row in ``rows`` has ``width`` tokens."""
    bad = next((r for r in rows if len(r[1]) != width), None)
    if bad is not None:
        raise MeshFormatError(f"{path}, line {bad[0]}: the {section} entry has {len(bad[1])} values, "
                              f"expected {width}")


def _counted(body, count, path, section, lineno):
    if len(body) != count:
        fix = "fix the count" if len(body) > count else "the file is truncated or the count is wrong"
        raise MeshFormatError(f"{path}: section {section} (line {lineno}) declares {count} entries but holds "
                              f"{len(body)}; {fix}")


def _element_nodes(gtype, lineno, path):
    """How many nodes a Gmsh element of type ``gtype`` has (refuses unknown types)."""
    nodes = _GMSH_NODES.get(gtype)
    if nodes is None:
        raise MeshFormatError(f"{path}, line {lineno}: unsupported Gmsh element type {gtype}; "
                              f"a tetrahedral mesh (type 4) is expected")
    return nodes


def _check_gmsh(data, path):
    """Check a Gmsh ASCII 2.2 or 4.1 file's structure; return ``(node count, tet count)``."""
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
    sections = _gmsh_sections(_lines(data, path, "Gmsh"), path)
    for name in ("Nodes", "Elements"):
        if len(sections.get(name, ())) != 1:
            raise MeshFormatError(f"{path} has {len(sections.get(name, ()))} ${name} sections; exactly one "
                                  f"is required")
    (nline, nodes), (eline, elems) = sections["Nodes"][0], sections["Elements"][0]
    if not nodes or not elems:
        raise MeshFormatError(f"{path}: an empty $Nodes or $Elements section")
    if fmt[0] == b"2.2":
        tags, tet_nodes = _gmsh22(nodes, nline, elems, eline, path)
    else:
        tags, tet_nodes = _gmsh41(nodes, nline, elems, eline, path)
    if len(np.unique(tags)) != len(tags):
        raise MeshFormatError(f"{path}: a node tag is defined twice in $Nodes; tags must be unique")
    if tet_nodes.size and not np.isin(tet_nodes, tags).all():
        missing = int(tet_nodes[~np.isin(tet_nodes, tags)][0])
        raise MeshFormatError(f"{path}: a tetrahedron refers to node tag {missing}, which $Nodes does not define")
    return len(tags), tet_nodes.shape[0]


def _gmsh22(nodes, nline, elems, eline, path):
    """Node tags and tet node tags of MSH 2.2 sections (counts, widths checked)."""
    _check_width(nodes[:1], 1, path, "$Nodes count")
    _counted(nodes[1:], _int(nodes[0][1][0], path, nodes[0][0], "node count"), path, "$Nodes", nline)
    _check_width(nodes[1:], 4, path, "$Nodes")
    tags = np.array([_int(t[0], path, ln, "node tag") for ln, t in nodes[1:]], dtype=np.int64)
    _check_width(elems[:1], 1, path, "$Elements count")
    _counted(elems[1:], _int(elems[0][1][0], path, elems[0][0], "element count"), path, "$Elements", eline)
    tets = []
    for ln, t in elems[1:]:
        if len(t) < 3:
            raise MeshFormatError(f"{path}, line {ln}: an element needs at least 3 values (tag, type, tags)")
        gtype, ntags = _int(t[1], path, ln, "element type"), _int(t[2], path, ln, "number of tags")
        width = 3 + ntags + _element_nodes(gtype, ln, path)
        if len(t) != width:
            raise MeshFormatError(f"{path}, line {ln}: an element of type {gtype} with {ntags} tags needs "
                                  f"{width} values, found {len(t)}")
        if gtype == _GMSH_TET:
            tets.append([_int(v, path, ln, "node tag") for v in t[-4:]])
    return tags, np.array(tets, dtype=np.int64).reshape(-1, 4)


def _gmsh41(nodes, nline, elems, eline, path):
    """Node tags and tet node tags of MSH 4.1 sections (block counts, widths checked)."""
    def header(rows, section, line):
        _check_width(rows[:1], 4, path, f"{section} header")
        return [_int(v, path, rows[0][0], f"{section} header") for v in rows[0][1]]

    nblocks, total, lo, hi = header(nodes, "$Nodes", nline)
    at, tags = 1, []
    for _ in range(nblocks):
        _check_width(nodes[at:at + 1], 4, path, "$Nodes block header")
        if at >= len(nodes):
            raise MeshFormatError(f"{path}: $Nodes (line {nline}) declares {nblocks} blocks but holds fewer")
        dim, _, parametric, n = (_int(v, path, nodes[at][0], "$Nodes block header") for v in nodes[at][1])
        block_tags, coords = nodes[at + 1:at + 1 + n], nodes[at + 1 + n:at + 1 + 2 * n]
        if len(coords) != n:
            raise MeshFormatError(f"{path}: a $Nodes block (line {nodes[at][0]}) declares {n} nodes but the "
                                  f"section ends first")
        _check_width(block_tags, 1, path, "$Nodes tag")
        _check_width(coords, 3 + (dim if parametric else 0), path, "$Nodes coordinate")
        tags += [_int(t[0], path, ln, "node tag") for ln, t in block_tags]
        at += 1 + 2 * n
    if at != len(nodes) or len(tags) != total:
        raise MeshFormatError(f"{path}: section $Nodes (line {nline}) declares {total} nodes in {nblocks} "
                              f"blocks but its blocks hold {len(tags)} nodes in {at} of {len(nodes)} lines; "
                              f"fix the counts")
    if tags and (min(tags), max(tags)) != (lo, hi):
        raise MeshFormatError(f"{path}: section $Nodes (line {nline}) holds node tags {min(tags)}..{max(tags)} "
                              f"but its header says {lo}..{hi}; fix the header")
    nblocks, total, _, _ = header(elems, "$Elements", eline)
    at, count, tets = 1, 0, []
    for _ in range(nblocks):
        if at >= len(elems):
            raise MeshFormatError(f"{path}: $Elements (line {eline}) declares {nblocks} blocks but holds fewer")
        _check_width(elems[at:at + 1], 4, path, "$Elements block header")
        _, _, gtype, n = (_int(v, path, elems[at][0], "$Elements block header") for v in elems[at][1])
        rows = elems[at + 1:at + 1 + n]
        if len(rows) != n:
            raise MeshFormatError(f"{path}: an $Elements block (line {elems[at][0]}) declares {n} elements "
                                  f"but the section ends first")
        if n:
            _check_width(rows, 1 + _element_nodes(gtype, rows[0][0], path), path, f"type-{gtype} element")
        if gtype == _GMSH_TET:
            tets += [[_int(v, path, ln, "node tag") for v in t[1:]] for ln, t in rows]
        count += n
        at += 1 + n
    if at != len(elems) or count != total:
        raise MeshFormatError(f"{path}: section $Elements (line {eline}) declares {total} elements in {nblocks} "
                              f"blocks but its blocks hold {count} elements in {at} of {len(elems)} lines; "
                              f"fix the counts")
    return np.array(tags, dtype=np.int64), np.array(tets, dtype=np.int64).reshape(-1, 4)


def _medit_keyword(token):
    """Whether a Medit token is a keyword (a word that is not a number such as ``nan``)."""
    return token[0].isalpha() and token.lower() not in ("nan", "inf", "infinity")


def _check_medit(data, path):
    """Check a Medit ASCII file's structure; return ``(vertex count, tet count)``."""
    rows = [(ln, t) for ln, t in _lines(data, path, "Medit") if not t[0].startswith("#")]
    if not rows or rows[0][1][0] != "MeshVersionFormatted":
        raise MeshFormatError(f"{path} does not start with MeshVersionFormatted; it is not an ASCII Medit file")
    i, version, dim, counts, end, last = 0, None, None, {}, None, None
    while i < len(rows):
        ln, t = rows[i]
        key = t[0]
        if key in ("MeshVersionFormatted", "Dimension"):
            if len(t) == 1 and i + 1 < len(rows):
                t, i = t + rows[i + 1][1], i + 1
            if len(t) != 2:
                raise MeshFormatError(f"{path}, line {ln}: {key} needs one integer")
            value = _int(t[1], path, ln, key)
            if key == "MeshVersionFormatted":
                if value not in (1, 2):
                    raise MeshFormatError(f"{path}, line {ln}: MeshVersionFormatted {value} is not supported "
                                          f"(1 or 2)")
                version = value
            elif value != 3:
                raise MeshFormatError(f"{path}, line {ln}: Dimension {value}; a tetrahedral mesh needs "
                                      f"Dimension 3")
            else:
                dim = value
            i += 1
            continue
        if key == "End":
            end = i
            break
        if not _medit_keyword(key) and last is not None:
            raise MeshFormatError(f"{path}, line {ln}: section {last[0]} (line {last[1]}) declares {last[2]} "
                                  f"entries but more follow; fix the count")
        if key not in _MEDIT_SECTIONS:
            raise MeshFormatError(f"{path}, line {ln}: unsupported Medit section {key!r}; supported: "
                                  f"{', '.join(_MEDIT_SECTIONS)}, End")
        if len(t) != 1 or i + 1 >= len(rows) or len(rows[i + 1][1]) != 1:
            raise MeshFormatError(f"{path}, line {ln}: expected {key} alone on its line and its count alone "
                                  f"on the next")
        if dim is None or version is None:
            raise MeshFormatError(f"{path}, line {ln}: {key} before MeshVersionFormatted and Dimension")
        n = _int(rows[i + 1][1][0], path, rows[i + 1][0], f"{key} count")
        width, indices = _MEDIT_SECTIONS[key]
        width = dim + 1 if width is None else dim if width == "dim" else width
        body = rows[i + 2:i + 2 + n]
        _counted([r for r in body if not _medit_keyword(r[1][0])], n, path, key, ln)
        _check_width(body, width, path, key)
        counts[key], last = n, (key, ln, n)
        if indices and n:
            ref = np.array([t[:indices] for _, t in body], dtype=np.int64)
            if key == "Tetrahedra" or key == "Corners" or key == "RequiredVertices":
                nv = counts.get("Vertices")
                if nv is None:
                    raise MeshFormatError(f"{path}, line {ln}: {key} before Vertices")
                bad = (ref < 1) | (ref > nv)
                if bad.any():
                    row = int(np.flatnonzero(bad.any(axis=1))[0])
                    raise MeshFormatError(f"{path}, line {body[row][0]}: {key} entry {row + 1} refers to vertex "
                                          f"{int(ref[row][bad[row]][0])}; Medit vertices are numbered 1..{nv}")
        i += 2 + n
    if end is None:
        raise MeshFormatError(f"{path} has no End keyword; the file is truncated")
    if end != len(rows) - 1:
        raise MeshFormatError(f"{path}, line {rows[end + 1][0]}: text after End")
    if "Vertices" not in counts:
        raise MeshFormatError(f"{path} has no Vertices section")
    return counts["Vertices"], counts.get("Tetrahedra", 0)


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
    path = Path(path)
    ext = _extension(path, "read")
    if ext == ".vtk":
        return read_vtk_tets(path)
    data = _existing(path)
    declared = _check_gmsh(data, path) if ext == ".msh" else _check_medit(data, path) if ext == ".mesh" else None
    import meshio

    reader = {".msh": meshio.gmsh.read, ".mesh": meshio.medit.read, ".vtu": meshio.vtu.read}[ext]
    with _quiet() as printed:
        try:
            mesh = reader(str(path))
        except (Exception, SystemExit) as exc:
            raise MeshFormatError(f"could not read {path} as {FORMATS[ext]}: {_detail(exc, printed)}; check "
                                  f"that the file is complete and of the format its extension says") from None
    if len(mesh.points) == 0:
        raise MeshFormatError(f"{path} has no points")
    others = sorted({c.type for c in mesh.cells if c.type in _VOLUME_CELLS})
    if others:
        raise MeshFormatError(f"{path} contains non-tetrahedral volume cells ({', '.join(others)}); "
                              f"only linear tetrahedral meshes are supported")
    tets = [c.data for c in mesh.cells if c.type == "tetra"]
    if not tets:
        found = sorted({c.type for c in mesh.cells}) or ["none"]
        raise MeshFormatError(f"{path} has no tetrahedra (cells found: {', '.join(found)})")
    T = np.concatenate(tets)
    if declared is not None and declared != (len(mesh.points), len(T)):
        raise MeshFormatError(f"{path}: the file declares {declared[0]} points and {declared[1]} tetrahedra "
                              f"but meshio read {len(mesh.points)} and {len(T)}; the file is malformed")
    P = validate_vertices(np.asarray(mesh.points, dtype=np.float64), f"{path.name}: points", dim=3)
    return P, validate_simplices(T, P.shape[0], 4, f"{path.name}: tetrahedra")


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
    path = Path(path)
    ext = _extension(path, "write")
    P = validate_vertices(P, "P", dim=3)
    T = validate_simplices(T, P.shape[0], 4, "T")
    if ext == ".vtk":
        return write_vtk_tets(path, P, T)
    check_output_path(path, what="tet mesh")
    import meshio

    if ext == ".msh":
        ones = np.ones(len(T), dtype=np.int64)
        mesh = meshio.Mesh(P, [("tetra", T)], cell_data={"gmsh:physical": [ones], "gmsh:geometrical": [ones]})
        write = lambda tmp: meshio.gmsh.write(tmp, mesh, fmt_version="4.1", binary=False)  # noqa: E731
    elif ext == ".mesh":
        write = lambda tmp: meshio.medit.write(tmp, meshio.Mesh(P, [("tetra", T)]))  # noqa: E731
    else:
        write = lambda tmp: meshio.vtu.write(tmp, meshio.Mesh(P, [("tetra", T)]), binary=True)  # noqa: E731
    with atomic_path(path, "tet mesh") as tmp, _quiet() as printed:
        try:
            write(str(tmp))
        except Exception as exc:  # meshio's WriteError, OSError (disk full), ...
            raise GeomoptError(f"could not write {path} as {FORMATS[ext]} ({_detail(exc, printed)}); "
                               f"nothing was written") from exc
    return path

"""Exact local injectivity around vertices and edges of a map with every element positive.

A piecewise-linear map with every triangle (tetrahedron) positively oriented is locally
injective inside elements and across interior facets, but not necessarily around vertices
(2D) or edges and vertices (3D).  This module finds, exactly, where it is not.

**Fans.**  The elements around a *centre* (a vertex in 2D, an edge in 3D) are wedges in the
circle of directions around it: corner ``(v, a, b)`` of a counter-clockwise triangle is the
half-open sector ``[a, b)`` seen from ``v``; tet ``(p, q, c, d)`` (an even permutation of its
corners) is the wedge ``[c, d)`` turning about the edge ``p -> q``.  Each wedge is less than a
half turn.  Around an interior centre they form closed cycles covering every direction ``w``
times (the *winding*); the map is locally injective there iff ``w = 1``.  Around a boundary
centre they form chains, from a *start* facet (a boundary edge in 2D, a boundary face in 3D)
to an *end* facet; the map is locally injective there iff the chains are disjoint arcs:
every start direction is covered exactly once by all the wedges together and no end
direction coincides with a start direction (a chain turning exactly a full turn, or two
chains touching).  (Two half-open arcs that meet contain each other's start.)

**Stars in 3D.**  Around a vertex ``v`` the tets' far faces form the *link*, mapped radially
onto the sphere of directions.  When every edge at ``v`` passes (the link map is a local
homeomorphism, an immersion up to its boundary), then with ``N(r)`` the number of tets at ``v``
whose cone contains direction ``r``:

* interior vertex (closed link): each link component is a closed surface covering the sphere,
  so ``N = 1`` everywhere iff ``N = 1`` at one direction; checked at the generic direction
  below (the components' number; a manifold vertex always passes, the sphere being simply
  connected);
* boundary vertex: the link boundary ``Gamma`` (the boundary faces at ``v`` seen from ``v``,
  arcs of great circles) must be simple: every two boundary faces at ``v`` sharing only ``v``
  must not meet anywhere else (exact arc test, :func:`_arcs_meet`); faces sharing an edge are
  the boundary edge's business.  Then an immersed disk with a simple boundary on the sphere is
  embedded (compactly supported Euler characteristics: ``1 = n + (n + 1)`` for the ``n`` and
  ``n + 1`` sheets over the two sides of ``Gamma``), so a manifold boundary vertex passes.
  Non-manifold ones (several boundary cycles, or a cycle plus a closed link component) are
  checked by counting ``N`` just inside each boundary cycle (:func:`_inner_counts`); one cycle
  with ``N(u) = 0`` or ``N(-u) = 0`` needs no count.

**Exactness.**  Every test is a sign of an orientation determinant
(:mod:`geomopt.exact.predicates`) or a float comparison.  The generic direction is
``u = e_z + eps e_x + eps^2 e_y`` (symbolic perturbation): the sign of ``n . u`` for a face
normal ``n`` is the first non-zero of ``n_z, n_x, n_y``, each an exact ``orient2d`` of the face
projected onto a coordinate plane, and never zero for a non-degenerate face.  The direction
just inside a boundary cycle is ``p1 + eps (p2 - p1) + eps^2 (q - p1)`` for a boundary face
``(v, p1, p2)`` of tet ``(v, p1, p2, q)``; its orientation tests expand the same way.

Every function expects every element positively oriented (see
:func:`geomopt.exact.predicates.count_inverted`); with an inverted element the answers mean nothing.
"""

from __future__ import annotations

import numpy as np

from .predicates import normal_signs, orient2d, orient3d, vertex_windings
from .topology import boundary_half_edges, graph_components

__all__ = ["fan_overlaps_2d", "star_overlaps_3d"]

_FACES = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))  # face i of a tet omits corner i
_EVEN_CORNER = ((0, 1, 2, 3), (1, 0, 3, 2), (2, 3, 0, 1), (3, 2, 1, 0))  # corner i first
_EVEN_EDGE = ((0, 1, 2, 3), (0, 2, 3, 1), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 2, 0), (2, 3, 0, 1))


def _pairs_by_key(ka, kb):
    """All index pairs ``(i, j)`` with ``ka[i] == kb[j]`` (int arrays), grouped by ``i``."""
    order = np.argsort(kb, kind="stable")
    sk = kb[order]
    lo = np.searchsorted(sk, ka, "left")
    cnt = np.searchsorted(sk, ka, "right") - lo
    i = np.repeat(np.arange(ka.size), cnt)
    j = np.arange(i.size) - np.repeat(np.cumsum(cnt) - cnt - lo, cnt)
    return i, order[j]


def _same_sign_directions(X, v, a, b):
    """Rows where ``a - v`` and ``b - v`` (collinear with ``v``) point the same way: their
    coordinate signs agree (the sign of a float difference is exact)."""
    da, db = X[a] - X[v], X[b] - X[v]
    return (np.sign(da) == np.sign(db)).all(axis=1)


def _chain_failures(center_start, start, center_end, end, wedges, covers, coincide):
    """Centres whose chains of wedges overlap (see the module docstring).

    ``center_start, start`` (s,): the start facets' centres and far vertices; ``center_end,
    end`` (e,) the same for end facets; ``wedges = (center, c, d)`` (w,) every wedge ``[c, d)``
    at those centres; ``covers(center_rows, c, d, f) -> bool`` whether wedge ``[c, d)`` covers
    the start direction ``f``; ``coincide(center_rows, f, g) -> bool`` whether directions
    ``f, g`` are the same.  Returns the failing centre keys (sorted, unique)."""
    wc, c, d = wedges
    i, j = _pairs_by_key(center_start, wc)
    hit = covers(j, c[j], d[j], start[i])
    count = np.bincount(i[hit], minlength=start.size)
    bad = [center_start[count != 1]]
    i, j = _pairs_by_key(center_start, center_end)
    same = coincide(i, start[i], end[j])
    bad.append(center_start[i[same]])
    return np.unique(np.concatenate(bad))


def fan_overlaps_2d(X, F):
    """Vertices around which a 2D map with every triangle positive is not locally injective.

    Parameters
    ----------
    X : (n, 2) float array, the map;  F : (m, 3) int array, counter-clockwise under ``X``.

    Returns
    -------
    branch : (k,) int64, interior vertices whose triangles wind around them other than once.
    overlaps : (q,) int64, boundary vertices whose fans overlap: they turn a full turn or more,
        or (non-manifold vertices) two fans meet.
    """
    X = np.asarray(X, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    B = boundary_half_edges(F)
    on_boundary = np.zeros(len(X), bool)
    on_boundary[B[:, 0]] = True
    used = np.zeros(len(X), bool)
    used[F.ravel()] = True
    branch = np.flatnonzero(used & ~on_boundary & (vertex_windings(X, F) != 1))
    if not B.size:
        return branch, np.zeros(0, np.int64)
    # corners (v, a, b): sector [a, b) at v; only those at boundary vertices matter
    corners = np.concatenate([F[:, [k, (k + 1) % 3, (k + 2) % 3]] for k in range(3)])
    corners = corners[on_boundary[corners[:, 0]]]
    v = corners[:, 0]

    def covers(j, c, d, f):
        P = X[v[j]]
        return (orient2d(P, X[c], X[f]) >= 0) & (orient2d(P, X[f], X[d]) > 0)

    def coincide(i, f, g):
        centre = B[i, 0]
        return (orient2d(X[centre], X[f], X[g]) == 0) & _same_sign_directions(X, centre, f, g)

    # a boundary half-edge (p -> q) starts the fan at p (towards q) and ends the one at q
    bad = _chain_failures(B[:, 0], B[:, 1], B[:, 1], B[:, 0], (v, corners[:, 1], corners[:, 2]),
                          covers, coincide)
    return branch, bad


# ---------------------------------------------------------------------------------- 3D


def _first_nonzero(N):
    """``(k,)`` the first non-zero entry of each row of ``N`` (k, 3) (0 if none)."""
    return np.where(N[:, 0] != 0, N[:, 0], np.where(N[:, 1] != 0, N[:, 1], N[:, 2]))


def _face_signs(X, T):
    """``(m, 4)`` int8: sign of ``n . u`` for face ``i`` of each tet (corners ``_FACES[i]`` in
    that order, ``n`` their normal) and the generic direction ``u`` (module docstring)."""
    P = X[T]  # (m, 4, 3)
    return np.stack([_first_nonzero(normal_signs(*(P[:, k] for k in face))) for face in _FACES], axis=1)


def _parity(perm) -> int:
    """0 for an even permutation (a sequence of distinct numbers), 1 for an odd one."""
    return sum(perm[a] > perm[b] for a in range(len(perm)) for b in range(a + 1, len(perm))) % 2


def _sigma(S, i, j, k):
    """Sign of ``n . u`` for the ordered face ``(i, j, k)`` of local corners: the stored face's
    sign times the parity of the reordering."""
    missing = 6 - i - j - k
    stored = _FACES[missing]
    odd = _parity([stored.index(x) for x in (i, j, k)])
    return -S[:, missing] if odd else S[:, missing]


def _boundary_faces(T):
    """``(tet, i)`` index arrays of the faces (face ``i`` omits corner ``i``) used by one tet."""
    m = len(T)
    faces = np.sort(np.concatenate([T[:, f] for f in _FACES]), axis=1)  # (4m, 3), face-major
    n = int(T.max()) + 1
    if float(n) ** 3 < 2.0**62:
        key = (faces[:, 0] * n + faces[:, 1]) * n + faces[:, 2]
        order = np.argsort(key)
        sk = key[order]
    else:
        order = np.lexsort(faces.T[::-1])
        sk = faces[order]
    differ = np.ones(len(order) + 1, bool)
    differ[1:-1] = (sk[1:] != sk[:-1]).reshape(len(order) - 1, -1).any(axis=1)
    single = order[differ[:-1] & differ[1:]]
    return single % m, single // m


def star_overlaps_3d(X, T, link=None):
    """Edges and vertices around which a tet map with every tet positive is not locally injective.

    Parameters
    ----------
    X : (n, 3) float array, the map;  T : (m, 4) int array, positively oriented under ``X``.
    link : (n,) bool or None, vertices whose own boundary tests are skipped: the boundary
        vertices that are not the apex of their star in :func:`geomopt.mesh.elements.corner_stars`
        (copies of an apex's edge neighbours), and the boundary edges between two of them.
        Those tests cannot fail there once every tet is positive and the edges to the apex pass:
        the tets at such a copy ``c`` all contain the edge from the apex ``v``, and seen from
        ``c`` their cones project, along ``c -> v``, onto angular wedges that turn about that
        edge once (closed fan) or less than a full turn (open fan), so no two of them overlap;
        an edge between two copies lies in at most the two tets of one shared face.  Each edge
        ``(v, c)`` is still tested (interior: winding; boundary: the chain of wedges).

    Returns
    -------
    branch_edges : (k, 2) int64, interior edges (sorted ids) whose tets turn other than once.
    branch_vertices : (k,) int64, interior vertices whose tets cover a neighbourhood other than once.
    boundary_edges : (q, 2) int64, boundary edges whose tets turn a full turn or more, or whose
        fans (non-manifold edges) meet.
    boundary_vertices : (q,) int64, boundary vertices whose stars overlap themselves.
    """
    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(T, dtype=np.int64)
    n = len(X)
    S = _face_signs(X, T)
    # winding of every edge at u: duplicated hits are edges covered more than once
    keys = []
    for i, j, k, l in _EVEN_EDGE:
        hit = (_sigma(S, i, j, k) > 0) & (_sigma(S, i, j, l) < 0)
        a, b = T[hit, i], T[hit, j]
        keys.append(np.minimum(a, b) * n + np.maximum(a, b))
    keys = np.sort(np.concatenate(keys))
    twice = np.unique(keys[1:][keys[1:] == keys[:-1]])
    # how many tets at each vertex contain u (and -u)
    up, down = np.zeros(n, np.int64), np.zeros(n, np.int64)
    for i, j, k, l in _EVEN_CORNER:
        s = np.stack([_sigma(S, i, k, l), _sigma(S, i, l, j), _sigma(S, i, j, k)])
        up += np.bincount(T[(s > 0).all(axis=0), i], minlength=n)
        down += np.bincount(T[(s < 0).all(axis=0), i], minlength=n)
    tet, face = _boundary_faces(T)
    on_boundary = np.zeros(n, bool)
    BF = np.stack([T[tet, f] for f in np.array(_FACES)[face].T], axis=1)  # (b, 3)
    on_boundary[BF.ravel()] = True
    lo_t, hi_t = twice // n, twice % n
    bkeys = np.concatenate([np.minimum(BF[:, a], BF[:, b]) * n + np.maximum(BF[:, a], BF[:, b])
                            for a, b in ((0, 1), (1, 2), (2, 0))])
    interior_edge = ~np.isin(twice, bkeys)
    branch_edges = np.stack([lo_t[interior_edge], hi_t[interior_edge]], axis=1)
    used = np.zeros(n, bool)
    used[T.ravel()] = True
    branch_vertices = np.flatnonzero(used & ~on_boundary & (up != 1))
    tested = on_boundary if link is None else on_boundary & ~np.asarray(link, bool)
    bad_edges = _boundary_edge_failures(X, T, tet, face, on_boundary, tested)
    # a boundary edge covered twice at u fails the chain test too; either way it is reported
    bad_edges = np.union1d(bad_edges, twice[~interior_edge])
    boundary_edges = np.stack([bad_edges // n, bad_edges % n], axis=1)
    bad_vertices = [np.flatnonzero(tested & (up > 1)),
                    _boundary_vertex_failures(X, T, BF, tet, face, up, down, tested)]
    return branch_edges, branch_vertices, boundary_edges, np.unique(np.concatenate(bad_vertices))


def _boundary_edge_failures(X, T, tet, face, on_boundary, tested):
    """Keys ``lo * n + hi`` of boundary edges (with an end in ``tested``) whose chains of wedges
    overlap."""
    n = len(X)
    # every (boundary face, edge): the face's third vertex starts or ends the chain about lo -> hi
    center_s, start, center_e, end = [], [], [], []
    for f_local, corners in enumerate(_FACES):
        rows = face == f_local
        t = tet[rows]
        for a in range(3):
            j, k, l = corners[a], corners[(a + 1) % 3], corners[(a + 2) % 3]
            # (j, k, l, f_local) even: the wedge about j -> k is [l, f_local)
            even = (_parity((j, k, l, f_local)) == 0)
            p, q, w = T[t, j], T[t, k], T[t, l]
            rows = tested[p] | tested[q]
            p, q, w = p[rows], q[rows], w[rows]
            key = np.minimum(p, q) * n + np.maximum(p, q)
            is_start = (p < q) == even
            center_s.append(key[is_start]), start.append(w[is_start])
            center_e.append(key[~is_start]), end.append(w[~is_start])
    center_s, start, center_e, end = map(np.concatenate, (center_s, start, center_e, end))
    # every wedge at those edges, in the lo -> hi direction
    wc, wcd = [], []
    for i, j, k, l in _EVEN_EDGE:
        p, q = T[:, i], T[:, j]
        rows = np.flatnonzero(on_boundary[p] & on_boundary[q] & (tested[p] | tested[q]))
        p, q, c, d = p[rows], q[rows], T[rows, k], T[rows, l]
        fwd = p < q
        wc.append(np.minimum(p, q) * n + np.maximum(p, q))
        wcd.append(np.stack([np.where(fwd, c, d), np.where(fwd, d, c)], axis=1))
    wc, wcd = np.concatenate(wc), np.concatenate(wcd)
    keep = np.isin(wc, center_s)
    wc, wcd = wc[keep], wcd[keep]

    def covers(j, c, d, f):
        lo, hi = X[wc[j] // n], X[wc[j] % n]
        return (orient3d(lo, hi, X[c], X[f]) >= 0) & (orient3d(lo, hi, X[f], X[d]) > 0)

    def coincide(i, f, g):
        lo, hi = X[center_s[i] // n], X[center_s[i] % n]
        flat = orient3d(lo, hi, X[f], X[g]) == 0  # then same half-plane iff same normal signs
        return flat & (normal_signs(lo, hi, X[f]) == normal_signs(lo, hi, X[g])).all(axis=1)

    return _chain_failures(center_s, start, center_e, end, (wc, wcd[:, 0], wcd[:, 1]), covers, coincide)




def _in_arc(X, v, p1, p2, x):
    """Whether direction ``x - v``, coplanar with ``v, p1, p2``, lies in the closed minor arc from
    ``p1 - v`` to ``p2 - v``: exact orientation within that plane, read off the coordinate
    projection on which the arc's plane does not degenerate."""
    V, P1, P2, Q = X[v], X[p1], X[p2], X[x]
    plane = normal_signs(V, P1, P2)
    col = np.argmax(plane != 0, axis=1)[:, None]  # a projection where the arc's plane is not flat
    sigma = np.take_along_axis(plane, col, 1)
    c1 = np.take_along_axis(normal_signs(V, P1, Q), col, 1)
    c2 = np.take_along_axis(normal_signs(V, Q, P2), col, 1)
    return ((sigma * c1 >= 0) & (sigma * c2 >= 0))[:, 0]


def _arcs_meet(X, v, p1, p2, q1, q2):
    """Whether the closed minor arcs ``[p1, p2]`` and ``[q1, q2]`` of directions seen from ``v``
    (rows of index arrays; each arc from a non-degenerate triangle) share a direction.  Exact.

    With ``s1, s2`` the sides of ``q1, q2`` of the plane through ``v, p1, p2`` and ``s3, s4`` those
    of ``p1, p2`` of the plane through ``v, q1, q2``: strictly on one side, apart; all four
    non-zero, the arcs cross iff ``s1 = -s3`` (the other crossing of the two great circles is
    the antipodal one); otherwise an endpoint on the other's plane is the only candidate (both
    on it: the arcs share a great circle and meet iff an endpoint lies in the other arc)."""
    V = X[v]
    s1 = orient3d(V, X[p1], X[p2], X[q1])
    s2 = orient3d(V, X[p1], X[p2], X[q2])
    s3 = orient3d(V, X[q1], X[q2], X[p1])
    s4 = orient3d(V, X[q1], X[q2], X[p2])
    near = (s1 * s2 <= 0) & (s3 * s4 <= 0)
    meet = near & (s1 != 0) & (s2 != 0) & (s3 != 0) & (s4 != 0) & (s1 == -s3)
    # an endpoint on the other arc's plane: a common point iff it lies in that arc (when one
    # of the tests applies, one of them is the only candidate; each true test is a common point)
    for a, b, x, on_plane in ((p1, p2, q1, s1), (p1, p2, q2, s2), (q1, q2, p1, s3), (q1, q2, p2, s4)):
        rows = np.flatnonzero(near & (on_plane == 0))
        if rows.size:
            meet[rows] |= _in_arc(X, v[rows], a[rows], b[rows], x[rows])
    return meet


def _boundary_vertex_failures(X, T, BF, tet, face, up, down, tested):
    """Boundary vertices (of ``tested``) whose stars overlap: two boundary faces at the vertex
    sharing only it meet elsewhere (the link boundary is not simple), or the count just inside
    a boundary cycle of a non-manifold vertex is not 1 (module docstring).  ``BF`` (b, 3) the
    boundary faces, of tets ``T[tet]`` omitting corner ``face``; ``up, down`` (n,) the counts
    at ``+-u``."""
    n = len(X)
    # corners of boundary faces: (vertex, the two other vertices: the arc seen from it)
    cv = BF.T.ravel()  # corner a of face r is entry a * b + r
    c1 = np.roll(BF, -1, axis=1).T.ravel()
    c2 = np.roll(BF, -2, axis=1).T.ravel()
    corner = np.flatnonzero(tested[cv])  # every corner of a tested vertex, none of the others
    cv, c1, c2 = cv[corner], c1[corner], c2[corner]
    i, j = _pairs_by_key(cv, cv)
    keep = (i < j) & (c1[i] != c1[j]) & (c1[i] != c2[j]) & (c2[i] != c1[j]) & (c2[i] != c2[j])
    i, j = i[keep], j[keep]
    bad = [cv[i[_arcs_meet(X, cv[i], c1[i], c2[i], c1[j], c2[j])]]]
    # boundary cycles at each vertex: corners linked through a shared boundary edge at it
    ends = np.concatenate([cv * n + c1, cv * n + c2])
    node = np.concatenate([np.arange(cv.size)] * 2)
    order = np.argsort(ends, kind="stable")
    link = np.flatnonzero(ends[order][1:] == ends[order][:-1])
    _, label = graph_components(cv.size, node[order][link], node[order][link + 1])
    first = np.unique(label, return_index=True)[1]  # one corner per cycle
    cycles = np.bincount(cv[first], minlength=n)
    need = (cycles > 1) | ((cycles == 1) & (up > 0) & (down > 0))
    pick = first[need[cv[first]]]
    if pick.size:
        r = corner[pick] % len(BF)
        q = T[tet[r], face[r]]  # the tet's vertex off the boundary face
        count = _inner_counts(X, T, cv[pick], c1[pick], c2[pick], q)
        bad.append(cv[pick][count != 1])
    return np.unique(np.concatenate(bad))


def _inner_counts(X, T, v, p1, p2, q):
    """For each row, how many tets at ``v`` contain the direction ``r = p1 + eps (p2 - p1) +
    eps^2 (q - p1)`` seen from ``v`` (just inside the boundary face ``(v, p1, p2)`` of tet
    ``(v, p1, p2, q)``, near ``p1``).  Exact: each orientation test against ``r`` is the first
    non-zero of the tests against ``p1``, ``p2``, ``q`` (affine in its last argument)."""
    sel = np.zeros(len(X), bool)
    sel[v] = True
    count = np.zeros(v.size, np.int64)
    for i, j, k, l in _EVEN_CORNER:
        tets = np.flatnonzero(sel[T[:, i]])
        a, b = _pairs_by_key(v, T[tets, i])
        t = tets[b]
        V = X[v[a]]
        inside = np.ones(a.size, bool)
        for x, y in ((k, l), (l, j), (j, k)):  # the faces at corner i, outward order
            Px, Py = X[T[t, x]], X[T[t, y]]
            s = np.zeros(a.size, np.int8)
            todo = np.arange(a.size)
            for target in (p1, p2, q):
                s[todo] = orient3d(V[todo], Px[todo], Py[todo], X[target[a[todo]]])
                todo = todo[s[todo] == 0]
            inside &= s > 0
        count += np.bincount(a[inside], minlength=v.size)
    return count

"""Quadrilaterals and hexahedra as corner simplices: corners, rest matrices, validity, quality.

A quad ``(0, 1, 2, 3)`` (counter-clockwise) is the image of the unit square under a bilinear
map, a hex (VTK order: bottom ``0 1 2 3`` counter-clockwise seen from above, top ``4 5 6 7``
above it) the image of the unit cube under a trilinear map.  Following Garanzha et al.'s
untangling code (and Gmsh's re-implementation of it), an element is evaluated at its
corners: corner ``c`` with its two (quad) or three (hex) edge neighbours is a *corner
simplex* (a triangle or tetrahedron), whose Jacobian ``J_c = [x_a - x_c, ...] @ inv(rest
edges)`` equals the derivative of the element's map at that corner (up to the rest frame).
A quad gives 4 corner triangles, a hex 8 corner tetrahedra (:data:`QUAD_CORNERS`,
:data:`HEX_CORNERS`), listed element-major (corner ``c`` of element ``e`` is row ``k e + c``).

Weights.  Each corner simplex is weighted by its own rest size (area / volume), exactly as a
simplex: the energy of a quad mesh is the triangle energy of its four corner triangles.  The
corner triangles of a quad cover it twice (corners 0 and 2 tile it along the diagonal 1-3,
corners 1 and 3 along 0-2), so a quad's corners weigh twice its area, and its energy is the
sum of the energies of the two diagonal triangulations; a parallelepiped hex's corners weigh
4/3 of its volume.  Downstream (energies, the injective search, solvers) corner simplices are
plain simplices.

Validity.  A bilinear quad has ``det J`` bilinear in ``(u, v)`` with the corner values as its
coefficients, so it is positive everywhere iff the four corner triangles are positive (exact
:func:`~geomopt.exact.predicates.orient2d`).  A trilinear hex needs more than its corners:
:mod:`geomopt.exact.hexvalid` proves ``det J > 0`` inside from Bernstein coefficients.

Local injectivity.  Elements with a positive Jacobian everywhere, sharing facets, can still
wind twice around a vertex or an edge, or overlap at the boundary.  Around a vertex ``v`` the
map is, to first order, linear on each element's tangent cone at ``v``: the cone of its corner
simplex *at* ``v`` (corner ``v`` and its edge neighbours).  These corner simplices, one per
element at ``v`` (:func:`corner_stars`), tile a neighbourhood of ``v`` without overlap, unlike
all the corner simplices together; the fan/star tests of :mod:`geomopt.exact.stars` run on them, so
a vertex's winding and its boundary fan are those of the element map (a homotopy ``x ->
(f(v + t x) - f(v)) / t`` to the tangent map keeps the degree), and an edge's winding, an
integer sum of the elements' dihedral angles along it, continuous along the edge and so
constant, is read at its ends.  :func:`element_local_certificate` is that certificate.

Quality: the scaled Jacobian, the smallest over the corners of ``det [e_1 .. e_d] / prod |e_i|``
with ``e_i`` the corner's edges (1 for a square / cube, 0 for a degenerate corner, negative
when inverted; Knupp, "Achieving finite element mesh quality via optimization of the Jacobian
matrix norm and associated quantities", IJNME 48, 2000).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from .._runtime.errors import MeshError, ParameterError
from .._runtime.validate import validate_simplices
from ..exact.certify import LocalCertificate, fixed_star_certificate, local_certificate
from ..exact.hexvalid import HEX_CORNERS, TESTS, hex_validity
from ..exact.predicates import orient2d
from ..exact.topology import repeated_elements
from ..io import CELL_WORDS

__all__ = ["QUAD_CORNERS", "HEX_CORNERS", "ELEMENT_KINDS", "ElementKind", "kind_of", "kind_named", "ElementCertificate", "Quality",
           "validate_elements", "corner_simplices", "corner_edges", "rest_elements",
           "reference_rest", "check_element_facets", "boundary_vertices",
           "scaled_jacobian", "quality", "certify_elements", "count_invalid", "valid_elements", "element_type",
           "corner_stars", "ElementLocalCertificate", "element_local_certificate", "element_fixed_star_certificate"]

#: Corner triangles of a quad: corner ``c`` then its neighbours ``c + 1`` and ``c - 1``.
QUAD_CORNERS = np.array([[0, 1, 3], [1, 2, 0], [2, 3, 1], [3, 0, 2]], dtype=np.int64)


@dataclasses.dataclass(frozen=True)
class ElementKind:
    """One kind of element evaluated at its corners: every fact about it that the library
    needs, in one row of :data:`ELEMENT_KINDS` (a new element type is a row here, its exact
    validity test, and its problem constructor).

    Attributes
    ----------
    word : its cell name in the files (:data:`geomopt.io.CELL_KINDS`) and in messages;
        :attr:`words`, the plural, is the files' table's (:data:`geomopt.io.CELL_WORDS`).
    dim : the dimension of its map (2: quads, 3: hexahedra); corner simplices have ``dim + 1``
        vertices.
    corners : (k, dim + 1) its corner simplices, as vertex positions in the element.
    reverse : (k,) a vertex permutation reversing its orientation.
    facets : (f, 2 or 4) its edges (quads) / faces (hexahedra), oriented outwards.
    edges : (e, 2) its edges.
    reference : (k, dim) the unit square / cube.
    map_file : the extension a map of these elements is written as (``.obj`` quads, ``.vtk``
        hexahedra).
    constructor : the :class:`~geomopt.mesh.problem.Problem` class method that makes a
        problem of them (:meth:`~geomopt.mesh.problem.Problem.cells` dispatches on it).
    problem_kind : the :attr:`~geomopt.mesh.problem.Problem.kind` of that problem (``"quad"``,
        ``"hex"``): what the writers and the viewer look the kind up by.
    vtk : its VTK cell type (9 quad, 12 hexahedron), the cell type of the files' readers and of
        the viewer (pyvista's ``CellType`` is VTK's).
    validity : ``(X, E) -> (valid, corner_valid, tests)``: the exact test that each element
        has a positive Jacobian everywhere under ``X`` (and at its corners), with the count of
        each test of :data:`~geomopt.exact.hexvalid.TESTS` it ran.
    """

    word: str
    dim: int
    corners: np.ndarray
    reverse: np.ndarray
    facets: np.ndarray
    edges: np.ndarray
    reference: np.ndarray
    map_file: str
    constructor: str
    validity: Callable
    problem_kind: str
    vtk: int

    @property
    def n_vertices(self) -> int:
        return len(self.reference)

    @property
    def words(self) -> str:
        """Its name in the plural (messages), from :data:`geomopt.io.CELL_WORDS`."""
        return CELL_WORDS[self.word][1]


def _quad_validity(X, E):
    """Quads: positive at the four corners, which is exact and sufficient for a bilinear quad."""
    C = E[:, QUAD_CORNERS].reshape(-1, 3)
    valid = (orient2d(X[C[:, 0]], X[C[:, 1]], X[C[:, 2]]) == 1).reshape(len(E), 4).all(axis=1)
    return valid, valid, {name: (len(E) if name == "corners" else 0) for name in TESTS}


def _hex_validity(X, E):
    """Hexahedra: corners, then the Bernstein test with subdivision (:func:`hex_validity`)."""
    r = hex_validity(X, E)
    return r.valid, r.corner_valid, r.tests


#: vertices per element -> its :class:`ElementKind`
ELEMENT_KINDS = {
    4: ElementKind("quad", 2, QUAD_CORNERS, np.array([0, 3, 2, 1]),
                   np.array([[0, 1], [1, 2], [2, 3], [3, 0]]), np.array([[0, 1], [1, 2], [2, 3], [3, 0]]),
                   np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64), ".obj", "quads", _quad_validity, "quad", 9),
    8: ElementKind("hexahedron", 3, HEX_CORNERS, np.array([0, 3, 2, 1, 4, 7, 6, 5]),
                   np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]),
                   np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6],
                             [3, 7]]),
                   np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
                            dtype=np.float64), ".vtk", "hexes", _hex_validity, "hex", 12),
}


def kind_named(problem_kind) -> ElementKind | None:
    """The :class:`ElementKind` whose problems have :attr:`~geomopt.mesh.problem.Problem.kind`
    ``problem_kind`` (``"quad"``, ``"hex"``), None for a problem of simplices."""
    return next((k for k in ELEMENT_KINDS.values() if k.problem_kind == problem_kind), None)


def kind_of(E) -> ElementKind:
    """The :class:`ElementKind` of elements ``E`` (m, k) by their vertex count ``k``;
    MeshError naming the kinds there are."""
    E = np.asarray(E)
    kind = ELEMENT_KINDS.get(E.shape[1]) if E.ndim == 2 else None
    if kind is None:
        raise MeshError(f"elements of shape {E.shape} are of no known kind: "
                        + ", ".join(f"{k.words} have {n} vertices" for n, k in ELEMENT_KINDS.items()))
    return kind


def element_type(E) -> tuple:
    """``(name, plural)`` of elements ``E`` (m, 4) or (m, 8)."""
    kind = kind_of(E)
    return kind.word, kind.words


def validate_elements(E, n_vertices, k, name=None) -> np.ndarray:
    """Check quads (``k = 4``) or hexahedra (``k = 8``) and return them as ``int64`` (m, k)
    (:func:`geomopt._runtime.validate.validate_simplices` with the element's words).

    Raises
    ------
    MeshError
        Wrong shape or dtype, no element, an index outside ``0 .. n_vertices - 1``, or an
        element that uses a vertex twice.
    """
    kind = ELEMENT_KINDS[k]
    return validate_simplices(E, n_vertices, k, name or kind.words, words=(kind.word, kind.words))


def corner_simplices(E) -> np.ndarray:
    """Corner simplices of elements ``E`` (m, 4) -> (4 m, 3) or (m, 8) -> (8 m, 4), element-major."""
    kind = kind_of(E)
    return np.asarray(E)[:, kind.corners].reshape(-1, kind.dim + 1)


def corner_edges(X, E) -> np.ndarray:
    """Edge matrices of the corner simplices, edges as columns: (m k, d, d) for ``X`` (n, d)."""
    S = corner_simplices(E)
    with np.errstate(all="ignore"):
        return np.swapaxes(X[S[:, 1:]] - X[S[:, :1]], 1, 2)


def _corner_dets(X, E):
    """(m, k) float determinants of the corner edge matrices."""
    return np.linalg.det(corner_edges(X, E)).reshape(len(E), -1)


def rest_elements(V, E, rest="mesh"):
    """Orient elements ``E`` on rest positions ``V`` and check them.

    Parameters
    ----------
    V : (n, d) rest positions: (n, 2) planar quads, (n, 3) a quad surface or hexahedra.
    E : (m, k) validated elements (:func:`validate_elements`).
    rest : ``"mesh"`` (``V``'s elements are the rest shapes: each must be valid) or
        ``"reference"`` (only the orientation is taken from ``V``).

    Returns
    -------
    E_oriented : (m, k), ``E`` or every element reversed (when ``V``'s total signed size is
    negative; a quad surface keeps its orientation).

    Raises
    ------
    MeshError
        Rest ``"mesh"``: a quad that is not strictly convex (non-convex, a bow tie, a flat or
        zero-length corner), a quad of a surface twisted against its mean normal, a hexahedron
        whose ``det J`` is not positive everywhere (exact), elements oriented against the
        others.  Any rest: a non-manifold or inconsistently oriented edge / face
        (:func:`check_element_facets`).
    """
    kind = ELEMENT_KINDS[E.shape[1]]
    if rest not in ("mesh", "reference"):
        raise ParameterError(f"rest must be 'mesh' or 'reference', got {rest!r}")
    surface = kind.word == "quad" and V.shape[1] == 3
    if not surface and float(np.sum(_corner_dets(V, E))) < 0:
        E = E[:, kind.reverse]
    if rest == "mesh":
        _check_rest_shapes(V, E, kind, surface)
    check_element_facets(E, len(V))
    return E


def _check_rest_shapes(V, E, kind, surface):
    if surface:
        ok = _untwisted(V, E)
    else:
        ok = valid_elements(V, E)
    if ok.all():
        return
    bad = np.flatnonzero(~ok)
    against = np.zeros(0, np.int64) if surface else bad[valid_elements(V, E[bad][:, kind.reverse])]
    if against.size:
        raise MeshError(
            f"{against.size} rest {kind.words} are oriented against the others (first: {against[:5].tolist()}); "
            f"list every {kind.word} with the same orientation "
            f"({'counter-clockwise' if kind.word == 'quad' else 'VTK order: bottom face, then the top one'})")
    shape = ("twisted (a corner triangle faces against the quad's mean normal) or degenerate" if surface else
             "not strictly convex (non-convex, twisted into a bow tie, or with a flat or zero-length corner)"
             if kind.word == "quad" else "not valid inside (det J <= 0 somewhere: twisted, inverted or degenerate)")
    raise MeshError(f"{bad.size} rest {kind.words} are {shape} (first: {bad[:5].tolist()}); repair the rest "
                    f"mesh: an element without a positive Jacobian has no shape to measure a map against")


def _untwisted(V, Q):
    """(m,) quads of a 3D surface whose four corner triangles all face along the quad's mean
    (Newell) normal."""
    C = corner_simplices(Q)
    n = np.cross(V[C[:, 1]] - V[C[:, 0]], V[C[:, 2]] - V[C[:, 0]]).reshape(len(Q), 4, 3)
    mean = n.sum(axis=1, keepdims=True)
    return (np.einsum("mki,mki->mk", n, np.broadcast_to(mean, n.shape)) > 0).all(axis=1)


def valid_elements(X, E) -> np.ndarray:
    """(m,) bool: exact validity of each element ``E`` (oriented) under ``X``: a positive
    Jacobian everywhere (quads: the four corners; hexahedra: :func:`~geomopt.exact.hexvalid.hex_validity`)."""
    return kind_of(E).validity(X, E)[0]


def reference_rest(V, E) -> np.ndarray:
    """Rest edge matrices (m k, d, d) of the reference element -- the unit square or cube
    scaled by the mean edge length of ``E`` on ``V`` -- for every element (Winslow smoothing:
    the computational element).  ``E`` must already be oriented."""
    kind = ELEMENT_KINDS[E.shape[1]]
    h = float(np.mean(np.linalg.norm(V[E[:, kind.edges[:, 1]]] - V[E[:, kind.edges[:, 0]]], axis=-1)))
    if not (np.isfinite(h) and h > 0):
        raise MeshError(f"the {kind.words} have a zero or non-finite mean edge length: the mesh is degenerate")
    Dm = corner_edges(kind.reference * h, np.arange(len(kind.reference))[None])  # (k, d, d)
    return np.tile(Dm, (len(E), 1, 1))


def check_element_facets(E, n_vertices) -> None:
    """Reject non-manifold or inconsistently oriented elements: every quad edge (hex face) is
    used by at most two elements, traversed in opposite directions.

    Raises
    ------
    MeshError
        Naming how many facets fail and the first elements involved.
    """
    kind = ELEMENT_KINDS[E.shape[1]]
    word, words = kind.word, kind.words
    facet = "edge" if word == "quad" else "face"
    key, sign, owner = _facets(E, n_vertices)
    order = np.lexsort((sign, key))
    key, sign, owner = key[order], sign[order], owner[order]
    uniq, start, counts = np.unique(key, return_index=True, return_counts=True)
    many = counts > 2
    if many.any():
        first = owner[start[np.flatnonzero(many)[0]]]
        raise MeshError(f"{int(many.sum())} non-manifold {facet}s (shared by more than two {words}; {word} "
                        f"{first}): every map of such a mesh folds there; split or remove the extra {words}"
                        + repeated_elements(E, word))
    pair = np.flatnonzero(counts == 2)
    same = sign[start[pair]] == sign[start[pair] + 1]
    if same.any():
        i = start[pair[same]]
        els = np.unique(np.concatenate([owner[i], owner[i + 1]]))
        raise MeshError(f"inconsistent orientation: {int(same.sum())} {facet}(s) are traversed the same way by "
                        f"two {words} ({words} {els[:6].tolist()}): a {word} is listed with the opposite "
                        f"orientation, or two {words} overlap; orient every {word} the same way")


def _facets(E, n):
    """Facets of every element (quad edges / hex faces), as an unoriented int key, an
    orientation bit and the owning element: each (m f,)."""
    facets = ELEMENT_KINDS[E.shape[1]].facets
    F = E[:, facets].reshape(-1, facets.shape[1])  # (m f, 2 or 4)
    owner = np.repeat(np.arange(len(E)), len(facets))
    if F.shape[1] == 2:
        return np.minimum(F[:, 0], F[:, 1]) * n + np.maximum(F[:, 0], F[:, 1]), F[:, 0] < F[:, 1], owner
    # a face cycle starting at its smallest vertex: (min, next, opposite, prev)
    r = np.argmin(F, axis=1)
    idx = (r[:, None] + np.arange(4)) % 4
    C = np.take_along_axis(F, idx, axis=1)
    lo, hi = np.minimum(C[:, 1], C[:, 3]), np.maximum(C[:, 1], C[:, 3])
    if float(n) ** 4 < 2.0**62:
        key = ((C[:, 0] * n + lo) * n + C[:, 2]) * n + hi
    else:
        key = np.unique(np.stack([C[:, 0], lo, C[:, 2], hi], 1), axis=0, return_inverse=True)[1].ravel()
    return key, C[:, 1] < C[:, 3], owner


def boundary_vertices(E, n_vertices) -> np.ndarray:
    """Sorted ids of the vertices on boundary facets (quad edges / hex faces used once)."""
    E = np.asarray(E)
    key, _, _ = _facets(E, n_vertices)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    facets = ELEMENT_KINDS[E.shape[1]].facets
    F = E[:, facets].reshape(-1, facets.shape[1])
    on = np.zeros(n_vertices, bool)
    on[F[counts[inverse.ravel()] == 1].ravel()] = True
    return np.flatnonzero(on)


# ------------------------------------------------------------------ quality and certificate


def scaled_jacobian(X, E) -> np.ndarray:
    """(m,) scaled Jacobian of each element under ``X``: the smallest over its corners of
    ``det[e_1, ..., e_d] / (|e_1| ... |e_d|)`` (1 for a square / cube; <= 0 when a corner is
    inverted or flat).  ``X`` (n, d) with d = 2 for quads, 3 for hexahedra; a zero-length
    edge gives -1 (the worst)."""
    X = np.asarray(X, dtype=np.float64)
    M = corner_edges(X, E)
    with np.errstate(all="ignore"):
        norms = np.prod(np.linalg.norm(M, axis=1), axis=-1)
        sj = np.linalg.det(M) / norms
    sj = np.where(np.isfinite(sj), sj, -1.0)
    return sj.reshape(len(E), -1).min(axis=1)


@dataclasses.dataclass(frozen=True)
class Quality:
    """Scaled-Jacobian figures of a quad or hex mesh (what mesh generators report).

    Attributes
    ----------
    min, mean : float, smallest and mean scaled Jacobian.
    below_0, below_0_2 : int, elements with a scaled Jacobian below 0 and below 0.2.
    elements : int.
    """

    min: float
    mean: float
    below_0: int
    below_0_2: int
    elements: int

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def quality(X, E) -> Quality:
    """The :class:`Quality` of elements ``E`` under ``X`` (see :func:`scaled_jacobian`)."""
    sj = scaled_jacobian(X, E)
    return Quality(float(sj.min()), float(sj.mean()), int(np.count_nonzero(sj < 0)),
                   int(np.count_nonzero(sj < 0.2)), len(E))


@dataclasses.dataclass(frozen=True)
class ElementCertificate:
    """Exact validity of every quad / hex of a map (:func:`certify_elements`).

    Attributes
    ----------
    valid : (m,) bool, ``det J > 0`` over the whole element (exact).
    corner_valid : (m,) bool, every corner simplex positive (exact).
    tests : dict, how many elements each test decided: ``corners`` (quads: always, and
        sufficient; hexes: a corner not positive), ``bernstein``, ``subdivision``, ``exact``,
        ``undecided`` (hexes, :mod:`geomopt.exact.hexvalid`).
    quality : :class:`Quality` of the map.
    """

    valid: np.ndarray
    corner_valid: np.ndarray
    tests: dict
    quality: Quality

    @property
    def invalid(self) -> int:
        return int(np.count_nonzero(~self.valid))

    @property
    def corner_only(self) -> int:
        """Elements whose corners are positive but which fold inside (hexes only)."""
        return int(np.count_nonzero(self.corner_valid & ~self.valid))

    @property
    def certified(self) -> bool:
        return self.invalid == 0

    def summary(self) -> dict:
        tests = {k: v for k, v in self.tests.items() if v}
        return {"elements": len(self.valid), "invalid": self.invalid, "corner_only": self.corner_only,
                "tests": tests, **{f"sj_{k}": v for k, v in self.quality.as_dict().items() if k != "elements"}}


def certify_elements(X, E) -> ElementCertificate:
    """Exact certificate that each quad (``X`` (n, 2)) or hexahedron (``X`` (n, 3)) of ``E``
    (oriented) has a positive Jacobian everywhere, with the mesh's :class:`Quality`.

    Quads: the four corner orientations (exact, and sufficient).  Hexahedra: corners, then
    the Bernstein test with subdivision of :func:`geomopt.exact.hexvalid.hex_validity`.
    """
    X = np.asarray(X, dtype=np.float64)
    E = np.asarray(E)
    valid, corner_valid, tests = kind_of(E).validity(X, E)
    return ElementCertificate(valid, corner_valid, tests, quality(X, E))


def count_invalid(X, E) -> int:
    """Elements of ``E`` (oriented) not certified valid under ``X`` (exact)."""
    return int(np.count_nonzero(~valid_elements(np.asarray(X, dtype=np.float64), np.asarray(E))))


def corner_stars(E, n_vertices):
    """The corner simplices of elements ``E`` (m, 4) or (m, 8) regrouped as disjoint stars: the
    star of vertex ``v`` holds the corner simplex *at* ``v`` of each element at ``v``, with its
    far vertices replaced by copies owned by ``v`` (so stars share no vertex).

    Returns
    -------
    S : (m k, d + 1) int64, the corner simplices, apex first, over the new vertex ids.
    source : (N,) int64, the original vertex each new id stands for (``source[:n_vertices]``
        is the identity: apexes keep their ids; copies follow).
    """
    C = corner_simplices(np.asarray(E))
    far = C[:, 1:]
    copies, inverse = np.unique(C[:, :1] * n_vertices + far, return_inverse=True)
    S = np.column_stack([C[:, 0], n_vertices + inverse.reshape(far.shape)])
    return S, np.concatenate([np.arange(n_vertices), copies % n_vertices])


@dataclasses.dataclass(frozen=True)
class ElementLocalCertificate(LocalCertificate):
    """:class:`~geomopt.exact.certify.LocalCertificate` of a quad or hex map (:func:`element_local_certificate`).

    ``inverted`` counts elements without a positive Jacobian everywhere (``first_inverted``:
    the first); the vertex and edge lists are in the mesh's vertex ids.  ``elements``: the
    :class:`ElementCertificate` (which test decided each element, how many are only
    corner-valid, the quality); ``words``: what the elements are called ("quads", "hexahedra").
    """

    elements: ElementCertificate | None = None
    words: str = "elements"

    @property
    def message(self) -> str:
        """One line naming the first failure ("" when :attr:`ok`)."""
        if not self.inverted or self.elements is None:
            return super().message.replace("tets", self.words)
        folded = self.elements.corner_only
        inside = (f", {folded} of them with every corner positive but folded inside (exact Bernstein test)"
                  if folded else "")
        return (f"{self.inverted} {self.words} without a positive Jacobian everywhere (first: element "
                f"{self.first_inverted}){inside}")


def element_local_certificate(X, E) -> ElementLocalCertificate:
    """Exact certificate that a quad map (``X`` (n, 2)) or hexahedral map (``X`` (n, 3)) of
    oriented elements ``E`` (m, 4) / (m, 8) is locally injective.

    Every element must have a positive Jacobian everywhere (:func:`certify_elements`: quads by
    their corners, hexahedra by Bernstein coefficients); then the fans / stars around every
    vertex and edge are checked on the tangent cones (:func:`corner_stars`, module notes),
    never on the overlapping corner simplices as one mesh.

    Returns
    -------
    :class:`ElementLocalCertificate`; ``ok`` iff the map is locally injective.
    """
    t0 = time.perf_counter()
    X = np.asarray(X, dtype=np.float64)
    E = np.asarray(E, dtype=np.int64)
    cert = certify_elements(X, E)
    bad = np.flatnonzero(~cert.valid)
    words = ELEMENT_KINDS[E.shape[1]].words
    if bad.size:
        return ElementLocalCertificate(int(bad.size), int(bad[0]), seconds=time.perf_counter() - t0,
                                       elements=cert, words=words)
    S, source = corner_stars(E, len(X))
    star = local_certificate(X[source], S, link=np.arange(len(source)) >= len(X))
    if star.inverted:  # valid elements have positive corners: never, but never certify then
        return ElementLocalCertificate(star.inverted, int(star.first_inverted) // E.shape[1],
                                       seconds=time.perf_counter() - t0, elements=cert, words=words)

    return _in_mesh_ids(star, source, t0, cert, words)


def _in_mesh_ids(star, source, t0, cert, words):
    """``star`` (a certificate of the :func:`corner_stars` complex) in the mesh's vertex ids."""
    def edges(A):
        return np.unique(np.sort(source[A], axis=1), axis=0) if len(A) else A

    return ElementLocalCertificate(
        star.inverted, star.first_inverted, np.unique(source[star.branch_vertices]), edges(star.branch_edges),
        np.unique(source[star.boundary_overlaps]), edges(star.boundary_edge_overlaps),
        time.perf_counter() - t0, elements=cert, words=words)


def element_fixed_star_certificate(X, E, fixed) -> ElementLocalCertificate:
    """The part of :func:`element_local_certificate` that no free vertex can change: vertices
    and edges whose tangent cones (the corner simplices at the vertex, :func:`corner_stars`)
    have every vertex fixed (:func:`geomopt.exact.certify.fixed_star_certificate` on that complex).
    ``ok`` when none of them overlaps; an overlap there makes every map with these handles fail.

    Parameters
    ----------
    X : (n, 2) or (n, 3) float array
        A map with the handles in place.
    E : (m, 4) or (m, 8) int array
        Oriented quads or hexahedra.
    fixed : (h,) int array
        The fixed vertices.
    """
    t0 = time.perf_counter()
    X = np.asarray(X, dtype=np.float64)
    E = np.asarray(E, dtype=np.int64)
    S, source = corner_stars(E, len(X))
    is_fixed = np.zeros(len(X), bool)
    is_fixed[np.asarray(fixed, dtype=np.int64)] = True
    star = fixed_star_certificate(X[source], S, np.flatnonzero(is_fixed[source]))
    return _in_mesh_ids(star, source, t0, None, ELEMENT_KINDS[E.shape[1]].words)

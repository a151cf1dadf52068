"""Exact certificates: local injectivity of any simplicial map, global injectivity of a disk map.

Local (:func:`local_certificate`): every element positively oriented, and around every vertex
(2D) or edge and vertex (3D) the elements cover a neighbourhood once (interior) or without
overlapping (boundary); see :mod:`geomopt.exact.stars` for what is checked and why it suffices.

Global, for a disk map:

A map ``x`` (n, 2) of a triangulated disk with faces ``F`` is *globally injective* when

1. every triangle is positively oriented (the local certificate,
   :func:`geomopt.exact.predicates.count_inverted`), and
2. the boundary polygon ``x[loop]`` is simple (:func:`polygon_crossings` finds no pair), and
3. the boundary polygon runs counter-clockwise (:func:`polygon_orientation` is ``+1``).

Why this suffices (degree theory): for a point ``p`` of the plane not on the image of an edge,
the number of triangles whose image contains ``p``, each counted with its orientation sign, equals
the winding number of the image of the boundary loop around ``p`` (both are the degree of the
piecewise-linear map over ``p``; e.g. Lipman 2012, "Bounded distortion mapping spaces for
triangular meshes", or Weber & Zorin 2014, "Locally injective parametrization with arbitrary fixed
boundaries").  With every triangle positive the count is the plain number of preimages; a simple
counter-clockwise polygon winds once around its inside and zero times around its outside, so
almost every point has at most one preimage: the open triangles are disjoint, and a vertex or edge
mapped onto another part of the mesh would make nearby points covered twice.  Condition 3 follows
from 1 and 2 (the polygon's signed area is the sum of the triangles' areas), but it is checked on
its own, exactly, so that the certificate does not rest on rounded sums.

Crossing, precisely.  Edge ``i`` of a closed polygon ``P`` (k, 2) is the closed segment from
``P[i]`` to ``P[(i + 1) % k]``.  Two edges that share no vertex index must not meet at all:
touching (a vertex on the other edge, or two equal vertices) counts as crossing, since it already
maps two boundary points to one.  Two consecutive edges share their common vertex and must meet
only there: they fail when they overlap along a segment (the polygon doubles back on itself,
``P[i], P[i+1], P[i+2]`` collinear with ``P[i+2]`` on the side of ``P[i]``), and a zero-length
edge fails with both its neighbours.

Every decision is exact (:func:`geomopt.exact.predicates.orient2d`, filtered float with an exact
fallback, and float comparisons, which are exact).  The broad phase is a uniform grid: each edge
is entered in the cells its bounding box covers (vectorised NumPy), the entries are sorted by
cell, and each pair of edges in a cell is a candidate; a pair is kept only in the cell holding the
lower-left corner of the intersection of the two bounding boxes, which both boxes cover (the floor
of a rounded product with 1 / cell size is monotone) and which removes duplicates without a second sort.
"""

from __future__ import annotations

import collections
import dataclasses
import time

import numpy as np

from .._runtime.errors import MeshError, ParameterError
from .._runtime.tracing import digest, refuse_traced
from .._runtime.validate import validate_indices
from .polygons import loop_crossings, polygon_crossings, polygon_orientation
from .predicates import cone_orientations, simplex_orientations
from .stars import fan_overlaps_2d, star_overlaps_3d
from .topology import check_disk

__all__ = ["Certificate", "LocalCertificate", "SphereCertificate", "certify_bijective", "certify_sphere",
           "fixed_star_certificate", "local_certificate", "loop_crossings", "polygon_crossings",
           "polygon_orientation", "spherical_areas"]

# Largest number of (edge, cell) entries per edge before the grid cells are made coarser.


def _no_vertices():
    return np.zeros(0, np.int64)


def _no_edges():
    return np.zeros((0, 2), np.int64)


@dataclasses.dataclass(frozen=True)
class LocalCertificate:
    """The outcome of :func:`local_certificate`: where a map is not locally injective.

    Attributes
    ----------
    inverted : int, elements not positively oriented (inverted or degenerate; exact).
    first_inverted : int, the first such element, or -1.
    branch_vertices : (k,) int64, interior vertices whose elements cover their neighbourhood
        more than once (2D: triangles winding around them twice or more; 3D: a pinched star).
    branch_edges : (k, 2) int64, interior edges whose tets turn around them more than once (3D).
    boundary_overlaps : (k,) int64, boundary vertices whose elements overlap each other (2D: the
        fan turns a full turn or more; 3D: boundary faces at the vertex meet away from it).
    boundary_edge_overlaps : (k, 2) int64, boundary edges whose tets turn a full turn or more (3D).
    seconds : float, time taken.

    The vertex and edge lists are only computed when no element is inverted (they assume it);
    with an inverted element they are empty.
    """

    inverted: int
    first_inverted: int = -1
    branch_vertices: np.ndarray = dataclasses.field(default_factory=_no_vertices)
    branch_edges: np.ndarray = dataclasses.field(default_factory=_no_edges)
    boundary_overlaps: np.ndarray = dataclasses.field(default_factory=_no_vertices)
    boundary_edge_overlaps: np.ndarray = dataclasses.field(default_factory=_no_edges)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """The map is locally injective (certified exactly)."""
        return self.inverted == 0 and not (len(self.branch_vertices) or len(self.branch_edges)
                                           or len(self.boundary_overlaps) or len(self.boundary_edge_overlaps))

    @property
    def message(self) -> str:
        """One line naming the first failure ("" when :attr:`ok`)."""
        def more(k, what):
            return f" ({k} such {what})" if k > 1 else ""

        if self.inverted:
            return (f"{self.inverted} element(s) inverted or degenerate (first: element "
                    f"{self.first_inverted})")
        if len(self.branch_edges):
            a, b = self.branch_edges[0]
            return (f"the tets around interior edge ({a}, {b}) turn around it more than once: the "
                    f"map is not locally injective there{more(len(self.branch_edges), 'edges')}")
        if len(self.branch_vertices):
            return (f"interior vertex {self.branch_vertices[0]} is a branch point: its elements "
                    f"cover its neighbourhood more than once{more(len(self.branch_vertices), 'vertices')}")
        if len(self.boundary_edge_overlaps):
            a, b = self.boundary_edge_overlaps[0]
            return (f"the tets around boundary edge ({a}, {b}) turn a full turn or more: they overlap"
                    f"{more(len(self.boundary_edge_overlaps), 'edges')}")
        if len(self.boundary_overlaps):
            return (f"the elements around boundary vertex {self.boundary_overlaps[0]} overlap (they turn "
                    f"a full turn or more, or the boundary meets itself there)"
                    f"{more(len(self.boundary_overlaps), 'vertices')}")
        return ""

    @property
    def failures(self) -> int:
        """Vertices and edges listed as not locally injective (0 when :attr:`ok` or when an
        element is inverted: the lists are not computed then)."""
        return sum(len(a) for a in (self.branch_vertices, self.branch_edges, self.boundary_overlaps,
                                    self.boundary_edge_overlaps))

    def beyond(self, forced: "LocalCertificate") -> "LocalCertificate":
        """This certificate without the vertices and edges that ``forced`` lists too.

        ``forced`` is what the handles make certain (:func:`fixed_star_certificate` of the
        input: stars whose every vertex is fixed); the copy lists only the failures a solver
        could have removed, so ``beyond(forced).ok`` means the map is locally injective
        wherever some free vertex reaches (``inverted`` is kept as it is).  A vertex at an end
        of a forced edge is forced too, whatever its star holds: every neighbourhood of it
        holds points of the edge, around which the map overlaps."""
        ends = np.concatenate([np.ravel(forced.branch_edges), np.ravel(forced.boundary_edge_overlaps)])
        vertices = np.concatenate([forced.branch_vertices, forced.boundary_overlaps, ends])
        return dataclasses.replace(
            self, branch_vertices=_rows_not_in(self.branch_vertices, vertices),
            branch_edges=_rows_not_in(self.branch_edges, forced.branch_edges),
            boundary_overlaps=_rows_not_in(self.boundary_overlaps, vertices),
            boundary_edge_overlaps=_rows_not_in(self.boundary_edge_overlaps, forced.boundary_edge_overlaps))


def _rows_not_in(a, b) -> np.ndarray:
    """The vertex ids (k,) or sorted edges (k, 2) of ``a`` that ``b`` does not list."""
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    if not len(a) or not len(b):
        return a
    if a.ndim == 1:
        return a[~np.isin(a, b)]
    n = int(max(a.max(), b.max())) + 1
    return a[~np.isin(a[:, 0] * n + a[:, 1], b[:, 0] * n + b[:, 1])]


def local_certificate(x, S, orientation: int = 1, link=None) -> LocalCertificate:
    """Exact certificate that a triangle map in the plane or a tet map is locally injective.

    Parameters
    ----------
    x : (n, 2) or (n, 3) float array, the map (2D: triangles; 3D: tetrahedra).
    S : (m, 3) or (m, 4) int array, the elements (e.g. :attr:`Problem.simplices`).
    orientation : +1 or -1, the orientation every element must have (-1: a file whose
        connectivity lists elements clockwise).
    link : (n,) bool or None, 3D only: vertices whose own boundary tests cannot fail (the
        copies of :func:`geomopt.mesh.elements.corner_stars`; see :func:`geomopt.exact.stars.star_overlaps_3d`).

    Returns
    -------
    :class:`LocalCertificate`; ``ok`` holds iff every element has ``orientation`` and the map
    is locally injective around every vertex and edge (:mod:`geomopt.exact.stars`).  A map with a
    non-finite coordinate is not certified (its elements count as inverted).

    Raises
    ------
    MeshError
        ``x`` or ``S`` has the wrong shape or type, or an index out of range.
    ParameterError
        ``orientation`` is not +1 or -1.
    """
    t0 = time.perf_counter()
    if isinstance(orientation, (bool, np.bool_)) or orientation not in (1, -1):
        raise ParameterError(f"orientation must be +1 or -1, got {orientation!r}")
    x = np.asarray(x)
    S = np.asarray(S)
    if x.ndim != 2 or x.shape[1] not in (2, 3) or x.dtype.kind not in "fiu":
        raise MeshError(f"the map must be a real array of shape (n, 2) or (n, 3), got shape "
                        f"{x.shape} and dtype {x.dtype}")
    key = (digest(x), digest(S), int(orientation), None if link is None else digest(np.asarray(link)))
    if key in _RECENT:
        return _recalled(key, t0)
    cert = _local_certificate(x, S, orientation, link, t0)
    _RECENT[key] = cert
    while len(_RECENT) > _RECENT_SIZE:
        _RECENT.popitem(last=False)
    return cert


#: the last certificates :func:`local_certificate` computed, by the digests of its inputs: the
#: certificate is a function of those bytes alone, so a map certified again unchanged (the
#: untangled map, then the file written from it and read back bit for bit: 3-8 s at 10^6 tets)
#: gets the same answer without the work.  Keyed by content, never by identity: an array
#: changed in place is certified anew.
_RECENT: "collections.OrderedDict[tuple, LocalCertificate]" = collections.OrderedDict()
_RECENT_SIZE = 2


def _recalled(key, t0) -> LocalCertificate:
    """A copy of the remembered certificate of ``key`` (its lists copied, its time this lookup's)."""
    _RECENT.move_to_end(key)
    cert = _RECENT[key]
    lists = {f.name: np.copy(getattr(cert, f.name)) for f in dataclasses.fields(cert)
             if isinstance(getattr(cert, f.name), np.ndarray)}
    return dataclasses.replace(cert, seconds=time.perf_counter() - t0, **lists)


def _local_certificate(x, S, orientation, link, t0) -> LocalCertificate:
    """:func:`local_certificate` of checked arrays, computed."""
    if orientation == -1 and S.ndim == 2 and S.shape[1] >= 3:
        S = S[:, [0, 2, 1] + list(range(3, S.shape[1]))]  # an odd permutation: -1 becomes +1
    bad = np.flatnonzero(simplex_orientations(x, S) != 1)
    if bad.size:
        return LocalCertificate(int(bad.size), int(bad[0]), seconds=time.perf_counter() - t0)
    x = x.astype(np.float64, copy=False)
    if x.shape[1] == 2:
        branch, overlaps = fan_overlaps_2d(x, S)
        return LocalCertificate(0, -1, branch, _no_edges(), overlaps, _no_edges(), time.perf_counter() - t0)
    edges, branch, bedges, overlaps = star_overlaps_3d(x, S, link)
    return LocalCertificate(0, -1, branch, edges, overlaps, bedges, time.perf_counter() - t0)


def _edge_keys(S, n):
    """``(m * C(k, 2),)`` int64 keys ``lo * n + hi`` of every edge of every element of ``S`` (m, k)."""
    k = S.shape[1]
    pairs = [(a, b) for a in range(k) for b in range(a + 1, k)]
    return np.concatenate([np.minimum(S[:, a], S[:, b]) * n + np.maximum(S[:, a], S[:, b])
                           for a, b in pairs])


def fixed_star_certificate(x, S, fixed) -> LocalCertificate:
    """The local certificate of the vertices and edges that no free vertex can change.

    A vertex (an edge) whose whole star -- every element containing it -- has all its vertices
    fixed, every element positively oriented, is certified the same way by every map with these
    handles (:mod:`geomopt.exact.stars` decides each vertex and edge from its star alone).  When such a
    star overlaps itself (tets winding twice around an edge, a boundary fan turning a full turn
    or more, ...), no map with these handles is locally injective, and solving is pointless.
    Stars with a free vertex, or with an inverted fixed element (see
    :func:`geomopt.exact.predicates.count_inverted`), are not judged here: only overlaps that are
    certain are reported.

    Parameters
    ----------
    x : (n, 2) or (n, 3) float array, a map with the handles in place.
    S : (m, 3) or (m, 4) int array, the elements, positively oriented when the map is valid.
    fixed : (h,) int array, the fixed vertices.

    Returns
    -------
    :class:`LocalCertificate` (``inverted == 0``) listing only vertices and edges whose whole
    star is fixed and positive; ``ok`` when there is none that overlaps.
    """
    t0 = time.perf_counter()
    x = np.asarray(x, dtype=np.float64)
    S = np.asarray(S, dtype=np.int64)
    n = len(x)
    is_fixed = np.zeros(n, bool)
    is_fixed[validate_indices(fixed, n, "fixed vertices")] = True
    sub = is_fixed[S].all(axis=1)
    sub[sub] = simplex_orientations(x, S[sub]) == 1
    if not sub.any():
        return LocalCertificate(0, seconds=time.perf_counter() - t0)
    cert = local_certificate(x, S[sub])
    # a vertex (edge) is judged only when no element outside the fixed positive part contains it
    open_vertex = np.zeros(n, bool)
    open_vertex[S[~sub].ravel()] = True

    def closed_edges(E):  # the open edges only when there is an edge to judge (1.7 s at 50k hexahedra)
        if not len(E):
            return E
        return E[~np.isin(E[:, 0] * n + E[:, 1], _edge_keys(S[~sub], n))]

    return LocalCertificate(
        0, -1, cert.branch_vertices[~open_vertex[cert.branch_vertices]],
        closed_edges(cert.branch_edges), cert.boundary_overlaps[~open_vertex[cert.boundary_overlaps]],
        closed_edges(cert.boundary_edge_overlaps), time.perf_counter() - t0)


@dataclasses.dataclass(frozen=True)
class Certificate:
    """The outcome of :func:`certify_bijective`.

    Attributes
    ----------
    inverted : int, triangles not positively oriented (exact).
    loop : (k,) int64, the boundary loop (vertex ids, faces to its left).
    crossings : (q, 2) int64, pairs of boundary edges (positions in ``loop``; edge ``i`` runs from
        ``loop[i]`` to ``loop[(i + 1) % k]``) that cross, touch or overlap.
    orientation : int, +1 when the boundary polygon is counter-clockwise (0 if not simple or
        not finite).
    seconds : float, time taken.
    local : :class:`LocalCertificate` of the same map.
    """

    inverted: int
    loop: np.ndarray
    crossings: np.ndarray
    orientation: int
    seconds: float
    local: LocalCertificate = dataclasses.field(default_factory=lambda: LocalCertificate(0))

    @property
    def locally_injective(self) -> bool:
        """Every triangle positively oriented and every fan covering its neighbourhood once
        (:func:`local_certificate`)."""
        return self.local.ok

    @property
    def globally_injective(self) -> bool:
        """Locally injective with a simple counter-clockwise boundary: a bijection onto its image."""
        return self.local.ok and len(self.crossings) == 0 and self.orientation == 1

    @property
    def injectivity(self) -> str:
        """``"global"``, ``"local"`` or ``"none"``."""
        return "global" if self.globally_injective else ("local" if self.locally_injective else "none")


def certify_bijective(x, F, loop=None) -> Certificate:
    """Exact certificate that a map of a triangulated disk is globally injective.

    Parameters
    ----------
    x : (n, 2) float array, the map.
    F : (m, 3) int array, triangles of a topological disk, oriented so that a valid map has every
        triangle counter-clockwise (as :class:`~geomopt.Problem` simplices are).
    loop : (k,) int array, optional, the boundary loop with the faces to its left (as
        :func:`~geomopt.exact.topology.check_disk` returns it, which is called when omitted).

    Returns
    -------
    :class:`Certificate`; ``globally_injective`` holds iff no triangle is inverted or degenerate,
    the map is locally injective at every vertex (implied by the rest, checked anyway), no two
    boundary edges cross or touch (see the module docstring), and the boundary runs
    counter-clockwise: then the map is a bijection onto its image (degree argument above).
    A map with a non-finite coordinate is certified neither locally nor globally.

    Raises
    ------
    MeshError
        ``F`` is not a disk, ``x`` has the wrong shape, or ``loop`` is not a list of at least 3
        distinct vertex ids.
    """
    t0 = time.perf_counter()
    refuse_traced("certify_bijective (exact predicates)", "it certifies concrete maps; inside a trace use "
                  "Objective.dets(x) (float determinants)", x)
    x = np.asarray(x)
    F = np.asarray(F)
    if x.ndim != 2 or x.shape[1] != 2 or x.dtype.kind not in "fiu":
        raise MeshError(f"the map must be a real array of shape (n, 2), got shape {x.shape} "
                        f"and dtype {x.dtype}")
    if loop is None:
        loop = check_disk(F, len(x))
    else:
        loop = validate_indices(loop, len(x), "boundary loop")
        if loop.size < 3:
            raise MeshError(f"the boundary loop needs at least 3 vertices, got {loop.size}")
    x = x.astype(np.float64, copy=False)
    local = local_certificate(x, F)
    P = x[loop]
    if np.isfinite(P).all():
        crossings = polygon_crossings(P)
        orientation = polygon_orientation(P) if len(crossings) == 0 else 0
    else:
        crossings, orientation = np.zeros((0, 2), np.int64), 0
    return Certificate(local.inverted, loop, crossings, orientation, time.perf_counter() - t0, local)


# --------------------------------------------------------------------------- sphere maps


def spherical_areas(x, F) -> np.ndarray:
    """(m,) signed areas of the geodesic triangles spanned by the directions ``x`` (n, 3) on the
    unit sphere (lengths do not matter), ``F`` (m, 3): Van Oosterom & Strackee's
    ``2 atan2(det[a, b, c], 1 + a.b + b.c + c.a)`` on the normalised corners; in (0, 2 pi) for
    a positively oriented triangle (float, not exact)."""
    x = np.asarray(x, dtype=np.float64)
    y = x / np.linalg.norm(x, axis=1, keepdims=True)
    a, b, c = (y[np.asarray(F)[:, k]] for k in range(3))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    dots = np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) + np.einsum("ij,ij->i", c, a)
    return 2.0 * np.arctan2(det, 1.0 + dots)


@dataclasses.dataclass(frozen=True)
class SphereCertificate:
    """The outcome of :func:`certify_sphere`.

    Attributes
    ----------
    inverted : int, triangles not positively oriented about the centre (exact).
    first_inverted : int, the first such triangle, or -1.
    area : float, the sum of the triangles' spherical areas (``4 pi`` for a map covering the
        sphere once; nan when a vertex is at the centre or not finite).
    degree : int, ``round(area / 4 pi)`` when no triangle is inverted (how many times the map
        covers the sphere), else 0.
    seconds : float, time taken.
    """

    inverted: int
    first_inverted: int
    area: float
    degree: int
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """Every triangle positive and the sphere covered once: a bijection onto the sphere."""
        return self.inverted == 0 and self.degree == 1

    locally_injective = ok  # a positive map of degree k > 1 has branch points (Riemann-Hurwitz)

    @property
    def globally_injective(self) -> bool:
        return self.ok

    @property
    def injectivity(self) -> str:
        """``"global"`` (a certified bijection onto the sphere) or ``"none"``."""
        return "global" if self.ok else "none"

    @property
    def message(self) -> str:
        """One line naming the failure ("" when :attr:`ok`)."""
        if self.inverted:
            return (f"{self.inverted} triangle(s) inverted or degenerate about the sphere's centre (first: "
                    f"triangle {self.first_inverted})")
        if self.degree != 1:
            return (f"the triangles' spherical areas sum to {self.area:.6g} = {self.area / (4 * np.pi):.6g} x 4 pi: "
                    f"the map covers the sphere {self.degree} times, not once")
        return ""


#: how far the spherical areas' float sum may be from 4 pi: far below the 4 pi (k - 1) by which
#: a positive map covering the sphere k times differs, far above the sum's rounding
SPHERE_AREA_TOL = 1e-6 * 4.0 * np.pi


def certify_sphere(x, F) -> SphereCertificate:
    """Exact certificate that a map of a closed genus-0 triangle mesh onto the sphere is a bijection.

    Parameters
    ----------
    x : (n, 3) float array, the map (directions from the centre).
    F : (m, 3) int array, the triangles, oriented so that a valid map turns them
        counter-clockwise seen from outside.

    Returns
    -------
    :class:`SphereCertificate`; ``ok`` holds iff every triangle is positively oriented about the
    centre (exact: ``orient3d(0, a, b, c) > 0``, :func:`geomopt.exact.predicates.cone_orientations`)
    and the spherical areas sum to ``4 pi`` within :data:`SPHERE_AREA_TOL`.

    Why this suffices: with every triangle positive, the map is orientation preserving on every
    open triangle and the number of triangles covering a point of the sphere (off the edges'
    images) is the same everywhere, the map's degree ``k >= 1``; so the areas sum to exactly
    ``4 pi k``.  A float sum within ``SPHERE_AREA_TOL`` of ``4 pi`` rules out every ``k > 1``;
    degree 1 means almost every point has one preimage, so the open triangles are disjoint and
    no vertex is a branch point (its neighbourhood would be covered twice): a homeomorphism.
    """
    t0 = time.perf_counter()
    x = np.asarray(x, dtype=np.float64)
    sign = cone_orientations(x, F)
    bad = np.flatnonzero(sign != 1)
    with np.errstate(all="ignore"):
        area = float(np.sum(spherical_areas(x, F)))
    degree = 0
    if bad.size == 0 and np.isfinite(area):
        k = round(area / (4.0 * np.pi))
        degree = int(k) if abs(area - 4.0 * np.pi * k) <= SPHERE_AREA_TOL else 0
    return SphereCertificate(int(bad.size), int(bad[0]) if bad.size else -1, area, degree,
                             time.perf_counter() - t0)

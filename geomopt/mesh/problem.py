"""Mesh problems: rest simplices turned into per-element inverse rest matrices and volumes.

A :class:`Problem` is immutable and holds only NumPy arrays computed once.  Its rest mesh is
checked so that "every element positively oriented" (what a solve certifies) means "no fold":
no degenerate element, one orientation for all elements, and adjacent elements on opposite
sides of their shared edge/face (a surface's faces consistently wound, no facet of more than
two elements).


* ``simplices`` (m, d+1): vertex indices, reordered internally where needed so every
  rest element is positively oriented (the caller's connectivity is kept in
  ``input_simplices`` for output);
* ``rest_inv`` (m, d, d): inverse of the rest edge matrix ``[p1-p0, ..., pd-p0]`` in a local
  frame, so that the Jacobian of a map ``x`` is ``J = [x1-x0, ..., xd-x0] @ rest_inv``;
* ``volumes`` (m,): rest areas (d=2) or volumes (d=3);
* ``fixed`` (k,) / ``fixed_positions`` (k, d): handles.

**Traced rest geometry.**  A Problem is a JAX pytree: its leaves are the float arrays
(``rest_inv``, ``volumes``, ``rest_vertices``, ``fixed_positions``), the connectivity and the
handle indices are static metadata (compared by content).  The constructors accept traced rest
vertices and handle positions (inside ``jax.grad`` / ``jit`` / ``vmap``; the connectivity must
stay concrete): shapes and the connectivity are checked as always, but the checks that need
values (finite coordinates, no degenerate or inverted rest element) are skipped, and the
elements are taken in the given order, which must then be positively oriented (planar
triangles counter-clockwise, tets of positive volume; a clockwise rest mesh is reordered only
from concrete input).  :func:`check_rest_values` runs those checks once values are concrete.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.errors import MeshError, ParameterError
from .geometry import det as _det
from .._runtime.tracing import StaticKey, digest, is_traced, refuse_traced
from .._runtime.validate import validate_indices, validate_simplices, validate_vertices
from ..exact.topology import boundary_vertices, nonmanifold_facets, repeated_elements, same_side_facets

__all__ = ["Problem", "check_rest_values"]


def _xp(*arrays):
    """The array module for ``arrays``: ``jax.numpy`` when one is traced, else NumPy."""
    return jnp if is_traced(*arrays) else np


def _local_frames(V, F):
    """Flatten each 3D triangle isometrically to 2D: rest edge matrices (m, 2, 2) and areas.

    Degenerate or overflowing triangles give zero or non-finite areas, which the caller rejects.
    NumPy, or JAX for traced ``V``.
    """
    xp = _xp(V)
    with np.errstate(all="ignore"):
        e1 = V[F[:, 1]] - V[F[:, 0]]
        e2 = V[F[:, 2]] - V[F[:, 0]]
        l1 = xp.linalg.norm(e1, axis=1)
        area2 = xp.linalg.norm(xp.cross(e1, e2), axis=1)
        x2 = xp.einsum("ij,ij->i", e2, e1 / l1[:, None])
        y2 = area2 / l1
    Dm = xp.stack([xp.stack([l1, x2], -1), xp.stack([xp.zeros_like(l1), y2], -1)], -2)
    return Dm, 0.5 * area2


def _edge_matrices(P, S):
    """Edge matrices ``[p1-p0, ..., pd-p0]`` as columns: (m, d, d); ``[pa, pb, pc]`` for the
    triangles ``S`` (m, 3) of a sphere map, cones over the origin (:mod:`geomopt.mesh.geometry`)."""
    with np.errstate(all="ignore"):  # overflow shows up as non-finite sizes
        if S.shape[1] == P.shape[-1]:
            return _xp(P).swapaxes(P[S], 1, 2)
        return _xp(P).swapaxes(P[S[:, 1:]] - P[S[:, :1]], 1, 2)


def _signed_sizes(Dm):
    """Signed areas (d=2) or volumes (d=3) from edge matrices (m, d, d); overflow gives inf
    (for rest shapes, :func:`_check_rest_volumes` rejects it)."""
    d = Dm.shape[-1]
    with np.errstate(all="ignore"):
        D = _det(Dm) if is_traced(Dm) else np.linalg.det(Dm)
        return D / (2.0 if d == 2 else 6.0)


def _check_rest_volumes(vol, what, rel_tol=1e-12, Dm=None):
    """Reject degenerate (near-zero) rest elements and mixed orientations.

    Near-zero: at most ``rel_tol`` of the mean size, or, given the edge matrices ``Dm``
    (m, d, d), of the element's own Hadamard bound (the product of its edge lengths, times 1/2 or
    1/6): a lone or uniformly degenerate element rounds to a tiny size of either sign, which the
    mean alone cannot tell from a real one."""
    if not np.isfinite(vol).all():
        idx = np.flatnonzero(~np.isfinite(vol))
        raise MeshError(
            f"{idx.size} rest {what}(s) have a size that overflows float64 (first: {idx[:5].tolist()}); "
            f"the coordinates are too large: rescale the mesh"
        )
    scale = np.mean(np.abs(vol))
    if not scale > 0:
        raise MeshError(
            f"every rest {what} has zero size: the rest mesh is degenerate (collinear or coincident "
            f"vertices) or its coordinates are too small for float64 (rescale it)"
        )
    small = np.abs(vol) <= rel_tol * scale
    if Dm is not None and not is_traced(Dm):
        Dm = np.asarray(Dm)
        with np.errstate(all="ignore"):
            bound = np.prod(np.linalg.norm(Dm, axis=-2), axis=-1) / (2.0 if Dm.shape[-1] == 2 else 6.0)
        small |= np.abs(vol) <= rel_tol * bound
    if small.any():
        idx = np.flatnonzero(small)
        raise MeshError(
            f"{idx.size} rest {what}(s) have (near-)zero size (first: {idx[:5].tolist()}); "
            f"remove or repair them (e.g. collapse short edges) before solving"
        )
    neg = vol < 0
    if neg.any() and not neg.all():
        idx = np.flatnonzero(neg if neg.sum() <= (~neg).sum() else ~neg)
        raise MeshError(
            f"{idx.size} rest {what}(s) are oriented against the others (first: {idx[:5].tolist()}); "
            f"the rest mesh must be consistently oriented (no element listed clockwise among "
            f"counter-clockwise ones) and not folded"
        )
    return bool(neg.all())


def _check_facet_orientation(kind, S):
    """Reject rest meshes whose elements (``S``, positively oriented in the problem's frame)
    share an edge (triangles) or face (tets) with the same induced orientation.

    Every map the solvers certify has all elements positively oriented; that means no
    overlap only when adjacent elements lie on opposite sides of their shared facet at rest,
    i.e. traverse it in opposite directions.  Otherwise a "flip-free" map folds there.
    """
    count, bad = same_side_facets(S)
    if not count:
        return
    what, one, facet = ("tetrahedra", "tetrahedron", "face") if kind == "tet" else ("triangles", "triangle", "edge")
    many, where = nonmanifold_facets(S)
    if many:
        raise MeshError(
            f"{many} non-manifold {facet}s (shared by more than two {what}; {what} "
            f"{np.flatnonzero(where)[:6].tolist()}): every map of such a mesh folds there; split "
            f"or remove the extra {what}" + repeated_elements(S, one))
    idx = np.flatnonzero(bad)
    if kind in ("surface", "sphere"):
        raise MeshError(
            f"inconsistent face orientation: {count} edge(s) are traversed in the same direction "
            f"by two triangles (triangles {idx[:6].tolist()}): a face is listed clockwise among "
            f"counter-clockwise ones, or the surface is non-orientable; orient all faces "
            f"consistently (e.g. trimesh.repair.fix_winding), since no map of such a mesh can be "
            f"certified fold-free")
    raise MeshError(
        f"{count} rest {facet}(s) are shared by {what} lying on the same side of them "
        f"({what} {idx[:6].tolist()}): the rest mesh overlaps itself there or repeats an element; "
        f"remove the duplicated or overlapping {what}, since no map of such a mesh can be "
        f"certified fold-free")


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """An injective-mapping problem over one kind of simplex.

    Build one with :meth:`planar`, :meth:`surface` or :meth:`tets`; do not call the
    constructor directly.  A JAX pytree (see the module notes): rest vertices and handle
    positions may be traced, e.g. ``jax.grad`` of an energy with respect to the rest shape.
    """

    kind: str
    dim: int
    n_vertices: int
    simplices: np.ndarray
    input_simplices: np.ndarray
    rest_inv: np.ndarray
    volumes: np.ndarray
    rest_vertices: np.ndarray
    fixed: np.ndarray
    fixed_positions: np.ndarray
    #: quads (m, 4) or hexahedra (m, 8), oriented, whose corner simplices are ``simplices``
    #: (:mod:`geomopt.mesh.elements`); None for a simplex problem
    elements: np.ndarray | None = None

    # -- constructors ---------------------------------------------------------------
    @classmethod
    def planar(cls, V, F, fixed=None, fixed_positions=None):
        """Triangles in the plane mapped to the plane.

        V : (n, 2) rest positions (an (n, 3) array with z == 0 is accepted); F : (m, 3).
        A clockwise rest mesh is handled by reordering each triangle internally; a mesh with
        both orientations, or overlapping itself, raises MeshError.  Traced ``V``: unchecked
        values, triangles taken counter-clockwise as given, the z column of (n, 3) dropped.
        """
        V = _vertices(V, "rest vertices")
        if V.shape[1] == 3:
            if not is_traced(V) and np.any(V[:, 2] != 0):
                raise MeshError("planar problem: rest vertices have nonzero z; use Problem.surface")
            V = V[:, :2]
        F = validate_simplices(F, len(V), 3, "triangles")
        Dm = _edge_matrices(V, F)
        S = F[:, [0, 2, 1]] if _flipped(_signed_sizes(Dm), "triangle", Dm) else F
        Dm = _edge_matrices(V, S)
        return cls._make("planar", 2, V, F, S, Dm, _signed_sizes(Dm), fixed, fixed_positions)

    @classmethod
    def surface(cls, V, F, fixed=None, fixed_positions=None):
        """Triangles of a 3D surface mapped to the plane (parameterization).

        V : (n, 3); F : (m, 3).  Each triangle is flattened isometrically to a local 2D frame,
        so rest triangles are positively oriented and a map is valid when every triangle
        ``(a, b, c)`` has positive signed area in the plane.  The faces must be consistently
        wound (adjacent faces traverse their shared edge in opposite directions), else
        MeshError: otherwise a map with no inverted triangle still folds.  Traced ``V``:
        values unchecked (no degenerate triangle is assumed).
        """
        V = _vertices(V, "surface problem: rest vertices", dim=3)
        F = validate_simplices(F, len(V), 3, "triangles")
        Dm, area = _local_frames(V, F)
        _flipped(area, "triangle", Dm)
        return cls._make("surface", 2, V, F, F, Dm, area, fixed, fixed_positions)

    @classmethod
    def sphere(cls, V, F):
        """Triangles of a closed 3D surface mapped onto the unit sphere (:func:`geomopt.sphere_map`).

        V : (n, 3); F : (m, 3), consistently oriented (outward normals for a positive map).
        A map is (n, 3), each vertex standing for its direction ``x / |x|``; a triangle is
        positively oriented when ``det[x_a, x_b, x_c] > 0`` (the cone over the origin,
        :mod:`geomopt.mesh.geometry`), and its Jacobian (2x2) is that of its chord triangle in the
        tangent plane (:func:`geomopt.mesh.geometry.chord_jacobians`) against the rest triangle in
        its local frame.  The rest areas are scaled to total ``4 pi`` (the sphere's), so an
        isometric density means no area distortion on average.  Only value and gradient
        solvers apply (the Jacobian is not linear in the map: no assembled Hessian).
        """
        V = _vertices(V, "sphere problem: rest vertices", dim=3)
        F = validate_simplices(F, len(V), 3, "triangles")
        Dm, area = _local_frames(V, F)
        _flipped(area, "triangle", Dm)
        scale = math.sqrt(4.0 * math.pi / float(np.sum(area)))  # lengths, so areas sum to 4 pi
        return cls._make("sphere", 3, V, F, F, Dm * scale, area * scale**2, None, None)

    @classmethod
    def tets(cls, V, T, fixed=None, fixed_positions=None):
        """Tetrahedra mapped to 3D.  V : (n, 3); T : (m, 4).

        A rest mesh whose tets are all negatively oriented (as in the LIM armadillo) is handled
        by swapping two vertices of every tet internally; a map is then valid when each tet
        has the same orientation as at rest.  Traced ``V``: values unchecked, tets taken as
        given (positive volumes).
        """
        V = _vertices(V, "tet problem: rest vertices", dim=3)
        T = validate_simplices(T, len(V), 4, "tetrahedra")
        Dm = _edge_matrices(V, T)
        S = T[:, [0, 2, 1, 3]] if _flipped(_signed_sizes(Dm), "tetrahedron", Dm) else T
        Dm = _edge_matrices(V, S)
        return cls._make("tet", 3, V, T, S, Dm, _signed_sizes(Dm), fixed, fixed_positions)

    @classmethod
    def quads(cls, V, Q, fixed=None, fixed_positions=None, *, rest="mesh"):
        """Quads in the plane mapped to the plane, evaluated at their 4 corner triangles
        (:mod:`geomopt.mesh.elements`).  V : (n, 2) rest positions (or (n, 3) with z == 0); Q : (m, 4).

        rest : ``"mesh"``: the rest shapes are ``V``'s quads, strictly convex and consistently
            oriented (all-clockwise quads are reversed internally); ``"reference"``: squares of
            the mean edge length (Winslow smoothing, a mesh with no rest shape), ``V`` setting
            only the orientation (its total signed area) and possibly tangled.
        """
        V = validate_vertices(V, "rest vertices")
        if V.shape[1] == 3:
            if np.any(V[:, 2] != 0):
                raise MeshError("quad problem: rest vertices have nonzero z (the quads are not planar); "
                                "use Problem.quad_surface for a quad surface in 3D")
            V = V[:, :2]
        return cls._elements("quad", V, Q, 4, rest, fixed, fixed_positions)

    @classmethod
    def quad_surface(cls, V, Q, fixed=None, fixed_positions=None, *, rest="mesh"):
        """Quads of a 3D surface mapped to the plane, each corner triangle flattened to its own
        frame (as :meth:`surface`).  V : (n, 3); Q : (m, 4), consistently oriented; a twisted
        rest quad (a corner facing against the quad's mean normal) raises MeshError."""
        V = validate_vertices(V, "quad surface: rest vertices", dim=3)
        return cls._elements("quad_surface", V, Q, 4, rest, fixed, fixed_positions)

    @classmethod
    def hexes(cls, V, H, fixed=None, fixed_positions=None, *, rest="mesh"):
        """Hexahedra (VTK order) mapped to 3D, evaluated at their 8 corner tetrahedra.
        V : (n, 3); H : (m, 8).  ``rest`` as in :meth:`quads` (``"mesh"``: every rest
        hexahedron valid everywhere, checked exactly).  :meth:`count_inverted` certifies a
        positive Jacobian inside every hexahedron (:mod:`geomopt.exact.hexvalid`), not only at its
        corners."""
        V = validate_vertices(V, "hex problem: rest vertices", dim=3)
        return cls._elements("hex", V, H, 8, rest, fixed, fixed_positions)

    @classmethod
    def cells(cls, V, E, fixed=None, fixed_positions=None, *, rest="mesh"):
        """Quads (``E`` (m, 4), :meth:`quads`) or hexahedra (``E`` (m, 8), :meth:`hexes`), by
        the element kind of ``E`` (:func:`geomopt.mesh.elements.kind_of`)."""
        from .elements import kind_of

        return getattr(cls, kind_of(E).constructor)(V, E, fixed, fixed_positions, rest=rest)

    @classmethod
    def _elements(cls, kind, V, E, k, rest, fixed, fixed_positions):
        """Quads / hexahedra: validated, oriented and checked (:func:`geomopt.mesh.elements.rest_elements`),
        their corner simplices' rest matrices from ``V``, local frames or reference shapes."""
        from . import elements

        E = elements.rest_elements(V, elements.validate_elements(E, len(V), k), rest)
        S = elements.corner_simplices(E)
        if rest == "reference":
            Dm = elements.reference_rest(V, E)
        else:
            Dm = _local_frames(V, S)[0] if kind == "quad_surface" else _edge_matrices(V, S)
        vol = _signed_sizes(Dm)
        d = elements.ELEMENT_KINDS[k].dim
        _check_rest_volumes(vol, "corner triangle" if d == 2 else "corner tetrahedron", Dm=Dm)
        return cls._make(kind, d, V, S, S, Dm, vol, fixed, fixed_positions, elements=E)

    @classmethod
    def _make(cls, kind, d, V, F_in, S, Dm, vol, fixed, fixed_positions, elements=None):
        if is_traced(V, vol):
            _check_traced_rest(kind, V, vol)
        p = cls(
            kind=kind,
            dim=d,
            n_vertices=len(V),
            simplices=np.ascontiguousarray(S, dtype=np.int64),
            input_simplices=np.ascontiguousarray(F_in, dtype=np.int64),
            rest_inv=_xp(Dm).linalg.inv(Dm),
            volumes=vol if is_traced(vol) else np.asarray(vol, dtype=np.float64),
            rest_vertices=V,
            fixed=np.zeros(0, np.int64),
            fixed_positions=np.zeros((0, d)),
            elements=elements,
        )
        used = np.zeros(len(V), bool)
        used[S.ravel()] = True  # a mask, not setdiff1d: that sorts every corner (2.2 s at 1e6 tets)
        unused = np.flatnonzero(~used)
        if unused.size:
            raise MeshError(
                f"{unused.size} vertices are not used by any element (first: {unused[:5].tolist()}); "
                f"remove unreferenced vertices first"
            )
        if elements is None:  # quads / hexahedra: checked on their edges / faces by the caller
            _check_facet_orientation(kind, S)
        if fixed is not None:
            p = p.with_fixed(fixed, fixed_positions)
        return p

    # -- handles --------------------------------------------------------------------
    def with_fixed(self, fixed, positions) -> "Problem":
        """A copy with vertices ``fixed`` (k,) held at ``positions`` (k, dim) (traceable: the
        positions unchecked then)."""
        idx = validate_indices(fixed, self.n_vertices, "fixed vertex indices")
        if idx.size == 0:
            return dataclasses.replace(self, fixed=idx, fixed_positions=np.zeros((0, self.dim)))
        pos = _vertices(positions, "fixed positions", dim=self.dim)
        if len(pos) != idx.size:
            raise MeshError(
                f"fixed positions has {len(pos)} rows for {idx.size} fixed vertices; give one position per fixed vertex"
            )
        order = np.argsort(idx)
        return dataclasses.replace(self, fixed=idx[order], fixed_positions=pos[order])

    @functools.cached_property
    def static_key(self) -> StaticKey:
        """The pytree metadata: kind, sizes, connectivity and handle indices, keyed by content
        (hashable; equal for problems of one mesh and handle set, whatever their values)."""
        meta = tuple(getattr(self, f) for f in _META)
        return StaticKey(meta[:3] + tuple(None if a is None else digest(a) for a in meta[3:]), meta)

    @property
    def n_elements(self) -> int:
        return len(self.simplices)

    @property
    def free_mask(self) -> np.ndarray:
        """(n,) bool: vertices the solver may move."""
        m = np.ones(self.n_vertices, bool)
        m[self.fixed] = False
        return m

    def check_map(self, x, name="map") -> np.ndarray:
        """Validate a map ``x`` (n, dim) and return it as a float64 copy with handles in place."""
        x = validate_vertices(x, name, dim=self.dim)
        if len(x) != self.n_vertices:
            raise MeshError(f"{name} has {len(x)} rows but the mesh has {self.n_vertices} vertices; "
                            f"give one position per vertex")
        x = x.copy()
        x[self.fixed] = self.fixed_positions
        return x

    def signed_volumes(self, x) -> np.ndarray:
        """(m,) signed area/volume of each element under the map, in the rest orientation
        (NumPy; traceable: :meth:`geomopt.Objective.dets`)."""
        refuse_traced("Problem.signed_volumes", "inside a trace use Objective.dets(x)", x)
        x = np.asarray(x, dtype=np.float64)
        return _signed_sizes(_edge_matrices(x, self.simplices))

    def count_inverted(self, x) -> int:
        """Elements whose orientation under ``x`` is not positive, by an exact predicate.

        Quads / hexahedra: elements (not corners) without a positive Jacobian everywhere
        (:func:`geomopt.mesh.elements.count_invalid`)."""
        if self.elements is not None:
            from .elements import count_invalid

            return count_invalid(x, self.elements)
        from ..exact.predicates import cone_orientations, count_inverted

        if self.kind == "sphere":
            return int(np.count_nonzero(cone_orientations(np.asarray(x, dtype=np.float64), self.simplices) != 1))
        refuse_traced("Problem.count_inverted (exact predicates)", "it certifies concrete maps; inside a trace "
                      "use Objective.dets(x) (float determinants)", x)
        return int(count_inverted(np.asarray(x, dtype=np.float64), self.simplices))

    def certify(self, x):
        """Exact certificate that ``x`` (n, dim) is locally injective: every element positively
        oriented and no vertex or edge around which the elements wind twice or overlap.

        Simplices: :func:`geomopt.exact.certify.local_certificate` of :attr:`simplices`.  Quads /
        hexahedra: :func:`geomopt.mesh.elements.element_local_certificate` of :attr:`elements`
        (each element valid everywhere, then the stars of their tangent cones), never of the
        overlapping corner simplices.

        Returns
        -------
        :class:`~geomopt.exact.certify.LocalCertificate` (``ok``, ``inverted``, ``message``...).
        """
        refuse_traced("Problem.certify (exact predicates)", "it certifies concrete maps; inside a trace "
                      "use Objective.dets(x) (float determinants)", x)
        x = np.asarray(x, dtype=np.float64)
        if self.elements is not None:
            from .elements import element_local_certificate

            return element_local_certificate(x, self.elements)
        if self.kind == "sphere":
            from ..exact.certify import certify_sphere

            return certify_sphere(x, self.simplices)
        from ..exact.certify import local_certificate

        return local_certificate(x, self.simplices)

    def certify_fixed(self, x):
        """The part of :meth:`certify` that no free vertex can change: vertices and edges whose
        whole star (for quads / hexahedra: the corner simplices *at* the vertex) has every vertex
        fixed (:func:`geomopt.exact.certify.fixed_star_certificate`,
        :func:`geomopt.mesh.elements.element_fixed_star_certificate`).  Not ``ok``: no map with these
        handles is locally injective."""
        refuse_traced("Problem.certify_fixed (exact predicates)", "it certifies concrete maps", x)
        x = np.asarray(x, dtype=np.float64)
        if self.elements is not None:
            from .elements import element_fixed_star_certificate

            return element_fixed_star_certificate(x, self.elements, self.fixed)
        from ..exact.certify import fixed_star_certificate

        return fixed_star_certificate(x, self.simplices, self.fixed)

    def boundary_vertices(self) -> np.ndarray:
        """Sorted ids of the boundary vertices (of the quads' edges / hexahedra's faces for
        element problems, not of their overlapping corner simplices)."""
        if self.elements is not None:
            from .elements import boundary_vertices as element_boundary

            return element_boundary(self.elements, self.n_vertices)
        return boundary_vertices(self.simplices, self.n_vertices)


_LEAVES = ("rest_inv", "volumes", "rest_vertices", "fixed_positions")
_META = ("kind", "dim", "n_vertices", "simplices", "input_simplices", "fixed", "elements")


def _unflatten(static: StaticKey, leaves) -> Problem:
    p = object.__new__(Problem)
    for name, value in zip(_META + _LEAVES, static.payload + tuple(leaves)):
        object.__setattr__(p, name, value)
    p.__dict__["static_key"] = static
    return p


jax.tree_util.register_pytree_with_keys(
    Problem, lambda p: (tuple((jax.tree_util.GetAttrKey(f), getattr(p, f)) for f in _LEAVES), p.static_key),
    _unflatten, lambda p: (tuple(getattr(p, f) for f in _LEAVES), p.static_key))


def _vertices(V, name, dim=None):
    """:func:`~geomopt.io.validate_vertices` for concrete ``V``; for traced ``V`` only its shape
    and dtype are checked (a float64 (n, dim) array)."""
    if not is_traced(V):
        return validate_vertices(V, name, dim)
    widths = (2, 3) if dim is None else (dim,)
    if V.ndim != 2 or V.shape[1] not in widths or V.shape[0] == 0:
        want = " or ".join(f"(n, {w})" for w in widths)
        raise MeshError(f"{name} must have shape {want} with n > 0, got shape {V.shape}")
    if V.dtype != jnp.float64:
        raise ParameterError(f"{name} is a traced {V.dtype} array: geomopt computes in float64; trace "
                             f"float64 values (with jax_enable_x64 on: see geomopt's README, 'float64')")
    return V


def _flipped(vol, what, Dm=None) -> bool:
    """:func:`_check_rest_volumes` (True: every rest element is negatively oriented) for concrete
    sizes; traced sizes are not checked and taken as positive."""
    return False if is_traced(vol) else _check_rest_volumes(vol, what, Dm=Dm)


def check_rest_values(problem: Problem) -> Problem:
    """Run the value checks that a problem built from traced rest vertices or handle positions
    skipped (finite coordinates, no degenerate rest element, every rest element positively
    oriented), on its now concrete arrays; returns ``problem``.  Raises MeshError."""
    _check_rest_arrays(problem.kind, problem.rest_vertices, problem.volumes)
    if problem.fixed.size:
        validate_vertices(problem.fixed_positions, "fixed positions")
    return problem


def _check_rest_arrays(kind, V, vol):
    """The value checks of :func:`check_rest_values` on rest vertices (n, d') and element sizes
    (m,) (NumPy arrays).  Raises MeshError."""
    what = {"tet": "tetrahedron"}.get(kind, "triangle")
    validate_vertices(np.asarray(V), "rest vertices")
    if _check_rest_volumes(np.asarray(vol), what):
        raise MeshError(f"every rest {what} is negatively oriented: a problem built from traced rest "
                        f"vertices takes the elements as given; reverse their order (e.g. F[:, [0, 2, 1]])")


def _check_traced_rest(kind, V, vol):
    """Traced rest vertices: the checks of :func:`check_rest_values` run on the host with the
    user's program (``jax.debug.callback``, per batch element under ``vmap``), so that a
    degenerate or inverted rest element raises MeshError instead of giving a NaN energy (inside
    ``jax.jit`` the error reaches the caller as JAX's runtime error carrying this message)."""
    jax.debug.callback(functools.partial(_check_rest_arrays, kind), V, vol)


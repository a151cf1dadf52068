"""``make_atlas``: any edge-manifold triangle surface to a certified texture atlas.

Cut into disk charts (:mod:`geomopt.atlas.cutting`), flatten every chart flip-free with
:func:`geomopt.parameterize` (free boundary; the bijective scaffold where a chart's boundary
overlaps itself), pack the charts into the unit square (``pack_charts``), certify the whole
atlas exactly (``certify_atlas``) and measure it (:mod:`geomopt.atlas.metrics`).

A pinched vertex (non-manifold: its faces form several fans that meet only there, as where two
parts of a surface touch at one point) is split into one vertex per fan before cutting, so the
charts are disks; the atlas lists such vertices (:attr:`Atlas.pinched`), the progress says so
and ``geomopt param`` prints one warning line with their count and the first one.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .._runtime.config import Instance, Int, Maybe, OneOf, Real, validate
from .._runtime.errors import MeshError, ParameterError, SolveError
from .._runtime.log import logger
from .._runtime.validate import validate_vertices
from .._runtime.x64 import float64
from ..energies import energy_spec, get_energy
from ..solvers import Details, Outcome, Result, RunStats
from ..exact.topology import as_faces, orientable, repeated_elements, same_side_facets, unique_edges
from ..exact.weld import equal_points
from .charts import charts_of_cut
from .cones import angle_defects
from .cutting import cut_surface
from .flatten import flatten_chart, flatten_to
from .inputs import AtlasInput, atlas_input, polygon_uv_faces
from .metrics import AtlasMetrics, atlas_metrics, seam_edges
from .seams import edge_costs, edge_graph, straighten_splits
from .visibility import vertex_visibility
from ._certify import certify_atlas
from ._pack import MARGIN, pack_charts, packing_estimate, widest_margin
from .flat_splits import split_to_pack
from .packed_splits import straighten_packed

__all__ = ["make_atlas", "AtlasDetails", "AtlasPart", "AtlasOptions", "check_atlas_input", "welded"]

# rays per vertex of the visibility that weights the seams' cost (the reported figure uses 96 per edge)
_COST_RAYS = 32
# above this many vertices the cost's visibility is cast from an independent set of them (about a fifth):
# on beetle (20k vertices) the sampled field moved the cut (4 charts, seam 1.71, visibility 1.005 against 3, 0.99, 0.96)
_SAMPLED_ABOVE = 100_000
_AXES = {"x": 0, "y": 1, "z": 2}
# the packing efficiency the straightened borders of the packing splits may lose (else they stay as cut)
_STRAIGHT_LOSS = 0.005

# the conformal estimate ran 0.3-0.45 above the flattened charts' mean symmetric Dirichlet on the
# meshes tried; the first cut aims this much above the goal, and flatten_to corrects it by measurement
_ESTIMATE_GAP = 0.35
_MARGIN = 0.005  # the default gap between charts, a fraction of the square's side
_PADDING = 2.0  # texels between charts when a resolution is given without a padding
_DIAGONAL = 1e4  # how much dearer a seam is along a polygon's diagonal (an edge of its fan only)
# the coarse screen of many packing splits (:func:`~geomopt.atlas.flat_splits.split_to_pack`): a coarser
# bitmap and fewer square packings than packing_estimate's defaults (128 pixels, 12 packings)
_COARSE_SCREEN = {"resolution": 64, "budget": 6}


@dataclasses.dataclass(frozen=True)
class AtlasOptions:
    """Settings of :func:`make_atlas` (validated).

    Attributes
    ----------
    max_distortion : the area-weighted mean symmetric Dirichlet (4 = isometric) the cone cuts
        bring the flattened charts down to (chosen by a conformal estimate,
        :func:`~geomopt.atlas.cones.scale_estimate`, then checked by measurement,
        :func:`~geomopt.atlas.flatten.flatten_to`).  Lower: more seams.
    crease : how much cheaper a seam is along a crease (:func:`~geomopt.atlas.seams.edge_costs`).
    hide : how much cheaper a seam is where the surface is occluded: an edge's cost is scaled by
        its ambient visibility to this power (:func:`~geomopt.atlas.seams.exposure`; 0: seams
        ignore visibility, and none is computed).
    up : None, or the axis that points up ("x", "y", "z", "-x", "-y", "-z"): seams prefer the
        underside (:func:`~geomopt.atlas.seams.underside`).
    straighten : the price of a seam's turning, in median edge costs per radian where it passes
        through a vertex: seam paths are rerouted to turn less (:func:`~geomopt.atlas.seams.straighten`),
        the borders of the packing splits too, along the surface's seam cost
        (:func:`~geomopt.atlas.seams.straighten_splits`, kept when the packing loses at most 0.005
        of efficiency); 0: not straightened.
    straighten_packed : with ``straighten``, where the straightened borders of the packing splits
        were not kept (they lost packing), straighten them after packing instead, each piece
        keeping its rotation and translation (faces that change piece take their new piece's):
        kept where a border gets no longer, the atlas stays certified and every piece at least
        the margin from the others (:func:`~geomopt.atlas.packed_splits.straighten_packed`), so
        charts, distortion and packing efficiency are unchanged.
    max_cuts : the most cone cuts.
    min_efficiency : split the largest flattened chart (at the best of many straight cuts) and
        repack while the packing efficiency (chart area / unit square) is below this and each
        split pays ``split_gain`` per chart it adds (:func:`~geomopt.atlas.flat_splits.split_to_pack`).
    split_gain : the least rise of the packing efficiency a split must buy per extra chart it
        makes; its seam is charged too, by length (:func:`~geomopt.atlas.flat_splits.split_to_pack`).
    margin : None, or the least distance between two packed charts, as a fraction of the unit
        square's side (default 0.005; not with ``resolution``).
    resolution : None, or the texture's side in texels ``N``: the charts are packed for an
        ``N x N`` texture, every two charts at least ``padding`` texels apart (Euclidean distance
        in UV, ``padding / N``: the room a baker needs to dilate each chart for bilinear
        filtering and mip levels) and every chart at least ``padding / 2`` texels inside the
        square (so also ``padding`` apart across the edges of a repeating texture).
    padding : None, or the texels between charts with ``resolution`` (default 2); below
        ``resolution / 5``.
    rotate : let the packer rotate charts (orientation is always kept: no mirroring).
    weld : join each input mesh's vertices at bit-identical positions (an export that splits
        vertices along normals, UV seams or every face leaves them), where the joined mesh is
        one an atlas can take (:func:`welded`): the atlas then cuts where it chooses, not along
        every split the file had (an unwelded mesh is otherwise a chart per triangle).
    """

    max_distortion: float = 4.15
    crease: float = 2.0
    hide: float = 2.0
    up: str | None = None
    straighten: float = 3.0
    straighten_packed: bool = True
    max_cuts: int = 200
    min_efficiency: float = 0.7
    split_gain: float = 0.01
    margin: float | None = None
    resolution: int | None = None
    padding: float | None = None
    rotate: bool = True
    weld: bool = True

    def __post_init__(self):
        validate(self, max_distortion=Real(4.0, lo_open=True), crease=Real(0.0), max_cuts=Int(0),
                 hide=Real(0.0), straighten=Real(0.0), up=Maybe(OneOf(("x", "y", "z", "-x", "-y", "-z"))),
                 min_efficiency=Real(0.0, 1.0), split_gain=Real(0.0, 1.0), margin=Maybe(MARGIN),
                 resolution=Maybe(Int(1)), padding=Maybe(Real(0.0)), rotate=Instance(bool),
                 straighten_packed=Instance(bool), weld=Instance(bool))
        if self.resolution is None and self.padding is not None:
            raise ParameterError(f"AtlasOptions: padding ({self.padding!r} texels) needs the texture's resolution: "
                                 f"give resolution=N too (or a margin, a fraction of the square)")
        if self.resolution is not None and self.margin is not None:
            raise ParameterError("AtlasOptions: give a margin (a fraction of the square) or a resolution with its "
                                 "padding (texels), not both")
        N, P = self.resolution, self.texels
        if N is not None and not 5 * P < N:
            raise ParameterError(f"AtlasOptions: padding {P!r} texels is too wide for a {N}-texel texture: keep it "
                                 f"below resolution / 5 = {N / 5:g}")

    @property
    def texels(self) -> float | None:
        """The padding in texels with a resolution (``padding``, or 2), else None."""
        return None if self.resolution is None else (_PADDING if self.padding is None else self.padding)

    def packing(self) -> tuple[float, float]:
        """``(margin, inset)``: the charts are packed into the unit square ``margin`` apart, then
        scaled by ``1 - 2 inset`` about its centre.  Without a resolution ``(margin, 0)``; with
        ``N`` texels and a padding of ``P``, ``(P / (N - P), P / (2 N))``: after the scaling by
        ``1 - P / N`` the charts are ``P / N`` apart and ``P / (2 N)`` inside the square."""
        if self.resolution is None:
            return (_MARGIN if self.margin is None else self.margin), 0.0
        N, P = float(self.resolution), self.texels
        return P / (N - P), P / (2.0 * N)


class AtlasPart(tuple):
    """One input mesh of an atlas, as written: ``(V (n, 3), faces, uv (k, 2), uv_faces)`` with
    ``faces`` and ``uv_faces`` (m, 3) int64 arrays for a triangle mesh, else lists of each
    face's corners and their UV rows (polygons, in input order)."""

    __slots__ = ()

    def __new__(cls, V, faces, uv, uv_faces):
        return super().__new__(cls, (V, faces, uv, uv_faces))

    V = property(lambda self: self[0])
    faces = property(lambda self: self[1])
    uv = property(lambda self: self[2])
    uv_faces = property(lambda self: self[3])


@dataclasses.dataclass(frozen=True)
class AtlasDetails(Details):
    """What :func:`make_atlas` adds to its :class:`~geomopt.solvers.Result` (``result.details``):
    the atlas of the triangle mesh ``vertices`` (n, 3), ``faces`` (m, 3) (every input mesh, mesh
    after mesh, polygons fan-triangulated); ``result.x`` (k, 2) holds one UV per chart corner,
    inside ``[0, 1]^2``.

    Attributes
    ----------
    uv_faces : (m, 3) int64, the row of ``result.x`` of each face corner (faces in input order).
    chart : (m,) int64, the chart of each face.
    vertex : (k,) int64, the vertex (row of ``vertices``) of each UV row; where copies of a
        vertex were welded (``AtlasOptions.weld``), the first copy (``faces`` keep the input's).
    seams : (s, 2) int64, the cut edges as sorted vertex pairs (of the welded vertices).
    metrics : :class:`~geomopt.atlas.metrics.AtlasMetrics` (charts, seam length, mean and worst
        symmetric Dirichlet, packing efficiency, mirrored charts).
    charts : one :class:`~geomopt.solvers.Result` per chart (its flattening before packing).
    seconds : wall time of the whole call.
    pinched : (p,) int64, the pinched (non-manifold, "bow-tie") vertices, sorted: vertices whose
        faces form several fans, each split into one copy per fan before cutting (so the atlas
        has at least one UV per fan there, even without a seam through them).
    vertices, faces : the triangle mesh the atlas maps.
    counts : (p,) int64, corners of each input face (3 for a triangle): the fan of face ``j``
        is the ``counts[j] - 2`` consecutive rows of ``faces`` from ``sum(counts[:j] - 2)``.
    vertex_offsets, face_offsets : (meshes + 1,) int64, input mesh ``i``'s vertices and faces
        (polygons) as ranges of ``vertices`` and ``counts``.
    margin : the least distance between two charts the packing kept (a fraction of the square);
        with ``AtlasOptions.resolution`` ``N``: ``padding / N``.
    """

    uv_faces: np.ndarray
    chart: np.ndarray
    vertex: np.ndarray
    seams: np.ndarray
    metrics: AtlasMetrics
    charts: tuple
    seconds: float
    pinched: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    counts: np.ndarray
    vertex_offsets: np.ndarray
    face_offsets: np.ndarray
    margin: float

    @property
    def meshes(self) -> int:
        """How many input meshes share the atlas."""
        return len(self.vertex_offsets) - 1

    def split_polygons(self) -> np.ndarray:
        """(q,) int64 the input faces (rows of ``counts``) that a seam crosses: written as their
        fan triangles (only a packing split through a polygon makes one)."""
        return np.flatnonzero(~polygon_uv_faces(self.uv_faces, self.counts)[1])

    def part(self, uv, i: int | None = None) -> AtlasPart:
        """Input mesh ``i``'s :class:`AtlasPart` (every mesh as one with ``i=None``), its faces
        as the input gave them (a polygon crossed by a seam, :meth:`split_polygons`, as its
        fan triangles) and only the UV rows of ``uv`` (``result.x``) they use."""
        k = self.meshes
        lo, hi = (0, k) if i is None else (int(i), int(i) + 1)
        if not 0 <= lo < hi <= k:
            raise ParameterError(f"the atlas has {k} mesh(es), 0-based ids 0 to {k - 1}; got {i}")
        n = self.counts - 2
        f0, f1 = (int(np.sum(n[:self.face_offsets[j]])) for j in (lo, hi))
        v0, v1 = int(self.vertex_offsets[lo]), int(self.vertex_offsets[hi])
        counts, T = self.counts[self.face_offsets[lo]:self.face_offsets[hi]], self.uv_faces[f0:f1]
        rows, T = np.unique(T, return_inverse=True)
        T = T.reshape(-1, 3)
        F = self.faces[f0:f1] - v0
        if (counts == 3).all():
            return AtlasPart(self.vertices[v0:v1], F, np.asarray(uv)[rows], T)
        corners, whole = polygon_uv_faces(T, counts)
        faces, uv_faces = _polygon_rows(F, T, counts, corners, whole)
        return AtlasPart(self.vertices[v0:v1], faces, np.asarray(uv)[rows], uv_faces)


def _polygon_rows(F, T, counts, corners, whole):
    """Per written face its vertices and UV rows: a whole polygon's corners, else its fan triangles."""
    fan = np.cumsum(counts - 2) - (counts - 2)
    ends = np.cumsum(counts)
    faces, uv_faces = [], []
    for j, k in enumerate(counts.tolist()):
        a = int(fan[j])
        if whole[j]:
            faces.append(_corner_vertices(F, a, k))
            uv_faces.append(corners[ends[j] - k:ends[j]])
        else:
            faces.extend(F[a:a + k - 2])
            uv_faces.extend(T[a:a + k - 2])
    return faces, uv_faces


def _corner_vertices(F, first, k):
    """The corners ``c0 .. c(k-1)`` of the polygon whose fan is rows ``first ..`` of ``F``."""
    fan = F[first:first + k - 2]
    return np.r_[fan[0, 0], fan[:, 1], fan[-1, 2]]


def check_atlas_input(V, F):
    """``(V, F)`` as float64 (n, 3) and int64 (m, 3), refused with one line (MeshError) when an
    atlas cannot be made: non-finite vertices, a face repeating a vertex, a zero-area face, an
    edge of more than two faces, or faces not consistently oriented."""
    V = validate_vertices(V, "V", dim=3)
    F = as_faces(F, len(V))
    bad = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    if bad.any():
        raise MeshError(f"{int(bad.sum())} face(s) use the same vertex twice (first: face "
                        f"{int(np.argmax(bad))}); remove these degenerate faces")
    P = V[F]
    area2 = np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    scale = max(float(np.ptp(V[F.ravel()], axis=0).max()), np.finfo(float).tiny)
    flat = area2 <= 1e-14 * scale ** 2
    if flat.any():
        raise MeshError(f"{int(flat.sum())} face(s) have zero area (first: face {int(np.argmax(flat))}); "
                        f"remove or repair them (e.g. trimesh's remove_degenerate_faces) before making an atlas")
    E, count, _ = unique_edges(F)
    if (count > 2).any():
        first = int(np.argmax(count > 2))
        a, b = E[first]
        raise MeshError(f"{int((count > 2).sum())} non-manifold edges (used by more than 2 faces; first: the edge of "
                        f"vertices {a} and {b}, in {int(count[first])} faces); an atlas needs an edge-manifold "
                        f"mesh: split or remove the extra faces" + repeated_elements(F))
    same, _ = same_side_facets(F)
    if same and not orientable(F):
        raise MeshError("the surface is non-orientable (a Moebius strip, a Klein bottle: no consistent face "
                        "orientation exists), which an atlas of this library does not map: cut it into "
                        "orientable parts, or map each part as its own mesh")
    if same:
        raise MeshError(f"inconsistent face orientation: {same} edge(s) used twice in the same direction; "
                        f"orient the faces consistently (e.g. trimesh.repair.fix_winding)")
    return V, F


def welded(V, F, offsets):
    """``(F, joined)``: the checked faces ``F`` with the vertices of each input mesh (rows
    ``offsets[i]:offsets[i + 1]`` of ``V``) at bit-identical positions made one, the first of them
    (:func:`~geomopt.exact.weld.equal_points`), and how many vertices were joined; ``(F, 0)``
    where none are, or where the joined faces would be refused by :func:`check_atlas_input` (an
    edge of three faces, a face on one vertex twice, faces not consistently oriented: the copies
    were kept apart on purpose).  Meshes are never joined to each other."""
    rep = np.arange(len(V))
    for lo, hi in zip(offsets[:-1], offsets[1:]):
        first, group = equal_points(V[lo:hi])
        rep[lo:hi] = lo + first[group]
    used = np.unique(F)
    joined = int(np.count_nonzero(rep[used] != used))
    if not joined:
        return F, 0
    try:
        return check_atlas_input(V, rep[F])[1], joined
    except MeshError:
        return F, 0


def _looks(g, options) -> dict:
    """The keywords of :func:`~geomopt.atlas.seams.edge_costs` that hide the seams: each
    vertex's visibility (when ``options.hide``) and the up axis (when ``options.up``)."""
    up = None
    if options.up is not None:
        up = np.zeros(3)
        up[_AXES[options.up[-1]]] = -1.0 if options.up.startswith("-") else 1.0
    sampled = len(g.V) > _SAMPLED_ABOVE
    visibility = vertex_visibility(g.V, g.F, _COST_RAYS, sampled=sampled) if options.hide > 0 else None
    return {"visibility": visibility, "hide": options.hide, "up": up}


def _say(progress, stage, **info):
    if progress is True:
        logger.info(f"atlas {stage}: " + ", ".join(f"{k} {v:.6g}" if isinstance(v, float) else f"{k} {v}"
                                                   for k, v in info.items()))
    elif callable(progress):
        progress(stage, info)


def _assemble(n_faces, meshes, packed):
    """Per-corner UVs ``(uv, uv_faces, vertex, chart)`` from the packed chart maps."""
    uv, uv_faces, vertex, offset = [], np.empty((n_faces, 3), dtype=np.int64), [], 0
    chart = np.empty(n_faces, dtype=np.int64)
    for c, (mesh, x) in enumerate(zip(meshes, packed)):
        uv.append(np.asarray(x, dtype=np.float64))
        uv_faces[mesh.faces] = mesh.F + offset
        chart[mesh.faces] = c
        vertex.append(mesh.vertices)
        offset += len(mesh.wedges)
    return np.concatenate(uv), uv_faces, np.concatenate(vertex), chart


def _check_options(options, energy, progress, where="make_atlas"):
    """The options (defaults for None) and the energy with its parameters, checked."""
    from ..solvers._iterate import check_progress

    options = AtlasOptions() if options is None else options
    if not isinstance(options, AtlasOptions):
        raise ParameterError(f"options must be a geomopt.atlas.AtlasOptions, got {type(options).__name__}")
    check_progress(progress, where)
    energy, energy_params = energy_spec(energy, where)
    get_energy(energy).check_scale_aware(energy_params)
    return options, energy, energy_params


@float64
def make_atlas(V, F=None, energy="symmetric_dirichlet", solver=None, *, options=None, progress=True,
               throw=False) -> Result:
    """A certified texture atlas of any edge-manifold surface: closed of any genus, with several
    boundary loops, with several components, of triangles or polygons, or of several meshes
    sharing one UV square (module doc).

    Parameters
    ----------
    V : (n, 3) float vertices; or a mesh object with ``.vertices`` and ``.faces`` (``F=None``);
        or, with ``F=None``, a list of meshes (mesh objects or ``(V, F)`` pairs): one atlas
        whose charts share the unit square (:meth:`AtlasDetails.part` gives each mesh's).
    F : (m, 3) int consistently oriented triangles, (m, k) polygons of k corners, or a list of
        polygons (convex, any number of corners): each is cut into a fan of triangles whose
        diagonals no seam follows, so that it lies in one chart and keeps one UV per corner.
    energy, solver : how each chart is flattened (see :func:`geomopt.parameterize`; ``energy``
        a name, an Energy or ``(name, {parameter: value})``).
    options : :class:`AtlasOptions` (cutting, margin or resolution and padding, rotation).
    progress : True: one record per stage on the ``geomopt`` logger (INFO; see
        :mod:`geomopt._runtime.log`) and the charts' solves' progress; a callable gets
        ``(stage, info_dict)``.
    throw : raise :class:`~geomopt.SolveError` (carrying the result) when it is not certified.

    Returns
    -------
    :class:`~geomopt.solvers.Result`: ``x`` (k, 2) one UV per chart corner in ``[0, 1]^2``;
    ``certificate`` the exact :class:`~geomopt.atlas.AtlasCertificate` of the whole atlas;
    ``success`` when every chart flattened and the atlas is certified; ``stats`` the charts'
    iterations, their total energy before packing (``mean_energy`` over the total area) and
    the call's seconds; ``details`` an :class:`AtlasDetails` (faces' UV rows, charts, seams,
    metrics, the charts' own results).  ``result.save("atlas.obj", png="atlas.png")`` writes it
    (:func:`geomopt.save`).

    Raises
    ------
    MeshError : invalid or non-manifold input (:func:`check_atlas_input`).
    ParameterError : bad options or energy parameters, or more charts than the margin (padding)
        can keep apart.

    Examples
    --------
    A closed tetrahedron (no boundary, so no single disk) becomes a certified atlas:

    >>> import geomopt
    >>> V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    >>> F = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    >>> result = geomopt.make_atlas(V, F, progress=False)
    >>> result.success, result.details.uv_faces.shape
    (True, (4, 3))
    """
    t0 = time.perf_counter()
    options, energy, energy_params = _check_options(options, energy, progress)
    given = atlas_input(V, F)
    V, faces = check_atlas_input(given.V, given.F)  # the input's faces, in the details
    F, g, manifold, pinched = _manifold_graph(V, faces, given.vertex_offsets if options.weld else None, progress)
    cost, tree_cost = _costs(g, given, options)
    cut, estimate, made = cut_surface(g, cost, options.max_distortion + _ESTIMATE_GAP, options.max_cuts,
                                      tree_cost=tree_cost, turn=options.straighten)
    _say(progress, "cut", seam_length=float(g.length[cut].sum()), cone_cuts=made, estimate=estimate)

    def solve(Vc, Fc, free=None, scaffold=True):
        return flatten_chart(Vc, Fc, energy, solver, energy_params, free=free, scaffold=scaffold)

    cut, split, meshes, results = flatten_to(g, cost, cut, estimate, options.max_distortion, solve,
                                             options.max_cuts - made, lambda stage, **info: _say(progress, stage, **info),
                                             turn=options.straighten)
    margin, inset = options.packing()
    _check_room(options, margin, len(meshes))

    def pack(maps, faces, certify=False):  # trial packings: the chosen one is certified by _place
        return pack_charts(maps, faces, margin=margin, rotate=options.rotate, certify=certify)

    def screen(maps, faces, boundaries, coarse=False):
        return packing_estimate(maps, faces, margin=margin, rotate=options.rotate, boundaries=boundaries,
                                **(_COARSE_SCREEN if coarse else {}))

    charts, flat = meshes, [r.x for r in results]
    meshes, maps, packing, owner = split_to_pack(charts, flat, pack, options.min_efficiency,
                                                 min_gain=options.split_gain,
                                                 screen=screen, V=g.V,
                                                 prescreen=lambda *a: screen(*a, coarse=True))
    repacked = False
    if options.straighten > 0 and len(meshes) > len(charts):  # the splits' borders follow the seam cost too
        pieces, order, changed = straighten_splits(g, tree_cost, charts, flat, owner, list(zip(meshes, maps)),
                                                   options.straighten)
        again = pack([x for _, x in pieces], [m.F for m, _ in pieces]) if changed else None
        repacked = again is not None and again.efficiency >= packing.efficiency - _STRAIGHT_LOSS
        if repacked:
            meshes, maps, packing, owner = [m for m, _ in pieces], [x for _, x in pieces], again, order
    if options.straighten > 0 and options.straighten_packed and not repacked and len(meshes) > len(set(owner)):
        meshes, maps, uvs, moved = straighten_packed(g, tree_cost, charts, flat, owner, meshes, maps, packing,
                                                     margin, options.straighten)
        packing = dataclasses.replace(packing, uvs=uvs) if moved else packing
    if len(meshes) > len(set(owner)):
        _say(progress, "split to pack", charts=len(meshes), efficiency=packing.efficiency)
    uv, uv_faces, wedge, chart, certificate = _place(len(F), meshes, maps, packing, pack, inset)
    details = AtlasDetails(uv_faces, chart, manifold.vertex[wedge], seam_edges(F, uv_faces), atlas_metrics(V, F, uv, uv_faces),
                           tuple(results[i] for i in owner), 0.0, pinched, V, faces, given.counts,
                           given.vertex_offsets, given.face_offsets, margin * (1.0 - 2.0 * inset))
    return _result(uv, certificate, details, results, solver, t0, progress, throw)


def _place(n_faces, meshes, maps, packing, pack, inset):
    """The packed charts assembled (:func:`_assemble`), inset by ``inset`` from the square's
    edges, with the one exact certificate of the packing; trial packings are uncertified, so a
    packing that fails it (not expected: the rasters are conservative) is packed again, certified."""
    uv, uv_faces, wedge, chart = _assemble(n_faces, meshes, packing.uvs)
    uv = inset + (1.0 - 2.0 * inset) * uv if inset else uv
    certificate = certify_atlas(uv, uv_faces, chart)
    if pack is not None and (len(certificate.overlapping_pairs) or certificate.out_of_range):
        return _place(n_faces, meshes, maps, pack(maps, [m.F for m in meshes], certify=True), None, inset)
    return uv, uv_faces, wedge, chart, certificate


def _manifold_graph(V, F, offsets, progress):
    """``(F, g, split, pinched)``: the faces with each mesh's copies of a vertex welded
    (:func:`welded`, the meshes' vertex ``offsets``; None: not welded), the edge graph of that
    mesh with its pinched vertices split (one wedge per fan), the split
    (:func:`~geomopt.atlas.charts.charts_of_cut`) and the pinched vertices."""
    if offsets is not None:
        F, joined = welded(V, F, offsets)
        if joined:
            _say(progress, "welded", vertices=joined)
    g0 = edge_graph(V, F)
    manifold = charts_of_cut(F, g0.edge_of, g0.edge_faces, np.zeros(len(g0.E), dtype=bool))  # bow-ties apart
    pinched = np.flatnonzero(np.bincount(manifold.vertex, minlength=len(V)) > 1)  # one wedge per fan
    if len(pinched):
        _say(progress, "pinched vertices split", count=len(pinched), first=int(pinched[0]))
    return F, edge_graph(V[manifold.vertex], manifold.wedge), manifold, pinched


def _costs(g, given: AtlasInput, options):
    """The seams' edge costs and the strong cones' tree's, each ``_DIAGONAL`` times dearer along
    a polygon's diagonal."""
    looks = _looks(g, options)
    cost = edge_costs(g, options.crease, angle_defects(g.V, g.F), **looks)
    tree_cost = edge_costs(g, options.crease, **looks)
    diagonal = np.unique(g.edge_of[given.diagonals()])
    cost[diagonal] *= _DIAGONAL
    tree_cost[diagonal] *= _DIAGONAL
    return cost, tree_cost


def _check_room(options, margin, charts):
    """Refuse, in the options' own terms, a padding too wide for the charts made."""
    if options.resolution is not None and margin >= widest_margin(charts):
        P, N = options.texels, options.resolution
        raise ParameterError(f"padding {P:g} texels cannot keep {charts} charts apart in a {N}-texel texture "
                             f"(at most {widest_margin(charts) * N / (1 + widest_margin(charts)):.4g} texels "
                             f"fit): use a smaller padding or a larger resolution")


def _result(uv, certificate, details, results, solver, t0, progress, throw) -> Result:
    """The atlas's :class:`Result` (see :func:`make_atlas`), said and, with ``throw``, raised."""
    failed = [i for i, r in enumerate(results) if not r.success]
    outcome, reason = Outcome.CONVERGED, ""
    if failed:
        first = results[failed[0]]
        outcome = first.outcome if first.outcome is not Outcome.CONVERGED else Outcome.NOT_INJECTIVE
        reason = f"chart {failed[0]} ({len(failed)} chart(s)) not flattened: {first.message}"
    elif not certificate.ok:
        reason = f"not certified: {certificate.message}"
    seconds = time.perf_counter() - t0
    stats = RunStats(iterations=sum(r.stats.iterations for r in results),
                     evaluations=sum(r.stats.evaluations for r in results),
                     outer_iterations=sum(r.stats.outer_iterations for r in results),
                     seconds=seconds, energy=float(sum(r.stats.energy for r in results)),
                     volume=float(sum(r.stats.volume for r in results)), certify_seconds=certificate.seconds)
    result = Result(uv, outcome, certificate, stats, solver=solver, reason=reason,
                    details=dataclasses.replace(details, seconds=seconds))
    m = details.metrics
    _say(progress, "packed", efficiency=m.efficiency, certified=bool(certificate.ok),
         mean_symmetric_dirichlet=m.mean_symmetric_dirichlet, success=result.success)
    if not result.success:
        _say(progress, "not successful", message=result.message)
        if throw:
            raise SolveError(f"the atlas is not certified: {result.message}", result)
    return result

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

from .._runtime.config import Instance, Int, Maybe, OneOf, Real, keyword_only, validate
from .._runtime.errors import MeshError, ParameterError, SolveError
from .._runtime.log import logger
from .._runtime.validate import validate_vertices
from .._runtime.x64 import float64
from ..energies import energy_spec
from ..exact.topology import as_faces, same_side_facets, unique_edges
from .charts import split_charts
from .cones import angle_defects
from .cutting import cut_surface
from .flatten import flatten_chart, flatten_to
from .metrics import AtlasMetrics, atlas_metrics, seam_edges
from .seams import edge_costs, edge_graph
from .visibility import vertex_visibility
from ._pack import MARGIN, packing_estimate
from .split import split_to_pack

__all__ = ["make_atlas", "Atlas", "AtlasOptions", "check_atlas_input"]

# rays per vertex of the visibility that weights the seams' cost (the reported figure uses 96 per edge)
_COST_RAYS = 32
_AXES = {"x": 0, "y": 1, "z": 2}

# the conformal estimate ran 0.3-0.45 above the flattened charts' mean symmetric Dirichlet on the
# meshes tried; the first cut aims this much above the goal, and flatten_to corrects it by measurement
_ESTIMATE_GAP = 0.35
# the coarse screen of many packing splits (:func:`~geomopt.atlas.split.split_to_pack`): a coarser
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
        through a vertex: seam paths are rerouted to turn less (:func:`~geomopt.atlas.seams.straighten`;
        0: not straightened).
    max_cuts : the most cone cuts.
    min_efficiency : split the largest flattened chart (at the best of many straight cuts) and
        repack while the packing efficiency (chart area / unit square) is below this and each
        split pays ``split_gain`` per chart it adds (:func:`~geomopt.atlas.split.split_to_pack`).
    split_gain : the least rise of the packing efficiency a split must buy per extra chart it
        makes; its seam is charged too, by length (:func:`~geomopt.atlas.split.split_to_pack`).
    margin : gap between packed charts, as a fraction of the unit square.
    rotate : let the packer rotate charts (orientation is always kept: no mirroring).
    """

    max_distortion: float = 4.15
    crease: float = 2.0
    hide: float = 2.0
    up: str | None = None
    straighten: float = 3.0
    max_cuts: int = 200
    min_efficiency: float = 0.7
    split_gain: float = 0.01
    margin: float = 0.005
    rotate: bool = True

    def __post_init__(self):
        validate(self, max_distortion=Real(4.0, lo_open=True), crease=Real(0.0), max_cuts=Int(0),
                 hide=Real(0.0), straighten=Real(0.0), up=Maybe(OneOf(("x", "y", "z", "-x", "-y", "-z"))),
                 min_efficiency=Real(0.0, 1.0), split_gain=Real(0.0, 1.0), margin=MARGIN, rotate=Instance(bool))


@dataclasses.dataclass(frozen=True)
class Atlas:
    """A texture atlas of a triangle mesh (``V`` (n, 3), ``F`` (m, 3)).

    Attributes
    ----------
    uv : (k, 2) float64, one UV per chart corner, inside ``[0, 1]^2``.
    uv_faces : (m, 3) int64, the UV row of each face corner (faces in input order).
    chart : (m,) int64, the chart of each face.
    vertex : (k,) int64, the input vertex of each UV row.
    seams : (s, 2) int64, the cut edges as sorted input vertex pairs.
    metrics : :class:`~geomopt.atlas.metrics.AtlasMetrics` (charts, seam length, mean and worst
        symmetric Dirichlet, packing efficiency, mirrored charts).
    certificate : the exact certificate of the packed atlas (``certify_atlas``).
    results : one :class:`~geomopt.solvers.Result` per chart (its flattening before packing).
    seconds : wall time of the whole call.
    pinched : (p,) int64, the input's pinched (non-manifold, "bow-tie") vertices, sorted: vertices
        whose faces form several fans, each split into one copy per fan before cutting (so the
        atlas has at least one UV per fan there, even without a seam through them).
    """

    uv: np.ndarray
    uv_faces: np.ndarray
    chart: np.ndarray
    vertex: np.ndarray
    seams: np.ndarray
    metrics: AtlasMetrics
    certificate: object
    results: tuple
    seconds: float
    pinched: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def success(self) -> bool:
        """Every chart flattened flip-free and the packed atlas certified."""
        return bool(self.certificate.ok) and all(r.success for r in self.results)

    @property
    def message(self) -> str:
        failed = [i for i, r in enumerate(self.results) if not r.success]
        if failed:
            return f"chart {failed[0]} ({len(failed)} chart(s)) not flattened: {self.results[failed[0]].message}"
        return "certified" if self.certificate.ok else f"not certified: {self.certificate.message}"


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
                        f"mesh: split or remove the extra faces")
    same, _ = same_side_facets(F)
    if same:
        raise MeshError(f"inconsistent face orientation: {same} edge(s) used twice in the same direction; "
                        f"orient the faces consistently (e.g. trimesh.repair.fix_winding), or the surface "
                        f"is non-orientable")
    return V, F


def _looks(g, options) -> dict:
    """The keywords of :func:`~geomopt.atlas.seams.edge_costs` that hide the seams: each
    vertex's visibility (when ``options.hide``) and the up axis (when ``options.up``)."""
    up = None
    if options.up is not None:
        up = np.zeros(3)
        up[_AXES[options.up[-1]]] = -1.0 if options.up.startswith("-") else 1.0
    visibility = vertex_visibility(g.V, g.F, _COST_RAYS) if options.hide > 0 else None
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


@keyword_only(4, ("options", "progress", "throw"))
@float64
def make_atlas(V, F=None, energy="symmetric_dirichlet", solver=None, *, options=None, progress=True,
               throw=False, **energy_params) -> Atlas:
    """A certified texture atlas of any edge-manifold triangle mesh: closed of any genus, with
    several boundary loops, with several components (module doc).

    Parameters
    ----------
    V : (n, 3) float vertices, or a mesh object with ``.vertices`` and ``.faces`` (``F=None``).
    F : (m, 3) int consistently oriented triangles.
    energy, solver : how each chart is flattened (see :func:`geomopt.parameterize`; ``energy``
        a name, an Energy or ``(name, {parameter: value})``); ``energy_params``: deprecated keywords.
    options : :class:`AtlasOptions` (cutting, margin, rotation).
    progress : True: one record per stage on the ``geomopt`` logger (INFO; see
        :mod:`geomopt._runtime.log`) and the charts' solves' progress; a callable gets
        ``(stage, info_dict)``.
    throw : raise :class:`~geomopt.SolveError` (carrying the atlas) when it is not certified.

    Returns
    -------
    :class:`Atlas`

    Raises
    ------
    MeshError : invalid or non-manifold input (:func:`check_atlas_input`).

    Examples
    --------
    A closed tetrahedron (no boundary, so no single disk) becomes a certified atlas:

    >>> import geomopt
    >>> V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    >>> F = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    >>> atlas = geomopt.make_atlas(V, F, progress=False)
    >>> atlas.certificate.ok, atlas.uv_faces.shape
    (True, (4, 3))
    """
    from ..param import check_scale_aware, mesh_arrays
    from ..solvers._iterate import check_progress
    from . import certify_atlas, pack_charts

    t0 = time.perf_counter()
    options = AtlasOptions() if options is None else options
    if not isinstance(options, AtlasOptions):
        raise ParameterError(f"options must be a geomopt.atlas.AtlasOptions, got {type(options).__name__}")
    check_progress(progress, "make_atlas")
    settings = [k for k in energy_params if k in {f.name for f in dataclasses.fields(AtlasOptions)}]
    if settings:  # not an energy parameter: say where it goes
        given = ", ".join(f"{k}={energy_params[k]!r}" for k in settings)
        are = "is an AtlasOptions field" if len(settings) == 1 else "are AtlasOptions fields"
        raise ParameterError(f"make_atlas: {', '.join(settings)} {are}: pass options=AtlasOptions({given})")
    energy, energy_params = energy_spec(energy, energy_params, "make_atlas")
    check_scale_aware(energy, energy_params)
    V, F = check_atlas_input(*mesh_arrays(V, F))
    g0 = edge_graph(V, F)
    manifold = split_charts(F, g0.edge_of, g0.edge_faces, np.zeros(len(g0.E), dtype=bool))  # bow-ties apart
    pinched = np.flatnonzero(np.bincount(manifold.vertex, minlength=len(V)) > 1)  # one wedge per fan
    if len(pinched):
        _say(progress, "pinched vertices split", count=len(pinched), first=int(pinched[0]))
    g = edge_graph(V[manifold.vertex], manifold.wedge)
    looks = _looks(g, options)
    cost = edge_costs(g, options.crease, angle_defects(g.V, g.F), **looks)
    cut, estimate, made = cut_surface(g, cost, options.max_distortion + _ESTIMATE_GAP, options.max_cuts,
                                      tree_cost=edge_costs(g, options.crease, **looks), turn=options.straighten)
    _say(progress, "cut", seam_length=float(g.length[cut].sum()), cone_cuts=made, estimate=estimate)

    def solve(Vc, Fc, free=None, scaffold=True):
        return flatten_chart(Vc, Fc, energy, solver, energy_params, free=free, scaffold=scaffold)

    cut, split, meshes, results = flatten_to(g, cost, cut, estimate, options.max_distortion, solve,
                                             options.max_cuts - made, lambda stage, **info: _say(progress, stage, **info),
                                             turn=options.straighten)
    def pack(maps, faces, certify=False):  # trial packings: the chosen one is certified below
        return pack_charts(maps, faces, margin=options.margin, rotate=options.rotate, certify=certify)

    def screen(maps, faces, boundaries, coarse=False):
        return packing_estimate(maps, faces, margin=options.margin, rotate=options.rotate, boundaries=boundaries,
                                **(_COARSE_SCREEN if coarse else {}))

    meshes, maps, packing, owner = split_to_pack(meshes, [r.x for r in results], pack, options.min_efficiency,
                                                 min_gain=options.split_gain,
                                                 screen=screen, V=g.V,
                                                 prescreen=lambda *a: screen(*a, coarse=True))
    results = [results[i] for i in owner]
    if len(meshes) > len(set(owner)):
        _say(progress, "split to pack", charts=len(meshes), efficiency=packing.efficiency)
    uv, uv_faces, wedge, chart = _assemble(len(F), meshes, packing.uvs)
    certificate = certify_atlas(uv, uv_faces, chart)  # the one exact certificate of the packing
    if len(certificate.overlapping_pairs) or certificate.out_of_range:  # not expected: rasters are conservative
        packing = pack(maps, [m.F for m in meshes], certify=True)  # retried finer until certified
        uv, uv_faces, wedge, chart = _assemble(len(F), meshes, packing.uvs)
        certificate = certify_atlas(uv, uv_faces, chart)
    metrics = atlas_metrics(V, F, uv, uv_faces)
    atlas = Atlas(uv, uv_faces, chart, manifold.vertex[wedge], seam_edges(F, uv_faces), metrics,
                  certificate, tuple(results), time.perf_counter() - t0, pinched)
    _say(progress, "packed", efficiency=metrics.efficiency, certified=bool(certificate.ok),
         mean_symmetric_dirichlet=metrics.mean_symmetric_dirichlet, success=atlas.success)
    if not atlas.success:
        _say(progress, "not successful", message=atlas.message)
    if throw and not atlas.success:
        raise SolveError(f"the atlas is not certified: {atlas.message}", atlas)
    return atlas

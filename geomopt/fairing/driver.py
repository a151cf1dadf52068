"""Surface and curve smoothing that never folds a face: :func:`fair` (certified, on the host)
and :func:`smoothed` (the method's target, differentiable with JAX).

:func:`fair` runs a method of :mod:`geomopt.fairing.methods` (or :mod:`geomopt.fairing.relax`),
which gives target vertices ``p*``; then

1. the **fold-safe step** (:func:`geomopt.fairing.certificate.safe_step`) goes from the input
   towards ``p*`` as far as each vertex can without a face folding that was not folded in the
   input (exact signs);
2. where the input itself has folded faces (heavy noise), **fold removal**
   (:func:`geomopt.fairing.unfold.remove_folds`) smooths growing neighbourhoods of the folded
   faces, keeping a round only where it folds fewer faces: the output never has more folded
   faces than the input (a face the input had unfolded may end folded while many others
   unfold: ``details.folds_added`` counts them; without fold removal it is 0);
3. with ``preserve_volume`` (closed surfaces), the result is scaled about its centroid to the
   input's enclosed volume (kept only if it folds nothing);
4. the **certificate** (:func:`geomopt.fairing.certificate.certify_folds`) of the output decides
   the outcome: CONVERGED when no face is folded, NOT_INJECTIVE otherwise.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .._runtime.config import options_or_default
from .._runtime.errors import MeshError, ParameterError, SolveError
from ..exact.topology import boundary_loops
from ..solvers import Details, Outcome, Result, RunStats
from .certificate import Stars, certify_folds, describe_folds, recertified, safe_step
from .methods import TARGETS
from .operators import Topology, mean_edge_length, xp_of
from .options import FairOptions
from .relax import relax
from .surface import largest_face_distance, shape_measures, volume
from .unfold import remove_folds

__all__ = ["fair", "smoothed", "FairDetails"]


@dataclasses.dataclass(frozen=True)
class FairDetails(Details):
    """What :func:`fair` adds to its :class:`~geomopt.solvers.Result`.

    Attributes
    ----------
    options : the :class:`FairOptions` used (defaults resolved).
    target : (n, d) the method's result before the fold-safe step (:func:`smoothed`).
    cut : vertices whose step towards ``target`` was shortened to keep every face unfolded.
    folded_before : faces folded in the input (its own certificate).
    removal_rounds : rounds of fold removal (0 when the input had no fold).
    volume_before, volume_after : enclosed volumes of a closed surface (nan otherwise).
    min_angle_before, min_angle_after : the smallest triangle angle, degrees (nan for curves).
    aspect_before, aspect_after : the largest aspect ratio (1: equilateral; nan for curves).
    folds_added : faces folded in the output that were not folded in the input (0 unless the
        input was folded and fold removal traded them for more unfolded ones).
    distance : ``relax``: the largest distance of an output face to the input surface (at a
        grid of 28 points on each face, :func:`~geomopt.fairing.surface.largest_face_distance`), over
        the input's bounding-box diagonal (nan for the other methods).
    scale : the power of two the input was multiplied by while smoothing (exact).
    """

    options: FairOptions
    target: np.ndarray
    cut: int
    folded_before: int
    removal_rounds: int
    volume_before: float
    volume_after: float
    min_angle_before: float
    min_angle_after: float
    aspect_before: float
    aspect_after: float
    distance: float = float("nan")
    scale: float = 1.0
    folds_added: int = 0

    @property
    def message(self) -> str:
        """One line: the fold counts, cuts, and quality before and after."""
        text = f"folded faces {self.folded_before} in the input; {self.cut} vertex steps cut to keep faces unfolded"
        if self.removal_rounds:
            text += f"; {self.removal_rounds} rounds of fold removal ({self.folds_added} faces folded that were not)"
        if np.isfinite(self.min_angle_before):
            text += (f"; min angle {self.min_angle_before:.2f} -> {self.min_angle_after:.2f} deg, max aspect "
                     f"{self.aspect_before:.3g} -> {self.aspect_after:.3g}")
        if np.isfinite(self.volume_before):
            text += f"; volume {self.volume_before:.6g} -> {self.volume_after:.6g}"
        return text


def _checked(V, F):
    """``(V float64 (n, d), F int64 (m, k), topology)`` or MeshError."""
    from .._runtime.validate import validate_vertices
    from ..exact.topology import as_faces

    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] not in (2, 3):
        raise MeshError(f"fair needs triangles (m, 3) or polyline edges (m, 2), got elements of shape {F.shape}")
    V = validate_vertices(V, "vertices", dim=3 if F.shape[1] == 3 else None)
    F = as_faces(F, len(V), corners=F.shape[1], name="elements")
    if F.max() >= len(V):
        raise MeshError(f"elements index vertex {F.max()}, but there are {len(V)} vertices")
    k = F.shape[1]
    if any(np.any(F[:, i] == F[:, j]) for i in range(k) for j in range(i + 1, k)):
        raise MeshError("an element repeats a vertex: remove degenerate elements first")
    return V, F, Topology.of(F, len(V))


def _boundary_curve(V, topo, o, h):
    """The ``"curve"`` boundary mode: ``V`` (n, 3) with each boundary loop of the surface
    smoothed first as a closed polyline by the same method."""
    loops = boundary_loops(topo.elements)
    if not loops or o.method == "relax":
        return V
    edges = np.concatenate([np.stack([lp, np.roll(lp, -1)], axis=1) for lp in loops])
    curve = Topology.of(edges, topo.n)
    return TARGETS[o.method](V, curve, curve.free_mask("free"), dataclasses.replace(o, boundary="free"), h)


def _target(V, topo, o, h):
    """``(target, free)``: the method's result (n, d) (NumPy or JAX like ``V``) and the vertices
    it was free to move (n,) bool."""
    if o.boundary == "curve" and not topo.is_curve:
        V = _boundary_curve(V, topo, o, h)
        free = topo.free_mask("free")  # the boundary moved as a curve, then held
        free[topo.boundary] = False
        return TARGETS[o.method](V, topo, free, o, h), topo.free_mask("free")
    free = topo.free_mask(o.boundary)
    return TARGETS[o.method](V, topo, free, o, h), free


def smoothed(V, F, options: FairOptions | None = None):
    """The target of ``options.method``, before the fold-safe step and the certificate: a pure
    function of ``V``, differentiable with JAX in ``V`` and the traceable options (``lam``,
    ``mu``, ``time``, ``weight``), under ``jax.grad`` and ``jax.jit`` alike.

    Parameters
    ----------
    V : (n, 3) surface or (n, 2|3) polyline vertices, NumPy or JAX (float64).
    F : (m, 3) triangles or (m, 2) edges (concrete).
    options : :class:`FairOptions` (not ``relax``: its projection is not differentiable).

    Returns
    -------
    (n, d) like ``V``; :func:`fair`'s ``details.target``, and its ``x`` when no step was cut
    (``details.cut == 0``), no fold removed and no volume rescaled.
    """
    o = (options or FairOptions()).resolved()
    if o.method == "relax":
        raise ParameterError("smoothed: 'relax' projects onto the input surface and is not differentiable; "
                             "use fair(..., method='relax')")
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] not in (2, 3):
        raise MeshError(f"smoothed needs triangles (m, 3) or polyline edges (m, 2), got shape {F.shape}")
    topo = Topology.of(F.astype(np.int64), len(V))
    return _target(V, topo, o, mean_edge_length(V, topo))[0]


def _measures(X, topo):
    """``(volume, min angle, max aspect)`` of ``X``; nan where they do not apply."""
    if topo.is_curve:
        return float("nan"), float("nan"), float("nan")
    return shape_measures(X, topo.elements, closed=len(topo.boundary) == 0)


def _rescaled(X, topo, target_volume):
    """``X`` scaled about its centroid to enclose ``target_volume`` (a closed surface)."""
    now = volume(X, topo.elements)
    if not (now > 0 and target_volume > 0):
        return X
    c = X[np.unique(topo.elements)].mean(axis=0)
    return c + (X - c) * (target_volume / now) ** (1.0 / 3.0)


def fair(V, F, method: str | None = None, *, options: FairOptions | None = None, progress: bool = False,
         throw: bool = False) -> Result:
    """Smooth a triangle surface or a polyline with no face folding (see the module notes).

    Parameters
    ----------
    V : (n, 3) surface vertices, or (n, 2) / (n, 3) polyline vertices.
    F : (m, 3) triangles (consistently oriented; closed, with boundary, several components) or
        (m, 2) polyline edges (closed or open).
    method : a name of :data:`~geomopt.fairing.options.METHODS`; overrides ``options.method``.
    options : :class:`FairOptions`.
    progress : print a line on stderr after each phase (target, fold-safe step, fold removal).
    throw : raise :class:`SolveError` when the output is not certified (faces of a folded input
        that could not be unfolded).

    Returns
    -------
    :class:`~geomopt.solvers.Result`: ``x`` (n, d); ``certificate`` a
    :class:`~geomopt.fairing.certificate.FoldCertificate` (exact); ``outcome`` CONVERGED when no
    face is folded, else NOT_INJECTIVE; ``details`` a :class:`FairDetails`.

    Raises
    ------
    MeshError : malformed vertices or elements, a non-manifold edge.
    ParameterError : invalid options; ``preserve_volume`` on a surface with boundary or a curve.

    Examples
    --------
    A noisy circle (a closed polyline) smoothed by Taubin's filter:

    >>> import numpy as np
    >>> from geomopt.fairing import fair
    >>> a = np.linspace(0, 2 * np.pi, 100, endpoint=False)
    >>> V = np.c_[np.cos(a), np.sin(a)] + 0.01 * np.random.default_rng(0).normal(size=(100, 2))
    >>> E = np.c_[np.arange(100), (np.arange(100) + 1) % 100]
    >>> r = fair(V, E, "taubin")
    >>> r.success, r.certificate.inverted
    (True, 0)
    """
    t0 = time.perf_counter()
    o = options_or_default(FairOptions, options, "fair")
    if method is not None:
        o = dataclasses.replace(o, method=method)
    o = o.resolved()
    V, F, topo = _checked(V, F)
    if o.preserve_volume and (topo.is_curve or len(topo.boundary)):
        raise ParameterError("preserve_volume needs a closed triangle surface (this one has a boundary or is a curve)")
    from ..exact.predicates import box_scale

    scale = box_scale(V)
    X0 = V * scale  # exact: sizes near 1 whatever the input's
    h = mean_edge_length(X0, topo)
    before = certify_folds(X0, F)
    stars = Stars(topo.elements, topo.n)  # (built on first use, then shared by the step, fold removal and the certificate)
    if o.method == "relax":
        target, _ = relax(X0, topo, topo.free_mask(o.boundary), o)
        free = topo.free_mask(o.boundary)
    else:
        target, free = _target(X0, topo, o, h)
    _say(progress, f"fair: {o.method} target of {len(V)} vertices, {before.inverted} faces folded in the input")
    if o.method == "relax":  # each round was a whole-vertex fold-safe step: a fraction would leave the surface
        X, t, after = target, np.where(free, 1.0, 0.0), None
    else:
        X, t, after = safe_step(X0, target, F, free, start=before, certify=True, stars=stars)
    _say(progress, f"fair: fold-safe step, {int(np.count_nonzero(free & (t < 1)))} vertex steps cut")
    # (relax keeps its vertices on the input surface: the centroid moves of fold removal would not)
    stepped = X
    X, rounds = (remove_folds(X, topo, free, start=after, stars=stars) if before.inverted and o.method != "relax"
                 else (X, 0))
    _say(progress and rounds, f"fair: {rounds} rounds of fold removal")
    measured0 = _measures(X0, topo)
    t1 = time.perf_counter()
    # the output's certificate: the step's, taken again only around the vertices fold removal moved
    cert = certify_folds(X, F) if after is None else recertified(X, F, after, stepped, stars)
    if o.preserve_volume:
        scaled = _rescaled(X, topo, measured0[0])
        scaled_cert = certify_folds(scaled, F)
        X, cert = (scaled, scaled_cert) if scaled_cert.inverted <= cert.inverted else (X, cert)
    certified = (t1, time.perf_counter())
    return _result(V, X, cert, target, t, free, before, rounds, topo, o, scale, measured0, (t0,) + certified, throw)


def _say(progress, line):
    if progress:
        import sys

        print(line, file=sys.stderr, flush=True)


def _result(V, X, cert, target, t, free, before, rounds, topo, o, scale, measured0, times, throw):
    """:func:`fair`'s :class:`Result` of the smoothed ``X`` (in the frame scaled by ``scale``)
    and its certificate ``cert``; ``times``: ``(start, certificate begun, certificate done)``."""
    t0, t1, t2 = times
    vol1, angle1, aspect1 = _measures(X, topo)
    distance = float("nan")
    if o.method == "relax":
        Vs = V * scale
        diag = float(np.linalg.norm(Vs.max(axis=0) - Vs.min(axis=0)))
        distance = largest_face_distance(X, topo.elements, Vs, topo.elements, order=6) / diag
    details = FairDetails(o, target / scale, int(np.count_nonzero(free & (t < 1.0))), before.inverted, rounds,
                          measured0[0] / scale ** 3, vol1 / scale ** 3, measured0[1], angle1, measured0[2], aspect1,
                          distance, scale, len(np.setdiff1d(cert.folded, before.folded)))
    outcome = Outcome.CONVERGED if cert.ok else Outcome.NOT_INJECTIVE
    reason = "" if cert.ok else (f"{describe_folds(X, topo.elements, cert)}; the input's {before.inverted} folded faces "
                                 f"could not all be removed")
    if throw and not cert.ok:
        raise SolveError(f"fair: {reason}")
    stats = RunStats(iterations=o.steps, outer_iterations=rounds, seconds=t1 - t0, certify_seconds=t2 - t1)
    return Result(X / scale, outcome, cert, stats, reason=reason, details=details)

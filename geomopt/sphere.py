"""Spherical parameterization of closed genus-0 surfaces: a certified start, the injective
search on the sphere, and an exact certificate that the map covers the sphere once.

:func:`sphere_map` maps a closed, manifold, connected genus-0 triangle mesh bijectively onto the
unit sphere, minimising a distortion energy of the chord triangles (any density of 2x2
Jacobians: :meth:`geomopt.Problem.sphere`):

1. **Start** (:func:`sphere_start`): one vertex ``v``'s star is removed; the rest is a disk
   whose boundary is ``v``'s link, which goes onto the unit circle, and the interior is Tutte
   embedded (flip-free, Tutte 1963).  The plane, scaled by ``s``, is wrapped onto the sphere by
   inverse stereographic projection, ``v`` at the south pole.  A planar circle of centre ``c``
   and radius ``r`` is the image of a spherical cap smaller than a hemisphere iff
   ``s^2 (r^2 - |c|^2) < 1``: below that bound on every triangle's circumcircle, each chord
   triangle turns counter-clockwise about the centre as its planar triangle does, and the
   triangles through the pole do too (the link is convex around the origin).  The start is
   then certified exactly.  A harmonic map crowds long limbs exponentially (start energies
   of 1e7-1e14, L-BFGS then needs thousands of iterations or stalls), so the disk map is
   re-solved with stretch-minimising weights for a few rounds (:func:`_balanced_rounds`), each
   flip-free in the plane, and the round of least estimated distortion that certifies is the
   start; failing that, the plain Tutte map with ``s`` halved until it certifies.
2. **Search**: the map ``x`` (n, 3) stands for the directions ``x / |x|``.  A triangle stays
   positive along ``x + t d`` until ``det[x_a + t d_a, x_b + t d_b, x_c + t d_c]``, a cubic in
   ``t``, vanishes; radial rescaling never changes its sign, so this is the tet bound of
   :mod:`geomopt.solvers.linesearch` with the apex at the centre (:mod:`geomopt.mesh.geometry`), used by
   L-BFGS through the one loop (:func:`geomopt.solvers.iterate`).  The energy is invariant to
   each vertex's length, so the gradient is tangent; the map is projected onto the sphere at
   the end.  The rotation gauge is fixed by the objective's pinned vertex.
3. **Certificate** (:func:`geomopt.exact.certify.certify_sphere`): every triangle positively
   oriented about the centre (exact) and the spherical areas summing to ``4 pi``: degree 1, a
   bijection.  A map that fails it is never a success.

References: Gotsman, Gu & Sheffer 2003 (spherical embeddings); Praun & Hoppe 2003 (spherical
parametrization and remeshing); Smith & Schaefer 2015 (the injective step bound).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ._runtime.config import Instance, Int, Maybe, OneOf, options_or_default, validate
from ._runtime.errors import MeshError, ParameterError
from .objective.objective import Objective
from ._runtime.tracing import refuse_traced
from .energies import energy_spec, get_energy
from ._runtime.validate import validate_vertices
from ._runtime.x64 import float64
from .exact.certify import SphereCertificate, certify_sphere
from .mesh.convert import mesh_arrays
from .mesh.problem import Problem
from .objective.distortion import sphere_distortion
from .solvers import LBFGS, AbstractContinuation, Decision, Details, Final, Outcome, get_solver, iterate
from .solvers._iterate import check_progress
from .exact.topology import as_faces, boundary_loops, check_sphere
from .mesh.tutte import WEIGHTS as TUTTE_WEIGHTS, circle_boundary, tutte_weights, weighted_embedding
from .mesh.quality import triangle_areas, triangle_symmetric_dirichlet

__all__ = ["sphere_map", "SphereOptions", "sphere_start", "candidate_poles", "given_start", "sphere_distortion", "default_solver", "SphereDetails", "stereographic"]

#: halvings of the stereographic scale before a pole's start is given up (each halves every cap)
MAX_HALVINGS = 60
#: poles :func:`sphere_start` tries when none is given (:func:`candidate_poles`)
POLE_TRIES = 5
#: most rounds of the start's area balancing, the damping power of its weight update, and the
#: rounds without a lower estimate that end it (:func:`_balanced_rounds`; measured on cow and a
#: hand-and-arm scan: power 1 overshoots into slivers, 0.5 takes the cow from 1,586 L-BFGS
#: iterations to 569 and the arm from no certified map to 541)
BALANCE_ROUNDS, BALANCE_POWER, BALANCE_PATIENCE = 30, 0.5, 3
#: the most a vertex's stretch may differ from the median stretch in one round of balancing
#: (:func:`_balanced_rounds`; unbounded, a limb crowded beyond float64 gave stretches of 1e150;
#: 1e4 leaves the starts of cow, bunny and cheburashka as they were, 1e2 changed cow's)
BALANCE_SPREAD = 1e4
#: most rounds of balancing while every round so far leaves triangles flat in the plane or has an
#: estimate above CROWDED_ESTIMATE (a limb crowded past float64 needs its weights moved further than
#: BALANCE_ROUNDS bounded rounds move them: a tail 100 times longer than thick had a certified start
#: of mean symmetric Dirichlet 2.7e22 after 30 rounds, where L-BFGS failed its first line search,
#: and 3.5e8 after 100, whence it converged)
BALANCE_ROUNDS_CROWDED, CROWDED_ESTIMATE = 100, 1e6
#: the spread of vertex lengths (largest / smallest) at which the map is put back on the sphere
#: and L-BFGS restarted there, and the most such restarts (:func:`_radial_guard`)
RESPHERE_SPREAD, MAX_RESPHERES = 2.0, 100


@dataclasses.dataclass(frozen=True)
class SphereDetails(Details):
    """What :func:`sphere_map` adds to its :class:`~geomopt.solvers.Result`: the certified
    ``start`` map (n, 3), its ``pole`` vertex and stereographic ``scale`` (-1 and nan for a
    given start), the halvings of the scale its exact check needed, the start's
    :class:`~geomopt.exact.certify.SphereCertificate`, and the round of area balancing it
    comes from (0: the plain Tutte map; :func:`sphere_start`)."""

    start: np.ndarray
    pole: int
    scale: float
    halvings: int
    start_certificate: SphereCertificate
    balance_round: int = 0


def stereographic(p, s: float = 1.0) -> np.ndarray:
    """(n, 3) inverse stereographic projection of the plane points ``p`` (n, 2) scaled by ``s``
    onto the unit sphere: the origin to the north pole ``(0, 0, 1)``, infinity to the south
    pole; counter-clockwise planar triangles turn counter-clockwise seen from outside."""
    q = s * np.asarray(p, dtype=np.float64)
    r2 = np.sum(q * q, axis=1, keepdims=True)
    return np.concatenate([2.0 * q, 1.0 - r2], axis=1) / (1.0 + r2)


def _cap_bound(P, F) -> float:
    """``max over triangles of r^2 - |c|^2`` for the circumcircles (centre c, radius r) of the
    planar triangles ``P[F]``: the power of the origin with respect to each circle, negated
    (``|a|^2 - 2 a.c`` for a corner ``a``).  Triangles degenerate in floating point (no
    circumcircle) are left out: they certify at no scale, and counting them as an infinite bound
    put the whole map at the north pole (scale 0)."""
    a, b, c = (P[F[:, k]] for k in range(3))
    d = 2.0 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    ab, ac = b - a, c - a
    lab, lac = np.sum(ab * ab, axis=1), np.sum(ac * ac, axis=1)
    with np.errstate(all="ignore"):
        centre = a + np.stack([ac[:, 1] * lab - ab[:, 1] * lac, ab[:, 0] * lac - ac[:, 0] * lab], axis=1) / d[:, None]
        q = np.sum(a * a, axis=1) - 2.0 * np.sum(a * centre, axis=1)
    q = q[np.isfinite(q)]  # a triangle degenerate in the plane: no scale certifies it, none is set by it
    return float(np.max(q)) if len(q) else 0.0


def _disk_without(F, n, pole):
    """The faces of the mesh less ``pole``'s star, renumbered without ``pole``: ``(faces,
    keep, loop)``, ``keep`` (n-1,) the old ids of the new vertices, ``loop`` the link of
    ``pole`` (new ids) in half-edge direction."""
    rest = F[~np.any(F == pole, axis=1)]
    keep = np.delete(np.arange(n), pole)
    new = np.full(n, -1, np.int64)
    new[keep] = np.arange(n - 1)
    rest = new[rest]
    loops = boundary_loops(rest)
    if len(loops) != 1:  # cannot happen on a manifold vertex of a checked mesh
        raise MeshError(f"the link of vertex {pole} is not one loop; the mesh is not a manifold there")
    return rest, keep, loops[0]


@float64
def sphere_start(V, F, pole=None, weights="uniform"):
    """A certified start map of a closed genus-0 mesh onto the unit sphere (see the module notes).

    Parameters
    ----------
    V : (n, 3) rest vertices;  F : (m, 3) triangles, consistently oriented (checked by
        :func:`geomopt.exact.topology.check_sphere`).
    pole : the vertex put at the south pole (0-based).  Default: one of highest degree, then, when
        no start from it certifies, up to :data:`POLE_TRIES` - 1 others (:func:`candidate_poles`:
        the mesh's middle in edge hops, then vertices spread over it).
    weights : Tutte weights, ``"uniform"`` or ``"mean_value"``.

    Returns
    -------
    x : (n, 3) float64 unit vectors, every triangle positively oriented about the centre and the
        sphere covered once (certified exactly);  details : :class:`SphereDetails`.

    Raises
    ------
    MeshError : not a closed genus-0 manifold mesh, or no certified start from any pole tried
        (rounding on a badly shaped mesh, or limbs so long that float64 cannot hold a flat map
        of them: remesh more evenly or coarser along the limbs).
    """
    V = validate_vertices(V, "rest vertices", dim=3)
    n = len(V)
    F = as_faces(F, n)
    check_sphere(F, n)
    if pole is not None and not (isinstance(pole, (int, np.integer)) and not isinstance(pole, bool)
                                 and 0 <= pole < n):
        raise ParameterError(f"pole must be a vertex index in [0, {n}) (0-based), got {pole!r}")
    poles = [int(pole)] if pole is not None else candidate_poles(F, n)
    for p in poles:
        found = _start_at(V, F, n, p, weights)
        if found is not None:
            return found
    tried = f"pole {poles[0]}" if len(poles) == 1 else f"poles {', '.join(map(str, poles))}"
    raise MeshError(f"no certified start map onto the sphere from {tried} (every round of the start and "
                    f"{MAX_HALVINGS} halvings of the stereographic scale left triangles degenerate in float64: "
                    f"limbs too long and thin for a flat map, or badly shaped triangles); "
                    f"{'try another pole, ' if pole is not None else ''}remesh more evenly, or coarser along "
                    f"long limbs")


def candidate_poles(F, n, count=None) -> list[int]:
    """Up to ``count`` (default :data:`POLE_TRIES`) distinct poles for :func:`sphere_start`: a vertex
    of highest degree; the middle of a longest shortest path in edge hops (double sweep: on a
    body, the torso, whence no limb crowds more than its own length makes it); then each vertex
    farthest in hops from those before (farthest-point sampling: the limbs' ends)."""
    from scipy.sparse.csgraph import dijkstra

    count = POLE_TRIES if count is None else count
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    graph = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()

    def hops(v):
        return dijkstra(graph, directed=False, indices=v, unweighted=True)

    first = int(np.argmax(np.bincount(F.ravel(), minlength=n)))
    a = int(np.argmax(hops(first)))
    to_a = hops(a)
    b = int(np.argmax(to_a))
    to_b = hops(b)
    on_path = np.flatnonzero(to_a + to_b == to_a[b])  # the vertices of shortest a-b paths
    centre = int(on_path[np.argmin(np.abs(to_a[on_path] - to_b[on_path]))])
    poles = [first] + ([centre] if centre != first else [])
    nearest = np.minimum(hops(first), hops(centre))
    while len(poles) < min(count, n):
        far = int(np.argmax(nearest))
        if nearest[far] == 0:
            break
        poles.append(far)
        nearest = np.minimum(nearest, hops(far))
    return poles[:count]


def _start_at(V, F, n, pole, weights):
    """``(x, details)`` of :func:`sphere_start` with the south pole at ``pole``, or None when no
    round and no halving of the scale certifies."""
    rest, keep, loop = _disk_without(F, n, pole)
    A = triangle_areas(V[F])
    share = min(max(float(np.sum(A[np.any(F == pole, axis=1)])) / float(np.sum(A)), 1e-12), 0.5)
    W = tutte_weights(V[keep], rest, weights)
    circle = circle_boundary(V[keep], loop)
    rounds = _balanced_rounds(V, F, keep, rest, loop, W, circle, share, pole)
    for estimate, r, P, s in sorted(rounds, key=lambda c: c[0])[:3]:  # the best few, at their own scale
        x = _on_sphere(P, s, keep, pole, n)
        cert = certify_sphere(x, F)
        if cert.ok:
            return x, SphereDetails(x, int(pole), s, 0, cert, r)
    P, s = rounds[0][2], rounds[0][3]  # the plain Tutte map, the scale halved until it certifies
    for halvings in range(MAX_HALVINGS + 1):
        x = _on_sphere(P, s, keep, pole, n)
        cert = certify_sphere(x, F)
        if cert.ok:
            return x, SphereDetails(x, int(pole), s, halvings, cert, 0)
        s *= 0.5
    return None


def _on_sphere(P, s, keep, pole, n):
    """(n, 3) the disk map ``P`` (of the vertices ``keep``) wrapped onto the sphere at scale ``s``,
    ``pole`` at the south pole."""
    x = np.zeros((n, 3))
    x[keep] = stereographic(P, s)
    x[pole] = (0.0, 0.0, -1.0)
    return x


def _stereo_scale(P, rest, share):
    """The stereographic scale of the disk map ``P``: the cap outside the unit circle gets the
    pole star's ``share`` of the area when every triangle's circumcircle allows (module notes)."""
    return min(math.sqrt((1.0 - share) / share), 0.9 / math.sqrt(max(_cap_bound(P, rest), 1e-300)))


def _balanced_rounds(V, F, keep, rest, loop, W, circle, share, pole):
    """``[(estimate, round, P, s)]``: the Tutte map of the disk (round 0) and the three best maps
    of up to :data:`BALANCE_ROUNDS` rounds of stretch-minimising reweighting (Yoshizawa, Belyaev &
    Seidel 2004): each vertex's incoming weights divided by ``sigma ** BALANCE_POWER``, ``sigma``
    its area-weighted RMS length stretch of the sphere map against the rest triangles scaled to
    ``4 pi``, kept within :data:`BALANCE_SPREAD` of its median.  Positive weights keep every round
    flip-free in the plane (Floater 2003), and each spreads what a harmonic map crowds
    exponentially (a long limb's far end).

    ``estimate`` is ``(flat, mean)``: the planar triangles not positive in floating point
    (:func:`_flat_in_plane`), then the area-weighted mean symmetric Dirichlet of the chord
    triangles (inf where it is not finite), compared in that order.  The rounds stop after
    :data:`BALANCE_ROUNDS` (:data:`BALANCE_ROUNDS_CROWDED` while every round leaves a flat
    triangle or estimates above :data:`CROWDED_ESTIMATE`), when :data:`BALANCE_PATIENCE` of them do not lower the estimate, when a stretch is
    not finite or when the reweighted system is singular.  The weights are divided by their
    largest after each round (the embedding does not change; a start collapsed near a point
    multiplied every weight by ~1e-75 a round, which underflowed to 0 in round 5).  A harmonic
    map crowds a long limb beyond float64 (its far end's triangles collinear or flipped in the
    plane, their stretch 1e150 and more): the bounded update spreads it over rounds instead of
    tearing the system apart in one."""
    n = len(V)
    P = weighted_embedding(W, loop, circle)
    A = triangle_areas(V[F])
    target = A * (4.0 * math.pi / A.sum())
    rest_tri = V[F] * math.sqrt(4.0 * math.pi / A.sum())
    rounds, history = [], []
    for r in range(BALANCE_ROUNDS_CROWDED + 1):
        s = _stereo_scale(P, rest, share)
        x = _on_sphere(P, s, keep, pole, n)
        sd = triangle_symmetric_dirichlet(rest_tri, x[F])
        estimate = float(np.sum(target * sd) / np.sum(target))
        history.append((_flat_in_plane(P, rest), estimate if np.isfinite(estimate) else math.inf))
        # round 0 and the three best others: a map per round kept would be 31 at 10^6 vertices
        rounds = rounds[:1] + sorted(rounds[1:] + [(history[-1], r, P, s)], key=lambda c: c[0])[:3]
        # stop when the last rounds found nothing lower (none finite counts as none lower)
        flat, best = min(history)  # more rounds while every one is flat or still far from balanced
        last = BALANCE_ROUNDS if flat == 0 and best <= CROWDED_ESTIMATE else BALANCE_ROUNDS_CROWDED
        if r >= last or (r >= BALANCE_PATIENCE and
                                   not min(history[-BALANCE_PATIENCE:]) < min(history[:-BALANCE_PATIENCE])):
            break
        chord = triangle_areas(x[F])
        stretch2 = target / np.maximum(chord, 1e-300 * target)  # squared length stretch per triangle
        per_vertex = np.bincount(F.ravel(), np.repeat(target * stretch2, 3), minlength=n)
        sigma = np.sqrt(per_vertex / np.bincount(F.ravel(), np.repeat(target, 3), minlength=n))[keep]
        if not (np.isfinite(sigma).all() and sigma.min() > 0):
            break
        middle = float(np.median(sigma))  # a round moves no weight by more than BALANCE_SPREAD ** BALANCE_POWER
        sigma = np.clip(sigma, middle / BALANCE_SPREAD, middle * BALANCE_SPREAD)
        W = W @ sp.diags(sigma ** -BALANCE_POWER)
        W = W / W.max()  # the same embedding; weights that shrink every round would underflow to 0
        try:
            P = weighted_embedding(W, loop, circle)
        except MeshError:  # rounding made the reweighted system singular: keep the rounds so far
            break
    return rounds


def _flat_in_plane(P, rest) -> int:
    """How many planar triangles ``P[rest]`` (P (k, 2)) are not counter-clockwise in floating
    point: crowded beyond float64 (a flip-free Tutte map has none in exact arithmetic)."""
    a, b, c = (P[rest[:, k]] for k in range(3))
    d = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return int(np.count_nonzero(~(d > 0)))


def given_start(problem, x0):
    """``(x, details)`` for a start map ``x0`` (n, 3) of :func:`sphere_map`'s ``problem``: its
    directions, once the mesh is checked (:func:`geomopt.exact.topology.check_sphere`) and ``x0``
    certified a bijection onto the sphere; MeshError otherwise."""
    check_sphere(problem.input_simplices, problem.n_vertices)
    x = problem.check_map(x0, "start map x0")
    with np.errstate(all="ignore"):
        x = x / np.linalg.norm(x, axis=1, keepdims=True)
    cert = certify_sphere(x, problem.input_simplices)
    if not cert.ok:
        raise MeshError(f"the start map x0 is not a bijection onto the sphere ({cert.message}); omit x0 for the "
                        f"certified stereographic start")
    return x, SphereDetails(x, -1, math.nan, 0, cert)


def default_solver() -> LBFGS:
    """:func:`sphere_map`'s L-BFGS: no gradient test (``gtol=0``: the Tutte start's gradient is
    some 1e14, so a test relative to it stops at energies far from the minimum; measured on cow),
    converged when 20 iterations lower the energy by less than 2e-5 relative, up to 3,000."""
    return LBFGS(gtol=0.0, rtol=1e-6, window=20, max_steps=3000)


def _radial_guard(solver, old, new):
    """End the phase (None) when the map's vertex lengths spread by more than
    :data:`RESPHERE_SPREAD`: the energy sees directions only, so its gradient is tangent and every
    step lengthens the vertices it moves; a vertex grown k-fold has a k times smaller gradient and
    moves k times slower in angle (and at 10^6 the solve would read as diverged)."""
    r = np.linalg.norm(np.asarray(new.x), axis=1)
    return new if r.max() <= RESPHERE_SPREAD * r.min() else None


class ResphereRecord(NamedTuple):
    """A phase of :func:`sphere_map` ended by :func:`_radial_guard`: its iterations and the
    spread of the map's vertex lengths that ended it (the next phase starts from the map put
    back on the sphere, its iterations counted from 1 again)."""

    iterations: int
    spread: float

    def line(self, k: int) -> str:
        return (f"phase {k:3d}  {self.iterations:4d} iterations, vertex lengths spread {self.spread:.3g}x: "
                f"back on the sphere")


class _OnTheSphere(AbstractContinuation):
    """The phases of :func:`sphere_map`: after :func:`_radial_guard` ends one, L-BFGS starts
    afresh from the map put back on the sphere (at most :data:`MAX_RESPHERES` times); at the end,
    the map projected onto the sphere and certified (:func:`geomopt.exact.certify.certify_sphere`),
    CONVERGED demoted to NOT_INJECTIVE when the certificate fails."""

    def __init__(self, objective, details, start):
        self.objective, self.details, self.x0 = objective, details, start
        self.respheres = 0

    def __call__(self, state, outcome):
        if outcome is None and self.respheres < MAX_RESPHERES:
            self.respheres += 1
            x = self.objective.unpad_map(np.asarray(state.x))
            r = np.linalg.norm(x, axis=1)
            record = ResphereRecord(state.iteration, float(r.max() / r.min()))
            x = np.asarray(state.x)
            return Decision.go(objective=self.objective, x=x / np.linalg.norm(x, axis=1, keepdims=True),
                               record=record)
        return Decision.stop_with(outcome if outcome is not None else Outcome.LINE_SEARCH_FAILED,
                                  "" if outcome is not None else "the map kept leaving the sphere")

    def finish(self, state, outcome, reason):
        x = self.objective.unpad_map(np.asarray(state.x))
        if not np.isfinite(x).all():
            outcome, x = Outcome.NONFINITE, self.x0
        t0 = time.perf_counter()
        x = x / np.linalg.norm(x, axis=1, keepdims=True)
        cert = certify_sphere(x, self.objective.problem.simplices)
        if outcome is Outcome.CONVERGED and not cert.ok:
            outcome, reason = Outcome.NOT_INJECTIVE, cert.message
        return Final(x, outcome, cert, reason, details=self.details, certify_seconds=time.perf_counter() - t0)


@dataclasses.dataclass(frozen=True)
class SphereOptions:
    """The settings of :func:`sphere_map` (validated).

    Attributes
    ----------
    weights : Tutte weights of the start, ``"uniform"`` or ``"mean_value"`` (:func:`sphere_start`).
    pole : the start's south-pole vertex (default: one of highest degree).
    buckets : pad to size buckets (shared compiled kernels), as :class:`geomopt.param.ParamOptions`.
    """

    weights: str = "uniform"
    pole: int | None = None
    buckets: bool = True

    def __post_init__(self):
        validate(self, weights=OneOf(TUTTE_WEIGHTS), pole=Maybe(Int(0)), buckets=Instance(bool))


@float64
def sphere_map(V, F=None, energy="symmetric_dirichlet", solver=None, *, options: SphereOptions | None = None,
               x0=None, progress=True, throw=False):
    """Map a closed genus-0 triangle mesh bijectively onto the unit sphere, minimising distortion.

    Parameters
    ----------
    V : (n, 3) float rest vertex positions, or a mesh object with ``.vertices`` and ``.faces``
        when ``F`` is None.
    F : (m, 3) int triangles, consistently oriented (the map keeps their orientation: outward
        normals map to triangles counter-clockwise seen from outside the sphere).
    energy : name or :class:`~geomopt.energies.Energy` (default symmetric Dirichlet), or a pair
        ``(name, {parameter: value})`` (:func:`geomopt.energies.energy_spec`): a density of 2x2
        Jacobians evaluated on the chord triangles against the rest triangles scaled to total
        area ``4 pi`` (:meth:`geomopt.Problem.sphere`).
    solver : ``None`` (:func:`default_solver`), ``"lbfgs"`` or an :class:`~geomopt.LBFGS` (the
        sphere map's Jacobians are not linear in ``x``, so no assembled-Hessian solver applies).
    options : :class:`SphereOptions` (the start's Tutte weights and pole, size buckets).
    x0 : None (the certified stereographic start, :func:`sphere_start`) or an (n, 3) start map
        (directions: e.g. another method's sphere map), which must itself certify
        (:func:`geomopt.exact.certify.certify_sphere`).
    progress, throw : see :func:`~geomopt.solvers.minimize`.

    Returns
    -------
    :class:`~geomopt.solvers.Result` whose ``x`` (n, 3) are unit vectors (same vertex order;
    the faces are ``F``), ``certificate`` a :class:`~geomopt.exact.certify.SphereCertificate` (exact:
    ``success`` only when converged with every triangle positive about the centre and the sphere
    covered once; ``injectivity`` is then ``"global"``), ``details`` a :class:`SphereDetails`.

    Raises
    ------
    MeshError : not a closed, edge-manifold, connected genus-0 mesh (boundary, other genus,
        non-manifold edges or vertices, zero-area faces...), one line.
    ParameterError : unknown energy or parameter, a solver other than L-BFGS, or an energy that
        lets the map collapse (e.g. Dirichlet).
    SolveError : only with ``throw=True``, when the result is not converged and certified.

    Examples
    --------
    An octahedron onto the unit sphere:

    >>> import numpy as np
    >>> import geomopt
    >>> V = [[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1]]
    >>> F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [5, 2, 1], [5, 3, 2], [5, 4, 3], [5, 1, 4]]
    >>> result = geomopt.sphere_map(V, F, progress=False)
    >>> result.success, result.injectivity, bool(np.allclose(np.linalg.norm(result.x, axis=1), 1.0))
    (True, 'global', True)
    """
    options = options_or_default(SphereOptions, options, "sphere_map")
    energy, energy_params = energy_spec(energy, where="sphere_map")
    refuse_traced("geomopt.sphere_map", "it certifies concrete maps", V, energy_params)
    V, F = mesh_arrays(V, F)
    check_progress(progress, "sphere_map")
    get_energy(energy).check_scale_aware(energy_params)
    solver = default_solver() if solver is None else get_solver(solver)
    if not isinstance(solver, LBFGS):
        raise ParameterError(f"sphere_map minimises with L-BFGS (value and gradient only: the map onto the sphere "
                             f"is not linear in x, so {type(solver).__name__}'s assembled Hessian does not apply); "
                             f"pass solver='lbfgs' or an LBFGS(...)")
    problem = Problem.sphere(V, F)  # rest checks first: zero-area faces, orientation, non-manifold edges
    x0, details = (sphere_start(V, problem.input_simplices, options.pole, options.weights) if x0 is None else
                   given_start(problem, x0))
    objective = Objective(problem, energy, buckets=options.buckets, **energy_params)
    return iterate(solver, objective, objective.prepare_map(x0), objective.params(),
                   continuation=_OnTheSphere(objective, details, x0), guard=_radial_guard, progress=progress, trace=True,
                   throw=throw, label="sphere_map")

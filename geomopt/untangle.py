"""Untangling: Garanzha et al.'s regularised energy with an eps-driving outer loop.

V. Garanzha, I. Kaporin, L. Kudryavtseva, F. Protais, N. Ray, D. Sokolov, "Foldover-free maps
in 50 lines of code", ACM Trans. Graph. 40(4), 2021.

Given a (possibly tangled) map with fixed handles, minimise

    E_eps(x) = sum_e vol_e * ( |J|^2 / chi(det J, eps)^(2/d) + lam (det J^2 + 1) / chi(det J, eps) )

(``geomopt.energies.garanzha``; the paper's code normalises it as ``(1-theta) f + theta g``,
the same up to the factor ``1 - theta``) at fixed ``eps`` with an inner solver, then shrink
``eps`` from the worst determinant ``D-``: with ``sigma = max(1 - E/E_prev, min_sigma)``
(at most ``max_sigma`` while ``D- <= 0``) and ``mu = (1 - sigma) chi(D-, eps)``,
``eps = 2 sqrt(mu (mu - D-))`` when ``D- < mu`` (so that ``chi(D-, eps_new) = mu``), else a
tiny floor (:func:`next_eps`).  Stop when every element
is positively oriented and the energy changed by less than ``1e-5`` (relative) during the last
inner solve.  ``theta`` weighs shape against area, ``lam = theta / (1 - theta)``: 1/128 in 2D
and 1/2 in 3D as in the paper's code, whose initial ``eps`` is 1.

Departures from the paper's code, each measured on the LIM sample and on generated tangles
(see ``benchmarks/untangle.py`` and the issue notes):

* ``sigma`` is at least 0.5 instead of 0.1 (the paper's 0.1 takes 5x more outer iterations,
  64 vs 12 on WeberZorin14_fig19), and at most 0.5 while some element is inverted: without
  that cap a first inner solve that lowers the energy a lot sends ``eps`` to ~0 while
  elements are still folded, after which the loop stalls (``random_interior`` on
  ``disk_mesh(60)``, seed 0, never untangles).  Once nothing is inverted the paper's rule
  applies uncapped (:func:`next_eps`): eps then usually drops to the floor in one step
  (the twisted cube of 48k tets: 3 outer iterations instead of 5);
* the initial eps is a tenth of the median ``|det J|`` of the normalised start when the median
  exceeds 10, else 1 (:func:`start_eps`): the normalisation below makes the mean determinant 1,
  but a start whose interior vertices are scattered over the domain has determinants of both
  signs that cancel in the mean while each is huge (``random_interior`` on an ``n x n`` grid:
  median ``|det J|`` about ``0.1 n^2``). At ``eps = 1`` such a start is in the barrier-like
  regime ``|det J| >> eps`` everywhere and the first inner solve's iteration count grows with the
  mesh (quads 100^2 / 150^2 / 200^2: 1,368 / 6,416 / 13,846 Laplacian-seeded iterations;
  triangles 2 x 224^2: 17,953) until, on 316^2 quads, it stalls with half the corners inverted
  and the loop never untangles; from that eps the first solve's stiffness no longer grows with
  the mesh (quads 150^2: 6,535 -> 62 inner iterations in all; 316^2: 2 outer, 142 inner
  iterations). Starts that are tangled only locally have a median below 10 and keep the paper's
  ``eps0 = 1`` (a larger one costs them outer iterations: a squashed quad boundary 368 inner
  iterations at 1, 449 at its median 1.8);
* the inner L-BFGS uses the M1QN3 diagonal seed, a loose tolerance (``1e-6``) and keeps its
  curvature pairs across outer iterations (2-5x fewer energy evaluations in total);
* the density is evaluated without ``pow`` (not vectorised by XLA on CPU).

Before solving, the map is scaled by a power of two to a box of size ~10 (exact, so scaling
back is exact too) and the rest mesh so that its volume equals the map's: the mean
determinant is then 1 and ``eps0`` is meaningful whatever the input units.  In 2D, rest
triangles with an aspect ratio above 10 are replaced by equilateral ones, as the paper's code
does.  Elements whose vertices are all fixed are left out of the inner energy (but not of
``D-`` and the stopping test), and so are the connected parts without a handle, held at a
certified map (:mod:`geomopt.starts`: at the first eps their energy is lowest collapsed to a point).  The handles are written back from ``problem.fixed_positions``
at the end (bit-exact), and the result is certified with the exact orientation predicate
(:mod:`geomopt.exact.predicates`) and around every vertex and edge (:func:`geomopt.exact.certify.local_certificate`):
a map with every element positive can still wind twice around an interior vertex (2D) or edge
(3D), or overlap itself around a boundary vertex or edge; such a map is ``NOT_INJECTIVE``
(the failures listed in ``certificate``: ``branch_vertices``, ``branch_edges``,
``boundary_overlaps``...).

The outer loop is a continuation of the one loop (:class:`EpsContinuation`, handed to
:func:`geomopt.solvers.iterate`): after each inner solve it measures the worst determinant,
decides to stop or picks the next eps, and asks for the solver's memory to be dropped when an
outer iteration increased the number of inverted elements.  With the default L-BFGS, an inner
solve that has not converged after :data:`STIFF_AFTER` iterations continues with the Laplacian
seed, or with Newton on the corners of hexahedra (:func:`stiff_solver`), for the rest of the solve.

``eps`` and ``lam`` are traced parameters of the jitted kernels: the whole outer loop compiles
once per mesh shape.
"""

from __future__ import annotations

import dataclasses
import math
import time
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._runtime.config import Instance, Int, Maybe, OneOf, Real, validate
from ._runtime.errors import MeshError, ParameterError, SolveError
from ._runtime.tracing import refuse_traced
from ._runtime.x64 import float64
from ._runtime.programs import jit as programs_jit
from .mesh.geometry import det, edge_rows
from .objective.objective import Objective, jacobians, total_energy
from .energies import garanzha
from .solvers.linesearch import InjectiveSearch
from .exact.predicates import box_scale, differing_rows
from .mesh.problem import Problem, fixed_total_problem
from .starts import BOX, STARTS, choose_start, harmonic_start, hold_free_parts
from .solvers import (LBFGS, AbstractContinuation, AbstractSolver, Decision, Final, LocalCertificate, Newton,
                      Outcome, Progress, Result, RunStats, UntangleDetails, iterate, local_certificate)
from .solvers._iterate import check_progress

__all__ = ["UntangleResult", "UntangleOptions", "UntangleRecord", "EpsContinuation", "untangle", "default_solver",
           "stiff_solver", "next_eps", "start_eps", "START_RATIO", "STIFF_AFTER",
           "STIFF_AFTER_NEWTON", "PROBE_PROGRESS", "STARTS", "harmonic_start", "choose_start"]

EPS_FLOOR = {2: 1e-9, 3: 1e-10}


#: the largest median ``|det J| / eps`` of the start's elements at the first eps (:func:`start_eps`)
START_RATIO = 10.0

LAPLACIAN_FROM = 50_000  # active elements from which the default L-BFGS uses the Laplacian seed

#: the share of inverted elements at the start from which a tangle counts as local (noise,
#: scattered vertices) and keeps the diagonal seed at any size (see :func:`default_solver`)
LOCAL_TANGLE_SHARE = 0.25

#: inner iterations after which the default L-BFGS continues with the Laplacian seed
STIFF_AFTER = 100

#: a probe of :data:`STIFF_AFTER` iterations that leaves fewer than these fractions of the
#: inverted elements and of the energy it started with is followed by another probe instead of
#: the switch (see :class:`EpsContinuation`)
PROBE_PROGRESS = (0.9, 0.5)

#: inner iterations after which the default L-BFGS on hexahedra's corners continues with Newton:
#: a Newton iteration costs about a hundred L-BFGS ones there (hex22-rot180, 85k corners: 13
#: Newton iterations took 13 s, compilation included, against 1.8 s for its 182 L-BFGS ones), so the probe is ten
#: Newton iterations' worth
STIFF_AFTER_NEWTON = 1000

#: what :func:`untangle` returns (one result type for every solve; kept as a name)
UntangleResult = Result


def stiff_solver(name: str, dim: int, corners: bool = False) -> AbstractSolver | None:
    """The solver an inner solve of :func:`default_solver` continues with when it has not
    converged after :data:`STIFF_AFTER` iterations (None: no switch).

    ``"lbfgs"``: the Laplacian seed (Sobolev-preconditioned L-BFGS).  An inner solve that
    needs more than a hundred iterations with the diagonal seed is a stiff, global one (the
    first outer iteration of a large rotation): there the Laplacian seed's iteration count
    does not grow with the mesh (disk 12.7k triangles rotated 180 degrees: 1,474 -> 50 inner
    iterations, 2.2 -> 0.2 s; an irregular Delaunay disk 6,855 -> 1,259), while on local
    tangles (noise) the diagonal seed converges within the probe at a third of the cost per
    iteration and is kept.

    ``corners`` in 3D (the corner tetrahedra of hexahedra): Newton (:func:`default_solver`
    ``"newton"``).  No L-BFGS seed solves a stiff corner problem: on the hex rod of 9 x 9 x 108
    bent by 180 degrees (69,984 corners; the tet rod of the same grid untangles in 1,565
    Laplacian-seeded iterations) the first eps solve stalls with the Laplacian seed after 8,437
    iterations at a mean energy of 567 with 26,627 corners inverted (6,304 at the start), with the
    diagonal seed after 15,736 at 72 with 1,137; each later eps then stalls too and the loop never
    untangles.  Newton reaches that eps's minimum (mean energy 4.31, every corner positive) in 73
    iterations.  The switch comes after :data:`STIFF_AFTER_NEWTON` L-BFGS iterations."""
    if str(name).strip().lower() != "lbfgs":
        return None
    if corners and dim == 3:
        return default_solver("newton", dim)
    return dataclasses.replace(default_solver("lbfgs", dim, LAPLACIAN_FROM, corners), precondition="laplacian")


def default_solver(name: str, dim: int, n_elements: int = 0, corners: bool = False,
                   inverted: int = 0) -> AbstractSolver:
    """The inner solver :func:`untangle` uses for ``"lbfgs"`` or ``"newton"``.

    ``"lbfgs"``: M1QN3 diagonal seed below ``LAPLACIAN_FROM`` elements, the Laplacian seed
    (:class:`~geomopt.solvers.LBFGS` ``precondition="laplacian"``) from there on.  Measured
    (warm seconds, diagonal -> Laplacian): ~1e5 elements: rotated square 104 -> 58, Tutte
    L / star 27 -> 11 / 19 -> 11, bent rod 43 -> 13, twisted cube 12.6 -> 6.1, noisy disk
    1.3 -> 3.0; the LIM armadillo (24k tets) 0.66 -> 1.04 and 2D cases of ~1e4 triangles
    were slower or even with it (its host solves cost more than the iterations they save).

    A start with at least :data:`LOCAL_TANGLE_SHARE` of its ``n_elements`` ``inverted`` is a
    local tangle and keeps the diagonal seed at any size (simplices only; the stiff switch's
    probe still hands a stalling solve to the Laplacian seed).  Global tangles invert a thin
    band: rotations, bends and Tutte stars 0.7-10% of their elements, noise of two edge
    lengths and scattered interiors 47-50%.  Measured at 6e4-1.4e5 elements (2-core box under
    load, same run; inner iterations and seconds, Laplacian -> diagonal): structured disk
    noise 83 / 1.32 -> 93 / 0.66, scattered disk 155 / 3.23 -> 142 / 1.69, Delaunay ball
    noise 562 / 5.65 -> 387 / 3.55, cube noise 108 / 1.14 -> 99 / 1.13, Delaunay disk noise
    925 / 13.3-13.8 -> 1,244 / 13.7-18.2 (even); a disk rotated by 180 degrees needs 739-874
    iterations instead of 296 once ten or more diagonal steps came first.

    ``corners``: the problem's simplices are the corner tetrahedra of hexahedra, which need more
    L-BFGS steps per eps than tets: 30000 as in 2D (a hex rod of 6 x 6 x 72 bent by 180 degrees
    took 9942 in its first outer iteration; capped at 3000 it stalled with 67 hexahedra inverted)."""
    key = str(name).strip().lower()
    local = not corners and inverted >= LOCAL_TANGLE_SHARE * n_elements > 0
    if key == "lbfgs":
        return LBFGS(history=10, rtol=1e-6, gtol=1e-6, max_steps=30000 if dim == 2 or corners else 3000,
                     search=InjectiveSearch(injective=False, c2=0.9),
                     precondition="laplacian" if n_elements >= LAPLACIAN_FROM and not local else "diagonal")
    if key == "newton":
        return Newton(projection="clamp", rtol=1e-7, max_steps=100,
                      search=InjectiveSearch(injective=False))
    raise ParameterError(f"unknown untangling solver {name!r}; valid: 'lbfgs', 'newton' or a solver object")


@dataclasses.dataclass(frozen=True)
class UntangleOptions:
    """The settings of :func:`untangle` (validated: a wrong type or range is a one-line
    :class:`~geomopt.ParameterError`).

    Attributes
    ----------
    theta : shape/area balance in ``(0, 1)``; ``lam = theta / (1 - theta)``.  None: 1/128 in
        2D, 1/2 in 3D.
    max_outer : outer (eps) iteration limit.
    energy_tol : stop once untangled and ``|E_prev - E| / E`` of an inner solve is below this.
    eps0 : initial eps (the map is normalised so the mean det J is 1).  None: the median
        ``|det J|`` of the start's active elements over :data:`START_RATIO`, at least 1
        (:func:`start_eps`).
    max_aspect : 2D only: rest triangles with an aspect ratio above this are replaced by
        equilateral ones (Garanzha et al.'s code uses 10); None keeps the rest mesh.
    keep_memory : keep the L-BFGS curvature pairs across outer iterations, except after one
        that increased the number of inverted elements (measured on square_rot180: it stalled
        with 64 folds under half of 14 exact rotations of its rest mesh when the pairs were
        always kept, and untangled under all 14 with this reset, at the same cost elsewhere).
    injective_when_untangled : once every element is positive, switch the inner line search
        to the injective one (no element can flip back; compiles a second kernel).
    min_sigma, max_sigma : bounds of ``sigma = 1 - E/E_prev``, the fraction by which each outer
        iteration shrinks ``chi(D-, eps)`` (:func:`next_eps`).  The paper uses ``0.1`` and no
        cap; the default halves it every outer iteration while elements are inverted and
        applies no cap once none is (see the module notes).
    bucket : pad the problem to its size bucket (``Objective(buckets=True)``,
        :mod:`geomopt._runtime.padding`), so that meshes of similar sizes share compiled kernels; same
        certificate, same map up to the rounding of sums over elements.
    start : where the eps loop starts (:data:`STARTS`): ``"given"`` ``x0``; ``"harmonic"`` ``x0``
        with its free vertices replaced by the harmonic extension of the handles
        (:func:`harmonic_start`); ``"auto"`` (default) the harmonic extension for quads and
        hexahedra when it has fewer inverted corners than ``x0``, else ``x0`` (see
        :func:`choose_start`), decided per connected part.  Whatever ``start``, a connected
        part without a handle is held at a certified map, not solved
        (:func:`geomopt.starts.hold_free_parts`).
    """

    theta: float | None = None
    max_outer: int = 200
    energy_tol: float = 1e-5
    eps0: float | None = None
    max_aspect: float | None = 10.0
    keep_memory: bool = True
    injective_when_untangled: bool = False
    min_sigma: float = 0.5
    max_sigma: float = 0.5
    bucket: bool = False
    start: str = "auto"

    def __post_init__(self):
        validate(self, theta=Maybe(Real(0.0, 1.0, lo_open=True, hi_open=True)), max_outer=Int(1),
                 energy_tol=Real(0.0, 1.0, lo_open=True, hi_open=True), eps0=Maybe(Real(0.0, lo_open=True)),
                 max_aspect=Maybe(Real(1.0)), keep_memory=Instance(bool),
                 injective_when_untangled=Instance(bool), min_sigma=Real(0.0, 1.0, lo_open=True, hi_open=True),
                 max_sigma=Real(0.0, 1.0, lo_open=True, hi_open=True), bucket=Instance(bool),
                 start=OneOf(STARTS))
        if not self.min_sigma <= self.max_sigma:
            raise ParameterError(f"UntangleOptions: need min_sigma <= max_sigma, got {self.min_sigma} and "
                                 f"{self.max_sigma}")

    def resolved_theta(self, dim: int) -> float:
        return self.theta if self.theta is not None else (1.0 / 128.0 if dim == 2 else 0.5)


def options_from(cls, options, overrides, where):
    """``options`` (an instance of ``cls`` or None) with ``overrides`` (field names) applied;
    ParameterError naming the unknown keywords."""
    if options is not None and not isinstance(options, cls):
        raise ParameterError(f"{where}: options must be a {cls.__name__} or None, got {type(options).__name__}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ParameterError(f"{where}: unknown keyword argument(s) {unknown}; the options are {sorted(known)}")
    return dataclasses.replace(options or cls(), **overrides)


class UntangleRecord(NamedTuple):
    """One outer iteration of :func:`untangle` (``trace.phases``): the eps used, the energy
    (total, and over the rest volume) of the whole problem after the inner solve, its worst
    ``det J`` and float-inverted count, and the inner iterations."""

    eps: float
    energy: float
    mean_energy: float
    min_det: float
    inverted: int
    inner: int

    def line(self, k: int) -> str:
        return (f"outer {k:3d}  eps {self.eps:9.3e}  mean energy {self.mean_energy:.8g}  min det {self.min_det:+.3e}  "
                f"inverted {self.inverted:6d}  inner {self.inner:5d}")


# --------------------------------------------------------------------- kernels


@partial(programs_jit, static_argnums=0)
def _outer_stats(density, geom, x, params):
    """(energy over all elements, min det J, #elements with det J <= 0), over the elements of
    positive rest volume (``bucket`` padding adds elements of zero volume)."""
    D = det(jacobians(geom, x))
    real = geom[2] > 0
    return total_energy(density, geom, x, params), jnp.min(jnp.where(real, D, jnp.inf)), jnp.sum(real & (D <= 0))


# --------------------------------------------------------------------- helpers


def _aspect_ratio(P):
    """(m,) aspect ratio ``lmax (l1+l2+l3) / (4 sqrt(3) area)`` of triangles P (m, 3, k); 1 = equilateral."""
    l = np.linalg.norm(P[:, [1, 2, 0]] - P, axis=2)
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    if P.shape[2] == 2:
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    else:
        area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return l.max(1) * l.sum(1) / (4.0 * np.sqrt(3.0) * area)


def badly_shaped(problem: Problem, max_aspect: float | None) -> np.ndarray:
    """(m,) bool: the rest triangles whose aspect ratio is above ``max_aspect``, which
    untangling replaces by equilateral ones (:func:`equilateral_rest`); none in 3D, for
    quads or with ``max_aspect`` None."""
    if max_aspect is None or problem.dim != 2 or problem.elements is not None:
        return np.zeros(problem.n_elements, bool)
    return _aspect_ratio(np.asarray(problem.rest_vertices)[problem.simplices]) > max_aspect


def equilateral_rest(problem: Problem, bad: np.ndarray):
    """``(rest_inv, volumes)`` of ``problem`` with the ``bad`` rest triangles replaced by
    equilateral ones of their mean edge length (as Garanzha et al.'s 2D code does).  NumPy for
    NumPy arrays, else JAX: traceable in the problem's arrays (:func:`geomopt.implicit.untangle`)."""
    arrays = (problem.rest_vertices, problem.rest_inv, problem.volumes)
    xp = np if all(isinstance(a, np.ndarray) for a in arrays) else jnp
    E = problem.rest_vertices[problem.simplices]
    a = xp.mean(xp.linalg.norm(E[:, [1, 2, 0]] - E, axis=2), axis=1)
    Dm = a[:, None, None] * xp.array([[[1.0, 0.5], [0.0, 0.5 * np.sqrt(3.0)]]])
    safe = xp.where(bad[:, None, None], Dm, xp.eye(2)[None])  # no inverse of a degenerate kept triangle
    rest_inv = xp.where(bad[:, None, None], xp.linalg.inv(safe), problem.rest_inv)
    return rest_inv, xp.where(bad, np.sqrt(3.0) / 4.0 * a * a, problem.volumes)


def _equilateral_rest(problem: Problem, max_aspect: float) -> Problem:
    """``problem`` with :func:`equilateral_rest` applied to its :func:`badly_shaped` triangles."""
    bad = badly_shaped(problem, max_aspect)
    if not bad.any():
        return problem
    rest_inv, vol = equilateral_rest(problem, bad)
    return dataclasses.replace(problem, rest_inv=rest_inv, volumes=vol)


def _chi_scalar(D: float, eps: float) -> float:
    """``geomopt.energies.chi`` for Python floats (cancellation-free for ``D <= 0``)."""
    r = math.sqrt(eps * eps + D * D)
    return 0.5 * (D + r) if D > 0 else eps * eps / (2.0 * (r - D))


def next_eps(eps: float, E: float, E_prev: float, detmin: float, min_sigma: float = 0.5,
             max_sigma: float = 0.5, floor: float = 1e-10) -> float:
    """The eps of the next outer iteration (Garanzha et al. 2021, section 4).

    ``sigma = max(1 - E/E_prev, min_sigma)``, capped at ``max_sigma`` while some element is
    inverted (``detmin <= 0``); ``mu = (1 - sigma) chi(detmin, eps)``; the new eps solves
    ``chi(detmin, eps_new) = mu`` when ``detmin < mu``, else it is ``floor``.  Once nothing is
    inverted the paper's rule applies uncapped: an inner solve that lowered the energy a lot
    (``sigma`` near 1) sends eps to the floor in one step, where the cap took several halvings.

    Parameters
    ----------
    eps : the eps of the inner solve just finished;  E, E_prev : the energy after and before it.
    detmin : the smallest det J after it.
    """
    sigma = max(1.0 - E / E_prev, min_sigma)
    if detmin <= 0:
        sigma = min(sigma, max_sigma)
    mu = (1.0 - sigma) * _chi_scalar(detmin, eps)
    return max(floor, 2.0 * math.sqrt(mu * (mu - detmin))) if detmin < mu else floor


def start_eps(problem: Problem, x) -> float:
    """The initial eps of :func:`untangle` when ``eps0`` is None: ``max(1, median |det J| /``
    :data:`START_RATIO` ``)`` over ``problem``'s elements (the active ones of the normalised
    problem) at the normalised start ``x`` (n, d); on the host, once.

    The normalisation makes the mean ``det J`` 1, and the paper's eps = 1 suits starts whose
    typical element has ``|det J|`` within :data:`START_RATIO` of 1 (every locally tangled
    family: rotations and squashed boundaries have a median of 1-2, noise of two edge lengths
    6.4).  When the typical element is far larger (interior vertices scattered over the
    domain: determinants of both signs that cancel in the mean, ``|det J|`` growing with the
    mesh), eps = 1 leaves nearly every element deep in the stiff regime ``|det J| >> eps`` of
    ``chi`` and the first inner solve takes iterations that grow with the mesh, or stalls (see
    the module notes).  This eps keeps the typical element's ``|det J| / eps`` at
    :data:`START_RATIO` whatever the mesh size; the eps schedule shrinks it from there."""
    if not len(problem.simplices):
        return 1.0
    D = det(edge_rows(problem.simplices, np.asarray(x, np.float64))) * det(problem.rest_inv)
    m = float(np.median(np.abs(D)))
    return max(1.0, m / START_RATIO) if math.isfinite(m) else 1.0




# --------------------------------------------------------------------- the outer loop


class EpsContinuation(AbstractContinuation):
    """The eps schedule of :func:`untangle` as a continuation of
    :func:`~geomopt.solvers.iterate`: after each inner solve, measure the energy and worst
    ``det J`` over the whole (normalised) problem; stop when nothing is inverted and the
    energy settled, else shrink eps (:func:`next_eps`) and go on.  ``finish`` maps the last
    iterate back to the input frame, writes the handles back bit for bit and certifies it.

    Parameters
    ----------
    problem : the input :class:`~geomopt.Problem`;  scaled : its normalised copy;  full : the
        objective of ``scaled`` (the outer statistics); objective : the inner one (the active
        elements, padded like ``full``), whose parameters change;  map_scale : the power of two
        the map was scaled by;  xs : the scaled start.
    options : :class:`UntangleOptions`;  details : :class:`UntangleDetails` of the result;
    initially : inverted elements of the start map;  solver : the inner solver (its search is
        made injective once nothing is inverted with ``injective_when_untangled``).
    stiff : the solver a stalled inner solve continues with (:func:`stiff_solver`), or None.

    Notes
    -----
    While ``stiff`` is pending the inner solves run :attr:`phase_solver`, the solver capped at
    :data:`STIFF_AFTER` iterations (the same compiled loop), and a solve that reaches the cap
    continues with ``stiff`` from its map, for the rest of the solve, unless (L-BFGS seeds
    only) the probe made fast progress: it removed inverted elements and energy, fewer than
    :data:`PROBE_PROGRESS` times those at its start are left.  Then the same solver goes on for
    another probe, memory kept.  Local tangles (noise) lose folds and energy fast under the
    diagonal seed, whose iterations cost a third of the Laplacian seed's and take as many;
    global ones (rotations, twists, bends) *gain* folds in their first hundred diagonal
    iterations (disk 12.7k rotated 180 degrees: 270 -> 772, ball 12k rotated: 1,966 -> 3,964,
    twisted cube 48k: 3,905 -> 10,926); a Tutte map onto a star loses folds but its energy
    only slowly (mean 3.24 -> 2.52), and the Laplacian seed smooths it in half the iterations.
    A Delaunay disk of 12k triangles with noise: 5,866 -> 4,035 -> 901 folds and mean energy
    5,358 -> 17.5 -> 3.1 at 100 and 200 iterations: no switch, 0.85 -> 0.63 s.
    """

    def __init__(self, problem, scaled, full, objective, map_scale, xs, options, details, initially, solver,
                 stiff=None, forced=None):
        self.problem, self.scaled, self.full, self.objective, self.solver = problem, scaled, full, objective, solver
        self.forced = forced  # the input's overlaps that the handles alone make (Problem.certify_fixed)
        self.probe = STIFF_AFTER_NEWTON if isinstance(stiff, Newton) else STIFF_AFTER
        self.stiff = stiff if stiff is not None and solver.max_steps > self.probe else None
        self.probed = 0  # inner iterations of this outer iteration before a switch to ``stiff``
        self.window = (initially, math.inf)  # inverted elements and energy at the probe's start
        self.k, self.xs, self.options, self.details, self.initially = map_scale, xs, options, details, initially
        self.eps = float(options.eps0)
        self.floor = EPS_FLOOR.get(problem.dim, 1e-10)
        self.injective = False
        self.inverted = []
        self.E = math.nan

    def _stats(self, x, params):
        return (float(v) for v in _outer_stats(self.objective.energy.density, self.full.geom, x, params))

    @property
    def phase_solver(self):
        """The solver of the next inner solve: capped at :data:`STIFF_AFTER` iterations
        (:data:`STIFF_AFTER_NEWTON` before Newton) while a switch to ``stiff`` is pending."""
        return self.solver if self.stiff is None else dataclasses.replace(self.solver, max_steps=self.probe)

    def _probe_progressed(self, state) -> bool:
        """Whether the probe that just ended removed enough inverted elements and energy to run
        another (:data:`PROBE_PROGRESS`; never before Newton, never past the solver's own step
        limit)."""
        if isinstance(self.stiff, Newton) or self.probed + state.iteration >= self.solver.max_steps:
            return False
        E, _, now = self._stats(state.x, state.params)
        (folds, energy), start = PROBE_PROGRESS, self.window
        progressed = now < folds * start[0] and E < energy * min(start[1], self.E)
        self.window = (int(now), E)
        return progressed

    def start(self, state):
        self.E = next(iter(self._stats(state.x, state.params)))

    def __call__(self, state, outcome) -> Decision:
        if self.stiff is not None and outcome is Outcome.MAX_STEPS and state.iteration >= self.probe:
            if self._probe_progressed(state):  # still untangling locally: another probe, same solver
                self.probed += state.iteration
                return Decision.go(state.params, solver=self.phase_solver)
            # a stiff, global inner solve: the Laplacian seed from here on, same eps, same map
            self.probed, self.solver, self.stiff = self.probed + state.iteration, self.stiff, None
            return Decision.go(state.params, objective=self.objective, x=state.x, solver=self.solver)
        opts, E_prev = self.options, self.E
        E, detmin, nneg = self._stats(state.x, state.params)
        self.E, nneg = E, int(nneg)
        self.inverted.append(nneg)
        record = UntangleRecord(self.eps, E, E / self.full.total_volume, detmin, nneg, self.probed + state.iteration)
        self.probed, self.window = 0, (nneg, math.inf)
        if not (math.isfinite(E) and math.isfinite(detmin)):
            return Decision.stop_with(Outcome.NONFINITE, record=record)
        settled = abs(E_prev - E) / abs(E) < opts.energy_tol
        folded = self.scaled.count_inverted(self.full.unpad_map(np.asarray(state.x))) if detmin > 0 and settled \
            else None
        if folded == 0:
            return Decision.stop_with(Outcome.CONVERGED, record=record)
        if folded and self.problem.elements is not None and self.eps <= self.floor:
            # hexahedra folded inside, every corner positive: the energy sees corners only, more
            # iterations cannot help
            return Decision.stop_with(Outcome.NOT_INJECTIVE, f"every corner is positive but {folded} hexahedra "
                                      f"fold inside (det J <= 0 between their corners, exact Bernstein test)", record)
        if len(self.inverted) >= opts.max_outer:
            return Decision.stop_with(Outcome.MAX_STEPS, f"stopped at the outer-iteration limit (max_outer="
                                      f"{opts.max_outer}) before it settled", record)
        self.eps = next_eps(self.eps, E, E_prev, detmin, opts.min_sigma, opts.max_sigma, self.floor)
        params = self.objective.params(eps=self.eps)
        if opts.injective_when_untangled and not self.injective and detmin > 0:
            self.injective = True  # from now on no element may flip back
            self.solver, self.stiff = (None if s is None else dataclasses.replace(
                s, search=dataclasses.replace(s.search, injective=True)) for s in (self.solver, self.stiff))
        self.E = next(iter(self._stats(state.x, params)))
        # stale curvature pairs can steer the next solve into more folds: drop them then
        worse = len(self.inverted) > 1 and self.inverted[-1] > self.inverted[-2]
        return Decision.go(params, restart=not opts.keep_memory or worse, solver=self.phase_solver, record=record)

    def finish(self, state, outcome, reason) -> Final:
        problem, k = self.problem, self.k
        xs_final = np.asarray(state.x, dtype=np.float64)
        if not np.isfinite(xs_final).all():
            outcome, xs_final = Outcome.NONFINITE, self.xs
        out = xs_final[: problem.n_vertices] / k  # without bucket padding
        out[problem.fixed] = problem.fixed_positions
        t_certify = time.perf_counter()
        outcome, cert, reason = judged(problem, out, outcome, reason, self.forced)
        return Final(out, outcome, cert, reason, problem=problem, energy=self.E,
                     volume=self.full.total_volume, details=self.details, inverted_at_start=self.initially,
                     certify_seconds=time.perf_counter() - t_certify)


def judged(problem, x, outcome, reason="", forced=None):
    """``(outcome, certificate, reason)`` of the final map ``x`` (n, d): its exact
    :class:`~geomopt.solvers.LocalCertificate` (``forced``, the input's
    :meth:`~geomopt.Problem.certify_fixed`, attached when it lists an overlap), and CONVERGED
    kept only for a valid map: CERTIFIED_EXCEPT_FIXED when it fails only where ``forced`` says
    the handles alone make it fail, else NOT_INJECTIVE with the first failure a free vertex
    could have removed."""
    moved = int(np.count_nonzero(differing_rows(x[problem.fixed], problem.fixed_positions)))
    cert = local_certificate(problem, x, moved)
    if forced is not None and not forced.ok:
        cert = dataclasses.replace(cert, forced=forced)
    if outcome is not Outcome.CONVERGED or cert.valid:
        return outcome, cert, reason
    if cert.valid_except_forced:
        return Outcome.CERTIFIED_EXCEPT_FIXED, cert, (
            f"converged, but the handles alone make the map overlap at {forced.failures} vertices and edges whose "
            f"elements all have every vertex fixed (a property of the input, the same for every map with these "
            f"handles; first: {forced.message}); everywhere else the map is certified locally injective")
    if not cert.inverted and not cert.ok:
        reason = _local_reason(problem, cert if cert.forced is None else cert.beyond(cert.forced))
    return Outcome.NOT_INJECTIVE, cert, reason


def _local_reason(problem, cert) -> str:
    """Why a map with every element positive is not locally injective, with what to do."""
    hint = ("the fixed boundary probably winds more than once or overlaps itself, check the handle "
            "positions" if np.isin(problem.boundary_vertices(), problem.fixed).all()
            else "flip-free motion cannot remove it; start from a map whose boundary is a simple "
            "polygon (e.g. a Tutte embedding) or fix the boundary while untangling")
    return f"no element is inverted, but {cert.message}; {hint}"


# --------------------------------------------------------------------- main entry


@float64
def untangle(problem: Problem, x0, solver="lbfgs", *, options: UntangleOptions | None = None, progress=True,
             throw: bool = False, **overrides) -> Result:
    """Untangle ``x0`` (n, d) with ``problem``'s handles fixed (Garanzha et al. 2021).

    With no handles (a free boundary, e.g. repairing a folded UV map) translation is pinned
    by the objective's gauge and rotation and scale are free; the map must not be mirrored as
    a whole (a positive total signed area/volume): mirror it first (see :func:`~geomopt.param.repair_map`).

    Parameters
    ----------
    problem : :class:`~geomopt.mesh.problem.Problem`, with fixed vertices (``with_fixed``) or not.
    x0 : (n, d) start map; its handle rows are replaced by ``problem.fixed_positions``.
    solver : ``"lbfgs"`` (default), ``"newton"`` (see :func:`default_solver`) or a solver object.
        Its line search should not be injective: the start is tangled.
    options : :class:`UntangleOptions` (theta, max_outer, energy_tol, eps0, max_aspect,
        keep_memory, injective_when_untangled, min_sigma, max_sigma, bucket); ``overrides``
        (those names as keywords) replace its fields.
    progress : True (one line per outer iteration on stderr), False, or a callable
        ``(outer, eps, energy, min_det, n_inverted, inner, seconds)``.
    throw : raise :class:`~geomopt.SolveError` (carrying the result) unless ``success``.

    Returns
    -------
    :class:`~geomopt.solvers.Result`: ``x`` in the input frame, handles bit-identical to
    ``problem.fixed_positions``; ``certificate`` the exact :class:`~geomopt.solvers.LocalCertificate`
    (inverted elements, 2D branch points, moved handles); ``stats.iterations`` the inner
    iterations, ``stats.outer_iterations``, ``stats.inverted_at_start``; ``trace.phases`` one
    :class:`UntangleRecord` per outer iteration; ``details`` the :class:`UntangleDetails`.
    ``energy`` and ``mean_energy`` are measured in the normalised frame.

    Stars whose every element has all its vertices fixed and that overlap in ``x0``
    (:meth:`~geomopt.Problem.certify_fixed`) are the same in every map with these handles: the
    rest is solved, and a map locally injective everywhere else ends
    ``Outcome.CERTIFIED_EXCEPT_FIXED`` (not ``success``; ``certificate.forced`` lists them).

    Raises
    ------
    MeshError
        The rest mesh of a triangle or tet problem is not locally injective (exact, at set-up).

    Examples
    --------
    A 4 x 4 grid whose interior is rotated by 180 degrees (folded), its boundary fixed:

    >>> from geomopt.mesh import generators
    >>> from geomopt.untangle import untangle
    >>> tangle = generators.rotated_interior(*generators.square_mesh(4), 180.0)
    >>> result = untangle(tangle.problem(), tangle.x0, progress=False)
    >>> tangle.inverted(), result.certificate.inverted, result.success
    (4, 0, True)
    """
    refuse_traced("geomopt.untangle.untangle", "for the untangled map as a differentiable function of the problem "
                  "(rest shape, handles) and theta use geomopt.implicit.untangle", problem, x0, options, overrides)
    opts = options_from(UntangleOptions, options, overrides, "untangle")
    if not isinstance(solver, (str, AbstractSolver)):
        raise ParameterError(f"solver must be 'lbfgs', 'newton' or a solver object, got {solver!r}")
    check_progress(progress, "untangle")
    t_setup = time.perf_counter()
    _check_rest(problem)  # exact, before anything is compiled
    x0 = problem.check_map(x0)
    initially = problem.count_inverted(x0)
    why = _refusal(problem, x0, initially, problem.free_mask[problem.simplices].any(axis=1))
    if why:
        return _early_result(problem, x0, initially, t_setup, throw, why)
    forced = problem.certify_fixed(x0)  # stars no free vertex changes (quads/hexahedra: their tangent cones)
    x_start, which = choose_start(problem, x0, opts.start)
    parts = hold_free_parts(problem, x_start)  # parts without a handle: held at a certified map
    held = np.union1d(problem.fixed, parts.held)
    solving = problem.with_fixed(held, parts.x[held]) if len(parts.held) else problem
    active = solving.free_mask[solving.simplices].any(axis=1)
    theta = opts.resolved_theta(problem.dim)
    details = UntangleDetails(theta, theta / (1.0 - theta), 1.0, 1.0, int(active.sum()), which,
                              parts.given + parts.rest + parts.pinned, parts.rest)
    if not active.any():  # nothing left to move: the map is certified as it is
        result = _held_result(problem, parts.x, initially, forced, t_setup, details)
    else:
        before = time.perf_counter() - t_setup
        result = _solve(problem, solving, parts.x, active, solver, opts, details, initially, forced, progress, throw)
        result = dataclasses.replace(result, problem=problem, stats=dataclasses.replace(
            result.stats, setup_seconds=result.stats.setup_seconds + before))
    if throw and not result.success:
        raise SolveError(f"untangling failed: {result.message}", result)
    return result


def _solve(problem, solving, x_start, active, solver, opts, details, initially, forced, progress, throw) -> Result:
    """The eps loop on ``solving`` (``problem`` with its handle-free parts held) from ``x_start``."""
    t_setup = time.perf_counter()
    stiff = None  # the solver a stalling inner solve continues with (default L-BFGS only)
    if isinstance(solver, str):
        corners = problem.elements is not None
        stiff = stiff_solver(solver, problem.dim, corners)
        solver = default_solver(solver, problem.dim, int(active.sum()), corners, initially)
    scaled, sub, xs, k, s = _normalised(solving, x_start, active, opts)
    energy = garanzha.with_params(eps=1.0, lam=details.lam)
    full = Objective(scaled, energy, buckets=opts.bucket)
    obj = Objective(sub, energy, buckets=full.sizes if opts.bucket else False)
    if opts.eps0 is None:
        opts = dataclasses.replace(opts, eps0=start_eps(sub, xs))
    details = dataclasses.replace(details, map_scale=k, rest_scale=s)
    eps = EpsContinuation(solving, scaled, full, obj, k, xs, opts, details, initially, solver, stiff, forced)
    setup = time.perf_counter() - t_setup
    result = iterate(eps.phase_solver, obj, jax.device_put(xs), obj.params(eps=float(opts.eps0)), continuation=eps,
                     progress=_phase_progress(progress), trace=False, throw=False, label="untangling",
                     warn=not throw)  # raised by untangle with the whole set-up time
    return dataclasses.replace(result, stats=dataclasses.replace(
        result.stats, setup_seconds=result.stats.setup_seconds + setup))


def _held_result(problem, x, initially, forced, t_setup, details) -> Result:
    """The result when no vertex is left to move (every part held or fixed): ``x`` certified."""
    t = time.perf_counter()
    outcome, cert, reason = judged(problem, x, Outcome.CONVERGED, "", forced)
    stats = RunStats(setup_seconds=t - t_setup, inverted_at_start=initially, certify_seconds=time.perf_counter() - t)
    return Result(x, outcome, cert, stats, problem=problem, reason=reason, details=details)


def _check_rest(problem: Problem) -> None:
    """MeshError (one line) when the rest mesh of a triangle (planar) or tet problem is not
    locally injective (exact, :meth:`Problem.certify` of the rest vertices): every element is
    measured against it, and its fold is no fault of the handles or of the start map."""
    if problem.kind not in ("planar", "tet"):
        return
    cert = problem.certify(np.asarray(problem.rest_vertices, dtype=np.float64))
    if not cert.ok:
        raise MeshError(f"the rest mesh itself is not locally injective: {cert.message}; untangling measures every "
                        f"element against the rest mesh, so fix the rest mesh (e.g. rest.vtk, or the 'v' lines)")


def _phase_progress(progress):
    """untangle's ``progress`` as an :func:`~geomopt.solvers.iterate` progress: lines per
    outer iteration, or the user's callable per outer iteration."""
    if progress is True:
        return Progress(iterations=False)
    if callable(progress):
        return _PhaseCallback(progress)
    return None


class _PhaseCallback:
    """A callable ``(outer, eps, energy, min_det, n_inverted, inner, seconds)`` called per
    outer iteration (and never per inner iteration)."""

    iterations = False

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, state, elapsed, mean_energy):
        return None

    def phase(self, index, r, elapsed):
        self.fn(index, r.eps, r.mean_energy, r.min_det, r.inverted, r.inner, elapsed)


def _refusal(problem, x0, initially, active) -> str | None:
    """Why no map with these handles can be injective (checked before solving), or None."""
    why = fixed_total_problem(problem, x0) if initially else None
    if why:
        return f"{why}; mirror the handle positions or free part of the boundary"
    if initially and not active.all():  # elements that cannot move: one inverted = infeasible
        dead = int(np.count_nonzero(_orient_bad(x0, problem.simplices[~active])))
        if dead:
            return (f"{dead} inverted element(s) have every vertex fixed: no map with these handles "
                    f"is injective")
    return None


def _normalised(problem, x0, active, opts):
    """``(scaled, sub, xs, k, s)``: the map scaled by a power of two ``k`` into a box of size
    ~BOX (``xs``), the rest mesh by ``s`` to the map's volume (equilateral rest triangles above
    ``max_aspect`` in 2D), ``sub`` its active elements."""
    d = problem.dim
    k = box_scale(x0, BOX)
    xs = x0 * k
    map_vol = float(problem.signed_volumes(xs).sum())
    rest_vol = float(problem.volumes.sum())
    s = (map_vol / rest_vol) ** (1.0 / d) if map_vol > 0 else k
    scaled = dataclasses.replace(
        problem, rest_inv=problem.rest_inv / s, volumes=problem.volumes * s**d,
        rest_vertices=problem.rest_vertices * s, fixed_positions=problem.fixed_positions * k)
    scaled = _equilateral_rest(scaled, opts.max_aspect)
    sub = dataclasses.replace(scaled, simplices=scaled.simplices[active],
                              input_simplices=scaled.input_simplices[active],
                              rest_inv=scaled.rest_inv[active], volumes=scaled.volumes[active])
    return scaled, sub, xs, k, s


def _orient_bad(x, S):
    from .exact.predicates import simplex_orientations

    return simplex_orientations(x, S) != 1


def _early_result(problem, x0, initially, t_setup, throw, reason):
    result = Result(x0, Outcome.NOT_INJECTIVE, LocalCertificate(initially),
                    RunStats(setup_seconds=time.perf_counter() - t_setup, inverted_at_start=initially),
                    problem=problem, reason=reason)
    if throw:
        raise SolveError(f"untangling failed: {reason}", result)
    return result

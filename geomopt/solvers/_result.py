"""The one result type of every solve: :func:`minimize`, :func:`~geomopt.untangling.untangle`,
:func:`~geomopt.parameterize` and the bijective mode, :func:`~geomopt.sphere_map` and
:func:`~geomopt.smooth`.

``Result(x, outcome, certificate, stats, trace)`` with typed parts: the map, how the solve
ended, an exact certificate of the map, the run's totals (:class:`RunStats`) and histories
(:class:`Trace`); plus what was solved (``problem``, ``objective``, ``solver``), why it stopped
(``reason``) and a driver's typed ``details`` (a :class:`Details`).

Energies: :attr:`Result.energy` is the total ``sum_e vol_e psi(J_e)`` of the map at the end;
:attr:`Result.mean_energy` is that total divided by the total rest area (2D) or volume (3D),
``RunStats.volume``: the area-weighted mean density (4 at an isometry for symmetric Dirichlet in
2D).  Untangling reports both in its normalised frame (the rest mesh scaled to the map's
volume).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..exact import certify
from ._termination import Outcome

__all__ = ["Result", "RunStats", "Trace", "LocalCertificate", "ResultCertificate", "Details", "UntangleDetails",
           "ParamDetails", "local_certificate", "ForwardCertificate", "traced_result"]


@dataclasses.dataclass(frozen=True)
class LocalCertificate(certify.LocalCertificate):
    """Exact checks that a map is locally injective (:class:`geomopt.exact.certify.LocalCertificate`:
    every element positively oriented, and the elements around every vertex and edge covering
    its neighbourhood once), and that its handles are in place.

    Attributes
    ----------
    handles_moved : int, fixed vertices whose position differs from the prescribed one as a
        number (:func:`geomopt.exact.predicates.differing_rows`); the other attributes are :class:`geomopt.exact.certify.LocalCertificate`'s (``inverted``,
        ``branch_vertices``, ``branch_edges``, ``boundary_overlaps``...).
    forced : the failures the handles alone make certain, or None: the input's
        :meth:`~geomopt.Problem.certify_fixed` (stars whose every vertex is fixed that overlap).
        They stay listed above (``ok`` is False); :attr:`valid_except_forced` says whether every
        other vertex and edge is certified.
    """

    handles_moved: int = 0
    forced: Any = None

    @classmethod
    def of(cls, exact: certify.LocalCertificate, handles_moved: int = 0) -> LocalCertificate:
        """``exact`` (a :class:`geomopt.exact.certify.LocalCertificate`, e.g. a quad / hex map's
        :class:`~geomopt.mesh.elements.ElementLocalCertificate`) with ``handles_moved``."""
        return cls(**{f.name: getattr(exact, f.name) for f in dataclasses.fields(certify.LocalCertificate)},
                   handles_moved=int(handles_moved))

    @property
    def locally_injective(self) -> bool:
        return self.ok

    @property
    def globally_injective(self) -> bool:
        """Not certified by local checks (see :func:`geomopt.exact.certify.certify_bijective`)."""
        return False

    @property
    def injectivity(self) -> str:
        """``"local"`` or ``"none"``."""
        return "local" if self.ok else "none"

    @property
    def valid(self) -> bool:
        """Locally injective with every handle exactly in place."""
        return self.ok and self.handles_moved == 0

    @property
    def valid_except_forced(self) -> bool:
        """Not :attr:`valid`, but only at the stars :attr:`forced` lists: no inverted element, every
        handle in place, and every vertex and edge a free vertex reaches locally injective."""
        return (self.forced is not None and not self.ok and self.inverted == 0 and self.handles_moved == 0
                and self.beyond(self.forced).ok)


def local_certificate(problem, x, handles_moved: int = 0, orientation: int = 1) -> LocalCertificate:
    """The :class:`LocalCertificate` of the map ``x`` (n, d) of ``problem`` (its simplices,
    positive when ``orientation`` is +1): :func:`geomopt.exact.certify.local_certificate` plus
    ``handles_moved``.  Quads / hexahedra: :meth:`~geomopt.mesh.problem.Problem.certify` (each element
    valid everywhere, then the stars of their tangent cones, never the overlapping corner
    simplices as one mesh)."""
    exact = (problem.certify(x) if getattr(problem, "elements", None) is not None and orientation == 1 else
             certify.local_certificate(x, problem.simplices, orientation))
    return LocalCertificate.of(exact, handles_moved)


@dataclasses.dataclass(frozen=True)
class RunStats:
    """Totals of a solve.

    Attributes
    ----------
    iterations : solver iterations, summed over every phase (untangling: the inner iterations).
    evaluations : energy (and gradient) evaluations.
    outer_iterations : continuation steps (untangling's eps updates, scaffold rebuilds).
    seconds : time of the loop (set-up excluded);  setup_seconds : set-up (pattern, symbolic
        factorization, JIT compilation or cache loading, scaling).
    energy : the final total energy;  volume : the total rest area/volume it is measured
        against (see the module notes).
    inverted_at_start : elements inverted in the start map (exact), where the solve counted them.
    certify_seconds : time of the final exact certificate (part of neither ``seconds`` nor
        ``setup_seconds``).
    cpu_seconds, setup_cpu_seconds : process-CPU seconds of the loop and of the set-up.
    """

    iterations: int = 0
    evaluations: int = 0
    outer_iterations: int = 0
    seconds: float = 0.0
    setup_seconds: float = 0.0
    energy: float = math.nan
    volume: float = math.nan
    inverted_at_start: int | None = None
    certify_seconds: float = 0.0
    cpu_seconds: float = 0.0
    setup_cpu_seconds: float = 0.0


@dataclasses.dataclass(frozen=True)
class Trace:
    """Histories of a solve.

    Attributes
    ----------
    energy, seconds, grad_norm : (k,) the total energy, the solve seconds and ``|grad E|``
        (free DOFs) at each recorded point: every iterate, the start first, when the solve
        traced them; else the end of every phase (an outer iteration), where the phase record's
        ``energy`` (if it has one) is the energy.
    flips : (k,) int, inverted elements of each recorded iterate where counted (``compare``),
        else None.
    phases : one record per outer iteration (a NamedTuple of the continuation, e.g.
        :class:`geomopt.untangling.UntangleRecord`); :meth:`column` reads one field of them.
    cpu_seconds : (k,) the process-CPU seconds of the solve at each recorded point.
    """

    energy: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    seconds: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    grad_norm: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    flips: np.ndarray | None = None
    phases: tuple = ()
    cpu_seconds: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def column(self, name: str, dtype=np.float64) -> np.ndarray:
        """(outer iterations,) field ``name`` of every phase record."""
        return np.asarray([getattr(r, name) for r in self.phases], dtype=dtype)


@dataclasses.dataclass(frozen=True)
class ForwardCertificate:
    """The certificate of a :class:`Result` returned for traced inputs (a driver under
    ``jax.grad``, ``jit``, ``vmap``): its map is a JAX value that no predicate can read here.
    The solve that computes it runs on the host and raises (:class:`~geomopt.SolveError`; inside
    ``jax.jit`` JAX's runtime error, whose text names it) unless it converged and its exact
    certificate passed, so a map that is returned at all was certified."""

    inverted: int = 0
    locally_injective: bool = True
    injectivity: str = "local"
    handles_moved: int = 0
    message: str = "certified by the solve on the host (it raises instead of returning a map that is not)"


#: what :attr:`Result.certificate` is: every one has ``inverted``, ``locally_injective`` and
#: ``injectivity``
ResultCertificate = LocalCertificate | certify.Certificate | certify.SphereCertificate | ForwardCertificate


@dataclasses.dataclass(frozen=True)
class Details:
    """Base class of what a driver adds to its :class:`Result` (:attr:`Result.details`):
    :class:`UntangleDetails`, :class:`ParamDetails`, :class:`geomopt.sphere.SphereDetails`,
    :class:`geomopt.smoothing.SmoothDetails`."""


@dataclasses.dataclass(frozen=True)
class UntangleDetails(Details):
    """What :func:`~geomopt.untangling.untangle` adds: ``theta`` and ``lam = theta / (1 - theta)``,
    the exact power-of-two ``map_scale`` and the ``rest_scale`` of its normalised frame, the
    elements that have a free vertex (``active_elements``), and the map the eps loop started
    from (``start``: ``"given"``, ``"harmonic"`` or ``"mixed"``, see :func:`geomopt.untangling.start.choose_start`,
    or ``"given, then harmonic"`` when ``start="auto"`` started again from the harmonic extension);
    the connected parts without a handle (``free_parts``), held at a certified map, ``rest_parts`` of
    them at their rest shape (see :func:`geomopt.untangling.start.hold_free_parts`); ``polished``
    whether the final Newton polish converged (the map is then the minimiser of the energy at
    :func:`geomopt.untangling.final_eps` to rounding, see :class:`~geomopt.untangling.UntangleOptions`)."""

    theta: float
    lam: float
    map_scale: float = 1.0
    rest_scale: float = 1.0
    active_elements: int = 0
    start: str = "given"
    free_parts: int = 0
    rest_parts: int = 0
    polished: bool = False


@dataclasses.dataclass(frozen=True)
class ParamDetails(Details):
    """What :func:`~geomopt.parameterize` adds: the ``start`` map (n, 2) after scaling, the
    ``scale`` applied to it, the ``repair`` (a :class:`Result` of the untangling of a folded
    start, or None); the bijective mode's scaffold-free iterations (``free_iterations``), edge
    ``flips`` and final ``scaffold_triangles``."""

    start: np.ndarray | None = None
    scale: float = 1.0
    repair: Result | None = None
    free_iterations: int = 0
    flips: int = 0
    scaffold_triangles: int = 0


@dataclasses.dataclass(frozen=True, eq=False)
class Result:
    """The outcome of a solve.

    Attributes
    ----------
    x : (n, d) ndarray, the map (input frame; handles equal to the prescribed ones as numbers).
    outcome : :class:`~geomopt.solvers.Outcome`.
    certificate : the exact certificate of ``x`` (:data:`ResultCertificate`):
        :class:`LocalCertificate` (``inverted``, ``branch_vertices``, ``boundary_overlaps``...,
        ``handles_moved``), for free-boundary parameterization :class:`geomopt.exact.certify.Certificate`
        (global: boundary crossings too), for :func:`~geomopt.sphere_map`
        :class:`geomopt.exact.certify.SphereCertificate`.  Every certificate has ``inverted``,
        ``locally_injective`` and ``injectivity``.
    stats : :class:`RunStats`;  trace : :class:`Trace`.
    problem : the :class:`~geomopt.Problem` ``x`` maps;  objective : the
        :class:`~geomopt.Objective` minimised (energy and parameters);  solver : the solver.
    reason : why the solve stopped, when the outcome alone does not say (divergence, a time
        limit, branch points...), else "".
    details : the driver's own :class:`Details` (:class:`UntangleDetails`, :class:`ParamDetails`,
        :class:`geomopt.sphere.SphereDetails`, :class:`geomopt.smoothing.SmoothDetails`), or None
        (:func:`minimize`)
    """

    x: np.ndarray
    outcome: Outcome
    certificate: ResultCertificate
    stats: RunStats = RunStats()
    trace: Trace = Trace()
    problem: Any = None
    objective: Any = None
    solver: Any = None
    reason: str = ""
    details: Details | None = None

    @property
    def success(self) -> bool:
        """Converged and certified: no inverted element, no branch point, handles in place."""
        return (self.outcome is Outcome.CONVERGED and self.certificate.locally_injective
                and getattr(self.certificate, "handles_moved", 0) == 0)

    @property
    def energy(self) -> float:
        """The final total energy ``sum_e vol_e psi(J_e)``."""
        return self.stats.energy

    @property
    def mean_energy(self) -> float:
        """:attr:`energy` divided by the total rest area/volume (see the module notes)."""
        return self.stats.energy / self.stats.volume

    @property
    def injectivity(self) -> str:
        """``"global"`` (exact certificate: flip-free and the boundary does not overlap itself),
        ``"local"`` (flip-free) or ``"none"``."""
        return self.certificate.injectivity

    @property
    def min_det_rel(self) -> float:
        """The smallest signed area/volume of ``x`` over the mean absolute one (nan when every
        element is degenerate or there is no problem)."""
        if self.problem is None:
            return math.nan
        vols = self.problem.signed_volumes(self.x)
        scale = float(np.mean(np.abs(vols)))
        return float(vols.min() / scale) if scale > 0 else math.nan

    @property
    def message(self) -> str:
        cert = self.certificate
        if self.reason and self.outcome is not Outcome.DIVERGED:
            msg = self.reason
        else:
            msg = self.outcome.message + (f" ({self.reason})" if self.reason else "")
        inverted = cert.inverted if np.ndim(cert.inverted) == 0 else len(cert.inverted)  # an atlas's: the faces
        if inverted:
            msg += f"; {inverted} inverted element(s)"
        if getattr(cert, "handles_moved", 0):
            msg += f"; {cert.handles_moved} handle(s) moved"
        return msg

    def save(self, path, png=None, *, inputs=()):
        """``geomopt.save(self, path, png, inputs=inputs)``: the map file and its picture, as the
        command line writes them (:func:`geomopt.save`, which says what is written and raised)."""
        import geomopt  # the writers live on the output floor, above the results

        return geomopt.save(self, path, png, inputs=inputs)


def traced_result(x, *, problem=None, objective=None, solver=None) -> Result:
    """The :class:`Result` of a driver called on traced inputs: ``x`` the differentiable map (a
    JAX value), the outcome CONVERGED and a :class:`ForwardCertificate` (the host solve raises
    otherwise), no statistics or trace (they are the host solve's, not values of the
    transformation).  Read ``.x`` inside the transformed function."""
    return Result(x, Outcome.CONVERGED, ForwardCertificate(), problem=problem, objective=objective, solver=solver,
                  reason="traced inputs: the map is differentiable (implicit function theorem at the optimum)")


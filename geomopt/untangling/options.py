"""The settings of :func:`~geomopt.untangling.untangle`: :class:`UntangleOptions`, validated."""

from __future__ import annotations

import dataclasses

from .._runtime.config import Either, Instance, Int, Maybe, OneOf, Real, Traceable, validate
from .._runtime.errors import ParameterError
from .start import STARTS

__all__ = ["UntangleOptions", "POLISH_UP_TO"]


#: free coordinates (free vertices times the dimension) up to which ``polish="auto"`` polishes
#: an untangled map that is not differentiated (:class:`UntangleOptions`)
POLISH_UP_TO = 300_000


@dataclasses.dataclass(frozen=True)
class UntangleOptions:
    """The settings of :func:`~geomopt.untangling.untangle` (validated: a wrong type or range is a one-line
    :class:`~geomopt.ParameterError`).

    Attributes
    ----------
    theta : shape/area balance in ``(0, 1)``; ``lam = theta / (1 - theta)``.  None: 1/128 in
        2D, 1/2 in 3D.
    max_outer : outer (eps) iteration limit.
    energy_tol : stop once untangled and ``|E_prev - E| / E`` of an inner solve is below this.
    eps0 : initial eps (the map is normalised so the mean det J is 1).  None: the median
        ``|det J|`` of the start's active elements over :data:`~geomopt.untangling.START_RATIO`, at least 1
        (:func:`~geomopt.untangling.start_eps`).
    max_aspect : 2D only: rest triangles with an aspect ratio above this are replaced by
        equilateral ones (Garanzha et al.'s code uses 10); None keeps the rest mesh.
    keep_memory : keep the L-BFGS curvature pairs across outer iterations, except after one
        that increased the number of inverted elements (measured on square_rot180: it stalled
        with 64 folds under half of 14 exact rotations of its rest mesh when the pairs were
        always kept, and untangled under all 14 with this reset, at the same cost elsewhere).
    injective_when_untangled : once every element is positive, switch the inner line search
        to the injective one (no element can flip back; compiles a second kernel).
    min_sigma, max_sigma : bounds of ``sigma = 1 - E/E_prev``, the fraction by which each outer
        iteration shrinks ``chi(D-, eps)`` (:func:`~geomopt.untangling.next_eps`).  The paper uses ``0.1`` and no
        cap; the default halves it every outer iteration while elements are inverted and
        applies no cap once none is (see the module notes).
    bucket : pad the problem to its size bucket (``Objective(buckets=True)``,
        :mod:`geomopt._runtime.padding`), so that meshes of similar sizes share compiled kernels; same
        certificate, same map up to the rounding of sums over elements.
    start : where the eps loop starts (:data:`STARTS`): ``"given"`` ``x0``; ``"harmonic"`` ``x0``
        with its free vertices replaced by the harmonic extension of the handles
        (:func:`~geomopt.untangling.harmonic_start`); ``"auto"`` (default) the harmonic extension for quads and
        hexahedra when it has fewer inverted corners than ``x0``, else ``x0`` (see
        :func:`~geomopt.untangling.choose_start`), decided per connected part; when the run from a start
        that is not the harmonic extension ends uncertified before ``max_outer``, or stalls (eps at its floor for
        :data:`~geomopt.untangling.driver.STALL_OUTER` outer iterations with no fewer inverted
        elements), ``"auto"`` runs the eps loop again from the harmonic extension (``details.start``
        ``"given, then harmonic"``, the stats summed over both runs, ``max_outer`` shared).  Whatever ``start``, a connected
        part without a handle is held at a certified map, not solved
        (:func:`geomopt.untangling.start.hold_free_parts`).
    polish : once untangled, polish the map by Newton at the constant
        :func:`~geomopt.untangling.final_eps` (:func:`~geomopt.untangling.polish_solver`,
        injective): the map returned is then the energy's minimiser to rounding, a smooth
        function of the rest mesh, the handles and ``theta``, and the map a traced call
        returns and differentiates.  False skips it (the map of the last inner solve, accurate
        to its tolerance only; traced calls refuse it); ``"auto"`` (default) polishes problems
        of up to :data:`~geomopt.untangling.POLISH_UP_TO` free coordinates and every traced one
        (a Newton step costs more than the whole untangling beyond, at 10^6 elements).
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
    polish: bool | str = "auto"

    def __post_init__(self):
        validate(self, theta=Maybe(Traceable(Real(0.0, 1.0, lo_open=True, hi_open=True))), max_outer=Int(1),
                 energy_tol=Real(0.0, 1.0, lo_open=True, hi_open=True), eps0=Maybe(Real(0.0, lo_open=True)),
                 max_aspect=Maybe(Real(1.0)), keep_memory=Instance(bool),
                 injective_when_untangled=Instance(bool), min_sigma=Real(0.0, 1.0, lo_open=True, hi_open=True),
                 max_sigma=Real(0.0, 1.0, lo_open=True, hi_open=True), bucket=Instance(bool),
                 start=OneOf(STARTS), polish=Either(Instance(bool), OneOf(("auto",))))
        if not self.min_sigma <= self.max_sigma:
            raise ParameterError(f"UntangleOptions: need min_sigma <= max_sigma, got {self.min_sigma} and "
                                 f"{self.max_sigma}")

    def resolved_theta(self, dim: int) -> float:
        return self.theta if self.theta is not None else (1.0 / 128.0 if dim == 2 else 0.5)

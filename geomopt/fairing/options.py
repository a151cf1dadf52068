"""The settings of :func:`~geomopt.fairing.fair` (validated; one frozen dataclass)."""

from __future__ import annotations

import dataclasses

from .._runtime.config import Instance, Int, Maybe, OneOf, Real, Traceable, validate

__all__ = ["FairOptions", "METHODS", "BOUNDARIES", "DEFAULT_LAPLACIAN"]

METHODS = ("laplacian", "taubin", "implicit", "least_squares", "energy", "spectral", "tangential", "relax")
BOUNDARIES = ("fixed", "free", "curve")
#: the Laplacian each method uses when ``laplacian`` is None (the lectures' choices)
DEFAULT_LAPLACIAN = {"laplacian": "uniform", "taubin": "uniform", "implicit": "cotangent",
                     "least_squares": "uniform", "energy": "cotangent", "spectral": "cotangent",
                     "tangential": "cotangent", "relax": "uniform"}
_DEFAULT_STEPS = {"laplacian": 10, "taubin": 10, "implicit": 1, "relax": 10}
#: the data term's weight when ``weight`` is None (each method's is in its own units)
_DEFAULT_WEIGHT = {"least_squares": 1.0, "energy": 10.0, "tangential": 1.0}


@dataclasses.dataclass(frozen=True)
class FairOptions:
    """How :func:`~geomopt.fairing.fair` smooths (see :mod:`geomopt.fairing.methods` for the
    formulas; lengths are relative to the input's mean edge length ``h``).

    Attributes
    ----------
    method : one of :data:`METHODS` (``relax``: tangential relaxation onto the input surface,
        :mod:`geomopt.fairing.relax`).
    laplacian : ``"uniform"``, ``"cotangent"`` (clamped, :mod:`geomopt.fairing.operators`) or None
        (the method's default, :data:`DEFAULT_LAPLACIAN`).
    steps : explicit / implicit / relaxation steps (None: 10, 10, 1, 10; Taubin counts pairs).
    lam, mu : the step factors of ``laplacian`` and ``taubin`` (``0 < lam <= 1``, ``mu < -lam``).
    time : ``implicit``'s total time in units of ``h^2``.
    weight : the data term's weight (``least_squares``, ``energy``, ``tangential``; > 0; None:
        1, 10 and 1).
        ``lam``, ``mu``, ``time`` and ``weight`` may be traced JAX scalars (differentiation through
        :func:`~geomopt.fairing.smoothed`).
    eigenvectors : ``spectral``'s basis size.
    boundary : ``"fixed"`` (held), ``"free"`` (moved like the rest), ``"curve"`` (each boundary
        loop smoothed first as a polyline by the same method, then held).
    crease_angle : degrees; edges with a larger dihedral angle are features: ``least_squares``
        fits them ``feature_weight`` times harder and fairs them as much less, ``relax`` holds
        them.  None: no features.
    feature_weight : see ``crease_angle`` (>= 1).
    preserve_volume : closed surfaces: scale the result about its centroid to the input's
        enclosed volume.
    surface_tolerance : ``relax``: how far an output face may leave the input surface, over the
        input's bounding-box diagonal (a vertex move that would take a face farther is undone).
    """

    method: str = "taubin"
    laplacian: str | None = None
    steps: int | None = None
    lam: float = 0.5
    mu: float = -0.53
    time: float = 1.0
    weight: float | None = None
    eigenvectors: int = 100
    boundary: str = "fixed"
    crease_angle: float | None = None
    feature_weight: float = 10.0
    preserve_volume: bool = False
    surface_tolerance: float = 1e-6

    def __post_init__(self):
        validate(self, method=OneOf(METHODS), laplacian=Maybe(OneOf(("uniform", "cotangent"))),
                 steps=Maybe(Int(1)), lam=Traceable(Real(0.0, 1.0, lo_open=True)),
                 mu=Traceable(Real(-2.0, 0.0, hi_open=True)), time=Traceable(Real(0.0, lo_open=True)),
                 weight=Maybe(Traceable(Real(0.0, lo_open=True))), eigenvectors=Int(1),
                 boundary=OneOf(BOUNDARIES), crease_angle=Maybe(Real(0.0, 180.0)),
                 feature_weight=Real(1.0), preserve_volume=Instance(bool),
                 surface_tolerance=Real(0.0))
        from .._runtime.tracing import is_traced

        if self.method == "taubin" and not is_traced(self.lam, self.mu) and not self.mu < -self.lam:
            from .._runtime.errors import ParameterError

            raise ParameterError(f"FairOptions: taubin needs mu < -lam (a pass band), got lam={self.lam}, "
                                 f"mu={self.mu}")

    def resolved(self) -> "FairOptions":
        """These options with ``laplacian``, ``steps`` and ``weight`` set to the method's defaults
        where None."""
        return dataclasses.replace(self, laplacian=self.laplacian or DEFAULT_LAPLACIAN[self.method],
                                   steps=self.steps or _DEFAULT_STEPS.get(self.method, 1),
                                   weight=_DEFAULT_WEIGHT.get(self.method, 1.0) if self.weight is None else self.weight)

"""The :class:`Energy` object: a density plus its default parameters, and the name registry."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Mapping

from .._errors import ParameterError
from . import _densities as _d


@dataclasses.dataclass(frozen=True, eq=False)
class Energy:
    """A distortion energy ``E(x) = sum_e vol_e * density(J_e(x), params)``.

    Parameters
    ----------
    density : callable ``(J (d, d), params: dict) -> scalar``
        Written once for one element; must be a pure JAX function.  Works in 2D and 3D
        when written in terms of ``J.shape``.
    params : mapping of str to float
        Default parameter values (e.g. ``eps``, ``lam``).  Solvers pass them as traced
        scalars, so changing them never recompiles.
    barrier : bool
        True when the density is ``+inf`` for ``det J <= 0`` (symmetric Dirichlet, MIPS...).
    rest_value : float or callable ``d -> float``, optional
        The density at a rotation, used to report a normalised energy (and in tests).
    name : str
    """

    density: Callable
    params: Mapping[str, float] = dataclasses.field(default_factory=dict)
    barrier: bool = False
    rest_value: object = None
    name: str = "custom"

    def __post_init__(self):
        if not callable(self.density):
            raise ParameterError(f"energy {self.name!r}: density must be a function psi(J, params), "
                                 f"got {type(self.density).__name__}")
        object.__setattr__(self, "params", _check_params(self.name, self.params))

    def with_params(self, **params) -> "Energy":
        """A copy with some parameters changed (validated)."""
        unknown = set(params) - set(self.params)
        if unknown:
            raise ParameterError(
                f"energy {self.name!r} has no parameter(s) {sorted(unknown)}; "
                f"its parameters are {sorted(self.params)}"
            )
        return dataclasses.replace(self, params={**self.params, **params})

    def value_at_rest(self, d: int):
        rv = self.rest_value
        return rv(d) if callable(rv) else rv


def _check_params(name, params) -> dict:
    """``params`` as a dict of finite floats, with ``eps > 0`` and ``lam >= 0``; else ParameterError."""
    try:
        items = dict(params).items()
    except (TypeError, ValueError):
        raise ParameterError(f"energy {name!r}: params must map names to numbers, got {params!r}") from None
    out = {}
    for k, v in items:
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            raise ParameterError(f"energy {name!r}: parameter {k}={v!r} must be a number") from None
        if not math.isfinite(out[k]):
            raise ParameterError(f"energy {name!r}: parameter {k}={v} must be finite")
    if "eps" in out and not out["eps"] > 0:
        raise ParameterError(f"energy {name!r}: eps={out['eps']} must be > 0 (e.g. 1e-3)")
    if "lam" in out and out["lam"] < 0:
        raise ParameterError(f"energy {name!r}: lam={out['lam']} must be >= 0")
    return out


dirichlet = Energy(_d.dirichlet, name="dirichlet", rest_value=lambda d: float(d))
symmetric_dirichlet = Energy(
    _d.symmetric_dirichlet, barrier=True, name="symmetric_dirichlet", rest_value=lambda d: 2.0 * d
)
mips = Energy(_d.mips, barrier=True, name="mips", rest_value=lambda d: float(d))
winslow = Energy(_d.winslow, barrier=True, name="winslow", rest_value=lambda d: float(d))
arap = Energy(_d.arap, name="arap", rest_value=0.0)
garanzha = Energy(
    _d.garanzha,
    params={"eps": 1e-3, "lam": 1.0},
    name="garanzha",
    rest_value=None,  # depends on eps and lam
)

REGISTRY: dict[str, Energy] = {
    e.name: e for e in (dirichlet, symmetric_dirichlet, mips, winslow, arap, garanzha)
}


def get_energy(name_or_energy, **params) -> Energy:
    """Look an energy up by name (``geomopt.energies.REGISTRY``) or pass an :class:`Energy`
    through; keyword arguments override its parameters."""
    if isinstance(name_or_energy, Energy):
        e = name_or_energy
    else:
        key = str(name_or_energy).strip().lower().replace("-", "_")
        if key not in REGISTRY:
            raise ParameterError(
                f"unknown energy {name_or_energy!r}; valid energies: {', '.join(sorted(REGISTRY))}"
            )
        e = REGISTRY[key]
    return e.with_params(**params) if params else e

"""The :class:`Energy` object: a density plus its default parameters, and the name registry."""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime import names as _names
from .._runtime.programs import jit as programs_jit
from .._runtime.errors import ParameterError
from .._runtime.names import resolve
from .._runtime.tracing import is_traced
from .._runtime.x64 import float64
from . import _densities as _d


_FREE_ADVICE = ("use a scale-aware energy (symmetric_dirichlet, arap, mips) or fix boundary vertices "
                "(geomopt.minimize with a Problem that has handles)")


@dataclasses.dataclass(frozen=True, eq=False)
class Energy:
    """A distortion energy ``E(x) = sum_e vol_e * density(J_e(x), params)``.

    Parameters
    ----------
    density : callable ``(J (d, d), params: dict) -> scalar``
        Written once for one element; must be a pure JAX function of a float64 ``(d, d)``
        array and a dict of float64 scalars returning a real float64 scalar.  Works in 2D and
        3D when written in terms of ``J.shape``; one that traces for only one ``d`` can be
        used only on problems of that dimension.  Checked once here by tracing it
        (``jax.eval_shape``) on 2x2 and 3x3 Jacobians.
    params : mapping of str to float
        Default parameter values (e.g. ``eps``, ``lam``).  Solvers pass them as traced
        scalars, so changing them never recompiles.  Overrides may be traced JAX scalars
        (``jax.grad`` with respect to a parameter); their values are checked only when concrete.
    barrier : bool
        True when the density is ``+inf`` for ``det J <= 0`` (symmetric Dirichlet, MIPS...).
    rest_value : float or callable ``d -> float``, optional
        The density at a rotation, used to report a normalised energy (and in tests).
    name : str
    lower_bound : float, optional
        A bound ``density(J) >= lower_bound`` for every ``J`` (0 for every built-in energy),
        or None when unknown.  A solve whose energy falls below ``lower_bound`` times the rest
        volume ends :attr:`~geomopt.solvers.Outcome.DIVERGED`.

    Raises
    ------
    ParameterError
        ``density`` is not such a function for either d = 2 or d = 3, or a parameter is
        invalid (not a finite number, ``eps <= 0``, ``lam < 0``).
    """

    density: Callable
    params: Mapping[str, float] = dataclasses.field(default_factory=dict)
    barrier: bool = False
    rest_value: object = None
    name: str = "custom"
    lower_bound: float | None = None

    def __post_init__(self):
        if not callable(self.density):
            raise ParameterError(f"energy {self.name!r}: density must be a function psi(J, params), "
                                 f"got {type(self.density).__name__}")
        try:
            hash(self.density)  # the jitted kernels take it as a static argument
        except TypeError:
            raise ParameterError(f"energy {self.name!r}: density must be hashable (a plain function), "
                                 f"got an unhashable {type(self.density).__name__}") from None
        object.__setattr__(self, "params", _check_params(self.name, self.params))
        if self.lower_bound is not None:
            lb = _finite(self.name, "lower_bound", self.lower_bound)
            object.__setattr__(self, "lower_bound", lb)
        if not _library_density(self.density):  # the library's are traced by its tests
            self.dims  # noqa: B018  (traces the density; raises ParameterError)

    @property
    def dims(self) -> tuple:
        """The dimensions (2 and/or 3) the density traces for; ParameterError when none."""
        return _density_dims(self.name, self.density, tuple(sorted(self.params)))[0]

    def check_dim(self, d: int):
        """Raise ParameterError unless the density supports ``(d, d)`` Jacobians."""
        if self.density in _builtin_densities() and d in (2, 3):
            return  # traced in 2D and 3D by the tests: no tracing here (30-80 ms per process)
        dims, errors = _density_dims(self.name, self.density, tuple(sorted(self.params)))
        if d not in dims:
            raise ParameterError(
                f"energy {self.name!r}: the density works only for d={dims[0]}, but the problem "
                f"has {d}x{d} Jacobians (tracing it on a {d}x{d} J: {errors[d]}); {_DENSITY_RULE}")

    def resolve_params(self, **override) -> dict:
        """The energy's parameters with ``override`` applied, validated like the defaults
        (known names only, finite numbers, ``eps > 0``, ``lam >= 0``)."""
        unknown = set(override) - set(self.params)
        if unknown:
            raise ParameterError(
                f"energy {self.name!r} has no parameter(s) {sorted(unknown)}; "
                f"its parameters are {sorted(self.params) or 'none'}"
            )
        return _check_params(self.name, {**self.params, **override})

    def with_params(self, **params) -> "Energy":
        """A copy with some parameters changed (validated)."""
        return dataclasses.replace(self, params=self.resolve_params(**params))

    def value_at_rest(self, d: int):
        rv = self.rest_value
        return rv(d) if callable(rv) else rv

    @float64
    def check_scale_aware(self, params=None, d: int = 2, problem: str = "a free-boundary parameterization",
                          advice: str = _FREE_ADVICE):
        """Refuse this energy for a free boundary when it lets the map shrink to a point (e.g.
        Dirichlet): that problem has no minimiser, so any "solution" is a collapsed map.  Tested
        on the density itself, so it covers user energies: ``psi(s I) < psi(I) / 2`` at
        ``s = 1e-3`` for d x d Jacobians (no scale-aware or scale-invariant distortion does that;
        Winslow does in 3D, not in 2D).

        Parameters
        ----------
        params : mapping of str to float, optional
            Overrides of the energy's parameters; names it does not have are ignored (the
            caller's own checks report them, with better advice).
        d : the Jacobians' size.
        problem, advice : the problem that would collapse and what to do instead, for the message.

        Raises
        ------
        ParameterError
            The density decreases so when the map shrinks, saying which energies to use instead.
        """
        params = self.resolve_params(**{k: v for k, v in (params or {}).items() if k in self.params})
        # one kept program per density (no trace in a warm process) instead of dozens of eager operations;
        # its argument a NumPy array: jnp.array would compile an eager conversion in every process
        values = np.asarray(_density_at_scales(self.density, params, np.array([1.0, 1e-3]), int(d))).tolist()
        at = dict(zip((1.0, 1e-3), values))
        if np.isfinite(at[1e-3]) and at[1e-3] < at[1.0] - 0.5 * abs(at[1.0]):
            raise ParameterError(
                f"energy {self.name!r} decreases when the map shrinks ({at[1e-3]:.3g} at 1/1000 scale vs "
                f"{at[1.0]:.3g} at rest), so {problem} would collapse to a point; {advice}")


@functools.partial(programs_jit, static_argnums=(0, 3))
def _density_at_scales(density, params, scales, d=2):
    """(k,) ``density(s I, params)`` for each scale ``s`` of ``scales`` (k,), I the d x d identity."""
    return jax.vmap(lambda s: density(s * jnp.eye(d), params))(scales)


_DENSITY_RULE = ("a density must be a pure JAX function psi(J, params) of a (d, d) float64 array J "
                 "and a dict of float64 scalars, returning a real float64 scalar (use jax.numpy, "
                 "not numpy, and no Python branching on J's values)")


@float64
@functools.lru_cache(maxsize=256)
def _density_dims(name, density, param_names):
    """``(dims, errors)``: the d in (2, 3) for which ``density`` traces to a float64 scalar, and
    for the others what went wrong.  Raises ParameterError when it works for neither."""
    params = {k: jax.ShapeDtypeStruct((), jnp.float64) for k in param_names}
    errors = {}
    for d in (2, 3):
        try:
            out = jax.eval_shape(density, jax.ShapeDtypeStruct((d, d), jnp.float64), params)
        except Exception as e:  # any failure to trace: wrong signature, numpy on tracers...
            first = (str(e).strip().splitlines() or [""])[0]
            errors[d] = f"{type(e).__name__}: {first[:200]}"
            continue
        if not isinstance(out, jax.ShapeDtypeStruct):
            errors[d] = f"it returned {type(out).__name__} {out!r}, not one array"
        elif out.shape != ():
            errors[d] = f"it returned an array of shape {out.shape}, not a scalar"
        elif out.dtype != jnp.float64:
            errors[d] = f"it returned dtype {out.dtype}, not float64"
        else:
            errors[d] = None
    dims = tuple(d for d in (2, 3) if errors[d] is None)
    if not dims:
        raise ParameterError(
            f"energy {name!r}: invalid density: on a 2x2 J {errors[2]}; on a 3x3 J {errors[3]}; "
            f"{_DENSITY_RULE}")
    return dims, errors


def _finite(name, what, value) -> float:
    if is_traced(value):  # a traced parameter (jax.grad / vmap over it): no value to check
        return value
    # a string or a bool is not a number here, even when float() would take it ("1", True)
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ParameterError(f"energy {name!r}: {what}={value!r} must be a number, not {type(value).__name__}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"energy {name!r}: {what}={value!r} must be a number") from None
    if not math.isfinite(v):
        raise ParameterError(f"energy {name!r}: {what}={value} must be finite")
    return v


def _check_params(name, params) -> dict:
    """``params`` as a dict of finite floats, with ``eps > 0`` and ``lam >= 0``; else ParameterError."""
    try:
        items = dict(params).items()
    except (TypeError, ValueError):
        raise ParameterError(f"energy {name!r}: params must map names to numbers, got {params!r}") from None
    bad = [k for k, _ in items if not isinstance(k, str)]
    if bad:
        raise ParameterError(f"energy {name!r}: parameter names must be strings, got {bad!r}")
    out = {k: _finite(name, f"parameter {k}", v) for k, v in items}
    if "eps" in out and not is_traced(out["eps"]) and not out["eps"] > 0:
        raise ParameterError(f"energy {name!r}: eps={out['eps']} must be > 0 (e.g. 1e-3)")
    if "lam" in out and not is_traced(out["lam"]) and out["lam"] < 0:
        raise ParameterError(f"energy {name!r}: lam={out['lam']} must be >= 0")
    return out


def _library_density(density) -> bool:
    """Whether ``density`` is defined in geomopt itself: every such density is a built-in
    energy's (a row of :data:`geomopt._runtime.names.ENERGIES`), traced for d = 2 and 3 by the
    tests, so constructing its :class:`Energy` does not trace it."""
    return getattr(density, "__module__", "").split(".")[0] == "geomopt"


@functools.lru_cache(maxsize=1)
def _builtin_densities() -> frozenset:
    """The densities of :data:`REGISTRY` (derived from the table, never listed by hand): traced
    for d = 2 and 3 by the tests, so :meth:`Energy.check_dim` does not trace them."""
    return frozenset(e.density for e in REGISTRY.values())


# every built-in density is >= 0 (garanzha given eps > 0 and lam >= 0, which params enforce)
dirichlet = Energy(_d.dirichlet, name="dirichlet", rest_value=lambda d: float(d), lower_bound=0.0)
symmetric_dirichlet = Energy(
    _d.symmetric_dirichlet, barrier=True, name="symmetric_dirichlet", rest_value=lambda d: 2.0 * d,
    lower_bound=0.0,
)
mips = Energy(_d.mips, barrier=True, name="mips", rest_value=lambda d: float(d), lower_bound=0.0)
winslow = Energy(_d.winslow, barrier=True, name="winslow", rest_value=lambda d: float(d),
                 lower_bound=0.0)
arap = Energy(_d.arap, name="arap", rest_value=0.0, lower_bound=0.0)
garanzha = Energy(
    _d.garanzha,
    params={"eps": 1e-3, "lam": 1.0},
    name="garanzha",
    rest_value=None,  # depends on eps and lam
    lower_bound=0.0,
)

#: name -> built-in energy (the names and definitions: geomopt._runtime.names)
REGISTRY: dict[str, Energy] = resolve(_names.ENERGIES)


def energy_spec(energy, where: str = "") -> tuple:
    """A driver's ``energy`` argument as ``(name or Energy, params)``: the one way every driver
    takes an energy with its parameters.

    ``energy`` is a name, an :class:`Energy` (e.g. ``garanzha.with_params(lam=0.1)``), or a pair
    ``(name or Energy, {parameter: value})``, whose values may be traced (they reach the
    objective as parameters, differentiable).  ``where`` names the driver in messages.
    """
    params = {}
    if isinstance(energy, tuple):
        if len(energy) != 2 or not isinstance(energy[1], Mapping):
            raise ParameterError(f"{where}: energy must be a name, an Energy or a pair (name, {{parameter: value}}), "
                                 f"got a tuple of {len(energy)}")
        energy, params = energy[0], dict(energy[1])
    return energy, params


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

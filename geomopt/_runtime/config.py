"""Validation of configuration objects (solvers, line searches, options): one rule per field kind.

Configuration classes are frozen dataclasses; their ``__post_init__`` calls :func:`validate`
with a rule per field, which checks the value, normalises it (``1e3`` -> ``1000`` for an
integer field, NumPy scalars -> Python ones) and raises :class:`ParameterError` naming the
class, the field, the accepted values and what was given.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

from .errors import ParameterError


@dataclasses.dataclass(frozen=True)
class Int:
    """An integer ``>= minimum`` (integral floats such as ``1e3`` are accepted)."""

    minimum: int = 1

    def __call__(self, value):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return None
        if isinstance(value, numbers.Integral):
            v = int(value)
        elif math.isfinite(value) and float(value).is_integer():
            v = int(value)
        else:
            return None
        return v if v >= self.minimum else None

    def __str__(self):
        return f"an integer >= {self.minimum}"


@dataclasses.dataclass(frozen=True)
class Traceable:
    """``rule``, except that a traced JAX value (inside ``jax.grad``, ``jit``, ``vmap``) passes
    unchecked: a differentiable driver checks its concrete value where it runs on the host."""

    rule: object

    def __call__(self, value):
        from .tracing import is_traced

        return value if is_traced(value) else self.rule(value)

    def __str__(self):
        return str(self.rule)


@dataclasses.dataclass(frozen=True)
class Real:
    """A finite real number in ``[lo, hi]``, each end open when ``*_open``."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False

    def __call__(self, value):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return None
        v = float(value)
        if not math.isfinite(v):
            return None
        if v < self.lo or v > self.hi or (self.lo_open and v == self.lo) or (self.hi_open and v == self.hi):
            return None
        return v

    def __str__(self):
        if self.hi == math.inf:
            return f"a finite number {'>' if self.lo_open else '>='} {self.lo:g}"
        return (f"a finite number in {'(' if self.lo_open else '['}{self.lo:g}, "
                f"{self.hi:g}{')' if self.hi_open else ']'}")


@dataclasses.dataclass(frozen=True)
class OneOf:
    """One of the given values (names)."""

    choices: tuple

    def __call__(self, value):
        return value if isinstance(value, str) and value in self.choices else None

    def __str__(self):
        return "one of " + ", ".join(repr(c) for c in self.choices)


@dataclasses.dataclass(frozen=True)
class Instance:
    """An instance of ``cls`` (``bool`` also accepts NumPy booleans)."""

    cls: type

    def __call__(self, value):
        if self.cls is bool:
            return bool(value) if type(value).__name__ in ("bool", "bool_") else None
        return value if isinstance(value, self.cls) else None

    def __str__(self):
        return "True or False" if self.cls is bool else f"a {self.cls.__name__} object"


@dataclasses.dataclass(frozen=True)
class Maybe:
    """None, or a value that ``rule`` accepts."""

    rule: object

    def __call__(self, value):
        return _NONE if value is None else self.rule(value)

    def __str__(self):
        return f"None or {self.rule}"


_NONE = object()  # what Maybe returns for None (validate stores None)


@dataclasses.dataclass(frozen=True)
class Either:
    """A value that ``first`` or, failing it, ``second`` accepts."""

    first: object
    second: object

    def __call__(self, value):
        ok = self.first(value)
        return self.second(value) if ok is None else ok

    def __str__(self):
        return f"{self.first} or {self.second}"


def validate(obj, **rules):
    """Check the fields of the frozen dataclass ``obj``, one rule per named field, and store
    the normalised values; raise :class:`ParameterError` at the first invalid one."""
    owner = type(obj).__name__
    for name, rule in rules.items():
        value = getattr(obj, name)
        ok = rule(value)
        if ok is None:
            raise ParameterError(f"{owner}: {name} must be {rule}, got {value!r}")
        object.__setattr__(obj, name, None if ok is _NONE else ok)


def options_or_default(cls, options, where: str):
    """``options`` (an instance of ``cls``), or ``cls()`` when it is None: a driver's settings.
    Anything else is a one-line :class:`ParameterError` naming the class to pass."""
    if options is None:
        return cls()
    if not isinstance(options, cls):
        raise ParameterError(f"{where}: options must be a {cls.__name__} or None, got {type(options).__name__}")
    return options

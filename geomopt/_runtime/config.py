"""Validation of configuration objects (solvers, line searches, options): one rule per field kind.

Configuration classes are frozen dataclasses; their ``__post_init__`` calls :func:`validate`
with a rule per field, which checks the value, normalises it (``1e3`` -> ``1000`` for an
integer field, NumPy scalars -> Python ones) and raises :class:`ParameterError` naming the
class, the field, the accepted values and what was given.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import warnings

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


def options_from(cls, options, overrides, where, deprecated: bool = True):
    """``options`` (an instance of ``cls`` or None) with ``overrides`` (field names) applied;
    ParameterError naming the unknown keywords.  With ``deprecated`` (a driver's keywords:
    deprecated for one release) a ``DeprecationWarning`` says to pass ``options=cls(...)``."""
    if options is not None and not isinstance(options, cls):
        raise ParameterError(f"{where}: options must be a {cls.__name__} or None, got {type(options).__name__}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ParameterError(f"{where}: unknown keyword argument(s) {unknown}; the options are {sorted(known)}")
    if overrides and deprecated:
        deprecated_call(f"{where}: settings as keywords ({', '.join(sorted(overrides))}) are deprecated and will be "
                        f"removed in the next release: pass options={cls.__name__}(...)")
    return dataclasses.replace(options or cls(), **overrides)


def keyword_only(kept: int, moved: tuple):
    """Decorate a driver whose parameters after the first ``kept`` are keyword-only: for one
    release the old positional ``moved`` (their former order) still work, with a
    ``DeprecationWarning`` naming them.  A name given both ways is a :class:`ParameterError`."""

    def wrap(func):
        @functools.wraps(func)
        def call(*args, **kwargs):
            extra = args[kept:]
            if extra:
                if len(extra) > len(moved):
                    raise ParameterError(f"{func.__name__} takes at most {kept + len(moved)} positional arguments "
                                         f"({kept} from the next release), got {len(args)}")
                names = moved[:len(extra)]
                twice = sorted(set(names) & set(kwargs))
                if twice:
                    raise ParameterError(f"{func.__name__}: {', '.join(twice)} given by position and by keyword")
                deprecated_call(f"{func.__name__}: passing {', '.join(names)} by position is deprecated and will be "
                                f"an error in the next release: pass {names[0]}=... by keyword")
                kwargs.update(zip(names, extra))
            return func(*args[:kept], **kwargs)

        return call

    return wrap


def split_options(cls, options, kwargs: dict, where: str):
    """``(options, rest)``: the deprecated setting keywords in ``kwargs`` that name fields of
    ``cls`` applied to ``options`` (:func:`options_from`, with its warning), the other keywords
    (e.g. deprecated energy parameters) returned for the caller to read."""
    fields = {f.name for f in dataclasses.fields(cls)}
    settings = {k: v for k, v in kwargs.items() if k in fields}
    return options_from(cls, options, settings, where), {k: v for k, v in kwargs.items() if k not in fields}


def deprecated_call(message: str) -> None:
    """A ``DeprecationWarning`` attributed to the first caller outside geomopt (the line of user
    code that used the deprecated form), however deep in geomopt it is found."""
    import os
    import sys

    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
    frame, level = sys._getframe(1), 2
    while frame is not None and frame.f_code.co_filename.startswith(package):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, DeprecationWarning, stacklevel=level)

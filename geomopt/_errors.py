"""The library's own exception types.

Every error geomopt raises on bad input derives from :class:`GeomoptError`, so
callers (and the command line) can catch one type.  Messages say what is wrong
and what to do about it.  Every warning derives from :class:`GeomoptWarning` (the command
line prints each as one ``geomopt: warning: ...`` line).
"""

from __future__ import annotations


class GeomoptError(ValueError):
    """Base class of all errors raised by geomopt on bad input or failed solves."""


class MeshError(GeomoptError):
    """A mesh is malformed: bad shapes, dtypes, indices, non-finite values,
    degenerate or inverted rest elements, or the wrong topology."""


class MeshFormatError(MeshError):
    """A mesh or case file could not be read (missing, empty, malformed, unsupported)."""


class ParameterError(GeomoptError):
    """An energy/solver name or a parameter value is invalid."""


class SolveError(GeomoptError):
    """A solve did not end with a certified (flip-free, converged) result.

    Raised only when the caller asked for it (``throw=True``); carries the result.
    """

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class GeomoptWarning(UserWarning):
    """Base class of geomopt's warnings: a result is returned, but it is not what was asked for."""


class MaxStepsWarning(GeomoptWarning):
    """A solve stopped at its iteration limit (a solver's ``max_steps``, or an outer scheme's
    limit) before converging; its result is returned with outcome ``MAX_STEPS``.  Not issued
    when the caller asked for ``throw=True`` (the :class:`SolveError` says it then)."""

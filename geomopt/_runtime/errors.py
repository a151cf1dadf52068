"""The library's own exception types.

Every error geomopt raises derives from :class:`GeomoptError`, so callers (and the command
line) can catch one type.  Bad input (a malformed mesh or file, an invalid name or value) is
also a ``ValueError`` (:class:`MeshError`, :class:`ParameterError`); a solve that did not
give the certified map asked for is a ``RuntimeError`` (:class:`SolveError`), never a
``ValueError``, so that ``except ValueError`` around input checks does not swallow a failed
solve.  Messages say what is wrong and what to do about it.  Every warning derives from
:class:`GeomoptWarning` (the command line prints each as one ``geomopt: warning: ...`` line).
"""

from __future__ import annotations


class GeomoptError(Exception):
    """Base class of every error geomopt raises: bad input (:class:`MeshError`,
    :class:`ParameterError`), failed solves (:class:`SolveError`), singular factorizations
    (:class:`NotPositiveDefinite`), and files or folders that cannot be written (raised as
    ``GeomoptError`` itself)."""


class MeshError(GeomoptError, ValueError):
    """A mesh is malformed: bad shapes, dtypes, indices, non-finite values,
    degenerate or inverted rest elements, or the wrong topology."""


class MeshFormatError(MeshError):
    """A mesh or case file could not be read (missing, empty, malformed, unsupported)."""


class ParameterError(GeomoptError, ValueError):
    """An energy/solver name or a parameter value is invalid."""


class SolveError(GeomoptError, RuntimeError):
    """A solve, or a certified write, did not give the certified result asked for.

    Raised

    * by a driver (:func:`~geomopt.minimize`, :func:`~geomopt.untangling.untangle`,
      :func:`~geomopt.parameterize` and its bijective mode, :func:`~geomopt.sphere_map`,
      :func:`~geomopt.make_atlas`) called with ``throw=True``, when its result is not
      ``success`` (converged and certified); without ``throw`` the result is returned instead;
    * always, where there is no result to return instead: by the certified writers
      (:func:`geomopt.mesh.cells.write_certified`, :meth:`geomopt.lim.LimCase.write_certified`) when the
      file written does not read back certified (nothing is left at the path), by
      :func:`geomopt.atlas.pack_charts` when no packing certifies, and by the implicit adjoint
      (:mod:`geomopt.objective.adjoint`) when the solve it differentiates did not succeed or its
      derivative is not defined (a saddle, a loose optimum, a gauge under second derivatives;
      under ``jax.jit`` it reaches the caller as JAX's runtime error naming ``SolveError``).

    Attributes
    ----------
    result : the :class:`~geomopt.solvers.Result` that failed (:func:`~geomopt.make_atlas`'s
        too), or None where there is none.
    outcome : ``result.outcome`` (:class:`~geomopt.solvers.Outcome`), or None.
    certificate : the certificate that failed: ``result.certificate``, the written file's, or
        the packing's; None where the failure is not a certificate's (the adjoint).
    """

    def __init__(self, message: str, result=None, *, certificate=None):
        super().__init__(message)
        self.result = result
        self.outcome = getattr(result, "outcome", None)
        self.certificate = getattr(result, "certificate", None) if certificate is None else certificate


class NotPositiveDefinite(GeomoptError, ArithmeticError):
    """A sparse factorization (:class:`geomopt.linalg.linsolve.SparseCholesky`) failed or produced a
    non-finite solution: the matrix is not positive definite (or not finite)."""


class GeomoptWarning(UserWarning):
    """Base class of geomopt's warnings: a result is returned, but it is not what was asked for."""


class MaxStepsWarning(GeomoptWarning):
    """A solve stopped at its iteration limit (a solver's ``max_steps``, or an outer scheme's
    limit) before converging; its result is returned with outcome ``MAX_STEPS``.  Not issued
    when the caller asked for ``throw=True`` (the :class:`SolveError` says it then)."""

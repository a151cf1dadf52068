"""Intel oneMKL PARDISO for symmetric positive-definite matrices, called directly.

The ``py-mkl-pardiso`` wheel links MKL's PARDISO statically and exports its 64-bit-index entry
point ``PARDISO_64``; :class:`Pardiso` calls it through ``ctypes`` instead of the wheel's
Python class, for two reasons measured at 10^6 triangles (996,872 rows, 7.5M entries):

* no copies: the class keeps its own int64 pattern and float64 values beside the caller's
  (0.12-0.18 GB); here PARDISO reads the caller's arrays, kept alive by this object;
* single precision (``iparm[27] = 1``, which the class refuses): the numeric factor in float32
  takes half the memory (885 -> ~440 MB) and less time.  Its solves are accurate to float32
  only: :class:`Refined` refines them in float64 against the float64 matrix, using the single-precision factor as the preconditioner of conjugate
  gradients (mixed-precision refinement).

Indices are zero-based (``iparm[34] = 1``); the pattern is the upper triangle in CSR, i.e. the
lower triangle in CSC.  ``ctypes`` releases the GIL during the calls.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np
import scipy.sparse as sp

from .._runtime.errors import NotPositiveDefinite
from .krylov import pcg, symmetric_product

__all__ = ["Pardiso", "Refined", "WheelPardiso", "available", "entry_point", "handle"]

_MTYPE_SPD = 2
_MESSAGES = {-1: "input inconsistent", -2: "not enough memory", -3: "reordering problem",
             -4: "zero or negative pivot: not positive definite", -5: "unclassified (internal) error",
             -6: "preordering failed", -7: "diagonal matrix is singular", -8: "32-bit integer overflow"}


@functools.cache
def entry_point():
    """``PARDISO_64`` of the installed py-mkl-pardiso wheel, or None when there is none."""
    try:
        from pymklpardiso import _mkl_pardiso
        fn = ctypes.CDLL(_mkl_pardiso.__file__).PARDISO_64
    except (ImportError, OSError, AttributeError):
        return None
    fn.restype = None
    fn.argtypes = [ctypes.c_void_p] * 16
    return fn


#: what :class:`WheelPardiso` calls on py-mkl-pardiso's (private) ``_mkl_pardiso.PardisoSolver``,
#: tested with py-mkl-pardiso 0.0.6
WHEEL_API = ("set_iparm", "set_pattern", "run_phase", "refactor_values", "solve", "release")


def _wheel_solver():
    """py-mkl-pardiso's own Python class when it offers :data:`WHEEL_API`, else None."""
    try:
        from pymklpardiso._mkl_pardiso import PardisoSolver
    except Exception:  # noqa: BLE001 -- not installed, or its layout changed
        return None
    return PardisoSolver if all(callable(getattr(PardisoSolver, n, None)) for n in WHEEL_API) else None


def available() -> bool:
    """Whether PARDISO can be called here: directly, or through the wheel's own class."""
    return entry_point() is not None or _wheel_solver() is not None


def handle(indptr, indices, ordering: str = "metis", single: bool = False):
    """A PARDISO handle for the pattern: :class:`Refined` (``single``) or :class:`Pardiso`
    where the library exports ``PARDISO_64``; else :class:`WheelPardiso` (float64 only)."""
    if entry_point() is None:
        return WheelPardiso(indptr, indices, ordering)
    return Refined(indptr, indices, ordering) if single else Pardiso(indptr, indices, ordering)


def _ptr(a):
    return None if a is None else a.ctypes.data_as(ctypes.c_void_p)


class Pardiso:
    """One PARDISO handle: the symbolic analysis of a pattern, then numeric factorizations of
    values on it and solves.

    Parameters
    ----------
    indptr, indices : the CSC pattern of the lower triangle (sorted row indices per column);
        copied once to int64 (PARDISO_64's index type) and kept.
    ordering : ``"metis"`` (nested dissection) or ``"amd"`` (minimum degree).
    single : factor and solve in float32 (half the factor's memory; see the module docstring).
    """

    def __init__(self, indptr, indices, ordering: str = "metis", single: bool = False):
        self._call = entry_point()
        if self._call is None:
            raise RuntimeError("PARDISO is not available: pip install py-mkl-pardiso (Linux/Windows x86-64)")
        self.ia = np.ascontiguousarray(indptr, dtype=np.int64)
        self.ja = np.ascontiguousarray(indices, dtype=np.int64)
        self.n = len(self.ia) - 1
        self.single = bool(single)
        self.dtype = np.float32 if single else np.float64
        self._pt = np.zeros(64, np.int64)  # PARDISO's internal handle: must start zeroed
        self._iparm = np.zeros(64, np.int64)
        self._iparm[0] = 1  # iparm given here; zeros elsewhere mean MKL's defaults
        self._iparm[1] = 2 if ordering == "metis" else 0
        self._iparm[27] = 1 if single else 0
        self._iparm[34] = 1  # zero-based indices
        self._values = None  # the values factored last, read again by the solves
        self._live = False

    def _run(self, phase, a=None, b=None, x=None, nrhs=1):
        ints = np.array([1, 1, _MTYPE_SPD, phase, self.n, nrhs, 0, 0], np.int64)  # maxfct .. msglvl, error
        p = [_ptr(ints[i:i + 1]) for i in range(8)]
        self._call(_ptr(self._pt), p[0], p[1], p[2], p[3], p[4], _ptr(a), _ptr(self.ia), _ptr(self.ja),
                   None, p[5], _ptr(self._iparm), p[6], _ptr(b), _ptr(x), p[7])
        return int(ints[7])

    def analyze(self):
        """Phase 11: the fill-reducing ordering and the symbolic factorization."""
        self._live = True
        error = self._run(11, a=np.zeros(len(self.ja), self.dtype))
        if error:
            raise RuntimeError(f"PARDISO analysis failed: {_MESSAGES.get(error, error)}")

    def factor(self, data):
        """Phase 22 on the values ``data`` (nnz,), converted to this handle's precision and
        kept for the solves.  Raises NotPositiveDefinite (or MemoryError) on failure."""
        self._values = None
        values = np.ascontiguousarray(data, dtype=self.dtype)
        error = self._run(22, a=values)
        if error == -2:
            raise MemoryError("PARDISO: not enough memory for the factorization")
        if error:
            raise NotPositiveDefinite(f"PARDISO factorization failed: {_MESSAGES.get(error, error)}")
        self._values = values

    def solve(self, b, rtol=None):
        """Phase 33: ``A^-1 b`` for ``b`` (n,) or (n, k), in this handle's precision (``rtol``
        unused: a direct solve)."""
        B = np.ascontiguousarray(np.asarray(b).T, dtype=self.dtype)  # column-major right-hand sides
        X = np.empty_like(B)
        error = self._run(33, a=self._values, b=B, x=X, nrhs=1 if B.ndim == 1 else B.shape[0])
        if error:
            raise RuntimeError(f"PARDISO solve failed: {_MESSAGES.get(error, error)}")
        return X.T

    def precondition(self, b):
        return self.solve(b)

    @property
    def factor_bytes(self) -> int:
        """The numeric factor's memory as PARDISO reports it (``iparm[16]``, after a factor)."""
        return int(self._iparm[16]) * 1024

    def free_factor(self):
        """Phase 0: free the numeric factor, keep the symbolic analysis (the next
        :meth:`factor` allocates it again)."""
        self._values = None
        if self._live:
            self._run(0)

    def release(self):
        """Phase -1: free PARDISO's memory for this handle (analysis and factor)."""
        if self._live:
            self._live = False
            self._values = None
            self._run(-1)

    def __del__(self):
        try:
            self.release()
        except Exception:  # noqa: BLE001 -- at interpreter exit the library may be gone
            pass


#: conjugate-gradient iterations of a refinement (measured at 10^6 triangles: 1-4 to 1e-10)
REFINE_ITERS = 40


class Refined:
    """A float32 PARDISO factorization refined in float64: the solves of the float64 matrix by
    conjugate gradients preconditioned with the float32 factor (at 10^6 triangles the factor
    885 -> 453 MB and 3.3 -> 1.9 s; the raw solve's relative residual 3e-3, refined to 1e-10
    in 3 iterations).  Same calls as :class:`Pardiso`; :meth:`solve` raises NotPositiveDefinite
    where conjugate gradients meet non-positive curvature or do not converge (a matrix
    indefinite or too ill-conditioned for this precision).

    The values given to :meth:`factor` are kept by reference (the refinement's matrix): the
    caller must not change them while it solves with this factorization."""

    def __init__(self, indptr, indices, ordering: str = "metis"):
        self._low = Pardiso(indptr, indices, ordering, single=True)
        self.n = self._low.n
        self._matvec = None
        self.iterations = 0  # of the last solve's conjugate gradients
        ia, ja = self._low.ia, self._low.ja  # the most entries in a row of the full matrix
        self._row_entries = int((np.diff(ia) + np.bincount(ja, minlength=self.n) - 1).max(initial=0))

    def analyze(self):
        self._low.analyze()

    def factor(self, data):
        self._matvec = None
        data = np.ascontiguousarray(data, dtype=np.float64)
        # no retry with a shift where float32 pivots fail: the matrices that fail here (an
        # indefinite exact Hessian) fail in float64 too, and a shifted factor then only makes
        # conjugate gradients run to their limit (6 s at 10^6 triangles) before failing
        self._low.factor(data)
        L = sp.csc_matrix((data, self._low.ja, self._low.ia), shape=(self.n, self.n))
        # a bound on |A|'s largest row sum without a copy of the values (at 10^6 triangles 60 MB
        # in the factor's phase): |a_ij| <= sqrt(a_ii a_jj) <= max a_ii in a positive-definite
        # matrix; the float64 residual of any x is only known to ~eps |A| |x|
        self._norm = float(data[self._low.ia[:-1]].max(initial=0.0)) * self._row_entries  # diagonal first
        self._matvec = symmetric_product(L)  # the refinement's matrix, holding data

    def free_factor(self):
        self._matvec = None
        self._low.free_factor()

    @property
    def factor_bytes(self) -> int:
        return self._low.factor_bytes

    def forget_values(self):
        """Drop the reference to the factored values: :meth:`precondition` still works,
        :meth:`solve` needs a new :meth:`factor`."""
        self._matvec = None

    def precondition(self, b):
        """The float32 factor's solve, unrefined (a preconditioner)."""
        return self._low.solve(b).astype(np.float64)

    def solve(self, b, rtol: float = 1e-10):
        """``A^-1 b`` to ``|b - A x| <= rtol |b|`` (per column of a 2D ``b``), or to the
        residual float64 can tell (``64 eps |A| |x|``) where that is larger: the accuracy of a
        float64 factorization's solve."""
        if self._matvec is None:
            raise RuntimeError("no factored values held (forgotten, or the last factor failed): factor again")
        b = np.asarray(b, dtype=np.float64)
        if b.ndim == 2:
            return np.stack([self.solve(col, rtol) for col in b.T], axis=1)
        x, r, goal, self.iterations = np.zeros_like(b), b, rtol * float(np.linalg.norm(b)), 0
        # the recurrence's residual drifts from the true one where |x| >> |b| (ill-conditioned):
        # restart from the true residual until it, too, meets the tolerance
        while self.iterations < REFINE_ITERS:
            dx, iterations = pcg(self._matvec, r, self.precondition, goal / max(float(np.linalg.norm(r)), 1e-300),
                                 REFINE_ITERS - self.iterations)
            self.iterations += iterations
            if dx is None:
                break
            x += dx
            r = b - self._matvec(x)
            if float(np.linalg.norm(r)) <= max(goal, 64 * np.finfo(float).eps * self._norm * float(np.linalg.norm(x))):
                return x
        raise NotPositiveDefinite(f"float32 factorization refined in float64: no convergence in {self.iterations} "
                                  f"conjugate-gradient iterations (indefinite or too ill-conditioned)")

    def release(self):
        self._matvec = None
        self._low.release()


class WheelPardiso:
    """:class:`Pardiso`'s calls (float64 only) through py-mkl-pardiso's own Python class, for a
    build of the wheel whose library does not export ``PARDISO_64`` (a DLL exports only what
    it declares).  It keeps its own copies of the pattern and values."""

    single = False

    def __init__(self, indptr, indices, ordering: str = "metis"):
        from pymklpardiso import MTYPE_REAL_SYM_POSDEF

        self._solver = _wheel_solver()(MTYPE_REAL_SYM_POSDEF, 0)
        self._solver.set_iparm(1, 2 if ordering == "metis" else 0)
        self._pattern = (np.asarray(indptr, np.int64), np.asarray(indices, np.int64))
        self.n = len(indptr) - 1

    def analyze(self):
        ia, ja = self._pattern
        self._solver.set_pattern(ia=ia, ja=ja, n=self.n)
        self._solver.run_phase(11)

    def factor(self, data):
        try:
            self._solver.refactor_values(np.ascontiguousarray(data, dtype=np.float64))
        except RuntimeError as exc:  # zero or negative pivot: not positive definite
            raise NotPositiveDefinite(str(exc)) from exc

    def solve(self, b, rtol=None):
        return self._solver.solve(np.ascontiguousarray(b, dtype=np.float64))

    def precondition(self, b):
        return self.solve(b)

    @property
    def factor_bytes(self) -> int:
        return int(self._solver.get_iparm()[16]) * 1024

    def free_factor(self):
        """Nothing: the class has no call that frees the factor alone (:meth:`release` frees all)."""

    def release(self):
        self._solver.release()

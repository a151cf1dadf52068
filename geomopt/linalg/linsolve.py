"""Sparse symmetric positive-definite solves for Newton steps, with a fixed pattern.

Backends (chosen by measurement: factor + solve with the analysis reused, on the Hessians of
the shared meshes; table in benchmarks/README.md):

* ``pardiso``  — Intel oneMKL PARDISO through the self-contained ``py-mkl-pardiso`` wheel (a
  default dependency on Linux/Windows x86-64; no system libraries or headers).  The symbolic
  analysis (fill-reducing ordering) is computed once per pattern and reused for every numeric
  factorization.  Measured fastest, ahead of CHOLMOD.
* ``cholmod``  — CHOLMOD through scikit-sparse, when importable (needs SuiteSparse headers:
  ``pip install ".[cholmod]"``); the analysis is reused too.
* ``cholespy`` — a self-contained supernodal Cholesky wheel (the fallback where no PARDISO
  wheel exists, e.g. macOS arm64); it repeats the analysis at every factorization.
* ``superlu``  — SciPy's SuperLU, the always-available last resort.

``auto`` picks the first available in that order.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading

import numpy as np
import scipy.sparse as sp

from .._runtime.errors import NotPositiveDefinite, ParameterError
from .._runtime.threads import usable_cores
from .krylov import pcg
from . import pardiso

__all__ = [
    "SparseCholesky", "NotPositiveDefinite", "available_backends", "repeated_solves_backend", "PARDISO_3D_FROM",
    "newton_linear_solver", "pcg", "spd_solve",
    "BACKENDS",
    "CG_FROM_DOFS", "SINGLE_FROM_ROWS",
]

BACKENDS = ("auto", "pardiso", "cholmod", "cholespy", "superlu")

#: rows from which a Newton Hessian's PARDISO factorization is made in float32 and refined in
#: float64 (:class:`SparseCholesky` ``single``; measured in benchmarks/README, "Newton at 10^6
#: in less memory"): half the factor's memory and less time where the factor dominates both
SINGLE_FROM_ROWS = 250_000


def _c_fflush():
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except Exception:  # pragma: no cover - no C library to flush
        pass


@contextlib.contextmanager
def _silence_c_output():
    """Mute what C code writes to file descriptors 1 and 2: cholespy prints a CHOLMOD warning
    for every indefinite matrix, which the adaptive Newton tries on purpose."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
    except (OSError, ValueError, AttributeError):  # no real descriptors: nothing to mute
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        _c_fflush()  # C stdio buffers the message: drop it while still muted
        for fd, copy in zip((1, 2), saved):
            os.dup2(copy, fd)
            os.close(copy)


@functools.cache  # a missing module is looked for on every import attempt (1.5 ms each)
def _have(module):
    try:
        __import__(module)
        return True
    except Exception:  # pragma: no cover - depends on the machine
        return False


def _have_pardiso():
    return pardiso.available()


def available_backends():
    """Installed backends, fastest first (the order ``auto`` uses).  PARDISO counts only when
    py-mkl-pardiso offers the calls geomopt makes (:data:`PARDISO_API`)."""
    out = []
    if _have_pardiso():
        out.append("pardiso")
    if _have("sksparse.cholmod"):
        out.append("cholmod")
    if _have("cholespy"):
        out.append("cholespy")
    out.append("superlu")
    return out


#: vertices (rows per coordinate) from which a 3D Laplacian solved many times is factored by
#: PARDISO rather than cholespy (see :func:`repeated_solves_backend`)
PARDISO_3D_FROM = 20_000
#: rows per coordinate from which a 2D Laplacian solved many times goes to PARDISO, one handle
#: per coordinate on its own core (see :func:`repeated_solves_backend`)
PARDISO_2D_FROM = 30_000


def repeated_solves_backend(dim: int = 2, n: int = 0) -> str:
    """The installed backend for a matrix factored once and solved many times (the Laplacian
    seed of L-BFGS, a solve per iteration), ``n`` rows per coordinate in ``dim`` dimensions.

    Below :data:`PARDISO_3D_FROM` rows in 3D, and in 2D, the fastest solves once factored.
    Measured, cotangent Laplacians (solve with d right-hand sides / factor, seconds): 67k
    vertices in the plane: cholespy 0.0079 / 0.375, PARDISO 0.0145 / 0.192, SuperLU 0.0134 /
    0.348; 12k in space: 0.0036 / 0.207, 0.0054 / 0.072, 0.0059 / 0.166 -- PARDISO factors
    fastest (the Newton order, :func:`available_backends`) but its solves cost the most.

    From :data:`PARDISO_3D_FROM` rows in 3D, PARDISO (nested dissection): cholespy's ordering
    fills in far more there and its factorization outgrows hundreds of solves (factor / solve
    with 3 right-hand sides, cholespy -> PARDISO): the corner Laplacian of 46^3 hexahedra
    (91k rows) 38.1 / 0.080 -> 3.6 / 0.121, of 30^3 (24k) 2.27 / 0.014 -> 0.42 / 0.020, a hex
    rod of 20 x 20 x 240 (86k) 8.3 / 0.065 -> 1.6 / 0.078; a box of 83k tetrahedra (12k rows)
    0.51 / 0.0052 -> 0.12 / 0.0072 stays with cholespy.

    From :data:`PARDISO_2D_FROM` rows in 2D, on two or more cores and where PARDISO is called
    directly, PARDISO too: the seed then factors each coordinate's copy on its own handle in
    float32 and solves the two at once on two threads (PARDISO's solves are sequential; see
    L-BFGS's seed in :mod:`geomopt.solvers`).  Measured, disk Laplacians, factor / solve of both
    coordinates, cholespy -> two float32 PARDISO handles: 19k rows 0.079 s / 0.90 ms -> 0.064 /
    1.74, 30k 0.150 / 2.05 -> 0.109 / 1.60, 67k 0.39 / 8.2 -> 0.23 / 4.3, 251k 2.15 / 38.2 ->
    0.99 / 20.4, 498k 6.4 / 82 -> 2.1 / 42."""
    installed = available_backends()
    split_2d = dim == 2 and n >= PARDISO_2D_FROM and usable_cores() >= 2 and pardiso.entry_point() is not None
    order = ("cholmod", "pardiso", "cholespy", "superlu") if (dim == 3 and n >= PARDISO_3D_FROM) or split_2d else \
        ("cholmod", "cholespy", "pardiso", "superlu")
    return next(b for b in order if b in installed)


def _check_lower_pattern(indptr, indices) -> None:
    """Refuse (ValueError) what is not a lower-triangle CSC pattern with every diagonal entry
    first in its column: the C libraries read such a pattern out of bounds (a column of a vertex
    that no element uses crashed the process in PARDISO's analysis), so it must never reach them."""
    n = len(indptr) - 1
    if n < 0 or indptr[0] != 0 or indptr[-1] != len(indices) or (np.diff(indptr) < 0).any():
        raise ValueError(f"sparse pattern: column pointers must rise from 0 to {len(indices)} entries")
    if n and (np.diff(indptr) == 0).any():
        j = int(np.flatnonzero(np.diff(indptr) == 0)[0])
        raise ValueError(f"sparse pattern: column {j} is empty (a DOF no element couples); every column needs "
                         f"its diagonal entry")
    if n and (indices[indptr[:-1]] != np.arange(n)).any():
        j = int(np.flatnonzero(indices[indptr[:-1]] != np.arange(n))[0])
        raise ValueError(f"sparse pattern: column {j} does not start with its diagonal entry (a lower triangle "
                         f"with sorted rows is expected)")
    if len(indices) and (indices.max() >= n or indices.min() < 0):
        raise ValueError(f"sparse pattern: a row index outside 0..{n - 1}")


class _Background(threading.Thread):
    """``fn()`` run in a daemon thread from construction; :meth:`result` joins it and raises
    what it raised."""

    def __init__(self, fn):
        super().__init__(daemon=True)
        self.fn, self.error = fn, None
        self.start()

    def run(self):
        try:
            self.fn()
        except BaseException as exc:  # noqa: BLE001 -- handed to the thread that waits
            self.error = exc

    def result(self):
        self.join()
        if self.error is not None:
            raise self.error


class SparseCholesky:
    """Factor symmetric positive-definite matrices sharing one CSC pattern (lower triangle), then
    solve.

    Parameters
    ----------
    indptr, indices : the CSC pattern of the lower triangle (sorted row indices per column).
    backend : one of ``BACKENDS``.
    ordering : the fill-reducing ordering of the backends that reuse their analysis (PARDISO,
        CHOLMOD): ``"metis"`` (nested dissection: 2x less factorization time than minimum degree
        on Newton's Hessians from 10^5 DOFs) or ``"amd"`` (minimum degree: an analysis 2-3x
        faster; for a 2D Laplacian factored once below ~3 x 10^5 rows: 11k rows 0.019 s against
        0.044 s analysis, factor and solve, 100k 0.44 against 0.61 s, 10^6 11.4 against 9.9 s;
        in 3D nested dissection wins from 30k rows: 0.44 against 0.63 s).
    single : PARDISO only (ignored by the other backends): factor in float32 and refine each
        solve in float64 (:class:`geomopt.linalg.pardiso.Refined`: half the factor's memory);
        the values given to :meth:`factor` are then kept by reference and must not change
        while this factorization is used.

    Attributes
    ----------
    generation : int, counts the numeric factorizations: a caller that keeps the matrix it
        factored can tell whether the factor still is of that matrix (another caller sharing the
        symbolic analysis may have refactored it since) and refactor before solving.
    """

    def __init__(self, indptr, indices, backend="auto", ordering="metis", single=False):
        if backend not in BACKENDS:
            raise ParameterError(f"unknown linear solver {backend!r}; valid: {', '.join(BACKENDS)}")
        if ordering not in ("metis", "amd"):
            raise ParameterError(f"unknown ordering {ordering!r}; valid: metis, amd")
        self.ordering = ordering
        if backend == "auto":
            backend = available_backends()[0]
        elif backend not in available_backends():
            raise ParameterError(
                f"linear solver {backend!r} is not installed here; available: {', '.join(available_backends())}"
            )
        self.backend = backend
        # float32 only where PARDISO is called directly (pardiso.handle)
        self.single = bool(single) and backend == "pardiso" and pardiso.entry_point() is not None
        # int32 indices are kept as given (a pattern's, shared: no copy); a PARDISO handle keeps
        # the int64 copies PARDISO_64 reads
        it = np.int32 if np.asarray(indptr).dtype == np.asarray(indices).dtype == np.int32 else np.int64
        self.indptr = np.asarray(indptr, it)
        self.indices = np.asarray(indices, it)
        self.n = len(indptr) - 1
        _check_lower_pattern(self.indptr, self.indices)
        self._analysis = None
        self._pending = None  # the analysis's thread while it runs in the background
        self._factor = None
        self.generation = 0
        if backend == "cholespy":
            self._ip32 = self.indptr.astype(np.int32, copy=False)
            self._ix32 = self.indices.astype(np.int32, copy=False)

    @classmethod
    def factored(cls, A, backend="auto", ordering="metis", single=False) -> "SparseCholesky":
        """The factorization of the symmetric positive-definite sparse matrix ``A`` (n, n), from
        its lower triangle (``single``: as the constructor's).  Raises :class:`NotPositiveDefinite`
        when it is not."""
        L = sp.tril(A).tocsc()
        L.sort_indices()
        chol = cls(L.indptr, L.indices, backend, ordering, single)
        chol.factor(L.data)
        return chol

    def _csc(self, data):
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))

    def analyze(self, background=False):
        """Symbolic analysis (fill-reducing ordering) of the pattern, for backends that reuse it.
        ``background``: PARDISO's runs in a thread (it releases the GIL) while the caller goes on
        (e.g. loads its kernels: camelhead's Newton set-up 0.20 -> 0.15-0.17 s); the first
        :meth:`factor` waits for it and raises what it raised."""
        if self.n == 0:  # no free DOF (every vertex a handle): nothing to factor, backends refuse n=0
            return
        if background and self.backend == "pardiso" and self._analysis is None and self._pending is None:
            self._pending = _Background(self.analyze)
            return
        if self._pending is not None and self._pending is not threading.current_thread():
            pending, self._pending = self._pending, None
            pending.result()
        if self.backend == "pardiso" and self._analysis is None:
            solver = pardiso.handle(self.indptr, self.indices, self.ordering, self.single)
            solver.analyze()
            self._analysis = solver
        if self.backend == "cholmod" and self._analysis is None:
            from sksparse.cholmod import analyze

            A = self._csc(np.ones(len(self.indices)))
            self._analysis = analyze(A, mode="supernodal", ordering_method=self.ordering)

    @property
    def has_factor(self) -> bool:
        """Whether a factorization is held: the last :meth:`factor` succeeded (a failed one
        leaves none: PARDISO's and CHOLMOD's factors are overwritten in place by the attempt)."""
        return self._factor is not None or (self.n == 0 and self.generation > 0)

    def factor(self, data):
        """Numeric factorization of the matrix with values ``data`` (nnz,) (replaces the previous
        one: :attr:`generation` counts them; when it raises, no factorization is held)."""
        self.generation += 1
        self._factor = None
        data = np.ascontiguousarray(data, dtype=np.float64)
        if data.shape != self.indices.shape:  # the C libraries would read past it: a crash, not an error
            raise ValueError(f"SparseCholesky.factor: {data.shape[0] if data.ndim == 1 else data.shape} values for a "
                             f"pattern of {self.indices.size} entries")
        if not np.isfinite(data).all():
            raise NotPositiveDefinite("matrix has non-finite entries")
        if self.n == 0:
            self._factor = None
            return
        if self.backend == "pardiso":
            self.analyze()
            self._analysis.factor(data)  # raises NotPositiveDefinite
            self._factor = self._analysis
        elif self.backend == "cholmod":
            from sksparse.cholmod import CholmodError

            self.analyze()
            try:
                self._analysis.cholesky_inplace(self._csc(data))
            except CholmodError as exc:
                raise NotPositiveDefinite(str(exc)) from exc
            self._factor = self._analysis
        elif self.backend == "cholespy":
            from cholespy import CholeskySolverD, MatrixType

            try:
                with _silence_c_output():
                    self._factor = CholeskySolverD(self.n, self._ip32, self._ix32, data, MatrixType.CSC)
            except (RuntimeError, ValueError) as exc:
                raise NotPositiveDefinite(str(exc)) from exc
        else:
            L = self._csc(data)
            try:
                import scipy.sparse.linalg as spla  # the fallback only: 0.1 s of import

                self._factor = spla.splu((L + L.T - sp.diags(L.diagonal())).tocsc(), permc_spec="MMD_AT_PLUS_A",
                                         diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            except RuntimeError as exc:
                raise NotPositiveDefinite(str(exc)) from exc

    def solve(self, b, rtol: float = 1e-10):
        """``A^-1 b`` for ``b`` (n,) or (n, k).  ``rtol``: the relative residual a float32
        factorization (``single``) is refined to; the other solves are direct.  Raises
        NotPositiveDefinite where a refinement does not converge."""
        b = np.ascontiguousarray(b, dtype=np.float64)
        if b.ndim not in (1, 2) or b.shape[0] != self.n:  # the C libraries would read and write past it
            raise ValueError(f"SparseCholesky.solve: right-hand side of shape {b.shape} for {self.n} unknowns")
        if self.n == 0:
            return np.zeros_like(b)
        if self._factor is None:
            raise RuntimeError("SparseCholesky.solve: no factorization held (none made yet, or the last factor() "
                               "failed): factor the matrix first")
        if self.backend == "pardiso":
            x = self._factor.solve(b, rtol)
        elif self.backend == "cholespy":
            x = np.empty_like(b)
            self._factor.solve(b, x)
        elif self.backend == "cholmod":
            x = self._factor(b)
        else:
            x = self._factor.solve(b)
        if not np.isfinite(x).all():
            raise NotPositiveDefinite("solve produced non-finite values")
        return x

    def free_factor(self):
        """Free the numeric factor and keep the symbolic analysis (PARDISO; the other backends
        drop their factor object): a finished solve's factor is not reused, while the analysis
        is the costly part to redo (at 10^6 triangles: 0.45 GB of float32 factor freed, 0.6 GB
        of analysis kept).  Counts as a new :attr:`generation`: a holder refactors."""
        self.generation += 1
        if self.backend == "pardiso" and self._analysis is not None and self._pending is None:
            self._analysis.free_factor()
        if self.backend != "cholmod":  # CHOLMOD's factor is its analysis object: kept
            self._factor = None

    def forget_values(self):
        """Drop the values a float32 factorization (``single``) keeps for refining its solves
        (at 10^6 triangles 60 MB, which a Newton step's next Hessian need not sit on):
        :meth:`precondition` still works; :meth:`solve` needs a new :meth:`factor`.  A no-op
        for the other factorizations."""
        if self.single and self._factor is not None:
            self._factor.forget_values()

    @property
    def refinements(self) -> int:
        """Conjugate-gradient iterations of the last :meth:`solve` of a float32 factorization
        (``single``); 0 for a direct solve."""
        return self._factor.iterations if self.single and self._factor is not None else 0

    def precondition(self, b):
        """An approximate ``A^-1 b``, for preconditioning: a float32 factor's raw solve
        (``single``), else :meth:`solve`."""
        if self.backend == "pardiso" and self._factor is not None:
            return self._factor.precondition(np.ascontiguousarray(b, dtype=np.float64))
        return self.solve(b)


def spd_solve(A, rhs):
    """``A^-1 rhs`` for a sparse symmetric positive-definite ``A`` (n, n) factored once, by the
    ordering that analyses faster at its size (:class:`SparseCholesky`: minimum degree below
    300,000 rows, nested dissection above).  Raises :class:`NotPositiveDefinite` when it is not."""
    return SparseCholesky.factored(A, ordering="amd" if A.shape[0] < 300_000 else "metis").solve(rhs)


#: Free DOFs from which ``Newton(linear_solver="auto")`` takes the CG direction on the CPU,
#: per dimension (None: never); see :func:`newton_linear_solver`.
CG_FROM_DOFS = {2: None, 3: 8_000}


def newton_linear_solver(dim: int, n_free: int, platform: str = "cpu") -> str:
    """How :class:`~geomopt.solvers.Newton` (``linear_solver="auto"``) makes its direction:
    ``"cg"`` (:class:`geomopt.objective.cg.NewtonCG`, in JAX) or ``"direct"`` (:class:`SparseCholesky`).

    Parameters
    ----------
    dim : 2 (triangles) or 3 (tets).
    n_free : free DOFs.
    platform : JAX's backend name.

    Notes
    -----
    The rule, by measurement: CPU seconds (all threads) of warm projected-Newton solves to
    convergence (clamp, symmetric Dirichlet, the swirled grids of ``benchmarks/scale.py``,
    PARDISO with METIS vs CG with Newton's forcing term ``eta_max=0.01``; same Newton
    iteration counts), 2-core machine at load 6-10, 2026-11-22:

    | mesh        | free DOFs | direct | CG   |
    |-------------|-----------|--------|------|
    | 10^4 tris   | 9.8k      | 0.21   | 0.18 |
    | 10^5 tris   | 99k       | 1.61   | 2.92 |
    | 10^4 tets   | 4.0k      | 0.48   | 0.44 |
    | 2x10^4 tets | 8.2k      | 1.11   | 0.87 |
    | 3x10^4 tets | 12k       | 1.62   | 1.27 |
    | 10^5 tets   | 47k       | 9.73   | 4.55 |

    (untangling the twisted 2x10^4-tet box with ``solver="newton"``: 3.7 s direct, 2.9 s CG,
    same 15 inner iterations.)  Hence:

    * off the CPU: ``"cg"`` (the direct step copies the Hessian to the host; not measured on
      a GPU here);
    * triangles: ``"direct"`` at every size: a 2D factorization grows like n^1.5 (10^6
      triangles, 10^6 DOFs: 2.2 s, beside 0.6 s for the Hessian) while CG's iterations grow
      with the condition number (hundreds at 10^5 DOFs);
    * tets: ``"cg"`` from ``CG_FROM_DOFS[3]`` = 8,000 free DOFs (3D fill makes the
      factorization grow like n^2; block-Jacobi CG needs tens of iterations there and costs
      about one Hessian evaluation).

    Measured on well-shaped meshes; CG's iteration limit (:class:`geomopt.objective.cg.NewtonCG`
    ``max_iters``) bounds a badly conditioned step, whose truncated direction is still a
    descent direction; pass a Cholesky backend explicitly to get the exact step.
    """
    if platform != "cpu":
        return "cg"
    limit = CG_FROM_DOFS.get(int(dim))
    return "cg" if limit is not None and n_free >= limit else "direct"

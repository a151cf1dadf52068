"""The rest Dirichlet Laplacian ``K`` of a problem: L-BFGS's Sobolev seed and AQP's proxy
(Kovalsky et al. 2016).

Two ways to apply ``K^-1`` from jitted code (:func:`laplacian_solve`):

* ``"host"``: ``K`` factored once by :class:`~geomopt.linalg.linsolve.SparseCholesky` and applied on
  the host through an XLA FFI target (:mod:`geomopt._runtime.hostcall`, by an integer handle; unlike
  ``jax.pure_callback`` it leaves the calling programs cacheable).  Exact to float64, or to
  float32 where PARDISO factors it (:func:`_seed_factor`: a seed needs no more, and PARDISO's
  solves then read half the bytes); the CPU default.
* ``"device"``: ``K`` kept as a sparse operator in JAX (:class:`LaplacianOperator`) and applied
  by Jacobi-preconditioned conjugate gradients warm-started from the previous solution, so a
  loop on an accelerator makes no host round trip.  Approximate (to ``rtol``); the default on
  GPU/TPU backends.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import os
import weakref
from concurrent.futures import ThreadPoolExecutor, wait

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .._runtime import hostcall as _hostcall
from .._runtime.errors import ParameterError
from .._runtime.threads import usable_cores
from ..linalg import pardiso
from ..linalg.linsolve import NotPositiveDefinite, SparseCholesky, repeated_solves_backend
from .._runtime.x64 import pure_callback

#: where K^-1 is applied: see the module docstring
LAPLACIAN_BACKENDS = ("auto", "host", "device")


_LIVE_PRECONDITIONERS: "weakref.WeakValueDictionary[int, RestLaplacian]" = \
    weakref.WeakValueDictionary()
_NEXT_HANDLE = itertools.count()
#: the live RestLaplacians by (id of their objective, backend, settings): see RestLaplacian.register
_BY_OBJECTIVE: "weakref.WeakValueDictionary[tuple, RestLaplacian]" = weakref.WeakValueDictionary()


def rest_laplacian(problem) -> sp.csc_matrix:
    """(n, n) ``K = sum_e 2 vol_e G_e G_e^T``: the Hessian of the rest Dirichlet energy
    ``sum_e vol_e |J_e|^2`` with respect to one coordinate of the vertices (all vertices)."""
    S, Minv, vol = problem.simplices, problem.rest_inv, problem.volumes
    k = S.shape[1]
    G = np.concatenate([-Minv.sum(axis=1, keepdims=True), Minv], axis=1)  # (m, d+1, d): J = X^T G
    Ke = 2.0 * vol[:, None, None] * np.einsum("mad,mbd->mab", G, G)
    rows, cols = np.repeat(S, k, axis=1), np.tile(S, (1, k))
    n = problem.n_vertices
    return sp.coo_matrix((Ke.reshape(-1), (rows.reshape(-1), cols.reshape(-1))), shape=(n, n)).tocsc()


def laplacian_solve_host(handle, q):
    """Host side of the preconditioner: ``K^-1 q`` on the free DOFs."""
    return _LIVE_PRECONDITIONERS[int(handle)].solve(np.asarray(q))


def _solve_into(handle, q, out):
    out[0][...] = laplacian_solve_host(handle, q)


#: the XLA FFI target of the host solve (:mod:`geomopt._runtime.hostcall`: cacheable programs)
_TARGET = "geomopt_rest_laplacian_solve"
_hostcall.register(_TARGET, _solve_into)


@functools.partial(jax.tree_util.register_dataclass, data_fields=["rows", "i", "j", "v", "inv_diag", "rtol"],
                   meta_fields=["maxiter", "per_vertex"])
@dataclasses.dataclass(frozen=True)
class LaplacianOperator:
    """``K`` on the free DOFs as a device-resident sparse operator (symmetric COO), with its
    Jacobi preconditioner; ``rows`` picks the reduced unknowns out of the map (vertices when
    ``per_vertex``, flat DOFs ``v * d + c`` otherwise).  A pytree (``maxiter`` and
    ``per_vertex`` static); a plain dataclass, so that importing the solvers does not import
    equinox (0.2-0.3 s of every CLI process)."""

    rows: jax.Array
    i: jax.Array
    j: jax.Array
    v: jax.Array
    inv_diag: jax.Array
    rtol: jax.Array
    maxiter: int
    per_vertex: bool

    def _reduce(self, q):
        return q[self.rows] if self.per_vertex else q.reshape(-1)[self.rows][:, None]

    def _expand(self, r, like):
        if self.per_vertex:
            return jnp.zeros_like(like).at[self.rows].set(r)
        return jnp.zeros(like.size, like.dtype).at[self.rows].set(r[:, 0]).reshape(like.shape)

    def solve(self, q, guess):
        """``K^-1 q`` by PCG from ``guess`` (both shaped like the map), relative tolerance
        ``rtol`` or ``maxiter`` iterations."""
        n = self.rows.shape[0]

        def matvec(u):
            return jax.ops.segment_sum(self.v[:, None] * u[self.j], self.i, num_segments=n)

        b = self._reduce(q)
        u, _ = jax.scipy.sparse.linalg.cg(matvec, b, self._reduce(guess), tol=self.rtol,
                                          maxiter=self.maxiter, M=lambda r: self.inv_diag[:, None] * r)
        return self._expand(u, q)


def laplacian_solve(pre, q, guess):
    """``K^-1 q`` from jitted code: ``pre`` is a host handle (int32, ``"host"``) or a
    :class:`LaplacianOperator` (``"device"``, warm-started from ``guess``)."""
    if isinstance(pre, LaplacianOperator):
        return pre.solve(q, guess)
    return _hostcall.call(_TARGET, _solve_into, jax.ShapeDtypeStruct(q.shape, q.dtype), pre, q)


def resolve_backend(backend: str) -> str:
    """``"auto"`` -> ``"host"`` on CPU, ``"device"`` on an accelerator."""
    if backend not in LAPLACIAN_BACKENDS:
        raise ParameterError(f"laplacian backend must be one of {LAPLACIAN_BACKENDS}, got {backend!r}")
    if backend == "auto":
        return "host" if jax.default_backend() == "cpu" else "device"
    return backend


#: the relative residual a float32 seed factor must reach on a test solve (see _seed_factor)
SEED_RTOL = 1e-3

_HELPERS = []  # the thread pool of the per-column solves, made on first use
if hasattr(os, "register_at_fork"):  # a forked child has none of its threads: it makes its own
    os.register_at_fork(after_in_child=_HELPERS.clear)


def _at_once(calls):
    """The results of the callables ``calls``, run at once: the first on this thread, the
    others on helper threads (PARDISO releases the GIL).  Waits for all before raising."""
    if not _HELPERS:
        _HELPERS.append(ThreadPoolExecutor(max(1, usable_cores() - 1), thread_name_prefix="geomopt-seed"))
    futures = [_HELPERS[0].submit(c) for c in calls[1:]]
    try:
        first = calls[0]()
    finally:
        wait(futures)
    return [first] + [f.result() for f in futures]


class _Float32Seed:
    """``H`` factored in float32 by PARDISO and applied unrefined, on one handle or on one per
    column of the right-hand side (``columns``), solved at once on as many threads: PARDISO's
    solves run on one core, so the two coordinates of a 2D seed on two cores take the time of
    one (498k rows: 82 ms with cholespy, 109 on one handle, 42 on two)."""

    def __init__(self, H, columns: int = 1):
        def part():
            chol = SparseCholesky.factored(H, "pardiso", single=True)
            chol.forget_values()  # the float64 values only serve refined solves
            return chol

        self._parts = _at_once([part] * columns)
        self.single = True

    def precondition(self, b):
        if len(self._parts) == 1:
            return self._parts[0].precondition(b)
        cols = [np.ascontiguousarray(b[:, i]) for i in range(b.shape[1])]
        return np.stack(_at_once([functools.partial(p.precondition, c) for p, c in zip(self._parts, cols)]), axis=1)


def _seed_factor(H, backend: str, columns: int = 1):
    """``H`` factored to be applied many times to ``columns`` right-hand sides as a
    preconditioner (``.precondition``): in float32 where PARDISO is called directly, unrefined.
    A seed or a proxy needs no float64 solve (its relative error, ~1e-6, is far below what
    L-BFGS's curvature pairs correct), and PARDISO's solve reads half the bytes: the corner
    Laplacian of 10^6 tetrahedra (157k rows, 3 right-hand sides) 204 -> 116 ms a solve,
    factored in 4.5 s instead of 7.6 s.  Two columns (a 2D seed) on two or more cores get a
    handle each (:class:`_Float32Seed`); three (3D) share one: splitting them 2 + 1 on two
    cores gained 8 % (110 -> 102 ms at 10^6 tets) for a second factor's 344 MB.  Where float32
    cannot hold ``H`` (its pivots fail, or a test solve misses by over :data:`SEED_RTOL`: a
    Laplacian kept definite only by its tiny shift) it is factored in float64."""
    if backend == "pardiso" and pardiso.entry_point() is not None:
        try:
            seed = _Float32Seed(H, columns if columns == 2 and usable_cores() >= 2 else 1)
            b = np.random.default_rng(0).standard_normal((H.shape[0], columns))
            if np.linalg.norm(H @ seed.precondition(b) - b) <= SEED_RTOL * np.linalg.norm(b):
                return seed
        except NotPositiveDefinite:
            pass
    return SparseCholesky.factored(H, backend)


class RestLaplacian:
    """``K^-1`` for the rest Dirichlet Hessian ``K`` of an objective's problem on its free DOFs,
    factored by :class:`~geomopt.linalg.linsolve.SparseCholesky`.

    The Dirichlet energy ``sum vol |J|^2`` with ``J = X^T G`` (``G`` the element's (d+1, d)
    matrix of barycentric gradients, from the rest inverse) has the Hessian ``K (x) I_d`` with
    ``K = sum_e 2 vol_e G_e G_e^T`` (the cotangent Laplacian), assembled here directly: one
    (d+1)^2 block per element instead of the autodiff Hessian's ((d+1) d)^2 pattern (0.3 s
    less set-up on 48k tets).  When every vertex is free or fixed as a whole, one
    coordinate's block is factored and applied to the d coordinates at once (d times smaller,
    one multi-right-hand-side solve).  Jitted kernels refer to it by an integer handle
    (traced, so new meshes or solves never recompile); it lives as long as a solver state
    holds it."""

    def __init__(self, objective, backend: str = "host", rtol: float = 1e-3, maxiter: int = 200):
        problem, d = objective.problem, objective.problem.dim
        self.backend = resolve_backend(backend)
        K = rest_laplacian(problem)
        free = np.asarray(objective.free_dofs, bool)
        self.per_vertex = bool(np.all(free.all(axis=1) | ~free.any(axis=1)))
        if self.per_vertex:
            self.rows = np.flatnonzero(free.all(axis=1))
            H = K[self.rows][:, self.rows]
        else:
            self.rows = np.flatnonzero(free.reshape(-1))  # dof = v * d + c
            H = sp.kron(K, sp.identity(d), format="csc")[self.rows][:, self.rows]
        n = H.shape[0]
        self.d = d
        if n:
            # a tiny shift keeps it definite when a component has no fixed vertex
            H = (H + sp.identity(n) * (1e-12 * max(float(H.diagonal().mean()), 1e-300))).tocsc()
        if self.backend == "device":
            C = H.tocoo()
            self.operator = LaplacianOperator(
                jnp.asarray(self.rows, jnp.int32), jnp.asarray(C.row, jnp.int32), jnp.asarray(C.col, jnp.int32),
                jnp.asarray(C.data), jnp.asarray(1.0 / H.diagonal()) if n else jnp.zeros(0),
                jnp.float64(rtol), int(maxiter), self.per_vertex)
        elif n:
            self._chol = _seed_factor(H, repeated_solves_backend(d, n if self.per_vertex else n // d),
                                      d if self.per_vertex else 1)

    def solve(self, q):
        out = np.zeros_like(q)
        if self.rows.size == 0:
            return out
        if self.per_vertex:  # the d coordinates as one multi-right-hand-side solve (2x faster)
            out[self.rows] = self._chol.precondition(np.ascontiguousarray(q[self.rows]))
        else:
            flat = out.reshape(-1)
            flat[self.rows] = self._chol.precondition(q.reshape(-1)[self.rows])
        return out

    @classmethod
    def register(cls, objective, backend: str = "host", **kw):
        """A RestLaplacian usable from jitted code through :attr:`token`.  One still held by a
        solver state for the same objective (the same object), backend and settings is shared,
        not built and factored again: a solver re-initialised on the objective it ran on (the
        untangling's stiff switch) paid a second factorization, 6.7 s of cholespy's at 10^6
        triangles."""
        key = (id(objective), resolve_backend(backend), tuple(sorted(kw.items())))
        pre = _BY_OBJECTIVE.get(key)
        if pre is not None and pre.source() is objective:
            return pre
        pre = cls(objective, backend, **kw)
        pre.source = weakref.ref(objective)
        _BY_OBJECTIVE[key] = pre
        if pre.backend == "host":
            pre.handle = next(_NEXT_HANDLE) % (2**31 - 1)
            _LIVE_PRECONDITIONERS[pre.handle] = pre
        return pre

    @property
    def token(self):
        """What jitted code passes to :func:`laplacian_solve`: the host handle (int32) or the
        device operator."""
        return self.operator if self.backend == "device" else jnp.int32(self.handle)

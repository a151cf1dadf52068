"""Projected-Newton directions by preconditioned conjugate gradients, entirely in JAX.

The direct Newton step copies the assembled Hessian to the host and factors it (CHOLMOD or
cholespy).  This module computes the same direction on the device, with no host round trip:

* the projected Hessian is kept as vertex blocks (:func:`geomopt.objective.objective.block_hessian`):
  for every pair of vertices ``w <= v`` sharing an element, the d x d block ``H[v, w]``;
* the operator applies them (block sparse, lower blocks and their transposes), restricted to
  the free DOFs, plus a diagonal shift ``shift * mean |diag|`` (the Newton solver's
  regularization, relative to the mean diagonal of the free DOFs as there);
* the preconditioner is block Jacobi: the shifted d x d diagonal vertex blocks, inverted in
  closed form (fixed DOFs replaced by identity rows);
* :func:`pcg` runs preconditioned CG from zero until ``|r| <= rtol |g|`` (inexact Newton,
  Eisenstat & Walker 1996: ``rtol = min(eta_max, sqrt(|g| / g_ref))`` by default), at most
  ``max_iters`` iterations, and stops early on non-positive curvature (Steihaug 1983), so
  that the direction is always a descent direction.

Why our own CG loop rather than ``lineax.CG`` or ``jax.scipy.sparse.linalg.cg``: we need the
iteration count and residual back (to measure and to choose the solver), the truncation on
non-positive curvature, and a traced tolerance (the forcing term changes every Newton
step); neither library gives all three.

Use :class:`NewtonCG`::

    cg = NewtonCG()
    prep = cg.prepare(objective)              # once per mesh (device arrays)
    dx, info = cg.direction(prep, objective, x, params, "clamp", shift=1e-9)

``dx`` (n, d) is zero on fixed DOFs; ``info`` holds the energy, gradient and CG statistics.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.errors import ParameterError
from .objective import block_hessian, free_value_and_grad, jit
from .projection import as_projection
from .._runtime.x64 import float64

__all__ = ["NewtonCG", "CGOperator", "CGInfo", "pcg"]


class CGOperator(NamedTuple):
    """Device arrays describing the block operator of one mesh (a pytree), in a hybrid
    ELL + COO layout: row vertex ``v`` of the symmetric block matrix keeps its first ``K``
    blocks in slots ``ell_*[v, :K]`` (padding: the zero block appended after the objective's
    ``n_blocks`` blocks, bucket-padded like its arrays), the blocks of rows with more than
    ``K`` go to the ``over_*`` lists.  A product is then gathers and a dense reduction (no
    scatter) for nearly all blocks: 2x faster than scattering on CPU.  ``n_vertices`` is the
    objective's padded vertex count (padded vertices have no block and are fixed).

    ell_src, ell_col : (n_vertices, K) int32, the lower block (index into the vertex blocks)
        and the column vertex of each slot;  ell_t : (n_vertices, K) bool, the slot holds the
        block's transpose (an upper block).
    over_row, over_src, over_col : (n_over,) int32;  over_t : (n_over,) bool, the overflow.
    diag : (n_vertices,) int32, the diagonal block of each vertex (the zero block if unused).
    free : (n_vertices, d) float64, 1 on free DOFs.
    blocks, swap : the element-to-block map of :class:`~geomopt.objective.pattern.HessianPattern`.
    """

    ell_src: jax.Array
    ell_col: jax.Array
    ell_t: jax.Array
    over_row: jax.Array
    over_src: jax.Array
    over_col: jax.Array
    over_t: jax.Array
    diag: jax.Array
    free: jax.Array
    blocks: jax.Array
    swap: jax.Array


class CGInfo(NamedTuple):
    """What a CG Newton direction computation returns besides the direction.

    value : energy at x;  grad : (n, d) gradient, zero on fixed DOFs.
    iterations : CG iterations run.
    residual : final ``|r| / |g|`` (2-norms on the free DOFs).
    rtol : the tolerance used.
    curvature : False when CG stopped on non-positive curvature ``p.A p <= 0``.
    slope : ``grad . dx`` (the directional derivative; ``-slope / 2`` is the Newton decrement).
    """

    value: jax.Array
    grad: jax.Array
    iterations: jax.Array
    residual: jax.Array
    rtol: jax.Array
    curvature: jax.Array
    slope: jax.Array


# ------------------------------------------------------------------- linear algebra


def _oriented(VB, src, t):
    """Blocks ``VB[src]`` (``src == n_blocks``: zero), transposed where ``t``."""
    d = VB.shape[-1]
    B = jnp.concatenate([VB, jnp.zeros((1, d, d), VB.dtype)])[src]
    return jnp.where(t[..., None, None], jnp.swapaxes(B, -1, -2), B)


def operator_blocks(VB, op: CGOperator):
    """The slot blocks ``(ell (n_vertices, K, d, d), over (n_over, d, d))`` of the symmetric
    block matrix with lower vertex blocks ``VB`` (n_blocks, d, d)."""
    return _oriented(VB, op.ell_src, op.ell_t), _oriented(VB, op.over_src, op.over_t)


def block_matvec(ell, over, op: CGOperator, p):
    """``y = H p``, ``p`` (n_vertices, d), for the slot blocks of :func:`operator_blocks`.
    Broadcast sums rather than batched d x d ``dot_general`` (slow on CPU)."""
    d = p.shape[1]
    pc = p[op.ell_col]  # (n_vertices, K, d)
    y = sum(jnp.sum(ell[:, :, :, e] * pc[:, :, None, e], axis=1) for e in range(d))
    po = p[op.over_col]
    return y.at[op.over_row].add(sum(over[:, :, e] * po[:, None, e] for e in range(d)))


def _inverse_spd(D):
    """Inverse of symmetric positive-definite blocks D (..., d, d), d = 2 or 3, by cofactors; a
    block that is singular to rounding gets the inverse of its (positive) diagonal instead."""
    d = D.shape[-1]
    if d == 2:
        a, b, c = D[..., 0, 0], D[..., 0, 1], D[..., 1, 1]
        det = a * c - b * b
        adj = jnp.stack([jnp.stack([c, -b], -1), jnp.stack([-b, a], -1)], -2)
    elif d == 3:
        C = [[None] * 3 for _ in range(3)]
        for i in range(3):
            for j in range(3):
                r = [k for k in range(3) if k != i]
                s = [k for k in range(3) if k != j]
                minor = D[..., r[0], s[0]] * D[..., r[1], s[1]] - D[..., r[0], s[1]] * D[..., r[1], s[0]]
                C[i][j] = (-1) ** (i + j) * minor
        det = sum(D[..., 0, j] * C[0][j] for j in range(3))
        adj = jnp.stack([jnp.stack([C[j][i] for j in range(3)], -1) for i in range(3)], -2)
    else:
        raise ParameterError(f"block Jacobi supports d = 2 or 3, got d={d}")
    diag = jnp.diagonal(D, axis1=-2, axis2=-1)
    scale = jnp.prod(jnp.abs(diag), axis=-1)
    ok = det > 1e-12 * scale
    safe = jnp.where(ok, det, 1.0)
    fallback = jnp.where(jnp.eye(d, dtype=bool), 1.0 / jnp.where(diag > 0, diag, 1.0)[..., None, :], 0.0)
    return jnp.where(ok[..., None, None], adj / safe[..., None, None], fallback)


def pcg(matvec, precond, b, rtol, max_iters):
    """Preconditioned conjugate gradients for ``A x = b`` from ``x = 0`` (jittable).

    Parameters
    ----------
    matvec, precond : functions of an array shaped like ``b`` (A and M^-1, symmetric; A is
        expected positive definite on the span of ``b``).
    b : array (any shape).
    rtol : stop when ``|r|_2 <= rtol |b|_2``;  max_iters : iteration limit (both may be traced).

    Returns
    -------
    x : like ``b``;  iterations : int;  relative residual ``|r| / |b|``;  curvature : bool,
    False when it stopped on ``p.A p <= 0``.  Then the last iterate is returned, or, at the
    first iteration, ``M^-1 b`` (so ``b.x > 0`` always: a descent direction for ``b = -g``).
    """
    bb = jnp.vdot(b, b)
    tol2 = rtol * rtol * bb
    z = precond(b)

    def cond(s):
        k, _, _, _, _, rr, ok = s
        return (k < max_iters) & ok & (rr > tol2)

    def body(s):
        k, x, r, p, rz, rr, _ = s
        Ap = matvec(p)
        pAp = jnp.vdot(p, Ap)
        ok = pAp > 0
        alpha = jnp.where(ok, rz / jnp.where(ok, pAp, 1.0), 0.0)
        x = jnp.where(ok | (k > 0), x + alpha * p, p)  # first step on p.A p <= 0: M^-1 b
        r = r - alpha * Ap
        z = precond(r)
        rz_new = jnp.vdot(r, z)
        p = z + (rz_new / jnp.where(rz != 0, rz, 1.0)) * p
        return k + 1, x, r, p, rz_new, jnp.vdot(r, r), ok

    state = (0, jnp.zeros_like(b), b, z, jnp.vdot(b, z), bb, bb > 0)
    k, x, _, _, _, rr, ok = jax.lax.while_loop(cond, body, state)
    return x, k, jnp.sqrt(rr / jnp.where(bb > 0, bb, 1.0)), ok


# ------------------------------------------------------------------- the Newton step


def cg_system(VB, op: CGOperator, shift):
    """``(matvec, precond)`` of the Newton system on the free DOFs for the lower vertex blocks
    ``VB`` (n_blocks, d, d): ``matvec(p) = F (H + mu I) F p`` and the block-Jacobi
    ``precond(r) = F (D + mu I)^-1 F r`` on (n_vertices, d) arrays, with ``F`` the free mask,
    ``D`` the diagonal vertex blocks (fixed DOFs replaced by identity rows and columns) and
    ``mu = shift * mean |diag H|`` over the free DOFs."""
    free = op.free
    d = free.shape[1]
    ell, over = operator_blocks(VB, op)
    D = _oriented(VB, op.diag, jnp.zeros(op.diag.shape, bool))  # (n_vertices, d, d)
    diag = jnp.diagonal(D, axis1=-2, axis2=-1) * free
    mu = shift * jnp.maximum(jnp.sum(jnp.abs(diag)) / jnp.maximum(jnp.sum(free), 1.0), 1e-300)
    eye = jnp.eye(d)
    F = free[:, :, None] * free[:, None, :]
    Dinv = _inverse_spd(D * F + (1.0 - free)[:, :, None] * eye[None] + mu * eye[None])

    def matvec(p):
        return free * (block_matvec(ell, over, op, free * p) + mu * p)

    def precond(r):
        r = free * r
        return free * sum(Dinv[:, :, e] * r[:, None, e] for e in range(d))

    return matvec, precond


@partial(jit, static_argnums=(0, 1, 2, 3))
def newton_cg_kernel(density, projection, chunk, n_blocks, geom, x, params, op, shift, rtol,
                     eta_max, gnorm_ref, max_iters):
    """Energy, gradient and the CG projected-Newton direction at ``x``; see :class:`NewtonCG`."""
    value, g = free_value_and_grad(density, geom, op.free, x, params)
    VB = block_hessian(density, projection, chunk, geom, x, params, op.blocks, op.swap, n_blocks)
    matvec, precond = cg_system(VB, op, shift)
    gnorm = jnp.sqrt(jnp.vdot(g, g))
    tol = jnp.where(rtol > 0, rtol, jnp.minimum(eta_max, jnp.sqrt(gnorm / gnorm_ref)))
    dx, iters, res, ok = pcg(matvec, precond, -g, tol, max_iters)
    return dx, CGInfo(value, g, iters, res, tol, ok, jnp.vdot(g, dx))


@dataclasses.dataclass(frozen=True)
class NewtonCG:
    """The projected-Newton direction by block-Jacobi preconditioned CG (inexact Newton).

    Attributes
    ----------
    max_iters : CG iteration limit per Newton step (the truncated direction is still a
        descent direction).
    rtol : fixed relative residual ``|r| / |g|``; 0 (default) uses the forcing term
        ``min(eta_max, sqrt(|g|_2 / g_ref))`` (Eisenstat & Walker 1996): loose far from the
        minimum, tight near it (superlinear convergence).  ``g_ref`` (``gnorm_ref`` of
        :meth:`direction`, default 1 as in the issue) makes it scale-free: pass the first
        gradient norm of the solve (meshes' areas here range over 5 orders of magnitude).
    eta_max : the loosest tolerance of the forcing term.
    """

    max_iters: int = 2000
    rtol: float = 0.0
    eta_max: float = 0.5

    def __post_init__(self):
        if int(self.max_iters) < 1:
            raise ParameterError(f"NewtonCG max_iters must be >= 1, got {self.max_iters}")
        if not 0.0 <= self.rtol < 1.0:
            raise ParameterError(f"NewtonCG rtol must lie in [0, 1), got {self.rtol}")
        if not 0.0 < self.eta_max < 1.0:
            raise ParameterError(f"NewtonCG eta_max must lie in (0, 1), got {self.eta_max}")

    @staticmethod
    @float64
    def prepare(objective) -> CGOperator:
        """The device arrays of ``objective``'s block operator (build once per mesh), padded
        like the objective (:mod:`geomopt._runtime.padding`): ``n_padded`` vertex rows, the padded
        vertices with no block (their rows stay zero and fixed)."""
        pat = objective.pattern
        blocks, swap, nb_all = objective.block_assembly
        nv = objective.free_mask.shape[0]
        ptr, idx, nb = pat.vertex_ptr, pat.vertex_idx, pat.n_blocks
        ptr = np.concatenate([ptr, np.full(nv + 1 - len(ptr), ptr[-1], ptr.dtype)])
        cols = np.repeat(np.arange(nv), np.diff(ptr))
        off = np.flatnonzero(idx != cols)
        # the symmetric matrix by rows: lower blocks (row idx) and their transposes (row cols)
        row = np.concatenate([idx, cols[off]])
        col = np.concatenate([cols, idx[off]])
        src = np.concatenate([np.arange(nb), off])
        tr = np.concatenate([np.zeros(nb, bool), np.ones(len(off), bool)])
        order = np.argsort(row, kind="stable")
        row, col, src, tr = row[order], col[order], src[order], tr[order]
        deg = np.bincount(row, minlength=nv)
        slot = np.arange(len(row)) - (np.cumsum(deg) - deg)[row]
        # ELL width: least padded slots + twice the overflow (a scattered block costs ~2 slots)
        counts = np.bincount(deg)
        widths = np.arange(len(counts))
        over_of = np.array([np.sum(np.maximum(widths - K, 0) * counts) for K in widths])
        K = max(int(np.argmin(nv * widths + 2 * over_of)), 1)
        inl = slot < K
        # empty slots point at the zero block appended after all (padded) blocks
        ell_src = np.full((nv, K), nb_all, np.int64)
        ell_col = np.zeros((nv, K), np.int64)
        ell_t = np.zeros((nv, K), bool)
        ell_src[row[inl], slot[inl]] = src[inl]
        ell_col[row[inl], slot[inl]] = col[inl]
        ell_t[row[inl], slot[inl]] = tr[inl]
        used = deg > 0
        i32 = lambda a: jnp.asarray(a, jnp.int32)  # noqa: E731
        return CGOperator(
            ell_src=i32(ell_src), ell_col=i32(ell_col), ell_t=jnp.asarray(ell_t),
            over_row=i32(row[~inl]), over_src=i32(src[~inl]), over_col=i32(col[~inl]),
            over_t=jnp.asarray(tr[~inl]), diag=i32(np.where(used, ptr[:-1], nb_all)),
            free=objective.free_mask, blocks=blocks, swap=swap)

    def _args(self, op, objective, x, params, projection, shift, gnorm_ref, rtol):
        return (objective.energy.density, as_projection(projection), objective.chunk, objective.block_assembly[2],
                objective.geom, objective.pad_map(jnp.asarray(x)), params, op, jnp.float64(shift),
                jnp.float64(self.rtol if rtol is None else rtol), jnp.float64(self.eta_max),
                jnp.float64(gnorm_ref), jnp.int32(self.max_iters))

    @float64
    def direction(self, op: CGOperator, objective, x, params, projection="clamp", shift=0.0,
                  gnorm_ref=1.0, rtol=None):
        """``(dx, info)``: the direction (n_padded, d), zero on fixed DOFs, and a :class:`CGInfo`.

        ``x`` has n or n_padded rows (:meth:`~geomopt.Objective.pad_map`); ``shift`` is the
        Newton regularization relative to the mean |diagonal| of the free DOFs (as in
        :class:`~geomopt.solvers.Newton`); ``gnorm_ref`` scales the forcing term; ``rtol``
        overrides the configuration's (e.g. an Eisenstat-Walker sequence kept by the caller).
        These, ``params`` and the configuration's numbers are traced: changing them never
        recompiles."""
        return newton_cg_kernel(*self._args(op, objective, x, params, projection, shift, gnorm_ref, rtol))

    @float64
    def compile(self, op: CGOperator, objective, x, params, projection="clamp"):
        """Compile (or load from the persistent cache) the kernel of :meth:`direction` for
        maps shaped like ``x`` without running it (a solver's set-up holds the compilation)."""
        newton_cg_kernel.lower(*self._args(op, objective, x, params, projection, 0.0, 1.0, None)).compile()

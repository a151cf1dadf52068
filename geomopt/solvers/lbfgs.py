"""Limited-memory BFGS with a Wolfe line search, jitted end to end.

One iteration (Nocedal & Wright 2006, Algorithms 7.4 and 7.5) is the two-loop recursion
over a fixed-size ring buffer of correction pairs (``lax.fori_loop``), the shared
:class:`~geomopt.solvers.linesearch.InjectiveSearch` (weak Wolfe by default: it brackets by bisection /
doubling, Lewis & Overton 2013), and the memory update.  Two jitted programs per mesh shape
do everything: the iteration loop (``lax.while_loop`` up to a traced limit, stopped by the
solver's :class:`~geomopt.solvers.Termination` on traced statistics: :meth:`LBFGS.advance`
runs it to the end without per-iteration Python dispatch, :meth:`LBFGS.step` one iteration
further) and the evaluation that starts a solve or re-parameterises it (``init``,
``reparam``, ``restart``).  They are keyed on the density, the array shapes and the solver's
configuration less ``max_steps``; energy parameters are traced, so changing eps / lambda never
recompiles.

The inverse-Hessian seed is the scalar ``s.y / y.y`` (``precondition="scalar"``), the
diagonal update of M1QN3 (Gilbert & Lemarechal 1989, ``"diagonal"``, as in the STLBFGS
library used by Garanzha et al. 2021), or a scaled inverse of the rest Dirichlet Hessian
(``"laplacian"``, the default; one solve with the rest Laplacian per iteration and the
direction in compact form: see :func:`_compact_direction`;
factored once on the host and applied through an XLA FFI target on CPU, by warm-started
conjugate gradients on the device elsewhere, so the loop makes no host round trip there).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._runtime.config import Int, OneOf, Real
from .._runtime.programs import jit as programs_jit
from .._runtime.errors import ParameterError
from ..objective.objective import free_value_and_grad
from .linesearch import InjectiveSearch
from ._base import AbstractSolver, State, start_stats
from ._laplacian import LAPLACIAN_BACKENDS, LaplacianOperator, RestLaplacian, laplacian_solve
from ._termination import RUNNING, Stats, Termination

__all__ = ["LBFGS", "PRECONDITIONERS"]

PRECONDITIONERS = ("scalar", "diagonal", "laplacian")


def _dot(a, b):
    return jnp.sum(a * b)


def _two_loop(S, Y, rho, k, seed, g):
    """``-H g`` (shaped like ``g``) for the L-BFGS inverse Hessian held in ring buffers S, Y
    (m, g.size), newest at slot ``(k-1) % m``; ``seed(q)`` applies the initial inverse Hessian
    to a flat vector."""
    m = S.shape[0]
    used = jnp.minimum(k, m)

    def back(j, carry):
        q, alpha = carry
        i = (k - 1 - j) % m
        a = rho[i] * _dot(S[i], q)
        return q - a * Y[i], alpha.at[i].set(a)

    q, alpha = lax.fori_loop(0, used, back, (g.reshape(-1), jnp.zeros(m, g.dtype)))
    r = seed(q)

    def forward(j, r):
        i = (k - used + j) % m
        b = rho[i] * _dot(Y[i], r)
        return r + (alpha[i] - b) * S[i]

    return -lax.fori_loop(0, used, forward, r).reshape(g.shape)


def _rows_dot(A, v):
    """``(A_i . v)_i`` for a buffer A (m, v.size): one matrix-vector product."""
    return A @ v.reshape(-1)


def _compact_direction(S, W, a, b, SY, YW, k, gamma, z):
    """``-H g`` for the L-BFGS inverse Hessian with the seed ``gamma P`` in the compact form of
    Byrd, Nocedal & Schnabel (1994): ``H g = gamma z + S p + gamma W q`` with ``q = -R^-1 a``
    and ``p = R^-T ((D + gamma Y^T W) R^-1 a - gamma b)``, where ``z = P g``, ``W = P Y`` (P
    symmetric; buffers (m, z.size)), ``a = S^T g``, ``b = W^T g``, ``SY[i, j] = s_i . y_j``
    (``R`` its upper triangle in the pairs' chronological order, ``D`` its diagonal) and
    ``YW[i, j] = y_i . w_j``, all carried (slot order, newest at ``(k-1) % m``).

    The same direction as the two-loop recursion with that seed (tested), from two passes over
    the buffers (matrix-vector products) instead of two dependent ones per pair.  Slots not in
    use get unit rows of ``R`` and no coefficients."""
    m = S.shape[0]
    used = jnp.minimum(k, m)
    order = (k - m + jnp.arange(m)) % m  # chronological: oldest possible slot first
    valid = jnp.arange(m) >= m - used
    both = valid[:, None] & valid[None, :]
    R = jnp.where(both, jnp.triu(SY[order][:, order]), jnp.eye(m, dtype=SY.dtype))
    inner = jnp.where(both, jnp.diag(jnp.diag(R)) + gamma * YW[order][:, order], 0.0)
    ac, bc = jnp.where(valid, a[order], 0.0), jnp.where(valid, b[order], 0.0)
    c = jax.scipy.linalg.solve_triangular(R, ac, lower=False)
    p = jax.scipy.linalg.solve_triangular(R, inner @ c - gamma * bc, trans=1, lower=False)
    coef_s = jnp.zeros(m, z.dtype).at[order].set(p)
    coef_w = jnp.zeros(m, z.dtype).at[order].set(-gamma * c)
    return -(gamma * z + (coef_s @ S + coef_w @ W).reshape(z.shape))


def _compact_update(c, S, Wn, gn, slot, good, sy, yPy, **extra):
    """The compact form's carried products after the pair at ``slot`` (stored when ``good``):
    ``a = S^T gn``, ``b = W^T gn`` at the iterate's gradient (one pass), and the new pair's column of
    ``SY`` and row and column of ``YW`` from their change, ``s_i . y = a_i - a_i(old)`` and
    ``w_i . y = b_i - b_i(old)`` (the old pairs are unchanged), without another pass."""
    a, b = _rows_dot(S, gn), _rows_dot(Wn, gn)
    col_sy = (a - c["a"]).at[slot].set(sy)
    col_yw = (b - c["b"]).at[slot].set(yPy)
    SY = jnp.where(good, c["SY"].at[:, slot].set(col_sy), c["SY"])
    YW = jnp.where(good, c["YW"].at[:, slot].set(col_yw).at[slot, :].set(col_yw), c["YW"])
    return dict(extra, a=a, b=b, SY=SY, YW=YW)


def _iteration(solver, density, geom, free, params, c):
    """One L-BFGS iteration on the carry ``c`` (a dict of arrays and the :class:`Stats`)."""
    def vg(x):
        return free_value_and_grad(density, geom, free, x, params)
    st = c["stats"]
    x, f, g, S, rho, k, H0 = c["x"], st.value, c["g"], c["S"], c["rho"], c["k"], c["H0"]
    laplacian = solver.precondition == "laplacian"

    def seed(q):  # flat q
        return (H0 * q.reshape(g.shape)).reshape(-1)
    if laplacian:  # z = K^-1 g, W = K^-1 Y and their products are carried: no solve here
        d = _compact_direction(S, c["W"], c["a"], c["b"], c["SY"], c["YW"], k, H0, c["z"])
    else:
        d = _two_loop(S, c["Y"], rho, k, seed, g)
    slope = _dot(g, d)
    restart = ~(slope < 0) | ~jnp.all(jnp.isfinite(d))
    d = jnp.where(restart, -g, d)
    k = jnp.where(restart, jnp.zeros_like(k), k)
    H0 = jnp.where(restart, jnp.ones_like(H0), H0)
    slope = jnp.where(restart, -_dot(g, g), slope)
    # without curvature pairs the step length is unknown: start with a unit move
    t0 = jnp.where(k == 0, 1.0 / jnp.maximum(jnp.sqrt(_dot(d, d)), 1e-300), 1.0)
    t, xn, fn, gn, ok, nls = solver.search.search(vg, geom[0], x, f, g, d, t0)

    s, y = xn - x, gn - g
    sy, yy, ss = _dot(s, y), _dot(y, y), _dot(s, s)
    good = ok & (sy > 1e-10 * jnp.sqrt(ss * yy)) & jnp.isfinite(sy)
    m = S.shape[0]
    slot = k % m
    # in place (dynamic-update-slice): a select between whole buffers would copy them; the
    # buffers are (m, n*d), which no product reshapes (a reshaped buffer made XLA copy it)
    S = S.at[slot].set(jnp.where(good, s.reshape(-1), S[slot]))
    rho = rho.at[slot].set(jnp.where(good, 1.0 / jnp.where(good, sy, 1.0), rho[slot]))
    # the compact form needs no Y: its products with S and W are carried instead
    extra = {} if laplacian else {"Y": c["Y"].at[slot].set(jnp.where(good, y.reshape(-1), c["Y"][slot]))}
    if solver.precondition == "diagonal":
        # M1QN3 diagonal update (Gilbert & Lemarechal 1989) of the seed D, as in STLBFGS
        dinvss = _dot(s * s, 1.0 / H0)
        dyy = _dot(y * y, H0)
        newH0 = 1.0 / (dyy / (sy * H0) + y * y / sy - dyy * s * s / (sy * dinvss * H0 * H0))
        newH0 = jnp.where(jnp.isfinite(newH0) & (newH0 > 0), newH0, sy / yy)
    elif laplacian:
        # the one Laplacian solve of the iteration: K^-1 g at the new point, whence K^-1 y
        z = c["z"]
        zn = lax.cond(ok, lambda: laplacian_solve(c["pre"], gn, z), lambda: z)
        w = zn - z
        Wn = c["W"].at[slot].set(jnp.where(good, w.reshape(-1), c["W"][slot]))
        yPy = _dot(y, w)
        extra = _compact_update(c, S, Wn, jnp.where(ok, gn, g), slot, good, sy, yPy, z=zn, W=Wn)
        newH0 = sy / jnp.where(yPy > 0, yPy, 1.0)
    else:
        newH0 = sy / jnp.where(yy > 0, yy, 1.0)
    H0 = jnp.where(good, newH0, H0)
    k = jnp.where(good, k + 1, k).astype(jnp.int32)

    # the energy test looks back over the last `window` steps: f_hist holds the values after each
    W = solver.window
    slot = st.iteration % W
    xk, gk = jnp.where(ok, xn, x), jnp.where(ok, gn, g)
    stats = st._replace(
        iteration=st.iteration + 1, value=jnp.where(ok, fn, f), past_value=c["f_hist"][slot],
        decrement=-0.5 * slope, step_size=t, grad_norm=jnp.sqrt(_dot(gk, gk)), accepted=ok,
        extent=jnp.max(jnp.max(xk, axis=0) - jnp.min(xk, axis=0)),
        evaluations=(st.evaluations + nls).astype(jnp.int32))
    return {"x": xk, "g": gk, "S": S, "rho": rho, "k": k, "H0": H0,
            "f_hist": c["f_hist"].at[slot].set(jnp.where(ok, fn, f)), "pre": c["pre"], "stats": stats, **extra}


@partial(programs_jit, static_argnums=(0, 1))
def _run_kernel(solver, density, geom, free, params, carry, max_it):
    """Iterations while the solver's termination says RUNNING and ``iteration < max_it``
    (traced): ``step`` is one call with ``max_it = iteration + 1``, so one compiled program
    serves ``step`` and ``advance``.  ``solver`` is the key of :meth:`LBFGS._kernel_key`
    (``max_steps`` left out)."""
    rule = solver.termination

    def cond(c):
        return (rule.status(c["stats"]) == RUNNING) & (c["stats"].iteration < max_it)

    return lax.while_loop(cond, partial(_iteration, solver, density, geom, free, params), carry)


def _blank_carry(m, precondition, window, x, pre, stats):
    """The carry of :func:`_iteration` before the first evaluation, built on the host (nothing
    to compile): empty memory, unit seed; ``stats`` (host :class:`Stats`) holds the references
    of the termination tests, its value and gradient entries are set by
    :func:`_reparam_kernel`.  ``x`` (n, d) float64."""
    n, d = x.shape
    f8, i4 = np.float64, np.int32
    types = dict(iteration=i4, evaluations=i4, accepted=np.bool_, broken=np.bool_, done=np.bool_)
    carry = {
        "x": x, "g": np.zeros((n, d)), "S": np.zeros((m, n * d)),
        "rho": np.zeros(m), "k": i4(0), "H0": np.ones((n, d)) if precondition == "diagonal" else f8(1.0),
        "f_hist": np.full(window, np.inf), "pre": pre if isinstance(pre, LaplacianOperator) else i4(pre),
        "stats": Stats(*(types.get(k, f8)(v) for k, v in zip(Stats._fields, stats))),
    }
    if precondition == "laplacian":  # the compact form: W = K^-1 Y and the products, no Y
        carry.update(z=np.zeros((n, d)), W=np.zeros((m, n * d)), a=np.zeros(m), b=np.zeros(m),
                     SY=np.zeros((m, m)), YW=np.zeros((m, m)))
    else:
        carry["Y"] = np.zeros((m, n * d))
    return jax.device_put(carry)


@partial(programs_jit, static_argnums=(0, 1))
def _reparam_kernel(laplacian, density, geom, free, params, carry):
    """``carry`` re-evaluated at its ``x`` under ``params``: value, gradient (and for the
    Laplacian seed ``K^-1 grad``), and the counters and energy window restarted; the
    curvature memory and the evaluation count are kept.  Serves ``init`` and ``reparam``."""
    f, g = free_value_and_grad(density, geom, free, carry["x"], params)
    gnorm = jnp.sqrt(_dot(g, g))
    stats = carry["stats"]._replace(
        iteration=jnp.int32(0), value=f, past_value=jnp.asarray(jnp.inf, f.dtype),
        decrement=jnp.asarray(jnp.inf, f.dtype), step_size=jnp.asarray(jnp.nan, f.dtype), grad_norm=gnorm,
        grad_norm0=gnorm, accepted=jnp.bool_(True), broken=jnp.bool_(False), done=jnp.bool_(False))
    out = dict(carry, g=g, stats=stats, f_hist=jnp.full_like(carry["f_hist"], jnp.inf).at[-1].set(f))
    if laplacian:  # warm start (device CG) from the last K^-1 g
        out["z"] = laplacian_solve(carry["pre"], g, carry["z"])
        out["a"], out["b"] = _rows_dot(carry["S"], g), _rows_dot(carry["W"], g)
    return out


def _host_stats(stats) -> Stats:
    """A device :class:`Stats` as Python scalars (one transfer)."""
    return Stats(*(v.item() for v in jax.device_get(stats)))


class LBFGSMemory(NamedTuple):
    """L-BFGS's memory: ``carry``, the device arrays of :func:`_iteration` (map, gradient,
    curvature pairs, seed, energy window, statistics), and the Laplacian preconditioner (or
    None) that the carry refers to by handle."""

    carry: Any
    preconditioner: Any = None


@dataclasses.dataclass(frozen=True)
class LBFGS(AbstractSolver):
    """Limited-memory BFGS (Liu & Nocedal 1989) with the shared injective search.

    Attributes
    ----------
    history : 10 (>= 1); number of correction pairs kept (``m``).
    rtol : 1e-10; stop when the last ``window`` steps decreased the energy by less than
        ``window * rtol * max(|E_k-window|, |E_k|)`` relative (``window = 1``: one step
        decreased it by less than ``rtol``).
    gtol : 1e-9 (0 turns it off); stop when ``|grad|_2 <= gtol * |grad at x0|_2``.
    max_steps : 1000; the iteration limit (a solve that reaches it ends ``MAX_STEPS``).
    search : :class:`~geomopt.solvers.linesearch.InjectiveSearch`, default
        ``InjectiveSearch(c2=0.9, safety=0.25)``: weak Wolfe (``c2 = 0.9``),
        injective, first trial at most a quarter of the flip bound by default (as
        :class:`~geomopt.AQP`'s: the Laplacian seed does not see the barrier; benchmarks/README.md,
        "L-BFGS's defaults").  The untangling solver (:func:`geomopt.untangling.default_solver`) turns
        ``injective`` off: its energy is finite on inverted elements.
    precondition : ``"laplacian"`` (default); the initial inverse Hessian of the two-loop recursion: ``"scalar"``
        (``s.y / y.y`` times the identity), ``"diagonal"`` (the M1QN3 diagonal update), or
        ``"laplacian"``: ``gamma K^-1`` with ``K`` the Hessian of the rest Dirichlet energy
        ``sum vol |J|^2`` on the free DOFs (a cotangent Laplacian per coordinate, assembled by
        :class:`~geomopt.Objective`), factored once by a sparse Cholesky, and
        ``gamma = s.y / y.K^-1 y`` (a Sobolev gradient, as in the Laplacian-preconditioned
        quasi-Newton methods of Zhu et al. 2018 and Kovalsky et al. 2016).  It makes
        L-BFGS's iteration count nearly independent of the mesh size on problems with large
        global motions (one Laplacian solve per iteration; the measurements behind the default
        are in benchmarks/README.md, "L-BFGS's defaults").
    laplacian : ``"auto"`` (default); where ``"laplacian"`` applies ``K^-1``: ``"host"`` (sparse Cholesky on the
        host through an XLA FFI target, :mod:`geomopt._runtime.hostcall`; exact), ``"device"`` (Jacobi-preconditioned CG in
        JAX, warm-started from the previous iteration's solution, relative tolerance 1e-3: no
        host round trip on an accelerator), or ``"auto"`` (host on CPU, device elsewhere).
    window : 1 (>= 1); number of iterations the energy test looks back over (see ``rtol``).

    Notes
    -----
    ``step`` runs one iteration and :meth:`advance` many, both in the same jitted
    ``lax.while_loop`` (a traced limit) whose condition is :attr:`termination`'s rule on the
    traced :class:`~geomopt.solvers.Stats`.

    Examples
    --------
    >>> import geomopt
    >>> V = [[0, 0, 0.5], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
    >>> F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]
    >>> solver = geomopt.LBFGS(history=5, max_steps=200)
    >>> result = geomopt.parameterize(V, F, solver=solver, progress=False)
    >>> result.success, result.certificate.inverted
    (True, 0)
    """

    history: int = 10
    rtol: float = 1e-10
    gtol: float = 1e-9
    max_steps: int = 1000
    search: InjectiveSearch = InjectiveSearch(c2=0.9, safety=0.25)
    precondition: str = "laplacian"
    window: int = 1
    laplacian: str = "auto"

    def __post_init__(self):
        self._check(history=Int(1), gtol=Real(0.0, 1.0, hi_open=True), precondition=OneOf(PRECONDITIONERS),
                    window=Int(1), laplacian=OneOf(LAPLACIAN_BACKENDS))

    @property
    def termination(self) -> Termination:
        """Converged when the gradient fell to ``gtol`` times its start, or the energy by at
        most ``window * rtol`` (relative) over the last ``window`` iterations while a full step
        promises at most ``sqrt(rtol)`` (``-g.d``); a failed search is converged when its
        direction promised less than the rounding of ``E``."""
        return Termination(rtol=0.0, ftol=self.window * self.rtol, stall=0.5 * math.sqrt(self.rtol),
                           gtol=self.gtol, flat=0.5e-14, max_steps=self.max_steps)

    @staticmethod
    def _args(objective):
        return objective.energy.density, objective.geom, objective.free_mask

    @staticmethod
    def _state(state, carry) -> State:
        """``state`` at the carry's map, with its statistics pulled to the host."""
        return dataclasses.replace(state, x=carry["x"], grad=carry["g"], stats=_host_stats(carry["stats"]),
                                   memory=state.memory._replace(carry=carry))

    @functools.cached_property
    def _kernel_key(self):
        """The static key of :func:`_run_kernel`: this configuration less ``max_steps`` (a
        traced limit there), so solvers that differ only in it share the compiled loop."""
        return dataclasses.replace(self, max_steps=1)

    # -- the interface ----------------------------------------------------------------
    def init(self, objective, x0, params, *, precompile: bool = True) -> State:
        """The start state.  ``precompile`` compiles the iteration kernel now (``step`` and
        ``advance`` share it), so that setup time holds the compilation."""
        density, geom, free = self._args(objective)
        if precompile not in (True, False):
            raise ParameterError(f"precompile must be True or False, got {precompile!r}")
        # a private copy put on the device as it is (jnp.asarray would compile a copy program
        # per shape)
        x = jax.device_put(np.array(objective.pad_map(np.asarray(x0, dtype=np.float64))))
        pre = RestLaplacian.register(objective, self.laplacian) if self.precondition == "laplacian" else None
        stats = start_stats(objective, x0, math.nan)
        blank = _blank_carry(self.history, self.precondition, self.window, x,
                             pre.token if pre is not None else -1, stats)
        carry = _reparam_kernel(self.precondition == "laplacian", density, geom, free, params, blank)
        floor = max(1e-12 * abs(float(carry["stats"].value)), 1e-300)
        carry = dict(carry, stats=carry["stats"]._replace(floor=jax.device_put(np.float64(floor))))
        if precompile:  # zero iterations: compiles (or loads) the loop, changes nothing
            _run_kernel(self._kernel_key, density, geom, free, params, carry, jnp.int32(0))
        return self._state(State(objective, params, x, carry["g"], stats, LBFGSMemory(carry, pre)), carry)

    def advance(self, state: State, limit: int) -> State:
        """Iterations in one jitted loop until the termination stops or ``state.iteration``
        reaches ``limit``."""
        density, geom, free = self._args(state.objective)
        carry = _run_kernel(self._kernel_key, density, geom, free, state.params, state.memory.carry,
                            jnp.int32(limit))
        return self._state(state, carry)

    def step(self, state: State) -> State:
        """One iteration (the kernel of :meth:`advance` with a limit one further)."""
        density, geom, free = self._args(state.objective)
        carry = _run_kernel(self._kernel_key, density, geom, free, state.params, state.memory.carry,
                            jnp.int32(state.iteration + 1))
        return self._state(state, carry)

    def reparam(self, state: State, params) -> State:
        """The state with new energy parameters (value and gradient re-evaluated); the
        curvature memory is kept.  Used by continuations (eps in untangling)."""
        density, geom, free = self._args(state.objective)
        carry = _reparam_kernel(self.precondition == "laplacian", density, geom, free, params,
                                state.memory.carry)
        return self._state(dataclasses.replace(state, params=params), carry)

    def restart(self, state: State, x=None) -> State:
        """The state with the curvature memory cleared; moved to ``x`` (value and gradient
        re-evaluated there, counters kept) when given."""
        carry = state.memory.carry
        # host-built constants: no per-shape fill kernel to compile or dispatch
        carry = dict(carry, **jax.device_put({"k": np.int32(0), "H0": np.ones(carry["H0"].shape)}))
        if x is None:
            return dataclasses.replace(state, memory=state.memory._replace(carry=carry))
        density, geom, free = self._args(state.objective)
        old = carry["stats"]
        carry = _reparam_kernel(self.precondition == "laplacian", density, geom, free, state.params,
                                dict(carry, x=jax.device_put(np.asarray(x, np.float64))))
        carry["stats"] = carry["stats"]._replace(iteration=old.iteration, evaluations=old.evaluations + 1)
        return self._state(state, carry)

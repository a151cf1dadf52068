"""Limited-memory BFGS with a Wolfe line search, jitted end to end.

One iteration (Nocedal & Wright 2006, Algorithms 7.4 and 7.5) is the two-loop recursion
over a fixed-size ring buffer of correction pairs (``lax.fori_loop``), a line search
that brackets a weak-Wolfe step by bisection / doubling (Lewis & Overton 2013) inside a
``lax.while_loop``, and the memory update.  Everything runs in one jitted function keyed
on the density, the array shapes and the solver's constants; energy parameters are traced,
so changing eps / lambda never recompiles (the ``injective`` line-search flag is static:
the non-injective kernel then carries no root finding).  :meth:`LBFGS.run` runs the whole
iteration loop inside ``lax.while_loop``, which removes the per-iteration Python dispatch
(the untangling outer loop uses it).

The inverse-Hessian seed is the scalar ``s.y / y.y`` (``precondition="scalar"``), the
diagonal update of M1QN3 (Gilbert & Lemarechal 1989, ``"diagonal"``, as in the STLBFGS
library used by Garanzha et al. 2021), or a scaled inverse of the rest Dirichlet Hessian
(``"laplacian"``, factored once on the host and applied through ``jax.pure_callback``).
"""

from __future__ import annotations

import dataclasses
import itertools
import weakref
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jax import lax

from .._config import Instance, Int, OneOf, Real, validate
from .._errors import ParameterError
from .._objective import _total
from ..linesearch import Backtracking, _still_positive, max_injective_step
from ._base import AbstractSolver, Outcome, State

# status codes of the jitted loop
RUNNING, CONVERGED_F, CONVERGED_G, LS_FAILED, NONFINITE, MAX_STEPS = range(6)
_OUTCOMES = {
    CONVERGED_F: Outcome.CONVERGED,
    CONVERGED_G: Outcome.CONVERGED,
    LS_FAILED: Outcome.LINE_SEARCH_FAILED,
    NONFINITE: Outcome.NONFINITE,
    MAX_STEPS: Outcome.MAX_STEPS,
}
PRECONDITIONERS = ("scalar", "diagonal", "laplacian")


def _dot(a, b):
    return jnp.sum(a * b)


def _value_and_grad(density, geom, free, x, params):
    v, g = jax.value_and_grad(_total, argnums=2)(density, geom, x, params)
    return v, g * free


def _two_loop(S, Y, rho, k, seed, g):
    """``-H g`` for the L-BFGS inverse Hessian held in ring buffers S, Y (m, n, d), newest at
    slot ``(k-1) % m``; ``seed(q)`` applies the initial inverse Hessian."""
    m = S.shape[0]
    used = jnp.minimum(k, m)

    def back(j, carry):
        q, alpha = carry
        i = (k - 1 - j) % m
        a = rho[i] * _dot(S[i], q)
        return q - a * Y[i], alpha.at[i].set(a)

    q, alpha = lax.fori_loop(0, used, back, (g, jnp.zeros(m, g.dtype)))
    r = seed(q)

    def forward(j, r):
        i = (k - used + j) % m
        b = rho[i] * _dot(Y[i], r)
        return r + (alpha[i] - b) * S[i]

    return -lax.fori_loop(0, used, forward, r)


def _line_search(cfg, vg, S_el, x, f, g, d, t0, injective):
    """Weak-Wolfe step along ``d``: ``(t, x_t, f_t, g_t, ok)``; ``ok`` False on failure.

    ``injective``: start no further than ``safety * t_max`` (first root of a det) and reject
    points where an element positive at ``x`` is not."""
    c1, c2, shrink, max_ls, safety = cfg["c1"], cfg["c2"], cfg["shrink"], cfg["max_ls"], cfg["safety"]
    slope = _dot(g, d)
    inf = jnp.array(jnp.inf, x.dtype)

    def cap_and_signs(_):
        X = x[S_el]
        E = X[:, 1:] - X[:, :1]
        if E.shape[-1] == 2:
            det = E[:, 0, 0] * E[:, 1, 1] - E[:, 0, 1] * E[:, 1, 0]
        else:
            det = jnp.einsum("ij,ij->i", E[:, 0], jnp.cross(E[:, 1], E[:, 2]))
        return safety * max_injective_step(S_el, x, d), det > 0

    def no_cap(_):
        return inf, jnp.zeros(S_el.shape[0], bool)

    tcap, was_pos = cap_and_signs(None) if injective else no_cap(None)
    t = jnp.minimum(t0, tcap)

    def cond(c):
        return (~c["done"]) & (c["i"] < max_ls)

    def body(c):
        t = c["t"]
        xt = x + t * d
        ft, gt = vg(xt)
        pos = _still_positive(S_el, x, d, t, was_pos) if injective else jnp.bool_(True)
        armijo = pos & jnp.isfinite(ft) & (ft <= f + c1 * t * slope)
        curv = (_dot(gt, d) >= c2 * slope) if c2 > 0 else jnp.bool_(True)
        at_cap = t >= tcap * (1.0 - 1e-12)
        accept = armijo & (curv | at_cap)
        better = armijo & (ft < c["bf"])
        hi = jnp.where(armijo, c["hi"], t)
        lo = jnp.where(armijo, t, c["lo"])
        t_next = jnp.where(
            armijo,
            jnp.where(jnp.isfinite(hi), 0.5 * (lo + hi), jnp.minimum(2.0 * t, tcap)),
            jnp.where(lo > 0, 0.5 * (lo + hi), shrink * t),
        )
        return {
            "i": c["i"] + 1, "t": jnp.where(accept, t, t_next), "lo": lo, "hi": hi, "done": accept,
            "bt": jnp.where(better, t, c["bt"]), "bf": jnp.where(better, ft, c["bf"]),
            "bx": jnp.where(better, xt, c["bx"]), "bg": jnp.where(better, gt, c["bg"]),
        }

    c0 = {"i": jnp.int32(0), "t": t, "lo": jnp.zeros_like(t), "hi": inf, "done": jnp.bool_(False),
          "bt": jnp.zeros_like(t), "bf": jnp.asarray(f), "bx": x, "bg": g}
    c = lax.while_loop(cond, body, c0)
    # on a weak-Wolfe failure take the best Armijo point seen (if any)
    ok = c["bt"] > 0
    return c["bt"], c["bx"], c["bf"], c["bg"], ok, c["i"]


def _iterate(cfg, density, geom, free, params, injective, c):
    """One L-BFGS iteration on the carry ``c`` (a dict of arrays)."""
    vg = partial(_value_and_grad, density, geom, free, params=params)
    x, f, g, S, Y, rho, k, H0 = c["x"], c["f"], c["g"], c["S"], c["Y"], c["rho"], c["k"], c["H0"]
    laplacian = cfg["laplacian"]
    if laplacian:
        def solve(q):
            return jax.pure_callback(_laplacian_solve_host, jax.ShapeDtypeStruct(q.shape, q.dtype),
                                     c["pre"], q)

        def seed(q):
            return H0 * solve(q)
    else:
        def seed(q):
            return H0 * q
    d = _two_loop(S, Y, rho, k, seed, g)
    slope = _dot(g, d)
    restart = ~(slope < 0) | ~jnp.all(jnp.isfinite(d))
    d = jnp.where(restart, -g, d)
    k = jnp.where(restart, jnp.zeros_like(k), k)
    H0 = jnp.where(restart, jnp.ones_like(H0), H0)
    slope = jnp.where(restart, -_dot(g, g), slope)
    # without curvature pairs the step length is unknown: start with a unit move
    t0 = jnp.where(k == 0, 1.0 / jnp.maximum(jnp.sqrt(_dot(d, d)), 1e-300), 1.0)
    t, xn, fn, gn, ok, nls = _line_search(cfg, vg, geom[0], x, f, g, d, t0, injective)

    s, y = xn - x, gn - g
    sy, yy, ss = _dot(s, y), _dot(y, y), _dot(s, s)
    good = ok & (sy > 1e-10 * jnp.sqrt(ss * yy)) & jnp.isfinite(sy)
    m = S.shape[0]
    slot = k % m
    S = jnp.where(good, S.at[slot].set(s), S)
    Y = jnp.where(good, Y.at[slot].set(y), Y)
    rho = jnp.where(good, rho.at[slot].set(1.0 / jnp.where(good, sy, 1.0)), rho)
    if cfg["diagonal"]:
        # M1QN3 diagonal update (Gilbert & Lemarechal 1989) of the seed D, as in STLBFGS
        dinvss = _dot(s * s, 1.0 / H0)
        dyy = _dot(y * y, H0)
        newH0 = 1.0 / (dyy / (sy * H0) + y * y / sy - dyy * s * s / (sy * dinvss * H0 * H0))
        newH0 = jnp.where(jnp.isfinite(newH0) & (newH0 > 0), newH0, sy / yy)
    elif laplacian:
        yPy = _dot(y, solve(y))
        newH0 = sy / jnp.where(yPy > 0, yPy, 1.0)
    else:
        newH0 = sy / jnp.where(yy > 0, yy, 1.0)
    H0 = jnp.where(good, newH0, H0)
    k = jnp.where(good, k + 1, k).astype(jnp.int32)

    it = c["it"] + 1
    fnext = jnp.where(ok, fn, f)
    # energy test over the last `window` steps: f_hist holds the values after each of them
    W = cfg["window"]
    slot = c["it"] % W
    f_old = c["f_hist"][slot]  # the energy W steps ago (inf before W steps were taken)
    scale = jnp.maximum(jnp.abs(f_old), jnp.abs(fn))
    small_f = ok & jnp.isfinite(f_old) & (f_old - fn <= W * cfg["rtol"] * scale)
    f_hist = c["f_hist"].at[slot].set(jnp.where(ok, fn, f))
    gn_norm = jnp.sqrt(_dot(gn, gn))
    small_g = ok & (gn_norm <= cfg["gtol"] * c["g0"])
    # a failed line search along a direction that promises no representable decrease means
    # the start of this iteration was already stationary up to rounding
    flat = -slope <= 1e-14 * jnp.maximum(jnp.abs(f), 1e-300)
    status = jnp.where(
        ~ok, jnp.where(flat, CONVERGED_G, LS_FAILED),
        jnp.where(~jnp.isfinite(fn), NONFINITE,
                  jnp.where(small_g, CONVERGED_G, jnp.where(small_f, CONVERGED_F, RUNNING)))).astype(jnp.int32)
    return {
        "x": jnp.where(ok, xn, x), "f": fnext, "g": jnp.where(ok, gn, g), "S": S, "Y": Y,
        "rho": rho, "k": k, "H0": H0, "it": it, "prev_f": f, "t": t, "status": status,
        "f_hist": f_hist,
        "g0": c["g0"], "dec": -0.5 * t * slope, "nfev": (c["nfev"] + nls).astype(jnp.int32),
        "pre": c["pre"],
    }


@partial(jax.jit, static_argnums=(0, 1, 5))
def _step_kernel(cfg_items, density, geom, free, params, injective, carry):
    return _iterate(dict(cfg_items), density, geom, free, params, injective, carry)


@partial(jax.jit, static_argnums=(0, 1, 5))
def _run_kernel(cfg_items, density, geom, free, params, injective, carry, max_it):
    cfg = dict(cfg_items)

    def cond(c):
        return (c["status"] == RUNNING) & (c["it"] < max_it)

    return lax.while_loop(cond, partial(_iterate, cfg, density, geom, free, params, injective), carry)


def _initial_status(g):
    return jnp.where(jnp.all(g == 0), CONVERGED_G, RUNNING).astype(jnp.int32)


@partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _init_kernel(m, diagonal, window, density, geom, free, params, x, pre):
    f, g = _value_and_grad(density, geom, free, x, params)
    H0 = jnp.ones_like(x) if diagonal else jnp.ones((), x.dtype)
    return {
        "x": x, "f": f, "g": g, "S": jnp.zeros((m,) + x.shape, x.dtype),
        "Y": jnp.zeros((m,) + x.shape, x.dtype), "rho": jnp.zeros(m, x.dtype),
        "k": jnp.int32(0), "H0": H0, "it": jnp.int32(0), "prev_f": jnp.asarray(jnp.inf, x.dtype),
        "t": jnp.asarray(jnp.nan, x.dtype), "status": _initial_status(g),
        "g0": jnp.sqrt(_dot(g, g)), "dec": jnp.asarray(jnp.inf, x.dtype), "nfev": jnp.int32(1),
        "f_hist": jnp.full(window, jnp.inf, x.dtype).at[window - 1].set(f),
        "pre": pre,
    }


@dataclasses.dataclass(frozen=True)
class LBFGS(AbstractSolver):
    """Limited-memory BFGS (Liu & Nocedal 1989) with a weak-Wolfe line search.

    Attributes
    ----------
    history : number of correction pairs kept (``m``).
    rtol : stop when the last ``window`` steps decreased the energy by less than
        ``window * rtol * max(|E_k-window|, |E_k|)`` relative (``window = 1``: one step
        decreased it by less than ``rtol``).
    gtol : stop when ``|grad|_2 <= gtol * |grad at x0|_2``.
    max_steps : iteration limit.
    line_search : :class:`~geomopt.linesearch.Backtracking`, read for its constants
        (``injective``, ``safety``, ``c1``, ``shrink``, ``max_backtracks``).  Not injective by
        default: L-BFGS is the untangling solver, whose energy is finite on inverted elements;
        pass ``Backtracking(injective=True)`` to keep positive elements positive.
    c2 : curvature constant of the weak Wolfe condition (``0.9`` as usual for quasi-Newton);
        ``0`` turns it off (Armijo backtracking only; curvature pairs with ``s.y <= 0``
        are then skipped).
    precondition : the initial inverse Hessian of the two-loop recursion: ``"scalar"``
        (``s.y / y.y`` times the identity), ``"diagonal"`` (the M1QN3 diagonal update), or
        ``"laplacian"``: ``gamma K^-1`` with ``K`` the Hessian of the rest Dirichlet energy
        ``sum vol |J|^2`` on the free DOFs (a cotangent Laplacian per coordinate), factored
        once by a sparse Cholesky, and ``gamma = s.y / y.K^-1 y`` (a Sobolev gradient, as in
        the Laplacian-preconditioned quasi-Newton methods of Zhu et al. 2018 and Kovalsky et al.
        2016).  It makes L-BFGS's iteration count nearly independent of the mesh size on
        problems with large global motions (two host solves per iteration).
    window : number of iterations the energy test looks back over (see ``rtol``); a window
        avoids stopping on one unlucky short step when ``rtol`` is loose.

    Notes
    -----
    ``step`` runs one jitted iteration; :meth:`run` runs up to ``max_steps`` iterations in a
    single jitted ``lax.while_loop`` and stops on the same tests as ``terminate``.
    """

    history: int = 10
    rtol: float = 1e-10
    gtol: float = 1e-9
    max_steps: int = 1000
    line_search: Backtracking = Backtracking(injective=False)
    c2: float = 0.9
    precondition: str = "scalar"
    window: int = 1

    def __post_init__(self):
        validate(self, history=Int(1), rtol=Real(0.0, 1.0, hi_open=True),
                 gtol=Real(0.0, 1.0, hi_open=True), max_steps=Int(1),
                 line_search=Instance(Backtracking), c2=Real(0.0, 1.0, hi_open=True),
                 precondition=OneOf(PRECONDITIONERS), window=Int(1))
        if 0 < self.c2 <= self.line_search.c1:
            raise ParameterError(f"LBFGS: the Wolfe constants need c1 < c2, got c1={self.line_search.c1} "
                                 f"(line_search) and c2={self.c2}; lower c1 or raise c2 (0 turns the "
                                 f"curvature condition off)")

    # -- jit configuration ------------------------------------------------------------
    def _cfg(self):
        ls = self.line_search
        return (
            ("c1", float(ls.c1)), ("c2", float(self.c2)), ("diagonal", self.precondition == "diagonal"),
            ("laplacian", self.precondition == "laplacian"),
            ("gtol", float(self.gtol)), ("max_ls", int(ls.max_backtracks)), ("rtol", float(self.rtol)),
            ("safety", float(ls.safety)), ("shrink", float(ls.shrink)), ("window", int(self.window)),
        )

    @staticmethod
    def _args(objective):
        return objective.energy.density, objective.geom, objective._free

    def _state(self, state, carry):
        """A :class:`State` from a carry (pulls the scalars to the host)."""
        it, status, f, prev, t, dec = jax.device_get(
            (carry["it"], carry["status"], carry["f"], carry["prev_f"], carry["t"], carry["dec"]))
        failure = None
        if int(status) in (LS_FAILED, NONFINITE):
            failure = _OUTCOMES[int(status)]
        return dataclasses.replace(
            state, x=carry["x"], value=float(f), grad=carry["g"], iteration=int(it),
            step_size=float(t), decrement=float(dec), prev_value=float(prev), failure=failure,
            aux=dict(state.aux, carry=carry, status=int(status)),
        )

    # -- the interface ----------------------------------------------------------------
    def init(self, objective, x0, params, *, precompile: str | None = "step") -> State:
        """The start state.  ``precompile`` (``"step"``, ``"run"`` or None) compiles that
        kernel now, so that setup time holds the compilation."""
        density, geom, free = self._args(objective)
        x = jnp.asarray(x0, dtype=jnp.float64)
        pre = _LaplacianPreconditioner.register(objective) if self.precondition == "laplacian" else None
        carry = _init_kernel(self.history, self.precondition == "diagonal", self.window, density, geom,
                             free, params, x, jnp.int32(pre.handle if pre is not None else -1))
        inj = bool(self.line_search.injective)
        if precompile == "step":
            _step_kernel(self._cfg(), density, geom, free, params, inj, carry)
        elif precompile == "run":
            _run_kernel(self._cfg(), density, geom, free, params, inj, carry, jnp.int32(0))
        elif precompile is not None:
            raise ParameterError(f"precompile must be 'step', 'run' or None, got {precompile!r}")
        state = State(objective, params, x, float(carry["f"]), carry["g"],
                      aux={"carry": carry, "status": RUNNING, "injective": bool(self.line_search.injective),
                           "preconditioner": pre})
        return self._state(state, carry)

    def step(self, state: State) -> State:
        density, geom, free = self._args(state.objective)
        carry = _step_kernel(self._cfg(), density, geom, free, state.params,
                             bool(state.aux["injective"]), state.aux["carry"])
        return self._state(state, carry)

    def run(self, state: State, max_steps: int | None = None) -> State:
        """Iterate inside one jitted loop until ``terminate`` would stop (or ``max_steps``
        more iterations); returns the final state."""
        density, geom, free = self._args(state.objective)
        limit = self.max_steps if max_steps is None else state.iteration + int(max_steps)
        carry = state.aux["carry"]
        if state.aux["status"] != RUNNING:
            return state
        carry = _run_kernel(self._cfg(), density, geom, free, state.params,
                            bool(state.aux["injective"]), carry, jnp.int32(limit))
        return self._state(state, carry)

    def terminate(self, state: State):
        status = state.aux["status"]
        if status != RUNNING:
            return True, _OUTCOMES[status]
        if not np.isfinite(state.value):
            return True, Outcome.NONFINITE
        if state.iteration >= self.max_steps:
            return True, Outcome.MAX_STEPS
        return False, None

    @staticmethod
    def with_params(state: State, params, injective: bool | None = None) -> State:
        """The state with new energy parameters (value and gradient re-evaluated); the
        curvature memory is kept.  Used by continuation loops (eps in untangling)."""
        density, geom, free = LBFGS._args(state.objective)
        carry = state.aux["carry"]
        f, g = _vg_kernel(density, geom, free, params, carry["x"])
        carry = dict(carry, f=f, g=g, status=_initial_status(g), prev_f=jnp.asarray(jnp.inf, f.dtype),
                     g0=jnp.sqrt(_dot(g, g)), it=jnp.int32(0),
                     f_hist=jnp.full_like(carry["f_hist"], jnp.inf).at[-1].set(f))
        aux = dict(state.aux, carry=carry, status=int(carry["status"]))
        if injective is not None:
            aux["injective"] = bool(injective)
        return dataclasses.replace(state, params=params, value=float(f), grad=g, iteration=0,
                                   prev_value=float("inf"), failure=None, aux=aux)


@partial(jax.jit, static_argnums=0)
def _vg_kernel(density, geom, free, params, x):
    return _value_and_grad(density, geom, free, x, params)


# ------------------------------------------------------------------ Laplacian preconditioner

_LIVE_PRECONDITIONERS: "weakref.WeakValueDictionary[int, _LaplacianPreconditioner]" = \
    weakref.WeakValueDictionary()
_NEXT_HANDLE = itertools.count()


def _laplacian_solve_host(handle, q):
    """Host side of the preconditioner (``jax.pure_callback``): ``K^-1 q`` on the free DOFs."""
    return _LIVE_PRECONDITIONERS[int(handle)].solve(np.asarray(q))


class _LaplacianPreconditioner:
    """``K^-1`` for the rest Dirichlet Hessian ``K`` of an objective's problem on its free DOFs.

    Jitted kernels refer to it by an integer handle (traced, so new meshes or solves never
    recompile); it lives as long as a solver state holds it."""

    def __init__(self, objective):
        problem = objective.problem
        S, Minv, vol = problem.simplices, problem.rest_inv, problem.volumes
        n, d = problem.n_vertices, problem.dim
        G = np.concatenate([-Minv.sum(axis=1, keepdims=True), Minv], axis=1)  # (m, d+1, d)
        Ke = 2.0 * vol[:, None, None] * np.einsum("mai,mbi->mab", G, G)  # Hessian of vol |J|^2
        rows = np.repeat(S, d + 1, axis=1).ravel()
        cols = np.tile(S, (1, d + 1)).ravel()
        K = sp.csc_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))
        free = np.asarray(objective.free_dofs, bool)
        self.free = free
        self.per_vertex = bool(np.all(free.all(axis=1) | ~free.any(axis=1)))
        if self.per_vertex:
            self.rows = np.flatnonzero(free.any(axis=1))
            A = K[self.rows][:, self.rows]
        else:
            self.rows = np.flatnonzero(free.ravel())
            A = sp.kron(K, sp.identity(d), format="csc")[self.rows][:, self.rows]
        A = A.tocsc()
        # a tiny shift keeps it definite when a component has no fixed vertex
        A = A + sp.identity(A.shape[0], format="csc") * (1e-12 * max(float(A.diagonal().mean()), 1e-300)
                                                         if A.shape[0] else 0.0)
        self._solve = _factor_spd(A)

    def solve(self, q):
        out = np.zeros_like(q)
        if self.rows.size == 0:
            return out
        if self.per_vertex:
            out[self.rows] = self._solve(q[self.rows])
        else:
            flat = out.reshape(-1)
            flat[self.rows] = self._solve(q.reshape(-1)[self.rows])
        return out

    @classmethod
    def register(cls, objective):
        pre = cls(objective)
        pre.handle = next(_NEXT_HANDLE) % (2**31 - 1)
        _LIVE_PRECONDITIONERS[pre.handle] = pre
        return pre


def _factor_spd(A):
    """A solve function for the sparse SPD matrix ``A``: CHOLMOD when importable, else SuperLU."""
    try:
        from sksparse.cholmod import cholesky

        factor = cholesky(A)
        return lambda b: factor(b)
    except ImportError:  # pragma: no cover - depends on the machine
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        return lu.solve

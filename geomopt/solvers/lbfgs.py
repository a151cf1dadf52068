"""Limited-memory BFGS with a Wolfe line search, jitted end to end.

One iteration (Nocedal & Wright 2006, Algorithms 7.4 and 7.5) is the two-loop recursion
over a fixed-size ring buffer of correction pairs (``lax.fori_loop``), the shared
:class:`~geomopt.linesearch.InjectiveSearch` (weak Wolfe by default: it brackets by bisection /
doubling, Lewis & Overton 2013), and the memory update.  Two jitted programs per mesh shape
do everything: the iteration loop (``lax.while_loop`` up to a traced limit: :meth:`LBFGS.run`
runs it to the end without per-iteration Python dispatch, :meth:`LBFGS.step` one iteration
further) and the evaluation that starts a solve or re-parameterises it (``init``,
``with_params``).  They are keyed on the density, the array shapes and the solver's
configuration less ``max_steps``; energy parameters are traced, so changing eps / lambda never
recompiles.

The inverse-Hessian seed is the scalar ``s.y / y.y`` (``precondition="scalar"``), the
diagonal update of M1QN3 (Gilbert & Lemarechal 1989, ``"diagonal"``, as in the STLBFGS
library used by Garanzha et al. 2021), or a scaled inverse of the rest Dirichlet Hessian
(``"laplacian"``, the default; one solve with the rest Laplacian per iteration: see :func:`_two_loop`;
factored once on the host and applied through an XLA FFI target on CPU, by warm-started
conjugate gradients on the device elsewhere, so the loop makes no host round trip there).
"""

from __future__ import annotations

import dataclasses
import functools
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._errors import ParameterError
from .._objective import total_energy
from .._config import Int, OneOf, Real
from .._programs import jit as programs_jit
from ..linesearch import InjectiveSearch
from ._base import DIVERGENCE_FACTOR, AbstractSolver, Outcome, State, reference_extent
from ._laplacian import LAPLACIAN_BACKENDS, LaplacianOperator, RestLaplacian, laplacian_solve

__all__ = ["LBFGS", "PRECONDITIONERS"]

# status codes of the jitted loop
RUNNING, CONVERGED_F, CONVERGED_G, LS_FAILED, NONFINITE, MAX_STEPS, DIVERGED = range(7)
_OUTCOMES = {
    CONVERGED_F: Outcome.CONVERGED,
    CONVERGED_G: Outcome.CONVERGED,
    LS_FAILED: Outcome.LINE_SEARCH_FAILED,
    NONFINITE: Outcome.NONFINITE,
    MAX_STEPS: Outcome.MAX_STEPS,
    DIVERGED: Outcome.DIVERGED,
}
PRECONDITIONERS = ("scalar", "diagonal", "laplacian")


def _dot(a, b):
    return jnp.sum(a * b)


def _value_and_grad(density, geom, free, x, params):
    v, g = jax.value_and_grad(total_energy, argnums=2)(density, geom, x, params)
    return v, g * free


def _two_loop(S, Y, rho, k, seed, g, W=None, z=None):
    """``-H g`` for the L-BFGS inverse Hessian held in ring buffers S, Y (m, n, d), newest at
    slot ``(k-1) % m``; ``seed(q)`` applies the initial inverse Hessian.

    With ``W`` (m, n, d) holding ``P y_i`` and ``z = P g`` for a linear operator ``P`` (the
    Laplacian seed's ``K^-1``), the first loop carries ``P q = z - sum a_i P y_i`` alongside
    ``q`` and the seed is ``seed(P q)``: the same direction without applying ``P`` here."""
    m = S.shape[0]
    used = jnp.minimum(k, m)
    tracked = W is not None

    def back(j, carry):
        q, pq, alpha = carry
        i = (k - 1 - j) % m
        a = rho[i] * _dot(S[i], q)
        return q - a * Y[i], (pq - a * W[i]) if tracked else pq, alpha.at[i].set(a)

    q, pq, alpha = lax.fori_loop(0, used, back, (g, z if tracked else g, jnp.zeros(m, g.dtype)))
    r = seed(pq if tracked else q)

    def forward(j, r):
        i = (k - used + j) % m
        b = rho[i] * _dot(Y[i], r)
        return r + (alpha[i] - b) * S[i]

    return -lax.fori_loop(0, used, forward, r)


def _iterate(solver, density, geom, free, params, c):
    """One L-BFGS iteration on the carry ``c`` (a dict of arrays)."""
    def vg(x):
        return _value_and_grad(density, geom, free, x, params)
    x, f, g, S, Y, rho, k, H0 = c["x"], c["f"], c["g"], c["S"], c["Y"], c["rho"], c["k"], c["H0"]
    laplacian = solver.precondition == "laplacian"

    def seed(q):
        return H0 * q
    if laplacian:  # z = K^-1 g and W = K^-1 Y are carried: no solve for the direction
        d = _two_loop(S, Y, rho, k, seed, g, W=c["W"], z=c["z"])
    else:
        d = _two_loop(S, Y, rho, k, seed, g)
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
    # in place (dynamic-update-slice): a select between whole buffers would copy them
    S = S.at[slot].set(jnp.where(good, s, S[slot]))
    Y = Y.at[slot].set(jnp.where(good, y, Y[slot]))
    rho = rho.at[slot].set(jnp.where(good, 1.0 / jnp.where(good, sy, 1.0), rho[slot]))
    extra = {}
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
        extra = {"z": zn, "W": c["W"].at[slot].set(jnp.where(good, w, c["W"][slot]))}
        yPy = _dot(y, w)
        newH0 = sy / jnp.where(yPy > 0, yPy, 1.0)
    else:
        newH0 = sy / jnp.where(yy > 0, yy, 1.0)
    H0 = jnp.where(good, newH0, H0)
    k = jnp.where(good, k + 1, k).astype(jnp.int32)

    it = c["it"] + 1
    fnext = jnp.where(ok, fn, f)
    # energy test over the last `window` steps: f_hist holds the values after each of them
    W = solver.window
    slot = c["it"] % W
    f_old = c["f_hist"][slot]  # the energy W steps ago (inf before W steps were taken)
    scale = jnp.maximum(jnp.abs(f_old), jnp.abs(fn))
    # a stalled energy counts only when a full step promises little more (else the search is
    # cutting steps short: a barrier of the injective cap, an energy unbounded below)
    small_f = ok & jnp.isfinite(f_old) & (f_old - fn <= W * solver.rtol * scale) & \
        (-slope <= jnp.sqrt(solver.rtol) * scale)
    f_hist = c["f_hist"].at[slot].set(jnp.where(ok, fn, f))
    gn_norm = jnp.sqrt(_dot(gn, gn))
    small_g = ok & (gn_norm <= solver.gtol * c["g0"])
    xk = jnp.where(ok, xn, x)
    extent = jnp.max(jnp.max(xk, axis=0) - jnp.min(xk, axis=0))
    diverged = (extent > DIVERGENCE_FACTOR * c["extent0"]) | (extent * DIVERGENCE_FACTOR < c["extent0"])
    # a failed line search along a direction that promises no representable decrease means
    # the start of this iteration was already stationary up to rounding
    flat = -slope <= 1e-14 * jnp.maximum(jnp.abs(f), 1e-300)
    status = jnp.where(
        ~ok, jnp.where(flat, CONVERGED_G, LS_FAILED),
        jnp.where(~jnp.isfinite(fn), NONFINITE,
                  jnp.where(diverged, DIVERGED,
                            jnp.where(small_g, CONVERGED_G, jnp.where(small_f, CONVERGED_F, RUNNING))))
    ).astype(jnp.int32)
    return {
        "x": xk, "f": fnext, "g": jnp.where(ok, gn, g), "S": S, "Y": Y,
        "rho": rho, "k": k, "H0": H0, "it": it, "prev_f": f, "t": t, "status": status,
        "f_hist": f_hist,
        "g0": c["g0"], "dec": -0.5 * t * slope, "nfev": (c["nfev"] + nls).astype(jnp.int32),
        "pre": c["pre"], "extent0": c["extent0"], **extra,
    }


@partial(programs_jit, static_argnums=(0, 1))
def _run_kernel(solver, density, geom, free, params, carry, max_it):
    """Iterations while the status is RUNNING and ``it < max_it`` (traced): ``step`` is one
    call with ``max_it = it + 1``, so one compiled program serves ``step`` and ``run``.
    ``solver`` is the key of :meth:`LBFGS._kernel_key` (``max_steps`` left out)."""
    def cond(c):
        return (c["status"] == RUNNING) & (c["it"] < max_it)

    return lax.while_loop(cond, partial(_iterate, solver, density, geom, free, params), carry)


def _initial_status(g):
    return jnp.where(jnp.all(g == 0), CONVERGED_G, RUNNING).astype(jnp.int32)


def _blank_carry(m, precondition, window, x, pre, extent0):
    """The carry of :func:`_iterate` before the first evaluation, built on the host (nothing
    to compile): empty memory, unit seed, counters at zero; ``f``, ``g`` and the evaluation
    dependent entries are set by :func:`_reparam_kernel`.  ``x`` (n, d) float64."""
    n, d = x.shape
    f8 = np.float64
    carry = {
        "x": x, "f": f8(np.nan), "g": np.zeros((n, d)), "S": np.zeros((m, n, d)), "Y": np.zeros((m, n, d)),
        "rho": np.zeros(m), "k": np.int32(0), "H0": np.ones((n, d)) if precondition == "diagonal" else f8(1.0),
        "it": np.int32(0), "prev_f": f8(np.inf), "t": f8(np.nan), "status": np.int32(RUNNING),
        "g0": f8(np.nan), "dec": f8(np.inf), "nfev": np.int32(1), "f_hist": np.full(window, np.inf),
        "pre": pre if isinstance(pre, LaplacianOperator) else np.int32(pre), "extent0": f8(extent0),
    }
    if precondition == "laplacian":
        carry.update(z=np.zeros((n, d)), W=np.zeros((m, n, d)))
    return jax.device_put(carry)


@partial(programs_jit, static_argnums=(0, 1))
def _reparam_kernel(laplacian, density, geom, free, params, carry):
    """``carry`` re-evaluated at its ``x`` under ``params``: value, gradient (and for the
    Laplacian seed ``K^-1 grad``), status, and the counters and energy window restarted; the
    curvature memory and the evaluation count are kept.  Serves ``init`` and ``with_params``."""
    f, g = _value_and_grad(density, geom, free, carry["x"], params)
    out = dict(carry, f=f, g=g, status=_initial_status(g), prev_f=jnp.asarray(jnp.inf, f.dtype),
               g0=jnp.sqrt(_dot(g, g)), it=jnp.int32(0),
               f_hist=jnp.full_like(carry["f_hist"], jnp.inf).at[-1].set(f))
    if laplacian:  # warm start (device CG) from the last K^-1 g
        out["z"] = laplacian_solve(carry["pre"], g, carry["z"])
    return out


@dataclasses.dataclass(frozen=True)
class LBFGS(AbstractSolver):
    """Limited-memory BFGS (Liu & Nocedal 1989) with the shared injective search.

    Attributes
    ----------
    history : number of correction pairs kept (``m``).
    rtol : stop when the last ``window`` steps decreased the energy by less than
        ``window * rtol * max(|E_k-window|, |E_k|)`` relative (``window = 1``: one step
        decreased it by less than ``rtol``).
    gtol : stop when ``|grad|_2 <= gtol * |grad at x0|_2``.
    max_steps : iteration limit.
    search : :class:`~geomopt.linesearch.InjectiveSearch`; weak Wolfe (``c2 = 0.9``),
        injective, first trial at most a quarter of the flip bound by default (as
        :class:`~geomopt.AQP`'s: the Laplacian seed does not see the barrier; at the other
        solvers' 0.9, camelhead from its Tutte map took 816 iterations to a 1e-4 gap, 164 at
        0.25).  The untangling solver (:func:`geomopt.untangle.default_solver`) turns
        ``injective`` off: its energy is finite on inverted elements.
    precondition : the initial inverse Hessian of the two-loop recursion: ``"scalar"``
        (``s.y / y.y`` times the identity), ``"diagonal"`` (the M1QN3 diagonal update), or
        ``"laplacian"``: ``gamma K^-1`` with ``K`` the Hessian of the rest Dirichlet energy
        ``sum vol |J|^2`` on the free DOFs (a cotangent Laplacian per coordinate, assembled by
        :class:`~geomopt.Objective`), factored once by a sparse Cholesky, and
        ``gamma = s.y / y.K^-1 y`` (a Sobolev gradient, as in the Laplacian-preconditioned
        quasi-Newton methods of Zhu et al. 2018 and Kovalsky et al. 2016).  It makes
        L-BFGS's iteration count nearly independent of the mesh size on problems with large
        global motions (one Laplacian solve per iteration).  The default: from a Tutte map the
        scalar and diagonal seeds were still at a gap > 1 after 1,000 iterations on camelhead
        and bunny_cut; on the saddle at 1.5k/6k/25k triangles the scalar seed took
        125/253/630 iterations to 1e-4, the Laplacian one 13/15/16; on a twisted cube of
        1.3k/6k/16k tets 17/32/51 against 7/7/8 to 1e-6 (``benchmarks/solvers.py``).
    laplacian : where ``"laplacian"`` applies ``K^-1``: ``"host"`` (sparse Cholesky on the
        host through an XLA FFI target, :mod:`geomopt._hostcall`; exact), ``"device"`` (Jacobi-preconditioned CG in
        JAX, warm-started from the previous iteration's solution, relative tolerance 1e-3: no
        host round trip on an accelerator), or ``"auto"`` (host on CPU, device elsewhere).
    window : number of iterations the energy test looks back over (see ``rtol``).

    Notes
    -----
    ``step`` runs one iteration and :meth:`run` up to ``max_steps`` iterations, both in the
    same jitted ``lax.while_loop`` (a traced limit), which stops on the same tests as
    ``terminate``.
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

    @staticmethod
    def _args(objective):
        return objective.energy.density, objective.geom, objective._free

    def _state(self, state, carry):
        """A :class:`State` from a carry (pulls the scalars to the host)."""
        it, status, f, prev, t, dec, nfev = jax.device_get(
            (carry["it"], carry["status"], carry["f"], carry["prev_f"], carry["t"], carry["dec"],
             carry["nfev"]))
        failure = None
        if int(status) in (LS_FAILED, NONFINITE, DIVERGED):
            failure = _OUTCOMES[int(status)]
        return dataclasses.replace(
            state, x=carry["x"], value=float(f), grad=carry["g"], iteration=int(it),
            step_size=float(t), decrement=float(dec), prev_value=float(prev), failure=failure,
            evaluations=int(nfev), aux=dict(state.aux, carry=carry, status=int(status)),
        )

    @functools.cached_property
    def _kernel_key(self):
        """The static key of :func:`_run_kernel`: this configuration less ``max_steps`` (a
        traced limit there), so solvers that differ only in it share the compiled loop."""
        return dataclasses.replace(self, max_steps=1)

    # -- the interface ----------------------------------------------------------------
    def init(self, objective, x0, params, *, precompile: str | None = "step") -> State:
        """The start state.  ``precompile`` (``"step"``, ``"run"`` or None) compiles the
        iteration kernel now (``step`` and ``run`` share it), so that setup time holds the
        compilation."""
        density, geom, free = self._args(objective)
        if precompile not in ("step", "run", None):
            raise ParameterError(f"precompile must be 'step', 'run' or None, got {precompile!r}")
        # a private copy put on the device as it is (jnp.asarray would compile a copy program
        # per shape)
        x = jax.device_put(np.array(objective.pad_map(np.asarray(x0, dtype=np.float64))))
        pre = RestLaplacian.register(objective, self.laplacian) if self.precondition == "laplacian" else None
        extent0 = reference_extent(objective, x0)
        blank = _blank_carry(self.history, self.precondition, self.window, x,
                             pre.token if pre is not None else -1, extent0)
        carry = _reparam_kernel(self.precondition == "laplacian", density, geom, free, params, blank)
        if precompile is not None:  # zero iterations: compiles (or loads) the loop, changes nothing
            _run_kernel(self._kernel_key, density, geom, free, params, carry, jnp.int32(0))
        state = State(objective, params, x, float(carry["f"]), carry["g"], extent0=extent0,
                      aux={"carry": carry, "status": RUNNING, "preconditioner": pre})
        return self._state(state, carry)

    def _iterations(self, state: State, limit: int) -> State:
        density, geom, free = self._args(state.objective)
        carry = _run_kernel(self._kernel_key, density, geom, free, state.params, state.aux["carry"],
                            jnp.int32(limit))
        return self._state(state, carry)

    def step(self, state: State) -> State:
        """One iteration (none when the state has stopped: see :meth:`terminate`)."""
        return self._iterations(state, state.iteration + 1)

    def run(self, state: State, max_steps: int | None = None) -> State:
        """Iterate inside one jitted loop until ``terminate`` would stop (or ``max_steps``
        more iterations); returns the final state."""
        if state.aux["status"] != RUNNING:
            return state
        limit = self.max_steps if max_steps is None else min(self.max_steps, state.iteration + int(max_steps))
        return self._iterations(state, limit)

    def terminate(self, state: State):
        status = state.aux["status"]
        if status != RUNNING:
            return True, _OUTCOMES[status]
        if not np.isfinite(state.value):
            return True, Outcome.NONFINITE
        if state.iteration >= self.max_steps:
            return True, Outcome.MAX_STEPS
        return False, None

    def with_params(self, state: State, params) -> State:
        """The state with new energy parameters (value and gradient re-evaluated); the
        curvature memory is kept.  Used by continuation loops (eps in untangling)."""
        density, geom, free = self._args(state.objective)
        carry = _reparam_kernel(self.precondition == "laplacian", density, geom, free, params,
                                state.aux["carry"])
        state = dataclasses.replace(state, params=params, failure=None)
        return self._state(state, carry)

    def forget(self, state: State) -> State:
        """The state with the curvature memory cleared (a restart)."""
        carry = state.aux["carry"]
        # host-built constants: no per-shape fill kernel to compile or dispatch
        carry = dict(carry, **jax.device_put({"k": np.int32(0), "H0": np.ones(carry["H0"].shape)}))
        return dataclasses.replace(state, aux=dict(state.aux, carry=carry))

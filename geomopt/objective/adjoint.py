"""Differentiable solves: a converged map as a function of its inputs, by the implicit function
theorem at the optimum (never by unrolling the iterations).

A solve returns ``x*`` with ``g_D(x*, theta) = 0``: the gradient of the energy on its free
DOFs ``D`` vanishes, ``theta`` being everything the energy depends on (the rest geometry of an
:class:`~geomopt.Objective`, hence the rest vertices it was built from, its element weights,
the handle positions and the energy parameters such as ``lam``, ``eps``).  Differentiating,
``H dx = -(dg/dtheta) dtheta`` with ``H`` the exact (unprojected) Hessian on ``D`` at ``x*``,
so a cotangent ``xbar`` of the map pulls back as

    ``lam = H^+ xbar``  (one sparse solve),   ``thetabar = -d/dtheta <g(x*, theta), lam>``

(one JAX reverse-over-forward pass of the energy), as in optimistix's ``ImplicitAdjoint`` and
jaxopt's ``custom_root`` (Blondel et al. 2022, "Efficient and modular implicit
differentiation").  :func:`argmin` wires this as a ``jax.custom_jvp``: the tangent is
``dx = -H^+ (dg/dtheta) dtheta``, the right-hand side a (compiled) JAX ``jvp`` of the gradient,
the solve a ``jax.lax.custom_linear_solve`` (symmetric) whose solve runs on the host; JAX
transposes both for reverse mode.  So ``jax.jvp``, ``jax.jacfwd``, ``jax.grad``, ``jax.vjp``,
``jax.jacrev`` and ``jax.vmap`` of them work, eagerly and inside ``jax.jit`` (the forward solve and
the sparse solves run on the host through ``jax.pure_callback``, one per batch element), and so
do second derivatives (``jax.hessian``) of maps held by handles: the solve's operator is the
exact Hessian-vector product, whose own derivative enters through ``custom_linear_solve``;
where the map has a gauge (below) the derivative of ``H^+`` is not that, and second
derivatives are refused (SolveError).

**One factorization per optimum.**  The numeric factor of a mesh is shared by every solve of it
(its symbolic analysis too): a forward's adjoint system keeps its own matrix and refactors it
when another solve (the next batch element under ``vmap``, a second solve in the same loss)
refactored the shared factor since (:attr:`geomopt.linalg.linsolve.SparseCholesky.generation`), so each
backward solves with the Hessian at its own optimum.

**Conventions.**

* The start map has zero derivative by construction: the optimum does not depend on where
  the solve started (except through the gauge, below).
* The handles' rows of the map are the handle positions themselves (derivative: identity).
* **Gauge.**  Where the optimum is not unique, the energy is invariant under motions of the
  map: translations (no handle), rotations (rotation-invariant energies; about the handle with
  one handle) and scaling (scale-invariant energies such as MIPS), detected on the density
  (:func:`gauge_motions`).  Their span ``N`` at ``x*`` is the null space of ``H``; the
  derivative returned is the minimum-norm one, orthogonal to ``N`` (``H^+`` above is the
  pseudo-inverse, ``xbar`` projected onto ``N``'s orthogonal complement first).  A loss that
  is invariant under these motions (areas, angles, distortion) gets its true gradient; one
  that is not gets the derivative of the map's gauge-free part.  Computed exactly: ``dim N``
  well-chosen DOFs are pinned (column-pivoted QR on ``N``), which leaves a matrix that is
  positive definite exactly when ``H`` is positive definite modulo ``N``, then the solution
  is projected onto ``N``'s orthogonal complement.
* **The map returned** is the solve's map refined by one exact Newton step modulo the gauge
  (``x - H^+ g``, kept only when still flip-free by the exact predicate): the optimum to
  rounding, so that the derivative and re-solves agree (an energy-based stopping rule leaves
  the map accurate to about the square root of the machine precision only).
* Refusals (:class:`~geomopt.SolveError`, never a silent wrong gradient), by the forward: a
  solve that did not succeed (converged and certified injective); a map whose Newton
  decrement ``g.H^+ g / 2`` exceeds :data:`DECREMENT_RTOL` ``* |E|`` (not a tight enough
  optimum for the theorem); an exact Hessian that is not positive definite modulo the gauge
  (a saddle or a degenerate minimum: the map is then not a differentiable function of its
  inputs).  Under ``jax.jit`` (or ``jax.hessian``'s batching) these surface as JAX's runtime
  error (``jax.errors.JaxRuntimeError``: no exception class crosses a compiled program) whose
  text ends with the class name and message, e.g. ``SolveError: implicit differentiation: ...``.

**Linear solves.**  ``linear_solver="auto"`` solves as the forward Newton would
(:func:`geomopt.linalg.linsolve.newton_linear_solver`): a sparse Cholesky (:mod:`geomopt.linalg.linsolve`,
its symbolic analysis shared with every solve of the mesh, :meth:`~geomopt.Objective.cholesky`)
or block-Jacobi CG (:mod:`geomopt.objective.cg`, whose positive-definiteness test only sees its Krylov
space).  The forward's refinement factors the exact Hessian once; the adjoint reuses that
factorization while the refining step stayed below :data:`REUSE_STEP` times the shortest edge
(the Hessian at the returned map then agrees with it to about that relative precision), else
it factors again at the returned map; either way one factorization serves every cotangent of
the same map (``jax.jacrev`` rows).  The forward solver's own last factorization is of another
matrix (the previous iterate, shifted) and is not used.
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import threading
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .cg import NewtonCG, cg_system, pcg
from .._runtime.errors import ParameterError, SolveError
from .gauge import gauge_motions, gauge_pins
from .objective import Objective, block_hessian, check_element_weights, jit
from .._runtime.tracing import is_traced
from .._runtime.x64 import float64, pure_callback
from ..linalg.linsolve import BACKENDS, NotPositiveDefinite, newton_linear_solver
from ..mesh.problem import check_rest_values

__all__ = ["argmin", "require_success", "host_constant", "gauge_motions", "DECREMENT_RTOL", "AdjointSystem"]

#: the largest Newton decrement ``g.H^+ g / 2``, relative to ``|E|``, at which a map is taken as
#: an optimum to differentiate (Newton's default stopping rule ends far below it)
DECREMENT_RTOL = 1e-10
#: relative residual of the CG adjoint solve
CG_RTOL = 1e-10
#: the forward's factorization is reused by the adjoint when its refining step moved no vertex
#: by more than this times the shortest edge of the map
REUSE_STEP = 1e-8


def _shortest_edge(x, S) -> float:
    return float(np.linalg.norm(x[S[:, 1:]] - x[S[:, :1]], axis=-1).min())


# --------------------------------------------------------------------- the core


@float64
def argmin(objective: Objective, params, x0, solve, linear_solver: str = "auto"):
    """The minimiser ``x*`` (n, d) of ``objective`` found by ``solve``, differentiable with
    respect to ``objective`` (its pytree leaves: rest geometry, element weights, handle
    positions) and ``params`` by the implicit function theorem (module notes).

    Parameters
    ----------
    objective : :class:`~geomopt.Objective`, possibly built from traced arrays.
    params : dict of energy parameters (floats or JAX scalars, traced or not).
    x0 : the start, passed to ``solve`` (zero derivative); any pytree of arrays.
    solve : host function ``(objective, params, x0) -> (x, context)`` on concrete values:
        ``x`` (n, d) the optimum (raise :class:`~geomopt.SolveError` if there is none),
        ``context`` a dict that may hold ``objective`` (a concrete one to assemble Hessians
        with) or None.
    linear_solver : ``"auto"``, a :data:`~geomopt.linalg.linsolve.BACKENDS` name or ``"cg"``.

    Returns
    -------
    (n, d) JAX array: the map, its handle rows equal to the handle positions.
    """
    if linear_solver not in BACKENDS + ("cg",):
        raise ParameterError(f"linear_solver must be one of {', '.join(BACKENDS + ('cg',))}, got {linear_solver!r}")
    if not isinstance(objective, Objective):
        raise ParameterError(f"argmin needs a geomopt.Objective, got {type(objective).__name__}")
    params = objective.params(**params)
    n, d = objective.problem.n_vertices, objective.problem.dim
    shape = jax.ShapeDtypeStruct((n, d), jnp.float64)
    token = jax.ShapeDtypeStruct((), jnp.int64)

    def forward(obj, p, x0):
        return _host(partial(_forward, solve, linear_solver), (shape, token), obj, p, x0)

    @jax.custom_jvp
    def f(obj, p, x0):  # (the map, the token of its forward's context)
        return forward(obj, p, x0)

    @f.defjvp
    def f_jvp(primals, tangents):
        obj, p, x0 = primals
        x, tok = f(obj, p, x0)  # through this very rule again under a second derivative
        if not is_traced(obj, p, x):  # eager: the JAX assembly here, not inside the solve's callback
            _adjoint_system(linear_solver, tok, obj, p, x)
        dg = _residual_tangent(obj, p, x, *tangents[:2])

        def solve(_, b):  # H^+ b on the host, with the factorization of this very optimum
            return _host(partial(_adjoint, linear_solver), shape, tok, obj, p, x, b)

        dx = -jax.lax.custom_linear_solve(partial(_hvp, tok, obj, p, x), dg, solve, symmetric=True)
        return (x, tok), (dx, np.zeros((), jax.dtypes.float0))

    x = f(objective, params, x0)[0]
    fixed = objective.problem.fixed
    return x.at[fixed].set(objective.problem.fixed_positions) if fixed.size else x


def _host(fn, shapes, *args):
    """``fn(*args)`` on the host: called directly on concrete values (errors keep their type),
    through ``jax.pure_callback`` on traced ones (one call per batch element under vmap)."""
    if not is_traced(args):
        out = fn(*args)
        return jax.tree_util.tree_map(lambda o, s: jnp.asarray(o, s.dtype), out, shapes)
    return pure_callback(fn, shapes, *args, vmap_method="sequential")


def _residual(obj, p, x):
    """``grad_x E(x, obj, p)`` (n, d) with the handle rows of ``x`` taken from the objective
    (so that handle positions get their share of the derivative)."""
    P = obj.problem
    xh = x.at[P.fixed].set(P.fixed_positions) if P.fixed.size else x
    return jax.grad(lambda y: obj.value(y, p))(xh)


@jax.jit
def _residual_tangent(obj, p, x, dobj, dp):
    """``d/d(obj, p) grad_x E(x, obj, p) . (dobj, dp)`` (n, d): the right-hand side of the
    forward-mode solve, linear in the tangents (its transpose is reverse mode's pullback);
    compiled, also when transposed."""
    return jax.jvp(partial(_residual, x=x), (obj, p), (dobj, dp))[1]


@jax.custom_jvp
def _hvp(tok, obj, p, x, v):
    """The exact Hessian at ``x`` on the free DOFs applied to ``v`` (n, d): the operator whose
    inverse the host solve applies, traced only when a second derivative differentiates it
    (then refused where the map has a gauge: the derivative of ``H^+`` is not ``H``'s)."""
    free = jnp.asarray(obj.free_dofs, v.dtype)
    return jax.jvp(partial(_residual, obj, p), (x,), (v * free,))[1] * free


@_hvp.defjvp
def _hvp_jvp(primals, tangents):
    one = _host(_gauge_free, jax.ShapeDtypeStruct((), jnp.float64), *primals[:4])
    out, dout = jax.jvp(_hvp.fun, primals, tangents)
    return out, dout * one


@float64
def _gauge_free(token, objective, params, x):
    """1.0 when the map ``x`` has no gauge motion (:func:`gauge_motions`), else SolveError."""
    with _lock:
        ctx = _CONTEXTS.get(int(np.asarray(token))) or {}
    system = ctx.get("system")
    obj = ctx.get("objective") or _concrete(objective)
    r = system.N.shape[1] if system is not None else gauge_motions(obj, _floats(params), np.asarray(x)).shape[1]
    if r:
        raise SolveError(f"implicit differentiation: second derivatives (jax.hessian, jacfwd of grad) of a map "
                         f"with {r} gauge motion(s) (translations/rotations/scale that leave the energy "
                         f"unchanged) are not supported; hold the map by handles, or use first derivatives")
    return np.float64(1.0)


# --------------------------------------------------------------------- host side

_CONTEXTS: collections.OrderedDict = collections.OrderedDict()
_KEEP = 8  # forward solves whose context (objective, factorization) is kept for their adjoint
_counter = itertools.count(1)
_lock = threading.Lock()


def _concrete(objective: Objective) -> Objective:
    """``objective`` with device arrays, its problem's and weights' values checked (they were
    not when it was built from traced arrays)."""
    obj = jax.tree_util.tree_map(jax.device_put, objective)
    check_rest_values(obj.problem)
    if obj.element_weights is not None:
        check_element_weights(np.asarray(obj.element_weights), obj.problem.n_elements)
    return obj


def _floats(params) -> dict:
    return {k: float(np.asarray(v)) for k, v in params.items()}


@float64
def _forward(solve, linear_solver, objective, params, x0):
    """Solve, then refine the map by one exact Newton step modulo the gauge (module notes)."""
    params = _floats(params)
    obj = _concrete(objective)
    x, ctx = solve(obj, params, x0)
    ctx = dict(ctx or {})
    obj = ctx.setdefault("objective", obj)
    x = np.asarray(x, np.float64)
    system = AdjointSystem(obj, params, x, linear_solver)
    x1 = x + system.step
    if obj.problem.count_inverted(x1) == 0:
        # the factorization at x serves the adjoint at x1 while the step is at rounding level
        # (the Hessian then agrees to about that relative precision), else it is redone there
        if np.abs(system.step).max() > REUSE_STEP * _shortest_edge(x1, obj.problem.simplices):
            system = None
        x = x1
    ctx["system"] = system
    with _lock:
        token = next(_counter)
        _CONTEXTS[token] = ctx
        while len(_CONTEXTS) > _KEEP:
            _CONTEXTS.popitem(last=False)
    return np.asarray(x, np.float64), np.int64(token)


@float64
def _adjoint(linear_solver, token, objective, params, x, xbar):
    """``lam = H^+ P xbar`` (n, d) at the optimum ``x`` (module notes)."""
    return _adjoint_system(linear_solver, token, objective, params, x).solve(np.asarray(xbar, np.float64))


@float64
def _adjoint_system(linear_solver, token, objective, params, x):
    """The :class:`AdjointSystem` of the forward ``token``: kept by the forward, else assembled
    at ``x`` (the forward ran elsewhere or long ago, or its refining step was too long) and kept.
    Its JAX assembly deadlocked inside a host callback on an 11k-triangle mesh: eagerly, the
    forward-mode rule calls this directly first."""
    with _lock:
        ctx = _CONTEXTS.get(int(np.asarray(token)))
    if ctx is None:
        ctx = {}
    if ctx.get("system") is None:
        obj = ctx.get("objective") or _concrete(objective)
        ctx["system"] = AdjointSystem(obj, _floats(params), np.asarray(x, np.float64), linear_solver, check=False)
    return ctx["system"]


# --------------------------------------------------------------------- the adjoint system


@dataclasses.dataclass(eq=False)
class AdjointSystem:
    """The exact Hessian at an optimum, the gauge pinned, factored or applied by CG: solves
    ``H lam = P xbar`` for any number of cotangents (see the module notes).

    Raises SolveError on construction when ``H`` is not positive definite modulo the gauge
    or, with ``check``, ``x`` is not a tight optimum (then :attr:`step` is the Newton step
    ``-H^+ g`` (n, d) and :attr:`decrement` ``g.H^+ g / 2``)."""

    objective: Objective
    params: dict
    x: np.ndarray
    linear_solver: str = "auto"
    check: bool = True  # test the decrement (and compute the refining step)

    def __post_init__(self):
        obj, x = self.objective, self.x
        self.N = gauge_motions(obj, self.params, x)
        self.pins = gauge_pins(self.N, obj.free_dofs)
        pat = obj.pattern
        n_free = int(np.count_nonzero(obj.free_dofs))
        kind = self.linear_solver
        if kind == "auto":
            kind = newton_linear_solver(obj.problem.dim, n_free, jax.default_backend())
            kind = "cg" if kind == "cg" else "auto"
        self.kind = kind
        p = {k: jnp.float64(v) for k, v in self.params.items()}
        xp = obj.pad_map(x)
        if kind == "cg":
            self._cg_setup(xp, p)
        else:
            value, grad, data = obj.hessian(xp, p, "none")
            self.value = float(value)
            data = np.array(data)
            self._pin(data, pat)
            self.chol, self.data = obj.cholesky(kind), data
            self._factor()
            self.grad = np.asarray(obj.unpad_map(grad))
        if self.check:
            self._check_decrement()

    def _factor(self):
        """Factor :attr:`data` with the mesh's shared :class:`~geomopt.linalg.linsolve.SparseCholesky`
        (its symbolic analysis shared, its numeric factor refactored by any later solve of the
        mesh: :attr:`generation` is the factorization that holds this map's matrix)."""
        try:
            self.chol.factor(self.data)
        except NotPositiveDefinite:
            raise SolveError(self._not_pd()) from None
        self.generation = self.chol.generation

    def _pin(self, data, pat):
        """Replace the rows and columns of the pinned free DOFs by identity ones, in place."""
        if not self.pins.size:
            return
        cols = np.repeat(np.arange(pat.n), np.diff(pat.indptr))
        hit = np.isin(pat.indices, self.pins) | np.isin(cols, self.pins)
        data[hit] = 0.0
        diag = data[pat.diag]
        data[pat.diag[self.pins]] = max(float(np.mean(np.abs(diag))), 1e-300)

    def _not_pd(self):
        what = " modulo its gauge (rotations/translations/scale of the map)" if self.N.shape[1] else ""
        return ("implicit differentiation: the exact Hessian of the energy at the map is not positive "
                f"definite on the free DOFs{what}: the map is a saddle or a degenerate minimum, where it "
                "is not a differentiable function of its inputs (fix more vertices, or check the energy)")

    def _check_decrement(self):
        """The Newton step ``-H^+ g`` (n, d) modulo the gauge (:attr:`step`) and the decrement;
        SolveError when it is above DECREMENT_RTOL * |E|."""
        g = self.grad
        z = self._solve_free(self._free(g))
        dec = 0.5 * float(np.dot(self._free(g), z))
        self.step = -self._embed(z, g.shape)
        scale = max(abs(self.value), 1e-300)
        self.decrement = dec
        if not dec <= DECREMENT_RTOL * scale:
            raise SolveError(f"implicit differentiation: the map is not a tight enough optimum (Newton "
                             f"decrement {dec:.3g} > {DECREMENT_RTOL:g} * |E| = {DECREMENT_RTOL * scale:.3g}); "
                             f"solve to a tighter tolerance, e.g. solver=Newton(rtol=1e-12)")

    def _project(self, v):
        """``v`` (n, d) minus its component along the gauge motions."""
        N = self.N
        flat = v.reshape(-1)
        return (flat - N @ (N.T @ flat)).reshape(v.shape) if N.shape[1] else v

    def _free(self, v):
        """The free-DOF vector of ``v`` (n, d) with the gauge pins zeroed."""
        out = v.reshape(-1)[self.objective.pattern.free_dofs].copy()
        out[self.pins] = 0.0
        return out

    def _solve_free(self, b):
        if self.kind == "cg":
            return self._cg_solve(b)
        with _lock:  # another solve of the mesh (a forward, a batch element) refactored it since
            if self.chol.generation != self.generation:
                self._factor()
            try:
                return self.chol.solve(b)
            except NotPositiveDefinite:  # a float32 factor's refinement that did not converge
                raise SolveError(self._not_pd()) from None

    def _embed(self, mu_free, shape):
        """The free-DOF solution ``mu_free`` as an (n, d) array (zero on fixed DOFs and gauge
        pins), projected orthogonally to the gauge motions."""
        mu_free[self.pins] = 0.0
        mu = np.zeros(int(np.prod(shape)))
        mu[self.objective.pattern.free_dofs] = mu_free
        return self._project(mu.reshape(shape))

    def solve(self, xbar):
        """``lam`` (n, d) for the cotangent ``xbar`` (n, d) of the map."""
        return self._embed(self._solve_free(self._free(self._project(xbar))), xbar.shape)

    # -- CG (geomopt.objective.cg): the exact Hessian's vertex blocks, the pinned DOFs masked out
    def _cg_setup(self, xp, p):
        obj = self.objective
        op = NewtonCG.prepare(obj)
        free = np.array(obj.free_mask)
        flat = free.reshape(-1)
        flat[obj.pattern.free_dofs[self.pins]] = 0.0
        self.op = op._replace(free=jax.device_put(free))
        blocks, swap, n_blocks = obj.block_assembly
        self.value, grad, self.VB = _exact_blocks(obj.energy.density, obj.chunk, n_blocks, obj.geom, xp, p,
                                                  blocks, swap)
        self.value = float(self.value)
        self.grad = np.asarray(obj.unpad_map(grad * obj.free_mask))

    def _cg_solve(self, b):
        obj = self.objective
        n_pad, d = obj.free_mask.shape
        rhs = np.zeros(n_pad * d)
        rhs[obj.pattern.free_dofs] = b
        mu, iters, res, ok = _cg_kernel(self.VB, self.op, jnp.asarray(rhs.reshape(n_pad, d)),
                                        jnp.float64(CG_RTOL), jnp.int32(20 * n_pad * d))
        if not bool(ok):
            raise SolveError(self._not_pd() + " (CG met non-positive curvature)")
        if not float(res) <= 10 * CG_RTOL:
            raise SolveError(f"implicit differentiation: CG reached a relative residual of {float(res):.3g} "
                             f"after {int(iters)} iterations (ill-conditioned Hessian); use a direct "
                             f"linear_solver ('auto' picks one in 2D)")
        return np.asarray(mu).reshape(-1)[obj.pattern.free_dofs]


@partial(jit, static_argnums=(0, 1, 2))
def _exact_blocks(density, chunk, n_blocks, geom, x, params, blocks, swap):
    from .objective import total_energy

    value, grad = jax.value_and_grad(total_energy, argnums=2)(density, geom, x, params)
    return value, grad, block_hessian(density, "none", chunk, geom, x, params, blocks, swap, n_blocks)


@jit
def _cg_kernel(VB, op, b, rtol, max_iters):
    matvec, precond = cg_system(VB, op, 0.0)
    return pcg(matvec, precond, b * op.free, rtol, max_iters)


# --------------------------------------------------------------------- the solves


def require_success(result, where):
    if not result.success:
        raise SolveError(f"{where}: the solve did not succeed ({result.message}): only a converged, "
                         f"certified map is differentiated (the plain geomopt function returns it "
                         f"without raising)", result)


def host_constant(fn, shapes, *args):
    """``fn(*args)`` run on the host with zero derivative (a step of a solve whose outcome is
    locally constant in the inputs), concrete inputs under eager ``jax.grad`` too; forward and
    reverse mode (a zero tangent transposes to zero cotangents)."""

    @jax.custom_jvp
    def f(*args):
        return _host(fn, shapes, *args)

    def zero(o):
        return jnp.zeros_like(o) if jnp.issubdtype(o.dtype, jnp.inexact) else np.zeros(o.shape, jax.dtypes.float0)

    @f.defjvp
    def f_jvp(primals, tangents):
        out = f(*primals)
        return out, jax.tree_util.tree_map(zero, out)

    return f(*args)

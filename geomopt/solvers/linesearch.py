"""The injective search: one line search, jittable, shared by every solver.

A solver is a *descent* (how a direction ``d`` is made) plus this *search* (how far to go
along it), in the spirit of optimistix's ``AbstractDescent`` / ``AbstractSearch``.

``max_injective_step`` returns the largest ``t`` such that no element that is positively
oriented at ``x`` reaches ``det J = 0`` on ``x + s*d`` for ``s`` in ``[0, t)``: the smallest
positive root of ``det(A + s B)``, a quadratic in 2D and a cubic in 3D (Smith & Schaefer
2015, "Bijective parameterization with free boundaries").  :class:`InjectiveSearch` starts
at ``min(t0, safety * t_max)``, then backtracks (Armijo) or brackets (weak Wolfe, when the
solver wants curvature information, ``c2 > 0``), rejecting any trial point at which an
element that was positive is not, and optionally expands an accepted first trial.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
from jax import lax

from .._runtime.config import Instance, Int, Real, validate
from .._runtime.errors import ParameterError
from .._runtime.x64 import float64
from .._runtime.programs import jit as programs_jit
from ..mesh.geometry import det, dets, edge_rows
from ..objective.objective import element_chunks, free_value_and_grad

__all__ = ["InjectiveSearch", "max_injective_step", "injective_step_bound", "still_positive"]


def _smallest_positive(roots):
    r = jnp.where(jnp.isfinite(roots) & (roots > 0), roots, jnp.inf)
    return jnp.min(r, axis=-1)


def _quadratic_roots(c2, c1, c0):
    """Both real roots of ``c2 t^2 + c1 t + c0`` (inf where absent), cancellation-free."""
    disc = c1 * c1 - 4.0 * c2 * c0
    ok = disc >= 0
    sq = jnp.sqrt(jnp.where(ok, disc, 0.0))
    q = -0.5 * (c1 + jnp.where(c1 >= 0, sq, -sq))
    qs = jnp.where(q != 0, q, 1.0)
    c2s = jnp.where(c2 != 0, c2, 1.0)
    r1 = jnp.where((c2 != 0) & ok, q / c2s, jnp.inf)
    r2 = jnp.where((q != 0) & ok, c0 / qs, jnp.inf)
    return jnp.stack([r1, r2], axis=-1)


def _cubic_roots(c3, c2, c1, c0):
    """Real roots of ``c3 t^3 + c2 t^2 + c1 t + c0`` (inf where absent).

    Closed form (trigonometric / Cardano) on the normalised cubic, each root polished by
    two Newton steps; a negligible leading coefficient falls back to the quadratic."""
    scale = jnp.maximum(jnp.maximum(jnp.abs(c0), jnp.abs(c1)), jnp.maximum(jnp.abs(c2), jnp.abs(c3)))
    scale = jnp.where(scale > 0, scale, 1.0)
    c3, c2, c1, c0 = c3 / scale, c2 / scale, c1 / scale, c0 / scale
    small = jnp.abs(c3) <= 1e-12 * (jnp.abs(c2) + jnp.abs(c1) + jnp.abs(c0))
    a3 = jnp.where(small, 1.0, c3)
    a, b, c = c2 / a3, c1 / a3, c0 / a3
    # depressed cubic t = y - a/3: y^3 + p y + q = 0
    p = b - a * a / 3.0
    q = 2.0 * a**3 / 27.0 - a * b / 3.0 + c
    disc = (q / 2.0) ** 2 + (p / 3.0) ** 3
    # one real root (disc > 0): Cardano
    sd = jnp.sqrt(jnp.maximum(disc, 0.0))
    u = jnp.cbrt(-q / 2.0 + jnp.where(q <= 0, sd, -sd))
    us = jnp.where(u != 0, u, 1.0)
    y1 = jnp.where(u != 0, u - p / (3.0 * us), 0.0)
    # three real roots (disc <= 0): trigonometric
    pm = jnp.minimum(p, -1e-300)
    m = 2.0 * jnp.sqrt(-pm / 3.0)
    arg = jnp.clip(3.0 * q / (pm * m), -1.0, 1.0)
    th = jnp.arccos(arg) / 3.0
    k = jnp.arange(3)[None, :] * (2.0 * jnp.pi / 3.0)
    y3 = m[..., None] * jnp.cos(th[..., None] - k)
    three = (disc <= 0)[..., None]
    ys = jnp.where(three, y3, jnp.stack([y1, jnp.full_like(y1, jnp.inf), jnp.full_like(y1, jnp.inf)], -1))
    t = ys - (a / 3.0)[..., None]

    def poly(t):
        return ((c3[..., None] * t + c2[..., None]) * t + c1[..., None]) * t + c0[..., None]

    def dpoly(t):
        return (3.0 * c3[..., None] * t + 2.0 * c2[..., None]) * t + c1[..., None]

    for _ in range(2):
        dp = dpoly(t)
        step = jnp.where(jnp.isfinite(t) & (dp != 0), poly(t) / jnp.where(dp != 0, dp, 1.0), 0.0)
        t = t - step
    quad = _quadratic_roots(c2, c1, c0)
    quad = jnp.concatenate([quad, jnp.full_like(quad[..., :1], jnp.inf)], -1)
    return jnp.where(small[..., None], quad, t)


@float64
@jax.jit
def max_injective_step(S, x, dx):
    """Largest ``t`` keeping every element positive at ``x`` positive along ``x + t dx``.

    S (m, d+1) simplices; x, dx (n, d).  Returns ``inf`` when nothing blocks the step.
    """
    return injective_step_bound(S, x, dx)


def injective_step_bound(S, x, dx, chunk=0):
    """:func:`max_injective_step`, traceable; ``chunk`` > 0 (below m): over chunks of that many
    elements, so that the (m, ...) temporaries of the roots are never all stored (the same
    minimum)."""
    m = S.shape[0]
    if not chunk or m <= chunk:
        return jnp.min(_step_bounds(edge_rows(S, x), edge_rows(S, dx)))
    count, part = element_chunks(m, chunk)

    def body(i, t):
        s, new = part(i, S)
        return jnp.minimum(t, jnp.min(jnp.where(new, _step_bounds(edge_rows(s, x), edge_rows(s, dx)), jnp.inf)))

    return lax.fori_loop(0, count, body, jnp.array(jnp.inf, x.dtype))


def _step_bounds(A, B):
    """(m,) the first positive root of ``det(A + t B)`` per element (edge rows (m, d, d)), inf
    where nothing blocks or the element is not positive at ``t = 0``."""
    if A.shape[-1] == 2:
        c0, c2 = det(A), det(B)
        c1 = A[:, 0, 0] * B[:, 1, 1] + B[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * B[:, 1, 0] - B[:, 0, 1] * A[:, 1, 0]
        roots = _quadratic_roots(c2, c1, c0)
    else:
        def cof(M):  # rows of the cofactor matrix, so that tr(adj(M) N) = sum(cof(M) * N)
            return jnp.stack([jnp.cross(M[:, 1], M[:, 2]), jnp.cross(M[:, 2], M[:, 0]), jnp.cross(M[:, 0], M[:, 1])], 1)

        c0, c3 = det(A), det(B)
        c1 = jnp.sum(cof(A) * B, axis=(1, 2))
        c2 = jnp.sum(cof(B) * A, axis=(1, 2))
        roots = _cubic_roots(c3, c2, c1, c0)
    return jnp.where(c0 > 0, _smallest_positive(roots), jnp.inf)


def still_positive(S, x, dx, t, was_positive, chunk=0):
    """True when every element positive at x is positive at x + s dx for s in {t/4, t/2, 3t/4, t}
    (a float guard on top of the closed-form bound, which rounding can make a hair too long);
    ``chunk`` as in :func:`injective_step_bound`."""
    m = S.shape[0]
    if not chunk or m <= chunk:
        return _positive_along(edge_rows(S, x), edge_rows(S, dx), t, was_positive)
    count, part = element_chunks(m, chunk)

    def body(i, ok):
        (s, new), (was, _) = part(i, S), part(i, was_positive)
        return ok & _positive_along(edge_rows(s, x), edge_rows(s, dx), t, was & new)

    return lax.fori_loop(0, count, body, jnp.bool_(True))


def _positive_along(A, B, t, was_positive):
    ok = jnp.bool_(True)
    for s in (0.25, 0.5, 0.75, 1.0):
        ok = ok & jnp.all(jnp.where(was_positive, det(A + (s * t) * B) > 0, True))
    return ok


@dataclasses.dataclass(frozen=True)
class InjectiveSearch:
    """The line search every geomopt solver uses.

    Attributes
    ----------
    injective : bool
        Cap the first trial at ``safety * t_max`` (the first root of an element's det along
        the direction) and reject trial points at which an element that was positively
        oriented is not (default True).  Untangling from a tangled start with a finite
        energy turns it off.
    safety : float in (0, 1]
        Fraction of ``t_max`` to start from (0.9, as in Smith & Schaefer 2015).
    c1 : float in (0, 1)
        Armijo sufficient-decrease constant.
    c2 : float in [0, 1)
        Curvature constant of the weak Wolfe condition (``c1 < c2``); ``0`` (default) means
        Armijo backtracking only.  Quasi-Newton solvers want ``0.9``.
    shrink : float in (0, 1)
        Backtracking factor.
    max_steps : int >= 1
        Trial points per search.
    expand : int >= 0
        When the first trial is accepted, try up to this many doublings of the step while
        the energy keeps decreasing (and, if injective, below the bound).  Projected Newton
        overestimates curvature where it clamped negative eigenvalues and then converges
        linearly with steps that are too short; doubling halved its iterations on bunny_cut
        and armadillo_cut_low (151 -> 61, 149 -> 68 with the clamp projection).

    Notes
    -----
    :meth:`search` is a pure JAX function (``lax.while_loop``) that solvers call inside their
    jitted kernels; calling the object runs it on an :class:`~geomopt.Objective` (one jitted
    kernel, one host sync).  The object is hashable: it is a static argument of the kernels.
    """

    injective: bool = True
    safety: float = 0.9
    c1: float = 1e-4
    c2: float = 0.0
    shrink: float = 0.5
    max_steps: int = 60
    expand: int = 0

    def __post_init__(self):
        validate(self, injective=Instance(bool), safety=Real(0.0, 1.0, lo_open=True),
                 c1=Real(0.0, 1.0, lo_open=True, hi_open=True), c2=Real(0.0, 1.0, hi_open=True),
                 shrink=Real(0.0, 1.0, lo_open=True, hi_open=True), max_steps=Int(1), expand=Int(0))
        if self.c2 and not self.c2 > self.c1:
            raise ParameterError(f"InjectiveSearch: the Wolfe constants need c1 < c2, got c1={self.c1} and "
                                 f"c2={self.c2}; lower c1 or raise c2 (0 turns the curvature condition off)")

    # -- the pieces of one search, pure JAX (the optimistix adapter and AQP's momentum use them)
    def cap(self, S, x, d, chunk=0):
        """The largest trial step along ``d`` from ``x``: ``safety`` times the first root of an
        element's det (inf when not injective or nothing blocks); ``chunk``: elements per chunk
        of the work (:func:`injective_step_bound`)."""
        if not self.injective:
            return jnp.array(jnp.inf, x.dtype)
        return self.safety * injective_step_bound(S, x, d, chunk)

    def positive(self, S, x):
        """(m,) bool, the elements positively oriented at ``x`` (None when not injective)."""
        return dets(S, x) > 0 if self.injective else None

    def admissible(self, S, x, d, t, was_positive, f_t, t_cap, chunk=0):
        """Whether the trial point ``x + t d`` with energy ``f_t`` may be accepted at all:
        within the cap, every element positive at ``x`` still positive (when injective; a float
        guard on top of the closed-form cap) and a finite energy."""
        pos = (t <= t_cap) & still_positive(S, x, d, t, was_positive, chunk) if self.injective else jnp.bool_(True)
        return pos & jnp.isfinite(f_t)

    def sufficient(self, f, f_t, t, slope):
        """Armijo's sufficient decrease ``f_t <= f + c1 t slope``."""
        return f_t <= f + self.c1 * t * slope

    def curvature(self, g_t, d, slope):
        """The weak Wolfe curvature condition (always true when ``c2 == 0``)."""
        return (jnp.vdot(g_t, d) >= self.c2 * slope) if self.c2 > 0 else jnp.bool_(True)

    def next_trial(self, t, lo, hi, armijo, t_cap):
        """``(t_next, lo, hi)``: bracket by bisection between the longest Armijo step ``lo``
        and the shortest failed one ``hi`` (weak Wolfe), double while nothing failed, or
        backtrack by ``shrink``; never beyond ``t_cap``."""
        hi = jnp.where(armijo, hi, t)
        lo = jnp.where(armijo, t, lo)
        t_next = jnp.where(
            armijo,
            jnp.where(jnp.isfinite(hi), 0.5 * (lo + hi), jnp.minimum(2.0 * t, t_cap)),
            jnp.where(lo > 0, 0.5 * (lo + hi), self.shrink * t),
        )
        return jnp.minimum(t_next, t_cap), lo, hi

    def search(self, value_and_grad, S, x, f, g, d, t0=1.0, chunk=0):
        """Search along ``d`` from ``x`` (pure JAX; call inside ``jit``).

        Parameters
        ----------
        value_and_grad : callable ``x -> (E, grad)`` (grad zero on fixed DOFs).
        S : (m, d+1) simplices (for the injective bound); x, d, g : (n, dim); f : E(x).
        t0 : the first trial step before the injective cap.
        chunk : elements per chunk of the injective cap and orientation tests (0: all at once;
            :func:`injective_step_bound`).

        Returns
        -------
        t, x_t, f_t, g_t : the accepted step and the point, energy and gradient there
            (``t == 0`` and ``x`` itself when nothing was accepted);
        ok : bool, a step was accepted;  evals : number of energy evaluations.
        """
        expand = self.expand
        slope = jnp.vdot(g, d)
        tcap = self.cap(S, x, d, chunk)
        was_pos = self.positive(S, x)
        t = jnp.minimum(jnp.asarray(t0, x.dtype), tcap)

        def body(c):
            t = c["t"]
            xt = x + t * d
            ft, gt = value_and_grad(xt)
            good = self.admissible(S, x, d, t, was_pos, ft, tcap, chunk)
            armijo = good & self.sufficient(f, ft, t, slope)
            at_cap = t >= tcap * (1.0 - 1e-12)
            expanding = c["phase"] == 1
            # the search phase: accept an Armijo (+ curvature) point, else bracket / backtrack
            accept = armijo & (self.curvature(gt, d, slope) | at_cap)
            start_expand = accept & (c["i"] == 0) & (expand > 0) & (2.0 * t < tcap)
            improve = jnp.where(expanding, good & (ft < c["bf"]), armijo & (ft < c["bf"]))
            t_search, lo, hi = self.next_trial(t, c["lo"], c["hi"], armijo, tcap)
            n_exp = c["n_exp"] + jnp.where(expanding & improve, 1, 0)
            more = (n_exp < expand) & (2.0 * t < tcap)
            done = jnp.where(expanding, ~improve | ~more, accept & ~start_expand)
            t_next = jnp.where(expanding | start_expand, 2.0 * t, t_search)
            return {
                "i": c["i"] + 1, "t": jnp.where(done, t, t_next), "lo": lo, "hi": hi, "done": done,
                "phase": jnp.where(start_expand, 1, c["phase"]), "n_exp": n_exp,
                "bt": jnp.where(improve, t, c["bt"]), "bf": jnp.where(improve, ft, c["bf"]),
                "bx": jnp.where(improve, xt, c["bx"]), "bg": jnp.where(improve, gt, c["bg"]),
            }

        c0 = {"i": jnp.int32(0), "t": t, "lo": jnp.zeros_like(t), "hi": jnp.array(jnp.inf, x.dtype),
              "done": jnp.bool_(False), "phase": jnp.int32(0), "n_exp": jnp.int32(0),
              "bt": jnp.zeros_like(t), "bf": jnp.asarray(f, x.dtype), "bx": x, "bg": g}
        c = lax.while_loop(lambda c: ~c["done"] & (c["i"] < self.max_steps), body, c0)
        # on a Wolfe failure take the best Armijo point seen (if any)
        return c["bt"], c["bx"], c["bf"], c["bg"], c["bt"] > 0, c["i"]

    @float64
    def __call__(self, objective, params, x, value, grad, dx, t0=1.0):
        """Search on an :class:`~geomopt.Objective`: ``(t, x_new, value_new, grad_new, evals)``;
        ``t == 0`` means no acceptable step."""
        t, xn, fn, gn, _, n = _search_kernel(self, objective.energy.density, objective.grad_chunk, objective.geom,
                                             objective.free_mask, params, x, value, grad, dx, t0)
        return float(t), xn, float(fn), gn, int(n)

    def cap_along(self, objective, x, d) -> float:
        """:meth:`cap` along ``d`` from ``x`` on an objective (one jitted kernel)."""
        return float(_cap_kernel(self, objective.geom[0], x, d))

    def admissible_step(self, objective, x, d, t, f_t) -> bool:
        """:meth:`admissible` of the point ``x + t d`` (energy ``f_t``) on an objective, with
        this search's own cap and orientation test (one jitted kernel)."""
        return bool(_admissible_kernel(self, objective.geom[0], x, d, jnp.asarray(t, x.dtype),
                                       jnp.asarray(f_t, x.dtype)))

    @float64
    def compile(self, objective, params, x, value, grad):
        """Compile (or load from the persistent cache) the kernel :meth:`__call__` runs, for
        maps shaped like ``x``, without running a search."""
        _search_kernel.prepare(self, objective.energy.density, objective.grad_chunk, objective.geom,
                               objective.free_mask, params, x,
                               value, grad, jax.ShapeDtypeStruct(x.shape, x.dtype), 1.0)


@partial(programs_jit, static_argnums=(0, 1, 2))
def _search_kernel(search, density, chunk, geom, free, params, x, f, g, d, t0):
    def vg(y):
        return free_value_and_grad(density, geom, free, y, params, chunk)

    return search.search(vg, geom[0], x, jnp.asarray(f, x.dtype), g, d, t0, chunk)


@partial(jax.jit, static_argnums=0)
def _cap_kernel(search, S, x, d):
    return search.cap(S, x, d)


@partial(jax.jit, static_argnums=0)
def _admissible_kernel(search, S, x, d, t, f_t):
    return search.admissible(S, x, d, t, search.positive(S, x), f_t, search.cap(S, x, d))

"""Projected Newton and the proxy-Newton solvers SLIM and CM, with a sparse Cholesky or CG.

Per iteration: per-element J-space blocks (the density's Hessian made PSD, or a convex proxy:
:mod:`geomopt.objective.projection`), assembled into a fixed CSC pattern, factored (symbolic analysis
reused), then the shared injective search (Teran et al. 2005; Smith & Schaefer 2015).
:class:`AbstractNewton` is that algorithm; :class:`Newton`, :class:`SLIM` and :class:`CM` are
its three configurations (a projection and defaults), not subclasses of one another.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, NamedTuple

import jax
import numpy as np

from ..objective.cg import NewtonCG
from .._runtime.config import OneOf, Real
from .._runtime.errors import ParameterError
from .._runtime.memory import release_free_memory
from .._runtime.threads import AHEAD_FROM, ahead
from ..objective.projection import Adaptive, AbstractProjection, Clamp, CMProxy, SLIMProxy, as_projection
from .linesearch import InjectiveSearch
from ..linalg.krylov import pcg, symmetric_product
from ..linalg.linsolve import BACKENDS, NotPositiveDefinite, newton_linear_solver
from ._base import AbstractSolver, State, map_extent
from ._termination import Termination

__all__ = ["Newton", "SLIM", "CM", "AbstractNewton", "NewtonMemory", "Reuse"]


#: how far above the energy a full Newton step at rounding level may land and still be taken
#: (:meth:`AbstractNewton._polish`): a few hundred ulps of the energy, which sums many elements' terms
POLISH_ROUNDING = 1e-13

#: fewest preconditioned CG iterations, in the time of one factorization, for which
#: ``reuse_factor`` tries CG before factoring
MIN_REUSE_ITERS = 4

#: the largest relative residual to which a direction is solved with a float32 factorization
#: refined in float64 (:class:`~geomopt.linalg.linsolve.SparseCholesky` ``single``)
REFINE_RTOL = 1e-6

#: free DOFs from which ``reuse_factor="auto"`` reuses the factorization (see :class:`AbstractNewton`)
REUSE_FROM_DOFS = 300_000

#: free DOFs from which a step hands the C heap's free memory back before its Hessian, before and
#: after its search (:func:`geomopt._runtime.memory.release_free_memory`): the temporaries of the previous
#: kernels, freed on other threads, would otherwise stay resident under the next ones (10^6
#: triangles, swirled grid: peak 2.66 -> 2.52 GB with the first two); below, a few MB are at stake
TRIM_FROM_DOFS = 100_000
#: a PSD projection's diagonal shifts are ``regularization * 100**k``, ``k < _SHIFT_LEVELS``
_SHIFT_LEVELS = 8


class Reuse(NamedTuple):
    """The bookkeeping of ``reuse_factor`` (:class:`AbstractNewton`).

    on : whether CG preconditioned with the factorization held is tried (``reuse_factor``
        resolved for the mesh);  factor_s, iter_s : wall seconds of the last numeric
        factorization and of one iteration of that CG (0: not measured yet);  wait : iterations
        that factor before the next try, after ``misses`` tries in a row did not reach the
        forcing term in time (1, 2, 4...; 0 again after a try that did).
    """

    on: bool = False
    factor_s: float = 0.0
    iter_s: float = 0.0
    wait: int = 0
    misses: int = 0

    def tried(self, ok: bool, iter_s: float) -> "Reuse":
        """After a try: its outcome and the measured seconds of one CG iteration."""
        misses = 0 if ok else self.misses + 1
        return self._replace(iter_s=iter_s, misses=misses, wait=0 if ok else 2 ** (misses - 1))

    def factored(self, factor_s: float, solve_s: float, refinements: int = 0) -> "Reuse":
        """After a factorization (seconds) and its solve (the first estimate of a CG iteration:
        a direct solve and about half a solve's time in products; a refined float32 solve's
        time per iteration of its own CG, the same preconditioner and products)."""
        first = solve_s / refinements if refinements else 1.5 * solve_s
        return self._replace(factor_s=factor_s, iter_s=self.iter_s or first)


class NewtonMemory(NamedTuple):
    """What a Newton-type solver keeps between steps.

    factor : the :class:`~geomopt.linalg.linsolve.SparseCholesky` (symbolic analysis done), or None
        on the CG path;  cg_op : the CG operator (:meth:`NewtonCG.prepare`), or None;
    grad_ref : the first gradient norm (CG's scale-free forcing term);
    cooldown : iterations left during which ``Adaptive`` clamps after an exact Hessian failed
        to factor;  mu : the Levenberg-Marquardt shift of the exact Hessian (None: not used yet);
    reuse : the :class:`Reuse` bookkeeping of ``reuse_factor``;
    level : where a PSD projection's growing shifts start, ``regularization * 100**level``
        (:meth:`AbstractNewton._psd_direction`).
    """

    factor: Any = None
    cg_op: Any = None
    grad_ref: float = 1.0
    cooldown: int = 0
    mu: float | None = None
    reuse: Reuse = Reuse()
    level: int = 0


@dataclasses.dataclass(frozen=True)
class AbstractNewton(AbstractSolver):
    """Newton steps on per-element blocks chosen by a projection (the shared algorithm of
    :class:`Newton`, :class:`SLIM` and :class:`CM`; not instantiated itself).

    Attributes
    ----------
    projection : a :mod:`geomopt.objective.projection` object (or its name): ``Adaptive()``,
        ``Clamp()``, ``Abs()``, ``Exact()``, ``SLIMProxy()``, ``CMProxy()``.  With an
        indefinite one (``Exact``, chosen by ``Adaptive`` near the minimum) the Hessian gets a
        Levenberg-Marquardt shift, relaxed after full steps and stiffened after cut ones; if
        it does not factor, clamping resumes for two iterations.
    linear_solver : a :data:`~geomopt.linalg.linsolve.BACKENDS` name (a sparse Cholesky), or
        ``"cg"``: the direction by block-Jacobi preconditioned CG in JAX
        (:class:`geomopt.objective.cg.NewtonCG`, inexact Newton; eigenvalue projections only, not
        proxies).  ``"auto"`` picks by device, dimension and size
        (:func:`geomopt.linalg.linsolve.newton_linear_solver`: CG off the CPU and for large tet
        meshes, else the fastest Cholesky installed).
    rtol : stop when the Newton decrement ``-g.d/2`` or the energy decrease is below
        ``rtol * |E|`` (:attr:`termination`).
    max_steps : iteration limit.
    regularization : relative diagonal shift added to the Hessian (it is singular for a free
        boundary: rotations); increased automatically when a factorization fails.
    search : the :class:`~geomopt.solvers.linesearch.InjectiveSearch`.
    cg : the :class:`geomopt.objective.cg.NewtonCG` configuration (iteration limit, forcing term) of
        the CG direction.
    reuse_factor : with a Cholesky, first try the direction by CG on the new Hessian
        preconditioned with the factorization already held (an earlier iteration's): taken when
        CG reaches the forcing term ``min(cg.eta_max, sqrt(|g| / g_ref))`` (Eisenstat & Walker
        1996) within the wall time of one factorization, else the Hessian is factored (an
        inexact Newton step that skips the factorization where the Hessian changed little).
        Tried only after a full step (Newton's local regime), and after a failed try the next
        1, 2, 4... iterations factor without trying.  ``"auto"`` (default): on from
        :data:`REUSE_FROM_DOFS` free DOFs, where a factorization costs seconds; measured at
        10^6 triangles (benchmarks/README, "Newton at 10^6"): the swirled grid 23.0 -> 16.3 s to
        convergence (1 factorization instead of 5), igea subdivided (960k triangles, free
        boundary, 17 iterations) 90.3 -> 88.3 s.
    """

    projection: Any = Clamp()
    linear_solver: str = "auto"
    rtol: float = 1e-10
    max_steps: int = 200
    regularization: float = 1e-9
    search: InjectiveSearch = InjectiveSearch()
    # eta_max 0.01, not 0.5: measured 4 instead of 8 Newton iterations, 1.9x less CPU (10^5 tets)
    cg: NewtonCG = NewtonCG(eta_max=0.01)
    reuse_factor: bool | str = "auto"

    def __post_init__(self):
        if type(self) is AbstractNewton:
            raise TypeError("AbstractNewton is the shared algorithm: use Newton, SLIM or CM")
        try:
            object.__setattr__(self, "projection", as_projection(self.projection))
        except ParameterError:
            raise ParameterError(f"{type(self).__name__}: projection must be one of 'adaptive', 'clamp', 'abs', "
                                 f"'none' (the exact Hessian) or a projection object (geomopt.solvers.Clamp(), "
                                 f"SLIMProxy()...), got {self.projection!r}") from None
        self._check(linear_solver=OneOf(BACKENDS + ("cg",)), regularization=Real(0.0, lo_open=True))
        if not (isinstance(self.reuse_factor, bool) or self.reuse_factor == "auto"):
            raise ParameterError(f"{type(self).__name__}: reuse_factor must be True, False or 'auto', "
                                 f"got {self.reuse_factor!r}")

    @property
    def termination(self) -> Termination:
        """As every solver's, but a failed search counts as converged when the decrement is
        within ``100 rtol |E|`` (already at the minimum up to rounding)."""
        return Termination(rtol=self.rtol, ftol=0.01 * self.rtol, stall=math.sqrt(self.rtol),
                           flat=100 * self.rtol, max_steps=self.max_steps)

    def uses_cg(self, objective) -> bool:
        """Whether the direction comes from CG (``linear_solver="cg"``, or ``"auto"`` and
        :func:`~geomopt.linalg.linsolve.newton_linear_solver` says so) rather than a Cholesky."""
        if self.projection.proxy:  # the proxies assemble for a factorization
            if self.linear_solver == "cg":
                raise ParameterError(f"{type(self).__name__}: linear_solver='cg' needs an eigenvalue "
                                     f"projection (Adaptive, Clamp, Abs, Exact), not a proxy")
            return False
        if self.linear_solver != "auto":
            return self.linear_solver == "cg"
        n_free = int(np.count_nonzero(objective.free_dofs))
        return newton_linear_solver(objective.problem.dim, n_free, jax.default_backend()) == "cg"

    def load_ahead(self, objective):
        if self.uses_cg(objective) or int(np.count_nonzero(objective.free_dofs)) < AHEAD_FROM:
            return None  # CG compiles its own kernels; a small problem's load is quicker than a thread

        def work():  # the kernels and arguments of init's compile_hessian and search.compile
            params = objective.params()
            x = jax.device_put(objective.pad_map(np.zeros(objective.free_dofs.shape)))
            for projection in self.projection.kernels():
                objective.compile_hessian(x, params, projection)
            self.search.compile(objective, params, x, 0.0, x)

        return ahead(work)

    def init(self, objective, x0, params) -> State:
        self.projection.check_dim(objective.problem.dim)
        if self.uses_cg(objective):
            state = self._start(objective, x0, params, NewtonMemory(cg_op=self.cg.prepare(objective)))
            state = _with_grad_ref(state)
            for projection in self.projection.kernels():
                self.cg.compile(state.memory.cg_op, objective, state.x, params, projection)
        else:
            # the mesh's shared Cholesky: one symbolic analysis (and one factor's memory) per
            # mesh and backend, whichever solves or derivatives use it; each step refactors
            # before it solves (SparseCholesky.generation)
            chol = objective.cholesky(self.linear_solver)
            reuse = self.reuse_factor is True or (self.reuse_factor == "auto" and chol.n >= REUSE_FROM_DOFS)
            state = _with_grad_ref(self._start(objective, x0, params, NewtonMemory(factor=chol, reuse=Reuse(on=reuse))))
            # compile (or load) every kernel the loop uses now, so that setup time holds the
            # compilation; ahead of time: no warm-up evaluation is run
            for projection in self.projection.kernels():
                objective.compile_hessian(state.x, params, projection)
        self.search.compile(objective, params, state.x, state.value, state.grad)
        return state

    def _direction(self, state, projection, shifts):
        """Newton direction with the first diagonal shift (relative to the mean diagonal) in
        ``shifts`` that factors: ``(value, grad, dx, decrement, shift, reuse)``, ``dx`` (shaped
        like ``x``, zero on fixed DOFs, on the device) None on failure; ``reuse`` the
        :class:`Reuse` bookkeeping after it."""
        if state.x.size >= TRIM_FROM_DOFS:  # also after a failed try: its factorization's temporaries
            release_free_memory()
        if state.memory.cg_op is not None:
            return self._cg_direction(state, projection, shifts) + (state.memory.reuse,)
        obj, pat, mem = state.objective, state.objective.pattern, state.memory
        value, grad, data = obj.hessian(state.x, state.params, projection)
        data = np.array(data)  # the one host copy (the kernel's output is freed), shifted in place
        if state.x.size >= TRIM_FROM_DOFS:  # the kernel's scratch, before the factorization's
            release_free_memory()
        diag = data[pat.diag]  # unshifted
        g = np.asarray(grad).reshape(-1)[pat.free_dofs]
        # the shifts' scale: the median diagonal, which a few huge entries do not move (one
        # sliver of a bijective scaffold gave 1e28 and a mean that shifted the whole direction
        # to 1e-19: a false convergence at 5x the optimum's distortion, 853k triangles)
        scale = max(float(np.median(np.abs(diag))) if len(pat.diag) else 1.0, 1e-300)  # no free DOF: any
        reuse = mem.reuse
        for i, shift in enumerate(shifts):
            data[pat.diag] = diag + shift * scale
            # the lagged factor only where Newton converges locally: after a full step
            lag = i == 0 and state.stats.step_size >= 1.0
            d_free, reuse = self._lagged_direction(mem, pat, data, g) if lag else (None, reuse)
            if d_free is None:
                d_free, reuse = self._factored_direction(mem.factor, data, g, reuse, mem.grad_ref)
            if d_free is None:
                continue
            dx = np.zeros(state.x.size)
            dx[pat.free_dofs] = d_free
            # device_put: no copy program per shape (jnp.asarray compiles one)
            return float(value), grad, jax.device_put(dx.reshape(state.x.shape)), 0.5 * float(-g @ d_free), shift, reuse
        return float(value), grad, None, None, None, reuse

    def _polish(self, obj, params, x, value, dx, decrement):
        """``(x + dx, E, gradient)`` where the search took no step, a sliver of one or a doubled
        one only because the energy cannot tell: the direction promises at most ``flat * |E|``
        (the termination's "stationary up to rounding"), the full step keeps every element
        positive (the search's own admissibility test) and the energy stays within
        :data:`POLISH_ROUNDING` ``|E|`` of ``E``; None otherwise.  Newton's last step there still
        squares the error of the map (its gradient 2e-7 -> 1e-13 on a curved free-boundary
        saddle, where energy tests alone leave maps accurate to ~1e-9: too little for finite
        differences of re-solves)."""
        scale = max(abs(value), 1e-300)
        if not decrement <= self.termination.flat * scale:
            return None
        xn = jax.device_put(np.asarray(x) + np.asarray(dx))  # on the host: no add program compiled per shape
        vn, gn = obj.value_and_grad(xn, params)
        vn = float(vn)
        if not vn <= value + POLISH_ROUNDING * scale or not self.search.admissible_step(obj, x, dx, 1.0, vn):
            return None
        return xn, vn, gn

    @staticmethod
    def _factored_direction(chol, data, g, reuse, grad_ref):
        """``(-H^-1 g, reuse)`` by factoring ``data``; None when it does not factor (or, for a
        float32 factor, its float64 refinement does not converge)."""
        t0 = time.perf_counter()
        try:
            chol.factor(data)
            t1 = time.perf_counter()
            # a float32 factor's refinement to Newton's own forcing term, |g| / |g_0| (quadratic
            # convergence), at most REFINE_RTOL; a float64 factor's solve is direct
            d_free = -chol.solve(g, rtol=min(REFINE_RTOL, float(np.linalg.norm(g)) / grad_ref))
        except NotPositiveDefinite:
            return None, reuse
        chol.forget_values()  # this factor's later use is as a preconditioner (reuse_factor)
        return d_free, reuse.factored(t1 - t0, time.perf_counter() - t1, chol.refinements)

    def _lagged_direction(self, mem, pat, data, g):
        """``(-H^-1 g, reuse)`` for the values ``data`` by CG preconditioned with the
        factorization held (``reuse_factor``); None instead of the direction when reuse is off
        or waits after failed tries, nothing is factored yet, or CG does not reach the forcing
        term within one factorization's time (or meets negative curvature); also when the last
        factorization failed (a shift too small for an indefinite Hessian): none is held then."""
        reuse = mem.reuse
        budget = int(reuse.factor_s / reuse.iter_s) if reuse.iter_s else 0
        # CG needs a few iterations even where the Hessian changed little (3-9 measured at 10^6
        # triangles): below MIN_REUSE_ITERS affordable ones, trying costs more than it saves
        if reuse.wait:
            return None, reuse._replace(wait=reuse.wait - 1)
        if not reuse.on or not mem.factor.has_factor or budget < MIN_REUSE_ITERS:
            return None, reuse
        matvec = symmetric_product(pat.lower(data))
        gnorm = float(np.linalg.norm(g))
        rtol = min(self.cg.eta_max, math.sqrt(gnorm / mem.grad_ref))
        t0 = time.perf_counter()
        d_free, iterations = pcg(matvec, -g, mem.factor.precondition, rtol, budget)
        return d_free, reuse.tried(d_free is not None, (time.perf_counter() - t0) / max(iterations, 1))

    def _cg_direction(self, state, projection, shifts):
        """:meth:`_direction` by CG, all on the device (only scalars come to the host): the
        first shift whose system CG finds positive definite along its iterates (always the
        first for a PSD projection)."""
        obj, mem = state.objective, state.memory
        for shift in shifts:
            dx, info = self.cg.direction(mem.cg_op, obj, state.x, state.params, projection, shift,
                                         gnorm_ref=mem.grad_ref)
            if bool(info.curvature) or projection.psd:
                return float(info.value), info.grad, dx, -0.5 * float(info.slope), shift
        return float(info.value), info.grad, None, None, None

    def _newton_direction(self, state, projection):
        """``(value, grad, dx, decrement, memory, exact)`` for ``projection``: an indefinite
        one with the Levenberg-Marquardt shift (``exact`` when it factors; else clamping, with
        a cooldown), a PSD one with the smallest of growing shifts that factors."""
        reg, mem = self.regularization, state.memory
        mem = mem._replace(cooldown=max(mem.cooldown - 1, 0))
        if not projection.psd:
            mu = max(mem.mu if mem.mu is not None else reg, reg)
            value, grad, dx, decrement, used, reuse = self._direction(state, projection, [mu, 1e2 * mu])
            if dx is not None:
                return value, grad, dx, decrement, mem._replace(mu=used, reuse=reuse), True
            mem = mem._replace(cooldown=2, mu=1e4 * mu, reuse=reuse)
            projection = Clamp()
        value, grad, dx, decrement, reuse, level = self._psd_direction(state, projection)
        return value, grad, dx, decrement, mem._replace(reuse=reuse, level=level), False

    def _psd_direction(self, state, projection):
        """:meth:`_direction` with the growing shifts ``regularization * 100**k`` (k < 8) from
        the level in memory: ``(value, grad, dx, decrement, reuse, next level)``.  A free
        boundary's Hessian is singular (rigid motions) and at 10^5-10^6 triangles the smallest
        shifts fail to factor in every iteration (three failed factorizations an iteration on an
        853k-triangle chart): after a shift that needed larger ones first, the next iteration
        starts at it; after one that factored at once, one level lower (so the shift can fall
        again as the Hessian improves)."""
        start = state.memory.level
        shifts = [self.regularization * 100**k for k in range(_SHIFT_LEVELS)]
        value, grad, dx, decrement, shift, reuse = self._direction(state, projection, shifts[start:])
        if dx is None:
            return value, grad, dx, decrement, reuse, start
        k = shifts.index(shift)
        return value, grad, dx, decrement, reuse, k if k > start else max(k - 1, 0)

    def step(self, state: State) -> State:
        obj, params, x = state.objective, state.params, state.x
        projection = self.projection.select(state.stats, state.memory.cooldown)
        trim = x.size >= TRIM_FROM_DOFS  # (and before each Hessian: _direction)
        value, grad, dx, decrement, mem, exact = self._newton_direction(state, projection)
        if dx is None or not np.isfinite(value):
            return state.update(broken=True, iteration=state.iteration + 1)
        if trim:
            release_free_memory()
        t, xn, vn, gn, evals = self.search(obj, params, x, value, grad, dx)
        if trim:  # and after it: what follows the solve (its exact certificate) allocates on top
            release_free_memory()
        it = state.iteration + 1
        evaluations = state.evaluations + evals
        # at rounding level the energy cannot rank steps: the search may stop at none, at a
        # sliver of the step or at a doubled one; the full step is taken when admissible
        polished = self._polish(obj, params, x, value, dx, decrement) if t != 1.0 else None
        if polished is not None:
            t, (xn, vn, gn), evaluations = 1.0, polished, evaluations + 1
        if t == 0.0:
            return state.update(iteration=it, decrement=decrement, step_size=0.0, evaluations=evaluations,
                                grad=grad, accepted=False)
        if exact:
            # trust-region-like damping: relax after a full (or longer) step, stiffen after a cut
            mem = mem._replace(mu=max(mem.mu / 10, self.regularization) if t >= 1.0 else mem.mu * 10)
        return state.update(x=xn, value=vn, grad=gn, iteration=it, step_size=t, decrement=decrement,
                            past_value=value, memory=mem, evaluations=evaluations, extent=map_extent(xn))


def _with_grad_ref(state):
    """``state`` with its first gradient norm in memory (the scale of the forcing terms)."""
    gref = max(float(np.linalg.norm(np.asarray(state.grad))), 1e-300)
    return dataclasses.replace(state, memory=state.memory._replace(grad_ref=gref))


@dataclasses.dataclass(frozen=True)
class Newton(AbstractNewton):
    """Projected Newton (:class:`AbstractNewton` with the ``Adaptive`` projection and step
    doubling in the search).

    Projected Newton converges only linearly near a minimum because the projection changes
    the Hessian of elements that are indefinite there (symmetric Dirichlet has many), so the
    default ``Adaptive()`` clamps while far from the minimum and switches to the exact Hessian
    near it (see :class:`~geomopt.objective.projection.Adaptive`).

    Attributes
    ----------
    projection : ``Adaptive()`` (default), ``Clamp()``, ``Abs()`` or ``Exact()``: how each
        element Hessian is made positive semi-definite (:class:`AbstractNewton`).
    linear_solver : ``"auto"`` (default; :func:`geomopt.linalg.linsolve.newton_linear_solver`), a
        sparse Cholesky backend (``"pardiso"``, ``"cholmod"``, ``"cholespy"``, ``"superlu"``) or
        ``"cg"`` (inexact Newton by block-Jacobi CG in JAX).
    rtol : 1e-10; stop when the Newton decrement or the energy decrease is below ``rtol * |E|``.
    max_steps : 200; the iteration limit (a solve that reaches it ends ``MAX_STEPS``).
    regularization : 1e-9; relative diagonal shift (raised when a factorization fails).
    search : ``InjectiveSearch(expand=3)``: the injective bound, Armijo backtracking, and up to
        three step doublings.
    cg : the CG direction's settings (:class:`geomopt.objective.cg.NewtonCG`).

    Examples
    --------
    >>> import geomopt
    >>> V = [[0, 0, 0.5], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
    >>> F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]
    >>> res = geomopt.parameterize(V, F, solver=geomopt.Newton(rtol=1e-8, max_steps=50), progress=False)
    >>> res.outcome.name, res.success
    ('CONVERGED', True)
    """

    projection: Any = Adaptive()
    search: InjectiveSearch = InjectiveSearch(expand=3)


@dataclasses.dataclass(frozen=True)
class SLIM(AbstractNewton):
    """SLIM (Rabinovich et al. 2017): Newton steps on the reweighted Laplacian proxy whose
    weights come from the density's singular-value derivatives
    (:class:`~geomopt.objective.projection.SLIMProxy`), then the injective search.  Works for any
    rotation-invariant density; the paper's closed form for symmetric Dirichlet.

    Attributes
    ----------
    projection : ``SLIMProxy()`` (default): the per-element proxy blocks; another projection
        makes it another solver (:class:`AbstractNewton`).
    linear_solver : ``"auto"`` (default: the fastest sparse Cholesky installed) or a backend
        name (``"pardiso"``, ``"cholmod"``, ``"cholespy"``, ``"superlu"``); ``"cg"`` is refused
        (CG takes eigenvalue projections only, not proxies).
    rtol : 1e-10; stop when the decrement or the energy decrease is below ``rtol * |E|``.
    max_steps : 1000; the iteration limit (a solve that reaches it ends ``MAX_STEPS``).
    regularization : 1e-9; relative diagonal shift of the proxy (raised when a factorization
        fails).
    search : ``InjectiveSearch()``: the injective bound (``safety`` 0.9), then Armijo
        backtracking.
    cg : unused (the proxies are factored, never solved by CG).
    """

    projection: AbstractProjection = SLIMProxy()
    max_steps: int = 1000


@dataclasses.dataclass(frozen=True)
class CM(AbstractNewton):
    """Composite majorization (Shtengel et al. 2017), 2D: Newton steps on the convex
    majorizer of :class:`~geomopt.objective.projection.CMProxy`, then the injective search.

    Attributes
    ----------
    projection : ``CMProxy()`` (default): the per-element convex majorizer blocks (2D only).
    linear_solver : ``"auto"`` (default: the fastest sparse Cholesky installed) or a backend
        name (``"pardiso"``, ``"cholmod"``, ``"cholespy"``, ``"superlu"``); ``"cg"`` is refused
        (CG takes eigenvalue projections only, not proxies).
    rtol : 1e-10; stop when the decrement or the energy decrease is below ``rtol * |E|``.
    max_steps : 500; the iteration limit (a solve that reaches it ends ``MAX_STEPS``).
    regularization : 1e-9; relative diagonal shift of the majorizer (raised when a
        factorization fails).
    search : ``InjectiveSearch()``: the injective bound (``safety`` 0.9), then Armijo
        backtracking.
    cg : unused (the majorizer is factored, never solved by CG).
    """

    projection: AbstractProjection = CMProxy()
    max_steps: int = 500

"""Energy, gradient and projected sparse Hessian of ``sum_e vol_e psi(J_e(x))``.

Everything is derived from the density by JAX: ``vmap`` over elements, ``grad`` for the
gradient, ``hessian`` for the element Hessian in J-space (``d^2 x d^2``), which is projected
to PSD there (cheaper than projecting the ``(d+1)d``-square element block, and valid since
the map from vertex positions to ``vec J`` is linear) and then lifted with the constant
matrix ``G`` such that ``J = X^T G`` for the element's vertex positions ``X`` ((d+1), d).
The lifted blocks are summed into *vertex blocks* (one d x d block per pair of vertices
sharing an element, :class:`~geomopt.objective.pattern.HessianPattern`), from which the CSC data of the free-DOF lower
triangle are gathered (direct solvers) or which :mod:`geomopt.objective.cg` applies as an operator.
The pattern is computed once per mesh from the vertex graph.

The hot functions are module-level ``jax.jit`` functions keyed on the density (static) and
array shapes; parameters (eps, lambda...) are traced, so a solve never recompiles.  Each is
made by :func:`jit`, which calls the plain function instead when an argument is traced (a
user's ``jax.jit`` / ``grad`` / ``vmap``: XLA options can only be given to a top-level jit):
the energy composes with every JAX transform, and runs the tuned kernel when called on
concrete arrays.  :class:`Objective` is a pytree (leaves: the problem's arrays, the element
weights and the padded rest geometry).
"""

from __future__ import annotations

import dataclasses
import functools
import threading
import types
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime import padding as _padding
from .._runtime import programs as _programs
from .._runtime import x64 as _x64
from .._runtime.threads import AHEAD_FROM
from ..mesh.geometry import chord_jacobians, dets
from .._runtime.errors import ParameterError
from .._runtime.tracing import StaticKey, is_traced, refuse_traced
from ..energies import Energy, get_energy
from .projection import as_projection, project_psd  # noqa: F401  (project_psd: re-exported)
from ..linalg.linsolve import SINGLE_FROM_ROWS, SparseCholesky, available_backends
from .pattern import HessianPattern, block_pairs, hessian_pattern, local_pairs  # noqa: F401  (re-exported)
from ..mesh.problem import Problem

__all__ = ["Objective", "HessianPattern", "hessian_pattern", "element_densities", "check_element_weights", "jit",
           "element_chunks"]

class _Kernel:
    """``jax.jit(fun, compiler_options=_programs.xla_options(), **options)`` (a kept
    :class:`~geomopt._runtime.programs.Program`), made at the first call (so
    that importing geomopt compiles nothing); attributes (``lower``, ``_cache_size``...) are
    the jitted function's.  Called with a tracer among its non-static arguments it calls
    ``fun`` itself (XLA options exist only for a top-level jit), so that the kernel can be used
    under a user's transforms; never in float32 (:mod:`geomopt._runtime.x64`)."""

    def __init__(self, fun, options):
        self._fun, self._options, self._jitted = fun, options, None
        static = options.get("static_argnums", ())
        self._static = {static} if isinstance(static, int) else set(static)
        functools.update_wrapper(self, fun)

    def _kernel(self):
        if self._jitted is None:
            self._jitted = _programs.jit(self._fun, **self._options)  # with _programs.xla_options()
        return self._jitted

    def __call__(self, *args, **kwargs):
        _x64.require()
        dynamic = [a for i, a in enumerate(args) if i not in self._static] + list(kwargs.values())
        if is_traced(dynamic):
            return self._fun(*args, **kwargs)
        if kwargs:
            return self._kernel().plain(*args, **kwargs)
        return self._kernel()(*args)

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self._kernel(), name)


def jit(fun=None, **options):
    """``jax.jit`` with :func:`geomopt._runtime.programs.xla_options`, its programs kept on disk
    (usable as ``@jit`` or ``partial(jit, ...)``)."""
    if fun is None:
        return partial(jit, **options)
    return _Kernel(fun, options)

#: Elements per chunk of the per-element Hessian work on CPU (see :func:`block_hessian`).
CPU_CHUNK = 1024

#: The energy and gradient of the kernels (not the Hessian's) run in chunks of this many times
#: :attr:`Objective.chunk` elements (:func:`free_value_and_grad`; 65,536 on CPU: a loop of 16 at
#: 10^6 elements, each chunk's scratch a few MB)
GRAD_CHUNK_FACTOR = 64


# ---------------------------------------------------------------- jitted kernels


def jacobians(geom, x):
    S, Minv, _ = geom
    return _jacobians_of(x[S], Minv)


def _jacobians_of(X, Minv):
    """(m, d, d) Jacobians from the elements' vertex positions ``X`` (m, k, dim)."""
    if X.shape[1] == X.shape[2]:  # triangles mapped onto the sphere (cones over the origin)
        return chord_jacobians(X, Minv)
    Ds = jnp.swapaxes(X[:, 1:] - X[:, :1], 1, 2)  # columns = edges
    return Ds @ Minv


def _dets(geom, x):
    return dets(geom[0], x)


def total_energy(density, geom, x, params):
    vol = geom[2]
    psi = jax.vmap(density, in_axes=(0, None))(jacobians(geom, x), params)
    return jnp.sum(vol * psi)


def element_chunks(m, chunk):
    """``(count, part)`` for a loop over ``m`` elements in chunks of ``chunk``: ``part(i, a)``
    is chunk ``i`` of the (m, ...) array ``a`` and a (chunk,) mask of its elements not in an
    earlier chunk (the last chunk is shifted back to end at element m, so that one loop body
    serves every chunk)."""

    def part(i, a):
        start = jnp.minimum(i * chunk, m - chunk)
        new = (start + jnp.arange(chunk)) >= i * chunk
        return jax.lax.dynamic_slice_in_dim(a, start, chunk), new

    return -(-m // chunk), part


def total_energy_chunked(density, geom, x, params, chunk):
    """:func:`total_energy` summed over chunks of ``chunk`` elements (all at once when ``chunk``
    is 0 or at least m): the (m, ...) temporaries of the Jacobians and densities are never all
    stored (at 10^6 triangles they are most of the kernels' scratch).  Traceable."""
    S, Minv, vol = geom
    m = S.shape[0]
    if not chunk or m <= chunk:
        return total_energy(density, geom, x, params)
    count, part = element_chunks(m, chunk)

    def body(i, v):
        (s, new), (M, _), (w, _) = part(i, S), part(i, Minv), part(i, vol)
        return v + _chunk_energy(density, x[s], M, w, new, params)

    return jax.lax.fori_loop(0, count, body, jnp.zeros((), x.dtype))


def _chunk_energy(density, X, M, w, new, params):
    """The energy of a chunk's elements (vertex positions ``X``, rest inverses ``M``, sizes
    ``w``) that ``new`` marks (the others were in an earlier chunk)."""
    psi = jax.vmap(density, in_axes=(0, None))(_jacobians_of(X, M), params)
    return jnp.sum(jnp.where(new, w * psi, 0.0))


@partial(jit, static_argnums=(0, 1))
def energy_kernel(density, chunk, geom, x, params):
    return total_energy_chunked(density, geom, x, params, chunk)


def free_value_and_grad(density, geom, free, x, params, chunk=0):
    """``(E(x), grad E(x) * free)``: the energy and its gradient on the free DOFs (``free``
    (n, d) is 1 on free DOFs, 0 on fixed and padded ones).  Traceable.

    ``chunk`` > 0 (and below m): elements in chunks of that many, each chunk's energy and
    element gradients (chunk, k, d) computed and added to the gradient in the loop, so that
    the (m, ...) temporaries are never all stored; the same terms, summed in another order.
    Measured at 10^6 triangles (symmetric Dirichlet, chunks of 65,536): XLA's scratch 118 ->
    9 MB, and 2.6x faster (0.124-0.140 -> 0.048 s: each chunk's intermediates stay in cache)."""
    S, Minv, vol = geom
    m = S.shape[0]
    if not chunk or m <= chunk:
        v, g = jax.value_and_grad(total_energy, argnums=2)(density, geom, x, params)
        return v, g * free
    count, part = element_chunks(m, chunk)

    def body(i, carry):
        v, g = carry
        (s, new), (M, _), (w, _) = part(i, S), part(i, Minv), part(i, vol)
        e, gX = jax.value_and_grad(_chunk_energy, argnums=1)(density, x[s], M, w, new, params)
        return v + e, g.at[s].add(gX)

    v, g = jax.lax.fori_loop(0, count, body, (jnp.zeros((), x.dtype), jnp.zeros_like(x)))
    return v, g * free


@partial(jit, static_argnums=(0, 1))
def value_and_grad_kernel(density, chunk, geom, free, x, params):
    return free_value_and_grad(density, geom, free, x, params, chunk)


@jit
def dets_kernel(geom, x):
    return _dets(geom, x)


def element_block(density, projection, J, params, vol, code=0):
    """(d*d, d*d) J-space block ``vol * H`` of one element under ``projection`` (a
    :mod:`geomopt.objective.projection` object or name: clamp, abs, exact, SLIM's or CM's proxy; or
    ``EigenFilter`` with the traced filter ``code``)."""
    return as_projection(projection).block(density, J, params, vol, code)


def _element_blocks(density, projection, params, code, x, s, Minv, vol, swap):
    """The projected Hessian blocks of one element: (nb, d, d), block ``i`` of
    :func:`block_pairs` ``(a, b)`` oriented as stored, ``H[v-dofs, w-dofs]`` with ``v >= w``
    (the element block ``(b, a)`` where ``swap[i]``, else ``(a, b)``).

    ``x`` (n, d) map, ``s`` (d+1,) vertex ids, ``Minv`` (d, d), ``vol`` scalar, ``swap`` (nb,).
    The J-space Hessian (d^2 x d^2) is projected, then lifted by ``Hx[a, c, b, e] =
    sum_jl G[a, j] HJ[c, j, e, l] G[b, l]`` with ``J = X^T G`` (broadcast products over the
    tiny axes: XLA fuses them into loops, faster on CPU than batched small ``dot_general``).
    """
    d = Minv.shape[0]
    X = x[s]
    J = (X[1:] - X[:1]).T @ Minv
    HJ = element_block(density, projection, J, params, vol, code).reshape(d, d, d, d)
    G = jnp.concatenate([-jnp.sum(Minv, axis=0, keepdims=True), Minv], axis=0)  # (d+1, d)
    T = sum(G[:, None, None, j, None] * HJ[None, :, j, :, :] for j in range(d))  # a c e l
    bi, bj = block_pairs(d)
    out = []
    for i, (a, b) in enumerate(zip(bi, bj)):
        B = sum(T[a, :, :, l] * G[b, l] for l in range(d))  # c e: element block (a, b)
        out.append(B if a == b else jnp.where(swap[i], B.T, B))
    return jnp.stack(out)


def block_hessian(density, projection, chunk, geom, x, params, blocks, swap, n_blocks, code=0):
    """Vertex-block data (n_blocks, d, d) of the projected Hessian (all DOFs; the pattern's
    ``gather`` picks the free lower-triangle entries).  Traceable.  ``code``: the traced filter
    of ``EigenFilter`` (a projection's ``kernel()`` form, :mod:`geomopt.objective.projection`).

    ``chunk`` > 0 (CPU) loops over chunks of that many elements, each computed and added to
    the blocks in the loop: the per-element intermediates stay in cache (measured 2x on the
    4x4 Jacobi projection) and the (m, nb, d, d) element blocks are never stored.  The last
    chunk is shifted back to end at element m, its elements already done masked out, so one
    loop body is compiled.  ``chunk`` = 0 vmaps over all elements at once (an accelerator)."""
    S, Minv, vol = geom
    m, d = S.shape[0], Minv.shape[-1]
    f = jax.vmap(partial(_element_blocks, density, projection, params, code, x))
    VB = jnp.zeros((n_blocks, d, d), x.dtype)
    if not chunk or m <= chunk:
        return VB.at[blocks].add(f(S, Minv, vol, swap))

    def body(i, VB):
        start = jnp.minimum(i * chunk, m - chunk)
        part = [jax.lax.dynamic_slice_in_dim(a, start, chunk) for a in (S, Minv, vol, swap, blocks)]
        new = (start + jnp.arange(chunk)) >= i * chunk  # not done by the previous chunk
        B = jnp.where(new[:, None, None, None], f(*part[:4]), 0.0)
        return VB.at[part[4]].add(B)

    return jax.lax.fori_loop(0, -(-m // chunk), body, VB)


@partial(jit, static_argnums=(0, 1, 2, 3))
def hessian_kernel(density, projection, chunk, n_blocks, geom, free, x, params, code, blocks, swap, gather):
    """Energy, gradient (times the free mask) and the assembled lower-triangle CSC data (nnz,)
    of the projected Hessian: vertex blocks (:func:`block_hessian`) gathered by the pattern's
    ``gather``.  ``projection, code``: a projection's ``kernel()`` form."""
    # all elements at once here: in chunks its scratch is 134 -> 68 MB at 10^6 triangles, but
    # the kernel 10-20 % slower (1.05 -> 1.28 s, the same process alternating)
    value, grad = free_value_and_grad(density, geom, free, x, params)
    VB = block_hessian(density, projection, chunk, geom, x, params, blocks, swap, n_blocks, code)
    return value, grad, VB.reshape(-1)[gather]


# ---------------------------------------------------------------- the objective


class Objective:
    """A problem, an energy and its parameters, with jitted evaluation.

    ``E(x) = sum_e w_e vol_e psi(J_e(x), params)``: ``vol_e`` the rest sizes, ``w_e`` the
    optional per-element weights (``element_weights``, default 1).  Maps ``x`` are (n, dim)
    arrays; gradients are returned with fixed DOFs zeroed.

    With no fixed vertex the energy is invariant to translations (always: J only sees edge
    vectors), which leaves the Hessian singular; then the first vertex of the first element is
    pinned, which changes no minimum.  Rotations (a null or negative-curvature direction of
    rotation-invariant energies) are left to the solvers' diagonal shift: pinning a vertex
    coordinate against them creates a soft, badly conditioned mode instead (measured: 72 vs
    19 Newton iterations on camelhead).

    With ``buckets=True`` (what :func:`~geomopt.parameterize` uses) the arrays are padded to
    size buckets (:mod:`geomopt._runtime.padding`, the one padding rule) so that meshes of similar size
    share compiled kernels and persistent-cache entries; ``buckets`` may also be another
    objective's ``sizes`` (a sub-problem on the same vertices padded like its whole).  Every
    method then takes maps with ``n`` rows (and returns ``n`` rows, ``m`` elements) or
    ``n_padded`` rows, as solver states hold them.

    **Composable.**  :meth:`value`, :meth:`value_and_grad` and :meth:`dets` work under
    ``jax.jit``, ``grad``, ``hessian``, ``jvp`` / ``vjp`` and ``vmap`` (over maps and over
    parameters: ``params`` is a dict of scalars, traced or not), calling the pure function
    there and the tuned jitted kernel on concrete arrays.  An Objective is a JAX pytree
    whose leaves are its problem's arrays (rest geometry, handle positions), the element
    weights, the energy parameters given as traced values, and the padded rest geometry: build it from a :class:`~geomopt.Problem` with
    traced rest vertices to differentiate with respect to the rest shape (e.g.
    ``jax.grad(lambda V: Objective(Problem.surface(V, F), e).value(x))(V)``), or
    ``jax.vmap`` over a batch of rest shapes of one connectivity.  The host-side methods
    (:meth:`hessian`, :meth:`prepare_map`) need concrete values.

    Parameters
    ----------
    problem : :class:`~geomopt.Problem`.
    energy : name or :class:`~geomopt.energies.Energy`.
    buckets : pad to size buckets (see above): True, False, or another objective's ``sizes``.
    element_weights : (m,) positive weights ``w_e`` (traceable), or None.
    params : energy parameters overriding the energy's defaults.
    """

    def __init__(self, problem: Problem, energy: Energy | str, *, buckets=False, element_weights=None,
                 **params):
        if not isinstance(problem, Problem):
            raise ParameterError(f"Objective needs a geomopt.Problem (Problem.planar, Problem.surface or "
                                 f"Problem.tets), got {type(problem).__name__}")
        # traced parameters are leaves of the objective, concrete ones part of its energy
        traced = {k: v for k, v in params.items() if is_traced(v)}
        energy = get_energy(energy, **{k: v for k, v in params.items() if k not in traced})
        energy.resolve_params(**traced)  # known names
        energy.check_dim(np.shape(problem.rest_inv)[-1])  # the Jacobians' size (2 for the sphere)
        mesh = _Mesh(problem, _padding.Sizes.of(problem, buckets))
        w = check_element_weights(element_weights, problem.n_elements)
        vol = problem.volumes if w is None else problem.volumes * w
        _, Minv, vol = _padding.pad_geometry(problem, mesh.sizes, vol)
        # device_put, not jnp.asarray: no copy program compiled per array shape
        Minv, vol = (a if is_traced(a) else jax.device_put(a) for a in (Minv, vol))
        self._set(problem, w, traced, Minv, vol, StaticKey((_energy_key(energy), mesh.key), (energy, mesh)))

    def _set(self, problem, weights, overrides, Minv, vol, static):
        self.problem, self.element_weights, self._overrides, self._static = problem, weights, overrides, static
        self.energy, self._mesh = static.payload
        self.geom = (self._mesh.simplices, Minv, vol)
        #: elements per chunk of the Hessian work (:func:`block_hessian`; 0: all at once)
        self.chunk = CPU_CHUNK if jax.default_backend() == "cpu" else 0

    @property
    def grad_chunk(self) -> int:
        """Elements per chunk of the kernels' energy and gradient (:func:`free_value_and_grad`;
        0: all at once): :data:`GRAD_CHUNK_FACTOR` times ``chunk`` (the Hessian work's,
        :data:`CPU_CHUNK` on CPU)."""
        return GRAD_CHUNK_FACTOR * self.chunk

    def tree_flatten(self):
        return (self.problem, self.element_weights, self._overrides, self.geom[1], self.geom[2]), self._static

    @classmethod
    def tree_unflatten(cls, static, leaves):
        obj = object.__new__(cls)
        obj._set(*leaves, static)
        return obj

    @functools.cached_property
    def total_volume(self):
        """``sum_e w_e vol_e``: a float, or a traced scalar when the rest geometry is traced."""
        vol = self.geom[2]
        return jnp.sum(vol) if is_traced(vol) else float(np.sum(np.asarray(vol)))

    @property
    def sizes(self) -> _padding.Sizes:
        return self._mesh.sizes

    @property
    def free_dofs(self) -> np.ndarray:
        """(n, d) bool: the DOFs a solver moves (not handles, not the gauge pin)."""
        return self._mesh.free_dofs

    @property
    def free_mask(self) -> jax.Array:
        """(n_padded, d) float64 device array: 1 on free DOFs, 0 on fixed and padded ones."""
        return self._mesh.free

    _free = free_mask

    def params(self, **override):
        """The energy's parameters with ``override`` applied, validated by the energy
        (:meth:`~geomopt.energies.Energy.resolve_params`; traced values pass unchecked), as
        float64 scalars for the kernels."""
        p = self.energy.resolve_params(**{**self._overrides, **override})
        return {k: jnp.asarray(v, jnp.float64) for k, v in p.items()}

    @property
    def pattern(self) -> HessianPattern:
        return self._mesh.pattern

    @property
    def block_assembly(self):
        """``(blocks, swap, n_blocks)``: the element-to-vertex-block map with which the kernels
        assemble the Hessian (:func:`block_hessian`), padded like :attr:`geom`: ``blocks``
        (m_padded, (d+1)(d+2)/2) int32 and ``swap`` (same shape) bool device arrays (padded
        elements add zero blocks to their originals' blocks), ``n_blocks`` the padded block count."""
        m = self._mesh
        m.pattern  # noqa: B018 - builds the pattern, its assembly and the padded sizes
        return m.assembly[0], m.assembly[1], m.n_blocks_padded

    def cholesky(self, backend: str = "auto"):
        """A :class:`~geomopt.linalg.linsolve.SparseCholesky` on :attr:`pattern`, its symbolic analysis
        done once per mesh and backend and shared by every copy of this objective."""
        return self._mesh.cholesky(backend)

    def free_factors(self) -> None:
        """Free the numeric factors of the mesh's sparse Cholesky factorizations, keeping
        their symbolic analyses (:meth:`~geomopt.linalg.linsolve.SparseCholesky.free_factor`):
        what a finished solve leaves that no later solve or derivative reuses (each refactors
        its own matrix)."""
        self._mesh.free_factors()

    def release_factorizations(self) -> None:
        """Forget the mesh's sparse Cholesky factorizations (:meth:`cholesky`: symbolic analyses
        and numeric factors, shared by every copy of this objective): their memory returns once
        nothing else holds them (PARDISO's at 10^6 triangles: 1.5 GB); a later solve on the
        mesh analyzes it again.  For a process that has finished solving (the command line
        before it writes its outputs)."""
        self._mesh.release_choleskys()

    # -- padded maps (see geomopt._runtime.padding) ------------------------------------------
    def prepare_map(self, x) -> np.ndarray:
        """A start map ``x`` ((n, d), or (n_padded, d) as a solver state holds it) checked by
        :meth:`Problem.check_map` (float64 copy, handles in place), then padded."""
        refuse_traced("Objective.prepare_map", "give the start map as a NumPy array", x)
        x = np.asarray(x)
        if x.ndim == 2 and x.shape[0] == self.sizes.n_padded != self.sizes.n:
            x = x[: self.sizes.n]
        return _padding.pad_rows(self.problem.check_map(x), self.sizes.n_padded)

    def _pad(self, x):
        """``x`` with n_padded rows (host-side pad for concrete ``x``: no kernel per mesh
        size), and whether it had n rows to begin with."""
        sz = self.sizes
        if not sz.padded or x.shape[0] == sz.n_padded:
            return x, False
        return _padding.pad_rows(x if is_traced(x) else np.asarray(x), sz.n_padded), True

    def pad_map(self, x):
        """``x`` (n, d) with n_padded rows (padded rows on vertex 0); unchanged when it has
        them already or the objective is not padded."""
        return self._pad(x)[0]

    def unpad_map(self, x):
        """The first n rows of a map (or per-vertex array) held with n_padded rows."""
        if not self.sizes.padded:
            return x
        return x[: self.sizes.n] if is_traced(x) else np.asarray(x)[: self.sizes.n]

    def _params(self, params):
        return self.params() if params is None else params

    def value(self, x, params=None) -> jax.Array:
        """The energy at ``x`` (n or n_padded, d); ``params`` default: :meth:`params`."""
        return energy_kernel(self.energy.density, self.grad_chunk, self.geom, self._pad(x)[0], self._params(params))

    def value_and_grad(self, x, params=None):
        """(value, grad with fixed rows zeroed); grad has as many rows as ``x``."""
        xp, cut = self._pad(x)
        v, g = value_and_grad_kernel(self.energy.density, self.grad_chunk, self.geom, self._free, xp,
                                     self._params(params))
        return v, (self.unpad_map(g) if cut else g)

    def hessian(self, x, params, projection="clamp"):
        """(value, grad with fixed rows zeroed (as many rows as ``x``), CSC data (nnz,) of the
        free-DOF Hessian in :attr:`pattern`), each element's block made by ``projection`` (a
        :mod:`geomopt.objective.projection` object or name: ``"clamp"``, ``"abs"``, ``"none"`` for the
        exact Hessian...).  Concrete values only (a host assembly)."""
        refuse_traced("Objective.hessian (a sparse assembly on the host)",
                      "use jax.hessian(lambda x: objective.value(x, params)) for a dense Hessian",
                      x, params, self.geom)
        pat, m = self.pattern, self._mesh
        xp, cut = self._pad(x)
        kernel, code = as_projection(projection).kernel()
        v, g, data = hessian_kernel(self.energy.density, kernel, self.chunk, m.n_blocks_padded,
                                    self.geom, self._free, xp, params, np.int32(code), *m.assembly)
        if m.nnz_padded != pat.nnz:
            data = np.asarray(data)[: pat.nnz]
        return v, (self.unpad_map(g) if cut else g), data

    def compile_hessian(self, x, params, projection="clamp"):
        """Compile (or load from the persistent cache) the kernel of :meth:`hessian` for maps
        shaped like ``x``, without running it: a solver's set-up then holds the compilation
        but no throw-away evaluation."""
        m = self._mesh
        m.pattern  # noqa: B018 - builds the pattern, its assembly and the padded sizes
        kernel, code = as_projection(projection).kernel()
        hessian_kernel.prepare(self.energy.density, kernel, self.chunk, m.n_blocks_padded,
                               self.geom, self._free, self._pad(x)[0], params, np.int32(code), *m.assembly)

    def dets(self, x) -> jax.Array:
        """(m,) determinant of each element's edge matrix (sign = orientation)."""
        out = dets_kernel(self.geom, self._pad(x)[0])
        if not self.sizes.padded:
            return out
        return out[: self.sizes.m] if is_traced(out) else np.asarray(out)[: self.sizes.m]


_x64.float64_methods("__init__", "params", "value", "value_and_grad", "hessian", "compile_hessian", "dets")(Objective)
jax.tree_util.register_pytree_node(Objective, Objective.tree_flatten, Objective.tree_unflatten)


def _energy_key(energy: Energy) -> tuple:
    """What a traced Objective's code depends on in its energy (its values by content)."""
    rest = energy.rest_value
    return (energy.density, energy.name, energy.barrier, energy.lower_bound,
            rest if rest is None or callable(rest) else float(rest), tuple(sorted(energy.params.items())))


def check_element_weights(w, m):
    """Per-element weights as (m,) float64 (positive and finite when concrete; ParameterError
    otherwise), or None."""
    if w is None:
        return None
    if not is_traced(w):
        w = np.asarray(w, dtype=np.float64) if np.ndim(w) else w
    if np.shape(w) != (m,):
        raise ParameterError(f"element_weights must have shape ({m},) (one weight per element), "
                             f"got shape {np.shape(w)}")
    if not is_traced(w) and not (np.isfinite(w).all() and (w > 0).all()):
        bad = np.flatnonzero(~(np.isfinite(w) & (w > 0)))
        raise ParameterError(f"element_weights must be finite and > 0; {bad.size} are not (first: "
                             f"element {bad[0]}, weight {w[bad[0]]!r})")
    return w


class _Mesh:
    """What an Objective derives from its problem's static data (connectivity, handles,
    sizes), shared by every copy of the objective (pytree unflattening): device simplices,
    the free DOFs and, built on first use, the Hessian pattern and its assembly arrays."""

    def __init__(self, problem: Problem, sizes: _padding.Sizes):
        self.key = (problem.static_key, sizes)
        self.sizes = sizes
        d = problem.dim
        free = np.repeat(problem.free_mask[:, None], d, axis=1)
        if problem.fixed.size == 0:
            free[problem.simplices[0, 0]] = False
        self.free_dofs = free
        with jax.ensure_compile_time_eval():  # concrete device arrays, also when built under a trace
            self.simplices = jax.device_put(_padding.pad_rows(problem.simplices, sizes.m_padded, cycle=True))
            self.free = jax.device_put(_padding.pad_rows(free.astype(np.float64), sizes.n_padded, fill=0.0))
        # the pattern needs the connectivity only (never the problem's possibly traced arrays)
        self._connectivity = types.SimpleNamespace(dim=d, simplices=problem.simplices,
                                                   n_vertices=problem.n_vertices)
        self._pattern = None
        self._building = threading.Lock()
        self._cholesky = {}

    def release_choleskys(self):
        self._cholesky.clear()

    def free_factors(self):
        for chol in self._cholesky.values():
            chol.free_factor()

    def cholesky(self, backend):
        if backend == "auto":  # one analysis whether asked for by name or as "auto"
            backend = available_backends()[0]
        if backend not in self._cholesky:
            pat = self.pattern
            chol = SparseCholesky(pat.indptr, pat.indices, backend, single=pat.n >= SINGLE_FROM_ROWS)
            chol.analyze(background=chol.n >= AHEAD_FROM)  # while the solver loads its kernels
            self._cholesky[backend] = chol
        return self._cholesky[backend]

    @property
    def pattern(self) -> HessianPattern:
        with self._building:  # built once, also when a solver's kernels are loaded ahead on a thread
            return self._pattern if self._pattern is not None else self._build_pattern()

    def _build_pattern(self) -> HessianPattern:
        if self._connectivity.simplices.shape[1] == self._connectivity.dim:  # cones over the origin
            raise ParameterError("a map onto the sphere has no assembled Hessian (its Jacobians are not "
                                 "linear in x): minimise it with L-BFGS (geomopt.sphere_map)")
        pat = hessian_pattern(self._connectivity, self.free_dofs)
        sz = self.sizes
        # padded kernels see bucketed sizes: padded elements (zero-volume copies, cycling)
        # add zero blocks to their originals' blocks, padded CSC entries gather block entry 0
        # and are cut off on the host
        self.nnz_padded = _padding.power_bucket(pat.nnz) if sz.padded else pat.nnz
        self.n_blocks_padded = _padding.power_bucket(pat.n_blocks) if sz.padded else pat.n_blocks
        blocks = _padding.pad_rows(pat.blocks, sz.m_padded, cycle=True)
        swap = _padding.pad_rows(pat.swap, sz.m_padded, cycle=True)
        gather = np.concatenate([pat.gather, np.zeros(self.nnz_padded - pat.nnz, pat.gather.dtype)])
        with jax.ensure_compile_time_eval():
            self.assembly = tuple(jax.device_put(a) for a in (blocks, swap, gather))
        if all(d.platform == "cpu" for a in self.assembly for d in a.devices()):
            # the pattern's assembly maps become read-only views of the device copies (NumPy
            # reads a CPU buffer in place): one copy of each in memory, not two (57 MB at 10^6
            # triangles)
            m = len(pat.blocks)
            blocks, swap, gather = (np.asarray(a) for a in self.assembly)
            pat = dataclasses.replace(pat, blocks=blocks[:m], swap=swap[:m], gather=gather[: pat.nnz])
        self._pattern = pat
        return pat


@partial(jit, static_argnums=0)
def _densities_kernel(density, geom, x, params):
    return jax.vmap(density, in_axes=(0, None))(jacobians(geom, x), params)


@_x64.float64
def element_densities(objective: Objective, x, params=None) -> jax.Array:
    """(m,) the density of each element under ``x`` (unweighted), e.g. for colouring.  A concrete
    ``x`` stays on the host up to the kept kernel and the result is cut to ``m`` there: no eager
    JAX operation, which a new process would compile."""
    concrete = not is_traced(x)
    x = np.asarray(x, np.float64) if concrete else jnp.asarray(x)
    out = _densities_kernel(objective.energy.density, objective.geom, objective.pad_map(x),
                            objective.params(**(params or {})))
    if not objective.sizes.padded:
        return out
    return jax.device_put(np.asarray(out)[: objective.sizes.m]) if concrete else out[: objective.sizes.m]

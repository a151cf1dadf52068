"""Energy, gradient and projected sparse Hessian of ``sum_e vol_e psi(J_e(x))``.

Everything is derived from the density by JAX: ``vmap`` over elements, ``grad`` for the
gradient, ``hessian`` for the element Hessian in J-space (``d^2 x d^2``), which is projected
to PSD there (cheaper than projecting the ``(d+1)d``-square element block, and valid since
the map from vertex positions to ``vec J`` is linear) and then lifted with the constant
matrix ``G`` such that ``J = X^T G`` for the element's vertex positions ``X`` ((d+1), d).
The global matrix is assembled into a CSC pattern computed once per mesh.

The hot functions are module-level ``jax.jit`` functions keyed on the density (static) and
array shapes; parameters (eps, lambda...) are traced, so a solve never recompiles.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from . import _padding
from ._eigh import eigh
from ._geometry import dets
from ._errors import ParameterError
from .energies import Energy, get_energy
from .problem import Problem

PROJECTIONS = ("clamp", "abs", "none")


# ---------------------------------------------------------------- jitted kernels


def _jacobians(geom, x):
    S, Minv, _ = geom
    X = x[S]  # (m, d+1, d)
    Ds = jnp.swapaxes(X[:, 1:] - X[:, :1], 1, 2)  # columns = edges
    return Ds @ Minv


def _dets(geom, x):
    return dets(geom[0], x)


def _total(density, geom, x, params):
    vol = geom[2]
    psi = jax.vmap(density, in_axes=(0, None))(_jacobians(geom, x), params)
    return jnp.sum(vol * psi)


@partial(jax.jit, static_argnums=0)
def energy_kernel(density, geom, x, params):
    return _total(density, geom, x, params)


@partial(jax.jit, static_argnums=0)
def value_and_grad_kernel(density, geom, x, params):
    return jax.value_and_grad(_total, argnums=2)(density, geom, x, params)


@jax.jit
def dets_kernel(geom, x):
    return _dets(geom, x)


def project_psd(H, method):
    """Project symmetric blocks ``H`` (..., k, k) to PSD by their eigenvalues.

    ``clamp``: ``max(lambda, floor)`` with a tiny relative floor (Teran et al. 2005);
    ``abs``: ``max(|lambda|, floor)`` (Chen et al. 2024, "Stabler Neo-Hookean simulation:
    absolute eigenvalue filtering for projected Newton"); ``none``: unchanged.
    PSD blocks are returned unchanged up to rounding and the floor.
    """
    if method == "none":
        return H
    w, Q = eigh(H)
    floor = 1e-10 * jnp.max(jnp.abs(w), axis=-1, keepdims=True)
    if method == "clamp":
        w = jnp.maximum(w, floor)
    elif method == "abs":
        w = jnp.maximum(jnp.abs(w), floor)
    else:
        raise ParameterError(f"unknown PSD projection {method!r}; valid: {', '.join(PROJECTIONS)}")
    return (Q * w[..., None, :]) @ jnp.swapaxes(Q, -1, -2)


def element_blocks(density, projection, J, params, vol):
    """(m, d*d, d*d) J-space element blocks ``vol * H_e``: the density's Hessian projected by
    ``projection`` (a :data:`PROJECTIONS` name), or a proxy object (SLIM, CM;
    :mod:`geomopt.solvers.proxies`) called as ``projection(density, J, params)``."""
    m, d = J.shape[0], J.shape[-1]
    if callable(projection):
        H = jax.vmap(projection, in_axes=(None, 0, None))(density, J, params).reshape(m, d * d, d * d)
        return H * vol[:, None, None]
    H = jax.vmap(jax.hessian(density), in_axes=(0, None))(J, params).reshape(m, d * d, d * d)
    return project_psd(H * vol[:, None, None], projection)


def _lift_matrix(Minv):
    """G (m, d+1, d) with ``J = X^T G`` for element vertex positions X (d+1, d)."""
    return jnp.concatenate([-jnp.sum(Minv, axis=1, keepdims=True), Minv], axis=1)


def local_pairs(d):
    """The element-local DOF pairs ``p <= q`` (DOF p = vertex a, coordinate c: p = a*d + c):
    the element Hessian is symmetric, so only these are lifted and assembled."""
    k = (d + 1) * d
    p, q = np.triu_indices(k)
    return p, q


def _lift_upper(HJ, G):
    """Entries ``p <= q`` (row-major upper triangle, as :func:`local_pairs`) of the element
    Hessians ``Hx[m, a, c, b, e] = sum_jl G[m, a, j] HJ[m, c, j, e, l] G[m, b, l]``.

    Written as broadcast products summed over the tiny axes j and l and static slices: XLA
    fuses these into loops, 2.5x faster on CPU than ``einsum`` (batched small dot_general)
    and 6x faster than gathering the pairs."""
    m, d = G.shape[0], G.shape[2]
    k = (d + 1) * d
    T = sum(G[:, :, None, None, j, None] * HJ[:, None, :, j, :, :] for j in range(d))  # m a c e l
    Hx = sum(T[:, :, :, None, :, l] * G[:, None, None, :, l, None] for l in range(d))  # m a c b e
    Hx = Hx.reshape(m, k, k)
    return jnp.concatenate([Hx[:, i, i:] for i in range(k)], axis=1)


@partial(jax.jit, static_argnums=(0, 1, 2))
def hessian_kernel(density, projection, nnz, geom, x, params, slots):
    """Energy, gradient and the assembled lower-triangle CSC data of the projected Hessian.

    Only the element pairs ``p <= q`` are formed (the element Hessian is symmetric); each goes
    to the lower-triangle slot of its global (row, col)."""
    value, grad = jax.value_and_grad(_total, argnums=2)(density, geom, x, params)
    S, Minv, vol = geom
    m, k1 = S.shape
    d = k1 - 1
    J = _jacobians(geom, x)
    HJ = element_blocks(density, projection, J, params, vol).reshape(m, d, d, d, d)
    Hx = _lift_upper(HJ, _lift_matrix(Minv))
    data = jnp.zeros(nnz + 1, Hx.dtype).at[slots].add(Hx.reshape(-1))[:nnz]
    return value, grad, data


# ---------------------------------------------------------------- sparsity pattern


@dataclasses.dataclass(frozen=True, eq=False)
class HessianPattern:
    """CSC pattern of the lower triangle of the Hessian restricted to free DOFs
    (vertex-major numbering: dof = v*d + c).  Sparse Cholesky backends read only the lower
    triangle; :meth:`matrix` gives the full symmetric matrix."""

    n: int  # number of free DOFs
    indptr: np.ndarray
    indices: np.ndarray
    slots: np.ndarray  # (m*P,) data position of each element pair p <= q; nnz = dropped
    free_dofs: np.ndarray  # (n,) global dof ids of free DOFs
    diag: np.ndarray  # (n,) data positions of the diagonal

    @property
    def nnz(self) -> int:
        return len(self.indices)

    def lower(self, data) -> sp.csc_matrix:
        return sp.csc_matrix((np.asarray(data), self.indices, self.indptr), shape=(self.n, self.n))

    def matrix(self, data) -> sp.csc_matrix:
        L = self.lower(data)
        return (L + L.T - sp.diags(L.diagonal())).tocsc()


def hessian_pattern(problem: Problem, free_dofs) -> HessianPattern:
    """The pattern for ``free_dofs`` (n, d) bool."""
    d = problem.dim
    free = np.asarray(free_dofs, bool).reshape(-1)
    red = np.full(problem.n_vertices * d, -1, np.int64)
    red[free] = np.arange(free.sum())
    n = int(free.sum())
    dof = (problem.simplices[:, :, None] * d + np.arange(d)).reshape(len(problem.simplices), -1)
    r = red[dof]
    p, q = local_pairs(d)
    rp, rq = r[:, p].reshape(-1), r[:, q].reshape(-1)
    rows, cols = np.maximum(rp, rq), np.minimum(rp, rq)
    valid = cols >= 0
    keys = cols[valid] * n + rows[valid]
    uniq, inv = np.unique(keys, return_inverse=True)
    slots = np.full(rows.shape, len(uniq), np.int64)
    slots[valid] = inv
    ucols, urows = np.divmod(uniq, n) if n else (uniq, uniq)
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(ucols, minlength=n), out=indptr[1:])
    diag = np.flatnonzero(urows == ucols)
    return HessianPattern(n, indptr, urows.astype(np.int64), slots, np.flatnonzero(free), diag)


# ---------------------------------------------------------------- the objective


class Objective:
    """A problem, an energy and its parameters, with jitted evaluation.

    Maps ``x`` are (n, dim) arrays; gradients are returned with fixed DOFs zeroed.

    With no fixed vertex the energy is invariant to translations (always: J only sees edge
    vectors), which leaves the Hessian singular; then the first vertex of the first element is
    pinned, which changes no minimum.  Rotations (a null or negative-curvature direction of
    rotation-invariant energies) are left to the solvers' diagonal shift: pinning a vertex
    coordinate against them creates a soft, badly conditioned mode instead (measured: 72 vs
    19 Newton iterations on camelhead).

    With ``buckets=True`` (what :func:`~geomopt.parameterize` uses) the arrays are padded to
    size buckets (:mod:`geomopt._padding`) so that meshes of similar size share compiled
    kernels and persistent-cache entries; every method then takes maps with ``n`` rows (and
    returns ``n`` rows, ``m`` elements) or ``n_padded`` rows, as solver states hold them.
    """

    def __init__(self, problem: Problem, energy: Energy | str, *, buckets: bool = False, **params):
        self.problem = problem
        self.energy = get_energy(energy, **params)
        self.energy.check_dim(problem.dim)
        # buckets=True pads the arrays to size buckets so that meshes of similar size share
        # compiled kernels (geomopt._padding); maps may then be given with n or n_padded rows
        self.sizes = _padding.Sizes.of(problem, buckets)
        # device_put, not jnp.asarray: no copy program compiled per array shape
        self.geom = tuple(jax.device_put(a) for a in _padding.pad_geometry(problem, self.sizes))
        self.total_volume = float(problem.volumes.sum())
        d = problem.dim
        free = np.repeat(problem.free_mask[:, None], d, axis=1)
        if problem.fixed.size == 0:
            free[problem.simplices[0, 0]] = False
        self.free_dofs = free
        self._free = jax.device_put(_padding.pad_rows(free.astype(np.float64), self.sizes.n_padded, fill=0.0))
        self._pattern = None
        self._slots = None
        self._nnz_padded = None

    def params(self, **override):
        """The energy's parameters with ``override`` applied, validated by the energy
        (:meth:`~geomopt.energies.Energy.resolve_params`), as float64 scalars for the kernels."""
        p = self.energy.resolve_params(**override)
        return {k: jnp.float64(v) for k, v in p.items()}

    @property
    def pattern(self) -> HessianPattern:
        if self._pattern is None:
            pat = hessian_pattern(self.problem, self.free_dofs)
            sz = self.sizes
            self._nnz_padded = _padding.bucket(pat.nnz) if sz.padded else pat.nnz
            self._slots = jax.device_put(_padding.pad_slots(pat.slots, pat.nnz, sz.m, sz.m_padded,
                                                            self._nnz_padded))
            self._pattern = pat
        return self._pattern

    # -- padded maps (see geomopt._padding) ------------------------------------------
    def prepare_map(self, x) -> np.ndarray:
        """A start map ``x`` ((n, d), or (n_padded, d) as a solver state holds it) checked by
        :meth:`Problem.check_map` (float64 copy, handles in place), then padded."""
        x = np.asarray(x)
        if x.ndim == 2 and x.shape[0] == self.sizes.n_padded != self.sizes.n:
            x = x[: self.sizes.n]
        return _padding.pad_rows(self.problem.check_map(x), self.sizes.n_padded)

    def _pad(self, x):
        """``x`` with n_padded rows (host-side pad: no kernel per mesh size), and whether it
        had n rows to begin with."""
        sz = self.sizes
        if not sz.padded or x.shape[0] == sz.n_padded:
            return x, False
        return _padding.pad_rows(np.asarray(x), sz.n_padded), True

    def pad_map(self, x):
        """``x`` (n, d) with n_padded rows (padded rows on vertex 0); unchanged when it has
        them already or the objective is not padded."""
        return self._pad(x)[0]

    def unpad_map(self, x):
        """The first n rows of a map (or per-vertex array) held with n_padded rows."""
        return np.asarray(x)[: self.sizes.n] if self.sizes.padded else x

    def value(self, x, params) -> jax.Array:
        return energy_kernel(self.energy.density, self.geom, self._pad(x)[0], params)

    def value_and_grad(self, x, params):
        """(value, grad with fixed rows zeroed); grad has as many rows as ``x``."""
        xp, cut = self._pad(x)
        v, g = value_and_grad_kernel(self.energy.density, self.geom, xp, params)
        g = g * self._free
        return v, (self.unpad_map(g) if cut else g)

    def hessian(self, x, params, projection="clamp"):
        """(value, grad with fixed rows zeroed (as many rows as ``x``), CSC data (nnz,) of the
        free-DOF Hessian in :attr:`pattern`)."""
        pat = self.pattern
        xp, cut = self._pad(x)
        v, g, data = hessian_kernel(
            self.energy.density, projection, self._nnz_padded, self.geom, xp, params, self._slots
        )
        g = g * self._free
        if self._nnz_padded != pat.nnz:
            data = np.asarray(data)[: pat.nnz]
        return v, (self.unpad_map(g) if cut else g), data

    def compile_hessian(self, x, params, projection="clamp"):
        """Compile (or load from the persistent cache) the kernel of :meth:`hessian` for maps
        shaped like ``x``, without running it: a solver's set-up then holds the compilation
        but no throw-away evaluation."""
        if self._pattern is None:
            self.pattern  # noqa: B018 - builds the pattern, the slots and the padded entry count
        hessian_kernel.lower(self.energy.density, projection, self._nnz_padded, self.geom, self._pad(x)[0],
                             params, self._slots).compile()

    def dets(self, x) -> jax.Array:
        """(m,) determinant of each element's edge matrix (sign = orientation)."""
        out = dets_kernel(self.geom, self._pad(x)[0])
        return np.asarray(out)[: self.sizes.m] if self.sizes.padded else out


@partial(jax.jit, static_argnums=0)
def _densities_kernel(density, geom, x, params):
    return jax.vmap(density, in_axes=(0, None))(_jacobians(geom, x), params)


def element_densities(objective: Objective, x, params=None) -> jax.Array:
    """(m,) the density of each element under ``x`` (unweighted), e.g. for colouring."""
    out = _densities_kernel(objective.energy.density, objective.geom, objective._pad(jnp.asarray(x))[0],
                            objective.params(**(params or {})))
    return out[: objective.sizes.m] if objective.sizes.padded else out

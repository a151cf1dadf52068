"""The gauge of a map: the motions (translations, rotations, scaling) that leave an energy
unchanged and every handle in place, and the DOFs to pin against them (the null space of the
exact Hessian at an optimum, for :mod:`geomopt.objective.adjoint`)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .objective import Objective

__all__ = ["gauge_motions", "gauge_pins"]

def _symmetries(energy, params, d):
    return _symmetries_of(energy.density, tuple(sorted(params.items())), d)


@functools.lru_cache(maxsize=64)
def _symmetries_of(density, params, d, samples=4, rtol=1e-9):
    """(rotation, scale): whether the density is invariant under ``J -> R J`` (rotations of the
    map) and ``J -> s J``, tested on random Jacobians with ``det J > 0``."""
    rng = np.random.default_rng(0)
    p = {k: jnp.float64(v) for k, v in params}
    psi = jax.vmap(density, in_axes=(0, None))
    J = np.eye(d) + 0.3 * rng.standard_normal((samples, d, d))
    J[np.linalg.det(J) < 0, 0] *= -1
    A = rng.standard_normal((d, d))
    import scipy.linalg  # here: 30 ms of import that a solve without a gauge question never needs

    R = scipy.linalg.expm(A - A.T)
    base = np.asarray(psi(J, p))
    ok = np.isfinite(base)

    def same(other):
        return bool(np.all(np.abs(np.asarray(psi(other, p)) - base)[ok] <= rtol * np.abs(base[ok]).clip(1e-300)))

    return same(R @ J), same(1.7 * J)


def gauge_motions(objective: Objective, params, x) -> np.ndarray:
    """An orthonormal basis (n*d, r) of the motions of the map ``x`` (n, d) that leave the energy
    unchanged and every handle in place: translations (always symmetries), rotations and
    scaling when the density is invariant under them (tested on it), restricted to those that
    fix the handles.  ``r = 0`` for a map held by enough handles."""
    P = objective.problem
    n, d = x.shape
    rotation, scale = _symmetries(objective.energy, params, d)
    gens = [np.tile(np.eye(d)[c], (n, 1)) for c in range(d)]
    if rotation:
        axes = [np.array([[0.0, -1.0], [1.0, 0.0]])] if d == 2 else [
            np.cross(np.eye(3)[a], np.eye(3)) for a in range(3)]  # skew generators: v -> e_a x v
        gens += [x @ K.T for K in axes]
    if scale:
        gens.append(x.copy())
    G = np.stack([g.reshape(-1) for g in gens], 1)
    handles = (P.fixed[:, None] * d + np.arange(d)).reshape(-1)
    if handles.size:
        G = G @ _null(G[handles])
    return _orthonormal(G)


def _null(A, rtol=1e-10):
    """Orthonormal basis of the null space of ``A`` (k, r): (r, r - rank)."""
    if A.shape[0] == 0:
        return np.eye(A.shape[1])
    _, s, Vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])  # no (k, k) U for tall A
    rank = int(np.sum(s > rtol * max(s.max(initial=0.0), 1e-300)))
    return Vt[rank:].T


def _orthonormal(G, rtol=1e-10):
    if G.shape[1] == 0:
        return G
    U, s, _ = np.linalg.svd(G, full_matrices=False)
    return U[:, : int(np.sum(s > rtol * max(s.max(initial=0.0), 1e-300)))]


def gauge_pins(N, free_dofs) -> np.ndarray:
    """The free DOFs (indices into the free numbering) to pin so that the pinned DOFs together
    with the objective's own gauge pin meet every motion of ``N`` (n*d, r) transversally: the
    motions vanishing on the objective's pin, restricted to the free DOFs, pivoted by QR."""
    free = free_dofs.reshape(-1)
    if N.shape[1] == 0:
        return np.zeros(0, np.int64)
    M = N @ _null(N[~free & _moving(N)])
    if M.shape[1] == 0:
        return np.zeros(0, np.int64)
    import scipy.linalg

    _, _, piv = scipy.linalg.qr(M[free].T, pivoting=True, mode="economic")
    return np.sort(piv[: M.shape[1]])


def _moving(N):
    """DOFs that some motion of ``N`` moves (handles never do)."""
    return np.abs(N).max(axis=1) > 0

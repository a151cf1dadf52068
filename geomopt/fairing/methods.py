"""The smoothing methods of the lectures, each a function of the input vertices that returns
the smoothed ones (its *target*), on NumPy arrays (host solves) or JAX arrays (differentiable,
:mod:`geomopt.fairing.solve`).

Every method reads the vertices ``V`` (n, d) of a triangle surface (d = 3) or a polyline
(d = 2 or 3), its :class:`~geomopt.fairing.operators.Topology`, the ``free`` (n,) vertices it
moves (the others held) and a :class:`~geomopt.fairing.options.FairOptions`.  Lengths enter
relative to the mean edge length ``h`` of the input, so a setting smooths a mesh the same way at
any size.  ``L`` is the stiffness matrix of :mod:`~geomopt.fairing.operators` (negative
semi-definite), ``M`` the lumped mass, ``D`` the diagonal of ``-L``.

- ``laplacian``: ``steps`` explicit steps ``p += lam D^-1 L p`` (the weights recomputed at each
  step; Taubin 1995, Desbrun et al. 1999).
- ``taubin``: the same with ``lam`` and ``mu < -lam`` alternating: a low-pass filter that does
  not shrink (Taubin, "A signal processing approach to fair surface design", 1995).
- ``implicit``: ``steps`` backward Euler steps of the Laplacian flow, ``(M - dt L) p' = M p``,
  ``dt = time h^2 / steps``, ``L`` and ``M`` at the current vertices (Desbrun, Meyer, Schroeder &
  Barr, "Implicit fairing of irregular meshes using diffusion and curvature flow", 1999).
- ``least_squares``: ``min |W_L A p|^2 + weight |W_P (p - p0)|^2`` with ``A = D^-1 L`` (uniform:
  inner and outer fairness) or ``h^2 M^-1 L`` (cotangent: outer fairness only); ``W_L, W_P``
  from a crease angle (features fit harder and fair less).  Nealen, Igarashi, Sorkine & Alexa,
  "Laplacian mesh optimization", 2006.
- ``energy``: ``min sum_i A_i (|(M^-1 L p)_i|^2 + w |p_i - p0_i|^2)``, ``w = weight / h^4``:
  ``(L M^-1 L + w M) p = w M p0`` (the bi-Laplacian fairing energy with a data term).
- ``spectral``: ``p = h + Phi Phi^T M (p0 - h)`` with ``Phi`` the ``eigenvectors`` lowest
  eigenvectors of ``-L phi = lambda M phi`` (M-orthonormal; Taubin 1995, Vallet & Levy, "Spectral
  geometry processing with manifold harmonics", 2008); ``h`` the harmonic extension of held
  vertices (0 when none: the basis then holds the constants).  Differentiable in the signal and
  the mass with the basis held (the eigenvectors' own derivative is not propagated).
- ``tangential``: ``min |D_u^-1 L_u p - D_c^-1 L_c p0|^2 + weight |p - p0|^2``: the uniform
  Laplacian of the result matches the input's cotangent one, which moves vertices along the
  surface towards regular triangles (Nealen et al. 2006, triangle shape optimization).
"""

from __future__ import annotations

import numpy as np

from .operators import Diag, Sparse, Sum, Product, edge_weights, masses, segment_sum, xp_of
from .solve import linear_solve

__all__ = ["TARGETS", "explicit_steps", "implicit", "least_squares", "energy", "spectral", "tangential",
           "crease_vertices", "normalized_laplacian"]


def normalized_laplacian(V, topo, laplacian):
    """``D^-1 L`` as an operator (rows of ``L`` divided by their weight sums) and ``L``."""
    xp = xp_of(V)
    w = edge_weights(V, topo, laplacian)
    L = Sparse.laplacian(topo, w)
    d = segment_sum(xp, xp.concatenate([w, w]), np.concatenate([topo.edges[:, 0], topo.edges[:, 1]]), topo.n)
    return Product(Diag(1.0 / xp.where(d > 0, d, 1.0)), L), L


def explicit_steps(V, topo, free, o, h):
    """``laplacian`` (``mu`` None) and ``taubin``: ``o.steps`` explicit steps (pairs for Taubin)."""
    xp = xp_of(V)
    move = xp.asarray(free, dtype=V.dtype)[:, None]
    factors = [o.lam] if o.method == "laplacian" else [o.lam, o.mu]
    p = V
    A = normalized_laplacian(p, topo, o.laplacian)[0] if o.laplacian == "uniform" else None  # weights fixed
    if A is not None and xp is np:
        K = A.csr()  # assembled once: a CSR product is several times faster than the scatter
        apply = K.dot
    else:
        apply = A.matvec if A is not None else None
    scaled = [f * move for f in factors]  # (f * move * step(p), evaluated left to right)
    for _ in range(o.steps):
        for f in scaled:
            step = apply or normalized_laplacian(p, topo, o.laplacian)[0].matvec
            if xp is np:  # in place: one temporary fewer per step, the same floats
                change = step(p)
                change *= f
                p = p + change
            else:
                p = p + f * step(p)
    return p


def implicit(V, topo, free, o, h):
    """``implicit``: ``o.steps`` backward Euler steps of ``(M - dt L) p' = M p``."""
    xp = xp_of(V)
    dt = o.time * h * h / o.steps
    p = V
    for _ in range(o.steps):
        L = Sparse.laplacian(topo, edge_weights(p, topo, o.laplacian))
        m = masses(p, topo)
        A = Sum(Diag(m), Sparse(L.rows, L.cols, -dt * L.vals, L.n))
        p = linear_solve(A, m[:, None] * p, free, p)
    return p


def crease_vertices(V, topo, angle):
    """(n,) bool: vertices on an edge whose dihedral angle (between the normals of its two
    triangles) exceeds ``angle`` degrees, or on the boundary (concrete)."""
    V = np.asarray(V, dtype=np.float64)
    on = np.zeros(topo.n, bool)
    on[topo.boundary] = True
    if topo.is_curve or angle is None:
        return on
    S = topo.elements
    n = np.cross(V[S[:, 1]] - V[S[:, 0]], V[S[:, 2]] - V[S[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    owner = np.repeat(np.arange(len(S)), 3)
    order = np.argsort(topo.element_edges.reshape(-1), kind="stable")
    e = topo.element_edges.reshape(-1)[order]
    pair = np.flatnonzero(e[1:] == e[:-1])
    f, g = owner[order][pair], owner[order][pair + 1]
    cos = np.clip(np.sum(n[f] * n[g], axis=1), -1.0, 1.0)
    sharp = topo.edges[e[pair][np.degrees(np.arccos(cos)) > angle]]
    on[sharp.ravel()] = True
    return on


def least_squares(V, topo, free, o, h):
    """``least_squares``: ``(A^T W_L^2 A + weight W_P^2) p = weight W_P^2 p0``."""
    xp = xp_of(V)
    if o.laplacian == "uniform":
        A, _ = normalized_laplacian(V, topo, "uniform")
    else:
        L = Sparse.laplacian(topo, edge_weights(V, topo, "cotangent"))
        A = Product(Diag(h * h / masses(V, topo)), L)
    feature = crease_vertices(V, topo, o.crease_angle) if o.crease_angle is not None else np.zeros(topo.n, bool)
    wl = xp.asarray(np.where(feature, 1.0 / o.feature_weight, 1.0) ** 2)
    wp = xp.asarray(np.where(feature, o.feature_weight, 1.0) ** 2) * o.weight
    system = Sum(Product(A.T, Product(Diag(wl), A)), Diag(wp))
    return linear_solve(system, wp[:, None] * V, free, V)


def energy(V, topo, free, o, h):
    """``energy``: ``(L M^-1 L + w M) p = w M p0``, ``w = weight / h^4``."""
    L = Sparse.laplacian(topo, edge_weights(V, topo, o.laplacian))
    m = masses(V, topo)
    w = o.weight / h ** 4
    system = Sum(Product(L, Product(Diag(1.0 / m), L)), Diag(w * m))
    return linear_solve(system, (w * m)[:, None] * V, free, V)


def tangential(V, topo, free, o, h):
    """``tangential``: ``(A_u^T A_u + weight I) p = A_u^T (A_c p0) + weight p0``."""
    xp = xp_of(V)
    Au, _ = normalized_laplacian(V, topo, "uniform")
    Ac, _ = normalized_laplacian(V, topo, "cotangent")
    system = Sum(Product(Au.T, Au), Diag(xp.full(topo.n, o.weight)))
    return linear_solve(system, Au.T.matvec(Ac.matvec(V)) + o.weight * V, free, V)


def _basis(V, topo, free, k, laplacian):
    """(n, k) the lowest ``k`` M-orthonormal eigenvectors of ``-L phi = lambda M phi`` on the
    ``free`` vertices (zero on the held ones); NumPy, from concrete ``V``."""
    from scipy.sparse.linalg import eigsh

    V = np.asarray(V, dtype=np.float64)
    L = Sparse.laplacian(topo, edge_weights(V, topo, laplacian)).csr()
    m = masses(V, topo)
    F = np.flatnonzero(free)
    K, Mf = -L[F][:, F], m[F]
    k = min(k, len(F))
    if k >= len(F) - 1 or len(F) < 200:
        from scipy.linalg import eigh

        _, vecs = eigh(K.toarray(), np.diag(Mf), subset_by_index=(0, k - 1))
    else:  # shift-invert about a point just below 0: the lowest eigenvalues converge first
        import scipy.sparse as sp

        _, vecs = eigsh(K.tocsc(), k=k, M=sp.diags(Mf).tocsc(), sigma=-1e-8 * float(np.mean(Mf)), which="LM")
    out = np.zeros((topo.n, k))
    out[F] = vecs
    return out


def spectral(V, topo, free, o, h):
    """``spectral``: the projection onto the lowest ``o.eigenvectors`` eigenvectors (see the
    module notes)."""
    xp = xp_of(V)
    k = min(o.eigenvectors, int(np.count_nonzero(free)))
    if xp is np:
        phi = _basis(V, topo, free, k, o.laplacian)
    else:
        import jax

        from .._runtime.x64 import pure_callback

        phi = jax.lax.stop_gradient(pure_callback(lambda v: _basis(v, topo, free, k, o.laplacian),
                                                  jax.ShapeDtypeStruct((topo.n, k), V.dtype), V))
    m = masses(V, topo)
    if np.all(free):
        base = xp.zeros_like(V)
    else:
        L = Sparse.laplacian(topo, edge_weights(V, topo, o.laplacian))  # a tiny mass term: 0 on free parts
        A = Sum(Sparse(L.rows, L.cols, -L.vals, L.n), Diag(1e-10 * m / (h * h)))  # that hold no vertex
        base = linear_solve(A, xp.zeros_like(V), free, V)
    d = V - base
    return base + phi @ (phi.T @ (m[:, None] * d))


TARGETS = {"laplacian": explicit_steps, "taubin": explicit_steps, "implicit": implicit,
           "least_squares": least_squares, "energy": energy, "spectral": spectral, "tangential": tangential}

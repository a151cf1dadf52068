"""The energies the solve-based methods minimise, as functions of the smoothed vertices, to add
to other energies (a distortion, a user's loss) and minimise together.

:func:`fairing_energy` returns ``E(p)``, a pure function of ``p`` (n, d), NumPy or JAX (then
differentiable, jittable), whose unique minimiser with the held vertices at the input's is the
target of :func:`~geomopt.fairing.smoothed` for the same options: the methods
``least_squares``, ``energy`` and ``tangential`` (see :mod:`geomopt.fairing.methods` for the
formulas); ``implicit`` gives its one backward Euler step's energy
``(p - p0)^T M (p - p0) / 2 - dt p^T L p / 2``; ``laplacian`` the Dirichlet energy
``-p^T L p / 2``, whose gradient steps the explicit Laplacian steps take.  The operators are
built once from the input ``V0`` (cotangent weights and masses at ``V0``).
"""

from __future__ import annotations

import numpy as np

from .methods import crease_vertices, normalized_laplacian
from .operators import Diag, Product, Sparse, Topology, edge_weights, masses, mean_edge_length, xp_of
from .options import FairOptions

__all__ = ["fairing_energy"]


def _sq(xp, A, x, w=None):
    """``sum_i w_i |(A x)_i|^2`` (``w`` 1 when None)."""
    y = A.matvec(x)
    return xp.sum((y * y) if w is None else w[:, None] * y * y)


def fairing_energy(V0, F, options: FairOptions | None = None):
    """``E(p) -> scalar`` of ``options.method`` about the input ``V0`` (see the module notes).

    Parameters
    ----------
    V0 : (n, d) the input vertices (NumPy or JAX; the operators are built from them).
    F : (m, 3) triangles or (m, 2) edges.
    options : :class:`~geomopt.fairing.FairOptions`; its method one of ``laplacian``, ``implicit``,
        ``least_squares``, ``energy``, ``tangential``.
    """
    from .._runtime.errors import ParameterError

    o = (options or FairOptions(method="energy")).resolved()
    topo = Topology.of(np.asarray(F, dtype=np.int64), len(V0))
    xp, h = xp_of(V0), mean_edge_length(V0, topo)
    build = {"laplacian": _dirichlet, "implicit": _implicit, "least_squares": _least_squares,
             "energy": _bilaplacian, "tangential": _tangential}.get(o.method)
    if build is None:
        raise ParameterError(f"fairing_energy: {o.method!r} has no energy of its own here; use one of "
                             f"laplacian, implicit, least_squares, energy, tangential")
    return build(xp, V0, topo, o, h)


def _dirichlet(xp, V0, topo, o, h):
    L = Sparse.laplacian(topo, edge_weights(V0, topo, o.laplacian))
    return lambda p: -0.5 * xp.sum(p * L.matvec(p))


def _implicit(xp, V0, topo, o, h):
    L = Sparse.laplacian(topo, edge_weights(V0, topo, o.laplacian))
    m, dt = masses(V0, topo), o.time * h * h
    return lambda p: 0.5 * xp.sum(m[:, None] * (p - V0) ** 2) - 0.5 * dt * xp.sum(p * L.matvec(p))


def _least_squares(xp, V0, topo, o, h):
    if o.laplacian == "uniform":
        A, _ = normalized_laplacian(V0, topo, "uniform")
    else:
        A = Product(Diag(h * h / masses(V0, topo)), Sparse.laplacian(topo, edge_weights(V0, topo, "cotangent")))
    feature = crease_vertices(V0, topo, o.crease_angle) if o.crease_angle is not None else np.zeros(topo.n, bool)
    wl = xp.asarray(np.where(feature, 1.0 / o.feature_weight, 1.0) ** 2)
    wp = xp.asarray(np.where(feature, o.feature_weight, 1.0) ** 2) * o.weight
    return lambda p: 0.5 * (_sq(xp, A, p, wl) + xp.sum(wp[:, None] * (p - V0) ** 2))


def _bilaplacian(xp, V0, topo, o, h):
    L = Sparse.laplacian(topo, edge_weights(V0, topo, o.laplacian))
    m = masses(V0, topo)
    w = o.weight / h ** 4
    return lambda p: 0.5 * (_sq(xp, L, p, 1.0 / m) + w * xp.sum(m[:, None] * (p - V0) ** 2))


def _tangential(xp, V0, topo, o, h):
    Au, _ = normalized_laplacian(V0, topo, "uniform")
    Ac, _ = normalized_laplacian(V0, topo, "cotangent")
    delta = Ac.matvec(V0)
    return lambda p: 0.5 * (xp.sum((Au.matvec(p) - delta) ** 2) + o.weight * xp.sum((p - V0) ** 2))

"""The eps schedule of untangling (Garanzha et al. 2021, section 4): the first eps
(:func:`start_eps`) and the next one after each inner solve (:func:`next_eps`)."""

from __future__ import annotations

import math

import numpy as np

from ..mesh.geometry import det, edge_rows
from ..mesh.problem import Problem

__all__ = ["EPS_FLOOR", "START_RATIO", "final_eps", "next_eps", "start_eps"]


#: the smallest eps of the schedule, per dimension; also the eps of the final polish
EPS_FLOOR = {2: 1e-9, 3: 1e-10}


def final_eps(dim: int) -> float:
    """The eps of untangling's final polish (:class:`~geomopt.untangling.EpsContinuation`): the
    floor, a constant, so that the returned map is the minimiser of one energy whose
    parameters do not depend on the inputs (at ``|det J| >> eps`` it is Garanzha et al.'s
    ``f_0`` to rounding)."""
    return EPS_FLOOR.get(dim, 1e-10)


#: the largest median ``|det J| / eps`` of the start's elements at the first eps (:func:`start_eps`)
START_RATIO = 10.0


def _chi_scalar(D: float, eps: float) -> float:
    """``geomopt.energies.chi`` for Python floats (cancellation-free for ``D <= 0``)."""
    r = math.sqrt(eps * eps + D * D)
    return 0.5 * (D + r) if D > 0 else eps * eps / (2.0 * (r - D))


def next_eps(eps: float, E: float, E_prev: float, detmin: float, min_sigma: float = 0.5,
             max_sigma: float = 0.5, floor: float = 1e-10) -> float:
    """The eps of the next outer iteration (Garanzha et al. 2021, section 4).

    ``sigma = max(1 - E/E_prev, min_sigma)``, capped at ``max_sigma`` while some element is
    inverted (``detmin <= 0``); ``mu = (1 - sigma) chi(detmin, eps)``; the new eps solves
    ``chi(detmin, eps_new) = mu`` when ``detmin < mu``, else it is ``floor``.  Once nothing is
    inverted the paper's rule applies uncapped: an inner solve that lowered the energy a lot
    (``sigma`` near 1) sends eps to the floor in one step, where the cap took several halvings.

    Parameters
    ----------
    eps : the eps of the inner solve just finished;  E, E_prev : the energy after and before it.
    detmin : the smallest det J after it.
    """
    sigma = max(1.0 - E / E_prev, min_sigma)
    if detmin <= 0:
        sigma = min(sigma, max_sigma)
    mu = (1.0 - sigma) * _chi_scalar(detmin, eps)
    return max(floor, 2.0 * math.sqrt(mu * (mu - detmin))) if detmin < mu else floor


def start_eps(problem: Problem, x) -> float:
    """The initial eps of :func:`~geomopt.untangling.untangle` when ``eps0`` is None: ``max(1, median |det J| /``
    :data:`START_RATIO` ``)`` over ``problem``'s elements (the active ones of the normalised
    problem) at the normalised start ``x`` (n, d); on the host, once.

    The normalisation makes the mean ``det J`` 1, and the paper's eps = 1 suits starts whose
    typical element has ``|det J|`` within :data:`START_RATIO` of 1 (every locally tangled
    family: rotations and squashed boundaries have a median of 1-2, noise of two edge lengths
    6.4).  When the typical element is far larger (interior vertices scattered over the
    domain: determinants of both signs that cancel in the mean, ``|det J|`` growing with the
    mesh), eps = 1 leaves nearly every element deep in the stiff regime ``|det J| >> eps`` of
    ``chi`` and the first inner solve takes iterations that grow with the mesh, or stalls (see
    the module notes).  This eps keeps the typical element's ``|det J| / eps`` at
    :data:`START_RATIO` whatever the mesh size; the eps schedule shrinks it from there."""
    if not len(problem.simplices):
        return 1.0
    D = det(edge_rows(problem.simplices, np.asarray(x, np.float64))) * det(problem.rest_inv)
    m = float(np.median(np.abs(D)))
    return max(1.0, m / START_RATIO) if math.isfinite(m) else 1.0

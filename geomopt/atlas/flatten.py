"""Flatten the charts of a seam graph, and cut more where the flattening is still too distorted.

Each chart is flattened by :func:`geomopt.parameterize` (free boundary, flip-free).  When that
map is flip-free but its boundary overlaps itself, the chart is cut between the overlapping
sheets (:func:`~geomopt.atlas.split.separate_overlaps`) unless the bijective scaffold keeps the
sheets apart at little cost (its mean symmetric Dirichlet at most the goal's or the free map's):
the pieces keep their nearly isometric coordinates, where the scaffold may squeeze a large chart
with many seams to tens or thousands of times the distortion, or not converge.  The cone cuts are chosen by a
conformal estimate (:mod:`geomopt.atlas.cones`) that runs above what the flattening reaches;
:func:`flatten_to` measures the real mean symmetric Dirichlet, and while it is above the goal it
lowers the estimate's target by the measured gap and cuts again, re-flattening only the charts
that changed.
"""

from __future__ import annotations

import numpy as np

from .charts import split_charts
from .cutting import relieve
from .metrics import face_symmetric_dirichlet
from .split import separate_overlaps

__all__ = ["flatten_chart", "flatten_to"]


def flatten_chart(Vc, Fc, energy, solver, energy_params, free=None, scaffold=True):
    """A chart's flip-free flattening (:class:`~geomopt.solvers.Result`, ``x`` (nc, 2)): free
    boundary (``free``, when that solve was made already), then, with ``scaffold``, the
    bijective scaffold when the boundary overlapped itself or the map is not certified."""
    from ..param import ParamOptions, parameterize

    res = free if free is not None else parameterize(Vc, Fc, energy=(energy, energy_params), solver=solver,
                                                     progress=False)
    if (res.success and res.injectivity == "global") or not scaffold:
        return res
    again = parameterize(Vc, Fc, energy=(energy, energy_params), solver=solver, progress=False,
                         options=ParamOptions(bijective=True))
    return again if again.success or not res.success else res


def _areas(V, F):
    P = V[F]
    return 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)


def _mean_sd(Vc, Fc, x):
    A = _areas(Vc, Fc)
    return float(np.sum(A * face_symmetric_dirichlet(Vc, Fc, x, Fc)) / A.sum()), float(A.sum())


def _separate(g, cut, mesh, res, known):
    """Cut the chart ``mesh`` of ``cut`` whose free flattening ``res`` is flip-free but overlaps
    itself into injective pieces (:func:`~geomopt.atlas.split.separate_overlaps`): returns the
    seam graph with the new cuts and records each piece in ``known`` (its own coordinates and
    exact certificate); None when no such cut exists."""
    import dataclasses

    pieces = separate_overlaps(mesh, res.x, g.V)
    if pieces is None:
        return None
    label = np.full(len(g.F), -1)
    for k, (piece, _, _) in enumerate(pieces):
        label[piece.faces] = k
    f1, f2 = g.edge_faces[:, 0], np.maximum(g.edge_faces[:, 1], 0)
    new = ~g.boundary & (label[f1] >= 0) & (label[f1] != label[f2])
    cut = cut | new
    split = split_charts(g.F, g.edge_of, g.edge_faces, cut)
    for piece, x, cert in pieces:
        mesh = split.mesh(int(split.chart[piece.faces[0]]))  # same faces, in the same order
        xs = np.empty((len(mesh.wedges), 2))
        xs[mesh.F.ravel()] = x[piece.F.ravel()]
        own = dataclasses.replace(res, x=xs, certificate=cert, problem=None)  # its part of the solve
        known[(int(mesh.faces[0]), len(mesh.wedges))] = (own,) + _mean_sd(g.V[mesh.vertices], mesh.F, xs)
    return cut


def _flatten_all(g, cut, solve, known, say, goal):
    """``(cut, split, meshes, results, sd, area)`` of every chart of ``cut``, reusing the
    results in ``known`` (keyed by the chart's first face and vertex count) of unchanged charts.
    A chart whose free flattening overlaps itself gets the bijective scaffold; when that does not
    converge or ends above both ``goal`` and the free map's mean symmetric Dirichlet, the chart
    is cut instead (:func:`_separate`), so ``cut`` may grow."""
    split = split_charts(g.F, g.edge_of, g.edge_faces, cut)
    meshes, results, sd, area = [], [], [], []
    for c in range(split.count):
        mesh = split.mesh(c)
        key = (int(mesh.faces[0]), len(mesh.wedges))
        if key not in known:
            Vc = g.V[mesh.vertices]
            free = solve(Vc, mesh.F, scaffold=False)
            res = solve(Vc, mesh.F, free=free)
            known[key] = (res,) + _mean_sd(Vc, mesh.F, res.x)
            if res is not free and free.success and free.injectivity == "local" and not (
                    res.success and known[key][1] <= max(goal, _mean_sd(Vc, mesh.F, free.x)[0])):
                more = _separate(g, cut, mesh, free, known)
                if more is not None:
                    say(f"chart {c}", faces=len(mesh.F), scaffold_mean_symmetric_dirichlet=known[key][1],
                        separated=int(more.sum() - cut.sum()))
                    return _flatten_all(g, more, solve, known, say, goal)
            say(f"chart {c}", faces=len(mesh.F), mean_symmetric_dirichlet=known[key][1],
                injectivity=res.injectivity)
        meshes.append(mesh)
        results.append(known[key][0])
        sd.append(known[key][1])
        area.append(known[key][2])
    return cut, split, meshes, results, np.array(sd), np.array(area)


def flatten_to(g, cost, cut, estimate, goal, solve, max_cuts, say, rounds=3):
    """Flatten the charts of ``cut`` and, while their area-weighted mean symmetric Dirichlet is
    above ``goal``, cut more (:func:`~geomopt.atlas.cutting.relieve`) and flatten again.

    Parameters
    ----------
    g : EdgeGraph
        The surface's :class:`~geomopt.atlas.seams.EdgeGraph`.
    cost : (k,) float
        Its edge costs.
    cut : (k,) bool
        The seam graph, whose charts' conformal estimate is ``estimate``.
    estimate : float
        That estimate.
    goal : float
        The area-weighted mean symmetric Dirichlet to reach.
    solve : callable
        ``(Vc, Fc, free=None, scaffold=True) -> Result``, one chart's flattening
        (:func:`flatten_chart`'s last two arguments).
    max_cuts : int
        The most further cone cuts.
    say : callable
        ``(stage, **info)`` progress.
    rounds : int
        The most re-cutting rounds.

    Returns
    -------
    ``(cut, split, meshes, results)``: the final seam graph, its
    :class:`~geomopt.atlas.charts.ChartSplit`, chart meshes and flattenings.
    """
    known = {}
    for _ in range(rounds + 1):
        cut, split, meshes, results, sd, area = _flatten_all(g, cut, solve, known, say, goal)
        measured = float(np.sum(sd * area) / area.sum())
        say("flattened", charts=split.count, mean_symmetric_dirichlet=measured, estimate=estimate)
        if measured <= goal or max_cuts <= 0 or _ == rounds:
            break
        # the estimate runs above the flattening by about the measured gap: aim it that much lower
        target = max(4.0 + 1e-3, goal + (estimate - measured))
        cut, estimate, made = relieve(g, cost, cut, target, max_cuts)
        max_cuts -= made
        if made == 0:
            break
    return cut, split, meshes, results

"""Flatten the charts of a seam graph, and cut more where the flattening is still too distorted.

Each chart is flattened by :func:`geomopt.parameterize` (free boundary, flip-free).  When that
map is flip-free but its boundary overlaps itself, the chart is cut between the overlapping
sheets (:func:`~geomopt.atlas.flat_splits.separate_overlaps`) unless the bijective scaffold keeps the
sheets apart at little cost (its mean symmetric Dirichlet at most the goal's or the free map's):
the pieces keep their nearly isometric coordinates, where the scaffold may squeeze a large chart
with many seams to tens or thousands of times the distortion, or not converge.  The cone cuts are chosen by a
conformal estimate (:mod:`geomopt.atlas.cones`) that runs above what the flattening reaches;
:func:`flatten_to` measures the real mean symmetric Dirichlet, and while it is above the goal it
lowers the estimate's target by the measured gap and cuts again, re-flattening only the charts
that changed.  Where the cone cuts stall above the goal (a coarse or strongly curved surface,
whose curvature is spread over many vertices rather than held by a few cones),
:func:`split_to_goal` splits charts into nearly developable pieces instead
(:mod:`geomopt.atlas.regions`), measured split by split, the most distortion bought per seam first.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._runtime.errors import MaxStepsWarning, MeshError
from ..solvers import Outcome
from ..mesh.quality import triangle_areas
from .charts import charts_of_cut
from .cutting import relieve
from .metrics import face_symmetric_dirichlet
from .regions import normal_regions
from .seams import straighten
from .flat_splits import separate_overlaps

__all__ = ["flatten_chart", "flatten_to", "split_to_goal"]

# a split of a chart into nearly developable pieces, or a round of cone cuts, must lower the
# measured mean symmetric Dirichlet by this much per unit of seam it adds (in units of the
# square root of the area)
_SPLIT_WORTH = 0.06
_SPLIT_REGIONS = (2, 3, 4)  # the numbers of pieces tried
_SPLIT_OFFERS = 4  # charts (of most excess) whose splits are tried per split made
_SPLIT_SEEDS = (True, False)  # each with seeds centred in their regions, and not (normal_regions)
# a free flattening that ended so is at a minimum of the free problem (a certificate may still fail)
_AT_REST = (Outcome.CONVERGED, Outcome.NOT_INJECTIVE)


def flatten_chart(Vc, Fc, energy, solver, energy_params, free=None, scaffold=True):
    """A chart's flip-free flattening (:class:`~geomopt.solvers.Result`, ``x`` (nc, 2)): free
    boundary (``free``, when that solve was made already), then, with ``scaffold``, the
    bijective scaffold when the boundary overlapped itself or the map is not certified.  Each
    solve starts from the first of :data:`_STARTS` whose start map has no inverted triangle."""
    from ..param import ParamOptions, parameterize

    def solve(weights, x0, bijective=False):
        # a chart's solve that stops at its limit is judged here (scaffold, cut, split or the
        # atlas's own message), so its MaxStepsWarning would only alarm beside a certified atlas
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MaxStepsWarning)
            return parameterize(Vc, Fc, energy=(energy, energy_params), solver=solver, progress=False, x0=x0,
                                options=ParamOptions(weights=weights, bijective=bijective))

    res = free if free is not None else _started(solve)
    if (res.success and res.injectivity == "global") or not scaffold:
        return res
    try:
        again = _started(lambda weights, x0: solve(weights, x0, bijective=True))
    except MeshError:  # no start map for the scaffold: the free map is what there is
        return res
    return again if again.success or not res.success else res


#: start maps tried in turn, ``(Tutte weights, x0)``: uniform Tutte; mean-value Tutte where
#: rounding inverts the uniform one's crowded triangles (a long chart of slivers: a cylinder cut
#: along one side); the projection to the chart's plane, its folds repaired
_STARTS = (("uniform", None), ("mean_value", None), ("uniform", "projection"))


def _started(solve):
    """``solve(weights, x0)`` from the first start map of :data:`_STARTS` that it accepts; the
    first one's MeshError when it accepts none."""
    first = None
    for weights, x0 in _STARTS:
        try:
            return solve(weights, x0)
        except MeshError as exc:
            first = first or exc
    raise first


def _key(mesh):
    """A chart's key in the caches of flattenings: its faces and their local vertex ids (the
    gluing inside it); alternative splits of one chart may give pieces with the same first face
    and vertex count."""
    return mesh.faces.tobytes(), mesh.F.tobytes()


def _mean_sd(Vc, Fc, x):
    A = triangle_areas(Vc[Fc])
    return float(np.sum(A * face_symmetric_dirichlet(Vc, Fc, x, Fc)) / A.sum()), float(A.sum())


def _separate(g, cut, mesh, res, known):
    """Cut the chart ``mesh`` of ``cut`` whose free flattening ``res`` is flip-free but overlaps
    itself into injective pieces (:func:`~geomopt.atlas.flat_splits.separate_overlaps`): returns the
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
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    for piece, x, cert in pieces:
        mesh = split.mesh(int(split.chart[piece.faces[0]]))  # same faces, in the same order
        xs = np.empty((len(mesh.wedges), 2))
        xs[mesh.F.ravel()] = x[piece.F.ravel()]
        own = dataclasses.replace(res, x=xs, certificate=cert, problem=None)  # its part of the solve
        known[_key(mesh)] = (own,) + _mean_sd(g.V[mesh.vertices], mesh.F, xs)
    return cut


def _free_state(g, cut, split, solve, known, frees):
    """A provisional :func:`_flatten_all` state of ``cut`` (its seventh item False): the known
    charts' results, the others' free flattenings (made now, kept in ``frees`` by key), each
    measured by its mean symmetric Dirichlet where that solve came to rest (its boundary may
    overlap), else 4 (isometric).  Its mean is one :func:`_flatten_all` cannot end below: the
    bijective scaffold only adds a constraint to a free map."""
    meshes, results, sd, area = [], [], [], []
    for c in range(split.count):
        mesh = split.mesh(c)
        key = _key(mesh)
        if key in known:
            res, s, a = known[key]
        else:
            Vc = g.V[mesh.vertices]
            if key not in frees:
                frees[key] = solve(Vc, mesh.F, scaffold=False)
            res = frees[key]
            s, a = _mean_sd(Vc, mesh.F, res.x)
            s = s if res.outcome in _AT_REST and np.isfinite(s) else 4.0
        meshes.append(mesh)
        results.append(res)
        sd.append(s)
        area.append(a)
    return cut, split, meshes, results, np.array(sd), np.array(area), False


def _flatten_all(g, cut, solve, known, say, goal, ceiling=None, frees=None):
    """``(cut, split, meshes, results, sd, area, True)`` of every chart of ``cut``, reusing the
    results in ``known`` (keyed by :func:`_key`) of unchanged charts.
    A chart whose free flattening overlaps itself gets the bijective scaffold; when that does not
    converge or ends above both ``goal`` and the free map's mean symmetric Dirichlet, the chart
    is cut instead (:func:`_separate`), so ``cut`` may grow.  With a ``ceiling``: when the free
    flattenings already put the mean above it, the provisional state of :func:`_free_state`,
    without any scaffold solve."""
    split = charts_of_cut(g.F, g.edge_of, g.edge_faces, cut)
    frees = {} if frees is None else frees
    if ceiling is not None:
        free = _free_state(g, cut, split, solve, known, frees)
        if _mean(free) > ceiling:
            return free
    meshes, results, sd, area = [], [], [], []
    for c in range(split.count):
        mesh = split.mesh(c)
        key = _key(mesh)
        if key not in known:
            Vc = g.V[mesh.vertices]
            free = frees.pop(key) if key in frees else solve(Vc, mesh.F, scaffold=False)
            res = solve(Vc, mesh.F, free=free)
            known[key] = (res,) + _mean_sd(Vc, mesh.F, res.x)
            if res is not free and free.success and free.injectivity == "local" and not (
                    res.success and known[key][1] <= max(goal, _mean_sd(Vc, mesh.F, free.x)[0])):
                more = _separate(g, cut, mesh, free, known)
                if more is not None:
                    say(f"chart {c}", faces=len(mesh.F), scaffold_mean_symmetric_dirichlet=known[key][1],
                        separated=int(more.sum() - cut.sum()))
                    return _flatten_all(g, more, solve, known, say, goal, frees=frees)
            say(f"chart {c}", faces=len(mesh.F), mean_symmetric_dirichlet=known[key][1],
                injectivity=res.injectivity)
        meshes.append(mesh)
        results.append(known[key][0])
        sd.append(known[key][1])
        area.append(known[key][2])
    return cut, split, meshes, results, np.array(sd), np.array(area), True


def flatten_to(g, cost, cut, estimate, goal, solve, max_cuts, say, rounds=3, turn=0.0):
    """Flatten the charts of ``cut`` and, while their area-weighted mean symmetric Dirichlet is
    above ``goal``, cut more (:func:`~geomopt.atlas.cutting.relieve`) and flatten again.  A
    round of cuts that lowers the measured mean by less than ``_SPLIT_WORTH`` per unit of seam
    it adds is taken back; when the mean is still above the goal, the charts are split instead
    (:func:`split_to_goal`).  A round that is cut again whose free flattenings are above the goal
    already is measured by them (progress ``free=True``): its bijective scaffolds, which could only
    end higher, are not solved.

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
    turn : float
        At the end the seams are straightened (:func:`~geomopt.atlas.seams.straighten` with this
        price of turning; 0: not) and the charts that changed flattened again; kept when no
        more charts fail and the mean stays at most the goal or, above it, does not rise.

    Returns
    -------
    ``(cut, split, meshes, results)``: the final seam graph, its
    :class:`~geomopt.atlas.charts.ChartSplit`, chart meshes and flattenings.
    """
    known, frees, last = {}, {}, None
    for _ in range(rounds + 1):
        final = max_cuts <= 0 or _ == rounds
        # a round whose free flattenings are above the goal is cut again: its scaffolds not solved
        state = _flatten_all(g, cut, solve, known, say, goal, ceiling=None if final else goal, frees=frees)
        frees = {key: frees[key] for key in map(_key, state[2]) if key in frees}  # the charts cut since: gone
        say("flattened", charts=state[1].count, mean_symmetric_dirichlet=_mean(state), estimate=estimate,
            **({} if state[6] else {"free": True}))
        if last is not None and _rate(g, last, state) < _SPLIT_WORTH:
            state = last  # the round's cuts did not pay for their seam: split instead
            say("cuts taken back", charts=state[1].count, mean_symmetric_dirichlet=_mean(state))
            break
        if _mean(state) <= goal or final:
            break
        # the estimate runs above the flattening by about the measured gap: aim it that much lower
        target = max(4.0 + 1e-3, goal + (estimate - _mean(state)))
        last = state
        cut, estimate, made = relieve(g, cost, state[0], target, max_cuts)
        max_cuts -= made
        if made == 0:
            break
    if _mean(state) > goal:
        cut = split_to_goal(g, state[0], solve, say, goal, known)[0]
        state = _flatten_all(g, cut, solve, known, say, goal)  # every chart known: nothing solved
    return _straightened(g, cost, state, turn, solve, known, say, goal)[:4]


def _straightened(g, cost, state, turn, solve, known, say, goal):
    """``state`` (:func:`_flatten_all`'s tuple) with its seams straightened (see
    :func:`flatten_to`), or ``state`` itself."""
    if turn <= 0:
        return state
    cut = straighten(g, cost, state[0], turn)
    if np.array_equal(cut, state[0]):
        return state
    ceiling = max(goal, _mean(state))
    trial = _flatten_all(g, cut, solve, known, say, goal, ceiling=ceiling)  # provisional: above the ceiling
    if _failed(trial) <= _failed(state) and _mean(trial) <= ceiling:
        say("straightened", charts=trial[1].count, mean_symmetric_dirichlet=_mean(trial))
        return trial
    return state


def _region_cuts(g, cut, mesh):
    """``cut`` with the borders of :func:`~geomopt.atlas.regions.normal_regions` of the chart
    ``mesh``, for each number of pieces in ``_SPLIT_REGIONS`` and seeding in ``_SPLIT_SEEDS``
    that gives disks (distinct splits only)."""
    import itertools

    out, seen = [], set()
    f1, f2 = g.edge_faces[:, 0], np.maximum(g.edge_faces[:, 1], 0)
    for k, centred in itertools.product(_SPLIT_REGIONS, _SPLIT_SEEDS):
        piece = normal_regions(g.V[mesh.vertices], mesh.F, k, centred=centred)
        if piece is None or piece.tobytes() in seen:
            continue
        seen.add(piece.tobytes())
        label = np.full(len(g.F), -1)
        label[mesh.faces] = piece
        new = ~g.boundary & (label[f1] >= 0) & (label[f1] != label[f2])
        if (new & ~cut).any():
            out.append(cut | new)
    return out


def _mean(state):
    return float(np.sum(state[4] * state[5]) / state[5].sum())


def _rate(g, before, after):
    """How much ``after`` (:func:`_flatten_all`'s tuple) lowered the measured mean symmetric
    Dirichlet of ``before`` per unit of seam it added (seam over the square root of the area)."""
    added = float(g.length[after[0]].sum() - g.length[before[0]].sum()) / np.sqrt(before[5].sum())
    return (_mean(before) - _mean(after)) / max(added, 1e-12)


def _failed(state):
    return sum(not r.success for r in state[3])


def _best_region_split(g, state, c, solve, known, goal):
    """``(rate, new_edges)``: the split of chart ``c`` of ``state`` (:func:`_flatten_all`'s
    tuple) by :func:`_region_cuts` that lowers the measured mean symmetric Dirichlet most per
    unit of seam it adds (seam over the square root of the surface's area), or None; a split
    with a piece not flattened flip-free is never taken."""
    best = None
    for more in _region_cuts(g, state[0], state[2][c]):
        trial = _flatten_all(g, more, solve, known, lambda *a, **k: None, goal)
        rate = _rate(g, state, trial)
        if _failed(trial) > _failed(state):
            continue  # a piece did not flatten flip-free
        if best is None or rate > best[0]:
            best = (rate, trial[0] & ~state[0])
    return best


def _best_offer(g, state, offers, solve, known, goal, worth):
    """The best split ``(rate, new_edges)`` offered for the charts of ``state`` (None when
    none): the charts above the goal are offered their best split (:func:`_best_region_split`,
    cached in ``offers`` by chart key), ``_SPLIT_OFFERS`` at a time in order of excess
    (symmetric Dirichlet above the goal times area), until one is worth making or all were."""
    keys = [_key(m) for m in state[2]]
    excess = (state[4] - goal) * state[5]
    waiting = [int(c) for c in np.argsort(-excess) if keys[c] not in offers and excess[c] > 0]
    while True:
        live = [offers[k] for k in keys if offers.get(k) is not None]
        best = max(live, key=lambda offer: offer[0]) if live else None
        if (best is not None and best[0] >= worth) or not waiting:
            return best
        for c in waiting[:_SPLIT_OFFERS]:
            offers[keys[c]] = _best_region_split(g, state, c, solve, known, goal)
        waiting = waiting[_SPLIT_OFFERS:]


def split_to_goal(g, cut, solve, say, goal, known=None, max_splits=32, worth=_SPLIT_WORTH):
    """Flatten the charts of ``cut`` and, while their area-weighted mean symmetric Dirichlet is
    above ``goal``, split charts into nearly developable pieces
    (:func:`~geomopt.atlas.regions.normal_regions`), the split that buys the most: of the best
    splits of the charts above the goal (:func:`_best_offer`, each candidate flattened and
    measured), the one that lowers the measured mean most per unit of seam it adds is made,
    while that rate is at least ``worth`` (per unit of seam length over the square root of the
    surface's area).  A chart's pieces may be split again.  Returns ``(cut, split, meshes,
    results)`` as :func:`flatten_to`."""
    known = {} if known is None else known
    state = _flatten_all(g, cut, solve, known, say, goal)
    offers = {}  # chart key -> its best split (rate, new edges) or None
    for _ in range(max_splits):
        if _mean(state) <= goal:
            break
        best = _best_offer(g, state, offers, solve, known, goal, worth)
        if best is None or best[0] < worth:
            break
        state = _flatten_all(g, state[0] | best[1], solve, known, say, goal)
        say("split", charts=state[1].count, rate=float(best[0]), mean_symmetric_dirichlet=_mean(state))
    return state[:4]

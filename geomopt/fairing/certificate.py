"""The fold certificate of a smoothed surface or curve, and the step that keeps it.

A face is *folded* when it is not positively oriented against the vertex normal at one of its
corners (:func:`geomopt.exact.normals.corner_signs`: exact signs of ``n_f . N_v``, ``N_v`` the
area-weighted mean of the normals around ``v``, taken on the vertices being certified).  The
same for the edges of a polyline with length-weighted vertex tangents.

:func:`safe_step` moves from a start ``X0`` towards a target ``X1`` as far as it can without a
corner failing that did not fail at ``X0``, and (surfaces) without a face's normal turning 90
degrees or more from its normal at ``X0`` (:func:`geomopt.exact.normals.normal_agreement`; faces
folded or degenerate at ``X0`` may turn, so that folds can be undone): each vertex ``i`` goes to ``X0_i + t_i (X1_i - X0_i)``,
every ``t_i = 1`` first; where a corner fails, the ``t`` of the vertices its sign depends on (the
face and the star of the corner's vertex) is halved, down to 0 after :data:`HALVINGS` halvings,
and the signs are taken again.  Per-vertex fractions, rather than one for the whole step (the
injective line search of maps), keep one bad spot from freezing the whole surface.  It ends,
because ``t = 0`` everywhere is ``X0``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..exact.topology import ranges
from ..exact.normals import corner_signs, normal_agreement, signs_and_agreement
from ..exact.predicates import normal_signs
from .operators import any_column

__all__ = ["FoldCertificate", "Stars", "certify_folds", "describe_folds", "recertified", "safe_step", "local_signs",
           "signs_near", "HALVINGS"]

#: halvings of a vertex's step fraction before it is set to 0 (its start position)
HALVINGS = 20


@dataclasses.dataclass(frozen=True)
class FoldCertificate:
    """Exact fold check of smoothed vertices (see the module notes).

    Attributes
    ----------
    folded : (k,) int64, the faces (edges of a curve) with a corner not positive, sorted.
    corners : (c, 2) int64, the (element, corner) pairs not positive.
    elements : the element count.
    """

    folded: np.ndarray
    corners: np.ndarray
    elements: int

    @property
    def inverted(self) -> int:
        """Folded faces (the name every certificate of a :class:`~geomopt.solvers.Result` has)."""
        return int(len(self.folded))

    @property
    def ok(self) -> bool:
        return len(self.folded) == 0

    @property
    def locally_injective(self) -> bool:
        """No folded face (each positive against its corners' vertex normals)."""
        return self.ok

    @property
    def globally_injective(self) -> bool:
        """Not certified (self-intersections of distant parts are not checked)."""
        return False

    @property
    def injectivity(self) -> str:
        return "local" if self.ok else "none"

    @property
    def message(self) -> str:
        return ("no folded face (exact)" if self.ok else
                f"{self.inverted} of {self.elements} faces folded against their vertex normals (exact)")


def certify_folds(X, S) -> FoldCertificate:
    """The :class:`FoldCertificate` of vertices ``X`` (n, d) with elements ``S`` (m, 3) or (m, 2)."""
    return _from_signs(corner_signs(X, S) <= 0, len(S))


def describe_folds(X, S, cert: FoldCertificate) -> str:
    """``cert.message`` (the :class:`FoldCertificate` of ``X`` (n, d), ``S``) with its folded
    elements told apart by their exact signs: *reversed* (a corner's sign negative), *degenerate*
    (a zero-area triangle or zero-length edge: every sign zero) and *perpendicular* (no sign
    negative, one zero: the element lies along the vertex normal at a corner, as each face of a
    right-angled tetrahedron does at the corners of its slanted face).  The last two count as
    folds by the certificate's definition (each corner strictly positive), though nothing is
    turned over."""
    if cert.ok:
        return cert.message
    X, S = np.asarray(X, dtype=np.float64), np.asarray(S, dtype=np.int64)
    signs = corner_signs(X, S)[cert.folded]
    if S.shape[1] == 3:
        a, b, c = (X[S[cert.folded, k]] for k in range(3))
        flat = ~normal_signs(a, b, c).any(axis=1)
    else:
        flat = (X[S[cert.folded, 0]] == X[S[cert.folded, 1]]).all(axis=1)
    reversed_ = (signs < 0).any(axis=1) & ~flat
    kinds = [(int(reversed_.sum()), "reversed at a corner"), (int(flat.sum()), "degenerate (zero area)"),
             (int((~reversed_ & ~flat).sum()), "perpendicular to the vertex normal at a corner (zero sign: "
              "nothing turned over, but not positively oriented, e.g. a right-angled tetrahedron's faces)")]
    return f"{cert.message}: " + ", ".join(f"{n} {what}" for n, what in kinds if n)


def _from_signs(neg, m) -> FoldCertificate:
    """The :class:`FoldCertificate` of the corners ``neg`` (m, k) bool not positive."""
    corners = np.argwhere(neg)
    return FoldCertificate(np.unique(corners[:, 0]), corners, m)


class Stars:
    """The elements around each vertex of the elements ``S`` (m, k) on ``n`` vertices, for the
    checks after a local change to gather only the elements near it instead of whole-mesh
    arrays: the vertex-element incidence in CSR form, built in linear time on the first
    :meth:`around` (so that a caller may make one to share before knowing it is needed)."""

    def __init__(self, S, n):
        self.S, self.n, self._csr = S, n, None

    def around(self, vertices) -> np.ndarray:
        """(e,) the sorted elements with a corner among ``vertices`` (p,) int."""
        if self._csr is None:
            import scipy.sparse as sp

            m, k = self.S.shape
            incidence = sp.csr_matrix((np.ones(m * k, bool), (self.S.ravel(), np.repeat(np.arange(m), k))),
                                      shape=(self.n, m))
            self._csr = incidence.indptr, incidence.indices  # (each row ascending: S is read in order)
        start, elements = self._csr
        return np.unique(elements[ranges(start, vertices)])


def recertified(X, S, base: FoldCertificate, X_base, stars: Stars | None = None) -> FoldCertificate:
    """``certify_folds(X, S)``, given ``base = certify_folds(X_base, S)``: the same certificate
    (exact signs), taken again only at the corners within one ring of a vertex where ``X``
    (n, d) differs from ``X_base`` (the others' signs cannot differ); ``base`` itself where no
    vertex differs.  ``stars``: the :class:`Stars` of ``S`` when the caller has them."""
    X, X_base = np.asarray(X, dtype=np.float64), np.asarray(X_base, dtype=np.float64)
    moved = np.flatnonzero(any_column(X != X_base))
    if len(moved) == 0:
        return base
    neg = np.zeros(S.shape, bool)
    neg[base.corners[:, 0], base.corners[:, 1]] = True
    _retaken(X, X_base, S, moved, neg, None, stars or Stars(S, len(X)))
    return _from_signs(neg, len(S))


def local_signs(X, S) -> np.ndarray:
    """``corner_signs(X, S)`` (m, k), the same exact signs, reading only the vertices that the
    elements ``S`` use: where they are few (the elements around a change), the other vertices'
    coordinates are not copied, scaled and checked at every call."""
    X = np.asarray(X)
    if 2 * S.size > len(X):
        return corner_signs(X, S)
    used, inverse = np.unique(S, return_inverse=True)
    return corner_signs(X[used], inverse.reshape(S.shape))


def _local_agreement(X, Y, F):
    """``normal_agreement(X, Y, F)`` reading only the vertices that ``F`` uses (as :func:`local_signs`)."""
    if 2 * F.size > len(X):
        return normal_agreement(X, Y, F)
    used, inverse = np.unique(F, return_inverse=True)
    return normal_agreement(X[used], Y[used], inverse.reshape(F.shape))


def _dependents(S, corners, stars):
    """(p,) the vertices, sorted, whose position enters the signs at ``corners`` (c, 2): the
    element's and those of every element around the corner's vertex."""
    star = np.union1d(stars.around(np.unique(S[corners[:, 0], corners[:, 1]])), corners[:, 0])
    return np.unique(S[star])


def signs_near(X, S, moved, stars: Stars):
    """``(affected, neg)``: the elements (e,), sorted, whose corner signs a move of the vertices
    ``moved`` (p,) int can change (those with a corner within one ring of one: its vertex normal
    sums the elements around it), and their corners not positive at ``X`` (e, k) bool (exact,
    :func:`certify_folds`' signs, read from the elements around those corners only)."""
    affected = stars.around(np.unique(S[stars.around(moved)]))
    sub = stars.around(np.unique(S[affected]))  # every element around a corner of an affected one
    return affected, local_signs(X, S[sub])[np.searchsorted(sub, affected)] <= 0


def _retaken(X, X0, S, moved, neg, turned, stars):
    """The elements (sorted) whose signs ``moved`` (p,) int vertices can change
    (:func:`signs_near`), and, there, ``neg`` (m, k) the corners not positive at ``X`` and
    (surfaces; else None) ``turned`` (m,) the faces turned 90 degrees or more from ``X0``, taken
    again (in place)."""
    affected, negative = signs_near(X, S, moved, stars)
    neg[affected] = negative
    if turned is not None:
        turned[affected] = _local_agreement(X, X0, S[affected]) <= 0
    return affected


def safe_step(X0, X1, S, free, halvings=HALVINGS, start: FoldCertificate | None = None, certify: bool = False,
              stars: Stars | None = None):
    """``(X, t)``: the vertices reached from ``X0`` towards ``X1`` (n, d) with no corner failing
    that did not fail at ``X0``, and the fractions ``t`` (n,) taken (0 on vertices not ``free``).

    ``X`` is ``X0`` where the step was cut to nothing; a corner failing at ``X0`` may fail or
    succeed at ``X`` (so folds are removed, never added); every other corner is positive there,
    and every face not folded at ``X0`` is within 90 degrees of its normal there (exact).  ``halvings``: of a vertex's fraction before it is set to 0 (1: every vertex
    moves all the way or not at all); ``start``: :func:`certify_folds` of ``X0, S`` when the caller
    has it (not taken again); ``certify``: return ``(X, t, certificate)``, the
    :class:`FoldCertificate` of ``X`` from the signs the step ended with (those of
    :func:`certify_folds`, not taken again); ``stars``: the :class:`Stars` of ``S`` when the
    caller has them.  The signs are taken on every element once, then after each cut only
    around the vertices it moved."""
    X0, X1 = np.asarray(X0, dtype=np.float64), np.asarray(X1, dtype=np.float64)
    n, surface = len(X0), S.shape[1] == 3
    if start is None:
        allowed = corner_signs(X0, S) <= 0
    else:
        allowed = np.zeros(S.shape, bool)
        allowed[start.corners[:, 0], start.corners[:, 1]] = True
    # faces with a corner failing at X0 may turn; so may degenerate ones (normal 0 or not finite
    # at X0), which are among them: their corner signs are 0
    may_turn = any_column(allowed) if surface else None
    stars = stars or Stars(S, n)
    t = np.where(free, 1.0, 0.0)
    halved = np.zeros(n, np.int64)
    X = np.where(free[:, None], X1, X0)
    if surface:
        signs, agreement = signs_and_agreement(X, X0, S)
        neg, turned = signs <= 0, agreement <= 0
    else:
        neg, turned = corner_signs(X, S) <= 0, None
    rows = np.flatnonzero(_bad(neg, allowed, turned, may_turn, slice(None)))  # the elements that may fail
    while True:
        bad = _bad(neg, allowed, turned, may_turn, rows)
        rows = rows[bad]
        if len(rows) == 0:
            return (X, t) if not certify else (X, t, _from_signs(neg, len(S)))
        failing = np.argwhere(neg[rows] & ~allowed[rows] | (turned[rows] & ~may_turn[rows])[:, None]
                              if surface else neg[rows] & ~allowed[rows])
        failing[:, 0] = rows[failing[:, 0]]
        cut = _dependents(S, failing, stars)
        cut = cut[t[cut] > 0]
        if len(cut) == 0:  # with t = 0 on all it depends on, a corner has its start's sign: positive
            raise RuntimeError("safe_step: a corner fails at the start positions (internal error)")
        halved[cut] += 1
        t[cut] = np.where(halved[cut] >= halvings, 0.0, t[cut] * 0.5)
        tc = t[cut][:, None]
        Xc = np.where(tc == 0.0, X0[cut], X0[cut] + tc * (X1[cut] - X0[cut]))
        moved = cut[any_column(Xc != X[cut])]
        X[cut] = Xc
        rows = np.union1d(rows, _retaken(X, X0, S, moved, neg, turned, stars)) if len(moved) else rows


def _bad(neg, allowed, turned, may_turn, rows):
    """(r,) bool: the elements ``rows`` with a corner failing that may not fail."""
    bad = any_column(neg[rows] & ~allowed[rows])
    if turned is not None:
        bad |= turned[rows] & ~may_turn[rows]
    return bad

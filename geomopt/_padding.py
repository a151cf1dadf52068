"""Size buckets: pad a problem's arrays so that meshes of similar size share compiled kernels.

XLA compiles one program per array shape, and the persistent compilation cache
(:mod:`geomopt._cache`) is keyed on shapes too: without padding every new mesh compiles
again.  Rounding the element count ``m``, the vertex count ``n`` and the Hessian's entry count
``nnz`` up to a few sizes per octave (:func:`bucket`: 4 per octave, at most 25% and on
average ~12% extra element work) lets a *different* mesh of the same bucket reuse them.

The padding changes no result:

* padded elements are copies of element 0 (same vertices, same inverse rest matrix) with
  rest volume 0, so they add exactly ``0`` to the energy and gradient where the energy is
  finite; their Hessian entries go to the dropped slot; to the injective line search they
  are element 0 again (same determinant, same step bound);
* padded vertices are referenced by no element and are fixed (their free mask is 0): their
  gradient is 0, no solver moves them, and they sit on vertex 0 so that map extents are
  unchanged;
* the Hessian data has ``nnz_padded`` slots of which the last ``nnz_padded - nnz`` stay 0 and
  are cut off before the factorization.

Certificates (``count_inverted``) and results only ever see the first ``n`` rows (see
:meth:`geomopt.Objective.unpad_map`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: sizes per octave (1, 1.25, 1.5, 1.75 times a power of two)
STEPS = (1.0, 1.25, 1.5, 1.75, 2.0)
#: the smallest bucket: tiny meshes all share one
MINIMUM = 64


def bucket(size: int) -> int:
    """The smallest bucket ``>= size``: ``64`` or ``2^k * {1, 1.25, 1.5, 1.75}`` (k >= 6)."""
    size = int(size)
    if size <= MINIMUM:
        return MINIMUM
    base = 2 ** int(math.floor(math.log2(size)))
    for f in STEPS:
        b = int(math.ceil(base * f))
        if b >= size:
            return b
    raise AssertionError("unreachable: 2 * base >= size")  # pragma: no cover


@dataclasses.dataclass(frozen=True)
class Sizes:
    """Real and padded sizes of one problem: vertices ``n -> n_padded`` and elements
    ``m -> m_padded``."""

    n: int
    m: int
    n_padded: int
    m_padded: int

    @classmethod
    def of(cls, problem, buckets: bool = True) -> "Sizes":
        n, m = problem.n_vertices, problem.n_elements
        return cls(n, m, bucket(n) if buckets else n, bucket(m) if buckets else m)

    @property
    def padded(self) -> bool:
        return (self.n_padded, self.m_padded) != (self.n, self.m)


def pad_geometry(problem, sizes: Sizes, volumes=None):
    """``(S, Minv, vol)`` of shapes (M, d+1), (M, d, d), (M,) for ``M = m_padded``: the
    problem's elements (``volumes`` in place of its rest volumes when given, e.g. weighted)
    followed by zero-volume copies of element 0.  NumPy, or JAX for traced arrays."""
    S, Minv = problem.simplices, problem.rest_inv
    vol = problem.volumes if volumes is None else volumes
    return (pad_rows(S, sizes.m_padded), pad_rows(Minv, sizes.m_padded),
            pad_rows(vol, sizes.m_padded, fill=0.0))


def pad_rows(a, rows: int, fill=None):
    """``a`` (k, ...) extended to ``rows`` rows with copies of row 0 (``fill=None``) or ``fill``
    (NumPy, or JAX when ``a`` is traced)."""
    xp = _xp(a)
    a = a if xp is not np else np.asarray(a)
    extra = rows - a.shape[0]
    if extra <= 0:
        return a
    tail = xp.repeat(a[:1], extra, axis=0) if fill is None else xp.full((extra,) + a.shape[1:], fill, a.dtype)
    return xp.concatenate([a, tail])


def _xp(a):
    from ._tracing import is_traced

    if is_traced(a):
        import jax.numpy as jnp

        return jnp
    return np



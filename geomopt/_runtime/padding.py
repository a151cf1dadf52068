"""Size buckets: pad a problem's arrays so that meshes of similar size share compiled kernels.

XLA compiles one program per array shape, and the persistent compilation cache
(:mod:`geomopt._runtime.cache`) is keyed on shapes too: without padding every new mesh compiles
again.  :class:`~geomopt.Objective` (``buckets=True``) rounds the element count ``m`` up to a
power of two (from :data:`MINIMUM_ELEMENTS`) and ties the vertex count to it
(:func:`bucket_sizes`): ``n`` goes to :data:`VERTEX_SHARE` times the element bucket, doubled
while the mesh has more vertices, so that a mesh family meets one (vertices, elements) bucket
per element bucket, not two or three.  Meshes above :data:`MAXIMUM_ELEMENTS` elements are not
padded: their solve, not the compilation, dominates.  The Hessian's entry and block counts
(Newton) round up to powers of two the same way.

This is the better of the two rules the project had (``benchmarks/README.md``, "Padding"):
60 generated untangling cases of 300-3,000 elements in one process lowered 23-27 programs
with powers of two and a tied vertex count, 72 with four buckets per octave for elements and
vertices independently, and took 4x longer cold (2x warm); the solves themselves were at most
a third slower with the coarser buckets.

The padding changes no result:

* padded element ``m + i`` is a copy of element ``i mod m`` (same vertices, same inverse rest
  matrix) with rest volume 0, so it adds exactly ``0`` to the energy, gradient and Hessian
  blocks where the energy is finite; to the injective line search it is that element again
  (same determinant, same step bound).  Copies of *one* element would send every padded
  element's zero gradient to the same vertices, and XLA's CPU scatter-add serialises on
  repeated indices: L-BFGS on a 12,272-triangle disk padded to 16,384 took 1.9-2.1 ms per
  iteration with copies of element 0 against 1.07 ms with spread copies (0.6-0.8 ms unpadded);
* padded vertices are referenced by no element and are fixed (their free mask is 0): their
  gradient is 0, no solver moves them, and they sit on vertex 0 so that map extents are
  unchanged;
* the Hessian data has ``nnz_padded`` slots of which the last ``nnz_padded - nnz`` stay 0 and
  are cut off before the factorization.

Only sums over all elements (the energy, dot products in a solver) may round differently, as
XLA splits a longer sum differently.  Certificates (``count_inverted``) and results only ever
see the first ``n`` rows (see :meth:`geomopt.Objective.unpad_map`); statistics over elements
must ignore those of zero rest volume.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .errors import ParameterError

#: the smallest element bucket (element buckets are MINIMUM_ELEMENTS * 2**k)
MINIMUM_ELEMENTS = 256
#: meshes with more elements are not padded: their solve, not the compilation, dominates
MAXIMUM_ELEMENTS = 2**14
#: the vertex bucket of an element bucket ``B`` is ``VERTEX_SHARE[d] * B`` (or twice that, ...,
#: when the mesh has more vertices): disk-like triangle meshes have about ``m / 2`` vertices
#: plus the boundary's half, box-like tet meshes ``m / 6`` to ``m / 3``
VERTEX_SHARE = {2: 0.625, 3: 0.375}


def power_bucket(size: int, smallest: int = 64) -> int:
    """The smallest ``smallest * 2**k >= size`` (k >= 0)."""
    b = int(smallest)
    while b < size:
        b *= 2
    return b


def bucket_sizes(n_vertices: int, n_elements: int, dim: int):
    """The padded sizes ``(vertices, elements)`` of a mesh, or None when it is not padded
    (more than :data:`MAXIMUM_ELEMENTS` elements).

    Parameters
    ----------
    n_vertices, n_elements : int, the mesh's counts.
    dim : 2 or 3, the Jacobians' size.
    """
    if n_elements > MAXIMUM_ELEMENTS:
        return None
    elements = power_bucket(n_elements, MINIMUM_ELEMENTS)
    return power_bucket(n_vertices, int(VERTEX_SHARE[dim] * elements)), elements


@dataclasses.dataclass(frozen=True)
class Sizes:
    """Real and padded sizes of one problem: vertices ``n -> n_padded`` and elements
    ``m -> m_padded``."""

    n: int
    m: int
    n_padded: int
    m_padded: int

    @classmethod
    def of(cls, problem, buckets=True) -> "Sizes":
        """The sizes of ``problem`` for ``buckets``: False (none), True (:func:`bucket_sizes`),
        or the :class:`Sizes` of another problem on the same vertices with at least as many
        elements (a sub-problem padded like its whole, so that both share one bucket)."""
        n, m = problem.n_vertices, problem.n_elements
        if isinstance(buckets, Sizes):
            if buckets.n != n or buckets.m_padded < m:
                raise ParameterError(f"buckets: the sizes {buckets} do not hold a problem of {n} vertices and "
                                     f"{m} elements")
            return cls(n, m, buckets.n_padded, buckets.m_padded)
        if not isinstance(buckets, (bool, np.bool_)):
            raise ParameterError(f"buckets must be True, False or another objective's sizes, got {buckets!r}")
        padded = bucket_sizes(n, m, problem.dim) if buckets else None
        return cls(n, m, *(padded or (n, m)))

    @property
    def padded(self) -> bool:
        return (self.n_padded, self.m_padded) != (self.n, self.m)


def pad_geometry(problem, sizes: Sizes, volumes=None):
    """``(S, Minv, vol)`` of shapes (M, d+1), (M, d, d), (M,) for ``M = m_padded``: the
    problem's elements (``volumes`` in place of its rest volumes when given, e.g. weighted)
    followed by zero-volume copies of elements ``0, 1, ...`` (cycling).  NumPy, or JAX for traced
    arrays."""
    S, Minv = problem.simplices, problem.rest_inv
    vol = problem.volumes if volumes is None else volumes
    return (pad_rows(S, sizes.m_padded, cycle=True), pad_rows(Minv, sizes.m_padded, cycle=True),
            pad_rows(vol, sizes.m_padded, fill=0.0))


def pad_rows(a, rows: int, fill=None, cycle: bool = False):
    """``a`` (k, ...) extended to ``rows`` rows with ``fill``, or copies of row 0, or with
    ``cycle`` copies of rows ``0, 1, ..., k-1, 0, ...`` (NumPy, or JAX when ``a`` is traced)."""
    xp = _xp(a)
    a = a if xp is not np else np.asarray(a)
    extra = rows - a.shape[0]
    if extra <= 0:
        return a
    if fill is not None:
        tail = xp.full((extra,) + a.shape[1:], fill, a.dtype)
    else:
        tail = a[np.arange(extra) % a.shape[0]] if cycle else xp.repeat(a[:1], extra, axis=0)
    return xp.concatenate([a, tail])


def _xp(a):
    from .tracing import is_traced

    if is_traced(a):
        import jax.numpy as jnp

        return jnp
    return np

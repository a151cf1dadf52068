"""Array validators: the checks every constructor and reader applies to vertices, elements and indices.

The ground floor of geomopt: plain NumPy, no I/O, no JAX, so that :mod:`geomopt.mesh.problem`,
:mod:`geomopt.exact.certify`, :mod:`geomopt.mesh.tutte` and the file readers (:mod:`geomopt.io`) share
one set of checks and one wording of their errors (:class:`~geomopt._runtime.errors.MeshError`).
"""

from __future__ import annotations

import numpy as np

from .errors import MeshError
from .tracing import refuse_traced

__all__ = ["validate_vertices", "validate_simplices", "validate_indices"]

_SIMPLEX_WORDS = {3: ("triangle", "triangles"), 4: ("tetrahedron", "tetrahedra")}



# ----------------------------------------------------------------------- validation


def _as_array(A, name):
    """``np.asarray`` that turns ragged/odd input into a MeshError (a traced JAX value into a
    ParameterError saying what can be traced)."""
    refuse_traced(f"the check of {name}", "connectivity and indices must be concrete (close over them); traceable: "
                  "rest vertices and handles in Problem.planar/surface/tets, Objective.value and the drivers on traced input", A)
    try:
        return np.asarray(A)
    except (ValueError, TypeError) as exc:
        raise MeshError(f"{name} is not a rectangular numeric array ({exc})") from None


def validate_vertices(V, name="vertices", dim=None):
    """Check vertex coordinates and return them as a ``float64`` array.

    Parameters
    ----------
    V : array_like, shape (n, d)
        Vertex positions, real-valued (integer or floating dtype).
    name : str
        What ``V`` is, used at the start of error messages.
    dim : {None, 2, 3}
        Required number of columns ``d``; ``None`` accepts 2 or 3.

    Returns
    -------
    numpy.ndarray, shape (n, d), float64
        A C-contiguous copy (or ``V`` itself when already so).

    Raises
    ------
    MeshError
        Wrong number of dimensions or columns, non-real dtype, no vertices, or
        NaN/infinite coordinates (the message gives the count and first index).
    """
    A = _as_array(V, name)
    widths = (2, 3) if dim is None else (dim,)
    want = " or ".join(f"(n, {w})" for w in widths)
    if A.ndim != 2 or A.shape[1] not in widths:
        raise MeshError(f"{name} must have shape {want}, got shape {A.shape}")
    if A.dtype.kind not in "fiu":
        raise MeshError(f"{name} must hold real numbers, got dtype {A.dtype}")
    if A.shape[0] == 0:
        raise MeshError(f"{name} has no vertices")
    A = np.ascontiguousarray(A, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(A).all(axis=1))
    if bad.size:
        raise MeshError(
            f"{name} has {bad.size} vertices with NaN or infinite coordinates "
            f"(first: vertex {bad[0]}); fix or remove them"
        )
    return A


def validate_simplices(S, n_vertices, k, name="faces", words=None):
    """Check an element (triangle, tetrahedron, quad, hexahedron) index array and return it as ``int64``.

    Parameters
    ----------
    S : array_like, shape (m, k)
        0-based vertex indices of ``m`` elements; must have an integer dtype
        (integer-valued floats are rejected, not rounded).
    n_vertices : int
        Number of vertices ``n``; valid indices are ``0 .. n-1``.
    k : int
        Vertices per element: 3 for triangles, 4 for tetrahedra.
    name : str
        What ``S`` is, used at the start of error messages.
    words : (str, str), optional
        The element's name, singular and plural, for messages (default: triangle /
        tetrahedron by ``k``).

    Returns
    -------
    numpy.ndarray, shape (m, k), int64
        A C-contiguous copy (or ``S`` itself when already so).

    Raises
    ------
    MeshError
        Wrong shape, non-integer dtype, no elements, indices out of range, or an
        element that uses a vertex twice (messages give the count and first element).
    """
    word, words = words or _SIMPLEX_WORDS.get(k, (f"{k}-vertex element", f"{k}-vertex elements"))
    A = _as_array(S, name)
    if A.ndim != 2 or A.shape[1] != k:
        raise MeshError(f"{name} must have shape (m, {k}) ({words}), got shape {A.shape}")
    if A.dtype.kind not in "iu":
        raise MeshError(
            f"{name} must have an integer dtype, got {A.dtype}; convert it with "
            f".astype(np.int64) after checking the values are whole numbers"
        )
    if A.shape[0] == 0:
        raise MeshError(f"{name} has no {words}")
    if A.min() < 0 or A.max() >= n_vertices:  # two reductions; the rows are found only on refusal
        bad = np.flatnonzero(((A < 0) | (A >= n_vertices)).any(axis=1))
        raise MeshError(
            f"{name} has {bad.size} {words} with vertex indices outside 0..{n_vertices - 1} "
            f"(first: {word} {bad[0]} = {A[bad[0]].tolist()}); indices must be 0-based "
            f"and below the vertex count {n_vertices}"
        )
    A = np.ascontiguousarray(A, dtype=np.int64)
    repeated = _repeats(A)
    if repeated.any():
        bad = np.flatnonzero(repeated)
        raise MeshError(
            f"{name} has {bad.size} {words} that use a vertex more than once "
            f"(first: {word} {bad[0]} = {A[bad[0]].tolist()}); remove these degenerate {words}"
        )
    return A


def _repeats(A, rows=32768):
    """Rows of ``A`` (m, k) that hold a value twice: k(k-1)/2 column comparisons, a block of ``rows``
    rows at a time so that they stay in cache (4x faster than sorting each row for tets)."""
    out = np.zeros(A.shape[0], dtype=bool)
    for start in range(0, A.shape[0], rows):
        block, found = A[start:start + rows], out[start:start + rows]
        for i in range(A.shape[1]):
            for j in range(i + 1, A.shape[1]):
                found |= block[:, i] == block[:, j]
    return out


def validate_indices(I, n_vertices, name="handles"):
    """Check a list of distinct vertex indices (e.g. fixed vertices) and return it as ``int64``.

    Parameters
    ----------
    I : array_like, shape (k,)
        0-based vertex indices; integer dtype; may be empty.
    n_vertices : int
        Number of vertices ``n``; valid indices are ``0 .. n-1``.
    name : str
        What ``I`` is, used at the start of error messages.

    Returns
    -------
    numpy.ndarray, shape (k,), int64
        The indices in their given order.

    Raises
    ------
    MeshError
        Not 1-D, non-integer dtype, out of range, or repeated indices.
    """
    A = _as_array(I, name)
    if A.ndim != 1:
        raise MeshError(f"{name} must be a 1-D array of vertex indices, got shape {A.shape}")
    if A.size == 0:
        return np.zeros(0, dtype=np.int64)
    if A.dtype.kind not in "iu":
        raise MeshError(f"{name} must have an integer dtype, got {A.dtype}")
    bad = np.flatnonzero((A < 0) | (A >= n_vertices))
    if bad.size:
        raise MeshError(
            f"{name} has {bad.size} indices outside 0..{n_vertices - 1} "
            f"(first: entry {bad[0]} = {A[bad[0]]}); indices must be 0-based vertex ids"
        )
    A = np.ascontiguousarray(A, dtype=np.int64)
    values, counts = np.unique(A, return_counts=True)
    repeated = values[counts > 1]
    if repeated.size:
        raise MeshError(
            f"{name} lists {repeated.size} vertices more than once "
            f"(first: vertex {repeated[0]}); each vertex may appear only once"
        )
    return A


"""Telling traced JAX values from concrete ones, and content keys for static pytree data.

Functions of geomopt run in two worlds: on concrete arrays (NumPy or JAX), where inputs are
validated value by value and solves run on the host, and inside a user's ``jax.jit`` /
``grad`` / ``vmap``, where values are abstract tracers.  :func:`is_traced` tells them apart;
:func:`refuse_traced` is the one-line error of an entry point that only runs on concrete
values; :class:`StaticKey` makes integer connectivity hashable pytree metadata.
"""

from __future__ import annotations

import hashlib
import sys

import numpy as np

from .errors import ParameterError


def is_traced(*trees) -> bool:
    """True when a leaf of ``trees`` is a JAX tracer (abstract: inside jit, grad, vmap...)."""
    if "jax" not in sys.modules:  # nothing can be traced before JAX is imported
        return False
    import jax

    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(trees))


def refuse_traced(where: str, instead: str, *trees):
    """Raise ParameterError when a leaf of ``trees`` is traced: ``where`` runs on concrete values
    only, ``instead`` says what to call for a differentiable or traceable result."""
    if is_traced(*trees):
        raise ParameterError(f"{where} cannot run on traced JAX values (inside jax.jit, grad or vmap): "
                             f"it works on concrete arrays; {instead}")


def digest(a) -> bytes:
    """A 16-byte content hash of a NumPy array (shape, dtype and bytes)."""
    a = np.ascontiguousarray(a)
    h = hashlib.blake2b(digest_size=16)
    h.update(repr((a.shape, a.dtype.str)).encode())
    h.update(a.data)
    return h.digest()


class StaticKey:
    """Hashable, comparable-by-content metadata of a pytree node (JAX compares it to reuse
    traces).  ``key`` is a tuple of hashables; ``payload`` travels along and is ignored by
    ``==`` and ``hash`` (objects that the key determines: arrays, caches)."""

    __slots__ = ("key", "payload", "_hash")

    def __init__(self, key: tuple, payload=None):
        self.key, self.payload, self._hash = key, payload, hash(key)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return self is other or (isinstance(other, StaticKey) and self._hash == other._hash
                                 and self.key == other.key)

    def __repr__(self):
        return f"StaticKey({self.key[:3]!r}...)"

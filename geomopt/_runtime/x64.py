"""The float64 policy: geomopt computes in float64 whatever JAX's global ``jax_enable_x64``.

Importing geomopt leaves JAX's global configuration alone, so float32 code (a neural network,
an optax loop over float32 parameters) keeps its dtypes beside it.  Every public function and
method that runs JAX computations is wrapped by :func:`float64`: when the 64-bit mode is off it
runs inside ``with jax.enable_x64(True):`` (JAX's scoped, thread-local switch), so its arrays
and kernels are float64; its results are NumPy arrays or Python floats where they leave the
library, float64 JAX arrays otherwise (arithmetic on those outside the 64-bit mode follows
JAX's rules, i.e. float32).

Inside a user's transformation (``jax.jit`` / ``grad`` / ``vmap`` of a function calling
``Objective.value`` or :mod:`geomopt.objective.adjoint`), the mode cannot be switched: the user's trace
must run in 64-bit mode (``with jax.enable_x64(True): jax.grad(f)(x)``, or
``jax.config.update("jax_enable_x64", True)`` at start-up); otherwise a ParameterError says so
(:data:`MESSAGE`) instead of computing in float32.  The compiled kernels refuse to run with the
mode off (:func:`require`): a path that escaped the wrapping fails loudly, never in float32.

The outermost wrapped call on a thread first waits for the host callbacks already dispatched
(``jax.effects_barrier()``): geomopt's callbacks (:func:`pure_callback`, the host solves of
:mod:`geomopt.objective.adjoint` under ``jax.jit``) run JAX computations themselves, and with JAX 0.4.x's
CPU client those, queued behind the caller's still-running jitted computation, deadlock against
computations the caller's thread dispatches meanwhile (an un-awaited ``jax.jit`` result followed
by an eager geomopt call).  Calls made inside a callback skip the wait (it would wait on itself).
Only JAX before 0.7 waits (:func:`_old_cpu_client`): newer clients did not deadlock.
"""

from __future__ import annotations

import functools
import threading

from .errors import ParameterError
from .tracing import is_traced

MESSAGE = ("geomopt computes in float64, and JAX's 64-bit mode is off in this transformation: run it "
           "inside `with jax.enable_x64(True):` or call jax.config.update('jax_enable_x64', True) at "
           "start-up (see the README, 'float64')")

_depth = threading.local()  # .n: wrapped calls (and geomopt host callbacks) running on this thread


def enabled() -> bool:
    import jax

    return bool(jax.config.jax_enable_x64)


def require():
    """Raise ParameterError (:data:`MESSAGE`) when JAX's 64-bit mode is off."""
    if not enabled():
        raise ParameterError(MESSAGE)


def float64(fn, method=False):
    """Run ``fn`` in JAX's 64-bit mode: as it is when the mode is on, inside
    ``jax.enable_x64(True)`` when it is off; ParameterError when it is off and an argument is
    traced (a float32 trace of the caller's cannot be switched).  ``method``: ``fn``'s first
    argument (``self``) is not looked at."""

    @functools.wraps(fn)
    def run(*args, **kwargs):
        traced = is_traced((args[1:] if method else args, kwargs))
        if not enabled() and traced:
            raise ParameterError(MESSAGE)
        with nested(wait=not traced):
            if enabled():
                return fn(*args, **kwargs)
            with scope():
                return fn(*args, **kwargs)

    return run


class nested:
    """Context of a geomopt call on this thread; the outermost one, with ``wait``, first waits
    for the host callbacks already dispatched (module notes)."""

    def __init__(self, wait=True):
        self.wait = wait

    def __enter__(self):
        n = getattr(_depth, "n", 0)
        if n == 0 and self.wait and _old_cpu_client():
            import jax

            jax.effects_barrier()
        _depth.n = n + 1

    def __exit__(self, *exc):
        _depth.n -= 1


@functools.cache
def _old_cpu_client() -> bool:
    """JAX before 0.7 (no ``jax.enable_x64``): the CPU client whose in-flight limit deadlocked
    (measured on 0.4.38; the wait is skipped on newer JAX, where it was not needed)."""
    import jax

    return not hasattr(jax, "enable_x64")


def scope():
    """JAX's scoped, thread-local 64-bit switch: ``jax.enable_x64(True)``, named
    ``jax.experimental.enable_x64()`` before JAX 0.7 (the declared floor is 0.4.38)."""
    import jax

    if hasattr(jax, "enable_x64"):
        return jax.enable_x64(True)
    from jax.experimental import enable_x64

    return enable_x64(True)


def float64_methods(*names):
    """Class decorator: wrap the methods ``names`` (defined on the class) with :func:`float64`."""

    def wrap(cls):
        for name in names:
            if name in vars(cls):
                setattr(cls, name, float64(vars(cls)[name], method=True))
        return cls

    return wrap


def pure_callback(fn, result_shapes, *args, vmap_method="sequential"):
    """``jax.pure_callback`` whose 64-bit results survive a callback thread where JAX's 64-bit
    mode is off (the mode is thread-local, and JAX converts a callback's results under the
    thread's own setting): each 64-bit result travels as its bytes, ``uint32`` pairs, and is
    bit-cast back in the caller's (64-bit) trace."""
    import jax
    import numpy as np

    def wide(s):
        return np.dtype(s.dtype).itemsize == 8

    flat, tree = jax.tree_util.tree_flatten(result_shapes)
    carried = [jax.ShapeDtypeStruct(tuple(s.shape) + (2,), np.uint32) if wide(s) else s for s in flat]

    def host(*a):
        with nested(wait=False):  # on a callback thread: waiting would wait on this very callback
            out = jax.tree_util.tree_leaves(fn(*a))
        return [np.ascontiguousarray(o, s.dtype).view(np.uint32).reshape(c.shape) if wide(s)
                else np.asarray(o, s.dtype) for o, s, c in zip(out, flat, carried)]

    res = jax.pure_callback(host, carried, *args, vmap_method=vmap_method)
    return tree.unflatten([jax.lax.bitcast_convert_type(r, s.dtype) if wide(s) else r
                           for r, s in zip(res, flat)])

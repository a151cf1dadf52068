"""Host (NumPy) functions called from jitted code through XLA's FFI, so the programs that call
them can be kept in the persistent compilation cache.

``jax.pure_callback`` is the usual way to run host code inside a jitted program, but JAX never
writes a program that holds one to the persistent cache (the Python callable is attached to
the executable), so such a program is compiled again in every process: the two L-BFGS
programs of an untangling with the Laplacian seed (:mod:`geomopt.solvers._laplacian`) cost
2.2-2.6 s of compilation per ``geomopt untangle`` process on an 83k-tet cube.  Here the host
function is registered once per process as an XLA FFI target (``jax.ffi.register_ffi_target``)
whose handler is a ``ctypes`` function: the program refers to it by name only, so it is cached
like any other and finds the handler again in the next process, once this module has
registered it (on import of the module that defines the function).

The handler follows the XLA FFI C API (``xla/ffi/api/c_api.h``, API 0.1): it answers the
metadata query, ignores every stage but execution, and views its buffers as NumPy arrays
without copying.  An exception inside the host function fills the outputs with NaN (the
solver then stops with a non-finite outcome) and is kept in :data:`last_error`.  Where JAX
has no ``jax.ffi`` (before 0.4.38) :func:`call` falls back to ``jax.pure_callback``.
"""

from __future__ import annotations

import ctypes as C

import jax
import numpy as np

from . import x64 as _x64

#: (name, exception) of the last host function that raised inside a handler, else None
last_error = None

_EXECUTE, _METADATA = 3, 1
_DTYPES = {4: C.c_int32, 5: C.c_int64, 11: C.c_float, 12: C.c_double}  # XLA_FFI_DataType


class _Extension(C.Structure):
    pass


_Extension._fields_ = [("struct_size", C.c_size_t), ("type", C.c_int), ("next", C.POINTER(_Extension))]


class _Version(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p),
                ("major", C.c_int), ("minor", C.c_int)]


class _Metadata(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("api_version", _Version), ("traits", C.c_uint32),
                ("state_type_id", C.c_int64)]


class _MetadataExtension(C.Structure):
    _fields_ = [("base", _Extension), ("metadata", C.POINTER(_Metadata))]


class _Buffer(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("dtype", C.c_int),
                ("data", C.c_void_p), ("rank", C.c_int64), ("dims", C.POINTER(C.c_int64))]


class _Buffers(C.Structure):  # XLA_FFI_Args / XLA_FFI_Rets
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("size", C.c_int64),
                ("types", C.POINTER(C.c_int)), ("buffers", C.POINTER(C.POINTER(_Buffer)))]


class _CallFrame(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.POINTER(_Extension)),
                ("api", C.c_void_p), ("ctx", C.c_void_p), ("stage", C.c_int), ("args", _Buffers),
                ("rets", _Buffers), ("attrs", _Buffers), ("future", C.c_void_p)]


_HANDLER = C.CFUNCTYPE(C.c_void_p, C.POINTER(_CallFrame))
_registered: dict = {}  # name -> ctypes handler (kept alive for the process)


def _view(ptr) -> np.ndarray:
    """A buffer of the call frame as a NumPy array (no copy)."""
    b = ptr.contents
    shape = tuple(int(b.dims[i]) for i in range(b.rank))
    n = int(np.prod(shape)) if shape else 1
    return np.ctypeslib.as_array(C.cast(b.data, C.POINTER(_DTYPES[b.dtype])), shape=(n,)).reshape(shape)


def _handler(name, fn):
    def handle(frame_ptr):
        global last_error
        frame = frame_ptr.contents
        ext = frame.extension_start
        if ext and ext.contents.type == _METADATA:  # registration asks for the API version
            meta = C.cast(ext, C.POINTER(_MetadataExtension)).contents.metadata.contents
            meta.api_version.major, meta.api_version.minor, meta.traits = 0, 1, 0
            return None
        if frame.stage != _EXECUTE:
            return None
        outs = [_view(frame.rets.buffers[i]) for i in range(frame.rets.size)]
        try:
            fn(*[_view(frame.args.buffers[i]) for i in range(frame.args.size)], out=outs)
        except Exception as exc:  # noqa: BLE001 -- must not unwind through XLA
            last_error = (name, exc)
            for o in outs:
                o[...] = np.nan
        return None
    return _HANDLER(handle)


def available() -> bool:
    """Whether this JAX can register FFI targets (else :func:`call` uses ``pure_callback``)."""
    return hasattr(jax, "ffi") and hasattr(jax.ffi, "register_ffi_target") and hasattr(jax.ffi, "pycapsule")


def register(name: str, fn) -> None:
    """Register ``fn(*inputs, out=[outputs])`` (NumPy arrays; it fills ``out`` in place) as the
    CPU target ``name``.  Once per process and name; later calls do nothing."""
    if name in _registered or not available():
        _registered.setdefault(name, fn)
        return
    handler = _handler(name, fn)
    jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(C.cast(handler, C.c_void_p)), platform="cpu")
    _registered[name] = handler


def call(name: str, fn, result: jax.ShapeDtypeStruct, *args):
    """``fn`` (registered as ``name``) applied to ``args`` from jitted code: one output shaped
    like ``result``.  CPU only; elsewhere, or without ``jax.ffi``, a ``jax.pure_callback``."""
    register(name, fn)
    if available() and jax.default_backend() == "cpu":
        return jax.ffi.ffi_call(name, result)(*args)

    def host(*arrays):
        out = np.empty(result.shape, result.dtype)
        fn(*(np.asarray(a) for a in arrays), out=[out])
        return out
    return _x64.pure_callback(host, result, *args)  # 64-bit results survive a callback thread

"""Traced programs kept on disk (``jax.export``), so that a warm process neither traces nor
compiles.

JAX's persistent compilation cache (:mod:`geomopt._cache`) skips XLA's compilation, but a new
process still traces and lowers every program before it can look the compiled one up: 0.3-0.6 s
per process for an untangling, 1.5-2 s for a Newton parameterization of 50k triangles (the
Hessian kernel alone traces in 0.5 s).  :func:`jit` is ``jax.jit`` whose programs are also
serialised with ``jax.export`` under ``<cache folder>/programs``, keyed by everything the
trace depends on:

* the function (module and qualified name) and its static arguments (energy density,
  projection, solver configuration, sizes...) by a stable text form;
* the structure, shapes and dtypes of the traced arguments (the size bucket, for padded
  meshes);
* JAX and jaxlib versions, the backend, the XLA options, and the source files of geomopt
  (size and modification time) and of any module a static function comes from.

A later call with the same key deserialises the program and calls it (``Exported.call``
under ``jax.jit``), which XLA then loads from the persistent compilation cache.  The first
process calls the exported program too, so both processes compile the same module and the
second one hits the cache.  Static arguments without a stable text form (a lambda, a local
function, an object without a dataclass ``repr``) are traced as usual, every process.  With
the persistent cache off, or ``GEOMOPT_PROGRAMS=off`` in the environment, this is plain
``jax.jit``.  Serialisation needs the ``flatbuffers`` package (a dependency).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import sys
import types

import jax
import numpy as np

from . import _cache, _hostcall

_UNSTABLE = object()
_fingerprints: dict = {}


def _source_fingerprint(module_name: str) -> str:
    """Size and modification time of a module's source (geomopt: the whole package)."""
    if module_name in _fingerprints:
        return _fingerprints[module_name]
    parts = []
    mod = sys.modules.get(module_name)
    files = []
    if module_name == "geomopt":
        root = os.path.dirname(os.path.abspath(__file__))
        for base, _, names in os.walk(root):
            files += [os.path.join(base, n) for n in names if n.endswith(".py")]
    elif getattr(mod, "__file__", None):
        files = [mod.__file__]
    for f in sorted(files):
        try:
            st = os.stat(f)
            parts.append(f"{f}:{st.st_size}:{st.st_mtime_ns}")
        except OSError:
            parts.append(f"{f}:?")
    _fingerprints[module_name] = hashlib.sha256("\n".join(parts).encode()).hexdigest()
    return _fingerprints[module_name]


def _stable(value, modules):
    """A text form of a static argument that is the same in every process, or _UNSTABLE;
    adds the modules whose source it depends on to ``modules``."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return repr(value)
    if isinstance(value, (tuple, list)):
        items = [_stable(v, modules) for v in value]
        return _UNSTABLE if _UNSTABLE in items else f"{type(value).__name__}({','.join(items)})"
    if isinstance(value, (types.FunctionType, type)):
        mod, name = getattr(value, "__module__", None), getattr(value, "__qualname__", "")
        owner = sys.modules.get(mod)
        if owner is None or "<" in name or functools.reduce(getattr, name.split("."), owner) is not value:
            return _UNSTABLE
        modules.add(mod.split(".")[0] if mod.startswith("geomopt") else mod)
        return f"{mod}.{name}"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        names = [f.name for f in dataclasses.fields(value)]
        values = [_stable(getattr(value, n), modules) for n in names]
        head = _stable(type(value), modules)
        if head is _UNSTABLE or any(v is _UNSTABLE for v in values):
            return _UNSTABLE
        return f"{head}({','.join(f'{n}={v}' for n, v in zip(names, values))})"
    return _UNSTABLE


def _folder():
    """Where programs are kept: the persistent cache's folder (None: plain ``jax.jit``)."""
    if os.environ.get("GEOMOPT_PROGRAMS", "on").strip().lower() in ("off", "0", "no", "false"):
        return None
    return _cache.cache_dir()


def _aval(x):
    t = jax.typeof(x)
    return jax.ShapeDtypeStruct(t.shape, t.dtype, weak_type=getattr(t, "weak_type", False))


class Program:
    """``jax.jit(fun, static_argnums=..., compiler_options=...)`` whose traced programs are
    kept on disk (see the module notes).  Call it like ``fun``; :meth:`lower` as ``jax.jit``'s."""

    def __init__(self, fun, static_argnums=(), compiler_options=None):
        self.fun = fun
        self.static = tuple(sorted(static_argnums if isinstance(static_argnums, tuple) else (static_argnums,)))
        self.options = dict(compiler_options or {})
        self.plain = jax.jit(fun, static_argnums=self.static, compiler_options=self.options or None)
        self._calls: dict = {}
        functools.update_wrapper(self, fun)

    def _split(self, args):
        statics = tuple(args[i] for i in self.static)
        dynamic = tuple(a for i, a in enumerate(args) if i not in self.static)
        return statics, dynamic

    def _bind(self, statics):
        """``fun`` of the traced arguments only."""
        def bound(*dynamic):
            it, st = iter(dynamic), iter(statics)
            n = len(dynamic) + len(statics)
            return self.fun(*[next(st) if i in self.static else next(it) for i in range(n)])
        return bound

    def _callable(self, args):
        statics, dynamic = self._split(args)
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        avals = tuple(_aval(x) for x in leaves)
        try:
            key = (statics, tree, tuple((a.shape, a.dtype, a.weak_type) for a in avals))
            hash(key)
        except TypeError:
            return None, dynamic
        call = self._calls.get(key)
        if call is None:
            call = self._calls[key] = self._load(statics, tree, avals)
        return call, dynamic

    def _load(self, statics, tree, avals):
        folder = _folder()
        modules = {"geomopt"}
        text, name = _stable(statics, modules), _stable(self.fun, modules)
        if folder is None or text is _UNSTABLE or name is _UNSTABLE:
            return None
        ident = "\n".join([jax.__version__, getattr(jax, "__jaxlib_version__", ""), jax.default_backend(),
                           name, text, str(tree), repr(avals),
                           repr(sorted(self.options.items())), str(jax.config.jax_enable_x64),
                           *sorted(_source_fingerprint(m) for m in modules)])
        key = hashlib.sha256(ident.encode()).hexdigest()
        path = os.path.join(folder, "programs", f"{self.fun.__name__}-{key}.jaxexport")
        exported = None
        try:
            with open(path, "rb") as fh:
                exported = jax.export.deserialize(bytearray(fh.read()))
        except (OSError, ValueError):
            pass
        if exported is None:
            try:
                checks = [jax.export.DisabledSafetyCheck.custom_call(n) for n in _hostcall.targets()]
                shaped = jax.tree_util.tree_unflatten(tree, avals)
                exported = jax.export.export(jax.jit(self._bind(statics)), disabled_checks=checks)(*shaped)
                if _cache.cache_writable():
                    _write(path, exported.serialize())
            except Exception:  # noqa: BLE001 -- anything export refuses is traced as usual
                return None
        def call(*dynamic):
            return exported.call(*dynamic)
        call.__name__ = call.__qualname__ = self.fun.__name__  # programs keep their names in logs
        return jax.jit(call, compiler_options=self.options or None)

    def __call__(self, *args):
        call, dynamic = self._callable(args) if _folder() else (None, None)
        return self.plain(*args) if call is None else call(*dynamic)

    def _cache_size(self) -> int:
        """Programs traced or loaded in this process (for no-recompile tests): ``jax.jit``'s count
        for the plain path, one per argument signature for the kept programs."""
        return self.plain._cache_size() + sum(c is not None for c in self._calls.values())

    def lower(self, *args):
        call, dynamic = self._callable(args) if _folder() else (None, None)
        return self.plain.lower(*args) if call is None else call.lower(*dynamic)


def _write(path, data: bytes) -> None:
    """Atomic write; a folder that cannot be written is skipped (the program is used anyway)."""
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except OSError:
        pass


def jit(fun=None, *, static_argnums=(), compiler_options=None):
    """``jax.jit`` with traced programs kept on disk (:class:`Program`); usable as
    ``@jit``, ``@partial(jit, static_argnums=0)``."""
    if fun is None:
        return functools.partial(jit, static_argnums=static_argnums, compiler_options=compiler_options)
    return Program(fun, static_argnums, compiler_options)

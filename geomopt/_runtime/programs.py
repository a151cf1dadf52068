"""Compiled programs kept on disk, so that a warm process neither traces nor compiles.

JAX's persistent compilation cache (:mod:`geomopt._runtime.cache`) skips XLA's compilation, but a new
process still traces and lowers every program to find the compiled one, a cost that for the
large kernels (the projected Hessian, the injective search) is a noticeable share of a warm
run (measurements: benchmarks/README.md, issue 49 section).  :class:`Program` is ``jax.jit``
whose compiled executables are also written with ``jax.experimental.serialize_executable`` under
``<cache folder>/programs``, keyed by everything the trace depends on:

* the function (module and qualified name) and its static arguments (energy density,
  projection, solver configuration, sizes...) by a stable text form;
* the structure, shapes and dtypes of the traced arguments (the size bucket, for padded
  meshes), and whether 64-bit types are on;
* geomopt, JAX and jaxlib versions, the backend, its platform version and devices, the host's
  CPU (architecture and feature flags: XLA CPU compiles for the host's instruction set), the
  compiler options and ``XLA_FLAGS``, and the source files of geomopt (size and modification
  time) and of any module a static function comes from.

A later process with the same key loads the executable and calls it: no trace, no lowering.
The file name is only a hash of the key: each file starts with a header that holds the whole
key (the fields above, in words) and the size and SHA-256 of the executable after it.  A file
is run only when its header equals what the caller asks for and its bytes match their
checksum; any other file (one swapped with another energy's, copied from another version, a
machine with other CPU features, damaged or of an older format) is ignored, counted in
``stats["rejected"]``, compiled afresh and replaced atomically.
Static arguments without a stable text form (a lambda, a local function, an object without a
dataclass ``repr``), programs that cannot be serialised (host callbacks, captured constants)
and calls on traced values go through plain ``jax.jit``.  With the persistent cache off, or
``GEOMOPT_PROGRAMS=off`` in the environment, this is plain ``jax.jit``.  As with JAX's own
cache, loading a program runs code from the cache folder: never point it at a folder that
others can write.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import hashlib
import json
import os
import pickle
import platform
import sys
import threading
import types
import weakref

import jax
import jaxlib
import numpy as np

from . import cache as _cache
from .._version import __version__

_UNSTABLE = object()
#: bumped when what is written changes (files of other formats are never read)
_FORMAT = "geomopt-programs-2 (compiled outside JAX's cache, header with the key)"
_MAGIC = b"GEOMOPT-PROGRAM 2\n"
_fingerprints: dict = {}
#: what happened to each program since start-up: "loaded" (from disk), "stored" (compiled here
#: and written), "plain" (through jax.jit), "broken" (loaded but failed at its first call:
#: deleted, plain jax.jit instead), "rejected" (a file whose header is not the caller's key or
#: whose bytes fail their checksum: never run, compiled afresh); for tests and benchmarks
stats = {"loaded": 0, "stored": 0, "plain": 0, "broken": 0, "rejected": 0}
#: executables one :class:`Program` keeps in memory; beyond, the least recently used is dropped
#: (and loaded from disk again if asked for).  Each live executable maps three regions of
#: memory (its code, constants and data) and Linux lets a process map 65,530 by default: a
#: process that called thousands of shapes (a test worker, a long sweep) crashed in XLA's
#: compiler when the next mapping failed
HELD = 64
_programs: "weakref.WeakSet[Program]" = weakref.WeakSet()

#: XLA options of every program (unless it names its own).  XLA CPU wraps reductions and
#: elementwise work over large arrays into YNNPACK library calls, which cuts its loop fusion;
#: turning that off makes the energy, its gradient and L-BFGS's loop faster on large arrays
#: and changes nothing below 16,384 entries (measurements: benchmarks/README.md, issue 49
#: section).  It changes nothing else (the option exists for CPU only).  jaxlib before 0.8.1
#: does not know it and refuses to compile with it: see :func:`xla_options`.
XLA_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}


@functools.cache
def xla_options() -> dict:
    """:data:`XLA_OPTIONS` if the running jaxlib accepts them, else ``{}``: decided once per
    process by compiling an identity (at the first program call, not at import)."""
    try:
        jax.jit(lambda v: v, compiler_options=XLA_OPTIONS).lower(np.float64(0.0)).compile()
    except Exception:  # noqa: BLE001 -- the error type differs across jaxlib versions
        return {}
    return dict(XLA_OPTIONS)


def _source_fingerprint(module_name: str) -> str:
    """Size and modification time of a module's source (geomopt: the whole package)."""
    if module_name in _fingerprints:
        return _fingerprints[module_name]
    mod = sys.modules.get(module_name)
    files = []
    if module_name == "geomopt":  # the package's root, one level above this module's _runtime
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        for base, _, names in os.walk(root):
            files += [os.path.join(base, n) for n in names if n.endswith(".py")]
    elif getattr(mod, "__file__", None):
        files = [mod.__file__]
    parts = []
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
        return _UNSTABLE if any(i is _UNSTABLE for i in items) else f"{type(value).__name__}({','.join(items)})"
    if isinstance(value, (types.FunctionType, type)):
        mod, name = getattr(value, "__module__", None), getattr(value, "__qualname__", "")
        owner = sys.modules.get(mod)
        try:  # the module's attribute is the function, or a wrapper of it (a jit decorator)
            found = functools.reduce(getattr, name.split("."), owner) if owner is not None and "<" not in name else None
        except AttributeError:
            found = None
        same = found is value or (found is not None and getattr(found, "__wrapped__", None) is value)
        if not same:
            return _UNSTABLE
        modules.add("geomopt" if mod.startswith("geomopt") else mod)
        return f"{mod}.{name}"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        names = [f.name for f in dataclasses.fields(value)]
        items = [_stable(getattr(value, n), modules) for n in names]
        head = _stable(type(value), modules)
        if head is _UNSTABLE or any(i is _UNSTABLE for i in items):
            return _UNSTABLE
        return f"{head}({','.join(f'{n}={v}' for n, v in zip(names, items))})"
    return _UNSTABLE


def _leaf_key(x):
    """Shape, dtype and weak type of a traced argument, cheaply (no JAX call)."""
    if isinstance(x, (bool, int, float, complex)):
        return type(x)
    return (tuple(x.shape), str(x.dtype), bool(getattr(x, "weak_type", False)))


@functools.cache
def _lapack_ready() -> None:
    """Lower one small ``eigh`` (no compilation): jaxlib fills its table of LAPACK functions
    (taken from SciPy) only while it lowers a LAPACK call, so a loaded executable that calls
    LAPACK (the 3D Hessian kernel's 9 x 9 ``eigh``) in a process that has lowered none would
    jump through an empty table: a segmentation fault in the second ``geomopt untangle``
    with Newton on a 3D mesh."""
    import jax.numpy as jnp

    jax.jit(jnp.linalg.eigh).lower(jax.ShapeDtypeStruct((3, 3), np.float32))


def _calls_lapack(compiled) -> bool:
    """Whether a compiled program calls LAPACK (a custom call to a ``lapack_*`` target in its HLO;
    the text's metadata also names the caller's functions and files, so the target is what is
    matched; True when the text cannot be had): only then does loading it need
    :func:`_lapack_ready`, whose lowering and import of ``scipy.linalg`` are a noticeable cost
    in a warm process."""
    try:
        return 'custom_call_target="lapack_' in compiled.as_text()
    except Exception:  # noqa: BLE001 -- no text on this backend or jax version
        return True


class Program:
    """``jax.jit(fun, static_argnums=..., compiler_options=...)`` whose compiled executables are
    kept on disk (see the module notes).  Call it like ``fun``; :meth:`prepare` loads or
    compiles for given arguments without running; other attributes are ``jax.jit``'s.
    ``compiler_options=None``: :func:`xla_options`, resolved at the first call (importing a
    module of programs compiles nothing)."""

    def __init__(self, fun, static_argnums=(), compiler_options=None):
        self.fun = fun
        self.static = tuple(sorted(static_argnums if isinstance(static_argnums, tuple) else (static_argnums,)))
        self._given = None if compiler_options is None else dict(compiler_options)
        self._calls: collections.OrderedDict = collections.OrderedDict()  # key -> executable, oldest first
        self._unproven: dict = {}  # key -> file of a loaded executable not yet run
        self._loading = threading.RLock()
        functools.update_wrapper(self, fun)
        _programs.add(self)

    @property
    def options(self) -> dict:
        """The compiler options (:func:`xla_options` unless given)."""
        return xla_options() if self._given is None else self._given

    @property
    def requested_options(self) -> dict:
        """The compiler options asked for (:data:`XLA_OPTIONS` unless given): the key of a kept
        program, so that loading one needs no :func:`xla_options` probe (a compilation in every
        process); whether jaxlib accepts them follows from its version, in the key."""
        return XLA_OPTIONS if self._given is None else self._given

    @functools.cached_property
    def plain(self):
        return jax.jit(self.fun, static_argnums=self.static, compiler_options=self.options or None)

    def _executable(self, args):
        """(executable or None, its arguments, key) for a call with ``args``; called inside
        ``jit``/``grad``/``vmap`` (traced arguments): ``fun`` itself, inlined into that trace
        (XLA options can only be given to the outermost program), with key None."""
        statics = tuple(args[i] for i in self.static)
        dynamic = tuple(a for i, a in enumerate(args) if i not in self.static)
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return self.fun, args, None
        folder = _cache.programs_dir()
        if folder is None:
            return None, None, None
        try:
            key = (statics, tree, tuple(map(_leaf_key, leaves)), jax.dtypes.canonicalize_dtype(np.float64).name)
            call = self._calls.get(key, False)
        except (TypeError, AttributeError):  # unhashable static argument, a leaf without dtype
            return None, None, None
        if call is not False:
            with contextlib.suppress(KeyError):  # dropped meanwhile by another thread
                self._calls.move_to_end(key)
            return call, dynamic, key
        with self._loading:  # a load already under way on another thread is waited for
            call = self._calls.get(key, False)
            if call is False:
                call = self._calls[key] = self._load(args, statics, tree, key, folder)
                while len(self._calls) > HELD:  # the least recently used (see HELD)
                    self._unproven.pop(self._calls.popitem(last=False)[0], None)
        return call, dynamic, key

    def _load(self, args, statics, tree, key, folder):
        ident = self._identity(statics, tree, key)
        if ident is None:
            stats["plain"] += 1
            return None
        text = json.dumps(ident, sort_keys=True)
        path = os.path.join(folder, f"{self.fun.__name__}-{hashlib.sha256(text.encode()).hexdigest()}.xla")
        from jax.experimental import serialize_executable as se

        data = _read(path, ident)
        if data is not None:
            try:
                blob, in_tree, out_tree, *lapack = pickle.loads(data)
                stats["loaded"] += 1
                if lapack != [False]:  # a file of a former release does not say: ready it
                    _lapack_ready()
                loaded = se.deserialize_and_load(blob, in_tree, out_tree)
                self._unproven[key] = path
                _cache.count_loaded()
                with contextlib.suppress(OSError):  # used now: the size limit removes the least recently used
                    os.utime(path)
                return loaded
            except Exception:  # noqa: BLE001 -- checksummed but not loadable here: compile it
                pass
        lowered = self.plain.lower(*args)
        with _cache.bypassed():
            compiled = lowered.compile()
        try:
            data = pickle.dumps((*se.serialize(compiled), _calls_lapack(compiled)))
        except Exception:  # noqa: BLE001 -- host callbacks, captured constants: plain jit
            stats["plain"] += 1
            return None
        if _cache.programs_writable():
            _write(path, _header(ident, data) + data)
            _cache.prune_once()  # the folder grows: keep it within its size limit
        stats["stored"] += 1
        return compiled

    def _identity(self, statics, tree, key) -> dict | None:
        """Everything the compiled program depends on, as a dict of strings (the file's
        header and, hashed, its name); None when a static argument has no stable text form."""
        modules = {"geomopt"}
        text = _stable(statics, modules)
        if modules != {"geomopt"}:  # e.g. a user's energy density: its source and the globals it
            return None  # reads (a notebook's, a config's) are no part of any key: JAX's cache only
        name = _stable(self.fun, modules)
        if text is _UNSTABLE or name is _UNSTABLE:
            return None
        devices = jax.devices()
        return {"format": _FORMAT, "geomopt": __version__, "jax": jax.__version__,
                "jaxlib": jaxlib.__version__, "backend": jax.default_backend(),
                "platform": str(getattr(devices[0].client, "platform_version", "")),
                "devices": f"{len(devices)} x {devices[0].device_kind}", "cpu": _cpu(), "function": name,
                "static": text, "tree": str(tree), "arguments": repr(key[2:]),
                "options": repr(sorted(self.requested_options.items())), "xla_flags": os.environ.get("XLA_FLAGS", ""),
                "sources": " ".join(sorted(_source_fingerprint(m) for m in modules))}

    def __call__(self, *args):
        call, dynamic, key = self._executable(args)
        if call is None:
            return self.plain(*args)
        if key is None or key not in self._unproven:  # key None: traced, ``fun`` itself
            return call(*dynamic)
        try:  # a loaded executable's first run, waited for: a broken file must not end the solve
            out = jax.block_until_ready(call(*dynamic))
        except Exception:  # noqa: BLE001 -- e.g. "Function ... not found" from a damaged file
            self._calls[key] = None
            stats["broken"] += 1
            with contextlib.suppress(OSError, TypeError):  # TypeError: dropped meanwhile (HELD)
                os.remove(self._unproven.pop(key, None))
            return self.plain(*args)
        self._unproven.pop(key, None)
        return out

    def prepare(self, *args) -> None:
        """Load (or compile and keep) the program for ``args`` without running it."""
        call, _, _ = self._executable(args)
        if call is None:
            self.plain.lower(*args).compile()

    def _cache_size(self) -> int:
        """Programs traced or loaded in this process (for no-recompile tests)."""
        return self.plain._cache_size() + sum(c is not None for c in self._calls.values())

    def __getattr__(self, name):
        if name.startswith("__") or name in ("plain", "options"):
            raise AttributeError(name)
        return getattr(self.plain, name)


def clear() -> None:
    """Forget the programs held in memory (as ``jax.clear_caches`` does for ``jax.jit``): the
    next call looks them up on disk again, as a new process would."""
    for program in list(_programs):
        program._calls.clear()
        program._unproven.clear()


@functools.cache
def _cpu() -> str:
    """The host's architecture and CPU feature flags (Linux: ``/proc/cpuinfo``; elsewhere the
    processor's name), so that a cache folder copied to a machine without, say, AVX-512 is not
    run there."""
    flags = ""
    with contextlib.suppress(OSError):
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            flags = next((line.split(":", 1)[1].strip() for line in fh
                          if line.split(":", 1)[0].strip() in ("flags", "Features")), "")
    flags = " ".join(sorted(flags.split())) or platform.processor()
    return f"{platform.machine()} {hashlib.sha256(flags.encode()).hexdigest()[:16]}"


def _header(ident: dict, data: bytes) -> bytes:
    """The first bytes of a program file: a magic line, then one JSON line with the key the
    program was compiled for and the size and SHA-256 of ``data`` (the pickled executable)."""
    head = {"key": ident, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    return _MAGIC + json.dumps(head, sort_keys=True).encode() + b"\n"


def _read(path, ident: dict) -> bytes | None:
    """The pickled executable in ``path`` if its header is ``ident`` and its bytes match the
    header's checksum; None when the file is absent, and (counted as rejected) when it is
    anything else -- another key, another format, damaged."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError:
        return None
    try:
        line, _, data = raw[len(_MAGIC):].partition(b"\n")
        head = json.loads(line) if raw.startswith(_MAGIC) else None
        if (isinstance(head, dict) and head.get("key") == ident and head.get("bytes") == len(data)
                and head.get("sha256") == hashlib.sha256(data).hexdigest()):
            return data
    except ValueError:  # not JSON, not UTF-8
        pass
    stats["rejected"] += 1
    return None


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
    """``jax.jit`` with compiled programs kept on disk (:class:`Program`); usable as ``@jit``
    and ``@partial(jit, static_argnums=0)``."""
    if fun is None:
        return functools.partial(jit, static_argnums=static_argnums, compiler_options=compiler_options)
    return Program(fun, static_argnums, compiler_options)

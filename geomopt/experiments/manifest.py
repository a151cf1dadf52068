"""What produced a result: versions, the machine, configurations and content hashes.

Every JSON geomopt writes carries :func:`versions` (cheap: package metadata only, JAX is not
imported); a comparison's manifest adds :func:`environment` (CPU, threads, JAX devices),
:func:`config` of every solver (its full, nested configuration) and :func:`array_hash` of the
mesh and start map, so that a published table can be reproduced or questioned.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import os
import platform
import sys
from pathlib import Path

import numpy as np

__all__ = ["SCHEMA_VERSION", "versions", "environment", "config", "array_hash", "file_hash"]

#: version of the layout of geomopt's JSON outputs (``--json``, compare's manifest.json); it
#: changes when a key is renamed or removed or its meaning changes, not when one is added
SCHEMA_VERSION = 2

_PACKAGES = ("jax", "jaxlib", "numpy", "scipy", "optimistix", "equinox", "py-mkl-pardiso", "cholespy",
             "scikit-sparse", "matplotlib", "meshio")
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "XLA_FLAGS",
                     "JAX_PLATFORMS", "GEOMOPT_CACHE_DIR")


def versions() -> dict:
    """``{"geomopt": ..., "python": ..., "jax": ..., ...}``: the installed versions (None for a
    package that is not installed), read from package metadata without importing anything."""
    from importlib import metadata

    from .._version import __version__

    out = {"geomopt": __version__, "python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment() -> dict:
    """The machine and process a timing was taken on: OS, CPU model, logical CPUs and those this
    process may run on, thread-count variables, JAX's backend and devices, the load, the
    command line and the sparse Cholesky backends installed."""
    import jax

    from ..linalg.linsolve import available_backends

    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        load = None
    return {
        "platform": platform.platform(), "machine": platform.machine(), "cpu": _cpu_model(),
        "logical_cpus": os.cpu_count(), "usable_cpus": affinity, "load_average": load,
        "thread_variables": {k: os.environ[k] for k in _THREAD_VARIABLES if k in os.environ},
        "jax_backend": jax.default_backend(), "jax_devices": [str(d) for d in jax.devices()],
        "jax_x64": bool(jax.config.jax_enable_x64), "executable": sys.executable, "argv": list(sys.argv),
        "sparse_cholesky_backends": available_backends(),  # linear_solver="auto" takes the first
    }


def config(obj, depth: int = 0):
    """A JSON-able record of a configuration object: dataclasses (geomopt's solvers and
    searches, equinox modules such as optimistix's solvers) field by field, recursively, with
    their type; enums by value; functions by qualified name; small arrays as lists."""
    if depth > 8:
        return repr(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out = {"type": f"{type(obj).__module__}.{type(obj).__qualname__}"}
        for f in dataclasses.fields(obj):
            if not f.name.startswith("_"):
                out[f.name] = config(getattr(obj, f.name, None), depth + 1)
        return out
    if isinstance(obj, enum.Enum):
        return obj.value
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else repr(obj)
    if isinstance(obj, (tuple, list)):
        return [config(v, depth + 1) for v in obj]
    if isinstance(obj, dict):
        return {str(k): config(v, depth + 1) for k, v in obj.items()}
    if hasattr(obj, "shape") and hasattr(obj, "dtype"):
        a = np.asarray(obj)
        return a.tolist() if a.size <= 16 else f"array{a.shape} {a.dtype}"
    if isinstance(obj, np.generic):
        return obj.item()
    if callable(obj):
        return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', type(obj).__name__)}"
    return repr(obj)


def array_hash(*arrays) -> str:
    """sha256 (hex) of the arrays' bytes as little-endian float64 (floats) / int64 (integers),
    in order, each preceded by its shape: the same mesh gives the same hash whatever the file."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.asarray(a)
        a = a.astype("<f8" if a.dtype.kind == "f" else "<i8")
        h.update(repr(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def file_hash(path) -> str:
    """sha256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(Path(path), "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()

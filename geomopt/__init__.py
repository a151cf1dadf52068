"""geomopt: locally injective maps of triangle and tetrahedral meshes in JAX.

geomopt computes in float64 whatever JAX's global ``jax_enable_x64`` says: its functions switch
JAX's 64-bit mode on for their own duration (:mod:`geomopt._runtime.x64`), and importing geomopt leaves
the global flag alone, so float32 code keeps its dtypes beside it.  Traced use (``jax.grad`` of
``Objective.value``, a driver on traced inputs) needs the 64-bit mode in the caller's
transformation (``with jax.enable_x64(True):``).  Importing geomopt turns on JAX's persistent
compilation cache, shared with the ``geomopt`` command: see
:func:`set_cache_dir` to move or disable it (or the ``GEOMOPT_CACHE_DIR`` environment
variable).  The import is light: JAX and the solvers load when a name that needs them is
first used.
"""

from ._version import __version__  # noqa: E402

from ._runtime import cache as _cache  # noqa: E402

_cache.configure()

from ._runtime.cache import cache_dir, cache_stats, set_cache_dir  # noqa: E402
from ._runtime.errors import (GeomoptError, GeomoptWarning, MaxStepsWarning, MeshError, MeshFormatError,
    NotPositiveDefinite, ParameterError, SolveError)

# public name -> module that defines it (imported on first use, PEP 562)
_LAZY = {
    "Objective": ".objective.objective", "parameterize": ".param", "Problem": ".mesh.problem",
    "AQP": ".solvers", "CM": ".solvers", "LBFGS": ".solvers", "SLIM": ".solvers", "Newton": ".solvers",
    "Outcome": ".solvers", "Result": ".solvers", "minimize": ".solvers", "smooth": ".smoothing",
    "tutte_embedding": ".mesh.tutte", "compare": ".experiments.comparison", "Comparison": ".experiments.comparison",
    "compare_meshes": ".experiments.comparison", "ComparisonSet": ".experiments.comparison", "sphere_map": ".sphere",
    "make_atlas": ".atlas", "untangle": ".untangling", "fair": ".fairing", "save": ".plot._save",
    # the drivers' options (one calling convention: data by position, settings in these)
    "ParamOptions": ".param", "SphereOptions": ".sphere", "AtlasOptions": ".atlas", "UntangleOptions": ".untangling",
    "SmoothOptions": ".smoothing", "CompareOptions": ".experiments.options",
    "FairOptions": ".fairing",
}
# public submodules reachable as attributes without an import of their own (imported on first use):
# the layers from the bottom up, then the drivers and the outputs on top
_SUBMODULES = ("exact", "io", "linalg", "mesh", "energies", "objective", "solvers", "param", "untangling", "smoothing",
               "sphere", "atlas", "fairing", "lim", "experiments", "plot", "data", "cli")


def __getattr__(name):
    import importlib

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module("." + name, __name__)
    else:
        raise AttributeError(f"module 'geomopt' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | set(_SUBMODULES))


# every public name above: the errors and cache functions imported here, the lazy names, the
# submodules (tests/test_api_names.py checks that nothing else is public)
__all__ = [
    "__version__", "GeomoptError", "MeshError", "MeshFormatError", "ParameterError", "SolveError", "GeomoptWarning",
    "MaxStepsWarning", "NotPositiveDefinite", "set_cache_dir", "cache_dir", "cache_stats", *_LAZY, *_SUBMODULES,
]

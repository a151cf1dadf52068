"""geomopt's public names: ``geomopt.__all__`` lists exactly what the package exports (the
names ``import geomopt`` makes public, eagerly or on first use), each resolves, the drivers are
top-level functions, and the names removed after their deprecation stay removed (issue 32)."""

from __future__ import annotations

import inspect
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import geomopt

REPO = Path(__file__).resolve().parents[1]


def test_all_is_exactly_the_public_namespace_of_a_fresh_import():
    """In a fresh interpreter (no other import has added a submodule as an attribute) the public
    names of ``dir(geomopt)`` are ``__all__``, no name twice, and nothing heavy is loaded."""
    code = ("import json, sys, geomopt\n"
            "print(json.dumps([sorted(n for n in dir(geomopt) if not n.startswith('_')), geomopt.__all__,\n"
            "                  sorted(m for m in sys.modules if m.startswith('geomopt.'))]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=str(REPO),
                          env={**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": "off"})
    assert proc.returncode == 0, proc.stderr
    public, names, loaded = json.loads(proc.stdout)
    assert len(names) == len(set(names)), "a name is listed twice in geomopt.__all__"
    assert sorted(set(names) - {"__version__"}) == public
    assert "__version__" in names
    assert loaded == ["geomopt._runtime", "geomopt._runtime.cache", "geomopt._runtime.errors",
                      "geomopt._version"]  # the import stays cheap


@pytest.mark.parametrize("name", geomopt.__all__)
def test_each_exported_name_resolves(name):
    """Submodules resolve to themselves, every other name to what its module defines."""
    value = getattr(geomopt, name)
    if name in geomopt._SUBMODULES:
        assert inspect.ismodule(value) and value.__name__ == f"geomopt.{name}"
    elif name == "__version__":
        assert isinstance(value, str) and value
    else:
        assert not inspect.ismodule(value) and getattr(value, "__name__", name) == name


def test_star_import_gives_exactly_all():
    namespace: dict = {}
    exec("from geomopt import *", namespace)
    assert set(namespace) - {"__builtins__"} == set(geomopt.__all__)


def test_smooth_is_a_top_level_driver_returning_the_common_result():
    """``geomopt.smooth`` is the function (like ``geomopt.parameterize``), not a module, also
    after its module is imported; it returns the Result of every driver, its details typed."""
    import geomopt.smoothing

    assert inspect.isfunction(geomopt.smooth) and geomopt.smooth is geomopt.smoothing.smooth
    assert "smooth" in geomopt.__all__ and "smoothing" in geomopt.__all__
    V, E = geomopt.mesh.generators.sector_mesh(2, 4, perturb=0.3, seed=3)
    res = geomopt.smooth(V, E)
    assert type(res) is geomopt.Result and isinstance(res.details, geomopt.smoothing.SmoothDetails)
    assert isinstance(res.details, geomopt.solvers.Details)
    assert res.success and res.details.improved and res.certificate.handles_moved == 0
    assert res.stats.outer_iterations == 1 and res.stats.iterations > 0 and res.mean_energy > 0
    assert res.details.after.min > res.details.before.min and res.details.elements.certified


def test_removed_names_stay_removed():
    """The ``tetio`` shim and the ``SmoothResult`` name were removed (``geomopt.io.read_tets`` /
    ``write_tets``; :class:`~geomopt.solvers.Result`)."""
    import geomopt.smoothing

    modules = {m.name for m in pkgutil.iter_modules(geomopt.__path__)}
    assert "smoothing" in modules and "tetio" not in modules
    assert "smooth" not in modules  # the function's name is not also a module's (an import would rebind it)
    assert not hasattr(geomopt.smoothing, "SmoothResult") and "tetio" not in dir(geomopt)
    # removed in 0.2 (the CHANGELOG says what to use): the implicit shim, the old module paths
    assert "implicit" not in modules and "implicit" not in dir(geomopt) and "predicates" not in dir(geomopt)
    for name in ("implicit", "predicates", "linsolve"):
        with pytest.raises(AttributeError, match=f"no attribute '{name}'"):
            getattr(geomopt, name)
    assert not hasattr(geomopt.mesh.problem, "check_initial_orientation")  # geomopt.mesh.orientation's
    import geomopt.lim

    assert not any(hasattr(geomopt.lim, n) for n in ("read_lim_case", "lim_case_dim", "lim_cases"))  # LimCase's

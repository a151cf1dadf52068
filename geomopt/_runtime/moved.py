"""Old module paths (before the layers became folders, geomopt 0.9) keep working for one
release: ``import geomopt.predicates`` gives :mod:`geomopt.exact.predicates` itself (the same
module object, so its names, private ones included, and monkeypatching behave as before) and
warns once with a ``DeprecationWarning`` naming the new path.  Removed in the next release."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

#: old dotted path -> new dotted path
MOVED = {
    "geomopt._cache": "geomopt._runtime.cache", "geomopt._programs": "geomopt._runtime.programs",
    "geomopt._x64": "geomopt._runtime.x64", "geomopt._tracing": "geomopt._runtime.tracing",
    "geomopt._hostcall": "geomopt._runtime.hostcall", "geomopt._timing": "geomopt._runtime.timing",
    "geomopt._config": "geomopt._runtime.config", "geomopt._padding": "geomopt._runtime.padding",
    "geomopt._names": "geomopt._runtime.names", "geomopt._validate": "geomopt._runtime.validate",
    "geomopt._errors": "geomopt._runtime.errors",
    "geomopt.predicates": "geomopt.exact.predicates", "geomopt.topology": "geomopt.exact.topology",
    "geomopt.stars": "geomopt.exact.stars", "geomopt.hexvalid": "geomopt.exact.hexvalid",
    "geomopt.certify": "geomopt.exact.certify",
    "geomopt.problem": "geomopt.mesh.problem", "geomopt.elements": "geomopt.mesh.elements",
    "geomopt.cells": "geomopt.mesh.cells", "geomopt.generators": "geomopt.mesh.generators",
    "geomopt.tutte": "geomopt.mesh.tutte", "geomopt._geometry": "geomopt.mesh.geometry",
    "geomopt.quality": "geomopt.mesh.quality",
    "geomopt._objective": "geomopt.objective.objective", "geomopt._projection": "geomopt.objective.projection",
    "geomopt._eigh": "geomopt.linalg.eigh", "geomopt.linsolve": "geomopt.linalg.linsolve",
    "geomopt._cg": "geomopt.objective.cg", "geomopt._gauge": "geomopt.objective.gauge",
    "geomopt.linesearch": "geomopt.solvers.linesearch",
    "geomopt._compare": "geomopt.experiments.comparison", "geomopt._compare_report": "geomopt.experiments.report",
    "geomopt._manifest": "geomopt.experiments.manifest", "geomopt.batch": "geomopt.experiments.batch",
    "geomopt.atlas.command": "geomopt.cli.atlas", "geomopt.starts": "geomopt.untangling.start",
    "geomopt.untangle": "geomopt.untangling",
}
#: old module paths that are now also the name of a top-level function (``geomopt.untangle``):
#: importing the old path binds ``geomopt.<name>`` to the module, so the module is made callable
#: as that function and ``geomopt.untangle(problem, x0)`` keeps working after such an import
CALLABLE = {"geomopt.untangle": "untangle"}


class _CallableModule(types.ModuleType):
    """A module that calls its function named in :data:`CALLABLE` when called."""

    def __call__(self, *args, **kwargs):
        return getattr(self, self.__dict__["_called_as_function"])(*args, **kwargs)


class _Redirect(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old paths (only those) and loads them as the new module, with a warning."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        warnings.warn(f"{spec.name} moved to {MOVED[spec.name]}; the old path will be removed in the next "
                      f"release", DeprecationWarning, stacklevel=2)
        module = importlib.import_module(MOVED[spec.name])
        if spec.name in CALLABLE:
            module._called_as_function = CALLABLE[spec.name]
            module.__class__ = _CallableModule
        spec.loader_state = module.__spec__  # the import system overwrites it: exec_module restores it
        return module

    def exec_module(self, module):
        """Nothing to run (the module is the new one, already executed); the import system set
        its ``__spec__`` to the old path's, put the module's own back."""
        module.__spec__ = module.__spec__.loader_state


def install() -> None:
    """Append the redirect to ``sys.meta_path`` once (the regular finders come first, so a
    module that exists at an old path is never shadowed)."""
    if not any(isinstance(f, _Redirect) for f in sys.meta_path):
        sys.meta_path.append(_Redirect())


def moved(name: str) -> str | None:
    """The new dotted path of top-level ``geomopt.<name>`` if it moved, else ``None``."""
    return MOVED.get(f"geomopt.{name}")

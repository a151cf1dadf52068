"""Attribute access to a package's submodules on first use (PEP 562), so that ``import geomopt``
and ``import geomopt.exact`` stay cheap while ``geomopt.exact.predicates`` works without an
import of its own."""

from __future__ import annotations

import importlib


def submodules(package: str, names: tuple[str, ...], attributes: dict[str, str] | None = None):
    """``(__getattr__, __dir__)`` for ``package`` that import ``package.<name>`` when a name in
    ``names`` is first read, and give ``attributes[name]``'s attribute ``name`` (a submodule's
    class or function re-exported by the package) likewise."""
    attributes = attributes or {}

    def __getattr__(name):
        if name in names:
            return importlib.import_module(f"{package}.{name}")
        if name in attributes:
            return getattr(importlib.import_module(f"{package}.{attributes[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted(set(importlib.import_module(package).__dict__) | set(names) | set(attributes))

    return __getattr__, __dir__

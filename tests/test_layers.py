"""The layers of geomopt are folders, imports only point down, and no import closes a circle
(issues 32 and 49).

Every ``import`` in every module of the package (at the top or inside a function: a lazy
import is still a dependency) is read with :mod:`ast`; each module belongs to the first layer
whose prefix it has, and no module may import one of a higher layer, nor, through any chain of
imports, itself.  The layers, bottom up: the runtime plumbing, exact predicates and file
formats, linear algebra, mesh problems, energies and the objective, the solvers, the drivers,
and the outputs and tools on top.  Only ``import geomopt`` (the package, whose ``__init__``
re-exports lazily) may be named from below: ``Result.save`` forwards to ``geomopt.save``."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "geomopt"

LAYERS = [
    ("runtime", ("geomopt._runtime", "geomopt._version")),
    ("exact and formats", ("geomopt.exact", "geomopt.io")),
    ("linear algebra", ("geomopt.linalg",)),
    ("mesh", ("geomopt.mesh",)),
    ("objective", ("geomopt.energies", "geomopt.objective")),
    ("solvers", ("geomopt.solvers",)),
    ("drivers", ("geomopt.param", "geomopt.bijective", "geomopt.smoothing", "geomopt.sphere", "geomopt.untangling",
                 "geomopt.optax", "geomopt.lim", "geomopt.atlas", "geomopt.fairing")),
    ("outputs and tools", ("geomopt.experiments", "geomopt.plot", "geomopt.data", "geomopt.cli", "geomopt.__main__",
                           "geomopt")),
]
DRIVERS = [name for name, _ in LAYERS].index("drivers")
#: the imports allowed to point up, each with why: none
UPWARD_ALLOWED: set = set()


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> int:
    for i, (_, prefixes) in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return i
    raise AssertionError(f"{module} is in no layer: add it to LAYERS in {__file__}")


def imports(path: Path) -> set[str]:
    """The geomopt modules (or packages) ``path`` imports, as absolute dotted names."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:  # ``from geomopt.exact import predicates`` imports the submodule
                sub = f"{target}.{alias.name}"
                is_module = (PACKAGE.parent / sub.replace(".", "/")).with_suffix(".py").exists() or \
                    (PACKAGE.parent / sub.replace(".", "/")).is_dir()
                found.add(sub if is_module else target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {m for m in found if m == "geomopt" or m.startswith("geomopt.")}


MODULES = sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", MODULES, ids=[module_name(p) for p in MODULES])
def test_imports_only_point_down(path):
    name = module_name(path)
    upward = [(target, LAYERS[layer(target)][0]) for target in sorted(imports(path))
              if layer(target) > layer(name) and (name, target) not in UPWARD_ALLOWED
              and not (target == "geomopt" and name.startswith("geomopt."))]
    assert not upward, f"{name} (layer {LAYERS[layer(name)][0]!r}) imports from a higher layer: {upward}"


def import_graph(paths) -> dict:
    """Module -> the geomopt modules it imports (:func:`imports`), for the modules at ``paths``."""
    return {module_name(p): imports(p) for p in paths}


def circle(graph: dict) -> list | None:
    """One circle of imports in ``graph`` as ``[a, b, ..., a]`` (``a`` imports ``b``...), or None.
    A depth-first walk; a package's ``__init__`` is a module like any other, so a module that
    imports its own package's re-exports, which import it, is a circle."""
    state = {}  # 1: on the current path, 2: every chain from it walked
    for root in sorted(graph):
        if root in state:
            continue
        path, stack, state[root] = [root], [iter(sorted(graph[root]))], 1
        while stack:
            for child in stack[-1]:
                if child not in graph or state.get(child) == 2:
                    continue
                if state.get(child) == 1:
                    return path[path.index(child):] + [child]
                state[child] = 1
                path.append(child)
                stack.append(iter(sorted(graph[child])))
                break
            else:
                state[path.pop()] = 2
                stack.pop()
    return None


def test_no_import_closes_a_circle():
    found = circle(import_graph(MODULES))
    assert found is None, f"these modules import each other (lazily or not): {' -> '.join(found)}"


def test_the_circle_check_sees_lazy_circles_through_packages():
    """The checker itself: a lazy import that closes a circle, and a module importing its own
    package's ``__init__`` that imports it, are caught; a chain that only meets again is not."""
    assert circle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert circle({"a": {"b", "c"}, "b": {"d"}, "c": {"d"}, "d": set()}) is None
    probe, package = PACKAGE / "exact" / "_circle_probe_tmp.py", PACKAGE / "exact" / "__init__.py"
    try:
        probe.write_text("def _probe():\n    from . import predicates\n    from .predicates import orient2d\n")
        graph = import_graph(MODULES + [probe])
        assert circle(graph) is None  # one-way
        probe.write_text("def _probe():\n    from . import certify_bijective\n")  # a name the package re-exports
        graph = import_graph(MODULES + [probe])
        graph["geomopt.exact"] = graph["geomopt.exact"] | {"geomopt.exact._circle_probe_tmp"}  # as if it re-exported it
        assert circle(graph) == ["geomopt.exact", "geomopt.exact._circle_probe_tmp", "geomopt.exact"]
    finally:
        probe.unlink()


def test_the_walk_sees_lazy_and_relative_imports(tmp_path):
    """The checker itself: an upward import inside a function, written relative, is caught."""
    assert layer("geomopt.exact.predicates") < layer("geomopt.mesh.problem") < layer("geomopt.solvers._iterate")
    source = PACKAGE / "exact" / "predicates.py"
    text = source.read_text() + "\n\ndef _probe():\n    from ..solvers import Newton\n"
    fake = PACKAGE / "exact" / "_layer_probe_tmp.py"
    try:
        fake.write_text(text)
        assert "geomopt.solvers" in imports(fake) and layer("geomopt.solvers") > layer(module_name(fake))
    finally:
        fake.unlink()


def test_no_module_left_flat_but_the_drivers_and_outputs():
    """The infrastructure lives in folders: the flat modules are the drivers and outputs only."""
    flat = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__", "__main__", "_version"}  # (read by the build)
    for stem in flat:
        assert layer(f"geomopt.{stem}") >= DRIVERS, \
            f"geomopt/{stem}.py is a lower layer's module: move it into its folder"


@pytest.mark.parametrize("old", ["geomopt.predicates", "geomopt.linsolve", "geomopt._objective", "geomopt.untangle",
                                 "geomopt.implicit"])
def test_the_old_module_paths_are_gone(old):
    """The module paths before the layers became folders (deprecated, removed in 0.2.0: the
    CHANGELOG lists the new ones) are not importable, and ``geomopt.untangle`` is the function."""
    import importlib
    import sys

    import geomopt

    sys.modules.pop(old, None)
    with pytest.raises(ModuleNotFoundError, match=f"No module named '{old}'"):
        importlib.import_module(old)
    assert not any(type(f).__module__.startswith("geomopt") for f in sys.meta_path)
    assert callable(geomopt.untangle) and geomopt.untangle.__module__ == "geomopt.untangling.driver"

"""The layers of geomopt are folders, and imports only point down (issue 32).

Every ``import`` in every module of the package (at the top or inside a function: a lazy
import is still a dependency) is read with :mod:`ast`; each module belongs to the first layer
whose prefix it has, and no module may import one of a higher layer.  The layers, bottom up:
the runtime plumbing, exact predicates and file formats, mesh problems, energies and the
objective, the solvers, the drivers, and the outputs and tools on top."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "geomopt"

LAYERS = [
    ("runtime", ("geomopt._runtime", "geomopt._version")),
    ("exact and formats", ("geomopt.exact", "geomopt.io")),
    ("mesh", ("geomopt.mesh",)),
    ("objective", ("geomopt.energies", "geomopt.objective")),
    ("solvers", ("geomopt.solvers",)),
    ("drivers", ("geomopt.param", "geomopt.bijective", "geomopt.smoothing", "geomopt.sphere", "geomopt.untangling",
                 "geomopt.optax", "geomopt.lim", "geomopt.atlas", "geomopt.fairing")),
    ("outputs and tools", ("geomopt.experiments", "geomopt.plot", "geomopt._render", "geomopt._compose",
                           "geomopt._view", "geomopt._save", "geomopt.data", "geomopt.cli", "geomopt.__main__",
                           "geomopt")),
]
#: the imports that point up, lazily, with why: ``Result.save`` is the convenience that hands a
#: result to the writers (files and figures) on top; the Tutte map's symmetric system is factored
#: by the sparse Cholesky the Newton step uses (``linsolve`` imports nothing of geomopt but the
#: runtime's errors), not by SciPy's SuperLU, which is 3x slower and whose import costs 40 ms
UPWARD_ALLOWED = {("geomopt.solvers._result", "geomopt._save"), ("geomopt.mesh.tutte", "geomopt.objective.linsolve")}


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
        assert layer(f"geomopt.{stem}") >= 5, f"geomopt/{stem}.py is a lower layer's module: move it into its folder"


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

"""mkdocs hook: one API page per public module of geomopt, generated at build time.

A module is public when no part of its dotted name starts with ``_``.  The top-level page
documents the names ``geomopt`` re-exports (``geomopt.__all__``) where they are defined.  New
modules get a page without editing anything here; ``mkdocs build --strict`` fails on any
docstring cross-reference that does not resolve.
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "geomopt"
NOTEBOOKS = ROOT / "notebooks"


def public_modules() -> list[str]:
    """Dotted names of geomopt's public modules and packages, sorted."""
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(p.startswith("_") for p in parts[1:]) or "__pycache__" in parts:
            continue
        names.append(".".join(parts))
    return names


def _public_home(obj):
    """The public module whose ``__all__`` lists ``obj`` (its API page renders it), or None."""
    for name in public_modules():
        module = importlib.import_module(name)
        if name != "geomopt" and any(getattr(module, n, None) is obj for n in getattr(module, "__all__", ())):
            return name
    return None


def _top_level_page() -> str:
    """``geomopt``'s own docstring, then each re-exported name: a link to the page of the public
    module that documents it, or rendered here when only private modules define it."""
    import geomopt

    lines = ["# geomopt", "", "::: geomopt", "    options:", "      members: false",
             "      show_root_heading: false", "", "## Names exported by `geomopt`", ""]
    rendered = []
    for name in geomopt.__all__:
        obj = getattr(geomopt, name)
        if inspect.ismodule(obj):
            lines.append(f"- [`geomopt.{name}`][{obj.__name__}]: module")
            continue
        if not hasattr(obj, "__module__"):
            continue
        home = _public_home(obj)
        if home is not None:
            lines.append(f"- [`geomopt.{name}`][{home}.{name}] (documented in `{home}`)")
        else:
            lines.append(f"- [`geomopt.{name}`][{obj.__module__}.{name}]")
            rendered += [f"::: {obj.__module__}.{name}", "    options:", "      show_root_heading: true",
                         "      show_root_full_path: false", ""]
    return "\n".join(lines + [""] + rendered)


def _module_page(name: str) -> str:
    return f"# {name}\n\n::: {name}\n    options:\n      show_root_heading: false\n"


def _page(name: str) -> str:
    return "api/" + name.replace(".", "/") + ".md" if name != "geomopt" else "api/index.md"


def notebooks() -> list[Path]:
    """The notebooks of ``notebooks/``, each a page of the site (rendered by mkdocs-jupyter)."""
    return sorted(NOTEBOOKS.glob("*.ipynb"))


def _title(path: Path) -> str:
    return path.stem.split("_", 1)[-1].replace("_", " ").capitalize()


def on_config(config):
    api = [{name: _page(name)} for name in public_modules()]
    gallery = [{_title(p): "notebooks/" + p.name} for p in notebooks()]
    config["nav"] = [{"Home": "index.md"}, {"Notebooks": gallery}, {"API reference": api},
                     {"References": "references.md"}, {"Untangling: design notes": "untangling.md"},
                     {"Changelog": "changelog.md"}]
    return config


@event_priority(50)  # before mkdocs-jupyter's on_files, which turns the notebooks into pages
def on_files(files, config):
    importlib.invalidate_caches()
    for name in public_modules():
        content = _top_level_page() if name == "geomopt" else _module_page(name)
        files.append(File.generated(config, _page(name), content=content))
    for path in notebooks():
        files.append(File("notebooks/" + path.name, str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files

"""Documentation that cannot rot: README's Python runs as written, the API site builds with
``--strict`` (every docstring cross-reference resolves), every public module declares
``__all__``, and every paper the code cites is in the bibliography."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def python_blocks(markdown: str) -> list[str]:
    """The fenced ```python blocks of a Markdown text, in order."""
    return re.findall(r"^```python\n(.*?)^```", markdown, flags=re.S | re.M)


def public_modules() -> list[str]:
    """geomopt's public modules: no part of the dotted name starts with ``_``."""
    names = []
    for path in sorted((ROOT / "geomopt").rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if not any(p.startswith("_") for p in parts[1:]):
            names.append(".".join(parts))
    return names


def test_readme_python_runs_as_written(tmp_path, monkeypatch):
    blocks = python_blocks(README)
    assert len(blocks) >= 3, "README.md lost its Python examples"
    monkeypatch.chdir(tmp_path)  # the examples write files (compare's out folder)
    namespace = {"__name__": "__readme__"}
    for k, block in enumerate(blocks):
        try:
            exec(compile(block, f"README.md python block {k + 1}", "exec"), namespace)
        except Exception as exc:  # say which block failed, then the traceback
            raise AssertionError(f"README.md python block {k + 1} fails as written:\n{block}") from exc


@pytest.mark.parametrize("name", public_modules())
def test_public_module_declares_all(name):
    module = importlib.import_module(name)
    assert hasattr(module, "__all__"), f"{name} has no __all__: list its public names"
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ names {missing}, which {name} does not define"


def modules_with_examples() -> list[str]:
    """geomopt's modules (private ones too) whose docstrings hold ``>>>`` examples."""
    names = []
    for path in sorted((ROOT / "geomopt").rglob("*.py")):
        if ">>>" in path.read_text(encoding="utf-8"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


@pytest.mark.parametrize("name", modules_with_examples())
def test_docstring_examples_run_as_written(name, tmp_path, monkeypatch):
    """Every ``Examples`` section is a doctest: its output is what the code prints."""
    import doctest

    monkeypatch.chdir(tmp_path)  # examples may write files
    module = importlib.import_module(name)
    failed, tried = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                                    report=True, verbose=False)
    assert tried and not failed, f"{failed} of {tried} docstring example(s) of {name} fail (see the output)"


def _references() -> list[str]:
    section = README.split("## References", 1)[1]
    return [entry for entry in re.split(r"\n- ", section)[1:]]


def test_every_cited_paper_is_in_the_bibliography():
    """Each "Author et al. YEAR" / "Author & Author YEAR" in the code has a full reference in
    README's References (and so in the docs, which include that section)."""
    cite = re.compile(r"\b([A-Z][a-zé]+)(?: et al\.,?| & [A-Z][a-zé]+,?| and [A-Z][a-zé]+,?"
                      r"|, [A-Z][a-z]+(?:,? (?:&|and) [A-Z][a-z]+)?) \(?((?:19|20)\d\d)\b")
    entries = _references()
    assert len(entries) >= 20
    missing = set()
    for path in (ROOT / "geomopt").rglob("*.py"):
        for author, year in cite.findall(path.read_text(encoding="utf-8")):
            if not any(author in e and year in e for e in entries):
                missing.add(f"{author} {year} ({path.relative_to(ROOT)})")
    assert not missing, ("cited in the code but missing from README.md's References (add the full "
                         "reference): " + "; ".join(sorted(missing)))


def test_citation_file_and_license():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    for key in ("cff-version", "message", "title", "authors", "version", "license"):
        assert cff.get(key), f"CITATION.cff lacks {key}"
    import geomopt

    assert str(cff["version"]) == geomopt.__version__, "CITATION.cff's version is not geomopt.__version__"
    assert "MIT License" in (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert re.search(r'license = \{ text = "MIT" \}', (ROOT / "pyproject.toml").read_text())


def test_bundled_data_has_its_attribution():
    import geomopt

    V, F = geomopt.data.load("camelhead")
    assert V.shape == (11381, 3) and F.shape == (22704, 3)
    sources = (ROOT / "geomopt" / "data" / "SOURCES.md").read_text(encoding="utf-8")
    assert "Sorkine" in sources and "camelhead.off" in sources
    with pytest.raises(geomopt.ParameterError, match="bundled meshes: camelhead"):
        geomopt.data.path("bunny")


def test_api_site_builds_strict(tmp_path):
    """``mkdocs build --strict``: a docstring that does not parse, a cross-reference that does
    not resolve, or a module that does not import fails the build."""
    for module in ("mkdocs", "material", "mkdocstrings_handlers.python", "mkdocs_jupyter"):
        if importlib.util.find_spec(module.split(".")[0]) is None:
            pytest.skip(f"{module} is not installed: pip install '.[docs]' to build the API docs")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
               NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(tmp_path / "site")], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=1200)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout}\n{proc.stderr}"
    site = tmp_path / "site"
    pages = {p.relative_to(site).as_posix() for p in site.rglob("index.html")}
    for name in public_modules():
        page = "api/index.html" if name == "geomopt" else "api/" + name.replace(".", "/") + "/index.html"
        assert page in pages, f"no API page for {name}"
    api = (site / "api" / "geomopt" / "param" / "index.html").read_text(encoding="utf-8")
    assert ":func:`" not in api and ":class:`" not in api  # Sphinx roles became links
    assert 'href="../solvers/#geomopt.solvers.Result"' in api  # ... that resolve
    assert "Rabinovich" in (site / "references" / "index.html").read_text(encoding="utf-8")
    for notebook in sorted((ROOT / "notebooks").glob("*.ipynb")):  # each a page, with its figures
        page = (site / "notebooks" / notebook.stem / "index.html").read_text(encoding="utf-8")
        assert "data:image/png" in page, f"the docs page of {notebook.name} shows no figure"
    # the fairing notebook is executed by the build itself (issue 52): the log says so
    assert re.search(r"Converting notebook \(execute=True\): \S*14_fairing\.ipynb", proc.stdout + proc.stderr)

"""Every notebook in notebooks/ runs top to bottom without error (examples cannot rot), is
stored executed with its figures inline, and uses only the public API."""

import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
#: what a notebook that teaches the public API must not do
PRIVATE = {r"geomopt\._": "imports a private module (geomopt._...)",
           r"__file__": "finds data through a module's __file__ (use geomopt.data)",
           r"\.info\[": "reads Result.info[...] (use the typed fields)",
           r"\.savefig\(|save_(layout|param_figure|convergence|untangle_figure)\(": "writes a picture file "
           "instead of showing the figure inline"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_executed_with_figures(path):
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.execution_count for c in code), f"{path.name}: run it and save it with its outputs"
    assert not [o for c in code for o in c.outputs if o.output_type == "error"], f"{path.name}: stored an error"
    assert any("image/png" in o.get("data", {}) for c in code for o in c.outputs), \
        f"{path.name}: no figure stored inline"
    for pattern, why in PRIVATE.items():
        bad = [c.source for c in code if re.search(pattern, c.source)]
        assert not bad, f"{path.name} {why}: {bad[0][:200]}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()


#: optional modules of geomopt's extras (pyproject.toml) a notebook may import
EXTRAS = {"dask": "batch", "distributed": "batch", "optax": "optax", "polyscope": "view", "pyvista": "view",
          "vtk": "view"}


def _imports(nb):
    src = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    return set(re.findall(r"^\s*(?:from|import)\s+([A-Za-z_]\w*)", src, re.M))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_a_notebook_that_needs_an_extra_says_so_in_its_first_cell(path):
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(path, as_version=4)
    for extra in sorted({EXTRAS[m] for m in _imports(nb) if m in EXTRAS}):
        assert f'pip install "geomopt[{extra}]"' in nb.cells[0].source, \
            f"{path.name} imports a module of the [{extra}] extra: say so in its first cell"


BATCH = [p for p in NOTEBOOKS if p.name.startswith("11_")]


@pytest.mark.parametrize("path", BATCH, ids=[p.name for p in BATCH])
def test_the_batch_notebook_runs_its_serial_path_without_dask(path, tmp_path, monkeypatch):
    """Without the [batch] extra (Dask distributed) the sweep runs one task after another."""
    import os

    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    for name in ("dask", "distributed"):  # packages that fail to import, first on the kernel's path
        (tmp_path / "blocked" / name).mkdir(parents=True)
        (tmp_path / "blocked" / name / "__init__.py").write_text(
            f"raise ModuleNotFoundError(\"No module named '{name}' (hidden by the test)\", name={name!r})\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path / "blocked"), os.environ.get("PYTHONPATH", "")]))
    nb = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "one after another" in text, text[-2000:]

"""Installs that the declared dependency floors allow must work (issue 19, install floors).

* The XLA option of geomopt's kernels is used only where the running jaxlib accepts it
  (jaxlib before 0.8.1 refused to compile every kernel with it).
* py-mkl-pardiso's private solver class is used only when it offers the calls geomopt makes;
  otherwise the next sparse Cholesky backend is taken.
* ``tests/install_floors.py`` installs the declared minimum versions into a fresh virtual
  environment and runs a subset of this suite there; it downloads packages and takes minutes,
  so it runs here only with ``GEOMOPT_TEST_INSTALL=1``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from geomopt.linalg import linsolve
from geomopt.objective import objective as _objective
from geomopt._runtime import programs as _programs

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def fresh_options():
    _programs.xla_options.cache_clear()
    yield
    _programs.xla_options.cache_clear()
    _programs.xla_options()  # probed again now, not inside a later test's cache-miss count


def test_xla_option_is_used_where_jaxlib_accepts_it(fresh_options):
    import jaxlib

    version = tuple(int(p) for p in jaxlib.__version__.split(".")[:3])
    assert _programs.xla_options() == (_programs.XLA_OPTIONS if version >= (0, 8, 1) else {})


def test_an_unknown_xla_option_is_left_out(fresh_options, monkeypatch):
    """What an older jaxlib sees: an option it does not know.  The probe leaves it out and every
    kernel still compiles and runs."""
    from geomopt import Objective, Problem
    from conftest import grid

    monkeypatch.setattr(_programs, "XLA_OPTIONS", {"xla_geomopt_no_such_option_for_the_test": ""})
    assert _programs.xla_options() == {}
    V, F = grid(4)
    obj = Objective(Problem.planar(V, F), "symmetric_dirichlet")
    kernel = _objective.jit(lambda x: (x * 2.0).sum())  # a kernel made now compiles without it
    assert float(kernel(np.ones(3))) == 6.0
    assert np.isfinite(float(obj.value(V * 1.1, obj.params())))


def test_every_kept_program_compiles_with_the_xla_options(fresh_options):
    """The solvers' own loops (L-BFGS, the injective search, untangling's statistics) are kept
    programs too: without the option L-BFGS's loop ran 1.9x slower per iteration once its
    vectors passed 16,384 entries."""
    import importlib

    names = ("geomopt.solvers.lbfgs", "geomopt.solvers.linesearch", "geomopt.untangling.continuation",
             "geomopt.objective.objective", "geomopt.energies._energy", "geomopt.objective.cg", "geomopt.objective.adjoint")
    kinds = (_programs.Program, type(_objective.energy_kernel))  # a Program, or one made at first call
    programs = [p for n in names for p in vars(importlib.import_module(n)).values() if isinstance(p, kinds)]
    assert len(programs) >= 10
    for program in programs:
        assert program.options == _programs.xla_options(), program.__name__


@pytest.fixture
def pardiso_without_entry_point(monkeypatch):
    """A py-mkl-pardiso whose library does not export ``PARDISO_64`` (another layout or build):
    here the C library stands in for its extension."""
    import ctypes.util

    from geomopt.linalg import pardiso

    fake = types.ModuleType("pymklpardiso._mkl_pardiso")
    fake.__file__ = ctypes.util.find_library("c") or "libc.so.6"
    pkg = types.ModuleType("pymklpardiso")
    pkg._mkl_pardiso = fake
    monkeypatch.setitem(sys.modules, "pymklpardiso", pkg)
    monkeypatch.setitem(sys.modules, "pymklpardiso._mkl_pardiso", fake)
    pardiso.entry_point.cache_clear()
    yield
    pardiso.entry_point.cache_clear()


def test_pardiso_without_its_entry_point_goes_through_the_wheels_class(monkeypatch):
    """A build of py-mkl-pardiso whose library exports no ``PARDISO_64`` (e.g. a Windows DLL)
    but has its Python class: PARDISO still factors, in float64, through that class."""
    from geomopt.linalg import pardiso

    if pardiso.entry_point() is None or not pardiso.available():
        pytest.skip("needs the py-mkl-pardiso wheel")
    monkeypatch.setattr(pardiso, "entry_point", lambda: None)
    import scipy.sparse as sp

    A = sp.diags([4.0] * 50) + sp.diags([1.0] * 49, -1) + sp.diags([1.0] * 49, 1)
    L = sp.tril(A).tocsc()
    chol = linsolve.SparseCholesky(L.indptr, L.indices, "pardiso", single=True)
    assert not chol.single  # float32 needs the direct call
    chol.factor(L.data)
    assert isinstance(chol._analysis, pardiso.WheelPardiso)
    b = np.arange(50.0)
    np.testing.assert_allclose(A @ chol.solve(b), b, atol=1e-12)
    np.testing.assert_allclose(A @ chol.precondition(b), b, atol=1e-12)
    with pytest.raises(linsolve.NotPositiveDefinite):
        chol.factor(-L.data)
    chol.free_factor()


@pytest.mark.skipif(sys.platform != "linux", reason="stands the C library in for the extension (Linux)")
def test_pardiso_without_its_entry_point_falls_back(pardiso_without_entry_point):
    backends = linsolve.available_backends()
    assert "pardiso" not in backends and backends[-1] == "superlu"
    # auto takes the next backend and solves
    import scipy.sparse as sp

    A = sp.diags([4.0] * 5) + sp.diags([1.0] * 4, -1)
    L = sp.tril(A).tocsc()
    chol = linsolve.SparseCholesky(L.indptr, L.indices)
    assert chol.backend == backends[0]
    chol.factor(L.data)
    b = np.arange(5.0)
    np.testing.assert_allclose((A + A.T - sp.diags(A.diagonal())) @ chol.solve(b), b)
    with pytest.raises(Exception, match="not installed here"):
        linsolve.SparseCholesky(L.indptr, L.indices, backend="pardiso")


@pytest.mark.skipif(not os.environ.get("GEOMOPT_TEST_INSTALL"),
                    reason="downloads the declared minimum versions (minutes): set GEOMOPT_TEST_INSTALL=1")
def test_declared_minimum_versions_install_and_work(tmp_path):
    out = subprocess.run([sys.executable, str(ROOT / "tests" / "install_floors.py"), "--venv", str(tmp_path / "venv")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]


def test_ci_runs_the_floor_check():
    """The floors stay true only if something runs them: CI's script does, after the suite."""
    lines = [l.strip() for l in (ROOT / ".ci" / "run").read_text().splitlines() if not l.lstrip().startswith("#")]
    assert any(l.endswith("tests/install_floors.py") or "tests/install_floors.py " in l for l in lines), lines

"""Issue 8: the default linear solver, the persistent compilation cache with size buckets,
start-up without JAX, --json, trimesh input, meshio tet formats and pictures."""

import numpy as np
import pytest
import scipy.sparse as sp

from geomopt.linalg import linsolve
from geomopt import ParamOptions


def _spd_lower(n=60, seed=0, shift=1.0):
    """A sparse SPD matrix (a shifted 1D Laplacian plus random symmetric couplings): the CSC
    pattern and data of its lower triangle, and the full matrix."""
    rng = np.random.default_rng(seed)
    A = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tolil()
    for _ in range(n):
        i, j = rng.integers(0, n, 2)
        if i != j:
            w = rng.uniform(0.1, 0.4)
            A[i, j] -= w
            A[j, i] -= w
            A[i, i] += w
            A[j, j] += w
    A = (A + shift * sp.eye(n)).tocsc()
    L = sp.tril(A).tocsc()
    L.sort_indices()
    return L.indptr, L.indices, L.data, A


@pytest.mark.parametrize("backend", linsolve.available_backends())
def test_backend_solves_two_factorizations_on_one_analysis(backend):
    ip, ix, data, A = _spd_lower()
    chol = linsolve.SparseCholesky(ip, ix, backend)
    chol.analyze()
    b = np.arange(A.shape[0], dtype=float)
    for scale in (1.0, 3.0):  # two factorizations on one analysis
        chol.factor(scale * data)
        x = chol.solve(b)
        np.testing.assert_allclose(scale * (A @ x), b, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("backend", linsolve.available_backends())
@pytest.mark.parametrize("ordering", ["metis", "amd"])
def test_either_ordering_solves(backend, ordering):
    _, _, _, A = _spd_lower(n=200, seed=3)
    chol = linsolve.SparseCholesky.factored(A, backend, ordering)
    assert chol.ordering == ordering
    b = np.cos(np.arange(A.shape[0]))
    np.testing.assert_allclose(A @ chol.solve(b), b, rtol=1e-10, atol=1e-10)


def test_an_analysis_in_the_background_is_waited_for_by_the_first_factorization():
    pytest.importorskip("pymklpardiso")
    ip, ix, data, A = _spd_lower(n=300, seed=5)
    chol = linsolve.SparseCholesky(ip, ix, "pardiso")
    chol.analyze(background=True)
    chol.factor(data)  # waits for the thread, then factors on its analysis
    b = np.sin(np.arange(A.shape[0]))
    np.testing.assert_allclose(A @ chol.solve(b), b, rtol=1e-10, atol=1e-10)
    assert chol._pending is None


def test_what_a_background_analysis_raises_is_raised_where_it_is_waited_for():
    def fail():
        raise MemoryError("the analysis ran out of memory")

    job = linsolve._Background(fail)
    with pytest.raises(MemoryError, match="ran out of memory"):
        job.result()


def test_a_pattern_or_array_the_c_libraries_would_overrun_is_refused():
    """A column without its diagonal (a DOF no element couples) crashed the process in PARDISO's
    analysis (heap corruption); such patterns, and values or right-hand sides of the wrong size,
    are refused before any C call."""
    ip, ix, data, A = _spd_lower(n=10)
    chol = linsolve.SparseCholesky(ip, ix)
    with pytest.raises(ValueError, match="9 values for a pattern of"):
        chol.factor(data[:9])
    chol.factor(data)
    with pytest.raises(ValueError, match=r"right-hand side of shape \(11,\) for 10 unknowns"):
        chol.solve(np.ones(11))
    empty = np.r_[ip[:5], ip[4], ip[5:] + 0]  # an 11th column, empty, inserted after the 4th
    with pytest.raises(ValueError, match="column 4 is empty"):
        linsolve.SparseCholesky(empty, np.where(ix >= 4, ix + 1, ix))
    with pytest.raises(ValueError, match="column 1 does not start with its diagonal"):
        linsolve.SparseCholesky(np.array([0, 2, 3, 4]), np.array([0, 1, 2, 2]))  # column 1: row 2 only
    with pytest.raises(ValueError, match="row index outside 0..1"):
        linsolve.SparseCholesky(np.array([0, 2, 3]), np.array([0, 5, 1]))  # column 0: rows 0 and 5 of 2


def test_an_unknown_ordering_is_refused():
    from geomopt import ParameterError

    ip, ix, _, _ = _spd_lower()
    with pytest.raises(ParameterError, match="unknown ordering 'rcm'; valid: metis, amd"):
        linsolve.SparseCholesky(ip, ix, ordering="rcm")


def test_a_tutte_system_factored_once_is_ordered_by_minimum_degree(monkeypatch):
    """Its analysis is most of the work: minimum degree analyses it 3x faster than nested
    dissection below ~3e5 rows (the factorization is no slower there)."""
    from geomopt.mesh.tutte import tutte_embedding
    from test_topology import grid_disk

    asked = []
    factored = linsolve.SparseCholesky.factored
    monkeypatch.setattr(linsolve.SparseCholesky, "factored",
                        classmethod(lambda cls, A, *a, **k: asked.append(k.get("ordering")) or factored(A, *a, **k)))
    V, F = grid_disk(6, 5)
    uv = tutte_embedding(V, F)
    assert asked == ["amd"] and np.isfinite(uv).all()


@pytest.mark.parametrize("backend", linsolve.available_backends())
def test_backend_reports_an_indefinite_matrix_then_recovers(backend):
    ip, ix, data, A = _spd_lower()
    chol = linsolve.SparseCholesky(ip, ix, backend)
    bad = data.copy()
    bad[ip[:-1]] -= 10.0  # diagonal entries (first in each column): indefinite
    if backend == "superlu":
        pytest.skip("SuperLU factors indefinite matrices (no positive-definiteness check)")
    with pytest.raises(linsolve.NotPositiveDefinite):
        chol.factor(bad)
    chol.factor(data)
    b = np.ones(A.shape[0])
    np.testing.assert_allclose(A @ chol.solve(b), b, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("backend", linsolve.available_backends())
def test_after_a_failed_factorization_no_factor_is_held(backend):
    """A failed factor() leaves none: PARDISO's and CHOLMOD's factors are overwritten in place by
    the attempt (a solve then raised "matrix is not factored" inside a 10^6-triangle Newton
    solve, from the lagged-factor CG), and cholespy's solve used the previous matrix's factor
    silently; the lagged direction asks `has_factor` first."""
    ip, ix, data, A = _spd_lower()
    chol = linsolve.SparseCholesky(ip, ix, backend)
    assert not chol.has_factor
    chol.factor(data)
    assert chol.has_factor
    if backend == "superlu":
        pytest.skip("SuperLU factors indefinite matrices (no positive-definiteness check)")
    bad = data.copy()
    bad[ip[:-1]] -= 10.0
    with pytest.raises(linsolve.NotPositiveDefinite):
        chol.factor(bad)
    assert not chol.has_factor
    with pytest.raises(RuntimeError, match="no factorization held"):
        chol.solve(np.ones(A.shape[0]))


def test_auto_backend_is_the_measured_winner_when_installed():
    pytest.importorskip("pymklpardiso")
    assert linsolve.available_backends()[0] == "pardiso"
    ip, ix, _, _ = _spd_lower()
    assert linsolve.SparseCholesky(ip, ix).backend == "pardiso"


def test_the_scale_awareness_check_does_not_trace_again_in_a_warm_process():
    from geomopt.energies import get_energy

    traces = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: traces.append(event) if event.endswith("jaxpr_trace_duration") else None)
    get_energy("mips").check_scale_aware({})
    traces.clear()
    get_energy("mips").check_scale_aware({})
    assert traces == []


def test_repeated_solves_take_the_backend_with_the_fastest_solves(monkeypatch):
    for installed, expect in ((["pardiso", "cholespy", "superlu"], "cholespy"), (["pardiso", "superlu"], "pardiso"),
                              (["pardiso", "cholmod", "cholespy", "superlu"], "cholmod"), (["superlu"], "superlu")):
        monkeypatch.setattr(linsolve, "available_backends", lambda: installed)
        assert linsolve.repeated_solves_backend() == expect
    # large 3D Laplacians: PARDISO's nested dissection (cholespy factored a 91k-row hex corner
    # Laplacian in 38 s, PARDISO in 3.6 s)
    big = linsolve.PARDISO_3D_FROM
    monkeypatch.setattr(linsolve, "usable_cores", lambda: 1)
    for installed, dim, n, expect in ((["pardiso", "cholespy", "superlu"], 3, big, "pardiso"),
                                      (["pardiso", "cholespy", "superlu"], 3, big - 1, "cholespy"),
                                      (["pardiso", "cholespy", "superlu"], 2, 10 * big, "cholespy"),
                                      (["pardiso", "cholmod", "cholespy", "superlu"], 3, big, "cholmod"),
                                      (["cholespy", "superlu"], 3, big, "cholespy")):
        monkeypatch.setattr(linsolve, "available_backends", lambda: installed)
        assert linsolve.repeated_solves_backend(dim, n) == expect
    # large 2D Laplacians on two or more cores: PARDISO, a float32 handle per coordinate solved
    # on its own thread (498k rows: 82 ms a seed solve with cholespy, 42 ms so)
    monkeypatch.setattr(linsolve, "available_backends", lambda: ["pardiso", "cholespy", "superlu"])
    direct = linsolve.pardiso.entry_point() is not None
    for cores, n, expect in ((2, linsolve.PARDISO_2D_FROM, "pardiso" if direct else "cholespy"),
                             (2, linsolve.PARDISO_2D_FROM - 1, "cholespy"), (1, 10**6, "cholespy")):
        monkeypatch.setattr(linsolve, "usable_cores", lambda: cores)
        assert linsolve.repeated_solves_backend(2, n) == expect


# ------------------------------------------------------------------ size buckets (padding)

import json  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402

import geomopt  # noqa: E402
from geomopt._runtime import cache as _cache, padding as _padding, programs as _programs  # noqa: E402
from geomopt.objective.objective import Objective  # noqa: E402
from geomopt.mesh.problem import Problem  # noqa: E402

from conftest import grid  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def bumpy(n=12, ears=0):
    """A bumpy disk surface on an n x n grid; ``ears`` (0-2) corner triangles removed (with
    their corner vertex): a different mesh of the same size buckets."""
    V2, F = grid(n)
    V = np.c_[V2, 0.3 * np.sin(3.0 * V2[:, 0]) * V2[:, 1]]
    for xy in [(1.0, 0.0), (0.0, 1.0)][:ears]:
        corner = int(np.flatnonzero((V[:, :2] == xy).all(axis=1))[0])
        keep = ~(F == corner).any(axis=1)
        assert keep.sum() == len(F) - 1  # an ear: the corner is in one triangle
        F = F[keep]
        used = np.zeros(len(V), bool)
        used[F.ravel()] = True
        remap = np.cumsum(used) - 1
        V, F = V[used], remap[F]
    return V, F


def test_buckets_are_few_and_tight():
    # elements: powers of two from MINIMUM_ELEMENTS (at most 2x), vertices tied to the element
    # bucket, so a mesh family meets one (vertices, elements) bucket per element bucket
    m = np.unique(np.geomspace(1, _padding.MAXIMUM_ELEMENTS, 3000).astype(int))
    for dim, share in ((2, 0.5), (3, 0.25)):
        sizes = [_padding.bucket_sizes(max(int(share * k), 3), k, dim) for k in m]
        nb, mb = np.array(sizes).T
        assert (mb >= m).all() and (np.diff(mb) >= 0).all()
        assert (mb <= np.maximum(2 * m, _padding.MINIMUM_ELEMENTS)).all()
        assert len(np.unique(mb)) <= np.log2(_padding.MAXIMUM_ELEMENTS / _padding.MINIMUM_ELEMENTS) + 1
        assert len(set(sizes)) == len(np.unique(mb))  # one vertex bucket per element bucket
    assert _padding.bucket_sizes(10, _padding.MAXIMUM_ELEMENTS + 1, 2) is None  # large meshes: no padding
    b = np.array([_padding.power_bucket(s) for s in range(1, 5000)])
    assert (b >= np.arange(1, 5000)).all() and len(np.unique(b)) == 8  # 64 .. 8192


def test_padding_changes_no_energy_gradient_hessian_or_dets():
    V, F = bumpy(10)
    problem = Problem.surface(V, F)
    exact, padded = Objective(problem, "symmetric_dirichlet"), Objective(problem, "symmetric_dirichlet",
                                                                        buckets=True)
    assert padded.sizes.n_padded > problem.n_vertices and padded.sizes.m_padded > problem.n_elements
    rng = np.random.default_rng(1)
    x = V[:, :2] + 0.01 * rng.standard_normal((len(V), 2))
    p = exact.params()
    for projection in ("clamp", "none"):
        v0, g0, h0 = exact.hessian(x, p, projection)
        v1, g1, h1 = padded.hessian(x, p, projection)
        np.testing.assert_allclose(float(v1), float(v0), rtol=1e-14)
        assert np.asarray(g1).shape == (len(V), 2)
        np.testing.assert_allclose(np.asarray(g1), np.asarray(g0), rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(np.asarray(h1), np.asarray(h0), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(np.asarray(padded.dets(x)), np.asarray(exact.dets(x)), rtol=1e-15)
    # a padded map (what solvers hold) gives the same value, and zero gradient on padded rows
    xp = padded.pad_map(x)
    vp, gp = padded.value_and_grad(xp, p)
    np.testing.assert_allclose(float(vp), float(v0), rtol=1e-14)
    assert not np.asarray(gp)[len(V):].any()


@pytest.mark.parametrize("solver", ["newton", "lbfgs", "slim", "aqp", "cm", "optx-bfgs"])
def test_padding_changes_no_result_or_certificate(solver):
    V, F = bumpy(8)
    runs = [geomopt.parameterize(V, F, solver=solver, progress=False, options=ParamOptions(buckets=b))
            for b in (False, True)]
    assert runs[1].objective.sizes.padded
    a, b = runs
    assert a.outcome == b.outcome and a.certificate.inverted == b.certificate.inverted == 0
    if solver in ("newton", "slim", "cm"):  # first-order and quasi-Newton histories see rounding
        assert a.stats.iterations == b.stats.iterations
    else:
        assert abs(a.stats.iterations - b.stats.iterations) <= 0.1 * a.stats.iterations
    assert b.x.shape == a.x.shape == (len(V), 2)
    # the same map up to the solver's tolerance: padded reductions (sums with extra exact
    # zeros) may round differently in the last bit, which an L-BFGS history amplifies
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-6 * np.abs(a.x).max())
    np.testing.assert_allclose(b.energy, a.energy, rtol=1e-10)


# ------------------------------------------------------------------ the persistent cache


@pytest.fixture
def cache_at(tmp_path):
    """Point the persistent cache at a fresh folder for one test, then restore it."""
    before = _cache.cache_dir()
    _cache.cache_stats()  # start counting

    def use(path):
        jax.clear_caches()  # programs compiled so far are in memory: look them up on disk again
        _programs.clear()
        return _cache.set_cache_dir(path)

    yield use
    jax.clear_caches()
    _programs.clear()
    _cache.set_cache_dir(before)


FAST = geomopt.Newton(projection="clamp", max_steps=5)  # fewer kernels to compile


def _misses_hits(fn):
    s0 = _cache.cache_stats()
    fn()
    s1 = _cache.cache_stats()
    return s1["misses"] - s0["misses"], s1["hits"] - s0["hits"]


def test_a_different_mesh_of_the_same_bucket_compiles_nothing(tmp_path, cache_at):
    A, B = bumpy(12), bumpy(12, ears=2)
    pa, pb = Problem.surface(*A), Problem.surface(*B)
    oa, ob = Objective(pa, "symmetric_dirichlet", buckets=True), Objective(pb, "symmetric_dirichlet",
                                                                          buckets=True)
    assert (pa.n_vertices, pa.n_elements) != (pb.n_vertices, pb.n_elements)
    assert oa.sizes.n_padded == ob.sizes.n_padded and oa.sizes.m_padded == ob.sizes.m_padded
    assert oa.pattern.nnz != ob.pattern.nnz
    assert _padding.power_bucket(oa.pattern.nnz) == _padding.power_bucket(ob.pattern.nnz)
    cache_at(tmp_path / "cache")
    misses, _ = _misses_hits(lambda: geomopt.parameterize(*A, solver=FAST, progress=False))
    assert misses > 0 and any((tmp_path / "cache").iterdir())
    jax.clear_caches()  # a new process, as far as compiled code goes (JAX's and the kept programs)
    _programs.clear()
    misses, hits = _misses_hits(lambda: geomopt.parameterize(*B, solver=FAST, progress=False))
    assert misses == 0 and hits > 0
    # the control: without buckets the second mesh compiles again (one kernel is enough to see it)
    jax.clear_caches()
    exact = Objective(pb, "symmetric_dirichlet")
    misses, _ = _misses_hits(lambda: exact.value(B[0][:, :2], exact.params()))
    assert misses > 0


def test_a_bijective_solve_of_another_mesh_of_the_same_bucket_compiles_nothing(tmp_path, cache_at):
    """The bijective mode's objectives (the mesh's, and mesh + scaffold at each remesh) are padded
    to size buckets as parameterize's are: without them every triangle count compiled its own
    kernels (~2.3 s a count in every process), and an atlas's charts compiled one set each."""
    from geomopt.mesh.generators import spiral_strip
    from geomopt.bijective import bijective_parameterize

    A = spiral_strip(turns=2.5, spacing=0.5, width=0.3, lift=1.5, n_across=2)
    B = spiral_strip(turns=2.4, spacing=0.5, width=0.3, lift=1.5, n_across=2)  # same size buckets
    assert len(A[1]) != len(B[1])
    cache_at(tmp_path / "cache")
    first = bijective_parameterize(*A, x0=A[0][:, :2].copy(), progress=False)
    assert first.success and first.details.scaffold_triangles > 0, first.message
    jax.clear_caches()  # a new process, as far as compiled code goes
    _programs.clear()
    misses, hits = _misses_hits(lambda: bijective_parameterize(*B, x0=B[0][:, :2].copy(), progress=False))
    assert misses == 0 and hits > 0


def test_a_read_only_cache_is_read_and_never_written(tmp_path, cache_at, monkeypatch):
    V, F = bumpy(8)
    folder = tmp_path / "cache"
    cache_at(folder)
    geomopt.parameterize(V, F, solver=FAST, progress=False)
    entries = sorted(p.name for p in folder.iterdir())
    monkeypatch.setattr(_cache, "_writable", lambda path: False)
    assert cache_at(folder) == str(folder)
    misses, hits = _misses_hits(lambda: geomopt.parameterize(V, F, solver=FAST, progress=False))
    assert misses == 0 and hits > 0
    jax.clear_caches()
    misses, _ = _misses_hits(lambda: geomopt.parameterize(*bumpy(16), solver=FAST, progress=False))  # another bucket
    assert misses > 0
    assert sorted(p.name for p in folder.iterdir()) == entries


def test_set_cache_dir_none_turns_it_off(tmp_path, cache_at):
    assert cache_at(None) is None and _cache.cache_dir() is None
    assert jax.config.jax_enable_compilation_cache is False


def _run(args, env=None, **kw):
    env = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, timeout=300,
                          cwd=str(REPO), **kw)


def test_cli_with_an_unwritable_cache_folder_runs_and_prints_json(tmp_path):
    V, F = bumpy(6)
    mesh, out = tmp_path / "m.obj", tmp_path / "uv.obj"
    geomopt.io.write_obj_with_uv(mesh, V, F, V[:, :2])  # any valid OBJ
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the cache folder would go")
    proc = _run(["-m", "geomopt", "param", str(mesh), "-o", str(out), "--json", "--quiet"],
                env={"GEOMOPT_CACHE_DIR": str(blocker / "cache")})
    assert proc.returncode == 0, proc.stderr
    assert "Warning" not in proc.stderr and "Traceback" not in proc.stderr
    summary = json.loads(proc.stdout)  # stdout holds exactly the summary
    assert summary["success"] and summary["exit_status"] == 0 and summary["flips"] == 0
    assert summary["faces"] == len(F) and summary["cache_dir"] is None and out.exists()


def test_cli_with_a_full_cache_disk_runs_quietly(tmp_path):
    V, F = bumpy(6)
    mesh, out = tmp_path / "m.obj", tmp_path / "uv.obj"
    geomopt.io.write_obj_with_uv(mesh, V, F, V[:, :2])
    code = ("import errno, sys\nimport jax._src.lru_cache as lru\n"
            "def put(self, key, value):\n    raise OSError(errno.ENOSPC, 'No space left on device')\n"
            "lru.LRUCache.put = put\nfrom geomopt.cli import main\n"
            f"sys.exit(main(['param', {str(mesh)!r}, '-o', {str(out)!r}, '--json', '--quiet']))")
    proc = _run(["-c", code], env={"GEOMOPT_CACHE_DIR": str(tmp_path / "cache")})
    assert proc.returncode == 0, proc.stderr
    assert "No space" not in proc.stderr and "Warning" not in proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["success"] and summary["cache_misses"] > 0 and out.exists()


def test_cli_json_reports_failures_too(tmp_path):
    proc = _run(["-m", "geomopt", "param", str(tmp_path / "missing.obj"), "-o", str(tmp_path / "o.obj"),
                 "--json"], env={"GEOMOPT_CACHE_DIR": "off"})
    assert proc.returncode == 2
    summary = json.loads(proc.stdout)
    assert summary["success"] is False and summary["exit_status"] == 2 and "does not exist" in summary["error"]


# ------------------------------------------------------------------ start-up


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["param", "--help"]])
def test_help_and_version_do_not_import_jax(argv):
    code = ("import sys\nfrom geomopt.cli import main\ntry:\n    main(%r)\nexcept SystemExit as e:\n"
            "    assert e.code == 0\nprint('JAX' if 'jax' in sys.modules else 'NOJAX', file=sys.stderr)" % argv)
    proc = _run(["-c", code])
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().endswith("NOJAX")
    if argv == ["--version"]:
        assert proc.stdout.strip() == f"geomopt {geomopt.__version__}"
    else:
        assert "``" not in proc.stdout and ":class:" not in proc.stdout  # no reST markup
        assert "symmetric_dirichlet" in proc.stdout and "newton" in proc.stdout


def test_import_geomopt_does_not_import_jax_nor_switch_its_global_float64():
    # geomopt's own calls run in float64 (geomopt._runtime.x64, tests/test_x64.py); the user's code keeps
    # JAX's default dtypes
    proc = _run(["-c", "import sys, geomopt; assert 'jax' not in sys.modules\n"
                       "import jax.numpy as jnp; print(jnp.zeros(1).dtype)"], env={"GEOMOPT_CACHE_DIR": "off"})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "float32"


def test_help_lists_exactly_the_registered_energies_and_solvers():
    from geomopt._runtime import names as _names
    from geomopt.energies import REGISTRY
    from geomopt.solvers import SOLVERS

    assert set(_names.ENERGIES) == set(REGISTRY) and set(_names.SOLVERS) == set(SOLVERS)


def test_compare_help_names_every_solver_of_the_table(monkeypatch):
    """``compare --solvers``'s help and the comparison's default come from the solver table (it
    used to list the optimistix solvers by hand, so a new solver was missing from it)."""
    import argparse

    from geomopt._runtime import names as _names
    from geomopt.cli.parser import build_parser
    from geomopt.experiments.options import DEFAULT_SOLVERS

    monkeypatch.setitem(_names.SOLVERS, "gd", "geomopt.solvers.newton:Newton")
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    text = " ".join(next(a.help for a in sub.choices["compare"]._actions if "--solvers" in a.option_strings).split())
    assert DEFAULT_SOLVERS == _names.COMPARED and set(DEFAULT_SOLVERS) <= set(_names.SOLVERS)
    assert f"default {','.join(DEFAULT_SOLVERS)};" in text
    rest = text.split("cm only in 2D; ")[1].removesuffix(" on request)").split(", ")
    assert sorted(rest) == sorted(set(_names.SOLVERS) - set(DEFAULT_SOLVERS)), text


def test_optimal_scale_matches_the_closed_form_for_symmetric_dirichlet():
    from geomopt.param import optimal_scale

    V, F = bumpy(9)
    problem = Problem.surface(V, F)
    obj = Objective(problem, "symmetric_dirichlet", buckets=True)
    x = V[:, :2] * 0.37 - V[:, :2].mean(axis=0) * 0.37
    P = x[problem.simplices]
    J = np.einsum("mij,mjk->mik", np.swapaxes(P[:, 1:] - P[:, :1], 1, 2), problem.rest_inv)
    a = (problem.volumes * (J**2).sum((1, 2))).sum()
    b = (problem.volumes * (np.linalg.inv(J) ** 2).sum((1, 2))).sum()
    assert optimal_scale(obj, x) == pytest.approx((b / a) ** 0.25, rel=1e-6)


# ------------------------------------------------------------------ trimesh input, tet formats


def test_optimal_scale_matches_the_closed_form_for_arap():
    # E(s) = sum_w sum_i (s sigma_i - 1)^2 is least at s = sum_w (sigma_1 + sigma_2) / sum_w |J|^2
    from geomopt.param import optimal_scale

    V, F = bumpy(9)
    problem = Problem.surface(V, F)
    obj = Objective(problem, "arap", buckets=True)
    x = (V[:, :2] - V[:, :2].mean(axis=0)) * np.array([2.3, 0.8])
    P = x[problem.simplices]
    J = np.einsum("mij,mjk->mik", np.swapaxes(P[:, 1:] - P[:, :1], 1, 2), problem.rest_inv)
    sigma = np.linalg.svd(J, compute_uv=False)
    s = (problem.volumes * sigma.sum(1)).sum() / (problem.volumes * (sigma**2).sum(1)).sum()
    assert optimal_scale(obj, x) == pytest.approx(s, rel=1e-6)


_LINE_CASES = {  # f(t), its minimiser on [-4, 4], the most evaluations allowed
    "symmetric Dirichlet": (lambda t: 3.0 * np.exp(2 * t) + 0.2 * np.exp(-2 * t), 0.25 * np.log(0.2 / 3.0), 14),
    "quadratic": (lambda t: (t - 1.3) ** 2, 1.3, 12),
    "quartic": (lambda t: (t - 0.01) ** 4, 0.01, 20),
    "kink": (lambda t: abs(t - 2.2), 2.2, 40),
    "barrier below -1": (lambda t: np.inf if t < -1 else np.exp(-3 * t) + np.exp(t), 0.25 * np.log(3.0), 16),
    "beyond the upper bound": (lambda t: (t - 7.0) ** 2, 4.0, 6),
    "beyond the lower bound": (lambda t: (t + 9.0) ** 2, -4.0, 6),
    "flat (scale-invariant)": (lambda t: 5.0, 0.0, 3),
}


@pytest.mark.parametrize("case", list(_LINE_CASES))
def test_the_scale_search_finds_the_minimum_in_few_evaluations(case):
    from geomopt.mesh.tutte import _line_minimum

    f, best, most = _LINE_CASES[case]
    calls = []
    t = _line_minimum(lambda t: calls.append(t) or f(t), -4.0, 4.0, 1e-7)
    tol = 1e-5 if case == "quartic" else 1e-6  # a quartic's values say less about where its minimum is
    assert t == pytest.approx(best, abs=tol) and len(calls) <= most
    assert all(-4.0 <= c <= 4.0 for c in calls)


def test_parameterize_accepts_a_trimesh_or_any_vertices_faces_object():
    import types

    import trimesh

    V, F = bumpy(6)
    ref = geomopt.parameterize(V, F, progress=False)
    mesh = trimesh.Trimesh(V, F, process=False)
    for obj in (mesh, types.SimpleNamespace(vertices=V.tolist(), faces=F.tolist())):
        res = geomopt.parameterize(obj, progress=False)
        assert res.success
        np.testing.assert_array_equal(res.x, ref.x)
    with pytest.raises(geomopt.ParameterError, match="trimesh"):
        geomopt.parameterize(V, progress=False)


# ------------------------------------------------------------------ pictures


def _image(path):
    import matplotlib.image

    img = matplotlib.image.imread(str(path))[..., :3]
    assert img.shape[0] > 300 and img.shape[1] > 600
    return img


def _reddish(img):
    """Pixels of the inverted-element red, possibly seen through a translucent surface."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((r > 0.55) & (r - g > 0.3) & (r - b > 0.3)).sum())


def test_param_png_shows_a_checkerboard_on_the_surface_beside_the_layout(tmp_path):
    V, F = bumpy(10)
    mesh = tmp_path / "m.obj"
    geomopt.io.write_obj_with_uv(mesh, V, F, V[:, :2])
    code = geomopt.cli.main(["param", str(mesh), "-o", str(tmp_path / "uv.obj"), "--png",
                             str(tmp_path / "uv.png"), "--quiet"])
    assert code == 0
    img = _image(tmp_path / "uv.png")
    left, right = img[:, : img.shape[1] // 2], img[:, img.shape[1] // 2:]
    # checker squares (orange and white, shaded) on the surface panel only
    orange = (np.abs(left[..., 0] - 2.0 * left[..., 2] - 0.0) > 0.3) & (left[..., 0] > left[..., 1]) & (left[..., 1] > left[..., 2] + 0.2)
    assert orange.sum() > 2000 and (left.min(axis=-1) < 0.9).sum() > 5000
    assert len(np.unique((right * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 50  # colour-mapped
    assert (tmp_path / "uv_convergence.png").stat().st_size > 10_000


@pytest.mark.parametrize("case", ["2D/Simple/Lshape", "twisted_box"])
def test_untangle_png_marks_the_inverted_elements_of_the_start_only(tmp_path, case):
    from conftest import shared_path

    if case == "twisted_box":  # (the LIM armadillo has no locally injective map: tests/test_untangle.py)
        from geomopt.mesh import generators
        from geomopt.lim import LimCase

        folder = LimCase.from_tangle(generators.twisted_box(4, 12, turns=0.5)).write(tmp_path / "twisted")
    else:
        folder = shared_path("lim", *case.split("/"))
    out = tmp_path / ("out.obj" if case.startswith("2D") else "out.vtk")
    code = geomopt.cli.main(["untangle", str(folder), "-o", str(out), "--png", str(tmp_path / "u.png"), "--quiet"])
    assert code == 0
    img = _image(tmp_path / "u.png")
    left, right = img[:, : img.shape[1] // 2], img[:, img.shape[1] // 2:]
    assert _reddish(left) > 500 and _reddish(right) == 0  # the result has none inverted
    assert (right.min(axis=-1) < 0.8).sum() > 2000  # the result is drawn

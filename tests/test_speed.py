"""Issue 22: cacheable host calls, the --json timing split, element quality."""

import json
import os
import time
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt._runtime import cache as _cache, hostcall as _hostcall, programs as _programs
from geomopt.lim import LimCase
from geomopt.mesh import generators as G
from geomopt.solvers._laplacian import RestLaplacian, laplacian_solve
from geomopt import UntangleOptions

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def fresh_cache(tmp_path):
    before = _cache.cache_dir()
    _cache.cache_stats()
    jax.clear_caches()
    _programs.clear()
    _cache.set_cache_dir(tmp_path / "cache")
    yield tmp_path / "cache"
    jax.clear_caches()
    _programs.clear()
    _cache.set_cache_dir(before)


def _misses(fn):
    s0 = _cache.cache_stats()
    out = fn()
    return _cache.cache_stats()["misses"] - s0["misses"], out


def test_a_program_with_the_host_laplacian_solve_is_cached_and_loaded(fresh_cache):
    t = G.rotated_interior(*G.square_mesh(9), 90)
    obj = geomopt.Objective(t.problem(), "dirichlet")
    pre = RestLaplacian.register(obj, "host")
    q = np.random.default_rng(0).standard_normal(t.x0.shape) * obj.free_dofs

    def solve():
        f = jax.jit(lambda h, q: 2.0 * laplacian_solve(h, q, q))  # a fresh function: traced anew
        return np.asarray(f(pre.token, jnp.asarray(q)))

    misses, first = _misses(solve)
    assert misses > 0
    np.testing.assert_allclose(first, 2.0 * pre.solve(q), rtol=1e-12)
    jax.clear_caches()  # as a new process sees it: look the program up on disk
    misses, again = _misses(solve)
    assert misses == 0  # jax.pure_callback programs were never written to the cache
    np.testing.assert_array_equal(again, first)


def test_a_solver_reinitialised_on_its_objective_shares_the_factored_laplacian(monkeypatch):
    """The untangling's stiff switch re-initialises L-BFGS on the objective it ran on: the rest
    Laplacian still held by the running state is shared, not factored again (6.7 s at 10^6
    triangles); another objective, or one whose states are gone, gets its own."""
    import gc

    from geomopt.linalg import linsolve
    from geomopt.solvers import LBFGS

    t = G.rotated_interior(*G.square_mesh(9), 90)
    obj = geomopt.Objective(t.problem(), "dirichlet")
    factored = []
    real = linsolve.SparseCholesky.factored
    monkeypatch.setattr(linsolve.SparseCholesky, "factored",
                        classmethod(lambda cls, *a, **k: factored.append(1) or real(*a, **k)))
    solver = LBFGS(precondition="laplacian", laplacian="host")
    first = solver.init(obj, t.x0, obj.params())
    again = solver.init(obj, t.x0, obj.params())
    assert again.memory.preconditioner is first.memory.preconditioner and len(factored) == 1
    other = solver.init(geomopt.Objective(t.problem(), "dirichlet"), t.x0, obj.params())
    assert other.memory.preconditioner is not first.memory.preconditioner and len(factored) == 2
    del first, again, other
    gc.collect()
    solver.init(obj, t.x0, obj.params())
    assert len(factored) == 3


def test_a_host_function_that_raises_gives_nan_and_is_recorded():
    def broken(x, out):
        raise RuntimeError("boom")

    f = jax.jit(lambda x: _hostcall.call("geomopt_test_broken", broken, jax.ShapeDtypeStruct(x.shape, x.dtype), x))
    out = np.asarray(f(jnp.ones(3)))
    assert np.isnan(out).all()
    assert _hostcall.last_error[0] == "geomopt_test_broken" and "boom" in str(_hostcall.last_error[1])


def test_untangle_json_has_the_timing_split_from_process_start(tmp_path):
    folder = LimCase.from_tangle(G.noisy_interior(*G.disk_mesh(6), 1.0, seed=2)).write(tmp_path / "case")
    env = {**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-m", "geomopt", "untangle", str(folder), "-o", str(tmp_path / "o.obj"),
                           "--json", "--quiet"], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    split = summary["timing"]
    for key in ("import", "read", "compile", "setup", "solve", "certify", "write", "total", "other"):
        assert split[key] >= 0.0, key
    assert split["import"] > 0.0 and split["compile"] > 0.0 and split["write"] > 0.0
    parts = sum(v for k, v in split.items() if k not in ("total", "other"))
    # compile may overlap solve (a program first used inside the loop), nothing else overlaps
    assert parts - split["compile"] <= split["total"] + 1e-3 and split["total"] <= summary["wall_seconds"] + 0.5


def test_scaled_jacobian_is_one_for_regular_simplices_and_negative_when_inverted():
    from geomopt.mesh.quality import element_quality, scaled_jacobians, size_ratios

    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3) / 2]])
    tet = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    T = np.array([[0, 1, 2, 3]]) if np.linalg.det(tet[1:] - tet[0]) > 0 else np.array([[0, 2, 1, 3]])
    np.testing.assert_allclose(scaled_jacobians(tri, [[0, 1, 2]]), [1.0])
    np.testing.assert_allclose(scaled_jacobians(tet, T), [1.0])
    np.testing.assert_allclose(scaled_jacobians(tri, [[0, 2, 1]]), [-1.0])
    # a right isosceles triangle: the 45-degree corners score sin(45) * 2/sqrt(3)
    right = np.array([[0.0, 0], [1, 0], [0, 1]])
    np.testing.assert_allclose(scaled_jacobians(right, [[0, 1, 2]]), [np.sqrt(0.5) * 2 / np.sqrt(3)])
    # a sliver: every corner is nearly flat, not only the first
    sliver = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0.5, 1e-3]])
    assert 0 < scaled_jacobians(sliver, [[0, 1, 2, 3]])[0] < 0.01
    V, F = G.disk_mesh(3)
    q = element_quality(V, F)
    assert q["min_size_ratio"] == pytest.approx(np.min(size_ratios(V, F))) and 0 < q["min_scaled_jacobian"] <= 1
    assert element_quality(V, F[:, ::-1], orientation=-1) == pytest.approx(q)


def test_a_stalling_inner_solve_continues_with_the_laplacian_seed():
    """The default untangling L-BFGS (diagonal seed below 50k elements) switches to the
    Laplacian seed when an inner solve has not converged after STIFF_AFTER iterations: a disk
    rotated by 180 degrees then takes a fraction of the inner iterations; a noisy one never
    switches (same iterations as the diagonal seed alone)."""
    from geomopt.untangling import STIFF_AFTER, default_solver, untangle

    rot = G.rotated_interior(*G.disk_mesh(24), 180)
    diag = untangle(rot.problem(), rot.x0, solver=default_solver("lbfgs", 2), progress=False)
    auto = untangle(rot.problem(), rot.x0, progress=False)
    assert diag.success and auto.success
    assert diag.stats.iterations > 2 * STIFF_AFTER and auto.stats.iterations < 0.6 * diag.stats.iterations
    assert auto.solver.precondition == "laplacian"
    # the switched solve starts from the map its inner solve started at, not the probe's (whose
    # 100 diagonal iterations had gained folds there); Newton (hexahedra) goes on from the probe's
    from geomopt.untangling import continuation as C

    starts, switched = [], []
    real_start, real_call = C.EpsContinuation.start, C.EpsContinuation.__call__

    def start(self, state):
        starts.append(np.asarray(state.x))
        return real_start(self, state)

    def call(self, state, outcome):
        decision = real_call(self, state, outcome)
        if decision.objective is not None and not self.polishing:  # a switch, not the final polish
            switched.append((np.asarray(decision.x), np.asarray(state.x)))
        return decision

    bend = G.bent_box(4, 48, 180.0, hexes=True)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(C.EpsContinuation, "start", start)
        mp.setattr(C.EpsContinuation, "__call__", call)
        untangle(rot.problem(), rot.x0, progress=False)
        assert len(switched) == 1 and np.array_equal(switched[0][0], starts[0])
        assert not np.array_equal(switched[0][1], starts[0])
        # hexahedra: L-BFGS's probe, Newton
        untangle(bend.problem(), bend.x0, progress=False, options=UntangleOptions(start="given"))
        assert len(switched) == 2 and np.array_equal(switched[1][0], switched[1][1])
        # a Laplacian-seeded probe (the mesh above LAPLACIAN_FROM) goes on from its own map
        import geomopt.untangling.inner as inner

        mp.setattr(inner, "LAPLACIAN_FROM", 100)
        mp.setattr(C, "STIFF_AFTER", 10)  # a probe short enough to end before that solve converges
        untangle(rot.problem(), rot.x0, progress=False)
        assert len(switched) == 3 and np.array_equal(switched[2][0], switched[2][1])
    noise = G.noisy_interior(*G.disk_mesh(12), 1.0, seed=3)
    a = untangle(noise.problem(), noise.x0, progress=False)
    b = untangle(noise.problem(), noise.x0, solver=default_solver("lbfgs", 2), progress=False)
    assert a.success and a.stats.iterations == b.stats.iterations < STIFF_AFTER
    assert a.solver.precondition == "diagonal"


def test_a_local_tangle_keeps_the_diagonal_seed_at_any_size(monkeypatch):
    """From LAPLACIAN_FROM elements the default L-BFGS starts with the Laplacian seed unless a
    quarter or more of the elements start inverted (noise, scattered vertices: a local tangle,
    where the diagonal seed is as fast per iteration count and half the cost per iteration)."""
    import geomopt.untangling.inner as U

    assert U.default_solver("lbfgs", 2, 60_000).precondition == "laplacian"
    assert U.default_solver("lbfgs", 2, 60_000, inverted=15_000).precondition == "diagonal"
    assert U.default_solver("lbfgs", 2, 60_000, inverted=14_999).precondition == "laplacian"
    assert U.default_solver("lbfgs", 3, 60_000, corners=True, inverted=30_000).precondition == "laplacian"
    monkeypatch.setattr(U, "LAPLACIAN_FROM", 100)  # the rule on a mesh small enough for a test
    noise = G.noisy_interior(*G.disk_mesh(12), 2.0, seed=3)
    rot = G.rotated_interior(*G.disk_mesh(12), 180)
    share = [t.problem().count_inverted(t.x0) / len(t.simplices) for t in (noise, rot)]
    assert share[0] >= 0.25 > share[1]
    for tangle, seed in ((noise, "diagonal"), (rot, "laplacian")):
        r = geomopt.untangle(tangle.problem(), tangle.x0, progress=False)
        assert r.success and r.solver.precondition == seed


def _delaunay_disk(n_points, seed=0):
    """An irregular Delaunay triangulation of the unit disk (boundary circle + random points)."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    h = np.sqrt(np.pi / n_points)
    t = np.linspace(0.0, 2.0 * np.pi, int(2.0 * np.pi / h), endpoint=False)
    P = rng.uniform(-1.0, 1.0, (4 * n_points, 2))
    P = P[np.linalg.norm(P, axis=1) < 1.0 - 0.5 * h][:n_points]
    V = np.vstack([np.c_[np.cos(t), np.sin(t)], P])
    F = Delaunay(V).simplices
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    flip = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    F[flip] = F[flip][:, [1, 0, 2]]
    return V, F


def test_a_probe_that_untangles_fast_keeps_the_diagonal_seed():
    """A noisy irregular disk needs more than STIFF_AFTER iterations in its first inner solve,
    but each probe removes folds and energy fast (PROBE_PROGRESS): it goes on with the diagonal
    seed; the same disk rotated by 180 degrees gains folds in its probe and switches, and so
    does a Tutte map onto a star, which loses folds but its energy only slowly."""
    from geomopt.untangling import STIFF_AFTER, untangle

    V, F = _delaunay_disk(800, seed=1)
    noise = G.noisy_interior(V, F, 3.0, seed=0)
    r = untangle(noise.problem(), noise.x0, progress=False)
    assert r.success and r.trace.phases[0].inner > STIFF_AFTER
    assert r.solver.precondition == "diagonal"
    for tangle in (G.rotated_interior(V, F, 180), G.tutte_nonconvex(24, "star")):
        r = untangle(tangle.problem(), tangle.x0, progress=False)
        assert r.success and r.solver.precondition == "laplacian"


def test_builtin_densities_trace_in_2d_and_3d_so_check_dim_may_skip_them():
    """The densities that skip tracing are the table's (geomopt._runtime.names.ENERGIES), never a
    list kept beside it: every Energy the library defines is a row of the table, so that a new
    energy is its module plus one row, and all of them trace for d = 2 and 3."""
    import importlib
    import pkgutil

    import geomopt.energies
    from geomopt._runtime import names
    from geomopt.energies import REGISTRY, Energy
    from geomopt.energies._energy import _builtin_densities, _density_dims, _library_density

    assert _builtin_densities() == {e.density for e in REGISTRY.values()}
    modules = {ref.split(":")[0] for ref in names.ENERGIES.values()}
    modules |= {f"geomopt.energies.{m.name}" for m in pkgutil.iter_modules(geomopt.energies.__path__)}
    defined = [v for m in sorted(modules) for v in vars(importlib.import_module(m)).values() if isinstance(v, Energy)]
    assert defined and all(any(e is r for r in REGISTRY.values()) for e in defined), \
        [e.name for e in defined if not any(e is r for r in REGISTRY.values())]
    assert all(_library_density(e.density) for e in REGISTRY.values())
    for e in REGISTRY.values():
        assert _density_dims(e.name, e.density, tuple(sorted(e.params)))[0] == (2, 3), e.name
        e.check_dim(2), e.check_dim(3)



def _gather_sum(scale, x, idx):
    return scale * jnp.sum(x[idx] * x[idx[::-1]])


def test_compiled_programs_are_kept_on_disk_and_loaded_by_a_new_process(fresh_cache):
    x, idx = np.linspace(0.0, 1.0, 50), np.arange(40)[::-1] % 50
    expect = 2.0 * np.sum(x[idx] * x[idx[::-1]])
    # JAX's own cache holds the program first: the kept one must still load and run (an
    # executable loaded from JAX's cache serialises without its kernels on XLA CPU)
    jax.jit(_gather_sum, static_argnums=0)(2.0, x, idx).block_until_ready()
    jax.clear_caches()
    _programs.xla_options()  # the once-per-process probe of the XLA options compiles a program of its own
    before = dict(_programs.stats)
    misses, first = _misses(lambda: float(_programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)))
    assert _programs.stats["stored"] == before["stored"] + 1 and misses == 1  # a compile is a miss
    assert len(list((fresh_cache / "programs").glob("_gather_sum-*.xla"))) == 1
    fresh = _programs.jit(_gather_sum, static_argnums=0)  # as a new process: nothing in memory
    misses, again = _misses(lambda: float(fresh(2.0, x, idx)))
    assert _programs.stats["loaded"] == before["loaded"] + 1 and misses == 0
    assert first == again and np.isclose(first, expect, rtol=1e-13)
    # another static value, other shapes: another program; a lambda: plain jax.jit
    assert np.isclose(float(fresh(3.0, x[:30], idx[:20] % 30)), 3.0 * np.sum(x[:30][idx[:20] % 30] * x[:30][(idx[:20] % 30)[::-1]]))
    assert _programs.stats["stored"] == before["stored"] + 2
    lam = _programs.jit(lambda s, v: s * v.sum(), static_argnums=0)
    assert float(lam(2.0, x)) == 2.0 * x.sum() and _programs.stats["plain"] == before["plain"] + 1


def _eigenvalues(a):
    return jnp.linalg.eigh(a)[0]


def test_only_a_kept_program_that_calls_lapack_readies_lapack_when_loaded(fresh_cache, monkeypatch):
    """Loading a kept program that calls LAPACK (a 3D Hessian's eigh) first lowers one eigh, so
    that jaxlib's table of LAPACK functions is filled (else: a segmentation fault); a program
    that calls none loads without it (the lowering and scipy.linalg's import: ~0.1 s)."""
    x, idx, A = np.linspace(0.0, 1.0, 40), np.arange(30)[::-1] % 40, np.diag([3.0, 1.0, 2.0])
    plain = float(_programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx))  # compiled and kept
    eig = np.asarray(_programs.jit(_eigenvalues)(A))
    readied = []
    monkeypatch.setattr(_programs, "_lapack_ready", lambda: readied.append(1))
    assert float(_programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)) == plain  # a new process's load
    assert readied == [] and _programs.stats["loaded"] >= 1
    assert np.array_equal(np.asarray(_programs.jit(_eigenvalues)(A)), eig) and eig.tolist() == [1.0, 2.0, 3.0]
    assert readied == [1]


def test_loading_a_kept_program_compiles_nothing_not_even_the_options_probe(fresh_cache):
    """A warm process loads its kept programs without compiling: the key names the XLA options
    asked for, so the probe of whether jaxlib takes them (a compilation of ~30 ms) waits for
    the first program that must be compiled."""
    x, idx = np.linspace(0.0, 1.0, 40), np.arange(30)[::-1] % 40
    expect = float(_programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx))  # compiled and kept
    _programs.xla_options.cache_clear()  # as a new process: nothing probed, nothing in memory
    try:
        misses, again = _misses(lambda: float(_programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)))
        assert again == expect and misses == 0
        assert _programs.xla_options.cache_info().currsize == 0
    finally:
        _programs.xla_options()  # probed now, not inside a later test's count


def test_a_kept_program_composes_with_jit_grad_and_vmap(fresh_cache):
    """Called on traced values a kept program is its function inlined into the caller's trace
    (a compiled executable takes no tracers, and XLA options only go to the outermost jit)."""
    x, idx = np.linspace(0.0, 1.0, 30), np.arange(20)[::-1] % 30
    kept = _programs.jit(_gather_sum, static_argnums=0)
    expect = float(kept(2.0, x, idx))
    assert float(jax.jit(lambda v: kept(2.0, v, idx))(x)) == pytest.approx(expect, rel=1e-14)
    grad = jax.grad(lambda v: kept(2.0, v, idx))(x)
    np.testing.assert_allclose(grad, jax.grad(lambda v: _gather_sum(2.0, v, idx))(x), rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(lambda v: kept(2.0, v, idx))(np.stack([x, 2 * x])), [expect, 4 * expect],
                               rtol=1e-14)


def test_a_kept_program_that_fails_at_its_first_run_is_deleted_and_jitted_again(fresh_cache, monkeypatch):
    """A damaged file (XLA CPU once reported "Function bitcast_concatenate_fusion not found"
    running a loaded program) must cost a compile, not the solve."""
    from jax.experimental import serialize_executable as se

    x, idx = np.linspace(0.0, 1.0, 30), np.arange(20)[::-1] % 30
    expect = 2.0 * np.sum(x[idx] * x[idx[::-1]])
    assert np.isclose(float(_programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)), expect, rtol=1e-13)
    kept = list((fresh_cache / "programs").glob("_gather_sum-*.xla"))
    assert len(kept) == 1

    def broken(*args, **kwargs):
        def run(*a):
            raise RuntimeError("INTERNAL: Function bitcast_concatenate_fusion not found")
        return run

    monkeypatch.setattr(se, "deserialize_and_load", broken)
    before = dict(_programs.stats)
    fresh = _programs.jit(_gather_sum, static_argnums=0)
    assert np.isclose(float(fresh(2.0, x, idx)), expect, rtol=1e-13)
    assert _programs.stats["loaded"] == before["loaded"] + 1 and _programs.stats["broken"] == before["broken"] + 1
    assert not kept[0].exists()
    assert np.isclose(float(fresh(2.0, x, idx)), expect, rtol=1e-13)  # the plain program from now on
    assert _programs.stats["loaded"] == before["loaded"] + 1


def _files(folder, sizes_and_ages):
    """Files of the given sizes (bytes), last used the given seconds ago, half in ``programs/``."""
    now = time.time()
    paths = []
    for k, (size, age) in enumerate(sizes_and_ages):
        sub = folder / "programs" if k % 2 else folder
        sub.mkdir(parents=True, exist_ok=True)
        path = sub / f"entry-{k}-cache"
        path.write_bytes(b"x" * size)
        os.utime(path, (now - age, now - age))
        paths.append(path)
    return paths


def test_the_cache_folder_is_kept_within_its_size_limit_least_recently_used_first(tmp_path):
    paths = _files(tmp_path, [(400, 50), (300, 10), (200, 40), (100, 1), (300, 30)])  # 1,300 bytes
    assert _cache.prune(tmp_path, limit=2000) == 0 and all(p.exists() for p in paths)  # under the limit
    assert _cache.prune(tmp_path, limit=1000) == 2  # over: down to 3/4 of it, oldest first
    assert [p.exists() for p in paths] == [False, True, False, True, True]
    assert _cache.prune(tmp_path, limit=None) == 0  # no limit


def test_the_size_limit_comes_from_the_environment(monkeypatch):
    from geomopt import ParameterError

    monkeypatch.setenv("GEOMOPT_CACHE_MAX_MB", "1.5")
    assert _cache.max_bytes() == int(1.5 * 2**20)
    monkeypatch.setenv("GEOMOPT_CACHE_MAX_MB", "off")
    assert _cache.max_bytes() is None
    monkeypatch.delenv("GEOMOPT_CACHE_MAX_MB")
    assert _cache.max_bytes() == _cache.DEFAULT_MAX_MB * 2**20
    monkeypatch.setenv("GEOMOPT_CACHE_MAX_MB", "lots")
    with pytest.raises(ParameterError, match="GEOMOPT_CACHE_MAX_MB='lots' is not a size in MB"):
        _cache.max_bytes()


def test_a_loaded_program_is_marked_used_and_a_kept_one_prunes_the_folder(fresh_cache, monkeypatch):
    """Loading a kept program touches its file (so the limit removes it last); keeping a new one
    prunes the folder once per process, old files first."""
    old = _files(fresh_cache, [(5000, 3600), (5000, 7200)])
    monkeypatch.setattr(_cache, "_state", {**_cache._state, "pruned": False})
    monkeypatch.setenv("GEOMOPT_CACHE_MAX_MB", str(1e-6))  # a byte: every old file must go
    monkeypatch.setattr(_cache.threading, "Thread", _Inline)
    x, idx = np.linspace(0.0, 1.0, 24), np.arange(20)[::-1] % 24
    _programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)  # compiled, kept: prunes
    assert not any(p.exists() for p in old) and _cache._state["pruned"]
    kept = next((fresh_cache / "programs").glob("_gather_sum-*.xla"), None)
    assert kept is None  # past a one-byte limit the new program went too: its file, not its use
    monkeypatch.setenv("GEOMOPT_CACHE_MAX_MB", "off")
    _programs.clear()
    _programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)  # compiled and kept again (no second prune)
    kept = next((fresh_cache / "programs").glob("_gather_sum-*.xla"))
    os.utime(kept, (1.0, 1.0))
    _programs.clear()
    _programs.jit(_gather_sum, static_argnums=0)(2.0, x, idx)  # loaded: touched
    assert kept.stat().st_mtime > time.time() - 60


class _Inline:
    """A Thread that runs its target at start, in the caller's thread."""

    def __init__(self, target, daemon=None):
        self.target = target

    def start(self):
        self.target()

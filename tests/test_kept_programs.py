"""Kept programs (geomopt._runtime.programs) loaded into a fresh process that has lowered nothing."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# a 3D Newton untangle: its Hessian kernel calls LAPACK (9 x 9 eigh)
SCRIPT = """
import jax
jax.config.update("jax_enable_x64", True)
from geomopt.mesh import generators as G
from geomopt.untangling import untangle
V, H = G.hex_mesh(3, 3, 3)
t = G.rotated_interior(V, H, 90)
r = untangle(t.problem(), t.x0, "newton", progress=False)
print(r.success)
"""


def test_a_loaded_lapack_program_runs_in_a_new_process(tmp_path):
    # the second process loads the Hessian program the first one kept: it segfaulted (exit
    # -11) when jaxlib's LAPACK table was filled only by lowering
    env = dict(os.environ, GEOMOPT_CACHE_DIR=str(tmp_path / "cache"), GEOMOPT_PROGRAMS="on",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for _ in range(2):
        run = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0 and run.stdout.split()[-1] == "True", (run.returncode, run.stderr[-2000:])
    assert any((tmp_path / "cache" / "programs").iterdir())


# --- issue 30 item 2: a program file is run only for the key its header names ---------------

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt._runtime import cache as _cache, programs as _programs
from geomopt.mesh import generators as G


@pytest.fixture
def fresh_cache(tmp_path):
    before = _cache.cache_dir()
    jax.clear_caches()
    _programs.clear()
    _cache.set_cache_dir(tmp_path / "cache")
    yield tmp_path / "cache" / "programs"
    jax.clear_caches()
    _programs.clear()
    _cache.set_cache_dir(before)


def _scaled_sum(scale, x):
    return scale * jnp.sum(x * x)


X = np.linspace(0.0, 1.0, 40)


def _kept(folder, scale):
    """Compile and keep the program for ``scale``; its file."""
    before = set(folder.glob("_scaled_sum-*.xla")) if folder.exists() else set()
    assert float(_programs.jit(_scaled_sum, static_argnums=0)(scale, X)) == pytest.approx(scale * np.sum(X * X))
    (path,) = set(folder.glob("_scaled_sum-*.xla")) - before
    return path


def _split(path):
    magic, head, data = path.read_bytes().split(b"\n", 2)
    return magic, json.loads(head), data


def _run_fresh(scale):
    """The program for ``scale`` as a new process finds it: nothing in memory."""
    _programs.clear()
    before = dict(_programs.stats)
    out = float(_programs.jit(_scaled_sum, static_argnums=0)(scale, X))
    return out, {k: _programs.stats[k] - before[k] for k in before}


def test_swapped_program_files_are_not_run(fresh_cache):
    two, three = _kept(fresh_cache, 2.0), _kept(fresh_cache, 3.0)
    a, b = two.read_bytes(), three.read_bytes()
    two.write_bytes(b), three.write_bytes(a)  # the same function and shapes, other static arguments
    out, delta = _run_fresh(2.0)
    assert out == pytest.approx(2.0 * np.sum(X * X), rel=1e-14)  # 3x as much when the file was trusted
    assert delta["rejected"] == 1 and delta["loaded"] == 0 and delta["stored"] == 1
    assert _split(two)[1]["key"]["static"] == "tuple(2.0)"  # replaced by the right program
    out, delta = _run_fresh(2.0)
    assert delta["loaded"] == 1 and delta["rejected"] == 0 and out == pytest.approx(2.0 * np.sum(X * X))


@pytest.mark.parametrize("field, value", [("jax", "0.0.1"), ("jaxlib", "0.0.1"), ("geomopt", "0.0.0"),
                                          ("cpu", "x86_64 0000000000000000"), ("backend", "gpu"),
                                          ("function", "tests.other"), ("static", "tuple(3.0)"),
                                          ("arguments", "((((41,), 'float64', False),), 'float64')")])
def test_a_file_whose_header_names_another_key_is_not_run(fresh_cache, field, value):
    """A file copied from another version, machine or program, with a valid checksum: its
    header differs from the key in one field; its program is another one (3x), never run."""
    two, three = _kept(fresh_cache, 2.0), _kept(fresh_cache, 3.0)
    magic, head, data = _split(three)
    head["key"] = dict(_split(two)[1]["key"], **{field: value})
    two.write_bytes(b"\n".join([magic, json.dumps(head).encode(), data]))
    out, delta = _run_fresh(2.0)
    assert out == pytest.approx(2.0 * np.sum(X * X), rel=1e-14)
    assert delta["rejected"] == 1 and delta["loaded"] == 0 and delta["stored"] == 1


@pytest.mark.parametrize("damage", ["empty", "truncated", "flipped", "header only", "old format"])
def test_a_damaged_program_file_is_compiled_again(fresh_cache, damage):
    import pickle

    two = _kept(fresh_cache, 2.0)
    raw = two.read_bytes()
    magic, head, data = _split(two)
    flipped = bytearray(raw)
    flipped[-100] ^= 0x10
    two.write_bytes({"empty": b"", "truncated": raw[: len(raw) // 2], "flipped": bytes(flipped),
                     "header only": magic + b"\n" + json.dumps(head).encode() + b"\n",
                     "old format": data}[damage])
    out, delta = _run_fresh(2.0)
    assert out == pytest.approx(2.0 * np.sum(X * X), rel=1e-14)
    assert delta["rejected"] == 1 and delta["stored"] == 1 and delta["broken"] == 0
    assert _split(two)[2] and pickle.loads(_split(two)[2])  # rewritten whole


def test_swapped_energy_kernels_give_the_asked_energy(fresh_cache):
    """The issue's case: the symmetric Dirichlet and MIPS energy kernels of one size bucket
    swapped; the symmetric Dirichlet energy must be its own (>= 4 per unit area), not MIPS's."""
    V, F = G.square_mesh(6)
    problem = geomopt.Problem.planar(V, F)
    x = V * np.array([1.6, 0.7])  # a stretched, flip-free map
    values = {}
    for energy in ("symmetric_dirichlet", "mips"):
        before = set(fresh_cache.glob("energy_kernel-*.xla")) if fresh_cache.exists() else set()
        values[energy] = float(geomopt.Objective(problem, energy).value(x))
        (values[energy + " file"],) = set(fresh_cache.glob("energy_kernel-*.xla")) - before
    sd, mips = values["symmetric_dirichlet file"], values["mips file"]
    a, b = sd.read_bytes(), mips.read_bytes()
    sd.write_bytes(b), mips.write_bytes(a)
    jax.clear_caches()
    _programs.clear()
    for energy in ("symmetric_dirichlet", "mips"):
        assert float(geomopt.Objective(problem, energy).value(x)) == pytest.approx(values[energy], rel=1e-13)
    assert values["symmetric_dirichlet"] != pytest.approx(values["mips"])


RACE = """
import numpy as np, geomopt
from geomopt._runtime import programs as _programs
from geomopt.mesh import generators as G
V, F = G.square_mesh(5)
print(float(geomopt.Objective(geomopt.Problem.planar(V, F), "symmetric_dirichlet").value(V * np.array([1.5, 0.5]))))
print(_programs.stats["rejected"])
"""


def test_two_processes_on_one_empty_cache_both_keep_a_valid_file(tmp_path):
    env = dict(os.environ, GEOMOPT_CACHE_DIR=str(tmp_path / "cache"), GEOMOPT_PROGRAMS="on",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    runs = [subprocess.Popen([sys.executable, "-c", RACE], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True) for _ in range(2)]
    outs = [run.communicate(timeout=600) for run in runs]
    assert all(run.returncode == 0 for run in runs), [err[-2000:] for _, err in outs]
    assert outs[0][0].split()[0] == outs[1][0].split()[0]
    again = subprocess.run([sys.executable, "-c", RACE], env=env, capture_output=True, text=True, timeout=600)
    assert again.stdout.split() == [outs[0][0].split()[0], "0"]  # every kept file read back whole
    assert not list((tmp_path / "cache" / "programs").glob("*.tmp"))


K = 1.0  # read by _user_density: a module global a user changes between runs


def _user_density(x):
    return K * jnp.sum(x * x)


def _apply(density, x):
    return density(x)


def test_a_static_function_from_outside_geomopt_is_never_kept(fresh_cache, monkeypatch):
    """A user's energy density (here from this test module) is keyed by nothing that sees its
    source or the globals it reads: a notebook that changes K and solves again loaded the
    program kept for the old K (wrong map, wrong energy, no error).  Such programs run through
    plain jax.jit (JAX's own cache keys the HLO, constants included) and no file is kept."""
    kept = _programs.jit(_apply, static_argnums=0)
    before = dict(_programs.stats)
    assert float(kept(_user_density, X)) == pytest.approx(np.sum(X * X))
    assert _programs.stats["plain"] == before["plain"] + 1 and _programs.stats["stored"] == before["stored"]
    assert not fresh_cache.exists() or not list(fresh_cache.glob("_apply-*.xla"))
    monkeypatch.setattr(sys.modules[__name__], "K", 5.0)
    _programs.clear()
    jax.clear_caches()
    assert float(_programs.jit(_apply, static_argnums=0)(_user_density, X)) == pytest.approx(5.0 * np.sum(X * X))


# --- kernels loaded ahead on a thread (issue 33: the demo's set-up) ----------------------------

def _slow_sum(x):
    return jnp.sum(jnp.sin(x) ** 2)


def test_one_program_asked_for_on_two_threads_is_compiled_once(fresh_cache, monkeypatch):
    """A solver's kernels are loaded ahead on a thread while the caller builds its start map;
    the caller's own call for the same program waits for that load instead of making its own."""
    import threading
    import time

    kept = _programs.jit(_slow_sum)
    real_load = _programs.Program._load

    def slow_load(self, *args):  # hold the first load long enough for the second call to arrive
        time.sleep(0.3)
        return real_load(self, *args)

    monkeypatch.setattr(_programs.Program, "_load", slow_load)
    before = dict(_programs.stats)
    thread = threading.Thread(target=kept.prepare, args=(X,))
    thread.start()
    time.sleep(0.05)
    assert float(kept(X)) == pytest.approx(np.sum(np.sin(X) ** 2))
    thread.join()
    assert _programs.stats["stored"] - before["stored"] == 1 and _programs.stats["loaded"] == before["loaded"]


def test_newton_loads_its_kernels_ahead_and_its_init_finds_them(fresh_cache, monkeypatch):
    from geomopt.solvers import Newton, newton

    monkeypatch.setattr(newton, "AHEAD_FROM", 0)  # a small mesh's kernels are loaded on the caller's thread
    V, F = G.square_mesh(7)
    objective = geomopt.Objective(geomopt.Problem.planar(V, F), "symmetric_dirichlet")
    solver = Newton()
    solver.load_ahead(objective).join()
    ahead = dict(_programs.stats)
    assert ahead["stored"] >= 2  # the Hessian and search kernels, compiled on the thread
    state = solver.init(objective, V * np.array([1.3, 0.8]), objective.params())
    # init compiles or loads only the value-and-gradient kernel it evaluates
    assert _programs.stats["stored"] - ahead["stored"] <= 1 and _programs.stats["loaded"] == ahead["loaded"]
    assert state.value > 0


def test_a_failure_ahead_is_dropped_quietly(monkeypatch):
    """The work ahead is best effort: an exception there is neither raised nor printed by the
    thread (the caller's own call, made anyway, raises it where it belongs)."""
    import threading

    from geomopt._runtime.threads import ahead

    hooked, seen = [], []
    monkeypatch.setattr(threading, "excepthook", hooked.append)
    ahead(lambda: seen.append(1) or 1 / 0).join()
    assert seen == [1] and hooked == []


def test_only_a_problem_of_thousands_of_unknowns_loads_its_kernels_on_a_thread(monkeypatch):
    """A thread's start and join cost more than a small problem's loading (AHEAD_FROM): none is
    started there, nor for the symbolic analysis; from AHEAD_FROM free unknowns both are."""
    from geomopt._runtime.threads import AHEAD_FROM
    from geomopt.linalg import linsolve
    from geomopt.solvers import Newton

    analyses = []
    real = linsolve.SparseCholesky.analyze
    monkeypatch.setattr(linsolve.SparseCholesky, "analyze",
                        lambda self, background=False: analyses.append(background) or real(self, background))
    for k, threaded in ((7, False), (int(np.sqrt(AHEAD_FROM / 2)) + 2, True)):
        V, F = G.square_mesh(k)
        objective = geomopt.Objective(geomopt.Problem.planar(V, F), "symmetric_dirichlet")
        thread = Newton().load_ahead(objective)
        assert (thread is not None) == threaded
        if thread is not None:
            thread.join()
        start = len(analyses)
        objective.cholesky("auto")
        assert analyses[start] == threaded  # the first call (a background one calls again on its thread)


def test_parameterize_loads_the_solvers_kernels_ahead(monkeypatch):
    from geomopt.solvers import Newton

    asked = []
    real = Newton.load_ahead
    monkeypatch.setattr(Newton, "load_ahead", lambda self, objective: asked.append(objective) or real(self, objective))
    V, F = G.square_mesh(6)
    result = geomopt.parameterize(np.c_[V, 0.1 * V[:, 0] ** 2], F, progress=False)
    assert result.success and len(asked) == 1 and asked[0] is result.objective


ANNULUS = """
import sys
import numpy as np, geomopt
from geomopt.mesh import generators as G
from geomopt.solvers import newton
newton.AHEAD_FROM = 0  # the kernels of this small mesh load on a thread too
V, F = G.square_mesh(12)
F = F[np.linalg.norm(V[F].mean(axis=1) - 0.5, axis=1) > 0.2]  # a hole: not a disk
used, F = np.unique(F, return_inverse=True)
V, F = V[used], F.reshape(-1, 3)
try:
    geomopt.parameterize(np.c_[V, 0.1 * V[:, 0] ** 2], F, progress=False)
except geomopt.MeshError as exc:
    assert "boundary loops" in str(exc), exc  # refused by the disk check, after the kernels started
    sys.exit(3)
"""


def test_a_script_ending_while_kernels_compile_ahead_exits_normally(tmp_path):
    """parameterize starts its solver's kernels compiling on a thread, then refuses the mesh; a
    script that catches the error and exits at once must end with its own status.  On a daemon
    thread, interpreter shutdown inside XLA's compiler aborted the process (exit 134, about one
    run in three): the thread is not a daemon, so the exit waits for it."""
    from geomopt._runtime.threads import ahead

    assert not ahead(lambda: None).daemon
    env = dict(os.environ, GEOMOPT_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run([sys.executable, "-c", ANNULUS], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 3, run.stderr[-2000:]


def test_kept_programs_are_keyed_on_every_source_file_of_geomopt():
    """A kept program's key holds the fingerprint of geomopt's sources: an edit anywhere in the
    package (here the objective's module, outside ``_runtime``) must give another key, else a
    process loads a program compiled from the code before the edit (the fingerprint had
    covered ``_runtime`` alone since the modules moved into layers)."""
    import geomopt.objective.objective as objective_module

    path = objective_module.__file__
    before = _programs._source_fingerprint("geomopt")
    st = os.stat(path)
    try:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
        _programs._fingerprints.clear()
        assert _programs._source_fingerprint("geomopt") != before
    finally:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
        _programs._fingerprints.clear()
    assert _programs._source_fingerprint("geomopt") == before


def _maps() -> int:
    with open("/proc/self/maps") as fh:
        return sum(1 for _ in fh)


def test_a_program_keeps_at_most_held_executables_in_memory(fresh_cache, monkeypatch):
    # each live executable maps three regions and a process may map 65,530: a test worker that
    # had called thousands of shapes crashed in XLA's compiler; the least recently used go
    monkeypatch.setattr(_programs, "HELD", 4)
    program = _programs.jit(_scaled_sum, static_argnums=0)
    for scale in (1.0, 2.0, 3.0, 4.0, 5.0, 6.0):
        program(scale, X)
        program(1.0, X)  # the most recently used stays
    assert len(program._calls) == 4
    assert {k[0][0] for k in program._calls} == {1.0, 4.0, 5.0, 6.0}
    assert float(program(2.0, X)) == pytest.approx(2.0 * np.sum(X * X))  # a dropped one loads again
    assert _programs.stats["loaded"] >= 1


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="counts memory mappings in Linux's /proc")
def test_dropped_executables_give_their_memory_mappings_back(fresh_cache, monkeypatch):
    program = _programs.jit(_scaled_sum, static_argnums=0)
    scales = [float(s) for s in np.arange(1.0, 41.0)]
    for scale in scales:  # compiled and kept on disk
        program(scale, X)
    jax.clear_caches()  # JAX's own caches hold what it compiled (up to its LRU sizes)
    _programs.clear()
    monkeypatch.setattr(_programs, "HELD", 2)
    program(0.5, X)
    before = _maps()
    for scale in scales:  # loaded from disk, two held at a time
        program(scale, X)
    assert _maps() - before < 40, "40 shapes, 2 executables held: their mappings must not pile up"

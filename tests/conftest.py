"""Strict JAX configuration for the whole suite: float64 on, implicit rank promotion raises."""

from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

#: each worker process imports JAX and compiles its own programs (about 1 GB): cap the count
MAX_WORKERS = 8


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject's addopts): one worker per core, at most MAX_WORKERS."""
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_WORKERS))


#: memory mappings (Linux's /proc/self/maps) above which a worker drops the executables it holds
#: before its next test: each live executable maps three or more regions, a process may map
#: 65,530 (vm.max_map_count), and a worker that had run ~1,000 tests crashed in XLA's compiler
#: when its next mapping failed (CI, 2026-12-07).  JAX's own caches hold thousands of executables;
#: geomopt's kept programs at most ``programs.HELD`` each
MAPS_LIMIT = 30_000
_MAPS = Path("/proc/self/maps")
_tests_run = [0]


@pytest.fixture(autouse=True)
def _bounded_memory_mappings():
    """Every 20th test, where the worker maps more than :data:`MAPS_LIMIT` regions, forget
    the compiled programs held in memory (JAX's caches and geomopt's; the next calls load them
    from the compilation cache on disk)."""
    _tests_run[0] += 1
    if _tests_run[0] % 20 == 0 and _MAPS.exists():
        with _MAPS.open() as fh:
            if sum(1 for _ in fh) > MAPS_LIMIT:
                import gc

                from geomopt._runtime import programs

                jax.clear_caches()
                programs.clear()
                gc.collect()
    yield


#: node ids of the long tests (tests/slow.txt): marked ``slow``, left out unless ``-m`` selects them
SLOW = frozenset(line.strip() for line in (Path(__file__).parent / "slow.txt").read_text().splitlines()
                 if line.strip() and not line.startswith("#"))


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Mark the tests of :data:`SLOW` (before ``-m`` deselects); a listed id whose file is
    missing, or whose test function its collected file lacks, is stale, and an error (a
    parameter that exists only with ../shared's data, such as a LIM case, is not; nor is one left
    out by -k or by naming tests)."""
    ids = {item.nodeid for item in items}
    for item in items:
        if item.nodeid in SLOW:
            item.add_marker(pytest.mark.slow)
    if config.getoption("keyword") or any("::" in arg for arg in config.args):
        return  # a selection of tests: the rest of their files is not collected
    files = {nodeid.split("::")[0] for nodeid in ids}
    functions = {nodeid.split("[")[0] for nodeid in ids}
    root = Path(config.rootpath)
    stale = sorted(i for i in SLOW - ids if (i.split("::")[0] in files and i.split("[")[0] not in functions)
                   or not (root / i.split("::")[0]).exists())
    if stale:
        raise pytest.UsageError(f"tests/slow.txt lists {len(stale)} test(s) that do not exist (first: {stale[0]}); "
                                f"remove them")


SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
#: the LIM cases: ../shared/data/lim where the project's shared folder is beside the clone (the 2D
#: cases and a 3D one), else the 2D cases the repository carries (tests/data/SOURCES.md)
LIM_ROOT = SHARED / "lim" if (SHARED / "lim" / "manifest.tsv").exists() else Path(__file__).resolve().parent / "data" / "lim"


def mesh_path(name):
    """A real surface: the copy bundled with geomopt (geomopt/data) when there is one, else
    ../shared/data/meshes; skip the test with a clear message when neither has it."""
    for folder in (Path(__file__).resolve().parents[1] / "geomopt" / "data", SHARED / "meshes"):
        if (folder / name).exists():
            return folder / name
    pytest.skip(f"mesh {name} is not redistributable with the repository and ../shared/data/meshes is absent "
                f"(clone the project next to its shared/ folder)")


def shared_path(*parts):
    """A file under ../shared/data (a LIM case may come from the repository's own copy), or skip
    the test with a clear message when it is absent."""
    root, rest = (LIM_ROOT, parts[1:]) if parts[:1] == ("lim",) else (SHARED, parts)
    p = root.joinpath(*rest)
    if not p.exists():
        pytest.skip(f"{'/'.join(parts)} is not in the data the repository carries (tests/data/SOURCES.md) and "
                    f"{SHARED} is absent (clone the project next to its shared/ folder)")
    return p


def grid(n=6, jitter=0.0, seed=0):
    """A planar triangulated unit square: V (n*n, 2), F (2(n-1)^2, 3), CCW."""
    xs = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(xs, xs, indexing="xy")
    V = np.stack([X.ravel(), Y.ravel()], 1)
    if jitter:
        rng = np.random.default_rng(seed)
        inner = (V[:, 0] > 0) & (V[:, 0] < 1) & (V[:, 1] > 0) & (V[:, 1] < 1)
        V[inner] += jitter / (n - 1) * rng.uniform(-1, 1, (inner.sum(), 2))
    F = []
    for j in range(n - 1):
        for i in range(n - 1):
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1
            F += [[a, b, d], [a, d, c]]
    return V, np.array(F, dtype=np.int64)


def cube_tets(n=3):
    """A unit cube split into 6 tets per cell (Kuhn): V ((n+1)^3, 3), T (6 n^3, 4), positive."""
    xs = np.linspace(0.0, 1.0, n + 1)
    V = np.stack(np.meshgrid(xs, xs, xs, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    T = []
    perms = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    for i in range(n):
        for j in range(n):
            for k in range(n):
                for p in perms:
                    c = np.array([i, j, k])
                    tet = [idx[tuple(c)]]
                    for axis in p:
                        c = c.copy()
                        c[axis] += 1
                        tet.append(idx[tuple(c)])
                    T.append(tet)
    T = np.array(T, dtype=np.int64)
    P = V[T]
    vol = np.einsum("ij,ij->i", P[:, 1] - P[:, 0], np.cross(P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]))
    T[vol < 0] = T[vol < 0][:, [0, 2, 1, 3]]
    return V, T


@pytest.fixture
def cli(capsys):
    """Run ``geomopt.cli.main(argv)`` in this process: ``cli(*argv) -> (exit code, stdout, stderr)``."""
    import geomopt.cli

    def run(*argv):
        code = geomopt.cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err
    return run


# ------------------------------------------------------------------ forced failures of the atlas


def _failed_certificate(cert):
    """``cert`` (an AtlasCertificate) with charts 0 and 1 reported overlapping: not ok."""
    import dataclasses

    return dataclasses.replace(cert, ok=False, overlapping_pairs=np.array([[0, 1]], np.int64),
                               message="atlas NOT certified: 1 overlapping chart pairs (first: (0, 1)) [forced]")


@pytest.fixture
def failing_certificate(monkeypatch):
    """The final certificate of :func:`geomopt.make_atlas` fails (it reports charts 0 and 1
    overlapping); the packer's own certificate is untouched.  Yields the list of certificates
    made."""
    import geomopt.atlas.build

    made, certify = [], geomopt.atlas.build.certify_atlas

    def fails(*args):
        made.append(_failed_certificate(certify(*args)))
        return made[-1]
    monkeypatch.setattr(geomopt.atlas.build, "certify_atlas", fails)
    return made


@pytest.fixture
def uncertified_packer(monkeypatch):
    """:func:`geomopt.atlas.pack_charts`'s certificate fails its first ``fails[0]`` times (all
    of them unless the test lowers it); ``resolutions`` records each layout's resolution.
    Yields ``(fails, resolutions)``, both lists the test may read or change."""
    from geomopt.atlas import _pack

    fails, resolutions = [10**9], []
    certify, layout = _pack.certify_atlas, _pack._layout

    def certificate(*args):
        cert = certify(*args)
        if fails[0] > 0:
            fails[0] -= 1
            return _failed_certificate(cert)
        return cert

    def recorded(U, Bs, bases, turns, area, margin, resolution, *rest):
        resolutions.append(resolution)
        return layout(U, Bs, bases, turns, area, margin, resolution, *rest)
    monkeypatch.setattr(_pack, "certify_atlas", certificate)
    monkeypatch.setattr(_pack, "_layout", recorded)
    return fails, resolutions

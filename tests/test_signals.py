"""An interrupt at any moment ends a command with status 128 + the signal and writes nothing
(issue 48, item 6): even a SIGINT whose KeyboardInterrupt is swallowed where Python cannot raise
it (a garbage-collection callback, such as JAX's, prints "Exception ignored in ...")."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import grid

REPO = Path(__file__).resolve().parents[1]


def bumpy_obj(path, n):
    """A bumpy square of 2 (n-1)^2 triangles: a surface ``param`` takes a few iterations on."""
    V2, F = grid(n, jitter=0.3)
    z = 0.3 * np.sin(3 * V2[:, 0]) * np.cos(4 * V2[:, 1])
    path.write_text("".join(f"v {x!r} {y!r} {w!r}\n" for (x, y), w in zip(V2.tolist(), z.tolist()))
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))
    return path


def env(tmp_path):
    return {**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}


SWALLOWED = """
import gc, os, signal, sys
import geomopt.cli

def importing():
    f = sys._getframe()
    while f is not None and not f.f_code.co_filename.startswith("<frozen importlib"):
        f = f.f_back
    return f is not None

def swallow(phase, info):  # a SIGINT whose KeyboardInterrupt lands in a GC callback
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler or importing():
        return  # (the command's handler not installed yet, or inside an import: only recorded there)
    gc.callbacks.remove(swallow)
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(10 ** 6):  # the handler runs here, its exception is ignored by the collector
        pass

gc.callbacks.append(swallow)
sys.exit(geomopt.cli.main(["param", sys.argv[1], "-o", sys.argv[2], "--quiet"]))
"""


def test_an_interrupt_swallowed_by_a_gc_callback_still_ends_the_run(tmp_path):
    mesh, out = bumpy_obj(tmp_path / "m.obj", 12), tmp_path / "uv.obj"
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(SWALLOWED), str(mesh), str(out)],
                          capture_output=True, text=True, env=env(tmp_path), timeout=300)
    assert "Exception ignored" in done.stderr, done.stderr  # the interrupt was swallowed there
    assert done.returncode == 128 + signal.SIGINT, done.stderr
    assert "interrupted by SIGINT" in done.stderr
    assert sorted(os.listdir(tmp_path)) == ["cache", "m.obj"]


def interrupted_param(tmp_path, mesh, out, after, signum=signal.SIGINT):
    """``python -m geomopt param mesh -o out`` sent ``signum`` ``after`` seconds in: (status, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "geomopt", "param", str(mesh), "-o", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(tmp_path))
    try:
        time.sleep(after)
        if proc.poll() is not None:  # it ended first (this machine ran it faster than measured)
            return None, ""
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    return proc.returncode, err


def test_an_interrupt_at_a_random_moment_ends_the_run_with_nothing_written(tmp_path):
    """SIGINT (and SIGTERM) at random moments of a whole ``python -m geomopt param`` run, from
    the interpreter's start to the solve's end: status 128 + signal, no output, no temporary.
    (Before geomopt's code runs, Python's own handler ends the process by the signal: -signum.)
    GEOMOPT_SIGNAL_TRIALS and GEOMOPT_SIGNAL_SEED choose how many trials and which moments."""
    mesh, out = bumpy_obj(tmp_path / "m.obj", 100), tmp_path / "uv.obj"
    for _ in range(2):  # the second run's time, with the compiled programs cached
        t = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "geomopt", "param", str(mesh), "-o", str(out), "--quiet"],
                              capture_output=True, text=True, env=env(tmp_path), timeout=300)
        whole = time.perf_counter() - t
        assert done.returncode == 0 and out.exists(), done.stderr
        out.unlink()
    rng = random.Random(int(os.environ.get("GEOMOPT_SIGNAL_SEED", "0")) or None)
    trials = int(os.environ.get("GEOMOPT_SIGNAL_TRIALS", "4"))
    for k in range(trials):
        after, signum = rng.uniform(0.05, 0.9 * whole), (signal.SIGINT, signal.SIGTERM)[k % 2 if k < 2 else 0]
        code, err = interrupted_param(tmp_path, mesh, out, after, signum)
        if code is None:
            out.unlink()
            continue
        what = f"{signal.Signals(signum).name} after {after:.2f} s of a {whole:.2f} s run: {err[-2000:]}"
        assert code in (128 + signum, -signum), what
        assert "Traceback" not in err or code == -signum, what
        assert sorted(os.listdir(tmp_path)) == ["cache", "m.obj"], what

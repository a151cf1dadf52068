"""Kept programs (geomopt._programs) loaded into a fresh process that has lowered nothing."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# a 3D Newton untangle: its Hessian kernel calls LAPACK (9 x 9 eigh)
SCRIPT = """
import jax
jax.config.update("jax_enable_x64", True)
from geomopt import generators as G
from geomopt.untangle import untangle
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

"""Install geomopt's declared minimum dependency versions in a fresh virtual environment and run
part of the test suite there: the floors in pyproject.toml must be true.

    python tests/install_floors.py [--venv DIR] [--python PYTHON] [--all] [-- PYTEST ARGS]

Every ``name>=X`` requirement of ``[project] dependencies`` whose environment marker holds on
this machine is installed as ``name==X`` (with the ``test`` extra, constrained by those pins), under the oldest
Python that ``requires-python`` allows (``--python`` to choose another); then geomopt itself
(``pip install --no-deps``) and ``pip check``; then the tests below (``--all``: the whole
suite) run against the installed package.  Needs network access to PyPI and a few minutes.
Exit status 0 when everything installed and passed.  (``tests/test_install.py`` runs this
when ``GEOMOPT_TEST_INSTALL=1``.)
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: a subset touching every dependency: predicates and certificates (numpy), energies and
#: kernels (jax), Newton with each sparse Cholesky (py-mkl-pardiso / cholespy / scipy), L-BFGS
#: and optimistix solvers (optimistix, equinox, lineax), untangling 2D/3D, free-boundary and
#: bijective parameterization, mesh formats (meshio), the CLI with pictures (matplotlib), batch
#: runs (distributed), the XLA-option guard, the float64 policy with the 64-bit mode off
SUBSET = ["test_predicates.py", "test_local_injectivity.py", "test_extreme_scales.py", "test_objective.py",
          "test_energies.py", "test_newton.py", "test_solvers.py", "test_untangle.py", "test_bijective.py",
          "test_formats.py", "test_batch.py", "test_install.py", "test_cli.py",
          "test_x64.py"]  # geomopt in a process where JAX's 64-bit mode is off (the CLI's case)


def _project():
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _run(cmd, **kw):
    print("+", " ".join(map(str, cmd)), flush=True)
    return subprocess.run([str(c) for c in cmd], check=True, **kw)


def _python_for(requires: str) -> str:
    """The oldest ``python3.X`` on PATH satisfying ``requires-python`` (``>=3.X`` form)."""
    found = re.fullmatch(r"\s*>=\s*3\.(\d+)\s*", requires)
    if not found:
        sys.exit(f"requires-python {requires!r}: give --python")
    for minor in range(int(found.group(1)), 20):
        exe = shutil.which(f"python3.{minor}")
        if exe and subprocess.run([exe, "-c", ""], capture_output=True).returncode == 0:  # not a dead shim
            return exe
    sys.exit(f"no python3.X >= {requires} on PATH: give --python")


def minimum_pins(python: str) -> list[str]:
    """``name==X`` for every ``name>=X`` dependency (and ``[batch]`` requirement) whose marker
    holds for ``python``."""
    code = ("import json, sys; from packaging.requirements import Requirement; "
            "reqs = [Requirement(r) for r in json.loads(sys.argv[1])]; "
            "print(json.dumps([[r.name, [[s.operator, s.version] for s in r.specifier]] "
            "for r in reqs if r.marker is None or r.marker.evaluate()]))")
    import json

    # the declared floors of the dependencies and of the [batch] extra (Dask, which the suite runs)
    declared = _project()["dependencies"] + _project()["optional-dependencies"]["batch"]
    out = subprocess.run([python, "-c", code, json.dumps(declared)],
                         check=True, capture_output=True, text=True).stdout
    pins = []
    for name, specs in json.loads(out):
        low = [v for op, v in specs if op == ">="]
        if len(low) != 1:
            sys.exit(f"dependency {name!r} has no single '>=' floor: {specs}")
        pins.append(f"{name}=={low[0]}")
    return pins


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--venv", default=None, help="where to create the environment (default: a temporary folder)")
    ap.add_argument("--python", default=None, help="the interpreter to build it from")
    ap.add_argument("--all", action="store_true", help="run the whole test suite, not the subset")
    ap.add_argument("pytest_args", nargs="*", help="extra pytest arguments (after --)")
    args = ap.parse_args(argv)
    python = args.python or _python_for(_project()["requires-python"])
    venv = Path(args.venv or tempfile.mkdtemp(prefix="geomopt-floors-"))
    _run([python, "-m", "venv", "--clear", venv])
    py = venv / "bin" / "python"
    _run([py, "-m", "pip", "install", "-q", "--upgrade", "pip", "packaging"])
    pins = minimum_pins(str(py))
    print("minimum versions:", " ".join(pins), flush=True)
    constraints = venv / "floors.txt"  # the test tools may not move a pinned package
    constraints.write_text("\n".join(pins) + "\n")
    # optax is an optional extra (geomopt.optax; tests/test_optax.py skips without it) whose
    # releases need a newer JAX than the core floor: it is left out here, not pinned down
    tools = [t for t in _project()["optional-dependencies"]["test"] if not t.startswith("optax")] + ["pytest-xdist"]
    _run([py, "-m", "pip", "install", "-q", "-c", constraints, *pins, *tools])
    _run([py, "-m", "pip", "install", "-q", "--no-deps", ROOT])
    _run([py, "-m", "pip", "check"])
    _run([py, "-c", "import sys, jax, numpy; print('python', sys.version.split()[0], 'jax', jax.__version__, "
                    "'numpy', numpy.__version__)"])
    tests = [ROOT / "tests"] if args.all else [ROOT / "tests" / t for t in SUBSET]
    # from outside the source tree, so that the installed geomopt is the one imported
    with tempfile.TemporaryDirectory() as cwd:
        done = subprocess.run([str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2",
                               *map(str, tests), *args.pytest_args], cwd=cwd)
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())

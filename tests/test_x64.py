"""Issue 17 item 3: geomopt computes in float64 beside float32 code (importing it leaves JAX's
global 64-bit flag alone), and entry points that cannot be traced say so with the traceable way.

The float64 checks run in a fresh interpreter: this suite's conftest switches x64 on globally."""

import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import Objective, ParameterError, Problem
from geomopt.mesh.generators import square_mesh
from geomopt.exact.topology import boundary_vertices

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r'''
import json, warnings
import numpy as np
import jax, jax.numpy as jnp
import geomopt
from geomopt import Objective, ParameterError, Problem
from geomopt.param import parameterize_map
from geomopt.solvers import minimize_map
from geomopt.mesh.generators import square_mesh
from geomopt.solvers import LBFGS
from geomopt.exact.topology import boundary_vertices

out = {"x64_after_import": bool(jax.config.jax_enable_x64)}
V, F = square_mesh(6)
V3 = np.c_[V, 0.3 * V[:, 0] * V[:, 1]]
r = geomopt.parameterize(V3, F, progress=False)
out["param_energy"], out["param_dtype"] = r.energy, str(r.x.dtype)
out["user_dtype_after"] = str(jnp.ones(2).dtype)  # float32 code beside geomopt
B = boundary_vertices(F, len(V))
x0 = V.copy(); x0[14] = [0.95, 0.9]
res = geomopt.untangling.untangle(Problem.planar(V, F, B, V[B]), x0, progress=False,
                                solver=LBFGS(rtol=1e-6, precondition="laplacian"))  # a host callback
out["untangle_success"] = bool(res.success)
obj = Objective(Problem.planar(V, F), "symmetric_dirichlet")
x = V + 0.01 * np.sin(7 * V)
out["value"] = float(obj.value(x))
solver = geomopt.Newton()
state = solver.step(solver.init(obj, x, obj.params()))  # driven by hand
out["by_hand"] = float(state.value)
try:
    jax.grad(lambda x: obj.value(x))(x)
    out["grad_off"] = "ran"
except ParameterError as e:
    out["grad_off"] = str(e)
x64 = getattr(jax, "enable_x64", None)  # jax.experimental.enable_x64 before JAX 0.7
if x64 is None:
    from jax.experimental import enable_x64 as x64
with x64(True):
    g = jax.grad(lambda x: obj.value(x))(x)
    out["grad_on_dtype"] = str(g.dtype)
    f = lambda h: jnp.sum(minimize_map(
        Objective(Problem.planar(V, F, B, jnp.asarray(V[B]).at[:4].set(h)), "symmetric_dirichlet"), x))
    gi = jax.jit(jax.grad(f))(jnp.asarray(V[B][:4]) + 0.01)
    out["implicit_jit_dtype"] = str(gi.dtype)
out["implicit_plain_dtype"] = str(parameterize_map(V3, F).dtype)
print(json.dumps(out))
'''


@pytest.fixture(scope="module")
def x64_off():
    """What the script reports from a process where nothing switched x64 on globally."""
    import json
    import os

    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_leaves_the_global_flag_and_float32_code_alone(x64_off):
    assert x64_off["x64_after_import"] is False
    assert x64_off["user_dtype_after"] == "float32"


def test_results_are_float64_and_equal_to_the_x64_process(x64_off):
    V, F = square_mesh(6)
    V3 = np.c_[V, 0.3 * V[:, 0] * V[:, 1]]
    r = geomopt.parameterize(V3, F, progress=False)
    assert x64_off["param_dtype"] == "float64"
    assert x64_off["param_energy"] == pytest.approx(r.energy, rel=1e-12)
    obj = Objective(Problem.planar(V, F), "symmetric_dirichlet")
    x = V + 0.01 * np.sin(7 * V)
    assert x64_off["value"] == pytest.approx(float(obj.value(x)), rel=1e-14)
    solver = geomopt.Newton()
    assert x64_off["by_hand"] == pytest.approx(float(solver.step(solver.init(obj, x, obj.params())).value), rel=1e-12)
    assert x64_off["untangle_success"] is True
    assert x64_off["implicit_plain_dtype"] == "float64"


def test_a_float32_trace_is_refused_and_a_float64_one_runs(x64_off):
    assert "enable_x64" in x64_off["grad_off"] and "float64" in x64_off["grad_off"]
    assert x64_off["grad_on_dtype"] == "float64"
    assert x64_off["implicit_jit_dtype"] == "float64"


def _refusals():
    V, F = square_mesh(4)
    V3 = np.c_[V, 0 * V[:, 0]]
    B = boundary_vertices(F, len(V))
    P = Problem.planar(V, F, B, V[B])
    obj = Objective(P, "arap")
    return V, V3, {
        "Objective.dets": lambda x: P.count_inverted(x),
        "Objective.dets(x)": lambda x: geomopt.exact.predicates.count_inverted(x, F),
        "Objective.dets(x) ": lambda x: geomopt.exact.certify.certify_bijective(x, F),
        "Objective.dets(x)  ": lambda x: P.signed_volumes(x),
        "jax.hessian": lambda x: obj.hessian(x, obj.params()),
        "Problem.planar/surface/tets": lambda V: geomopt.tutte_embedding(V, F),
    }


@pytest.mark.parametrize("hint", list(_refusals()[2]))
def test_entry_points_that_cannot_be_traced_say_what_to_use(hint):
    V, V3, cases = _refusals()
    arg = V3 if "parameterize" in hint or "Problem" in hint else V
    with pytest.raises(ParameterError, match="traced") as info:
        jax.grad(lambda a: jnp.sum(jnp.asarray(cases[hint](a), float)))(jnp.asarray(arg))
    assert hint.strip() in str(info.value) and "\n" not in str(info.value)

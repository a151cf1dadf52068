"""Rules that no test pinned (issue 30 item 6): mutants that inverted them survived the whole
suite.  One test of each rule itself, through the public functions:

* compare's reference is the *lower* of the tight Newton solve and the best solver;
* the certified writers (cells and LIM) certify the file read back, not the map in memory;
* the stopping rule never counts a slightly *rising* energy as converged;
* untangling's eps loop stops exactly when its own rule says so.
"""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geomopt
from geomopt import CompareOptions, SolveError, io
from geomopt.mesh import generators as G
from geomopt.mesh.cells import read_cell_case, write_certified
from geomopt.lim import LimCase
from geomopt.smoothing import element_problem
from geomopt.solvers import Outcome, Stats, Termination
from geomopt.solvers._termination import RUNNING
from geomopt.untangling import EpsContinuation, UntangleOptions, untangle

from conftest import grid
from test_cli import one_error_line

compare_module = importlib.import_module("geomopt.experiments.comparison")
V2, F = grid(4)
V3 = np.c_[V2, 0.3 * np.sin(3.0 * V2[:, 0]) * V2[:, 1]]  # test_compare's curved disk


# ------------------------------------------------------------------ compare's reference


def test_compare_reference_is_the_lower_of_the_newton_reference_and_the_best_solver(monkeypatch):
    """Inverted, every gap in the table is measured to the wrong energy: to a solver's energy
    above the Newton reference, or to a reference above a solver's energy."""
    early = geomopt.compare(V3, F, solvers=["lbfgs"], options=CompareOptions(max_steps=3))  # stopped far above the min
    ref = early.reference
    assert "lower" not in ref.detail and ref.energy == ref.detail["energy"]
    assert ref.energy < early.results["lbfgs"].energy and early.gap("lbfgs")[-1] > 0
    # a reference solve cut to one Newton step: the solver that went lower is the reference
    monkeypatch.setattr(compare_module, "REFERENCE_MAX_STEPS", 1)
    cut = geomopt.compare(V3, F, solvers=["newton"])
    ref = cut.reference
    assert ref.detail["lower"] == "newton" and ref.energy < ref.detail["energy"]
    assert ref.energy == np.min(cut.results["newton"].energy_history) and cut.gap("newton")[-1] == 0.0


# ------------------------------------------------------------------ the certified writers


def _corrupting(write, how):
    """A writer that writes ``how(x)`` instead of the map ``x`` it is given (a writer that
    rounds or corrupts: the bytes on disk are not the map in memory)."""

    def corrupt(path, x, *args, **kwargs):
        return write(path, how(np.array(x, dtype=np.float64)), *args, **kwargs)

    return corrupt


def _shift_row(i, by):
    def how(x):
        x[i] += by
        return x

    return how


@pytest.mark.parametrize("kind", ["quad", "hexahedron"])
def test_cells_write_certified_certifies_the_file_not_the_map_in_memory(monkeypatch, tmp_path, kind):
    V, E = G.sector_mesh(2, 3, 0 if kind == "quad" else 2, perturb=0.2, seed=1)
    src = io.write_cells(tmp_path / "in.vtk", V, E, kind)
    case = read_cell_case(src)
    problem = element_problem(V, E)
    out = tmp_path / "out.vtk"
    assert write_certified(out, V, case, problem)["local_certificate"].ok  # the map itself certifies
    before = out.read_bytes()
    handle = int(problem.fixed[0])
    interior = int(np.setdiff1d(np.arange(len(V)), problem.fixed)[0])
    far = 10.0 * (V.max(axis=0) - V.min(axis=0))  # an interior vertex thrown out: its elements fold
    for how, words in ((_shift_row(handle, 1e-9), "1 handle(s) moved"), (_shift_row(interior, far), "without a "
                                                                         "positive Jacobian")):
        monkeypatch.setattr(io, "write_cells", _corrupting(io.write_cells, how))
        with pytest.raises(SolveError, match="the written file did not certify") as info:
            write_certified(out, V, case, problem)
        assert words in str(info.value) and "nothing was written" not in str(info.value)
        # what failed travels with it: the file's certificate (its elements fold only when thrown out)
        assert info.value.result is None and info.value.certificate.ok == words.startswith("1 handle")
        monkeypatch.undo()
        assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.vtk", "out.vtk"]  # no temporary left


def test_the_command_line_says_nothing_was_written_once(cli, monkeypatch, tmp_path):
    V, E = G.sector_mesh(3, 5, perturb=0.3, seed=3)
    src = io.write_cells(tmp_path / "in.vtk", V, E, "quad")
    b = element_problem(V, E).fixed
    monkeypatch.setattr(io, "write_cells", _corrupting(io.write_cells, _shift_row(int(b[0]), 1e-9)))
    code, _, err = cli("smooth", src, "-o", tmp_path / "out.vtk", "--quiet")
    line = one_error_line(err, "the written file did not certify (1 handle(s) moved)")
    assert code == 1 and line.count("nothing") == 1 and line.endswith("; nothing written")
    assert not (tmp_path / "out.vtk").exists()


@pytest.mark.parametrize("dim", [2, 3])
def test_lim_write_certified_certifies_the_file_not_the_map_in_memory(monkeypatch, tmp_path, dim):
    t = G.rotated_interior(*(G.square_mesh(5) if dim == 2 else G.box_mesh(2, 2, 2)), 90.0)
    case = LimCase.from_tangle(t)
    x = np.asarray(t.rest, dtype=np.float64)  # the rest mesh: a valid map with the handles in place
    out = tmp_path / ("out.obj" if dim == 2 else "out.vtk")
    assert case.write_certified(x, out)["certified"]
    before = out.read_bytes()
    lim = importlib.import_module("geomopt.lim")
    name = "write_obj_with_uv" if dim == 2 else "write_vtk_tets"
    original = getattr(lim, name)
    interior = int(np.setdiff1d(np.arange(len(x)), case.handles)[0])

    def writer(how):
        if dim == 3:
            return _corrupting(original, how)
        return lambda path, rest, S, uv: original(path, rest, S, how(np.array(uv, dtype=np.float64)))

    for how, words in ((_shift_row(int(case.handles[0]), 1e-9), r"1 handle\(s\) moved"),
                       (_shift_row(interior, 10.0), "inverted or degenerate")):
        monkeypatch.setattr(lim, name, writer(how))
        with pytest.raises(SolveError, match=words) as info:
            case.write_certified(x, out)
        assert (info.value.certificate.inverted > 0) == (words == "inverted or degenerate")
        monkeypatch.undo()
        assert out.read_bytes() == before


# ------------------------------------------------------------------ the stopping rule


def test_a_slightly_rising_energy_is_not_convergence():
    """The stall test asks for an energy that *fell* by at most ftol: one that rose by as
    little is not convergence (a search that accepts uphill steps would stop 'converged'), on
    host and traced values alike."""
    rule = Termination(rtol=0.0, ftol=1e-12, stall=1e-5, max_steps=100)
    base = Stats(iteration=3, value=1.0, past_value=1.0, decrement=1e-9, step_size=1.0, grad_norm=1.0,
                 grad_norm0=1.0, extent=1.0, extent0=1.0)
    traced = jax.jit(rule.status)
    for value, expected in ((1.0 - 4e-13, Outcome.CONVERGED.code), (1.0, Outcome.CONVERGED.code),
                            (1.0 + 4e-13, RUNNING), (1.0 + 1e-15, RUNNING)):
        s = base._replace(value=value)
        assert rule(s) == expected == int(traced(Stats(*(jnp.asarray(v) for v in s)))), value


# ------------------------------------------------------------------ the eps loop's stop rule


def test_the_eps_loop_stops_exactly_when_its_rule_says_so(monkeypatch):
    """After each inner solve the eps loop stops, converged, iff nothing is inverted
    (``det J > 0`` in float, then the exact count of the whole map is 0) and the energy settled:
    ``|E_prev - E| / |E| < energy_tol``, ``E_prev`` the previous map's energy at this eps.  Every
    outer iteration is checked against the rule, so stopping early, late or never is caught."""
    seen = []
    decide = EpsContinuation.__call__

    def spy(self, state, outcome):
        E_prev = self.E
        decision = decide(self, state, outcome)
        r = decision.record
        if r is not None:  # an outer iteration (not a probe's switch)
            x = self.full.unpad_map(np.asarray(state.x))
            untangled = r.min_det > 0 and self.scaled.count_inverted(x) == 0
            settled = abs(E_prev - r.energy) / abs(r.energy) < self.options.energy_tol
            seen.append((untangled and settled, decision.stop and decision.outcome is Outcome.CONVERGED))
        return decision

    monkeypatch.setattr(EpsContinuation, "__call__", spy)
    t = G.noisy_interior(*G.square_mesh(8), 2.0)
    # settles a few iterations after untangling; the eps loop's rule alone (the polish after it is a phase of its own)
    res = untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(energy_tol=1e-8, polish=False))
    assert res.success and len(seen) == res.stats.outer_iterations >= 3
    assert [rule for rule, _ in seen] == [stopped for _, stopped in seen] == [False] * (len(seen) - 1) + [True]

"""Untangling (Garanzha et al. 2021) and the L-BFGS solver.

Every LIM case in ../shared/data/lim is untangled and certified: no inverted element under the
exact predicate, handles unchanged bit for bit, also in the file written and read back.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from geomopt.mesh import generators as G
from geomopt._runtime.errors import MeshError, ParameterError, SolveError
from geomopt.objective.objective import Objective
from geomopt.lim import LimCase, untangle_case
from geomopt.solvers.linesearch import InjectiveSearch
from geomopt.exact.predicates import count_inverted
from geomopt.mesh.problem import Problem
from geomopt.solvers import Newton, Outcome, minimize
from geomopt.solvers import lbfgs as lbfgs_module
from geomopt.solvers.lbfgs import LBFGS
from geomopt.untangling import continuation, driver, schedule
from geomopt.energies import chi
from geomopt.untangling import default_solver, next_eps, untangle
from test_objective import cot_laplacian
from geomopt import UntangleOptions

from conftest import LIM_ROOT
CASES = LimCase.cases(LIM_ROOT) if LIM_ROOT.is_dir() else []


def _bits_equal(a, b):
    a, b = np.ascontiguousarray(a, np.float64), np.ascontiguousarray(b, np.float64)
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


# ----------------------------------------------------------------------------- LIM cases


@pytest.mark.parametrize("folder", CASES or [None], ids=[c.name for c in CASES] or ["missing"])
def test_lim_case_untangled_and_certified(folder, tmp_path):
    if folder is None:
        pytest.skip(f"LIM sample data not found under {LIM_ROOT} (clone the project next to shared/)")
    case, result = untangle_case(folder, progress=False)
    if folder.name == "armadillo-598":
        # every tet around 5 boundary edges has all four vertices fixed, and those tets turn
        # 1.0-1.2 times around each edge in the given handle positions: no map with these
        # handles is locally injective there (a property of the input, issue 19); everything a
        # free vertex reaches is, and the forced overlap is reported (issue 30; tests/test_fixed_stars.py)
        assert result.outcome is Outcome.CERTIFIED_EXCEPT_FIXED and not result.success, result.message
        assert result.certificate.valid_except_forced and "(752, 782)" in result.message
        check = case.write_certified(result, tmp_path / "out.vtk")
        assert check["outcome"] == "certified_except_fixed" and check["inverted"] == check["handles_moved"] == 0
        return
    assert result.success, result.message
    assert result.stats.inverted_at_start > 0
    H = case.handles
    # exact predicate on the returned map, in the case's own connectivity and orientation
    assert count_inverted(result.x, case.simplices, orientation=case.to_problem().orientation) == 0
    assert _bits_equal(result.x[H], case.init[H])
    assert result.min_det_rel > 0
    assert len(result.trace.energy) == len(result.trace.phases) == result.stats.outer_iterations
    # the written file certifies too (read back: exact predicate, handles bit-exact)
    out = tmp_path / ("result.obj" if case.dim == 2 else "result.vtk")
    report = case.write_certified(result, out)
    assert report["certified"] and report["path"] == out, report
    if case.dim == 2:
        back = read_lim2d_like(out)
        assert _bits_equal(back, result.x)


def read_lim2d_like(path):
    """The ``vt`` lines of an OBJ written by LimCase.write_certified."""
    folder = path.parent / "readback"
    folder.mkdir()
    shutil.copy(path, folder / "input.obj")
    (folder / "handles.txt").write_text("")
    return LimCase.read(folder).init


def test_lim_case_clockwise_map(tmp_path):
    """A 2D case whose map is clockwise overall (mirrored) is solved in the mirrored frame."""
    src = LIM_ROOT / "2D" / "Simple" / "square_rot90"
    if not src.is_dir():
        pytest.skip(f"LIM sample data not found under {LIM_ROOT}")
    dst = tmp_path / "mirrored"
    dst.mkdir()
    shutil.copy(src / "handles.txt", dst / "handles.txt")
    lines = []
    for line in (src / "input.obj").read_text().splitlines():
        t = line.split()
        if t and t[0] == "vt":
            u = float(t[1])
            line = f"vt {-u!r} {t[2]}"
        lines.append(line)
    (dst / "input.obj").write_text("\n".join(lines) + "\n")
    case, result = untangle_case(dst, progress=False)
    assert case.to_problem().orientation == -1
    assert result.success, result.message
    assert count_inverted(result.x, case.simplices, orientation=-1) == 0
    assert case.write_certified(result, tmp_path / "out.obj")["certified"]


@pytest.mark.parametrize("name", ["square", "cube"])
def test_write_certified_refuses_a_folded_map_or_a_moved_handle(name, tmp_path):
    """Only a file that certifies replaces the target: a folded map (the tangled start) or a
    map with one handle moved by one ulp raises SolveError and leaves the old file as it was."""
    t = G.rotated_interior(*(G.square_mesh(6) if name == "square" else G.box_mesh(3, 3, 3)), 90.0)
    case = LimCase.from_tangle(t)
    case, result = untangle_case(case, progress=False)
    assert result.success, result.message
    out = tmp_path / ("out.obj" if case.dim == 2 else "out.vtk")
    assert case.write_certified(result, out)["certified"]
    before = out.read_bytes()
    moved = result.x.copy()
    h = case.handles[0]
    moved[h, 0] = np.nextafter(moved[h, 0], np.inf)
    for bad, words in ((case.init, "inverted or degenerate"), (moved, "1 handle")):
        with pytest.raises(SolveError, match=words):
            case.write_certified(bad, out)
        assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]  # no temporary left


def test_lim_problem_rejects_collapsed_and_mirrored_maps():
    V, F = G.square_mesh(4)
    b = G.boundary_vertices(F, len(V))
    rest = np.column_stack([V, np.zeros(len(V))])
    with pytest.raises(MeshError, match="collapsed"):
        LimCase(2, rest, np.zeros_like(V), F, b).to_problem()
    P, T = G.box_mesh(2, 2, 2)
    b = G.boundary_vertices(T, len(P))
    with pytest.raises(MeshError, match="mirrored"):
        LimCase(3, P, P * [-1.0, 1.0, 1.0], T, b).to_problem()
    # a clockwise 2D map is accepted, mirrored (exactly) into the problem's frame
    b = G.boundary_vertices(F, len(V))
    problem, x0, orientation, mirror = LimCase(2, rest, V * [-1.0, 1.0], F, b).to_problem()
    assert orientation == -1 and _bits_equal(x0, V)


def test_lim_problem_accepts_a_negative_total_when_part_of_the_boundary_is_free():
    """The total signed volume is fixed only when the whole boundary is: a tet whose free
    apex was pushed through its fixed base has a negative total and is untangled, not refused
    as mirrored."""
    P = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1]])
    T = np.array([[0, 1, 2, 3]])
    init = P * [1.0, 1.0, -1.0]
    case = LimCase(3, P, init, T, np.array([0, 1, 2]))
    problem, x0, orientation, _ = case.to_problem()
    assert float(problem.signed_volumes(x0).sum()) < 0 and orientation == 1
    result = untangle(problem, x0, progress=False)
    assert result.success and count_inverted(result.x, T) == 0
    with pytest.raises(MeshError, match="whole boundary fixed"):
        dataclasses.replace(case, handles=np.arange(4)).to_problem()


# ----------------------------------------------------------------------------- synthetic


def test_square_interior_rotated_180():
    V, F = G.square_mesh(16)
    t = G.rotated_interior(V, F, 180.0)
    assert t.inverted() > 0
    problem = t.problem()
    result = untangle(problem, t.x0, progress=False)
    assert result.success, result.message
    assert problem.count_inverted(result.x) == 0
    assert _bits_equal(result.x[t.fixed], t.x0[t.fixed])


@pytest.mark.parametrize("make", [
    lambda: G.rotated_interior(*G.box_mesh(5, 5, 5), 180.0),
    lambda: G.twisted_box(4, 4, 0.5),
], ids=["cube-rotated", "cube-twisted"])
def test_cube_interior_tangled(make):
    t = make()
    assert t.inverted() > 0
    problem = t.problem()
    result = untangle(problem, t.x0, progress=False)
    assert result.success, result.message
    assert count_inverted(result.x, t.simplices) == 0
    assert _bits_equal(result.x[t.fixed], t.x0[t.fixed])


@pytest.mark.parametrize("solver", ["newton", LBFGS(precondition="laplacian", rtol=1e-6, gtol=1e-6)],
                         ids=["newton", "lbfgs-laplacian"])
def test_tutte_onto_star_untangled_with_other_inner_solvers(solver):
    """Projected Newton (non-injective line search) and Laplacian-preconditioned L-BFGS
    also untangle."""
    t = G.tutte_nonconvex(6, "star", arms=5, depth=0.6)
    assert t.inverted() > 0
    result = untangle(t.problem(), t.x0, solver=solver, progress=False)
    assert result.success, result.message


def test_progress_lines_and_result_fields(caplog, capsys):
    caplog.set_level(logging.DEBUG, logger="geomopt")
    t = G.rotated_interior(*G.square_mesh(8), 90.0)
    result = untangle(t.problem(), t.x0, progress=True)
    assert capsys.readouterr() == ("", "")  # nothing printed into a pipe: the records go to the logger
    err = [r.getMessage() for r in caplog.records if r.name == "geomopt"]
    assert len(err) == result.stats.outer_iterations
    assert all(line.startswith("outer") and "eps" in line and "inverted" in line for line in err)
    assert result.outcome is Outcome.CONVERGED and result.certificate.handles_moved == 0
    assert result.stats.iterations >= result.stats.outer_iterations
    assert len(result.trace.column("eps")) == len(result.trace.column("min_det")) == result.stats.outer_iterations
    assert result.trace.column("min_det")[-1] > 0 and result.trace.column("inverted", int)[-1] == 0
    assert result.stats.seconds > 0 and result.stats.setup_seconds >= 0


def test_infeasible_reports_and_throws():
    """A tangled triangle whose vertices are all fixed cannot be repaired."""
    V, F = G.square_mesh(3)
    x0 = V.copy()
    x0[[0, 1]] = x0[[1, 0]]  # swap two corners: their triangle is inverted, all its vertices fixed
    problem = Problem.planar(V, F, np.arange(len(V)), x0)
    result = untangle(problem, x0, progress=False)
    assert not result.success and result.outcome is Outcome.NOT_INJECTIVE
    assert "every vertex fixed" in result.message
    assert result.problem.n_elements == len(F)  # the CLI summary prints it (it printed '?')
    with pytest.raises(SolveError):
        untangle(problem, x0, progress=False, throw=True)


@pytest.mark.parametrize("dim", [2, 3])
def test_mirrored_fixed_boundary_refused_at_once(dim):
    """Every boundary vertex fixed, boundary mirrored: no injective map; said at once, not after
    max_outer iterations (it ran 200 outer iterations to 'outer-iteration limit' before)."""
    V, S = G.disk_mesh(4) if dim == 2 else G.box_mesh(3, 3, 3)
    bnd = G.boundary_vertices(S, len(V))
    x0 = V.copy()
    x0[:, 0] = -x0[:, 0]
    make = Problem.planar if dim == 2 else Problem.tets
    problem = make(V, S, bnd, x0[bnd])
    result = untangle(problem, x0, progress=False)
    assert not result.success and result.outcome is Outcome.NOT_INJECTIVE
    assert result.stats.outer_iterations == 0 and "mirrored" in result.message
    with pytest.raises(SolveError, match="no map can change"):
        untangle(problem, x0, progress=False, throw=True)
    # one boundary vertex free: the total is no longer fixed, so no refusal at setup
    free_one = make(V, S, bnd[1:], x0[bnd[1:]])
    assert "mirrored" not in untangle(free_one, x0, progress=False, options=UntangleOptions(max_outer=1)).message


def test_boundary_winding_twice_is_not_success():
    """A fixed boundary that winds twice has no locally injective map; untangling reaches every
    triangle positive around a branch vertex (angle sum 4 pi), which was reported as success."""
    from geomopt.exact.predicates import vertex_windings

    V, F = G.disk_mesh(10)
    t = G.random_interior(V, F, seed=5)
    bnd = G.boundary_vertices(F, len(V))
    ang = np.arctan2(V[bnd, 1], V[bnd, 0])
    r = 1.0 + 0.5 * np.cos(7.0 * ang)
    x0 = t.x0.copy()
    x0[bnd] = np.c_[np.cos(2.0 * ang) * r, np.sin(2.0 * ang) * r]
    interior = np.setdiff1d(np.arange(len(V)), bnd)
    assert (vertex_windings(V, F)[interior] == 1).all()
    Vs, Fs = G.square_mesh(5)  # grid: neighbours at exactly the vertex's height (half-open sectors)
    inner_s = np.setdiff1d(np.arange(len(Vs)), G.boundary_vertices(Fs, len(Vs)))
    assert (vertex_windings(Vs, Fs)[inner_s] == 1).all()
    result = untangle(Problem.planar(V, F, bnd, x0[bnd]), x0, progress=False)
    assert result.certificate.inverted == 0  # the local predicate alone is satisfied...
    assert (vertex_windings(result.x, F)[interior] > 1).any()
    assert not result.success and result.outcome is Outcome.NOT_INJECTIVE  # ...but no success
    assert "branch" in result.message and len(result.certificate.branch_vertices) >= 1
    # given as a start map, that flip-free but branched map is repaired, not optimised as it is
    from geomopt.param import parameterize
    from geomopt.exact.predicates import branch_vertices

    res = parameterize(np.c_[V, np.zeros(len(V))], F, x0=result.x, progress=False)
    assert res.details.repair is not None and res.success
    assert count_inverted(res.x, F) == 0 and len(branch_vertices(res.x, F)) == 0


def test_bad_arguments():
    t = G.rotated_interior(*G.square_mesh(4), 90.0)
    with pytest.raises(ParameterError):
        untangle(t.problem(), t.x0, solver="gradient-descent", progress=False)
    with pytest.raises(ParameterError):
        untangle(t.problem(), t.x0, options=UntangleOptions(theta=1.5), progress=False)
    # no handles is no longer an error: a free boundary (tests/test_freeboundary.py); a tangled
    # mesh without any handle is one part without a handle: held at its rest shape moved onto
    # the given map (the eps loop ended flip-free around a branch vertex there, issue 30)
    free = Problem.planar(t.rest, t.simplices)
    res = untangle(free, t.x0, progress=False)
    assert res.success and (res.details.free_parts, res.details.rest_parts) == (1, 1), res.message


def test_outer_loop_compiles_once():
    """eps and lambda are traced: a second untangling of the same mesh shape compiles nothing,
    and one untangling compiles each kernel once however many outer iterations it runs."""
    t = G.tutte_nonconvex(7, "L")
    kernels = [lbfgs_module._run_kernel, lbfgs_module._reparam_kernel,
               continuation._outer_stats]
    before = [k._cache_size() for k in kernels]
    with lowered_programs() as lowered:
        r1 = untangle(t.problem(), t.x0, progress=False)
    # only the kernels the loop runs (no step kernel, no per-shape copy programs); jax < 0.5
    # (the floor, 0.4.38) names no program in its events: there the cache sizes below decide
    names = {"jit(_run_kernel)", "jit(_reparam_kernel)", "jit(_outer_stats)", "jit(convert_element_type)",
             # the final Newton polish (UntangleOptions.polish): its Hessian, search and last step
             "jit(value_and_grad_kernel)", "jit(hessian_kernel)", "jit(_search_kernel)", "jit(_admissible_kernel)",
             "jit(add)"}
    if not any(name.startswith("/jax/") for name in lowered):
        assert set(lowered) <= names, lowered
    mid = [k._cache_size() for k in kernels]
    assert r1.success and r1.stats.outer_iterations > 2
    assert all(m - b <= 1 for b, m in zip(before, mid))
    r2 = untangle(t.problem(), t.x0, progress=False)
    assert [k._cache_size() for k in kernels] == mid
    assert r2.stats.outer_iterations == r1.stats.outer_iterations
    np.testing.assert_array_equal(r2.x, r1.x)


def test_next_eps_cap_applies_only_while_inverted():
    """sigma = 1 - E/E_prev = 0.99 here: with nothing inverted the paper's rule sends eps to the
    floor; with an element still inverted the cap (0.5) halves chi(D-, eps) instead."""
    assert next_eps(1.0, 1.0, 100.0, 0.02, floor=1e-10) == 1e-10
    eps = next_eps(1.0, 1.0, 100.0, -0.02, floor=1e-10)
    assert float(chi(-0.02, eps)) == pytest.approx(0.5 * float(chi(-0.02, 1.0)), rel=1e-12)
    # untangled, but the energy barely moved: sigma = min_sigma, chi(D-, eps) halves
    eps = next_eps(1.0, 99.0, 100.0, 0.02, floor=1e-10)
    assert float(chi(0.02, eps)) == pytest.approx(0.5 * float(chi(0.02, 1.0)), rel=1e-12)


def test_eps_reaches_the_floor_in_one_step_once_nothing_is_inverted():
    """A twisted cube untangled by the first inner solve: the next eps is the floor (the cap
    used to take it to 0.40 first: 4 outer iterations instead of 3)."""
    t = G.twisted_box(6, 6, 0.75)
    result = untangle(t.problem(), t.x0, progress=False)
    assert result.success, result.message
    assert result.trace.column("inverted", int)[0] == 0
    assert result.trace.column("eps")[1] == schedule.EPS_FLOOR[3]
    assert result.stats.outer_iterations == 4  # three eps solves and the final polish


def test_random_interior_disk_needs_the_cap_while_inverted():
    """Without the cap, the first inner solve (energy down by orders of magnitude, half the
    triangles still folded) sends eps to ~0 and the loop stalls with folds left; with it, this
    disk untangles in a few outer iterations."""
    t = G.random_interior(*G.disk_mesh(60), seed=0)
    # the diagonal seed throughout: the default's switch to the Laplacian seed untangles this
    # disk within its first outer iteration, where the cap does not come into play
    solver = default_solver("lbfgs", 2)
    # the paper's eps0 = 1: from start_eps's (151 here) the first solve leaves 1,637 folds
    # instead of 12,335 and the loop untangles with or without the cap
    result = untangle(t.problem(), t.x0, solver=solver, progress=False, options=UntangleOptions(max_outer=30, eps0=1.0))
    assert result.success, result.message
    assert result.trace.column("inverted", int)[0] > 0 and result.stats.outer_iterations <= 6


def test_start_eps_is_one_unless_the_start_is_scattered():
    """Locally tangled starts (median |det J| of the normalised start below START_RATIO: rotated,
    noisy, squashed boundaries) keep the paper's eps0 = 1; a start scattered over the domain
    begins at a tenth of its median |det J|; an explicit eps0 is used as given."""
    V, F = G.square_mesh(17)
    V4, Q = G.quad_mesh(16, 16)
    for t in (G.rotated_interior(V, F, 180), G.noisy_interior(V, F, 2.0, seed=1), G.squashed_boundary(V4, Q, 0.7),
              G.noisy_interior(*G.box_mesh(5, 5, 5), 1.0, seed=1)):
        given = UntangleOptions(max_outer=1, start="given")
        assert untangle(t.problem(), t.x0, progress=False, options=given).trace.column("eps")[0] == 1.0, t.name
    t = G.random_interior(V4, Q, seed=1)  # quads: from the given map, not the harmonic start of "auto"
    given = UntangleOptions(max_outer=1, start="given")
    assert untangle(t.problem(), t.x0, progress=False, options=given).trace.column("eps")[0] > 1.0
    assert untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(max_outer=1, eps0=1.0, start="given")
                    ).trace.column("eps")[0] == 1.0
    with pytest.raises(ParameterError):
        untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(eps0=0.0))


@pytest.mark.parametrize("mesh", ["quads", "triangles"])
def test_scattered_start_first_solve_does_not_grow_with_the_mesh(mesh):
    """Interior vertices scattered over the square (random_interior): the normalised start's
    determinants cancel in the mean but their median is ~0.1 n^2 (about 700 here).  At eps = 1
    the first inner solve's iterations grew with the mesh (80^2 quads 614, 2 x 80^2 triangles
    757, 100^2 quads 1,458, 200^2 13,846) until on 316^2 quads it stalled with half the corners
    inverted and the loop never untangled (issue 18); from start_eps these take 157 and 176."""
    V, S = G.quad_mesh(80, 80) if mesh == "quads" else G.square_mesh(81)
    t = G.random_interior(V, S, seed=1)
    # quads: not the harmonic start
    result = untangle(t.problem(), t.x0, progress=False, options=UntangleOptions(start="given"))
    assert result.success, result.message
    assert result.trace.column("eps")[0] > 10.0
    assert result.stats.iterations < 250, result.stats.iterations


def test_generators_are_valid():
    for V, S in (G.square_mesh(5), G.disk_mesh(4), G.box_mesh(2, 3, 4)):
        assert count_inverted(V, S) == 0
    V, F = G.disk_mesh(5)
    b = G.boundary_vertices(F, len(V))
    np.testing.assert_array_equal(b, np.arange(len(V) - 30, len(V)))
    assert not np.isin(F, b).all(axis=1).any()  # no triangle with every vertex on the boundary
    for t in (G.noisy_interior(V, F, 2.0), G.tutte_nonconvex(5, "crescent"),
              G.bent_box(2, 8, 180.0), G.random_interior(V, F)):
        assert t.inverted() > 0
        assert _bits_equal(t.x0[t.fixed], t.problem().fixed_positions)


# ----------------------------------------------------------------------------- L-BFGS




@contextlib.contextmanager
def lowered_programs():
    """The programs JAX lowers in the block (each in-memory compilation-cache miss, whether
    XLA then compiles it or loads it from the persistent cache), as a list of program names."""
    seen = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/jaxpr_to_mlir_module_duration":
            seen.append(kwargs.get("fun_name", event))

    jax.monitoring.register_event_duration_secs_listener(listen)
    unregister = getattr(jax.monitoring, "unregister_event_duration_listener", None)
    if unregister is None:  # jax < 0.5 (the floor, 0.4.38): only the private name
        from jax._src import monitoring

        unregister = monitoring._unregister_event_duration_listener_by_callback
    try:
        yield seen
    finally:
        unregister(listen)


def test_lbfgs_reaches_the_harmonic_map():
    """Dirichlet energy with a fixed boundary: the minimiser solves the cotangent Laplace
    equation, which scipy solves directly."""
    V, F = G.disk_mesh(8)
    b = G.boundary_vertices(F, len(V))
    target = V.copy()
    target[b] = V[b] * [1.5, 0.8] + 0.2 * V[b, ::-1] ** 2
    problem = Problem.planar(V, F, b, target[b])
    L = cot_laplacian(V, F).tocsc()
    inner = np.setdiff1d(np.arange(len(V)), b)
    X = target.copy()
    X[inner] = spla.spsolve(L[inner][:, inner], -L[inner][:, b] @ target[b])
    obj = Objective(problem, "dirichlet")
    result = minimize(obj, V, LBFGS(rtol=0.0, gtol=1e-12, max_steps=5000), progress=False)
    assert result.outcome is Outcome.CONVERGED, result.message
    np.testing.assert_allclose(result.x, X, atol=1e-8)
    assert _bits_equal(result.x[b], target[b])
    # advance() (the whole loop in one jitted while_loop) gives the same iterates as step(),
    # with the same programs (step is the loop with a limit of one more iteration), which a
    # solver differing only in max_steps shares too: stepping and running again lowers nothing
    s = LBFGS(rtol=0.0, gtol=1e-12, max_steps=4000)
    x0 = jnp.asarray(problem.check_map(V))
    with lowered_programs() as lowered:
        state = s.init(obj, x0, obj.params(), precompile=False)
        state = s.advance(s.step(state), s.max_steps)
    assert lowered == []
    assert state.iteration == result.stats.iterations
    np.testing.assert_allclose(np.asarray(state.x), result.x, rtol=0, atol=1e-13)


@pytest.mark.parametrize("precondition", ["scalar", "diagonal", "laplacian"])
@pytest.mark.parametrize("c2", [0.9, 0.0])
def test_lbfgs_variants_converge(precondition, c2):
    V, F = G.square_mesh(6)
    b = G.boundary_vertices(F, len(V))
    problem = Problem.planar(V, F, b, V[b] * 1.3)
    obj = Objective(problem, "dirichlet")
    result = minimize(obj, V, LBFGS(precondition=precondition, search=InjectiveSearch(c2=c2), gtol=1e-10, rtol=1e-14),
                      progress=False)
    assert result.outcome is Outcome.CONVERGED
    np.testing.assert_allclose(result.x, V * 1.3, atol=1e-7)


@pytest.mark.parametrize("backend", ["host", "device"])
def test_lbfgs_laplacian_preconditioner_is_exact_for_dirichlet(backend):
    """For the Dirichlet energy the Laplacian seed is the inverse Hessian: the first step
    lands on the minimum (to the device CG's tolerance: a few more steps).  The search's
    first trial may reach 0.9 of the flip bound (the default's quarter cuts the first
    step: 5 iterations instead of 3)."""
    V, F = G.disk_mesh(10)
    b = G.boundary_vertices(F, len(V))
    target = V.copy()
    target[b] = V[b] * [1.4, 0.9]
    problem = Problem.planar(V, F, b, target[b])
    obj = Objective(problem, "dirichlet")
    result = minimize(obj, V, LBFGS(precondition="laplacian", laplacian=backend, gtol=1e-10, rtol=0.0,
                                    search=InjectiveSearch(c2=0.9)), progress=False)
    assert result.outcome is Outcome.CONVERGED and result.stats.iterations <= (3 if backend == "host" else 8)
    np.testing.assert_allclose(result.x, V * [1.4, 0.9], atol=1e-9)


@pytest.mark.parametrize("case", ["disk-fixed", "disk-free", "box-fixed"])
def test_device_laplacian_solve_equals_the_host_factorization(case):
    """The device operator (COO + Jacobi PCG in JAX) solves the same system as the host
    Cholesky, on per-vertex and per-DOF free sets; warm starts converge to the same answer."""
    from geomopt.solvers._laplacian import RestLaplacian

    if case == "box-fixed":
        V, T = G.box_mesh(3, 3, 4)
        problem = Problem.tets(V, T, G.boundary_vertices(T, len(V))[:20], V[G.boundary_vertices(T, len(V))[:20]])
    else:
        V, T = G.disk_mesh(6)
        b = G.boundary_vertices(T, len(V))
        problem = Problem.planar(V, T, b, V[b]) if case == "disk-fixed" else Problem.planar(V, T)
    obj = Objective(problem, "dirichlet")
    q = np.random.default_rng(0).normal(size=V.shape)
    exact = RestLaplacian(obj, "host").solve(q)
    dev = RestLaplacian(obj, "device", rtol=1e-12, maxiter=2000).operator
    for guess in (np.zeros_like(q), exact + 1e-3):
        np.testing.assert_allclose(np.asarray(dev.solve(jnp.asarray(q), jnp.asarray(guess))), exact,
                                   rtol=1e-8, atol=1e-8 * np.abs(exact).max())


def test_device_laplacian_lbfgs_makes_no_host_round_trip():
    """With ``laplacian="device"`` the L-BFGS iteration's program has no host callback (what
    lets it run on an accelerator without syncing); with ``"host"`` it has one."""
    from geomopt.solvers.lbfgs import _iteration

    V, F = G.disk_mesh(4)
    b = G.boundary_vertices(F, len(V))
    obj = Objective(Problem.planar(V, F, b, V[b] * 1.2), "symmetric_dirichlet")
    for backend, callbacks in (("device", 0), ("host", 1)):
        solver = LBFGS(precondition="laplacian", laplacian=backend)
        state = solver.init(obj, V, obj.params(), precompile=False)
        density, geom, free = obj.energy.density, obj.geom, obj.free_mask
        jaxpr = jax.make_jaxpr(lambda c: _iteration(solver, density, geom, free, state.params, c))(
            state.memory.carry)
        host_calls = sum(str(jaxpr).count(k) for k in ("pure_callback", "ffi_call"))  # geomopt._runtime.hostcall
        assert (host_calls > 0) == bool(callbacks), backend
    with pytest.raises(ParameterError, match="laplacian"):
        LBFGS(laplacian="gpu")


def test_lbfgs_injective_line_search_keeps_orientation():
    """With the injective line search L-BFGS minimises a barrier energy from a flip-free start
    without ever flipping; it reaches Newton's minimum."""
    V, F = G.disk_mesh(5)
    b = G.boundary_vertices(F, len(V))
    target = V.copy()
    target[b] = V[b] * [1.6, 0.7]
    problem = Problem.planar(V, F, b, target[b])
    x0 = V * [1.6, 0.7]  # an affine start: flip-free
    obj = Objective(problem, "symmetric_dirichlet")
    seen = []

    def progress(state, elapsed, mean_energy):
        seen.append(problem.count_inverted(np.asarray(state.x)))

    solver = LBFGS(search=InjectiveSearch(injective=True, c2=0.9), rtol=1e-14, gtol=1e-10, max_steps=3000)
    result = minimize(obj, x0, solver, progress=progress)
    assert result.success and max(seen) == 0
    newton = minimize(obj, x0, Newton(), progress=False)
    assert result.energy == pytest.approx(newton.energy, rel=1e-9)


def test_lbfgs_bad_configuration():
    with pytest.raises(ParameterError):
        LBFGS(history=0)
    with pytest.raises(ParameterError):
        LBFGS(precondition="bfgs")
    with pytest.raises(ParameterError):
        LBFGS(search=InjectiveSearch(c2=1.0))


def test_lbfgs_stops_at_a_stationary_start():
    V, F = G.square_mesh(4)
    b = G.boundary_vertices(F, len(V))
    obj = Objective(Problem.planar(V, F, b, V[b]), "dirichlet")
    result = minimize(obj, V, LBFGS(), progress=False)  # the identity is already harmonic
    assert result.outcome is Outcome.CONVERGED and result.stats.iterations <= 1
    np.testing.assert_allclose(result.x, V, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_rest_laplacian_is_the_dirichlet_hessian(dim):
    """The Laplacian seed's directly assembled K equals the autodiff Hessian of the Dirichlet
    energy, per coordinate (2D: a disk; 3D: a box)."""
    from geomopt.solvers._laplacian import rest_laplacian

    if dim == 2:
        V, F = G.disk_mesh(3)
        problem = Problem.planar(V, F)
    else:
        V, T = G.box_mesh(2, 2, 3)
        problem = Problem.tets(V, T)
    obj = Objective(problem, "dirichlet")
    pat = obj.pattern
    H = pat.matrix(np.asarray(obj.hessian(jnp.zeros_like(jnp.asarray(V)), {}, "none")[2])).toarray()
    full = np.zeros((V.size, V.size))
    full[np.ix_(pat.free_dofs, pat.free_dofs)] = H
    K = rest_laplacian(problem).toarray()
    for c in range(dim):
        dofs = np.arange(len(V)) * dim + c
        keep = np.isin(dofs, pat.free_dofs)  # Objective pins the first vertex of a free problem
        np.testing.assert_allclose(full[np.ix_(dofs[keep], dofs[keep])], K[np.ix_(keep, keep)],
                                   atol=1e-12)


# ------------------------------------------------- connected parts without handles (issue 30)


def _two_blocks(tangle_b):
    """Two 3^3 hex blocks side by side: A's interior rotated by 120 degrees, its boundary the
    handles; B without any handle, at rest (``tangle_b`` False) or with noisy vertices."""
    V, H = G.hex_mesh(3, 3, 3)
    a = G.rotated_interior(V, H, 120.0)
    b = G.noisy_interior(V, H, 1.0, seed=2).x0 if tangle_b else V
    W, HH = np.concatenate([V, V + [2.0, 0.0, 0.0]]), np.concatenate([H, H + len(V)])
    x0 = np.concatenate([a.x0, b + [2.0, 0.0, 0.0]])
    return Problem.hexes(W, HH, a.fixed, a.x0[a.fixed]), x0, a, len(V)


def test_a_valid_part_without_handles_keeps_the_harmonic_start_of_the_others():
    """--start auto dropped the harmonic start for the whole mesh when one part had no handle
    (failed, hexahedra folded inside, the free block collapsed to a point); now the handled
    block starts from its harmonic extension as it does alone, the free one is held as given."""
    problem, x0, a, n = _two_blocks(False)
    alone = untangle(a.problem(), a.x0, progress=False)
    res = untangle(problem, x0, progress=False)
    assert res.success, res.message
    assert res.details.start == "harmonic" and (res.details.free_parts, res.details.rest_parts) == (1, 0)
    assert res.stats.outer_iterations == alone.stats.outer_iterations == 2  # one eps solve, the polish
    assert _bits_equal(res.x[n:], x0[n:]) and res.problem is problem


def test_a_tangled_part_without_handles_is_held_at_its_rest_shape():
    """Two tangled blocks, one without any handle, ran for minutes in the eps loop (the free
    block collapses at the first eps); it is replaced by its rest shape moved by the best
    similarity onto its given map, and certifies with the other block's few iterations."""
    from geomopt.untangling.start import hold_free_parts

    problem, x0, a, n = _two_blocks(True)
    assert problem.count_inverted(x0) > a.inverted() > 0
    res = untangle(problem, x0, progress=False)
    assert res.success, res.message
    assert (res.details.free_parts, res.details.rest_parts) == (1, 1) and res.stats.outer_iterations <= 2
    held = hold_free_parts(problem, x0)
    assert held.held.tolist() == list(range(n, 2 * n)) and _bits_equal(res.x[n:], held.x[n:])
    B = res.x[n:] - res.x[n:].mean(axis=0)
    R = problem.rest_vertices[:n] - problem.rest_vertices[:n].mean(axis=0)
    Q, *_ = np.linalg.lstsq(R, B, rcond=None)  # a rotation times a scale: a similarity
    assert np.abs(R @ Q - B).max() < 1e-12 and np.linalg.det(Q) > 0
    s = np.linalg.svd(Q, compute_uv=False)
    assert np.ptp(s) < 1e-12 * s[0]
    # the 2D analogue, triangles: same rule
    V, F = G.square_mesh(4)
    t = G.rotated_interior(V, F, 90.0)
    noisy = G.noisy_interior(V, F, 1.0, seed=1).x0
    W, FF = np.concatenate([V, V + [2.0, 0.0]]), np.concatenate([F, F + len(V)])
    p2 = Problem.planar(W, FF, t.fixed, t.x0[t.fixed])
    r2 = untangle(p2, np.concatenate([t.x0, noisy + [2.0, 0.0]]), progress=False)
    assert r2.success and (r2.details.free_parts, r2.details.rest_parts) == (1, 1), r2.message


def test_harmonic_start_is_taken_per_part():
    from geomopt.untangling.start import choose_start, harmonic_start

    problem, x0, a, n = _two_blocks(True)
    xh = harmonic_start(problem, x0)
    assert _bits_equal(xh[n:], x0[n:])  # the part without a handle keeps its map
    assert np.abs(xh[:n] - a.rest).max() < 1e-12  # the other: its extension (the rest grid, boundary at rest)
    x, which = choose_start(problem, x0)
    assert which == "harmonic" and _bits_equal(x, xh)
    with pytest.raises(ParameterError, match="needs a handle"):
        choose_start(Problem.hexes(problem.rest_vertices, problem.elements), x0, "harmonic")


def _doubled_rest():
    """Tets around the interior edge (0, 1) turning twice at rest (every tet positive), the
    ring fixed at a once-turning star, the axis vertices free and swapped (tangled)."""
    from test_local_injectivity import edge_star

    rest, T = edge_star(2.0, 11, True)
    once, _ = edge_star(1.0, 11, True)
    ring = np.arange(2, len(rest))
    x0 = once.copy()
    x0[[0, 1]] = x0[[1, 0]]
    return rest, T, ring, x0


def test_a_rest_mesh_that_is_not_locally_injective_is_refused_at_setup(monkeypatch):
    """It was blamed on 'the fixed boundary ... check the handle positions' after a solve."""
    rest, T, ring, x0 = _doubled_rest()
    problem = Problem.tets(rest, T, ring, x0[ring])
    monkeypatch.setattr(driver, "iterate", lambda *a, **k: pytest.fail("solved"))
    with pytest.raises(MeshError, match=r"^the rest mesh itself is not locally injective: .*edge \(0, 1\)"):
        untangle(problem, x0, progress=False)


def test_cli_refuses_a_rest_mesh_that_is_not_locally_injective_in_one_line(tmp_path, capsys):
    from geomopt import cli

    rest, T, ring, x0 = _doubled_rest()
    folder = LimCase.from_tangle(G.Tangle("doubled", rest, T, x0, ring)).write(tmp_path / "case")
    out = tmp_path / "out.vtk"
    assert cli.main(["untangle", str(folder), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rest mesh itself is not locally injective" in err[0], err
    assert not out.exists()


def test_a_mirrored_part_without_handles_gets_a_proper_rotation_of_its_rest_shape():
    """The best orthogonal fit of the rest shape onto a mirrored map is a reflection, which
    would invert every element: the rotation is taken without it (Kabsch's sign fix)."""
    from geomopt.untangling.start import hold_free_parts

    V, F = G.square_mesh(4)
    p = Problem.planar(V, F)
    x0 = V * [-1.0, 1.0]
    x0[5] += [0.4, 0.3]  # and tangled
    held = hold_free_parts(p, x0)
    assert (held.given, held.rest, held.pinned) == (0, 1, 0) and len(held.held) == len(V)
    assert p.certify(held.x).ok

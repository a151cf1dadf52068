"""Reliability of the Python API, round two (issue 10): no wrong success, validated input.

* a rest mesh whose elements are not consistently oriented is refused, never certified
  (2D LIM cases planar or surface, every problem kind);
* ``minimize(params=...)`` is validated like the energy's own parameters;
* a solve whose energy is unbounded below ends DIVERGED, not converged;
* a user density that is not a pure JAX ``psi(J, params) -> float64 scalar`` is refused when
  the :class:`Energy` is built; solver and line-search settings are validated when built;
* messages say where a setting goes.

Solves use small meshes so that each kernel compiles once.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from geomopt import MeshError, Objective, Outcome, ParamOptions, ParameterError, Problem, SolveError, UntangleOptions
from geomopt.mesh import generators as G
from geomopt import minimize, parameterize
from geomopt import param as param_module
from geomopt.energies import REGISTRY, Energy, garanzha, get_energy
from geomopt.solvers.linesearch import InjectiveSearch
from geomopt.exact.predicates import count_inverted
from geomopt.solvers import LBFGS, Adaptive, Newton
from geomopt.exact.topology import same_side_facets
from geomopt.lim import LimCase, untangle_case
from geomopt.untangling import untangle

from conftest import cube_tets, grid

from conftest import LIM_ROOT

LIM_SQUARE = LIM_ROOT / "2D" / "Simple" / "square_rot90"


def _bumpy(V):
    return 0.3 * np.sin(3.0 * V[:, 0]) * V[:, 1]


# ------------------------------------------------------------------ orientation of the rest mesh


def _square_case(z, faces=None):
    """A LIM-style 2D case: the 6x6 square with its interior rotated by 90 degrees (tangled),
    rest heights ``z`` (0: planar), boundary fixed."""
    V, F = G.square_mesh(6)
    t = G.rotated_interior(V, F, 90.0)
    return LimCase(2, np.c_[V, z * _bumpy(V)], t.x0, F if faces is None else faces, t.fixed)


@pytest.mark.parametrize("z, match", [(0.0, "oriented against the others"),
                                      (1.0, "inconsistent face orientation")])
def test_lim_2d_case_with_one_face_listed_clockwise_is_refused(z, match):
    case = _square_case(z)
    F = case.simplices.copy()
    F[12] = F[12, [0, 2, 1]]
    with pytest.raises(MeshError, match=match):
        dataclasses.replace(case, simplices=F).to_problem()
    with pytest.raises(MeshError, match=match):
        untangle_case(dataclasses.replace(case, simplices=F), progress=False)


@pytest.mark.parametrize("z, kind", [(0.0, "planar"), (1.0, "surface")])
@pytest.mark.parametrize("reverse", [False, True])
def test_lim_2d_consistent_cases_are_certified_in_their_own_orientation(z, kind, reverse, tmp_path):
    """Planar rest -> Problem.planar, curved rest -> Problem.surface; every face listed the other
    way round (a clockwise rest, a clockwise map) is consistent and certified too."""
    case = _square_case(z)
    if reverse:
        case = dataclasses.replace(case, simplices=case.simplices[:, ::-1].copy())
    problem, x0, orientation, mirror = case.to_problem()
    assert problem.kind == kind and orientation == (-1 if reverse else 1)
    case, result = untangle_case(case, progress=False)
    assert result.success, result.message
    assert count_inverted(result.x, case.simplices, orientation=orientation) == 0
    assert case.write_certified(result, tmp_path / "out.obj")["certified"]


def test_lim_folder_with_one_face_reversed_is_refused(tmp_path):
    if not LIM_SQUARE.is_dir():
        pytest.skip(f"LIM sample data not found at {LIM_SQUARE}")
    for curved in (False, True):
        dst = tmp_path / f"case{int(curved)}"
        dst.mkdir()
        shutil.copy(LIM_SQUARE / "handles.txt", dst / "handles.txt")
        lines, flipped = [], False
        for line in (LIM_SQUARE / "input.obj").read_text().splitlines():
            t = line.split()
            if t and t[0] == "f" and not flipped:
                line, flipped = f"f {t[1]} {t[3]} {t[2]}", True
            elif t and t[0] == "v" and curved:
                x, y = float(t[1]), float(t[2])
                line = f"v {t[1]} {t[2]} {float(0.3 * np.sin(3 * x) * y)!r}"
            lines.append(line)
        (dst / "input.obj").write_text("\n".join(lines) + "\n")
        with pytest.raises(MeshError, match="inconsistent face orientation" if curved else "oriented against"):
            untangle_case(dst, progress=False)


@pytest.mark.parametrize("angle", [0.0, 45.0, 180.0, 200.0])
def test_square_rot180_untangles_under_exact_rotations_of_its_rest_mesh(angle):
    """Read as planar (rather than per-triangle frames) the case's rounding changes; keeping
    stale L-BFGS pairs after an outer iteration that added folds then stalled it at 0, 180
    and 200 degrees (64 folds after 200 outer iterations)."""
    folder = LIM_SQUARE.parent / "square_rot180"
    if not folder.is_dir():
        pytest.skip(f"LIM sample data not found at {folder}")
    from geomopt.lim import LimCase

    case = LimCase.read(folder)
    a = np.deg2rad(angle)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    H = case["handles"]
    problem = Problem.planar(case["rest"] @ R.T, case["faces"], H, case["init"][H])
    result = untangle(problem, case["init"], progress=False)
    assert result.success, result.message


def test_every_problem_kind_refuses_elements_on_the_same_side_of_a_facet():
    V, F = grid(4)
    bad = F.copy()
    bad[3] = bad[3, [0, 2, 1]]
    with pytest.raises(MeshError, match="inconsistent face orientation: 3 edge"):
        Problem.surface(np.c_[V, _bumpy(V)], bad)
    # two positive triangles on the same side of edge 0-1: the rest overlaps itself
    P = np.array([[0, 0], [1, 0], [0, 1], [0.5, 0.4]])
    with pytest.raises(MeshError, match="1 rest edge.*same side"):
        Problem.planar(P, [[0, 1, 2], [0, 1, 3]])
    with pytest.raises(MeshError, match=r"2 non-manifold edges \(shared by more than two triangles.*; 1 "
                                        rf"triangle\(s\) repeat another's vertices \(first: triangle {len(F)} repeats "
                                        r"triangle 0\): remove the repeated ones"):
        Problem.planar(V, np.r_[F, F[:1]])  # a repeated triangle: its 2 interior edges have 3
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.2, 0.2, 0.5]])
    with pytest.raises(MeshError, match="1 rest face.*tetrahedra lying on the same side"):
        Problem.tets(P, [[0, 1, 2, 3], [0, 1, 2, 4]])
    # a consistent tet mesh, and one listed with all tets negative, are accepted
    P, T = cube_tets(2)
    assert Problem.tets(P, T).n_elements == Problem.tets(P, T[:, [1, 0, 2, 3]]).n_elements
    # with x0 given, parameterize does not run the disk check: the problem itself refuses
    V3 = np.c_[V, _bumpy(V)]
    with pytest.raises(MeshError, match="inconsistent face orientation"):
        parameterize(V3, bad, x0=V, progress=False)


def test_same_side_facets_counts_and_locates():
    V, F = grid(4)
    assert same_side_facets(F)[0] == 0
    bad = F.copy()
    bad[3] = bad[3, [0, 2, 1]]
    count, elements = same_side_facets(bad)
    assert count == 3 and elements[3] and elements.sum() == 4  # triangle 3 and its 3 neighbours
    P, T = cube_tets(2)
    T2 = T.copy()
    T2[5] = T2[5, [1, 0, 2, 3]]
    count, elements = same_side_facets(T2)
    assert count == 3 and elements[5]  # tet 5 has one boundary face: 3 interior ones repeat


# ------------------------------------------------------------------ params= is validated


@pytest.mark.parametrize("params, match", [
    ({"lam": -5}, "lam=-5.0 must be >= 0"),
    ({"eps": 0}, "eps=0.0 must be > 0"),
    ({"lamm": 1}, r"no parameter\(s\) \['lamm'\]; its parameters are \['eps', 'lam'\]"),
    ({"eps": float("nan")}, "must be finite"),
    ({"eps": "small"}, "must be a number"),
])
def test_minimize_params_are_validated_like_the_energy(params, match):
    V, F = grid(3)
    obj = Objective(Problem.planar(V, F), garanzha)
    with pytest.raises(ParameterError, match=match):
        minimize(obj, V, params=params, progress=False)
    with pytest.raises(ParameterError, match=match):
        obj.params(**params)


# ------------------------------------------------------------------ divergence


def _minus_dirichlet(J, params):
    return -jnp.sum(J * J)


def _minus_log(J, params):
    return -jnp.log1p(jnp.sum(J * J))


@pytest.mark.parametrize("density, solver", [
    (_minus_dirichlet, "newton"), (_minus_dirichlet, "lbfgs"),
    (_minus_log, LBFGS(search=InjectiveSearch(injective=False, c2=0.9)))])
def test_energy_unbounded_below_diverges(density, solver):
    V, F = grid(4)
    obj = Objective(Problem.planar(V, F), Energy(density, name="unbounded"))
    res = minimize(obj, V, solver, progress=False)
    assert res.outcome is Outcome.DIVERGED and not res.success
    assert np.ptp(res.x) > 1e6 and np.isfinite(res.x).all()
    assert "diverged" in res.message and "times its start and rest size" in res.message
    with pytest.raises(SolveError, match="diverged"):
        minimize(obj, V, solver, progress=False, throw=True)


@pytest.mark.parametrize("solver", ["newton", "lbfgs"])
def test_injective_search_stalling_at_the_fold_barrier_is_not_convergence(solver):
    """-log(1 + |J|^2) under the injective search: the steps end at an element about to
    collapse, cut shorter and shorter; the energy stalls but that is not a minimum."""
    V, F = grid(4)
    obj = Objective(Problem.planar(V, F), Energy(_minus_log, name="unbounded"))
    res = minimize(obj, V, solver, progress=False)
    assert res.outcome is not Outcome.CONVERGED and not res.success


def test_stalled_energy_with_a_large_decrement_is_not_convergence():
    """Newton on -log(1 + |J|^2): the line search cuts every step 10x shorter, so the energy
    stalls while the Newton decrement stays ~E/8; that used to end CONVERGED."""
    V, F = grid(4)
    obj = Objective(Problem.planar(V, F), Energy(_minus_log, name="unbounded"))
    res = minimize(obj, V, Newton(projection="clamp", max_steps=30), progress=False)
    assert res.outcome is not Outcome.CONVERGED and not res.success


def test_energy_below_its_declared_lower_bound_diverges():
    V, F = grid(3)
    liar = Energy(lambda J, p: jnp.sum(J * J) - 10.0, name="liar", lower_bound=0.0)
    res = minimize(Objective(Problem.planar(V, F), liar), V, progress=False)
    assert res.outcome is Outcome.DIVERGED and "below the energy's lower bound 0" in res.message
    with pytest.raises(ParameterError, match="lower_bound=nan must be finite"):
        Energy(lambda J, p: jnp.sum(J * J), lower_bound=float("nan"))


def test_large_but_bounded_motion_is_not_divergence():
    """Handles 1e8 away from the rest mesh: the start map holds them, so the reference scale
    is theirs and the harmonic map converges."""
    V, F = grid(4)
    b = np.flatnonzero(((V == 0) | (V == 1)).any(axis=1))
    P = Problem.planar(V, F, b, V[b] * 1e8)
    res = minimize(Objective(P, "dirichlet"), V, progress=False)
    assert res.outcome is Outcome.CONVERGED and res.success
    assert all(REGISTRY[n].lower_bound == 0.0 for n in REGISTRY)


# ------------------------------------------------------------------ user densities


def _vector(J, params):
    return J.ravel()


def _one_argument(J):
    return jnp.sum(J * J)


def _numpy_only(J, params):
    return np.linalg.det(np.asarray(J))


def _integer(J, params):
    return jnp.sum(J > 0)


def _complex(J, params):
    return jnp.sum(J * J) + 1j


def _pair(J, params):
    return jnp.sum(J * J), jnp.sum(J)


def _branchy(J, params):
    return jnp.sum(J * J) if J[0, 0] > 0 else 0.0


@pytest.mark.parametrize("density, detail", [
    (_vector, r"shape \(4,\), not a scalar"),
    (_one_argument, "TypeError"),
    (_numpy_only, "TracerArrayConversionError"),
    (_integer, "dtype int64, not float64"),
    (_complex, "dtype complex128, not float64"),
    (_pair, "returned tuple"),
    (_branchy, "Error"),
])
def test_bad_user_density_is_refused_when_the_energy_is_built(density, detail):
    with pytest.raises(ParameterError, match=f"invalid density: on a 2x2 J .*{detail}.*"
                                             f"a density must be a pure JAX function psi\\(J, params\\)"):
        Energy(density, name="bad")


def test_density_for_one_dimension_only_is_checked_against_the_problem():
    def corner(J, params):  # traces for 3x3 J only
        return jnp.sum(J * J) + params["w"] * J.reshape(3, 3)[2, 2] ** 2

    e = Energy(corner, params={"w": 0.5}, name="corner")
    assert e.dims == (3,)
    P, T = cube_tets(1)
    Objective(Problem.tets(P, T), e)
    V, F = grid(3)
    with pytest.raises(ParameterError, match=r"'corner': the density works only for d=3, but the "
                                             r"problem has 2x2 Jacobians.*TypeError"):
        Objective(Problem.planar(V, F), e)


def test_builtin_densities_pass_the_density_check():
    for e in REGISTRY.values():
        assert e.dims == (2, 3)


def test_unhashable_density_is_refused():
    class Psi:
        __hash__ = None

        def __call__(self, J, params):
            return jnp.sum(J * J)

    with pytest.raises(ParameterError, match="must be hashable"):
        Energy(Psi())


# ------------------------------------------------------------------ solver configuration


@pytest.mark.parametrize("build, match", [
    (lambda: Newton(max_steps=-5), "Newton: max_steps must be an integer >= 1, got -5"),
    (lambda: Newton(max_steps=2.5), "Newton: max_steps must be an integer >= 1, got 2.5"),
    (lambda: Newton(max_steps=True), "max_steps must be an integer"),
    (lambda: Newton(rtol=float("nan")), r"Newton: rtol must be a finite number in \[0, 1\), got nan"),
    (lambda: Newton(projection="eig"), "Newton: projection must be one of 'adaptive', 'clamp'"),
    (lambda: Newton(regularization=0.0), "regularization must be a finite number > 0"),
    (lambda: Newton(projection=Adaptive(exact_below=-1.0)), "Adaptive: exact_below must be a finite number >= 0"),
    (lambda: Newton(linear_solver="lu"), "linear_solver must be one of 'auto'"),
    (lambda: Newton(search="armijo"), "search must be a InjectiveSearch object"),
    (lambda: LBFGS(max_steps=-5), "LBFGS: max_steps must be an integer >= 1"),
    (lambda: LBFGS(rtol=float("nan")), "LBFGS: rtol must be a finite number"),
    (lambda: LBFGS(gtol=float("inf")), "LBFGS: gtol must be a finite number"),
    (lambda: LBFGS(history=2.5), "LBFGS: history must be an integer >= 1"),
    (lambda: LBFGS(window=0), "LBFGS: window must be an integer >= 1"),
    (lambda: InjectiveSearch(c2=1e-5), "need c1 < c2"),
    (lambda: InjectiveSearch(shrink=2), r"InjectiveSearch: shrink must be a finite number in \(0, 1\), got 2"),
    (lambda: InjectiveSearch(c1=-1), r"InjectiveSearch: c1 must be a finite number in \(0, 1\), got -1"),
    (lambda: InjectiveSearch(safety=0.0), "safety must be a finite number in"),
    (lambda: InjectiveSearch(max_steps=0), "max_steps must be an integer >= 1"),
    (lambda: InjectiveSearch(expand=-1), "expand must be an integer >= 0"),
    (lambda: InjectiveSearch(injective="yes"), "injective must be True or False"),
])
def test_bad_solver_configuration_is_refused_when_built(build, match):
    with pytest.raises(ParameterError, match=match):
        build()


def test_solver_configuration_is_normalised():
    s = Newton(max_steps=1e3, rtol=np.float32(0.5), search=InjectiveSearch(max_steps=np.int64(7)))
    assert s.max_steps == 1000 and type(s.max_steps) is int
    assert type(s.rtol) is float and s.search.max_steps == 7
    assert LBFGS(history=np.int32(3)).history == 3
    assert InjectiveSearch(injective=np.bool_(False)).injective is False


def test_minimize_accepts_solver_names():
    V, F = grid(4)
    b = np.flatnonzero(((V == 0) | (V == 1)).any(axis=1))
    x0 = V.copy()
    x0[5] += 0.05
    obj = Objective(Problem.planar(V, F, b, V[b]), "symmetric_dirichlet")
    by_name = minimize(obj, x0, solver="newton", progress=False)
    assert by_name.success and np.array_equal(by_name.x, minimize(obj, x0, Newton(), progress=False).x)
    assert minimize(obj, x0, solver=" LBFGS ", progress=False).success
    with pytest.raises(ParameterError, match="unknown solver 'bfgs'; valid solvers: newton, lbfgs, slim"):
        minimize(obj, x0, solver="bfgs", progress=False)


# ------------------------------------------------------------------ messages


def test_solver_settings_passed_to_parameterize_say_where_they_go():
    V, F = grid(4)
    V3 = np.c_[V, _bumpy(V)]
    with pytest.raises(ParameterError, match=r"max_steps is a setting of the solver, not a parameter of "
                                             r"the energy 'symmetric_dirichlet': pass parameterize\(\.\.\., "
                                             r"solver=Newton\(max_steps=\.\.\.\)\)"):
        parameterize(V3, F, ("symmetric_dirichlet", {"max_steps": 0}), progress=False)
    with pytest.raises(ParameterError, match=r"solver=LBFGS\(rtol=\.\.\.\)"):
        parameterize(V3, F, ("symmetric_dirichlet", {"rtol": 1e-3}), solver="lbfgs", progress=False)
    with pytest.raises(ParameterError, match=r"solver=Newton\(search=InjectiveSearch\(c1=\.\.\.\)\)"):
        parameterize(V3, F, ("symmetric_dirichlet", {"c1": 0.1}), progress=False)
    with pytest.raises(ParameterError, match=r"no parameter\(s\) \['lamm'\]"):
        parameterize(V3, F, energy=("garanzha", {"lamm": 1.0}), progress=False)


def test_inverted_tutte_start_message_has_no_api_only_remedy(monkeypatch):
    """Rounding can fold a Tutte map of a very anisotropic mesh; simulate it."""
    V, F = grid(4)
    V3 = np.c_[V, _bumpy(V)]

    def folded_tutte(V, F, weights, boundary):
        x = np.asarray(V)[:, :2].copy()
        x[5] = [0.9, 0.9]
        return x

    monkeypatch.setattr(param_module, "tutte_embedding", folded_tutte)
    with pytest.raises(MeshError) as info:
        parameterize(V3, F, progress=False)
    msg = str(info.value)
    assert "the Tutte start map has" in msg and "mean_value Tutte weights" in msg and "x0" not in msg
    with pytest.raises(MeshError, match="try uniform Tutte weights"):
        parameterize(V3, F, options=ParamOptions(weights="mean_value"), progress=False)
    # the API's own folded start map is repaired (free-boundary untangling), not refused
    assert parameterize(V3, F, x0=folded_tutte(V3, F, None, None), progress=False).success


# ------------------------------------------------------- free boundary: energies that collapse


def _curved_disk():
    V, F = G.disk_mesh(5)
    return np.c_[V, 0.2 * np.sin(2.0 * V[:, 0])], F


@pytest.mark.parametrize("energy", ["dirichlet", Energy(lambda J, p: jnp.sum(J * J) ** 2, name="quartic")])
def test_free_boundary_parameterization_refuses_an_energy_that_shrinks_the_map(energy):
    """Dirichlet (or any density lower at a smaller scale) has no free-boundary minimiser: the
    map collapses to a point, which solvers used to report as converged."""
    V, F = _curved_disk()
    with pytest.raises(ParameterError, match="decreases when the map shrinks.*collapse"):
        parameterize(V, F, energy=energy, progress=False)
    with pytest.raises(ParameterError, match="decreases when the map shrinks"):
        geomopt_compare(V, F, energy=energy, solvers=["newton"])
    for fine in ("symmetric_dirichlet", "arap", "mips"):  # scale-aware or scale-invariant
        get_energy(fine).check_scale_aware({})


def test_the_scale_check_is_the_energys_own_and_reads_its_parameters():
    """``Energy.check_scale_aware(params)``: the density at the given parameters decides (here
    ``w = 0`` is Dirichlet, which collapses; ``w = 1`` adds a barrier); names the energy does not
    have are left to the caller's checks."""
    energy = Energy(lambda J, p: jnp.sum(J * J) + p["w"] / jnp.abs(jnp.linalg.det(J)), params={"w": 1.0},
                    name="dirichlet_plus_barrier")
    energy.check_scale_aware()
    energy.check_scale_aware({"w": 1.0, "max_steps": 3})
    with pytest.raises(ParameterError, match="'dirichlet_plus_barrier' decreases when the map shrinks"):
        energy.check_scale_aware({"w": 0.0})
    with pytest.raises(ParameterError, match="decreases when the map shrinks"):
        get_energy("dirichlet").check_scale_aware()


def geomopt_compare(*a, **k):
    from geomopt import compare

    return compare(*a, **k)


@pytest.mark.parametrize("solver", ["newton", "aqp"])
def test_a_map_that_collapses_is_diverged_not_converged(solver):
    """The shared divergence rule: a map shrunk below 1e-6 of its start/rest size is
    DIVERGED, never CONVERGED (Dirichlet with a free boundary, through minimize)."""
    V, F = _curved_disk()
    obj = Objective(Problem.surface(V, F), "dirichlet")
    x0, _, _ = param_module.start_map(Objective(Problem.surface(V, F), "symmetric_dirichlet"), None, "uniform", False)
    res = minimize(obj, x0, solver, progress=False)
    assert res.outcome is Outcome.DIVERGED and not res.success and "collapsed" in res.message


@pytest.mark.parametrize("x0", ["projection", "array"])
def test_a_non_disk_is_refused_before_any_repair_or_solve(x0, monkeypatch):
    """Free-boundary maps are certified as a disk's: a closed surface or an annulus is refused
    up front for every start (it used to be repaired for up to 200 outer iterations first)."""
    octa = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    octa_F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = G.square_mesh(6)
    keep = ~np.all(np.isin(F, np.flatnonzero((np.abs(V - 0.5) < 0.2).all(axis=1))), axis=1)
    ring = (np.c_[V, np.zeros(len(V))], F[keep])
    used = np.unique(ring[1])
    ring = (ring[0][used], np.searchsorted(used, ring[1]))
    monkeypatch.setattr(param_module, "repair_map", lambda *a, **k: pytest.fail("repaired a non-disk"))
    for (P, T), words in (((octa, octa_F), "no boundary"), (ring, "boundary loops")):
        start = x0 if x0 == "projection" else np.random.default_rng(0).normal(size=(len(P), 2))
        with pytest.raises(MeshError, match=words):
            parameterize(P, T, x0=start, progress=False)


def test_small_api_misuses_get_clear_errors():
    V, F = G.square_mesh(4)
    with pytest.raises(ParameterError, match="Objective needs a geomopt.Problem.*got str"):
        Objective("pr", "arap")
    t = G.rotated_interior(V, F, 90)
    for bad in (float("nan"), 0.0, 2.0, "1e-5"):
        with pytest.raises(ParameterError, match="energy_tol"):
            untangle(t.problem(), t.x0, options=UntangleOptions(energy_tol=bad), progress=False)
    res = untangle(t.problem(), t.x0, options=UntangleOptions(max_outer=1), progress=False)  # cannot settle in one
    assert not res.success and "outer-iteration limit (max_outer=1)" in res.message


@pytest.mark.filterwarnings("error::RuntimeWarning")  # the mean of an empty diagonal warned
@pytest.mark.parametrize("solver", ["newton", "slim", "cm", "lbfgs", "aqp"])
def test_every_vertex_a_handle(solver):
    """No free DOF: the direct-step solvers raised the sparse backend's bare ValueError
    ('n must be positive'); now every solver returns the handles' map, a success only when it
    is injective."""
    V, F = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]])
    good = Problem.planar(V, F, fixed=[0, 1, 2], fixed_positions=2.0 * V)
    r = minimize(Objective(good, "symmetric_dirichlet"), 2.0 * V, solver, progress=False)
    assert r.success and r.certificate.inverted == 0 and np.array_equal(r.x, 2.0 * V)
    mirrored = Problem.planar(V, F, fixed=[0, 1, 2], fixed_positions=V[[0, 2, 1]])
    r = minimize(Objective(mirrored, "symmetric_dirichlet"), V[[0, 2, 1]], solver, progress=False)
    assert not r.success and r.certificate.inverted == 1


@pytest.mark.parametrize("bad", [dict(progress="yes"), dict(progress=2), dict(params=[("lam", 1.0)])])
def test_progress_and_params_type_refused(bad):
    """A non-callable progress failed with a bare TypeError at the first report (after the
    set-up and compilation), a non-mapping params with one from the ** unpacking."""
    V, F = grid(3)
    problem = Problem.planar(V, F)
    with pytest.raises(ParameterError, match="progress must be|params must be"):
        minimize(Objective(problem, "symmetric_dirichlet"), V, "lbfgs", **bad)
    if "progress" in bad:
        with pytest.raises(ParameterError, match="untangle: progress must be"):
            untangle(problem, V, **bad)


def test_parameterize_progress_callable_with_folded_start():
    """parameterize forwarded a minimize-style progress callable to the repair's untangle,
    whose callback takes other arguments: TypeError on any folded start."""
    V, F = grid(6)
    x0 = V.copy()
    x0[7] += [0.5, 0.4]  # folds the triangles around vertex 7
    energies = []
    r = parameterize(np.c_[V, _bumpy(V)], F, x0=x0, progress=lambda state, elapsed, e: energies.append(e))
    assert r.details.repair is not None and r.success and r.certificate.inverted == 0
    assert len(energies) == r.stats.iterations
    with pytest.raises(ParameterError, match="parameterize: progress must be"):
        parameterize(np.c_[V, _bumpy(V)], F, progress="yes")

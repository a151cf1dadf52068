"""Reliability of the Python API: every bad input gets a clear geomopt error, no NaN escapes,
nothing inverted is ever called success, and the same input gives the same map.

The command line is covered by tests/test_cli.py; the file readers' own fuzzing is in
tests/test_io.py.  Solves reuse one small mesh (4x4 grid, 18 triangles) so that the JIT
compiles once per energy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from geomopt import GeomoptError, MeshError, Objective, Outcome, ParamOptions, ParameterError, Problem, SolveError
from geomopt import minimize, parameterize
from geomopt.energies import REGISTRY, Energy, get_energy
from geomopt.mesh.orientation import check_initial_orientation
from geomopt.solvers import Newton

from conftest import cube_tets, grid



def fuzz(max_examples):
    return settings(max_examples=max_examples, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def bumpy_grid(n=4):
    """The parameterization test surface: a (n*n, 3) height field over the unit square, CCW."""
    V, F = grid(n)
    return np.c_[V, 0.3 * np.sin(3.0 * V[:, 0]) * V[:, 1]], F


V3, F3 = bumpy_grid()  # 16 vertices, 18 triangles, boundary: the 12 outer vertices


def closed_tetrahedron():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    return V, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


# ------------------------------------------------------------------ problem constructors


@pytest.mark.parametrize(
    "V, F, match",
    [
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]]), [[0, 1, 2]], "1 vertices with NaN or infinite"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 1]]), [[0, 1, 2]], "NaN or infinite.*vertex 2"),
        (V3, np.r_[F3, [[0, 1, 16]]], r"1 triangles with vertex indices outside 0\.\.15.*triangle 18"),
        (V3, np.r_[F3, [[0, -1, 5]]], "outside 0..15"),
        (V3, np.r_[F3, [[3, 7, 3]]], "1 triangles that use a vertex more than once"),
        (V3, F3.astype(float), "integer dtype"),
        (V3, F3.astype(bool), "integer dtype"),
        (V3, F3.ravel(), r"shape \(m, 3\)"),
        (V3, np.zeros((0, 3), int), "no triangles"),
        (V3, [[0, 1, 2], [0, 1]], "not a rectangular"),
        (V3[:, :1], F3, r"must have shape \(n, 3\), got shape \(16, 1\)"),
        (np.zeros((0, 3)), F3, "no vertices"),
        (V3.astype(complex), F3, "real numbers"),
        (V3.astype(bool), F3, "real numbers"),
        (np.r_[V3, [[5.0, 5.0, 5.0]]], F3, "1 vertices are not used"),
        (V3 * 1e160, F3, "overflows"),
    ],
)
def test_surface_rejects_bad_input(V, F, match):
    with pytest.raises(MeshError, match=match):
        Problem.surface(V, F)


def test_zero_area_rest_elements_are_counted_and_located():
    V, F = grid(4)
    V = V.copy()
    V[5] = [0.5, 1.0 / 6.0]  # on the segment 1-6: triangle 3 = [1, 6, 5] is flat
    with pytest.raises(MeshError, match=r"1 rest triangle\(s\) have \(near-\)zero size \(first: \[3\]\)"):
        Problem.planar(V, F)
    with pytest.raises(MeshError, match=r"1 rest triangle\(s\).*\[3\]"):
        Problem.surface(np.c_[V, np.zeros(16)], F)
    Vc = np.c_[np.linspace(0, 1, 16), np.linspace(0, 2, 16), np.zeros(16)]  # all collinear
    with pytest.raises(MeshError, match="every rest triangle has zero size"):
        Problem.surface(Vc, F)
    P, T = cube_tets(1)
    P = P.copy()
    P[4] = P[0]  # two coincident vertices: the 2 tets holding both are flat
    with pytest.raises(MeshError, match=r"2 rest tetrahedron\(s\) have \(near-\)zero size"):
        Problem.tets(P, T)


def test_planar_and_tets_reject_bad_shapes():
    V, F = grid(3)
    with pytest.raises(MeshError, match="nonzero z"):
        Problem.planar(np.c_[V, np.ones(len(V))], F)
    with pytest.raises(MeshError, match=r"\(n, 3\)"):
        Problem.tets(V, F)
    P, T = cube_tets(1)
    with pytest.raises(MeshError, match=r"shape \(m, 4\)"):
        Problem.tets(P, T[:, :3])
    with pytest.raises(MeshError, match="oriented against the others"):
        Problem.tets(P, np.r_[T, T[:1, [1, 0, 2, 3]]])


def test_fixed_vertices_and_maps_are_validated():
    V, F = grid(3)
    P = Problem.planar(V, F)
    for fixed, pos, match in [
        ([0, 9], np.zeros((2, 2)), r"outside 0\.\.8"),
        ([0, 0], np.zeros((2, 2)), "more than once"),
        ([0.0, 1.0], np.zeros((2, 2)), "integer dtype"),
        ([[0, 1]], np.zeros((2, 2)), "1-D"),
        ([0, 1], np.zeros((3, 2)), "3 rows for 2 fixed"),
        ([0, 1], np.zeros((2, 3)), r"\(n, 2\)"),
        ([0, 1], [[0, 0], [np.nan, 0]], "NaN"),
        ([0, 1], None, "shape"),
    ]:
        with pytest.raises(MeshError, match=match):
            P.with_fixed(fixed, pos)
    assert P.with_fixed([], np.zeros((0, 2))).fixed.size == 0
    for x, match in [
        (V[:-1], "8 rows but the mesh has 9"),
        (np.c_[V, V[:, :1]], r"\(n, 2\)"),
        (np.where(np.eye(9, 2, dtype=bool), np.nan, V), "NaN"),
        (V.astype(bool), "real numbers"),
        ([[0, 1], [2]], "not a rectangular"),
    ]:
        with pytest.raises(MeshError, match=match):
            P.check_map(x)


def test_check_initial_orientation():
    P, T = cube_tets(1)
    prob = Problem.tets(P, T, fixed=[0], fixed_positions=P[:1])
    assert check_initial_orientation(prob, P) == pytest.approx(1.0)
    mirrored = P * [-1.0, 1.0, 1.0]
    with pytest.raises(MeshError, match=r"total signed volume is -1, negative: it is mirrored"):
        check_initial_orientation(Problem.tets(P, T), mirrored)
    with pytest.raises(MeshError, match="zero: it is collapsed"):
        check_initial_orientation(Problem.tets(P, T), P * [1.0, 1.0, 0.0])
    V, F = grid(3)
    with pytest.raises(MeshError, match="total signed area"):
        check_initial_orientation(Problem.planar(V, F), V[:, ::-1])
    # an all-negative rest mesh (as in the LIM armadillo) is the reference orientation
    Tneg = T[:, [1, 0, 2, 3]]
    assert check_initial_orientation(Problem.tets(P, Tneg), P) > 0
    with pytest.raises(MeshError, match="initial map has 7 rows"):
        check_initial_orientation(Problem.tets(P, T), P[:7])


# ------------------------------------------------------------------ names and parameters


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(ParameterError, match="valid energies: arap, dirichlet"):
        parameterize(V3, F3, energy="symmetric-dirichlett", progress=False)
    with pytest.raises(ParameterError, match="valid solvers: .*newton"):
        parameterize(V3, F3, solver="gradient_descent", progress=False)
    with pytest.raises(ParameterError, match="'uniform', 'mean_value'"):
        parameterize(V3, F3, options=ParamOptions(weights="cotan"), progress=False)


def test_invalid_energy_parameters():
    dens = REGISTRY["garanzha"].density
    for kwargs, match in [
        ({"lam": -1.0}, "lam=-1.0 must be >= 0"),
        ({"eps": 0.0}, "eps=0.0 must be > 0"),
        ({"eps": -1e-3}, "eps=-0.001 must be > 0"),
        ({"eps": float("nan")}, "must be finite"),
        ({"eps": "small"}, "must be a number"),
        ({"mu": 1.0}, "no parameter"),
    ]:
        with pytest.raises(ParameterError, match=match):
            get_energy("garanzha", **kwargs)
        with pytest.raises(ParameterError, match=match):
            parameterize(V3, F3, energy=("garanzha", kwargs), progress=False)
        if "mu" not in kwargs:
            with pytest.raises(ParameterError, match=match):
                Energy(dens, params={"eps": 1e-3, "lam": 1.0, **kwargs})
    with pytest.raises(ParameterError, match="must be a function"):
        Energy("not a function")
    with pytest.raises(ParameterError, match="must map names to numbers"):
        Energy(dens, params=[1.0, 2.0])


# ------------------------------------------------------------------ parameterize: topology, start map


@pytest.mark.parametrize(
    "mesh, match",
    [
        (closed_tetrahedron(), r"no boundary \(a closed surface\)"),
        ((np.r_[V3, V3 + [5.0, 0, 0]], np.r_[F3, F3 + 16]), "2 connected components"),
        ((V3, np.delete(F3, [8, 9], axis=0)), "2 boundary loops"),  # the middle cell removed
        ((np.r_[V3, [[0.5, -0.5, 1.0], [0.5, -0.5, -1.0]]], np.r_[F3, [[1, 0, 16], [1, 0, 17]]]),
         "1 non-manifold edges"),
    ],
)
def test_parameterize_rejects_non_disks_with_the_topology_message(mesh, match):
    with pytest.raises(MeshError, match=match):
        parameterize(*mesh, progress=False)


def test_start_map_with_inverted_triangles_is_repaired_with_a_free_boundary():
    V, F = grid(4)
    x0 = V.copy()
    x0[5] = [0.9, 0.9]  # folds the triangles around vertex 5
    res = parameterize(V3, F3, x0=x0, progress=False)
    assert res.success and res.certificate.inverted == 0
    assert res.details.repair.stats.inverted_at_start > 0 and res.details.repair.success
    with pytest.raises(MeshError, match="collapsed"):
        parameterize(V3, F3, x0=np.zeros((16, 2)), progress=False)
    with pytest.raises(MeshError, match="NaN"):
        parameterize(V3, F3, x0=np.full((16, 2), np.nan), progress=False)
    with pytest.raises(MeshError, match="15 rows but the mesh has 16"):
        parameterize(V3, F3, x0=V[:15], progress=False)


def test_start_map_units_do_not_matter():
    ref = parameterize(V3, F3, progress=False)
    for k in (-150, 150):
        res = parameterize(V3, F3, x0=ref.details.start * 10.0**k, progress=False)
        assert res.success and res.energy == pytest.approx(ref.energy, rel=1e-9)


# ------------------------------------------------------------------ numerical safety


@pytest.mark.parametrize("name", [n for n in sorted(REGISTRY) if REGISTRY[n].barrier])
def test_barrier_objective_is_inf_with_finite_derivatives_on_inverted_maps(name):
    V, F = grid(3)
    obj = Objective(Problem.planar(V, F), name)
    x = V.copy()
    x[4] = [0.9, 0.9]  # inverts some triangles around the centre vertex
    x[0] = x[1]  # and makes one degenerate
    value, grad = obj.value_and_grad(jnp.asarray(x), obj.params())
    assert float(value) == np.inf
    assert np.isfinite(np.asarray(grad)).all()
    v2, g2, data = obj.hessian(jnp.asarray(x), obj.params(), "clamp")
    assert float(v2) == np.inf
    assert np.isfinite(np.asarray(g2)).all() and np.isfinite(np.asarray(data)).all()


def _nan_everywhere(J, params):
    return jnp.sum(J * J) * jnp.nan


@jax.custom_jvp
def _poison(s):
    """0 everywhere, with a NaN derivative where ``s > 3``: finite energy, NaN gradient."""
    return jnp.zeros_like(s)


@_poison.defjvp
def _poison_jvp(primals, tangents):
    (s,), (ds,) = primals, tangents
    return _poison(s), jnp.where(s > 3.0, jnp.nan, 0.0) * ds


def _nan_gradient_beyond_scale(J, params):
    """Minimum at J = 2 I, where |J|^2 = 8 > 3: the gradient is NaN there."""
    d = J.shape[-1]
    return jnp.sum((J - 2.0 * jnp.eye(d)) ** 2) + _poison(jnp.sum(J * J))


@pytest.mark.parametrize("density", [_nan_everywhere, _nan_gradient_beyond_scale])
def test_nonfinite_solve_ends_nonfinite_without_a_nan_map(density):
    V, F = grid(3)
    obj = Objective(Problem.planar(V, F), Energy(density, name="poisoned"))
    res = minimize(obj, V, Newton(max_steps=20), progress=False)
    assert res.outcome is Outcome.NONFINITE
    assert not res.success
    assert np.isfinite(res.x).all()
    assert res.certificate.inverted == obj.problem.count_inverted(res.x)
    with pytest.raises(SolveError, match="NaN/inf") as info:
        minimize(obj, V, Newton(max_steps=20), progress=False, throw=True)
    assert info.value.result.outcome is info.value.outcome is Outcome.NONFINITE
    assert info.value.certificate is info.value.result.certificate


def test_a_failed_solve_is_a_runtime_error_not_a_value_error():
    """`except ValueError` around a call (for its input checks) must not swallow a solve that
    failed: SolveError is a GeomoptError and a RuntimeError; bad input stays a ValueError."""
    from geomopt._runtime import errors as _errors
    from geomopt.linalg import linsolve

    assert issubclass(SolveError, GeomoptError) and issubclass(SolveError, RuntimeError)
    assert not issubclass(SolveError, ValueError) and not issubclass(GeomoptError, ValueError)
    assert issubclass(MeshError, ValueError) and issubclass(ParameterError, ValueError)
    errors = [c for c in vars(_errors).values() if isinstance(c, type) and issubclass(c, Exception)
              and not issubclass(c, Warning)]
    assert len(errors) == 6 and all(issubclass(e, GeomoptError) for e in errors)
    assert issubclass(linsolve.NotPositiveDefinite, GeomoptError) and issubclass(linsolve.NotPositiveDefinite,
                                                                                 ArithmeticError)
    P, x0 = _dead_inverted_problem()
    with pytest.raises(RuntimeError) as info:
        try:
            minimize(Objective(P, "dirichlet"), x0, progress=False, throw=True)
        except ValueError:  # user code guarding its input: the failed solve passes through
            pytest.fail("a failed solve was caught as a ValueError")
    assert type(info.value) is SolveError and info.value.outcome is not Outcome.CONVERGED


# ------------------------------------------------------------------ honest outcomes


def _dead_inverted_problem():
    """4x4 grid, boundary fixed with corner 3 moved so that triangle [2, 3, 7] (all vertices
    fixed) is inverted: no solve can fix it."""
    V, F = grid(4)
    boundary = np.flatnonzero(((V == 0) | (V == 1)).any(axis=1))
    pos = V[boundary].copy()
    pos[boundary == 3] = [0.5, 0.3]
    P = Problem.planar(V, F, fixed=boundary, fixed_positions=pos)
    return P, P.check_map(V)


def test_inverted_result_is_never_success():
    P, x0 = _dead_inverted_problem()
    assert P.count_inverted(x0) == 1
    res = minimize(Objective(P, "dirichlet"), x0, progress=False)
    assert res.certificate.inverted == P.count_inverted(res.x) == 1
    assert res.outcome is not Outcome.CONVERGED and not res.success
    assert "1 inverted element" in res.message
    with pytest.raises(SolveError, match="1 inverted element") as info:
        minimize(Objective(P, "dirichlet"), x0, progress=False, throw=True)
    assert info.value.result.certificate.inverted == 1


def test_success_result_is_flip_free_and_deterministic():
    a = parameterize(V3, F3, progress=False, throw=True)
    b = parameterize(V3, F3, progress=False)
    assert a.outcome is Outcome.CONVERGED and a.success and a.certificate.inverted == 0
    assert a.certificate.inverted == a.problem.count_inverted(a.x)
    assert np.array_equal(a.x, b.x) and a.energy == b.energy
    assert np.array_equal(a.trace.energy, b.trace.energy)
    c = parameterize(V3, F3, solver="newton", progress=False)  # a name works too
    assert np.array_equal(a.x, c.x)


def test_iteration_limit_is_reported_not_success():
    res = parameterize(V3, F3, solver=Newton(max_steps=1), progress=False)
    assert res.outcome is Outcome.MAX_STEPS and not res.success and res.certificate.inverted == 0
    with pytest.raises(SolveError, match="iteration limit"):
        parameterize(V3, F3, solver=Newton(max_steps=1), progress=False, throw=True)


# ------------------------------------------------------------------ fuzzing


def _arrays(kinds, max_side=6):
    """Small arrays of any shape (0-3 dims) and the given dtype kinds, with special values."""
    dtype = st.sampled_from(kinds)
    return dtype.flatmap(lambda dt: hnp.arrays(
        dt, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=max_side),
        elements=_elements(dt)))


def _elements(dt):
    dt = np.dtype(dt)
    if dt == np.float64:
        return st.one_of(st.floats(), st.sampled_from([0.0, 1.0, 1e-300, 1e200, -1e200]))
    if dt.kind == "f":
        return st.floats(width=dt.itemsize * 8)
    if dt.kind in "iu":
        info = np.iinfo(dt)
        return st.one_of(st.integers(max(info.min, -2), min(info.max, 8)), st.sampled_from([info.max, info.min]))
    return None  # bool, complex: hypothesis defaults


ANY_V = _arrays([np.float64, np.float32, np.int64, np.bool_, np.complex128])
ANY_S = _arrays([np.int64, np.int32, np.uint8, np.uint64, np.float64, np.bool_])


def _valid_or_geomopt_error(build):
    try:
        p = build()
    except GeomoptError:
        return None
    assert np.isfinite(p.rest_inv).all() and np.isfinite(p.volumes).all() and (p.volumes > 0).all()
    assert p.simplices.dtype == np.int64 and p.simplices.min() >= 0 and p.simplices.max() < p.n_vertices
    return p


@fuzz(250)
@given(V=ANY_V, S=ANY_S, kind=st.sampled_from(["planar", "surface", "tets"]))
def test_fuzz_problem_constructors_any_arrays(V, S, kind):
    _valid_or_geomopt_error(lambda: getattr(Problem, kind)(V, S))


@st.composite
def small_meshes(draw, corners):
    """Meshes that get past the array checks more often: few vertices, some coincident or
    collinear, random (possibly degenerate) index arrays."""
    n = draw(st.integers(3, 7))
    d = draw(st.sampled_from([2, 3]))
    coord = st.one_of(st.integers(-2, 2).map(float), st.floats(-2, 2), st.sampled_from([1e-9, 1e150]))
    V = np.array(draw(st.lists(st.lists(coord, min_size=d, max_size=d), min_size=n, max_size=n)))
    if draw(st.booleans()):  # make some vertices coincide
        i, j = draw(st.integers(0, n - 1)), draw(st.integers(0, n - 1))
        V[i] = V[j]
    m = draw(st.integers(1, 6))
    S = np.array(draw(st.lists(st.lists(st.integers(0, n - 1), min_size=corners, max_size=corners),
                               min_size=m, max_size=m)), dtype=np.int64)
    return V, S


@fuzz(200)
@given(mesh=small_meshes(3), fixed=st.lists(st.integers(-1, 7), max_size=3))
def test_fuzz_triangle_problems(mesh, fixed):
    V, F = mesh
    for build in (Problem.planar, Problem.surface):
        p = _valid_or_geomopt_error(lambda: build(V, F))
        if p is not None:
            _valid_or_geomopt_error(lambda: p.with_fixed(np.array(fixed, dtype=np.int64),
                                                        np.zeros((len(fixed), 2))))


@fuzz(150)
@given(mesh=small_meshes(4))
def test_fuzz_tet_problems(mesh):
    V, T = mesh
    _valid_or_geomopt_error(lambda: Problem.tets(V, T))


def _check_param_result(res, problem=None):
    assert isinstance(res.outcome, Outcome)
    assert np.isfinite(res.x).all() and res.x.shape == (16, 2)
    assert res.certificate.inverted == res.problem.count_inverted(res.x)
    if res.success:
        assert res.certificate.inverted == 0 and res.outcome is Outcome.CONVERGED
    if res.certificate.inverted:
        assert not res.success


@st.composite
def degenerate_grids(draw):
    """The 4x4 grid topology with random geometry: random heights, merged and collinear
    vertices, extreme scales, random 3D positions."""
    V = V3.copy()
    how = draw(st.sampled_from(["heights", "merge", "collinear", "scale", "random"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if how == "heights":
        V[:, 2] = rng.uniform(-1, 1, 16) * draw(st.sampled_from([0.1, 1.0, 10.0]))
    elif how == "merge":
        i, j = rng.integers(0, 16, 2)
        V[i] = V[j]
    elif how == "collinear":
        k = rng.integers(0, 16, draw(st.integers(1, 16)))
        V[k] = np.c_[V[k, 0], V[k, 0], V[k, 0]]
    elif how == "scale":
        V = V * 10.0 ** draw(st.sampled_from([-150, -100, -20, 20, 100, 150]))
    else:
        V = rng.uniform(-1, 1, (16, 3))
    return V


@fuzz(30)
@given(V=degenerate_grids())
def test_fuzz_parameterize_degenerate_geometry(V):
    try:
        res = parameterize(V, F3, progress=False)
    except GeomoptError:
        return
    _check_param_result(res)


@st.composite
def corrupted_faces(draw):
    """The grid's faces with a few entries replaced (or a wrong dtype/shape): same sizes, so a
    mesh that happens to be valid reuses the compiled kernels."""
    F = F3.copy()
    for _ in range(draw(st.integers(1, 3))):
        F[draw(st.integers(0, 17)), draw(st.integers(0, 2))] = draw(st.integers(-2, 17))
    how = draw(st.sampled_from(["ints", "ints", "float", "bool", "1d", "empty", "drop"]))
    return {"ints": F, "float": F.astype(float), "bool": F.astype(bool), "1d": F.ravel(),
            "empty": F[:0], "drop": F[:-2]}[how]


@fuzz(40)
@given(F=corrupted_faces())
def test_fuzz_parameterize_corrupted_faces(F):
    try:
        res = parameterize(V3, F, progress=False)
    except GeomoptError:
        return
    _check_param_result(res)


def test_a_lone_degenerate_rest_element_is_refused_though_its_size_rounds_away_from_zero():
    # found by the fuzz above: LU rounds this triangle's zero area to -8e-17, which the mean size
    # (its own) could not call small; its own edge lengths can
    V = np.array([[1.5, 0.125], [0.0, 1.0], [0.0, 1.0]])
    with pytest.raises(MeshError, match="near-\\)zero size"):
        Problem.planar(V, np.array([[0, 1, 2]]))
    T = np.array([[0, 1, 2, 3]])
    P = np.array([[0.1, 0.2, 0.3], [1.7, 0.3, 0.9], [0.4, 1.3, 0.2], [0.4, 1.3, 0.2]])
    with pytest.raises(MeshError, match="zero size"):
        Problem.tets(P, T)

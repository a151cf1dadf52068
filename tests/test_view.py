"""``geomopt.plot.show``: what it draws for each kind of map (no viewer needed), the one-line
message naming the ``[view]`` extra when neither viewer is installed, and screenshots taken
off-screen by each installed viewer (skipped when neither is)."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from geomopt import ParameterError, Problem, plot
from geomopt.mesh import generators
from geomopt.plot._view import BACKENDS, camera, inverted_rgb, scene
from geomopt.solvers import Outcome, Result

from conftest import cube_tets


def _result(problem, x):
    return Result(np.asarray(x, np.float64), Outcome.CONVERGED, problem.certify(x), problem=problem)


@pytest.fixture(scope="module")
def param():
    """A saddle-shaped disk and its projection to the plane, a flip-free UV map."""
    V, F = generators.saddle(rings=3)
    return _result(Problem.surface(V, F), V[:, :2])


@pytest.fixture(scope="module")
def tangled_tets():
    """A cube of 48 tets whose centre vertex is pulled out of it: some tets inverted."""
    V, T = cube_tets(2)
    x = V.copy()
    centre = int(np.flatnonzero(np.all(V == 0.5, axis=1))[0])
    x[centre] = [0.5, 0.5, 1.6]
    return _result(Problem.tets(V, T), x)


def test_a_parameterization_is_the_checkerboard_on_the_rest_surface(param):
    s = scene(param)
    assert not s.volume and s.colors is None
    np.testing.assert_array_equal(s.points, param.problem.rest_vertices)
    assert s.uv.min() == 0.0 and s.uv.max() == 1.0  # the map's bounding square is the unit square
    u = param.x - param.x.min(axis=0)
    np.testing.assert_allclose(s.uv, u / np.ptp(param.x, axis=0).max())  # uniform: the aspect is kept


def test_a_volume_map_is_coloured_and_its_inverted_tets_red(tangled_tets):
    s = scene(tangled_tets)
    P = tangled_tets.problem
    assert s.volume and s.uv is None and s.cells.shape == (48, 4)
    np.testing.assert_array_equal(s.points, tangled_tets.x)
    assert 0 < s.bad.sum() == P.count_inverted(tangled_tets.x) < len(s.cells)
    red = np.all(np.isclose(s.colors, inverted_rgb()), axis=1)
    np.testing.assert_array_equal(red, s.bad)
    assert np.all(s.colors >= 0) and np.all(s.colors <= 1)


def test_planar_quads_hexes_and_meshes():
    V, F = generators.square_mesh(4)
    planar = scene(_result(Problem.planar(V, F), V * [2.0, 1.0]))
    assert planar.planar and not planar.volume and not planar.bad.any()
    assert np.all(planar.points[:, 2] == 0) and np.allclose(planar.points[:, 0].max(), 2.0)
    Vh, H = generators.hex_mesh(2, 2, 2)
    hexes = scene(_result(Problem.hexes(Vh, H), Vh))
    assert hexes.volume and hexes.cells.shape == (8, 8) and hexes.colors.shape == (8, 3)
    Vt, T = cube_tets(1)
    assert scene((Vt, T)).volume and scene((Vt, T)).colors is None  # a bare mesh: one colour
    mesh = types.SimpleNamespace(vertices=V, faces=F)  # what trimesh offers
    withuv = scene(mesh, uv=V[:, :2])
    assert withuv.planar and withuv.uv.shape == (len(V), 2)


def test_meshio_meshes_prefer_volume_cells():
    meshio = pytest.importorskip("meshio")
    Vt, T = cube_tets(1)
    m = meshio.Mesh(Vt, [("triangle", T[:, :3]), ("tetra", T)])
    s = scene(m)
    assert s.volume and s.cells.shape == T.shape


def test_bad_input_is_refused_in_one_line(param, tangled_tets):
    with pytest.raises(ParameterError, match="Result, a mesh object"):
        scene(42)
    with pytest.raises(ParameterError, match="uv= is for a mesh"):
        scene(param, uv=param.x)
    V, T = cube_tets(1)
    with pytest.raises(ParameterError, match="volume mesh"):
        scene((V, T), uv=V[:, :2])
    with pytest.raises(ParameterError, match="backend must be one of"):
        plot.show(param, backend="mayavi", screenshot="x.png")
    for bad in ({"size": (0, 100)}, {"size": 300}, {"up": "w"}, {"checks": 0}):
        with pytest.raises(ParameterError, match=next(iter(bad))):
            plot.show(param, backend="polyscope", screenshot="x.png", **bad)


def test_without_a_viewer_the_message_names_the_extra(param, monkeypatch):
    for name in BACKENDS:
        monkeypatch.setitem(sys.modules, name, None)  # import fails as if not installed
    with pytest.raises(ParameterError, match=r'pip install "geomopt\[view\]"') as err:
        plot.show(param, screenshot="x.png")
    assert "\n" not in str(err.value) and "polyscope or pyvista" in str(err.value)
    with pytest.raises(ParameterError, match=r"needs pyvista.*geomopt\[view\]"):
        plot.show(param, backend="pyvista", screenshot="x.png")


def test_without_a_display_a_window_is_refused(param, monkeypatch):
    monkeypatch.setitem(sys.modules, "polyscope", types.ModuleType("polyscope"))
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ParameterError, match="screenshot="):
        plot.show(param, backend="polyscope")


def test_camera_sees_everything_from_the_view():
    P = np.random.default_rng(0).normal(size=(50, 3))
    pos, target, up = camera(P, (15.0, 30.0), "y", False, fov=45.0)
    view = target - pos
    assert np.isclose(np.dot(view, up), 0.0) and np.isclose(np.linalg.norm(up), 1.0)
    d = P - pos  # every point inside the view cone
    cos = d @ view / (np.linalg.norm(d, axis=1) * np.linalg.norm(view))
    assert np.all(cos > np.cos(np.radians(22.5 * np.sqrt(2))))
    pos, target, up = camera(P, (15.0, 30.0), "y", True)  # planar: from +z, y up
    assert np.allclose((pos - target)[:2], 0) and pos[2] > target[2] and np.allclose(up, [0, 1, 0])


def _viewer(name):
    pytest.importorskip(name)
    return name


@pytest.mark.parametrize("backend", BACKENDS)
def test_screenshot_of_a_parameterization(backend, param, tmp_path):
    _viewer(backend)
    path = tmp_path / "param.png"
    image = plot.show(param, backend=backend, screenshot=path, size=(240, 200))
    assert image.shape == (200, 240, 3) and image.dtype == np.uint8
    from PIL import Image

    np.testing.assert_array_equal(np.asarray(Image.open(path).convert("RGB")), image)
    orange = (image[..., 0] > 150) & (image[..., 2] < 110) & (image[..., 1] < image[..., 0] - 40)
    assert orange.mean() > 0.02  # the checkerboard's orange squares are on the surface
    rows = orange[80:120]
    assert np.median(np.count_nonzero(rows[:, 1:] != rows[:, :-1], axis=1)) >= 8  # many squares across


@pytest.mark.parametrize("backend", BACKENDS)
def test_screenshot_shows_inverted_tets_red(backend, tangled_tets, tmp_path):
    _viewer(backend)
    image = plot.show(tangled_tets, backend=backend, screenshot=tmp_path / "tets.png", size=(200, 200))
    red = (image[..., 0] > 120) & (image[..., 1] < 80) & (image[..., 2] < 80)
    assert red.mean() > 0.01
    P = tangled_tets.problem
    valid = plot.show(_result(P, P.rest_vertices), backend=backend, screenshot=tmp_path / "ok.png",
                      size=(200, 200))
    assert not ((valid[..., 0] > 120) & (valid[..., 1] < 80) & (valid[..., 2] < 80)).any()


def test_a_map_onto_the_sphere_is_drawn_on_the_unit_sphere():
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(1)
    V, F = np.asarray(m.vertices), np.asarray(m.faces)
    s = scene(_result(Problem.sphere(V, F), 3.0 * V))
    np.testing.assert_allclose(np.linalg.norm(s.points, axis=1), 1.0)
    assert not s.volume and not s.planar and s.colors.shape == (len(F), 3) and not s.bad.any()

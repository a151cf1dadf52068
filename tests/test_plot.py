"""Pictures: the checkerboard is a per-pixel texture through the UV map (not one colour per
triangle), the nearest surface wins each pixel, figures have the sizes and panels they promise,
and ``param --uv-range unit`` writes UVs in the unit square."""

from __future__ import annotations

import numpy as np
import pytest

from geomopt import plot
from geomopt._render import CHECKER_COLORS, camera_rotation, project, rasterize, render_uv_checker

from test_cli import read_uv_obj, write_obj
from test_compare import V3, F, png_size

SQUARE_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def test_camera_is_a_rotation_and_looks_from_the_named_side():
    for elev, azim, up in ((15.0, 30.0, "y"), (90.0, 0.0, "z"), (-40.0, 200.0, "x")):
        R = camera_rotation(elev, azim, up)
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(camera_rotation(90.0, 0.0, "z")[2], [0, 0, 1])  # from above, z up
    assert np.allclose(camera_rotation(0.0, 0.0, "y")[2], [0, 0, 1])  # from +z, y up (OpenGL)


def test_checkerboard_is_per_pixel_inside_a_triangle():
    """Two triangles, an 8 x 8 checkerboard: one colour per triangle would give 2 regions;
    per pixel, a row crosses 7 square borders and a pixel's colour is the checker's at its
    UV (seen from above with z up the square fills the image, u to the right, v up)."""
    img = render_uv_checker(SQUARE_V, SQUARE_F, SQUARE_V[:, :2], size=(200, 200), elev=90.0, azim=-90.0,
                            up="z", checks=8, light=(0.0, 0.0, 1.0), supersample=1)
    assert img.shape == (200, 200, 4) and img[5:-5, 5:-5, 3].min() == 1.0  # covered inside the margin
    orange = np.abs(img[..., :3] - CHECKER_COLORS[1]).sum(axis=-1) < 0.05
    row = orange[100, 5:-5]
    assert np.count_nonzero(row[1:] != row[:-1]) == 7
    # the checker at the pixel centres (the margin maps the square into [4, 196] pixels)
    c = (np.arange(200) + 0.5 - 100) / 192 + 0.5
    u, v = np.meshgrid(c, c[::-1])
    expected = (np.floor(8 * u) + np.floor(8 * v)) % 2 == 1
    inner = (np.minimum(u, v) > 0.01) & (np.maximum(u, v) < 0.99)
    assert np.mean(orange[inner] == expected[inner]) > 0.99  # all but pixels on a border


def test_nearest_surface_wins_each_pixel():
    V = np.r_[SQUARE_V, SQUARE_V * [0.5, 0.5, 1] + [0.25, 0.25, 1.0]]  # a smaller square above
    F = np.r_[SQUARE_F, SQUARE_F + 4]
    R = camera_rotation(90.0, -90.0, "z")
    face, bary = rasterize(*project(V, R, (64, 64)), F, (64, 64))
    assert set(np.unique(face[28:36, 28:36])) <= {2, 3}  # the centre: the upper square
    assert set(np.unique(face[2:6, 2:6])) <= {0, 1}  # a corner: only the lower one
    assert np.allclose(bary[face >= 0].sum(axis=1), 1.0) and (bary >= -1e-9).all()
    R = camera_rotation(-90.0, -90.0, "z")  # from below the lower square hides the upper one
    face, _ = rasterize(*project(V, R, (64, 64)), F, (64, 64))
    assert set(np.unique(face[28:36, 28:36])) <= {0, 1}


def test_param_figure_panels_and_size(tmp_path):
    uv = V3[:, :2]
    fig = plot.param_figure(V3, F, uv, np.arange(len(F), dtype=float), title="t")
    assert [ax.get_title() for ax in fig.axes[:3]] == ["20 x 20 checkerboard through the UV map",
                                                       "other side", "UV layout"]
    plot.save_param_figure(tmp_path / "p.png", V3, F, uv)
    assert png_size((tmp_path / "p.png").read_bytes()) == (1760, 825)
    with pytest.raises(Exception, match="format="):
        plot.save_param_figure(open(tmp_path / "q", "wb"), V3, F, uv)


def test_convergence_figure_leaves_out_the_reference_point():
    e = np.array([3.0, 2.0, 1.5, 1.0])
    fig = plot.convergence_figure({"a": (np.arange(4), e, np.array([1.0, 0.1, 0.01, 0.001]))})
    line = fig.axes[0].get_lines()[0]
    assert list(line.get_xdata()) == [0, 1, 2]  # the last iterate is the reference: no gap to draw
    assert np.allclose(line.get_ydata(), [2.0, 1.0, 0.5])
    assert len(fig.axes) == 2 and len(fig.axes[1].get_lines()[0].get_xdata()) == 4


def test_param_uv_range_unit(cli, tmp_path):
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    assert cli("param", mesh, "-o", tmp_path / "raw.obj", "--quiet")[0] == 0
    code, out, _ = cli("param", mesh, "-o", tmp_path / "unit.obj", "--uv-range", "unit", "--quiet", "--json")
    assert code == 0 and '"uv_range": "unit"' in out
    raw, unit = read_uv_obj(tmp_path / "raw.obj")[1], read_uv_obj(tmp_path / "unit.obj")[1]
    assert np.allclose(unit.min(axis=0), 0.0) and np.isclose(np.ptp(unit, axis=0).max(), 1.0)
    scale = np.ptp(raw, axis=0).max()
    assert np.allclose(unit * scale + raw.min(axis=0), raw)  # the same map, moved and scaled uniformly


def test_distortion_of_a_similarity_and_a_stretch():
    from geomopt import Problem

    problem = Problem.surface(V3, F)
    flat = Problem.planar(V3[:, :2], F)
    d = plot.distortion(flat, 2.0 * V3[:, :2] @ np.array([[0.6, -0.8], [0.8, 0.6]]))  # rotate, scale 2
    assert np.allclose(d["conformal"], 1.0) and np.allclose(d["area"], 4.0)
    d = plot.distortion(flat, V3[:, :2] * [3.0, 1.0])
    assert np.allclose(d["conformal"], 3.0) and np.allclose(d["area"], 3.0)
    assert plot.distortion(problem, V3[:, :2])["area"].shape == (len(F),)


def test_many_triangles_are_numbered_over_several_drawings(monkeypatch):
    """Triangle numbers wider than one drawing's colour bits are drawn in several passes with
    the same painter's order: 3 bits a pass gives the faces and coordinates of 24 bits."""
    import geomopt._render as render

    V = np.r_[SQUARE_V, SQUARE_V * [0.5, 0.5, 1] + [0.25, 0.25, 1.0]]
    V, F = np.r_[V, V + [2.0, 0.0, 0.0]], np.r_[SQUARE_F, SQUARE_F + 4]
    F = np.r_[F, F + 8, F + 8]  # 12 triangles (the last four twice): numbers up to 12 need 2 passes
    R = camera_rotation(90.0, -90.0, "z")
    args = (*project(V, R, (96, 48)), F, (96, 48))
    face, bary = rasterize(*args)
    monkeypatch.setattr(render, "CODE_BITS", 3)
    face3, bary3 = rasterize(*args)
    assert len(np.unique(face)) == 9 and (face == face3).all() and (bary == bary3).all()


def test_checker_borders_are_anti_aliased_without_supersampling():
    """Each pixel's colour is the checkerboard averaged over the pixel: pure inside a square,
    a blend only in the pixels a border crosses (a row of 200 pixels crosses 7 borders), and
    mostly the colour of the side its centre lies on (7 checks over 192 pixels: every border
    falls inside a pixel)."""
    img = render_uv_checker(SQUARE_V, SQUARE_F, SQUARE_V[:, :2], size=(200, 200), elev=90.0, azim=-90.0,
                            up="z", checks=7, light=(0.0, 0.0, 1.0), supersample=1)
    white, orange = (np.abs(img[..., :3] - c).sum(axis=-1) < 0.02 for c in CHECKER_COLORS)
    row = ~(white | orange)[100, 5:-5]  # blended pixels in a row through the middle
    assert 6 <= np.count_nonzero(row) <= 18
    assert np.count_nonzero(white[100, 5:-5]) > 70 and np.count_nonzero(orange[100, 5:-5]) > 70

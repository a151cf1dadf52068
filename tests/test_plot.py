"""Pictures: the checkerboard is a per-pixel texture through the UV map (not one colour per
triangle), the nearest surface wins each pixel, figures have the sizes and panels they promise,
and ``param --uv-range unit`` writes UVs in the unit square."""

from __future__ import annotations

import numpy as np
import pytest

from geomopt import plot
from geomopt.plot import _figures
from geomopt.plot._render import CHECKER_COLORS, camera_rotation, project, rasterize, render_uv_checker

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


def test_checkerboard_follows_u_across_and_v_up():
    """UV (u, v / 2) on the square seen from above: u spans the 8 checks of the bounding square
    across the image, v half of them (4) up it."""
    img = render_uv_checker(SQUARE_V, SQUARE_F, SQUARE_V[:, :2] * [1.0, 0.5], size=(200, 200), elev=90.0,
                            azim=-90.0, up="z", checks=8, light=(0.0, 0.0, 1.0), supersample=1)
    orange = np.abs(img[..., :3] - CHECKER_COLORS[1]).sum(axis=-1) < 0.05
    row, col = orange[100, 5:-5], orange[5:-5, 101]
    assert np.count_nonzero(row[1:] != row[:-1]) == 7 and np.count_nonzero(col[1:] != col[:-1]) == 3
    assert not orange[190, 8] and orange[190, 30] and not orange[190, 60]  # bottom left: u in checks 0, 1, 2


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


def _brute_force_z_buffer(xy, depth, F, size):
    """Per pixel centre, every triangle tested: (face, margin) with face the nearest triangle
    containing the centre (-1 for none) and margin how far the decision is from a tie (the
    smallest barycentric coordinate of any triangle near the centre, and the depth gap)."""
    width, height = size
    cx, cy = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    T = xy[F]
    e1, e2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    dx, dy = cx[..., None] - T[:, 0, 0], cy[..., None] - T[:, 0, 1]
    l1 = (dx * e2[:, 1] - dy * e2[:, 0]) / area
    l2 = (dy * e1[:, 0] - dx * e1[:, 1]) / area
    lam = np.stack([1 - l1 - l2, l1, l2], axis=-1)  # (h, w, m, 3)
    inside = lam.min(axis=-1) >= 0
    z = np.where(inside, (lam * depth[F]).sum(axis=-1), -np.inf)
    face = np.where(inside.any(axis=-1), z.argmax(axis=-1), -1)
    edge = np.abs(lam.min(axis=-1)).min(axis=-1)  # how near the centre is to any triangle's edge
    zs = np.sort(z, axis=-1)
    with np.errstate(invalid="ignore"):
        gap = np.where(np.isfinite(zs[..., -2]), zs[..., -1] - zs[..., -2], np.inf)
    return face, np.minimum(edge * np.abs(area).min() ** 0.5, gap), lam


def test_rasterize_agrees_with_a_brute_force_z_buffer():
    """40 random overlapping triangles at random depths: wherever the brute-force answer is
    not a near tie, the rasteriser names the same nearest triangle (or none) and the same
    barycentric coordinates."""
    rng = np.random.default_rng(3)
    size = (80, 60)
    xy = rng.uniform([-5, -5], [85, 65], (120, 2))
    depth = rng.uniform(0, 1, 120)
    F = rng.permutation(120).reshape(40, 3)
    face, bary = rasterize(xy, depth, F, size)
    expected, margin, lam = _brute_force_z_buffer(xy, depth, F, size)
    clear = margin > 1e-6
    assert clear.mean() > 0.95 and (expected[clear] >= 0).mean() > 0.5
    assert (face[clear] == expected[clear]).all()
    rows, cols = np.nonzero(clear & (expected >= 0))
    assert np.allclose(bary[rows, cols], lam[rows, cols, expected[rows, cols]], atol=1e-9)
    assert (bary[face < 0] == 0).all()


def test_a_fine_mesh_leaves_no_cracks():
    """A 25 x 25 jittered grid of 1250 triangles over the square, edges crossing pixel centres
    everywhere: every pixel centre inside the square belongs to some triangle."""
    rng = np.random.default_rng(0)
    n = 25
    g = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(g, g)
    inner = (X > 0) & (X < 1) & (Y > 0) & (Y < 1)
    P = np.c_[X.ravel(), Y.ravel()] + np.where(inner.ravel()[:, None], rng.uniform(-0.3, 0.3, ((n + 1) ** 2, 2)) / n, 0)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)).ravel()
    F = np.r_[np.c_[i, i + 1, i + n + 2], np.c_[i, i + n + 2, i + n + 1]]
    size = (97, 97)
    xy = np.round(P * 96.0 * 2) / 2  # vertices on pixel centres and corners: the hardest case
    face, _ = rasterize(xy, np.zeros(len(P)), F, size)
    assert (face[1:96, 1:96] >= 0).all()


def test_a_pixel_centre_on_a_shared_edge_is_covered():
    """An edge through the pixel centre (5.5, 5.5) whose crossing with the row's centre line
    rounds to 5.5 + 1 ulp from one end and 5.5 - 1 ulp from the other: evaluated from each
    triangle's own first corner, both triangles would leave the pixel out (a crack)."""
    P, Q = [2.165451919112565, 3.3945176788905553], [8.66931011918644, 7.501148660685806]
    xy = np.array([P, Q, [0.0, 8.0], [11.0, 3.0]])
    for F in ([[0, 1, 2], [1, 0, 3]], [[1, 0, 2], [0, 1, 3]], [[0, 1, 3], [1, 0, 2]]):
        face, _ = rasterize(xy, np.zeros(4), np.array(F), (12, 12))
        assert face[5, 5] >= 0


def test_surface_pixels_have_their_triangle_colour_and_lambert_shading():
    """A unit square of two triangles tilted 60 degrees about the x axis, seen along z with a
    light along z: the pixels of each triangle have its colour times 0.3 + 0.7 cos 60."""
    from geomopt.plot._render import render_surface

    c, s = np.cos(np.radians(60)), np.sin(np.radians(60))
    V = SQUARE_V @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]]).T
    palette = np.array([[1.0, 0.2, 0.2], [0.2, 0.2, 1.0]])
    img = render_surface(V, SQUARE_F, lambda f, b, hit: palette[f], size=(100, 100), elev=0.0, azim=0.0,
                         light=(0.0, 0.0, 1.0), supersample=1)
    shade = 0.3 + 0.7 * 0.5
    lower_right, upper_left = img[60, 80], img[40, 20]  # triangle 0 is (0,0),(1,0),(1,1): below the diagonal
    assert np.allclose(lower_right, [*(palette[0] * shade), 1.0]) and np.allclose(upper_left, [*(palette[1] * shade), 1.0])
    assert img[2, 50, 3] == 0.0  # the square fills the width but only half the height: empty above


def test_flat_tripcolor_colours_each_face_flat():
    """The layout's per-face colours drawn as Gouraud triangles come out flat: the pixels well
    inside each triangle have its value's colour."""
    from matplotlib import colormaps

    fig = _figures._figure(2, 2, 100, layout=None)
    ax = fig.add_axes((0, 0, 1, 1))
    x = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    plot.flat_tripcolor(ax, x, SQUARE_F, [0.0, 1.0], cmap="viridis", vmin=0.0, vmax=1.0)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_axis_off()
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0  # 200 x 200, row 0 at the top
    for (row, col), value in (((150, 150), 0.0), ((170, 120), 0.0), ((50, 50), 1.0), ((30, 80), 1.0)):
        assert np.abs(img[row, col] - colormaps["viridis"](value)[:3]).max() < 2 / 255


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


def test_log_ticks_are_powers_of_ten_in_superscripts_not_mathtext():
    """The convergence plot's log-axis labels are plain text (no mathtext to parse): 10⁻² for
    a power of ten, 2×10⁻³ between them, as matplotlib's own labels read."""
    assert _figures.superscript_powers(r"$\mathdefault{10^{-12}}$") == "10\u207b\u00b9\u00b2"
    assert _figures.superscript_powers(r"$\mathdefault{2\times10^{3}}$") == "2\u00d710\u00b3"
    assert _figures.superscript_powers("0.5") == "0.5"
    e = 1.0 + np.logspace(0.0, -6.0, 8)
    fig = plot.convergence_figure({"a": (np.arange(8), e, np.logspace(1.0, -3.0, 8))})
    fig.canvas.draw()
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.yaxis.get_ticklabels(which="both") if t.get_text()]
        assert labels and not any("$" in t for t in labels)
    assert "10\u207b\u00b2" in [t.get_text() for t in fig.axes[1].yaxis.get_ticklabels()]

"""PNG pictures composed without matplotlib (geomopt.plot._compose): the param picture's panels hold
the rasterizer's renders where matplotlib's layout puts them, the layout's triangles have their
values' viridis colours, the text is drawn, the ticks are the ones matplotlib picks, anything
this module would draw differently falls back to matplotlib, and ``geomopt param --png`` never
imports matplotlib."""

from __future__ import annotations

import io
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from geomopt import plot
from geomopt.plot import _compose
from geomopt.plot._render import render_uv_checker

from test_cli import write_obj
from test_compare import V3, F, png_size

REPO = Path(__file__).resolve().parents[1]
SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def _pixels(image):
    return np.asarray(image.convert("RGB")).astype(int)


def test_viridis_is_matplotlibs_table():
    from matplotlib import colormaps

    assert _compose.VIRIDIS.shape == (256, 3)
    assert np.abs(_compose.VIRIDIS / 255.0 - colormaps["viridis"].colors).max() <= 0.5 / 255 + 1e-12
    values = np.array([-1.0, 0.0, 0.3, 0.5, 0.999, 1.0])
    expected = np.clip((colormaps["viridis"](np.clip(values, 0, 1)) * 255)[:, :3], 0, 255)
    assert np.abs(_compose.VIRIDIS[_compose.colour_index(values, 0.0, 1.0)] - expected).max() <= 1.0


@pytest.mark.parametrize("lo, hi, nbins, integer", [(-0.8, 16.8, 10, True), (-0.85, 17.85, 10, True),
                                                    (-1.45, 30.45, 10, True), (-0.2, 4.2, 10, True),
                                                    (0.0, 1.2, 9, False), (0.013, 1.19, 9, False),
                                                    (-3.3, 7.1, 9, False), (0.0, 0.37, 5, False)])
def test_linear_ticks_are_matplotlibs(lo, hi, nbins, integer):
    """The colour bar's ticks as AutoLocator's, the convergence plot's iterations as
    MaxNLocator(integer=True)'s (the ticks in the view: matplotlib's run one beyond)."""
    from matplotlib.ticker import MaxNLocator

    eps = 1e-9 * (hi - lo)

    steps = _compose.MAXN_STEPS if integer else _compose.AUTO_STEPS
    mpl = MaxNLocator(nbins=nbins, steps=steps, integer=integer).tick_values(lo, hi)
    assert np.allclose(_compose.linear_ticks(lo, hi, nbins, steps, integer), mpl[(mpl >= lo - eps) & (mpl <= hi + eps)])
    if integer:
        mpl = MaxNLocator(integer=True).tick_values(lo, hi)  # the plot's own locator: its default steps
        in_view = mpl[(mpl >= lo - eps) & (mpl <= hi + eps)]
        assert np.allclose(_compose.linear_ticks(lo, hi, nbins, steps, integer), in_view)


@pytest.mark.parametrize("lo, hi, n", [(-14.7, 1.2, 9), (-11.7, 3.6, 9), (-3.2, 0.4, 9), (-2.3, 5.9, 4),
                                       (-20.0, 2.0, 9), (0.2, 1.6, 9), (-6.1, -1.05, 2),
                                       (-13.5, 2.5, 9)])
def test_log_ticks_are_matplotlibs(lo, hi, n):
    import matplotlib
    from matplotlib.ticker import LogLocator

    if tuple(int(p) for p in matplotlib.__version__.split(".")[:2]) < (3, 11):
        pytest.skip(f"the composed log ticks follow matplotlib 3.11's LogLocator (its rule for the decades "
                    f"labelled changed since {matplotlib.__version__}, the version installed)")

    major, minor = _compose.log_ticks(lo, hi, n)
    mpl = np.log10(LogLocator(numticks=n).tick_values(10.0**lo, 10.0**hi))
    assert major == [round(e) for e in mpl if lo <= e <= hi]
    mpl_minor = np.log10(LogLocator(subs="auto", numticks=n).tick_values(10.0**lo, 10.0**hi))
    assert np.allclose(minor, [e for e in mpl_minor if lo <= e <= hi])


@pytest.mark.parametrize("lo, hi", [(0.0, 1.2), (0.0, 4.3e-5), (-3.3, 7.1), (1e6, 2.5e6), (0.013, 0.0171)])
def test_colour_bar_labels_are_matplotlibs(lo, hi):
    """Tick labels and the power of ten at the axis' end as matplotlib's ScalarFormatter writes
    them (its minus sign too)."""
    from matplotlib.figure import Figure

    ax = Figure().add_subplot()
    ax.set_ylim(lo, hi)
    ticks = _compose.linear_ticks(lo, hi, 9)
    formatter = ax.yaxis.get_major_formatter()
    assert _compose.scalar_labels(ticks) == (formatter.format_ticks(ticks), formatter.get_offset())


def _param_picture(title="t", values=None, **kw):
    uv = V3[:, :2]
    values = np.linspace(0.0, 1.2, len(F)) if values is None else values
    return _compose.param_picture(V3, F, uv, values, title=title, label="distortion", **kw), uv


def test_checker_panels_are_the_rasterizers_renders_where_matplotlib_puts_them():
    """matplotlib's layout at 110 dpi (measured): the front panel a 695 px square at column 11,
    row 100.75; the back one 291.9 px at column 734, row 302.3; the renders 1.25x as large."""
    image, uv = _param_picture()
    assert image.size == (1760, 825)
    pixels = _pixels(image)
    for size, azim, (col, row, side) in ((869, 30.0, (11, 101, 695)), (365, 210.0, (734, 302, 292))):
        render = render_uv_checker(V3, F, uv, size=(size, size), elev=15.0, azim=azim, checks=20, supersample=1)
        a = render[..., 3:]
        rgb = np.rint((render[..., :3] * a + 1.0 - a) * 255).astype(np.uint8)
        shown = _pixels(Image.fromarray(rgb).resize((side, side), Image.Resampling.HAMMING))
        assert np.abs(pixels[row:row + side, col:col + side] - shown).max() <= 1
        assert (shown.min(axis=-1) < 200).sum() > 0.1 * side * side  # something was drawn there


def test_layout_triangles_have_their_values_colours():
    """Two triangles of a 1 x 2 rectangle with the values 0 and 1: each one's inside is the
    first and the last viridis colour, placed as matplotlib places the layout; the colour bar
    runs through the table, top the last."""
    uv = SQUARE * [1.0, 2.0]
    image = _pixels(_compose.param_picture(np.c_[uv, np.zeros(4)], SQUARE_F, uv, np.array([0.0, 1.0]), title="t"))
    # matplotlib's layout axes: the cell's 556 x 731.5 px left of the colour bar (from column
    # 1054, row 82.5), equal aspect, 5% margins: data 1.1 x 2.2 scaled to the height, the
    # axes anchored to the right
    scale = 731.5 / 2.2
    left, top = 1054.0 + 556.0 - 1.1 * scale, 82.5

    def at(u, v):
        return int(round(top + (2.1 - v) * scale)), int(round(left + (u + 0.05) * scale))

    first, last = _compose.VIRIDIS[0], _compose.VIRIDIS[255]
    for (u, v), colour in (((0.8, 0.4), first), ((0.6, 0.7), first), ((0.2, 1.6), last), ((0.35, 1.2), last),
                           ((0.02, 1.95), last), ((0.98, 0.05), first)):
        assert np.array_equal(image[at(u, v)], colour), (u, v)
    for u, v in ((-0.03, 1.0), (1.03, 1.0), (0.5, -0.03), (0.5, 2.03)):  # outside the rectangle: white
        assert np.array_equal(image[at(u, v)], [255, 255, 255]), (u, v)
    # the colour bar: 585.2 x 29.3 px from row 155.65, column 1644.7 (matplotlib's), its outline
    # on rows 156 and 741; each row inside the table's colour of its place, top the largest value
    rows = np.arange(158, 739)
    expected = _compose.VIRIDIS[np.minimum(np.floor((1.0 - (rows - 156 + 0.5) / 585) * 256), 255).astype(int)]
    assert np.array_equal(image[rows, 1660], expected)
    assert (image[150:154, 1660] == 255).all() and (image[156, 1650:1670] == 0).all()


def test_text_is_drawn_and_left_out_without_a_title():
    with_title, _ = _param_picture(title="a title")
    without, _ = _param_picture(title="")
    top = _pixels(with_title)[5:35, 600:1160]
    assert (top.max(axis=-1) < 100).sum() > 150  # dark letters of the title
    assert (_pixels(without)[5:35, 600:1160] == 255).all()
    label = _pixels(with_title)[300:550, 1700:1760]  # the colour bar's label, turned upwards
    assert (label.max(axis=-1) < 100).sum() > 100
    ticks = _pixels(with_title)[150:680, 1680:1705]  # its tick labels
    assert (ticks.max(axis=-1) < 100).sum() > 100
    caption = _pixels(with_title)[70:100, 150:550]  # "20 x 20 checkerboard through the UV map"
    assert (caption.max(axis=-1) < 100).sum() > 100


def test_convergence_picture_size_lines_and_fallback(tmp_path):
    e = 1.0 + np.logspace(0.0, -12.0, 15)
    g = np.logspace(3.0, -9.0, 15)
    image = _compose.convergence_picture({"a": (np.arange(15), e, g), "b": (np.arange(15), e + 1e-3, 10 * g)},
                                         title="t")
    assert image.size == (1200, 480)
    pixels = _pixels(image)
    blue, orange = np.array([31, 119, 180]), np.array([255, 127, 14])
    for colour in (blue, orange):
        near = np.abs(pixels - colour).max(axis=-1) < 40
        assert near[:, :600].sum() > 200  # each series in the gap panel
        assert near[:, 600:].sum() > 200  # and in the gradient norms
    assert _compose.convergence_picture({"a": (np.arange(3), np.array([1.5, 1.2, 1.0]))}) is None  # < a decade
    plot.save_convergence(tmp_path / "c.png", {"a": (np.arange(3), np.array([1.5, 1.2, 1.0]))})
    assert png_size((tmp_path / "c.png").read_bytes()) == (720, 480)  # matplotlib's 6 x 4 inches


def test_what_compose_cannot_draw_matplotlib_does(tmp_path, monkeypatch):
    assert _param_picture(values=np.ones(len(F)))[0] is None  # one value: no scale
    assert _param_picture(values=np.r_[np.inf, np.zeros(len(F) - 1)])[0] is None
    assert _param_picture(values=np.linspace(100.0, 100.01, len(F)))[0] is None  # an offset: +1e2
    plot.save_param_figure(tmp_path / "w.png", V3, F, V3[:, :2])  # a wireframe: matplotlib
    assert png_size((tmp_path / "w.png").read_bytes()) == (1760, 825)
    monkeypatch.setattr(_compose, "font_path", lambda: None)
    assert _param_picture()[0] is None
    buffer = io.BytesIO()
    plot.save_param_figure(buffer, V3, F, V3[:, :2], np.linspace(0.0, 1.0, len(F)), format="png")
    assert png_size(buffer.getvalue()) == (1760, 825)


def test_the_font_is_matplotlibs_found_without_importing_it():
    path = _compose.font_path()
    assert path is not None and path.endswith("DejaVuSans.ttf") and os.path.isfile(path)


def test_a_warm_param_png_process_traces_lowers_and_compiles_nothing(tmp_path):
    """The second ``geomopt param --png`` process (its programs kept on disk by the first) runs
    no JAX trace, lowering or compilation: every kernel is loaded, nothing is done eagerly
    (an eager ``jnp.asarray`` or slice would be lowered and compiled in every process)."""
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    script = ("import sys, jax, geomopt.cli\n"
              "events = []\n"
              "jax.monitoring.register_event_duration_secs_listener(\n"
              "    lambda event, secs, **kw: events.append(event.rsplit('/', 1)[-1]))\n"
              f"code = geomopt.cli.main(['param', {str(mesh)!r}, '-o', {str(tmp_path / 'uv.obj')!r}, '--png', "
              f"{str(tmp_path / 'uv.png')!r}, '--quiet'])\n"
              "print(code, sorted(set(e for e in events if 'trace' in e or 'mlir' in e or 'compile' in e)))\n")
    env = {**os.environ, "PYTHONPATH": str(REPO), "GEOMOPT_CACHE_DIR": str(tmp_path / "cache")}
    runs = [subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=env,
                           cwd=str(tmp_path)) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[-1].stderr
    assert "trace" in runs[0].stdout  # the cold process does trace: the listener hears it
    assert runs[1].stdout.split() == ["0", "[]"], runs[1].stdout


def test_param_png_does_not_import_matplotlib(tmp_path):
    """``geomopt param --png`` writes both PNGs (composed) with matplotlib never imported (nor
    scipy.optimize, nor scipy.sparse.linalg and csgraph where a sparse Cholesky other than SuperLU
    is installed: their imports cost 50 ms of every run); a PDF still goes through matplotlib."""
    mesh = write_obj(tmp_path / "m.obj", V3, F)
    script = ("import sys, geomopt.cli\n"
              f"code = geomopt.cli.main(['param', {str(mesh)!r}, '-o', {str(tmp_path / 'uv.obj')!r}, '--png', "
              f"{str(tmp_path / 'uv.png')!r}, '--quiet'])\n"
              "from geomopt.linalg.linsolve import available_backends\n"
              "print(code, 'matplotlib' in sys.modules, 'scipy.optimize' in sys.modules,\n"
              "      available_backends()[0] != 'superlu' and any(m in sys.modules for m in\n"
              "      ('scipy.sparse.linalg', 'scipy.sparse.csgraph', 'scipy.linalg')))\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["0", "False", "False", "False"]  # scipy.optimize: 0.15 s of import
    assert png_size((tmp_path / "uv.png").read_bytes()) == (1760, 825)
    assert png_size((tmp_path / "uv_convergence.png").read_bytes()) == (1200, 480)
    assert math.isclose(Image.open(tmp_path / "uv.png").info["dpi"][0], 110.0, abs_tol=0.01)

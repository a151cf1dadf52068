"""Raster (PNG) pictures composed with NumPy and Pillow, without importing matplotlib.

``geomopt param --png`` (and ``demo``) draws two pictures, the checkerboard beside the UV
layout (:func:`param_picture`) and the convergence plot (:func:`convergence_picture`); drawn
through matplotlib, its import and its drawing would take a large share of the command's
time (measurements: benchmarks/README.md, issue 49 section).  Here they are composed directly:
the checkerboard renders and the layout's flat triangles come from the NumPy rasterizer
(:mod:`geomopt.plot._render`), the colour table is viridis' 256 entries, and titles, tick
labels and lines are drawn by Pillow with matplotlib's own font (DejaVu Sans, found in
matplotlib's data folder without importing it).  The layout,
panel sizes, tick choice and text sizes follow :mod:`geomopt.plot`'s figures at the same dpi.

Each ``*_picture`` returns a Pillow RGB image, or None when it cannot draw the picture the way
matplotlib would (no font or no Pillow, non-finite values, a log axis spanning less than a
decade): the caller then draws it with matplotlib (:mod:`geomopt.plot`).  Vector formats
always take matplotlib's path.
"""

from __future__ import annotations

import concurrent.futures
import functools
import math

import numpy as np

__all__ = ["VIRIDIS", "SUPERSCRIPT", "TAB10", "AUTO_STEPS", "MAXN_STEPS", "RENDER_SCALE", "font_path",
           "colour_index", "linear_ticks", "scalar_labels", "log_ticks", "flat_triangles", "param_picture",
           "convergence_picture", "save_png"]

#: viridis' 256 colours, RGB 0-255 rows (matplotlib's table, rounded)
VIRIDIS = np.frombuffer(bytes.fromhex(
    "44015444025645045745055946075a46085c460a5d460b5e470d60470e61471063471164471365481467481668481769"
    "48186a481a6c481b6d481c6e481d6f481f70482071482173482374482475482576482677482878482979472a7a472c7a"
    "472d7b472e7c472f7d46307e46327e46337f463480453581453781453882443983443a83443b84433d84433e85423f85"
    "4240864241864142874144874045884046883f47883f48893e49893e4a893e4c8a3d4d8a3d4e8a3c4f8a3c508b3b518b"
    "3b528b3a538b3a548c39558c39568c38588c38598c375a8c375b8d365c8d365d8d355e8d355f8d34608d34618d33628d"
    "33638d32648e32658e31668e31678e31688e30698e306a8e2f6b8e2f6c8e2e6d8e2e6e8e2e6f8e2d708e2d718e2c718e"
    "2c728e2c738e2b748e2b758e2a768e2a778e2a788e29798e297a8e297b8e287c8e287d8e277e8e277f8e27808e26818e"
    "26828e26828e25838e25848e25858e24868e24878e23888e23898e238a8d228b8d228c8d228d8d218e8d218f8d21908d"
    "21918c20928c20928c20938c1f948c1f958b1f968b1f978b1f988b1f998a1f9a8a1e9b8a1e9c891e9d891f9e891f9f88"
    "1fa0881fa1881fa1871fa28720a38620a48621a58521a68522a78522a88423a98324aa8325ab8225ac8226ad8127ad81"
    "28ae8029af7f2ab07f2cb17e2db27d2eb37c2fb47c31b57b32b67a34b67935b77937b87838b9773aba763bbb753dbc74"
    "3fbc7340bd7242be7144bf7046c06f48c16e4ac16d4cc26c4ec36b50c46a52c56954c56856c66758c7655ac8645cc863"
    "5ec96260ca6063cb5f65cb5e67cc5c69cd5b6ccd5a6ece5870cf5773d05675d05477d1537ad1517cd2507fd34e81d34d"
    "84d44b86d54989d5488bd6468ed64590d74393d74195d84098d83e9bd93c9dd93ba0da39a2da37a5db36a8db34aadc32"
    "addc30b0dd2fb2dd2db5de2bb8de29bade28bddf26c0df25c2df23c5e021c8e020cae11fcde11dd0e11cd2e21bd5e21a"
    "d8e219dae319dde318dfe318e2e418e5e419e7e419eae51aece51befe51cf1e51df4e61ef6e620f8e621fbe723fde725"
), np.uint8).reshape(256, 3)

#: Unicode superscripts of the digits and signs (10⁻³ as plain text, no mathtext)
SUPERSCRIPT = str.maketrans("0123456789-+", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b\u207a")

#: matplotlib's default colour cycle ("tab10"), one colour per series
TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
         "#17becf")

#: the checkerboard renders have this many times the pixels they are shown at, smoothed by the
#: downsampling: fewer than matplotlib's figure renders, because the result looks the same and
#: the rasterizer's time grows with the pixels (measurements: benchmarks/README.md, issue 49)
RENDER_SCALE = 1.25

_GRID = (231, 231, 231)  # matplotlib's grid, #b0b0b0 at alpha 0.3, on white
_MINUS = "\u2212"  # matplotlib's tick labels write negative numbers with a real minus sign


@functools.lru_cache(maxsize=None)
def font_path():
    """The path of DejaVu Sans, matplotlib's default font, in its data folder (found without
    importing matplotlib), or None when it or Pillow is not installed."""
    import importlib.util
    from pathlib import Path

    if importlib.util.find_spec("PIL") is None:
        return None
    spec = importlib.util.find_spec("matplotlib")
    for root in (spec.submodule_search_locations or []) if spec is not None else []:
        path = Path(root, "mpl-data", "fonts", "ttf", "DejaVuSans.ttf")
        if path.is_file():
            return str(path)
    return None


@functools.lru_cache(maxsize=64)
def _font(pixels):
    from PIL import ImageFont

    return ImageFont.truetype(font_path(), pixels)


class _Canvas:
    """A white Pillow RGB image ``width`` x ``height`` inches at ``dpi``; coordinates in pixels
    from the top left, line widths and font sizes in points (as matplotlib's)."""

    def __init__(self, width, height, dpi):
        from PIL import Image, ImageDraw

        self.image = Image.new("RGB", (int(round(width * dpi)), int(round(height * dpi))), "white")
        self.draw = ImageDraw.Draw(self.image)
        self.width, self.height = self.image.size
        self.pt = dpi / 72.0  # pixels per point

    def font(self, size):
        return _font(round(size * self.pt, 2))

    def text(self, xy, text, size, anchor, fill=(0, 0, 0)):
        """``text`` at ``xy``, Pillow's ``anchor`` (e.g. "ms": its middle and baseline there)."""
        self.draw.text(xy, text, fill=fill, font=self.font(size), anchor=anchor)

    def text_width(self, text, size):
        return self.draw.textlength(text, font=self.font(size))

    def vtext(self, x, y, text, size, edge):
        """``text`` turned to read upwards, centred on the row ``y``, its ``edge`` ("left" or
        "right") on the column ``x``."""
        from PIL import Image, ImageDraw

        font = self.font(size)
        left, top, right, bottom = font.getbbox(text, anchor="ls")
        strip = Image.new("L", (int(math.ceil(right - left)) + 2, int(math.ceil(bottom - top)) + 2), 0)
        ImageDraw.Draw(strip).text((1 - left, 1 - top), text, fill=255, font=font, anchor="ls")
        strip = strip.rotate(90, expand=True)
        x0 = x if edge == "left" else x - strip.width
        self.image.paste((0, 0, 0), (int(round(x0)), int(round(y - strip.height / 2))), strip)

    def line(self, points, width, fill=(0, 0, 0)):
        self.draw.line([tuple(p) for p in points], fill=fill, width=max(1, int(round(width * self.pt))),
                       joint="curve")


def _columns(left, right, ratios, wspace):
    """(left, width) of matplotlib's subplot columns between the pixels ``left`` and ``right``
    with the width ``ratios`` and ``wspace`` (a fraction of the mean column width)."""
    n = len(ratios)
    cell = (right - left) / (n + wspace * (n - 1))
    widths = cell * n * np.asarray(ratios, np.float64) / np.sum(ratios)
    starts = left + np.concatenate([[0.0], np.cumsum(widths[:-1] + wspace * cell)])
    return list(zip(starts.tolist(), widths.tolist()))


def colour_index(values, vmin, vmax):
    """(m,) rows of :data:`VIRIDIS` for ``values`` (m,) on the scale ``vmin`` .. ``vmax``, as
    matplotlib's ``Normalize`` and ``Colormap`` pick them (``floor(256 t)``, the top in the last)."""
    t = (np.asarray(values, np.float64) - vmin) / (vmax - vmin)
    return np.clip(np.floor(t * 256.0), 0, 255).astype(np.int64)


#: the steps of matplotlib's ``AutoLocator`` (colour bars), and of a plain ``MaxNLocator``
AUTO_STEPS, MAXN_STEPS = (1.0, 2.0, 2.5, 5.0, 10.0), (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)


def linear_ticks(lo, hi, nbins, steps=AUTO_STEPS, integer=False):
    """The ticks matplotlib's ``MaxNLocator(nbins, steps, integer)`` puts in [lo, hi]: the
    multiples of the smallest of the ``steps`` times a power of ten that is at least
    ``(hi - lo) / nbins`` (``integer``: only whole steps from 1 on)."""
    raw = (hi - lo) / nbins
    scale = 10.0 ** math.floor(math.log10(raw))
    steps = [*(0.1 * s for s in steps[:-1]), *steps, 10.0 * steps[1]]  # matplotlib's staircase
    steps = [s * scale for s in steps if not integer or s * scale < 1 or abs(s * scale - round(s * scale)) < 1e-3]
    step = next((s for s in steps if s >= raw * (1 - 1e-10)), steps[-1])
    step = max(step, 1.0) if integer and math.floor(hi) - math.ceil(lo) >= 1 else step
    k = np.arange(math.ceil(lo / step - 1e-10), math.floor(hi / step + 1e-10) + 1)
    return k * step


def _tick_labels(ticks):
    """The ticks as matplotlib's ``ScalarFormatter`` writes them: one number of decimals for all,
    the fewest that shows each exactly; a real minus sign."""
    span = max(float(np.max(np.abs(ticks))), 1e-300)
    for decimals in range(12):
        if np.allclose(np.round(ticks, decimals), ticks, rtol=0.0, atol=1e-9 * span):
            break
    return [f"{t:.{decimals}f}".replace("-", _MINUS) if abs(t) > 1e-12 * span else f"{0:.{decimals}f}"
            for t in ticks]


def scalar_labels(ticks):
    """The labels of the linear ``ticks`` and the text matplotlib's ``ScalarFormatter`` writes at
    the axis' end: a power of ten ("1e−5") that the labels are in where the largest tick's is
    below -4 or above 5, else ""."""
    top = float(np.max(np.abs(ticks))) if len(ticks) else 0.0
    power = math.floor(math.log10(top)) if top > 0 else 0
    if -5 < power < 6:
        return _tick_labels(ticks), ""
    return _tick_labels(ticks / 10.0**power), f"1e{power}".replace("-", _MINUS)


def _plain_scale(lo, hi):
    """Whether matplotlib writes the ticks of [lo, hi] without an offset (a number added to all
    labels, for a range narrow beside its values), as :func:`scalar_labels` does."""
    top = max(abs(lo), abs(hi))
    return top == 0.0 or hi - lo > 1e-3 * top


def log_ticks(lo, hi, n_request):
    """The ticks matplotlib's ``LogLocator`` puts on a log axis whose view spans the decades
    ``lo`` .. ``hi`` (log10 limits) for at most ``n_request`` labelled ticks: (major exponents,
    minor tick positions as log10), the minor ones at 2..9 times each decade only where every
    decade has a major tick and fewer than ten fit."""
    emin, emax = math.ceil(lo), math.floor(hi)
    n_avail = emax - emin + 1
    stride = n_avail // (n_request + 1) + 1
    n_request = min(n_request, math.ceil(n_avail / stride))
    if n_request == 0:
        decades = [emin - 1, emax + 1]
    elif n_request == 1:
        mid = round((lo + hi) / 2)
        stride = max(mid - (emin - 1), (emax + 1) - mid)
        decades = [mid - stride, mid, mid + stride]
    else:
        stride = (n_avail - 1) // (n_request - 1)
        if stride < n_avail / n_request:
            stride = n_avail // n_request
        olo, ohi = max(n_avail - stride * n_request, 0), min(n_avail - stride * (n_request - 1), stride)
        offset = (-emin) % stride
        offset = offset if olo <= offset < ohi else olo
        decades = range(emin + offset - stride, emax + stride + 1, stride)
    major = [d for d in decades if lo <= d <= hi]
    minor = []
    if n_avail < 10 and (stride == 1 or n_avail <= 1):
        minor = [d + math.log10(s) for d in range(emin - 1, emax + 1) for s in range(2, 10)
                 if lo <= d + math.log10(s) <= hi]
    return major, minor


def _rgb(image):
    """An RGBA float image (h, w, 4) in [0, 1] over white, as uint8 RGB."""
    a = image[..., 3:]
    rgb = image[..., :3] * (255.0 * a)
    rgb += 255.5 - 255.0 * a  # white behind, and 0.5 to round
    return rgb.astype(np.uint8)


def _image_panel(c, image, box, caption):
    """The RGBA render ``image`` shown as matplotlib's ``imshow`` (equal aspect) shows it in
    the axes ``box`` = (left, top, width, height): a square centred in it, the render
    downsampled with a Hamming filter (imshow's anti-aliasing: a Hanning window)."""
    from PIL import Image

    x, y, w, h = box
    side = min(w, h)
    x0, y0 = x + (w - side) / 2, y + (h - side) / 2
    n = int(round(side))
    c.image.paste(Image.fromarray(_rgb(image)).resize((n, n), Image.Resampling.HAMMING),
                  (int(round(x0)), int(round(y0))))
    c.text((x + w / 2, y0 - 6 * c.pt), caption, 11, "ms")


def flat_triangles(xy, F, rgb, size, supersample=1):
    """(height, width, 3) uint8 image of the triangles ``F`` (m, 3) with the pixel
    coordinates ``xy`` (n, 2) (column, row from the top), each filled with its colour ``rgb``
    (m, 3) uint8 over white, rasterised by :func:`geomopt.plot._render.nearest_faces` (no depth: a
    later triangle wins a shared pixel).  ``supersample`` > 1 renders that many times larger
    and averages down (Pillow's ``reduce``) for an anti-aliased outline, at a multiple of the
    rasterizer's time, so the layout is drawn at 1 (steps of one pixel along its
    outline, no seams inside)."""
    from PIL import Image

    from ._render import nearest_faces

    s = supersample
    big = (size[0] * s, size[1] * s)
    pixels, face, _ = nearest_faces(np.asarray(xy, np.float64) * s, np.zeros(len(xy)), F, big)
    image = np.full((big[1] * big[0], 3), 255, np.uint8)
    image[pixels] = rgb[face]
    return np.asarray(Image.fromarray(image.reshape(big[1], big[0], 3)).reduce(s))


def _layout_panel(c, uv, F, values, box, label):
    """The UV layout, faces coloured by ``values`` through viridis, with its colour bar, in the
    axes ``box``: as matplotlib places ``colorbar(ax=..., shrink=0.8)`` (the right 20% for the
    bar) and an equal-aspect axes with 5% margins anchored to the bar."""
    from PIL import Image

    x, y, w, h = box
    pw = 0.8 * w
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    lo, hi = lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo)
    span = np.maximum(hi - lo, 1e-300)
    s = min(pw / span[0], h / span[1])
    ax0, ay0 = x + pw - span[0] * s, y + (h - span[1] * s) / 2
    ox, oy = int(math.floor(ax0)), int(math.floor(ay0))
    size = (int(math.ceil(x + pw)) - ox, int(math.ceil(ay0 + span[1] * s)) - oy)
    xy = np.c_[(uv[:, 0] - lo[0]) * s + (ax0 - ox), (hi[1] - uv[:, 1]) * s + (ay0 - oy)]
    vmin, vmax = float(values.min()), float(values.max())
    tile = flat_triangles(xy, F, VIRIDIS[colour_index(values, vmin, vmax)], size)
    c.image.paste(Image.fromarray(tile), (ox, oy))
    c.text((ax0 + span[0] * s / 2, ay0 - 6 * c.pt), "UV layout", 11, "ms")
    _colorbar(c, (x + 0.85 * w, y + 0.1 * h, 0.8 * h / 20, 0.8 * h), vmin, vmax, label)


def _colorbar(c, box, vmin, vmax, label):
    """A vertical viridis bar in ``box`` (left, top, width, height) for ``vmin`` .. ``vmax``,
    its ticks and their labels on the right, and ``label`` beside them reading upwards."""
    from PIL import Image

    x0, y0 = int(round(box[0])), int(round(box[1]))
    x1, y1 = int(round(box[0] + box[2])), int(round(box[1] + box[3]))
    t = 1.0 - (np.arange(y1 - y0) + 0.5) / (y1 - y0)  # each row's place on the scale, top first
    strip = VIRIDIS[np.minimum(np.floor(t * 256.0), 255).astype(np.int64)]
    c.image.paste(Image.fromarray(np.ascontiguousarray(np.repeat(strip[:, None], x1 - x0, axis=1))), (x0, y0))
    c.draw.rectangle((x0, y0, x1, y1), outline=(0, 0, 0), width=max(1, int(round(0.8 * c.pt))))
    ticks = linear_ticks(vmin, vmax, int(np.clip(math.floor(box[3] / c.pt / 20.0), 1, 9)))
    labels, power = scalar_labels(ticks)
    if power:
        c.text((x1, y0 - 3.5 * c.pt), power, 10, "ld")
    for tick, text in zip(ticks, labels):
        row = y1 - (tick - vmin) / (vmax - vmin) * (y1 - y0)
        c.line([(x1, row), (x1 + 3.5 * c.pt, row)], 0.8)
        c.text((x1 + 7.0 * c.pt, row), text, 10, "lm")
    widest = max((c.text_width(text, 10) for text in labels), default=0.0)
    c.vtext(x1 + 11.0 * c.pt + widest, (y0 + y1) / 2, label, 10, "left")


def param_picture(V, F, uv, face_values, title="", label="distortion", checks=20, view=(15.0, 30.0), up="y",
                  dpi=110):
    """:func:`geomopt.plot.param_figure` composed as a Pillow RGB image (16 x 7.5 inches at
    ``dpi``): the checkerboard renders of :func:`geomopt.plot._render.render_uv_checker`
    (:data:`RENDER_SCALE` times the pixels shown, downsampled), the layout by
    :func:`flat_triangles` with its colour bar, titles by Pillow.  None where matplotlib has to
    draw it: no ``face_values`` (a wireframe), values not finite or all equal, tick labels
    matplotlib would write with an offset (values differing in their fourth digit), or no
    font."""
    from ._render import render_uv_checker

    values = None if face_values is None else np.asarray(face_values, np.float64)
    if font_path() is None or values is None or values.size == 0 or not np.all(np.isfinite(values)):
        return None
    vmin, vmax = float(values.min()), float(values.max())
    if not vmax > vmin or not _plain_scale(vmin, vmax):
        return None
    V, F, uv = np.asarray(V, np.float64), np.asarray(F, np.int64), np.asarray(uv, np.float64)
    c = _Canvas(16, 7.5, dpi)
    top = (0.75 if title else 0.4) * dpi
    cells = _columns(0.1 * dpi, c.width - 0.1 * dpi, (1.0, 0.42, 1.0), 0.05)
    height = c.height - 0.1 * dpi - top
    panels = ((cells[0], view[1], f"{checks} x {checks} checkerboard through the UV map"),
              (cells[1], view[1] + 180.0, "other side"))

    def render(panel):
        (_, w), azim, _ = panel
        px = int(round(RENDER_SCALE * min(w, height)))
        return render_uv_checker(V, F, uv, size=(px, px), elev=view[0], azim=azim, up=up, checks=checks,
                                 supersample=1)

    # the large render on a thread while this one renders the small one and draws the layout
    # (about as much work): NumPy and Pillow release the GIL in their loops
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        large = pool.submit(render, panels[0])
        small = render(panels[1])
        _layout_panel(c, uv, F, values, (cells[2][0], top, cells[2][1], height), label)
        images = (large.result(), small)
    for ((x, w), _, caption), image in zip(panels, images):
        _image_panel(c, image, (x, top, w, height), caption)
    if title:
        c.text((c.width / 2, 0.02 * c.height), title, 12, "ma")
    return c.image


def _log_limits(lines):
    """The view of a log-y panel over ``lines`` [(x, y, colour)]: (x lo, x hi, log10 y lo,
    log10 y hi) with matplotlib's 5% margins, or None where this module does not draw it as
    matplotlib would (no or non-positive values, one x, a view of a decade or less: matplotlib
    labels minor ticks then)."""
    if not lines:
        return None
    xs = np.concatenate([x for x, _, _ in lines])
    ys = np.concatenate([y for _, y, _ in lines])
    if ys.size == 0 or not (np.all(np.isfinite(xs)) and np.all(np.isfinite(ys)) and np.all(ys > 0)):
        return None
    ly = np.log10(ys)
    (xlo, xhi), (ylo, yhi) = (xs.min(), xs.max()), (ly.min(), ly.max())
    if not xhi > xlo or 1.1 * (yhi - ylo) <= 1.0:
        return None
    dx, dy = 0.05 * (xhi - xlo), 0.05 * (yhi - ylo)
    return float(xlo - dx), float(xhi + dx), float(ylo - dy), float(yhi + dy)


def _log_panel(c, box, lines, view, ylabel, title):
    """One semilog-y axes of the convergence plot in ``box`` (left, top, width, height): grid,
    ``lines`` [(x, y, colour)] with dots, frame, ticks (integers on x, powers of ten on y as
    matplotlib picks them) and labels, ``ylabel`` and ``title``."""
    x0, y0, w, h = box
    xlo, xhi, ylo, yhi = view

    def at(x, ly):
        return x0 + (x - xlo) / (xhi - xlo) * w, y0 + h - (ly - ylo) / (yhi - ylo) * h

    major, minor = log_ticks(ylo, yhi, int(np.clip(math.floor(h / c.pt / 20.0), 2, 9)))
    xticks = linear_ticks(xlo, xhi, 10, MAXN_STEPS, integer=True)  # as MaxNLocator(integer=True)
    for x in xticks:
        c.line([at(x, ylo), at(x, yhi)], 0.8, _GRID)
    for ly in (*major, *minor):
        c.line([at(xlo, ly), at(xhi, ly)], 0.8, _GRID)
    for x, y, colour in lines:
        points = [at(a, b) for a, b in zip(x.tolist(), np.log10(y).tolist())]
        c.line(points, 1.5, colour)
        r = 1.25 * c.pt  # matplotlib's "." marker of size 3 with its 1 pt edge
        for px, py in points:
            c.draw.ellipse((px - r, py - r, px + r, py + r), fill=colour)
    c.draw.rectangle((x0, y0, x0 + w, y0 + h), outline=(0, 0, 0), width=max(1, int(round(0.8 * c.pt))))
    label_left = x0
    for ly, length, width in [(e, 3.5, 0.8) for e in major] + [(e, 2.0, 0.6) for e in minor]:
        c.line([(x0 - length * c.pt, at(xlo, ly)[1]), (x0, at(xlo, ly)[1])], width)
    for e in major:
        text = "10" + str(e).translate(SUPERSCRIPT)
        c.text((x0 - 7.0 * c.pt, at(xlo, e)[1]), text, 10, "rm")
        label_left = min(label_left, x0 - 7.0 * c.pt - c.text_width(text, 10))
    bottom = y0 + h
    for x, text in zip(xticks, _tick_labels(xticks)):
        c.line([(at(x, ylo)[0], bottom), (at(x, ylo)[0], bottom + 3.5 * c.pt)], 0.8)
        c.text((at(x, ylo)[0], bottom + 7.0 * c.pt), text, 10, "ma")
    c.text((x0 + w / 2, bottom + 11.0 * c.pt + c.font(10).getbbox("0", anchor="la")[3]), "iteration", 10, "ma")
    c.vtext(label_left - 4.0 * c.pt, y0 + h / 2, ylabel, 10, "right")
    c.text((x0 + w / 2, y0 - 6.0 * c.pt), title, 10, "ms")


def _legend(c, box, entries):
    """matplotlib's legend (font size 8) in the upper right corner of ``box``: a framed line
    sample with its dot and the label per entry [(label, colour)]."""
    fs = 8.0 * c.pt  # the legend's lengths are in font sizes
    widest = max(c.text_width(label, 8) for label, _ in entries)
    width = (0.4 + 2.0 + 0.8 + 0.4) * fs + widest
    height = (2 * 0.4 + len(entries) + 0.5 * (len(entries) - 1)) * fs
    right, top = box[0] + box[2] - 0.5 * fs, box[1] + 0.5 * fs
    c.draw.rounded_rectangle((right - width, top, right, top + height), radius=0.2 * fs, fill=(255, 255, 255),
                             outline=(204, 204, 204), width=max(1, int(round(c.pt))))
    for k, (label, colour) in enumerate(entries):
        row = top + (0.4 + 0.5 + 1.5 * k) * fs
        x = right - width + 0.4 * fs
        c.line([(x, row), (x + 2.0 * fs, row)], 1.5, colour)
        r = 1.25 * c.pt
        c.draw.ellipse((x + fs - r, row - r, x + fs + r, row + r), fill=colour)
        c.text((x + 2.8 * fs, row), label, 8, "lm")


def convergence_picture(series, ylabel="energy", title="", reference=None, dpi=120):
    """:func:`geomopt.plot.convergence_figure` composed as a Pillow RGB image (10 x 4 inches at
    ``dpi``, 6 x 4 without gradient norms), drawn at twice the size and reduced (anti-aliased
    lines).  None where matplotlib has to draw it (see :func:`_log_limits`; no font)."""
    if font_path() is None or not series:
        return None
    grads = any(len(s) > 2 for s in series.values())
    ref = min(float(np.min(s[1])) for s in series.values()) if reference is None else float(reference)
    gap_lines, grad_lines = [], []
    for k, s in enumerate(series.values()):
        e = np.asarray(s[1], np.float64)
        gap = (e - ref) / max(abs(ref), 1e-300)
        keep = gap > 0
        gap_lines.append((np.arange(len(e))[keep], gap[keep], TAB10[k % 10]))
        if grads and len(s) > 2:
            g = np.asarray(s[2], np.float64)
            grad_lines.append((np.arange(len(g)), g, TAB10[k % 10]))
    panels = [(gap_lines, "(E - E_ref) / |E_ref|", f"relative gap in {ylabel}, E_ref = {ref:.10g}")]
    if grads:
        panels.append((grad_lines, "gradient norm", f"gradient norm of {ylabel}"))
    views = [_log_limits(lines) for lines, _, _ in panels]
    if any(v is None for v in views):
        return None
    scale = 2  # drawn twice as large and reduced: Pillow's lines are not anti-aliased
    c = _Canvas(10 if grads else 6, 4, dpi * scale)
    top, bottom = (0.75 if title else 0.4) * dpi * scale, c.height - 0.55 * dpi * scale
    columns = _columns(0.85 * dpi * scale, c.width - 0.15 * dpi * scale, (1.0,) * len(panels), 0.3)
    for (x, w), view, (lines, label, name) in zip(columns, views, panels):
        _log_panel(c, (x, top, w, bottom - top), lines, view, label, name)
    x, w = columns[0]
    _legend(c, (x, top, w, bottom - top), [(str(label), TAB10[k % 10]) for k, label in enumerate(series)])
    if title:
        c.text((c.width / 2, 0.02 * c.height), title, 11, "ma")
    return c.image.reduce(scale)


def save_png(image, target, dpi):
    """Write the Pillow ``image`` as PNG into the open binary file ``target`` or atomically to
    the path ``target`` (``dpi`` recorded in the file): zlib level 1 with run-length matching
    only (``Z_RLE``), because on these flat-coloured pictures it encodes faster and smaller
    than matplotlib's level 1 (measurements: benchmarks/README.md, issue 49 section)."""
    options = {"format": "PNG", "compress_level": 1, "compress_type": 3, "dpi": (dpi, dpi)}
    if hasattr(target, "write"):
        image.save(target, **options)
        return
    from ..io import atomic_output

    with atomic_output(target, "wb") as fh:
        image.save(fh, **options)

"""The packing margin at its bounds: a margin too wide for the number of charts is refused up
front, every margin loop is bounded, and a legitimate wide margin between many charts packs."""

import math
import subprocess
import sys

import numpy as np
import pytest

from geomopt._runtime.errors import ParameterError
from geomopt.atlas import certify_atlas, pack_charts
from geomopt.mesh import generators as g

from test_atlas_pack import as_atlas, min_chart_distance


def little_squares(k, seed=0):
    """``k`` small square charts of sizes 0.5 to 1.5."""
    V, F = g.square_mesh(3)
    rng = np.random.default_rng(seed)
    return [V * rng.uniform(0.5, 1.5) for _ in range(k)], [F] * k


@pytest.mark.parametrize("k, widest", [(2, 1.0), (4, 1.0), (5, 0.5), (9, 0.5), (10, 1 / 3), (30, 0.2), (150, 1 / 12)])
def test_widest_margin_is_the_grid_bound_of_the_max_norm(k, widest):
    from geomopt.atlas import widest_margin

    assert math.isclose(widest_margin(k), widest)
    assert widest_margin(1) == math.inf


@pytest.mark.parametrize("k, margin", [(30, 0.2), (30, 0.24), (150, 1 / 12), (150, 0.1)])
def test_a_margin_too_wide_for_the_charts_is_refused_up_front(k, margin, monkeypatch):
    """30 charts cannot be kept 0.2 apart (6 rows of gaps of 0.2 exceed the square): refused
    before any packing, naming the widest margin that fits (it used to re-pack forever)."""
    from geomopt.atlas import _pack

    def no_layout(*args, **kwargs):  # the refusal comes before any packing
        raise AssertionError("packed a margin that cannot fit")

    monkeypatch.setattr(_pack, "_layout", no_layout)
    uvs, faces = little_squares(k)
    with pytest.raises(ParameterError, match=rf"{k} charts.*below {1 / (math.ceil(math.sqrt(k)) - 1):.4g}"):
        pack_charts(uvs, faces, margin=margin, resolution=64)


def test_the_margin_loop_is_bounded(monkeypatch):
    """A layout whose side grows faster than its gap (every gap adds more than 1 / margin of
    itself to the side) never covers the margin: the loop gives up after a bounded number of
    layouts with a ParameterError naming the widest margin reached, instead of widening forever."""
    from geomopt.atlas import _pack

    calls = []

    def search(U, shapes, h, r, passes):  # a side of 100 pixels plus 10 per pixel of gap
        calls.append(r)
        if len(calls) > 50:
            raise AssertionError("the margin loop does not end")
        return [(np.eye(2), np.zeros(2)) for _ in U], 100.0 + 10.0 * r

    monkeypatch.setattr(_pack, "_search", search)
    uvs, faces = little_squares(3)
    with pytest.raises(ParameterError, match="margin 0.15 could not be kept between 3 charts.*widest"):
        pack_charts(uvs, faces, margin=0.15, resolution=64)
    assert len(calls) <= 10


@pytest.mark.parametrize("k, margin", [(30, 0.15), (30, 0.18), (150, 0.05), (150, 0.002)])
def test_a_wide_margin_between_many_charts_packs_in_a_few_layouts(k, margin, monkeypatch):
    """Many little charts at a margin not far below the widest that fits pack, certified, each
    chart at least the margin from the others, in a few layouts (the loop jumps to the fixed
    point of gap = margin x side rather than creeping to it: 0.15 between 30 took 14 layouts)."""
    from geomopt.atlas import _pack

    calls = []
    search = _pack._search

    def counted(*args):
        calls.append(args[3])
        return search(*args)

    monkeypatch.setattr(_pack, "_search", counted)
    uvs, faces = little_squares(k, seed=k)
    p = pack_charts(uvs, faces, margin=margin, resolution=128)
    assert certify_atlas(*as_atlas(p.uvs, faces)).ok
    assert min_chart_distance(p.uvs, faces, 2 * margin) >= margin
    assert len(calls) <= 6, calls


def test_the_command_refuses_a_margin_too_wide_for_many_closed_components(tmp_path):
    """``geomopt param`` on 40 little closed cubes at ``--margin 0.2``: exit 2 with one line
    naming the widest margin, no output (in a subprocess with a timeout: it used to run forever
    with its memory growing without bound)."""
    import meshio

    V, F = [], []
    for i in range(40):
        v, f = cube()
        F.append(f + len(V) * 8)
        V.append(v * 0.1 + [3 * (i % 7), 3 * (i // 7), 0])
    mesh = tmp_path / "cubes.off"
    meshio.write_points_cells(str(mesh), np.concatenate(V), [("triangle", np.concatenate(F))])
    out = tmp_path / "cubes.obj"
    run = subprocess.run([sys.executable, "-m", "geomopt", "param", str(mesh), "-o", str(out), "--margin", "0.2"],
                         capture_output=True, text=True, timeout=240)
    assert run.returncode == 2, run.stderr[-2000:]
    assert "below" in run.stderr and "charts" in run.stderr
    assert not out.exists()


def cube():
    """A closed unit cube: 8 vertices, 12 outward triangles."""
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F

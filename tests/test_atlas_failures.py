"""The atlas's failure paths, walked on purpose: a certificate that fails (forced through the
conftest fixtures ``failing_certificate`` and ``uncertified_packer``), a degenerate UV face,
the raster's tolerance at pixel borders, and the margin's half-open range."""

import numpy as np
import pytest

from geomopt._runtime.errors import ParameterError, SolveError
from geomopt.atlas import AtlasOptions, certify_atlas, make_atlas, pack_charts
from geomopt.mesh import generators as g

from test_atlas_pack import as_atlas, random_charts

TET = ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_a_zero_area_uv_face_is_not_certified():
    """A chart whose third face is flat (its three corners on a line): the boundary is a clean
    counter-clockwise triangle, so only the orientation test (not positive, rather than
    negative) can see it."""
    uv = np.array([[0.1, 0.1], [0.9, 0.1], [0.5, 0.1], [0.5, 0.9]])
    F = np.array([[0, 2, 3], [2, 1, 3], [0, 1, 2]])
    cert = certify_atlas(uv, F, np.zeros(3, np.int64))
    assert cert.inverted.tolist() == [2] and not cert.ok
    assert "1 faces not positively oriented" in cert.message
    assert certify_atlas(uv, F[:2], np.zeros(2, np.int64)).ok


def test_a_packing_that_never_certifies_is_retried_finer_then_refused(uncertified_packer):
    fails, resolutions = uncertified_packer
    uvs, faces = random_charts(3, 1)
    with pytest.raises(SolveError, match="could not certify a packing") as err:
        pack_charts(uvs, faces, resolution=32)
    assert resolutions == [32, 64, 128, 256]  # every try at twice the resolution
    assert not err.value.certificate.ok and err.value.certificate.overlapping_pairs.tolist() == [[0, 1]]


def test_a_packing_that_fails_its_certificate_once_is_repacked_finer(uncertified_packer):
    fails, resolutions = uncertified_packer
    fails[0] = 1
    uvs, faces = random_charts(3, 1)
    p = pack_charts(uvs, faces, resolution=32)
    assert resolutions == [32, 64]
    assert certify_atlas(*as_atlas(p.uvs, faces)).ok


def test_make_atlas_reports_a_failed_certificate_and_raises_with_throw(failing_certificate):
    atlas = make_atlas(*TET, progress=False)
    assert not atlas.success and atlas.message.startswith("not certified")
    with pytest.raises(SolveError, match="not certified") as err:
        make_atlas(*TET, progress=False, throw=True)
    assert err.value.result.certificate is failing_certificate[-1]


def test_the_command_fails_an_uncertified_atlas_and_writes_nothing(failing_certificate, cli, tmp_path):
    import meshio

    mesh, out = tmp_path / "tet.off", tmp_path / "tet.obj"
    meshio.write_points_cells(str(mesh), np.array(TET[0], float), [("triangle", np.array(TET[1]))])
    code, _, err = cli("param", mesh, "-o", out)
    assert code == 1 and "atlas not certified" in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["tet.off"]


@pytest.mark.parametrize("margin", [0.25, 0.3, -0.01, float("nan")])
def test_a_margin_outside_the_half_open_range_is_refused_everywhere(margin, capsys, tmp_path):
    import geomopt.cli

    uvs, faces = random_charts(2, 0)
    with pytest.raises(ParameterError, match="margin"):
        pack_charts(uvs, faces, margin=margin)
    with pytest.raises(ParameterError, match="margin"):
        AtlasOptions(margin=margin)
    with pytest.raises(SystemExit) as info:
        geomopt.cli.main(["param", str(tmp_path / "none.off"), "-o", str(tmp_path / "none.obj"), "--margin", str(margin)])
    assert info.value.code == 2 and "--margin" in capsys.readouterr().err


def test_a_margin_just_below_a_quarter_packs():
    margin = np.nextafter(0.25, 0)
    V, F = g.square_mesh(3)
    p = pack_charts([V, V * 0.5], [F, F], margin=margin, resolution=64)
    assert certify_atlas(*as_atlas(p.uvs, [F, F])).ok
    assert AtlasOptions(margin=margin).margin == margin


def _supercover_near(kind, seed):
    """Segments whose ends lie within half the raster's tolerance of pixel borders, on either
    side (``kind``: "below" or "above")."""
    from geomopt.atlas import _raster

    rng = np.random.default_rng(seed)
    a, b = np.round(rng.uniform(-3, 30, (3, 2))), np.round(rng.uniform(-3, 30, (3, 2)))
    d = 0.5 * _raster._EPS * (-1 if kind == "below" else 1)
    return a + d * rng.integers(0, 2, a.shape), b + d * rng.integers(0, 2, b.shape)


@pytest.mark.parametrize("kind", ["below", "above"])
def test_the_boundary_raster_widens_every_side_by_its_tolerance(kind):
    """Segments ending within _EPS of a pixel border (below or above it) set the pixels across
    it, as the bounding-box reference does (the first and last column and row of each segment)."""
    from geomopt.atlas import _raster
    from test_atlas_pack import _supercover_by_box

    for seed in range(200):
        a, b = _supercover_near(kind, seed)
        got = set(zip(*(v.tolist() for v in _raster._supercover(a, b, (27, 31)))))
        assert got == _supercover_by_box(a, b, (27, 31)), seed


@pytest.mark.parametrize("kind", ["below", "above"])
def test_a_chart_within_tolerance_of_a_pixel_border_is_rastered_across_it(kind):
    """A square chart whose sides lie within _EPS of pixel borders: its raster (and its box)
    covers the pixels across each border too."""
    from geomopt.atlas import _raster
    from geomopt.exact.topology import boundary_half_edges

    d = 0.5 * _raster._EPS * (-1 if kind == "below" else 1)
    V, F = g.square_mesh(3, 4.0)
    q = V + 2.0 + d
    mask, origin = _raster.rasterize(q, boundary_half_edges(F))
    lo, hi = np.floor(q.min(axis=0) - _raster._EPS), np.floor(q.max(axis=0) + _raster._EPS)
    assert origin.tolist() == lo.astype(int).tolist()
    assert mask.shape == (hi[1] - lo[1] + 1, hi[0] - lo[0] + 1) and mask.all()


def test_an_uncertified_trial_packing_that_fails_the_atlas_certificate_is_repacked_certified(monkeypatch):
    """make_atlas packs its trials uncertified (``pack_charts(certify=False)``) and certifies the
    whole atlas once; when that certificate finds the packing wrong (here a trial packing moved
    off the square), the charts are packed again with the packer's own certificate and the
    atlas ends certified."""
    import dataclasses

    from geomopt.atlas import build

    calls, real = [], build.pack_charts

    def shifted(uvs, faces, **kw):
        calls.append(kw.get("certify", True))
        p = real(uvs, faces, **kw)
        return p if kw.get("certify", True) else dataclasses.replace(p, uvs=[u + 2.0 for u in p.uvs])
    monkeypatch.setattr(build, "pack_charts", shifted)
    atlas = make_atlas(*TET, progress=False)
    assert atlas.success and atlas.certificate.ok
    assert False in calls and calls[-1] is True  # trials uncertified, then one certified packing
    assert ((atlas.x >= 0) & (atlas.x <= 1)).all()

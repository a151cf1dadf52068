"""Free-boundary repair of folded maps (Garanzha et al.'s untangling with no handle), from the
API and the command line; every result certified by the exact predicate."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import geomopt.cli
from geomopt import MaxStepsWarning, MeshFormatError, ParameterError, Problem, SolveError, UntangleOptions, parameterize
from geomopt.mesh.generators import disk_mesh
from geomopt.io import read_obj_uv, write_obj_with_uv
from geomopt.param import projection_map, repair_map
from geomopt.exact.predicates import count_inverted
from geomopt.mesh.tutte import tutte_embedding

from conftest import grid


def u_bent_disk(rings=8, bend=2.6):
    """A disk bent into a U (developable): its plane projection folds along both sides."""
    V, F = disk_mesh(rings)
    a = bend * V[:, 0]
    return np.column_stack([np.sin(a), V[:, 1], 1 - np.cos(a)]), F


def test_folded_projection_of_a_curved_patch_is_repaired_then_optimised():
    V, F = u_bent_disk()
    x0 = projection_map(V, F)
    assert count_inverted(x0, F) > len(F) // 4  # the projection is badly folded
    res = parameterize(V, F, x0="projection", progress=False)
    rep = res.details.repair
    assert rep.success and rep.stats.inverted_at_start == count_inverted(x0, F)
    assert res.success and count_inverted(res.x, F) == 0
    # developable: the repaired-then-optimised map reaches the isometric value
    assert res.mean_energy == pytest.approx(4.0, abs=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_flips_of_a_good_surface_map_are_repaired(seed):
    V, F = u_bent_disk(6, 1.2)
    P = Problem.surface(V, F)
    x = tutte_embedding(V, F)
    rng = np.random.default_rng(seed)
    for v in rng.choice(len(V), 8, replace=False):
        x[v] = x[rng.integers(len(V))] + 0.05 * rng.standard_normal(2)  # teleport: folds around v
    assert P.count_inverted(x) > 0
    rep = repair_map(P, x, progress=False)
    assert rep.success and rep.certificate.inverted == 0 and count_inverted(rep.x, F) == 0


def test_planar_free_boundary_and_a_mirrored_map():
    V, F = grid(7)
    P = Problem.planar(V, F)
    x = V * [-1.0, 1.0]  # mirrored as a whole: every triangle inverted
    x[10] += [0.3, 0.2]
    assert P.count_inverted(x) > len(F) - 6  # all but the few the displaced vertex unfolded
    rep = repair_map(P, x, progress=False)
    assert rep.success and P.count_inverted(rep.x) == 0
    with pytest.raises(Exception, match="collapsed"):
        repair_map(P, np.zeros_like(V), progress=False)


def test_repair_map_reads_an_options_object_and_throws_on_request():
    """``repair_map`` takes the untangling's settings as every driver does (issue 49): an
    UntangleOptions (theta reaches the solve), no loose keywords, and ``throw``."""
    V, F = grid(7)
    P = Problem.planar(V, F)
    x = V * [-1.0, 1.0]
    x[10] += [0.3, 0.2]
    rep = repair_map(P, x, options=UntangleOptions(theta=0.25), progress=False)
    assert rep.success and rep.details.theta == 0.25
    assert repair_map(P, x, progress=False, throw=True).success
    with pytest.raises(ParameterError, match="repair_map: options must be a UntangleOptions or None, got dict"):
        repair_map(P, x, options={"theta": 0.25}, progress=False)
    with pytest.raises(TypeError, match="unexpected keyword argument 'theta'"):
        repair_map(P, x, theta=0.25, progress=False)
    cut = UntangleOptions(max_outer=1, start="given")  # one outer iteration: not untangled yet
    with pytest.warns(MaxStepsWarning):
        assert not repair_map(P, x, options=cut, progress=False).success
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the error says it: no warning before it
        with pytest.raises(SolveError, match="repair_map failed") as info:
            repair_map(P, x, options=cut, progress=False, throw=True)
    assert not info.value.result.success


def test_cli_init_uv_and_projection(tmp_path):
    V, F = u_bent_disk(6)
    uv = projection_map(V, F)
    src = tmp_path / "folded.obj"
    write_obj_with_uv(src, V, F, uv)
    V2, F2, UV2 = read_obj_uv(src)
    assert np.array_equal(UV2, uv) and np.array_equal(F2, F)
    for init in ("uv", "projection"):
        out = tmp_path / f"{init}.obj"
        code = geomopt.cli.main(["param", str(src), "-o", str(out), "--init", init, "--quiet"])
        assert code == 0
        _, _, x = read_obj_uv(out)
        assert count_inverted(x, F) == 0


def test_read_obj_uv_refuses_seams(tmp_path):
    p = tmp_path / "seam.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvt 5 5\n"
                 "f 1/1 2/2 3/3\nf 2/2 4/4 3/5\n")
    with pytest.raises(MeshFormatError, match="two different UVs"):
        read_obj_uv(p)
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshFormatError, match="no 'vt' lines"):
        read_obj_uv(p)


def test_init_uv_with_a_nan_vt_says_nan_not_unused(tmp_path, cli):
    """``vt nan`` was reported as 'vertices used by no face' (NaN marked unused vertices)."""
    p = tmp_path / "nan.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt nan 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(geomopt.MeshError, match="NaN or infinite coordinates .*first: vertex 1") as info:
        read_obj_uv(p)
    assert "used by no face" not in str(info.value)
    code, _, err = cli("param", p, "-o", tmp_path / "out.obj", "--init", "uv", "--quiet")
    assert code == 2 and "NaN" in err and "used by no face" not in err and len(err.splitlines()) == 1
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(MeshFormatError, match="1 vertices are used by no face"):
        read_obj_uv(p)

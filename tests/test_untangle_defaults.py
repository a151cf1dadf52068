"""Every LIM case of ../shared/data/lim and every generated family of benchmarks/untangle.py
certifies with default options (issue 48 item 3), and ``start="auto"`` falls back to the
harmonic extension of the handles when the run from the given map stalls.

The LIM cases run through the command line, as a user runs them (its size buckets change the
rounding of the sums, and with it the path of L-BFGS: square_rot180 stalled at 64 folds there
while the unpadded API certified it); the families at their smallest benchmark size.
"""

from __future__ import annotations

import logging
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import geomopt.cli
from geomopt.exact.predicates import count_inverted
from geomopt.lim import LimCase, untangle_case
from geomopt.untangling import UntangleOptions, untangle
from geomopt.untangling import continuation

from conftest import LIM_ROOT

ROOT = Path(__file__).resolve().parents[1]
CASES = LimCase.cases(LIM_ROOT) if LIM_ROOT.is_dir() else []
#: cases whose handles alone make some star overlap (a property of the input: tests/test_untangle.py)
EXCEPT_FIXED = {"armadillo-598"}


def _benchmark():
    spec = importlib.util.spec_from_file_location("untangle_benchmark", ROOT / "benchmarks" / "untangle.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


FAMILIES = _benchmark().families({100})


@pytest.mark.parametrize("folder", CASES or [None], ids=[c.name for c in CASES] or ["missing"])
def test_every_lim_case_certifies_through_the_cli_with_default_options(folder, tmp_path):
    if folder is None:
        pytest.skip(f"LIM sample data not found under {LIM_ROOT} (clone the project next to shared/)")
    out = tmp_path / f"out{'.obj' if LimCase.dim_of(folder) == 2 else '.vtk'}"
    code = geomopt.cli.main(["untangle", str(folder), "-o", str(out), "--quiet"])
    assert code == (3 if folder.name in EXCEPT_FIXED else 0)
    assert out.exists()


@pytest.mark.parametrize("name, factory", [(n, f) for n, _, f in FAMILIES], ids=[n for n, _, _ in FAMILIES])
def test_every_benchmark_family_certifies_with_default_options(name, factory):
    tangle = factory()
    assert tangle.inverted() > 0, "a family at this size must start tangled"
    result = untangle(tangle.problem(), tangle.x0, progress=False)
    assert result.success, result.message
    assert count_inverted(result.x, tangle.simplices) == 0


def test_auto_start_falls_back_to_the_harmonic_extension_when_the_given_map_stalls(caplog):
    caplog.set_level(logging.INFO, logger="geomopt")
    folder = LIM_ROOT / "2D" / "Simple" / "square_rot180"
    if not folder.is_dir():
        pytest.skip(f"LIM sample data not found at {folder}")
    case = LimCase.read(folder)
    # given: the run the CLI made (size buckets) stalls; auto stops it early and starts again
    with pytest.warns(Warning, match="outer-iteration limit"):
        _, given = untangle_case(case, options=UntangleOptions(bucket=True, start="given", max_outer=60),
                                 progress=False)
    assert not given.success and given.certificate.inverted > 0
    _, auto = untangle_case(case, options=UntangleOptions(bucket=True), progress=True)
    assert auto.success, auto.message
    assert auto.details.start == "given, then harmonic"
    assert auto.stats.outer_iterations < 100  # the stall ended the first run long before max_outer
    assert any("again from the harmonic extension" in r.getMessage() for r in caplog.records)


def _continuation(stall, inverted, eps):
    eps_loop = continuation.EpsContinuation.__new__(continuation.EpsContinuation)  # the rule's state only
    eps_loop.stall, eps_loop.at_floor, eps_loop.floor = stall, 0, 1e-9
    eps_loop.eps, eps_loop.inverted = eps, list(inverted)
    return eps_loop


def test_the_stall_rule_waits_for_the_floor_and_for_no_new_best():
    """``EpsContinuation._stalled``: fires once ``stall`` outer iterations at the eps floor found
    no fewer inverted elements than the best before them; never while eps is above the floor,
    never when the window holds a new best, never without ``stall``."""
    loop = _continuation(3, [4, 5, 6, 7], 1e-9)
    assert [loop._stalled() for _ in range(3)] == [False, False, True]
    loop = _continuation(3, [10, 5, 6, 7], 1e-9)  # 5 < 10: still improving
    assert not any(loop._stalled() for _ in range(5))
    loop = _continuation(3, [4, 5, 6, 7], 1e-3)  # above the floor
    assert not any(loop._stalled() for _ in range(5))
    loop = _continuation(None, [4, 5, 6, 7], 1e-9)
    assert not any(loop._stalled() for _ in range(5))

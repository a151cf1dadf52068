"""One calling convention for the drivers: the data (and energy, solver) by position, every
setting keyword-only, configuration in frozen validated options objects, energy parameters
with the energy; the old forms (deprecated, removed in 0.2.0) are refused."""

import dataclasses
import inspect

import numpy as np
import pytest

import geomopt
from geomopt import ParameterError
from geomopt.experiments.options import CompareOptions
from geomopt.param import ParamOptions
from geomopt.bijective import ScaffoldOptions
from geomopt.smoothing import SmoothOptions
from geomopt.sphere import SphereOptions

V = [[0, 0, 0.5], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]
F = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]
DRIVERS = {  # name -> (function, its positional parameters)
    "parameterize": (geomopt.parameterize, ("V", "F", "energy", "solver")),
    "sphere_map": (geomopt.sphere_map, ("V", "F", "energy", "solver")),
    "make_atlas": (geomopt.make_atlas, ("V", "F", "energy", "solver")),
    "smooth": (geomopt.smooth, ("V", "E", "energy", "solver")),
    "fair": (geomopt.fair, ("V", "F", "method")),
    "minimize": (geomopt.minimize, ("objective", "x0", "solver", "params")),
    "untangle": (geomopt.untangle, ("problem", "x0", "solver")),
    "compare": (geomopt.compare, ("mesh", "faces", "energy", "solvers")),
    "compare_meshes": (geomopt.compare_meshes, ("meshes", "energy", "solvers")),
}


@pytest.mark.parametrize("name", sorted(DRIVERS))
def test_every_driver_takes_data_by_position_and_settings_by_keyword(name):
    func, positional = DRIVERS[name]
    params = inspect.signature(func).parameters.values()
    assert tuple(p.name for p in params if p.kind is p.POSITIONAL_OR_KEYWORD) == positional
    keyword = {p.name for p in params if p.kind is p.KEYWORD_ONLY}
    assert "progress" in keyword
    assert name == "minimize" or "options" in keyword  # minimize's settings are its solver's


def test_positional_settings_are_refused():
    """The former positional settings after the solver (removed in 0.2.0) are a TypeError."""
    with pytest.raises(TypeError, match="positional argument"):
        geomopt.parameterize(V, F, "symmetric_dirichlet", None, "mean_value", None, False)
    with pytest.raises(TypeError, match="positional argument"):
        geomopt.minimize(None, None, None, None, False)


@pytest.mark.parametrize("name", sorted(set(DRIVERS) - {"minimize"}))
def test_settings_and_energy_parameters_as_keywords_are_refused(name):
    """The former keyword settings and loose energy parameters (removed in 0.2.0): refused
    before any work, naming the keyword; a dict for ``options`` names the class to pass."""
    func, positional = DRIVERS[name]
    data = {"untangle": (None, None), "compare_meshes": ([],)}.get(name, (V, F))
    for keyword in ("weights", "lam"):
        with pytest.raises((TypeError, ParameterError), match=f"keyword argument.*'?{keyword}'?"):
            func(*data, **{keyword: 1})
    if name != "untangle":  # (untangle: tests/test_differentiable.py)
        with pytest.raises(ParameterError, match=r"options must be a [\w.]+Options( or None)?, got dict"):
            func(*data, options={"weights": "uniform"}, progress=False)


def test_the_bijective_mode_and_its_scaffold_come_from_the_options():
    eager = geomopt.parameterize(V, F, options=ParamOptions(bijective=True, scaffold=ScaffoldOptions(lazy=False)),
                                 progress=False)
    assert eager.success and eager.injectivity == "global" and eager.stats.outer_iterations >= 1
    plain = geomopt.parameterize(V, F, options=ParamOptions(bijective=True), progress=False)
    assert plain.stats.outer_iterations == 0  # lazy: no scaffold needed on a tent


@pytest.mark.parametrize("cls, field, bad", [
    (ParamOptions, "weights", "cotan"), (ParamOptions, "bijective", "no"), (ParamOptions, "scaffold", {"lazy": 1}),
    (SphereOptions, "pole", -1), (SphereOptions, "weights", 1), (SmoothOptions, "rest", "square"),
    (SmoothOptions, "max_rounds", 0), (CompareOptions, "repeat", 0), (CompareOptions, "clock", "gpu"),
    (CompareOptions, "max_seconds", float("nan")), (CompareOptions, "tolerances", (0.1, 2.0)),
    (CompareOptions, "formats", ("png", "jpg")), (CompareOptions, "reference", "lowest"),
    (CompareOptions, "font_size", 100),
])
def test_options_refuse_a_bad_value_naming_the_field(cls, field, bad):
    with pytest.raises(ParameterError, match=rf"{field}"):
        cls(**{field: bad})


def test_options_are_frozen_and_normalised():
    opts = CompareOptions(tolerances=[1e-6, 1e-2], formats="pdf", reference="0.5", repeat=2.0)
    assert opts.tolerances == (1e-2, 1e-6) and opts.formats == ("pdf",) and opts.reference == 0.5
    assert opts.repeat == 2 and isinstance(opts.repeat, int)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.repeat = 3


def test_compare_runs_as_its_options_say():
    c = geomopt.compare(V, F, "symmetric_dirichlet", ["newton"], options=CompareOptions(repeat=2, reference="best"))
    assert len(c.runs["newton"]) == 2 and c.reference.source == "best"
    with pytest.raises(ParameterError, match="options must be a CompareOptions"):
        geomopt.compare(V, F, options={"repeat": 2})


def test_smooth_and_sphere_read_their_options():
    from geomopt.mesh import generators

    Vq, Q = generators.sector_mesh(2, 4, perturb=0.4, seed=1)
    one = geomopt.smooth(Vq, Q, options=SmoothOptions(max_steps=1))
    assert one.stats.iterations <= 1 < geomopt.smooth(Vq, Q).stats.iterations
    Vs = [[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1]]
    Fs = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [5, 2, 1], [5, 3, 2], [5, 4, 3], [5, 1, 4]]
    poles = {geomopt.sphere_map(Vs, Fs, options=SphereOptions(pole=p), progress=False).details.pole for p in (0, 5)}
    assert poles == {0, 5}

"""The settings of a comparison (:func:`geomopt.compare`): :class:`CompareOptions`, validated
before anything runs."""

from __future__ import annotations

import dataclasses
import math

from .._runtime.config import Instance, Int, Maybe, OneOf, Real, validate
from .._runtime.errors import ParameterError
from .._runtime.names import COMPARED
from ..mesh.tutte import WEIGHTS

__all__ = ["CompareOptions", "TOLERANCES", "CLOCKS", "FORMATS", "WARMUP_STEPS", "DEFAULT_SOLVERS", "HISTORY_COLUMNS",
           "summary_columns"]

TOLERANCES = (1e-2, 1e-4, 1e-6)
#: untimed iterations each solver runs before its timed runs when ``warmup`` is on
WARMUP_STEPS = 5
#: what ``clock`` may name: elapsed (wall) or process CPU seconds of the solve
CLOCKS = ("wall", "cpu")
#: figure formats :meth:`~geomopt.experiments.comparison.Comparison.write` writes (PDF / PS with TrueType fonts)
FORMATS = ("png", "pdf", "svg", "eps", "ps")
LAYOUTS = ("wide", "column")
#: what ``geomopt compare`` runs when no ``--solvers`` is given (``cm`` is left out in 3D): the
#: table's choice (:data:`geomopt._runtime.names.COMPARED`)
DEFAULT_SOLVERS = COMPARED
HISTORY_COLUMNS = ("solver", "repeat", "iteration", "wall_s", "cpu_s", "energy", "mean_energy", "gap",
                   "grad_norm", "flips")
_SUMMARY_COLUMNS = ("solver", "outcome", "certified", "iterations", "wall_s", "cpu_s", "setup_s", "setup_cpu_s",
                    "s_per_it", "energy", "mean_energy", "gap", "max_flips", "repeats")
#: the largest font size (points) at which every title, axis label and the legend of six solvers
#: stay inside each layout's figure (15 in and 3.4 in wide; tests/test_messages.py draws it)
MAX_FONT_SIZE = {"wide": 16.0, "column": 10.0}


def summary_columns(tolerances=TOLERANCES) -> tuple:
    """The columns of ``summary.csv``: the run's totals, then per tolerance ``t`` the iteration
    and the wall and CPU seconds to a gap of ``t`` (``it_to_1e-04``, ``wall_s_to_1e-04``,
    ``cpu_s_to_1e-04``; empty when the gap never got there)."""
    return _SUMMARY_COLUMNS + tuple(f"{what}_to_{t:.0e}" for t in tolerances for what in ("it", "wall_s", "cpu_s"))


def check_font_size(layout, font_size, where="CompareOptions"):
    """ParameterError when ``font_size`` (points, or None: the layout's default) does not fit
    ``layout``'s figure: not in [1, :data:`MAX_FONT_SIZE`]."""
    if font_size is None:
        return
    top = MAX_FONT_SIZE[layout]
    if not (isinstance(font_size, (int, float)) and not isinstance(font_size, bool) and 1.0 <= font_size <= top):
        raise ParameterError(f"{where}: font_size must be a number of points in [1, {top:g}] for the {layout} "
                             f"layout (at most {top:g}: larger text does not fit its figure), got {font_size!r}")


@dataclasses.dataclass(frozen=True)
class CompareOptions:
    """The settings of :func:`geomopt.compare` and :func:`geomopt.compare_meshes` (validated:
    a wrong type or range is a one-line :class:`~geomopt.ParameterError`).

    Attributes
    ----------
    weights : Tutte weights of the default start map (``"uniform"`` or ``"mean_value"``).
    max_seconds : float > 0 or None: stop a solver once its solve time (set-up excluded, on
        ``clock``) reaches this; its outcome is then ``"max_seconds"`` (``Outcome.MAX_STEPS``).
    max_steps : int >= 1 or None: iteration limit of every solver (default: each solver's own).
    reference : ``"auto"`` (a tight Newton solve from the same start, run after the solvers),
        a float (the reference *mean* energy, as printed; a numeric string is read as one), or
        ``"best"`` (the lowest energy any solver reached).
    repeat : int >= 1, runs per solver; times are medians over them.
    warmup : True (default): :data:`WARMUP_STEPS` untimed, discarded iterations per solver
        before its timed runs, so that lazy compilation is not solve time; False: the first run
        is timed cold.
    clock : ``"wall"`` (default) or ``"cpu"``: the seconds ``max_seconds``, the figure, the
        LaTeX table and the choice of the median run use.
    tolerances : the relative gaps in (0, 1) the summary reports iterations and seconds to
        (stored largest first).
    formats : figure formats written with ``out`` (:data:`FORMATS`).
    log_x : a logarithmic time axis in the figure.
    layout : ``"wide"`` or ``"column"`` (one panel, a paper column wide).
    font_size : the figure's font size in points, in [1, 16] (wide) or [1, 10] (column): where the
        figure fits (:data:`MAX_FONT_SIZE`), or None (the layout's).
    """

    weights: str = "uniform"
    max_seconds: float | None = None
    max_steps: int | None = None
    reference: str | float = "auto"
    repeat: int = 1
    warmup: bool = True
    clock: str = "wall"
    tolerances: tuple = TOLERANCES
    formats: tuple = ("png",)
    log_x: bool = False
    layout: str = "wide"
    font_size: float | None = None

    def __post_init__(self):
        validate(self, weights=OneOf(WEIGHTS), max_seconds=Maybe(Real(0.0, lo_open=True)), max_steps=Maybe(Int(1)),
                 repeat=Int(1), warmup=Instance(bool), clock=OneOf(CLOCKS), log_x=Instance(bool),
                 layout=OneOf(LAYOUTS), font_size=Maybe(Real(1.0, 72.0)))
        check_font_size(self.layout, self.font_size)
        object.__setattr__(self, "reference", _reference(self.reference))
        object.__setattr__(self, "tolerances", _tolerances(self.tolerances))
        object.__setattr__(self, "formats", _formats(self.formats))


def _reference(value):
    if isinstance(value, str) and value in ("auto", "best"):
        return value
    try:
        v = float(value) if isinstance(value, (str, int, float)) and not isinstance(value, bool) else math.nan
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ParameterError(f"CompareOptions: reference must be 'auto', 'best' or a finite mean energy, got {value!r}")
    return v


def _tolerances(value):
    try:
        tol = tuple(float(t) for t in value)
    except (TypeError, ValueError):
        tol = ()
    if not tol or any(not (0 < t < 1) for t in tol):
        raise ParameterError(f"CompareOptions: tolerances must be relative gaps in (0, 1), got {value!r}")
    return tuple(sorted(tol, reverse=True))


def _formats(value):
    formats = (value,) if isinstance(value, str) else tuple(value)
    bad = [str(f) for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ParameterError(f"CompareOptions: figure formats are {', '.join(FORMATS)}, got {', '.join(bad) or 'none'}")
    return formats

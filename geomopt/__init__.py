"""geomopt: locally injective maps of triangle and tetrahedral meshes in JAX.

Importing geomopt enables float64 in JAX (``jax_enable_x64``): all numerics are float64.
"""
import jax as _jax

_jax.config.update("jax_enable_x64", True)

from . import energies, io, predicates  # noqa: E402
from ._errors import GeomoptError, MeshError, MeshFormatError, ParameterError, SolveError  # noqa: E402
from ._objective import Objective  # noqa: E402
from .compare import Comparison, compare  # noqa: E402
from .param import parameterize  # noqa: E402
from .problem import Problem  # noqa: E402
from .solvers import AQP, CM, LBFGS, SLIM, Newton, Outcome, Result, minimize  # noqa: E402
from .tutte import tutte_embedding  # noqa: E402

__all__ = [
    "GeomoptError", "MeshError", "MeshFormatError", "ParameterError", "SolveError",
    "Objective", "Problem", "compare", "Comparison", "Newton", "LBFGS", "SLIM", "AQP", "CM", "Outcome", "Result", "minimize", "parameterize",
    "tutte_embedding", "energies", "io", "predicates",
]

"""geomopt: locally injective maps of triangle and tetrahedral meshes in JAX."""
import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._errors import GeomoptError, MeshError, MeshFormatError, ParameterError, SolveError  # noqa: E402

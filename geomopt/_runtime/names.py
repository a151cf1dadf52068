"""The built-in energies and solvers: each name with where it is defined, the one table both
registries (:data:`geomopt.energies.REGISTRY`, :data:`geomopt.solvers.SOLVERS`) are built
from.  The command line's help text reads the names only, without importing JAX
(``geomopt --help`` starts in a few tens of milliseconds).

A new built-in energy is its definition plus one row here; a new solver likewise.
"""

import importlib

#: energy name -> ``module:attribute`` of its :class:`~geomopt.energies.Energy`
ENERGIES = {
    "symmetric_dirichlet": "geomopt.energies._energy:symmetric_dirichlet",
    "dirichlet": "geomopt.energies._energy:dirichlet",
    "mips": "geomopt.energies._energy:mips",
    "winslow": "geomopt.energies._energy:winslow",
    "arap": "geomopt.energies._energy:arap",
    "garanzha": "geomopt.energies._energy:garanzha",
}
#: solver name -> ``module:attribute`` of a factory of the default-configured solver
SOLVERS = {
    "newton": "geomopt.solvers.newton:Newton",
    "lbfgs": "geomopt.solvers.lbfgs:LBFGS",
    "slim": "geomopt.solvers.newton:SLIM",
    "aqp": "geomopt.solvers.aqp:AQP",
    "cm": "geomopt.solvers.newton:CM",
    "optx-bfgs": "geomopt.solvers._registry:optx_bfgs",
    "optx-lbfgs": "geomopt.solvers._registry:optx_lbfgs",
    "optx-ncg": "geomopt.solvers._registry:optx_ncg",
}

#: the solvers ``geomopt compare`` runs when none is named (``cm`` is left out in 3D); the others
#: of :data:`SOLVERS` run when named.  Not ``optx-lbfgs``: optimistix's L-BFGS seeds its inverse
#: Hessian with the scalar ``s.y / y.y`` and has no preconditioner hook, and from the Tutte map
#: of a large mesh it stalls where geomopt's L-BFGS with its Laplacian seed converges.
COMPARED = ("newton", "lbfgs", "slim", "aqp", "cm")


def resolve(table: dict) -> dict:
    """``{name: definition}`` for a table of ``module:attribute`` references."""
    out = {}
    for name, ref in table.items():
        module, attribute = ref.split(":")
        out[name] = getattr(importlib.import_module(module), attribute)
    return out

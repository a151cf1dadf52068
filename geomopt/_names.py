"""Names of the built-in energies and solvers, for the command line's help text, which must
not import JAX (``geomopt --help`` starts in a few tens of milliseconds).

tests/test_startup.py checks them against :data:`geomopt.energies.REGISTRY` and
:data:`geomopt.solvers.SOLVERS`.
"""

ENERGIES = ("symmetric_dirichlet", "dirichlet", "mips", "winslow", "arap", "garanzha")
SOLVERS = ("newton", "lbfgs", "slim", "aqp", "cm", "optx-bfgs", "optx-lbfgs", "optx-ncg")

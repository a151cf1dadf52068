"""The linear algebra floor, above the runtime and below the mesh: sparse symmetric
positive-definite solves with a fixed pattern (:mod:`~geomopt.linalg.linsolve`: PARDISO, CHOLMOD,
cholespy or SuperLU, chosen by measurement; :mod:`~geomopt.linalg.pardiso`, oneMKL PARDISO called
directly), conjugate gradients on the host (:mod:`~geomopt.linalg.krylov`) and the batched
eigendecomposition of small symmetric matrices (:mod:`~geomopt.linalg.eigh`).  Imports nothing
of geomopt but the runtime, so the Tutte map (:mod:`geomopt.mesh.tutte`), the objective, the
solvers and the drivers all factor with the same backends."""

from .._runtime.lazy import submodules

__all__ = ["eigh", "krylov", "linsolve", "pardiso"]
__getattr__, __dir__ = submodules(__name__, tuple(__all__))

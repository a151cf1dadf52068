"""Experiments on top of the drivers: solver comparisons (:mod:`~geomopt.experiments.comparison`)
and their writers (:mod:`~geomopt.experiments.report`), the manifest of a run's settings and
machine (:mod:`~geomopt.experiments.manifest`), and batches of untangling cases
(:mod:`~geomopt.experiments.batch`)."""

from .._runtime.lazy import submodules

__all__ = ["batch", "comparison", "manifest", "inputs", "report", "writers"]
__getattr__, __dir__ = submodules(__name__, tuple(__all__))

"""The inputs of a comparison (:func:`geomopt.experiments.comparison.compare`), checked before
anything runs: its settings, the problem and start map from a mesh, and the solvers by name."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from . import manifest as _manifest
from .. import io
from .._runtime.errors import MeshError, ParameterError
from ..objective.objective import Objective
from ..mesh.elements import element_type
from ..mesh.problem import Problem
from ..solvers import CM, get_solver
from .options import DEFAULT_SOLVERS

__all__ = ["mesh_key", "comparison_problem", "comparison_solvers", "NAME"]

#: a solver or mesh name usable as a file name
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]*")
# optimistix's BFGS keeps a dense (n d) x (n d) inverse Hessian; refuse what cannot fit
DENSE_SOLVERS = ("optx-bfgs",)
DENSE_LIMIT_BYTES = 2 << 30


def mesh_key(mesh) -> str:
    return Path(mesh).stem if not Path(mesh).is_dir() else Path(mesh).name


def comparison_problem(mesh, faces, energy, x0, weights, energy_params):
    """``(objective, start map, mirror, label, source)`` for :func:`compare`'s ``mesh``
    argument; ``source`` records the input (path, content hash) and the start map."""
    from ..param import start_map

    mirror, case, given = None, None, x0 is not None
    if isinstance(mesh, (Problem, str, Path)) and faces is not None:
        raise ParameterError("compare: give faces only with a vertex array, not with a path or a Problem")
    source = {"input": "arrays", "start": "given x0" if given else None}
    if isinstance(mesh, Problem):
        problem, label = mesh, f"{mesh.kind} problem"
    elif isinstance(mesh, (str, Path)):
        path = Path(mesh)
        label = path.name
        source["input"] = str(path)
        if path.is_dir():
            from ..lim import LimCase

            case = path
            problem, case_x0, _, mirror = LimCase.read(path).to_problem()
            x0 = case_x0 if x0 is None else io.validate_vertices(x0, "start map x0", dim=problem.dim) * mirror
            source["files_sha256"] = {p.name: _manifest.file_hash(p) for p in sorted(path.iterdir()) if p.is_file()}
            source["start"] = source["start"] or "the LIM case's map"
        else:
            problem = Problem.surface(*io.read_mesh(path))
            source["file_sha256"] = _manifest.file_hash(path)
    else:
        if faces is None:
            raise ParameterError("compare: give the faces (m, 3) with a vertex array, or a mesh path, "
                                 "a LIM case folder or a Problem")
        V = io.validate_vertices(mesh, "compare: vertices")
        problem = (Problem.planar if V.shape[1] == 2 else Problem.surface)(V, faces)
        label = "mesh"
    objective = Objective(problem, energy, **energy_params)
    if problem.fixed.size == 0 and problem.dim == 2:
        objective.energy.check_scale_aware(energy_params)
    if x0 is None:
        if problem.fixed.size or problem.dim != 2 or problem.elements is not None:
            raise ParameterError(f"compare: a {problem.kind} problem with {problem.fixed.size} fixed "
                                 f"vertices needs a start map x0; only free-boundary 2D maps default "
                                 f"to the Tutte start")
        x0, _, _ = start_map(objective, None, weights)
        source["start"] = f"Tutte embedding ({weights} weights), centred and scaled as parameterize does"
    x0 = problem.check_map(x0, "start map x0")
    inverted = problem.count_inverted(x0)
    if inverted:
        what = ("tetrahedra" if problem.dim == 3 else "triangle(s)") if problem.elements is None else \
            element_type(problem.elements)[1]
        which = "the start map x0" if given else "the start map"
        if case is not None:
            which = which if given else f"the map of LIM case {case}"
            hint = (f"untangle it first (geomopt untangle {case} -o DIR/input.obj, copy its handles "
                    f"file into DIR, then compare DIR)" if problem.dim == 2 else
                    f"untangle it first (geomopt untangle {case} -o DIR/init.vtk, copy its rest.vtk and "
                    f"handles file into DIR, then compare DIR)")
        else:
            hint = "untangle it first (geomopt.untangle) or give a flip-free x0"
        raise MeshError(f"{which} has {inverted} inverted or degenerate {what}; compare needs a "
                        f"flip-free start map so that every solver can stay flip-free: {hint}")
    return objective, x0, np.ones(problem.dim) if mirror is None else mirror, label, source


def comparison_solvers(solvers, problem, max_steps) -> dict:
    """``{name: solver}`` with ``max_steps`` applied, checked before anything runs."""
    if solvers is None:
        solvers = [s for s in DEFAULT_SOLVERS if problem.dim == 2 or s != "cm"]
    if isinstance(solvers, str):
        solvers = [s for s in solvers.split(",") if s.strip()]
    items = list(solvers.items()) if isinstance(solvers, dict) else [
        (s.strip().lower().replace("_", "-") if isinstance(s, str) else type(s).__name__.lower(), s)
        for s in solvers]
    if not items:
        raise ParameterError("compare: no solver given; name at least one (e.g. newton,lbfgs)")
    named = {}
    for name, s in items:
        if not isinstance(name, str) or not NAME.fullmatch(name):
            raise ParameterError(f"compare: solver name {name!r} cannot be a file name; use letters, "
                                 f"digits and _.+- (starting with a letter or digit)")
        if name in named:
            raise ParameterError(f"compare: solver {name!r} is given twice; name each solver once")
        solver = get_solver(s)
        if max_steps is not None:
            solver = dataclasses.replace(solver, max_steps=max_steps)
        if isinstance(solver, CM) and problem.dim != 2:
            raise ParameterError("compare: cm (composite majorization) is defined for triangles only; "
                                 "leave it out for a tet problem")
        if name in DENSE_SOLVERS:
            nbytes = 8 * (problem.n_vertices * problem.dim) ** 2
            if nbytes > DENSE_LIMIT_BYTES:
                raise ParameterError(
                    f"compare: {name} keeps a dense inverse Hessian of {nbytes / 2**30:.1f} GiB for "
                    f"{problem.n_vertices} vertices; use optx-lbfgs or lbfgs on a mesh this size")
        named[name] = solver
    return named



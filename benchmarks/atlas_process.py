"""Texture atlases as a user meets them: the whole ``geomopt param`` process beside an xatlas process.

For each mesh, as separate processes, alternating, timed from outside (wall seconds; peak
resident memory from ``os.wait4``):

* geomopt **first run**: ``geomopt param MESH -o OUT.obj --json --quiet`` (an atlas for a mesh
  that is not a disk) with an empty compilation cache (``GEOMOPT_CACHE_DIR`` pointed at a fresh
  folder: JAX's persistent cache and geomopt's kept programs both live there);
* xatlas: a small script that reads the mesh with trimesh (``process=False``), calls
  ``xatlas.parametrize`` (default options, all threads) and writes the OBJ with ``xatlas.export``;
* geomopt **later run**: the same command again, the cache now filled; then xatlas again;
  ``--repeat`` such later rounds (medians reported).

Per mesh: wall seconds, peak RSS and the ratio geomopt / xatlas for first and later runs,
geomopt's own ``--json`` timing split (import, read, cut, flatten, pack, write) of the later runs,
and where each tool's seams run, read back from its first output OBJ
(:func:`geomopt.atlas.seam_metrics`, in this process): the seams' ambient visibility relative to
the average edge's (1: as exposed as a random cut) and their mean turning angle in degrees.
Each process is checked: exit status 0, geomopt's atlas certified, the output written, the
input file's bytes unchanged.  Outputs go to a temporary folder, removed at the end.

``--stages``: instead, where the time goes: per mesh, one geomopt process that imports, reads,
makes the atlas once (warming the process) and again timed by its progress stages (cut,
flatten, split search + packing, the exact certificate) and writes the OBJ, beside the xatlas
process, alternating, ``--repeat`` rounds (medians; peak resident memory, the largest).

``--subdivide K``: the meshes after ``K`` Loop subdivisions (4^K times the faces: cow's 5,520
become 353,280 at ``K = 3``), for the atlas at scan sizes.

Run it with the Python of the install being measured, as a user installs it::

    python3 -m venv /tmp/plainvenv && /tmp/plainvenv/bin/pip install . xatlas trimesh
    /tmp/plainvenv/bin/python benchmarks/atlas_process.py            # shared/data/closed/*.off
    /tmp/plainvenv/bin/python benchmarks/atlas_process.py MESH ... [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CLOSED = REPO.parent / "shared/data/closed"

#: the xatlas process: read, parametrize, export; its own timing split on stdout
XATLAS = """
import json, sys, time
t0 = time.perf_counter()
import trimesh, xatlas
t1 = time.perf_counter()
mesh = trimesh.load(sys.argv[1], force="mesh", process=False)
t2 = time.perf_counter()
c2 = time.process_time()
vmapping, indices, uvs = xatlas.parametrize(mesh.vertices, mesh.faces)
t3, c3 = time.perf_counter(), time.process_time()
xatlas.export(sys.argv[2], mesh.vertices[vmapping], indices, uvs)
t4 = time.perf_counter()
print(json.dumps({"vertices": len(mesh.vertices), "faces": len(mesh.faces), "uv_vertices": len(uvs),
                  "timing": {"import": t1 - t0, "read": t2 - t1, "parametrize": t3 - t2, "write": t4 - t3},
                  "cpu": {"parametrize": c3 - c2}}))
"""


#: geomopt's stages, in one process: import, read, then ``make_atlas`` twice (the first warms the
#: process: its programs loaded or compiled), the second timed by its progress stages, the exact
#: certificate's own seconds, and the write
STAGES = """
import json, sys, time
clock = time.process_time if sys.argv[3] == "cpu" else time.perf_counter
t0 = clock()
import geomopt
from geomopt import io
from geomopt.atlas import make_atlas
t1 = clock()
V, F = io.read_mesh(sys.argv[1])
t2 = clock()
make_atlas(V, F, progress=False)
mark, stages = [clock()], {"cut": 0.0, "flatten": 0.0, "split+pack": 0.0}

def say(stage, info):
    now = clock()
    key = {"cut": "cut", "split to pack": "split+pack", "packed": "split+pack"}.get(stage, "flatten")
    stages[key] += now - mark[0]
    mark[0] = now

t3 = clock()
atlas = make_atlas(V, F, progress=say)
t4 = clock()
d = atlas.details
io.write_mesh_with_uv(sys.argv[2], V, F, atlas.x, format="obj", uv_faces=d.uv_faces)
t5 = clock()
geomopt.atlas.certify_atlas(atlas.x, d.uv_faces, d.chart)  # the atlas's certificate again, timed
stages["certificate"] = clock() - t5
stages["split+pack"] -= stages["certificate"]
m = d.metrics
print(json.dumps({"faces": len(F), "charts": m.charts, "efficiency": m.efficiency, "certified": atlas.success,
                  "timing": {"import": t1 - t0, "read": t2 - t1, "first atlas": t3 - t2, **stages,
                             "atlas": t4 - t3, "write": t5 - t4}}))
"""


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def run_process(args, env=None):
    """One process to its exit: wall and CPU seconds, peak resident MB (``os.wait4``), exit status,
    stdout, stderr, the 1-minute load average before it."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        load = os.getloadavg()[0]
        t = time.perf_counter()
        p = subprocess.Popen(args, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t
        p.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        out.seek(0), err.seek(0)
        return {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime, "peak_mb": usage.ru_maxrss / 1024.0,
                "rc": p.returncode, "load": load,
                "stdout": out.read().decode(errors="replace"), "stderr": err.read().decode(errors="replace")}


def geomopt_command():
    """The installed ``geomopt`` script next to this Python (``python -m geomopt`` without one)."""
    script = Path(sys.executable).parent / "geomopt"
    return [str(script)] if script.exists() else [sys.executable, "-m", "geomopt"]


def obj_seams(mesh, output):
    """:class:`geomopt.atlas.SeamMetrics` of the atlas OBJ ``output`` (``v``, ``vt``, ``f v/vt``;
    xatlas repeats a vertex per UV) of the mesh file ``mesh``: its faces (both tools keep the
    input's order) checked against the input's corner by corner, by position, and their ``vt``
    ids taken as the per-corner UVs of the input's faces."""
    import numpy as np

    from geomopt.atlas import seam_metrics
    from geomopt.atlas.metrics import seam_edges
    from geomopt.io import read_mesh

    V, F = (np.asarray(a) for a in read_mesh(mesh))
    v, corners = [], []
    for line in Path(output).read_text().splitlines():
        if line.startswith("v "):
            v.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            corners.append([[int(i) - 1 for i in c.split("/")[:2]] for c in line.split()[1:]])
    C = np.asarray(corners)  # (m, 3, 2): vertex and vt ids
    tol = 1e-6 * float(np.linalg.norm(np.ptp(V, axis=0)))  # the OBJ's digits may round the positions
    if C.shape != (len(F), 3, 2) or np.abs(np.asarray(v)[C[:, :, 0]] - V[F]).max() > tol:
        raise RuntimeError(f"{output}: its faces are not {mesh}'s, in order")
    return seam_metrics(V, F, seam_edges(F, C[:, :, 1]))


def checked(run, tool, mesh, output, digest, seams=False):
    """``run`` with its ``--json`` line parsed (and, with ``seams``, the :func:`obj_seams` of its
    output); raises when the process failed, wrote nothing, changed the input or (geomopt) did
    not certify its atlas."""
    if run["rc"] != 0:
        raise RuntimeError(f"{tool} on {mesh} exited {run['rc']}: {run['stderr'][-1500:]}")
    if not Path(output).is_file() or Path(output).stat().st_size == 0:
        raise RuntimeError(f"{tool} on {mesh} wrote no {output}")
    if sha256(mesh) != digest:
        raise RuntimeError(f"{tool} changed its input {mesh}")
    run["summary"] = json.loads(run["stdout"].strip().splitlines()[-1])
    if tool == "geomopt" and not run["summary"].get("certified"):
        raise RuntimeError(f"geomopt's atlas of {mesh} is not certified: {run['summary'].get('message')}")
    if seams:
        m = obj_seams(mesh, output)
        run["seams"] = {"visibility": m.visibility, "turning": m.turning_degrees}
    Path(output).unlink()
    return run


def cache_mb(folder):
    return sum(p.stat().st_size for p in Path(folder).rglob("*") if p.is_file()) / 2**20


def sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def measure(mesh, tmp, repeat):
    """First and ``repeat`` later runs of both tools on ``mesh``, alternating."""
    cache = Path(tempfile.mkdtemp(prefix="cache-", dir=tmp))
    env = {**os.environ, "GEOMOPT_CACHE_DIR": str(cache)}
    env.pop("PYTHONPATH", None)  # the installed package, not a checkout
    digest, out_g, out_x = sha256(mesh), tmp / "geomopt.obj", tmp / "xatlas.obj"

    def geomopt(first):
        cmd = [*geomopt_command(), "param", str(mesh), "-o", str(out_g), "--json", "--quiet"]
        return checked(run_process(cmd, env), "geomopt", mesh, out_g, digest, first)

    def xatlas(first):
        return checked(run_process([sys.executable, "-c", XATLAS, str(mesh), str(out_x)], env),
                       "xatlas", mesh, out_x, digest, first)

    runs = {"geomopt": [], "xatlas": []}
    for i in range(1 + repeat):
        for tool, call in (("geomopt", geomopt), ("xatlas", xatlas)):
            runs[tool].append(call(i == 0))
            r = runs[tool][-1]
            log(f"  {'first' if i == 0 else 'later'} {tool}: {r['wall']:.2f} s, {r['peak_mb']:.0f} MB "
                f"(load {r['load']:.2f})" + (f"; cache {cache_mb(cache):.0f} MB" if tool == "geomopt" else ""))
    faces = (runs["geomopt"][0]["summary"]["faces"], runs["xatlas"][0]["summary"]["faces"])
    if faces[0] != faces[1]:
        log(f"  NOTE: geomopt read {faces[0]} faces, trimesh {faces[1]}")
    return runs


def summarise(name, runs):
    """One row: first run, median of later runs, for both tools, and geomopt's later split."""
    def later(tool, key):
        return statistics.median(r[key] for r in runs[tool][1:])

    g, x = runs["geomopt"], runs["xatlas"]
    phases = [k for k in g[-1]["summary"].get("timing", {}) if k != "total"]
    return {"mesh": name, "faces": g[0]["summary"]["faces"], "xatlas_faces": x[0]["summary"]["faces"],
            "charts": g[0]["summary"]["charts"], "efficiency": g[0]["summary"]["efficiency"],
            "seams": {t: runs[t][0]["seams"] for t in runs},
            "first": {t: {k: runs[t][0][k] for k in ("wall", "peak_mb")} for t in runs},
            "later": {t: {k: later(t, k) for k in ("wall", "peak_mb")} for t in runs},
            "split": {k: statistics.median(r["summary"]["timing"].get(k, 0.0) for r in g[1:]) for k in phases},
            "xatlas_split": {k: statistics.median(r["summary"]["timing"][k] for r in x[1:])
                             for k in ("import", "parametrize")},
            "load": [r["load"] for t in runs for r in runs[t]]}


def table(rows):
    lines = ["| mesh | faces | charts | geomopt first s / MB | later s / MB | xatlas first s / MB | later s / MB "
             "| ratio first: s, MB | ratio later: s, MB | seam visibility geomopt / xatlas "
             "| seam turning deg geomopt / xatlas | load |", "|---" * 12 + "|"]
    for r in rows:
        f, lt = r["first"], r["later"]
        cell = (lambda d: f"{d['wall']:.2f} / {d['peak_mb']:.0f}")
        ratio = (lambda d: f"{d['geomopt']['wall'] / d['xatlas']['wall']:.1f}, "
                           f"{d['geomopt']['peak_mb'] / d['xatlas']['peak_mb']:.1f}")
        lines.append(f"| {r['mesh']} | {r['faces']} | {r['charts']} | {cell(f['geomopt'])} | {cell(lt['geomopt'])} | "
                     f"{cell(f['xatlas'])} | {cell(lt['xatlas'])} | {ratio(f)} | {ratio(lt)} | "
                     f"{r['seams']['geomopt']['visibility']:.3f} / {r['seams']['xatlas']['visibility']:.3f} | "
                     f"{r['seams']['geomopt']['turning']:.1f} / {r['seams']['xatlas']['turning']:.1f} | "
                     f"{min(r['load']):.1f}-{max(r['load']):.1f} |")
    phases = list(dict.fromkeys(k for r in rows for k in r["split"]))
    lines += ["", "geomopt's own `--json` split of the later runs, and xatlas's import and parametrize "
              "(wall s, medians)", "", "| mesh | " + " | ".join(phases) + " | xatlas import | xatlas parametrize |",
              "|---" * (3 + len(phases)) + "|"]
    lines += [f"| {r['mesh']} | " + " | ".join(f"{r['split'].get(k, 0.0):.2f}" for k in phases)
              + f" | {r['xatlas_split']['import']:.2f} | {r['xatlas_split']['parametrize']:.2f} |" for r in rows]
    return "\n".join(lines)


def stages(paths, repeat, clock="wall"):
    """Per mesh, ``repeat`` rounds of geomopt's :data:`STAGES` process and the xatlas process,
    alternating: medians of each stage beside xatlas's, as a markdown table; ``clock`` "wall"
    (seconds) or "cpu" (the process's CPU seconds, all threads: steadier than wall time on a
    loaded machine; xatlas's parametrize runs on all threads, so its CPU seconds exceed its
    wall time on an idle machine)."""
    rows = ["| mesh | faces | charts | import | read | cut | flatten | split search + packing | certificate "
            "| write | atlas (warm) | xatlas parametrize | xatlas process | geomopt process (incl. first atlas) "
            "| ratio atlas / xatlas parametrize | peak MB geomopt / xatlas |", "|---" * 16 + "|"]
    with tempfile.TemporaryDirectory(prefix="atlas_stages-") as tmp:
        for path in paths:
            g, x = [], []
            for _ in range(repeat):
                g.append(checked(run_process([sys.executable, "-c", STAGES, str(path), f"{tmp}/g.obj", clock]), "geomopt",
                                 path, f"{tmp}/g.obj", sha256(path)))
                x.append(checked(run_process([sys.executable, "-c", XATLAS, str(path), f"{tmp}/x.obj"]), "xatlas",
                                 path, f"{tmp}/x.obj", sha256(path)))
                log(f"  {path.name}: geomopt {g[-1]['wall']:.1f} s, xatlas {x[-1]['wall']:.1f} s")
            med = {k: statistics.median(r["summary"]["timing"][k] for r in g) for k in g[0]["summary"]["timing"]}
            xp = statistics.median(r["summary"]["cpu" if clock == "cpu" else "timing"]["parametrize"] for r in x)
            s = g[0]["summary"]
            rows.append(f"| {path.stem} | {s['faces']} | {s['charts']} | " + " | ".join(
                f"{med[k]:.2f}" for k in ("import", "read", "cut", "flatten", "split+pack", "certificate", "write",
                                          "atlas")) + f" | {xp:.2f} | {statistics.median(r[clock] for r in x):.2f} | "
                f"{statistics.median(r[clock] for r in g):.2f} | {med['atlas'] / xp:.2f} | "
                f"{max(r['peak_mb'] for r in g):.0f} / {max(r['peak_mb'] for r in x):.0f} |")
    return "\n".join(rows)


def subdivided(path, k, folder):
    """``path``'s mesh after ``k`` Loop subdivisions, as an OFF file in ``folder``."""
    import trimesh

    mesh = trimesh.load(path, force="mesh", process=False)
    V, F = mesh.vertices, mesh.faces
    for _ in range(k):
        V, F = trimesh.remesh.subdivide_loop(V, F)
    out = folder / f"{Path(path).stem}-x{4 ** k}.off"
    trimesh.Trimesh(V, F, process=False).export(out)
    log(f"{out.name}: {len(F)} faces")
    return out


def report(args, paths):
    """The table of ``args`` (``--stages`` or the processes) on the mesh files ``paths``."""
    if args.stages:
        print(stages([p for p in paths if p.is_file()], args.repeat, args.clock))
        return
    version = subprocess.run([*geomopt_command(), "--version"], capture_output=True, text=True).stdout.strip()
    log(f"{' '.join(geomopt_command())} ({version or 'no --version'}); load {os.getloadavg()}")
    rows, failed = [], {}
    with tempfile.TemporaryDirectory(prefix="atlas_process-") as tmp:
        for path in paths:
            if not path.is_file():
                log(f"{path}: not found, skipped")
                continue
            log(f"{path.name}")
            try:
                rows.append(summarise(path.stem, measure(path, Path(tmp), args.repeat)))
            except RuntimeError as exc:  # a failed process: say so and go on with the next mesh
                log(f"  FAILED: {exc}")
                failed[path.stem] = str(exc)
    print(table(rows))
    for name, why in failed.items():
        print(f"failed {name}: {why.strip().splitlines()[0]}")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "failed": failed, "geomopt": version}, indent=1))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("meshes", nargs="*", help="mesh files (default: shared/data/closed/*.off)")
    ap.add_argument("--repeat", type=int, default=1, help="later rounds per mesh (medians; default 1)")
    ap.add_argument("--json", help="write the raw results here")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="--stages: wall seconds, or the processes' CPU seconds (steadier on a loaded machine)")
    ap.add_argument("--subdivide", type=int, default=0, metavar="K",
                    help="run on each mesh after K Loop subdivisions (trimesh.remesh.subdivide_loop: 4^K times "
                         "the faces; e.g. cow at K=3: 353k faces), written to a temporary folder")
    ap.add_argument("--stages", action="store_true",
                    help="instead: geomopt's stages in a warm process (cut, flatten, split search + packing, "
                         "certificate, write) beside xatlas, --repeat rounds")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat: at least one later round")
    if args.subdivide < 0:
        ap.error("--subdivide: a number of subdivisions, 0 or more")
    if importlib.util.find_spec("xatlas") is None:
        ap.exit(2, "atlas_process.py: xatlas is not installed; install the benchmark extra: pip install \".[bench]\"\n")
    paths = [Path(p) for p in args.meshes] or sorted(CLOSED.glob("*.off"))
    if not paths:
        sys.exit(f"no meshes given and none at {CLOSED}: name mesh files, or clone the project next to shared/")
    with tempfile.TemporaryDirectory(prefix="atlas_subdivided-") as folder:
        if args.subdivide > 0:
            paths = [subdivided(p, args.subdivide, Path(folder)) for p in paths if p.is_file()]
        report(args, paths)


if __name__ == "__main__":
    main()

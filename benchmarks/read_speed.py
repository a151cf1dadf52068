"""Reading speed: geomopt's mesh readers against meshio (and trimesh for surfaces) at 10^6 elements.

Writes, in a temporary folder, one tetrahedral mesh of about 10^6 tets (a jittered cube grid,
6 Kuhn tets per cell) as ``.vtu`` (meshio's binary zlib, what :func:`geomopt.io.write_tets`
writes), legacy ``.vtk`` ASCII (geomopt) and binary (meshio, file version 5.1 and 4.2),
``.msh`` (Gmsh 4.1 ASCII, meshio) and ``.mesh`` (Medit ASCII, meshio); and one triangle mesh
of about 10^6 triangles (a jittered grid) as ``.obj``, ``.off``, ``.ply`` binary and ASCII, and
binary ``.stl``.  Coordinates carry all 17 digits, as a solver's output does.

Each file is read ``--repeat`` times (default 3) by :func:`geomopt.io.read_tets` /
:func:`geomopt.io.read_mesh`, by ``meshio.read`` and, for surfaces, by
``trimesh.load(..., process=False)``; the table gives the median seconds and geomopt's ratio
to the fastest other reader.  The readers do not all do the same work: geomopt checks every
count, index and number and welds STL corners; meshio and trimesh return what they tokenize
(trimesh's STL keeps 3 corners per triangle).  Timings on a shared machine are noisy: the
load average is printed beside the table.

    python benchmarks/read_speed.py                  # all formats, 10^6 elements
    python benchmarks/read_speed.py --size 0.1 --formats .vtu .ply-bin   # a tenth, two files
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def tet_grid(n, rng):
    """A jittered cube grid of ``n^3`` cells, 6 tets each: ``(P ((n+1)^3, 3), T (6 n^3, 4))``."""
    xs = np.linspace(0.0, 1.0, n + 1)
    P = np.stack(np.meshgrid(xs, xs, xs, indexing="ij"), -1).reshape(-1, 3)
    P = P + rng.uniform(-0.1, 0.1, P.shape) / n
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    corner = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    tets = []
    for perm in [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]:
        c, path = corner.copy(), [idx[tuple(corner.T)]]
        for axis in perm:
            c = c.copy()
            c[:, axis] += 1
            path.append(idx[tuple(c.T)])
        tets.append(np.stack(path, 1))
    T = np.stack(tets, 1).reshape(-1, 4)
    a, b, c, d = (P[T[:, i]] for i in range(4))
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    T[flip] = T[flip][:, [1, 0, 2, 3]]
    return P, T


def tri_grid(n, rng):
    """A jittered ``n x n`` grid of squares, 2 triangles each: ``(V ((n+1)^2, 3), F (2 n^2, 3))``."""
    xs = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), 0.1 * np.sin(7 * X.ravel()) * np.cos(5 * Y.ravel())], 1)
    V[:, :2] += rng.uniform(-0.1, 0.1, (len(V), 2)) / n
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


@contextlib.contextmanager
def quiet():
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()), \
            contextlib.redirect_stderr(io.StringIO()):
        warnings.simplefilter("ignore")
        yield


def write_files(folder, size, formats):
    """``{label: path}`` of the benchmark files (only ``formats``)."""
    import meshio
    import trimesh

    import geomopt.io as gio

    rng = np.random.default_rng(0)
    files = {}
    P, T = tet_grid(max(2, round((1e6 * size / 6) ** (1 / 3))), rng)
    V, F = tri_grid(max(2, round((1e6 * size / 2) ** 0.5)), rng)
    log(f"tets: {len(P)} points, {len(T)} tets; triangles: {len(V)} vertices, {len(F)} faces")
    tet_mesh = meshio.Mesh(P, [("tetra", T)])
    surface = trimesh.Trimesh(V, F, process=False)
    writers = {
        ".vtu": ("t.vtu", lambda p: gio.write_tets(p, P, T)),
        ".vtk-ascii": ("ta.vtk", lambda p: gio.write_vtk_tets(p, P, T)),
        ".vtk-bin": ("tb.vtk", lambda p: meshio.vtk.write(str(p), tet_mesh, binary=True)),
        ".vtk-bin42": ("tb42.vtk", lambda p: meshio.vtk.write(str(p), tet_mesh, binary=True, fmt_version="4.2")),
        ".msh": ("t.msh", lambda p: gio.write_tets(p, P, T)),
        ".mesh": ("t.mesh", lambda p: gio.write_tets(p, P, T)),
        ".obj": ("s.obj", lambda p: gio.write_obj(p, V, F)),
        ".off": ("s.off", lambda p: p.write_bytes(surface.export(file_type="off").encode())),
        ".ply-bin": ("s.ply", lambda p: p.write_bytes(surface.export(file_type="ply", encoding="binary"))),
        ".ply-ascii": ("sa.ply", lambda p: p.write_bytes(surface.export(file_type="ply", encoding="ascii"))),
        ".stl-bin": ("s.stl", lambda p: p.write_bytes(surface.export(file_type="stl"))),
    }
    for label in formats:
        name, write = writers[label]
        files[label] = folder / name
        if (folder / name).exists():
            continue
        with quiet():
            write(folder / name)
        log(f"wrote {name}: {(folder / name).stat().st_size / 1e6:.1f} MB")
    return files


def timed(read, path, repeat):
    """Median seconds of ``repeat`` reads, or ``None`` when the reader fails."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        try:
            with quiet():
                read(path)
        except Exception as exc:  # noqa: BLE001 -- a reader that cannot read the file gets no time
            log(f"  {getattr(read, '__name__', read)} failed on {path.name}: {type(exc).__name__}: {exc}"[:200])
            return None
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    labels = [".vtu", ".vtk-ascii", ".vtk-bin", ".vtk-bin42", ".msh", ".mesh", ".obj", ".off", ".ply-bin",
              ".ply-ascii", ".stl-bin"]
    parser.add_argument("--size", type=float, default=1.0, help="elements, in millions (default 1)")
    parser.add_argument("--repeat", type=int, default=3, help="reads per reader and file (median; default 3)")
    parser.add_argument("--formats", nargs="+", choices=labels, default=labels)
    parser.add_argument("--folder", type=Path, help="write the files here and keep them (reused when present)")
    args = parser.parse_args(argv)

    import meshio
    import trimesh

    import geomopt.io as gio

    def meshio_read(path):
        return meshio.read(str(path), file_format="gmsh" if path.suffix == ".msh" else None)

    def trimesh_read(path):
        return trimesh.load(str(path), process=False)

    with tempfile.TemporaryDirectory() as tmp:
        folder = args.folder or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        files = write_files(folder, args.size, args.formats)
        rows = []
        for label, path in files.items():
            volume = path.suffix in (".vtu", ".vtk", ".msh", ".mesh")
            ours = timed(gio.read_tets if volume else gio.read_mesh, path, args.repeat)
            theirs = {"meshio": timed(meshio_read, path, args.repeat)}
            if not volume:
                theirs["trimesh"] = timed(trimesh_read, path, args.repeat)
            best = min((t for t in theirs.values() if t is not None), default=None)
            rows.append((label, ours, theirs.get("meshio"), theirs.get("trimesh"),
                         None if ours is None or best is None else ours / best))
            log(f"{label}: geomopt {ours}, others {theirs}")
    load = os.getloadavg()

    def cell(t, fmt="{:.3f}"):
        return "-" if t is None else fmt.format(t)

    print(f"\nmedian of {args.repeat} reads, seconds; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} "
          f"on {os.cpu_count()} CPUs")
    print("| file | geomopt | meshio | trimesh | geomopt / fastest other |")
    print("|---|---|---|---|---|")
    for label, ours, mio, tri, ratio in rows:
        print(f"| {label} | {cell(ours)} | {cell(mio)} | {cell(tri)} | {cell(ratio, '{:.2f}x')} |")


if __name__ == "__main__":
    main()

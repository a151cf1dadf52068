"""Quads and hexahedra (issue 18): untangling families, references, smoothing, evaluation speed.

Usage::

    python benchmarks/quadhex.py families [--sizes 1000,10000,100000]
    python benchmarks/quadhex.py cpp --cpp /path/to/untangle3d_locked [--family noise|squash|bend] [--n 37]
                                     [--repeat 1]
    python benchmarks/quadhex.py gmsh [--n 12]
    python benchmarks/quadhex.py smooth
    python benchmarks/quadhex.py energy [--m 1000000] [--repeat 20]
    python benchmarks/quadhex.py oracle [--m 10000] [--samples 17]
    python benchmarks/quadhex.py agree
    python benchmarks/quadhex.py errors

``families``: every generated tangled quad and hex family (interior rotations, noise, random
interiors, squashed boundaries; hex twists and bends) at about each size, untangled by
:func:`geomopt.untangling.untangle` and certified (:func:`geomopt.mesh.elements.certify_elements`:
quads by their corners, hexahedra inside by Bernstein coefficients), one row each.  ``--start
given`` starts every case from its tangled map (the eps loop's own test; the default ``auto``
starts from the harmonic extension of the boundary when that has fewer inverted corners, which for
a boundary at rest is the rest mesh itself).

``cpp``: a noisy hex block of ``n^3`` hexahedra (37: 50,653; ``--family squash``: its boundary
squashed; ``bend``: a rod of ``n x n x 12 n`` bent by 180 degrees) beside the authors' C++
(Garanzha et al. 2021, ``untangle3d``) on the same input, geomopt from its default start
(``auto``) and from the tangled map the C++ gets (``given``): the C++ takes tetrahedral meshes, so it
gets the 8 corner tetrahedra of every hexahedron -- the same energy (each corner tetrahedron
weighted by its rest volume, theta = 1/2) -- with the boundary vertices locked.  The C++ locks
the vertices of tetrahedron faces without a neighbour, which for overlapping corner
tetrahedra would be every vertex, so it is built with a 6-line patch that reads the locked
vertices from the file named by ``LOCK_FILE`` (not part of geomopt; build outside the
repository)::

    git clone --recursive https://github.com/ssloy/invertible-maps im
    # in im/cpp/untangle3d.cpp, replace `opt.lock_boundary_verts();` by reading LOCK_FILE
    cmake -S im/cpp -B im/build -DCMAKE_BUILD_TYPE=Release && make -C im/build untangle3d

It runs with ``OMP_NUM_THREADS`` = the CPU count (all its threads).  Both results are certified
as hexahedra (inside, not only the corners).

``gmsh``: the same kind of block with Gmsh's own Winslow untangler
(``gmsh.model.mesh.optimize("UntangleMeshGeometry")``, the ``gmsh`` wheel: ``pip install
".[gmsh]"``), nodes on the box's surfaces fixed, geomopt with the boundary fixed.

``smooth``: Winslow smoothing (``geomopt.smooth``) of perturbed structured hex meshes of
non-box shapes: a generated annulus sector and Gmsh-made transfinite meshes (an extruded quarter
annulus and a revolved rectangle; skipped without the wheel): scaled Jacobian figures before and
after.

``energy``: energy + gradient of 10^6 hex corners (125,000 hexahedra) against 10^6 tetrahedra
(the same jitted kernel sees corner simplices), median of ``--repeat`` warm calls.

``oracle``: the exact hex certificate (:func:`geomopt.exact.hexvalid.hex_validity`) on ``--m`` random
hexahedra (the unit cube, vertices moved by noise of random size) against a dense sampling of
``det J`` at ``samples^3`` points: certified valid must be positive at every sample; elements the
sampling misses must carry an exact witness point.

``agree``: energy and gradient of a jittered quad grid (with handles) on the quad path against
the triangle path on its two diagonal triangulations (the four corner triangles), per energy.

``errors``: bad quad / hex files through ``geomopt smooth`` and ``geomopt untangle``: exit
status and the one line printed.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from geomopt.mesh import generators as G  # noqa: E402
from geomopt.mesh.elements import boundary_vertices, certify_elements, corner_simplices  # noqa: E402
from geomopt.mesh.problem import Problem  # noqa: E402
from geomopt.untangling import UntangleOptions, untangle  # noqa: E402


def _families(size):
    """name -> Tangle of about ``size`` elements."""
    q = max(int(round(size ** 0.5)), 4)
    h = max(int(round(size ** (1 / 3))), 4)
    r = max(int(round((size / 12) ** (1 / 3))), 3)  # rods of r x r x 12 r
    Vq, Q = G.quad_mesh(q, q)
    Vh, H = G.hex_mesh(h, h, h)
    return {
        f"quad{q}-rot120": lambda: G.rotated_interior(Vq, Q, 120),
        f"quad{q}-rot300": lambda: G.rotated_interior(Vq, Q, 300),
        f"quad{q}-noise2": lambda: G.noisy_interior(Vq, Q, 2.0, seed=1),
        f"quad{q}-random": lambda: G.random_interior(Vq, Q, seed=1),
        f"quad{q}-squash0.7": lambda: G.squashed_boundary(Vq, Q, 0.7),
        f"hex{h}-rot90": lambda: G.rotated_interior(Vh, H, 90),
        f"hex{h}-rot180": lambda: G.rotated_interior(Vh, H, 180),
        f"hex{h}-noise1": lambda: G.noisy_interior(Vh, H, 1.0, seed=1),
        f"hex{h}-squash0.6": lambda: G.squashed_boundary(Vh, H, 0.6),
        f"rod{r}x{12 * r}-twist0.5": lambda: G.twisted_box(r, 12 * r, 0.5, hexes=True),
        f"rod{r}x{12 * r}-twist1": lambda: G.twisted_box(r, 12 * r, 1.0, hexes=True),
        f"rod{r}x{12 * r}-bend180": lambda: G.bent_box(r, 12 * r, 180.0, hexes=True),
    }


def cmd_families(args):
    rows = []
    for size in args.sizes:
        for name, make in _families(size).items():
            if args.only and not re.search(args.only, name):
                continue
            t = make()
            p = t.problem()
            t0 = time.perf_counter()
            r = untangle(p, t.x0, progress=False, options=UntangleOptions(start=args.start))
            wall = time.perf_counter() - t0
            c = certify_elements(r.x, p.elements)
            row = dict(case=name, elements=len(p.elements), inverted0=t.inverted(), start=r.details.start,
                       success=r.success,
                       certified=c.certified, corner_only=c.corner_only, outer=r.stats.outer_iterations,
                       inner=r.stats.iterations, solve_s=round(r.stats.seconds, 2), wall_s=round(wall, 2),
                       sj_min=round(c.quality.min, 4), sj_mean=round(c.quality.mean, 4),
                       tests={k: v for k, v in c.tests.items() if v})
            rows.append(row)
            print(json.dumps(row), flush=True)
    _table(rows, ["case", "elements", "inverted0", "start", "certified", "outer", "inner", "solve_s", "wall_s", "sj_min",
                  "sj_mean", "tests"])
    bad = [r["case"] for r in rows if not (r["success"] and r["certified"])]
    print(f"\n{len(rows) - len(bad)}/{len(rows)} untangled and certified" + (f"; failed: {bad}" if bad else ""))


def _block(n, scale=1.0, seed=0):
    V, H = G.hex_mesh(n, n, n)
    return V, H, G.noisy_interior(V, H, scale, seed=seed)


def _write_medit_tets(path, P, T):
    with open(path, "w") as fh:
        fh.write(f"MeshVersionFormatted 2\nDimension 3\nVertices\n{len(P)}\n")
        np.savetxt(fh, np.column_stack([P, np.zeros(len(P))]), fmt="%.17g %.17g %.17g %d")
        fh.write(f"Tetrahedra\n{len(T)}\n")
        np.savetxt(fh, np.column_stack([T + 1, np.zeros(len(T), np.int64)]), fmt="%d")
        fh.write("End\n")


def _read_medit_points(path, n):
    lines = Path(path).read_text().split("\n")
    i = next(k for k, s in enumerate(lines) if s.strip() == "Vertices")
    return np.array([[float(v) for v in lines[i + 2 + k].split()[:3]] for k in range(n)])


def _geomopt_run(p, x0, start):
    """untangle with the default solver from ``start`` ("auto": the user's default; "given": the
    tangled map the C++ gets)."""
    t0 = time.perf_counter()
    r = untangle(p, x0, progress=False, options=UntangleOptions(start=start))
    return r, time.perf_counter() - t0


def _cpp_case(family, n):
    """(V, H, tangle) of the ``cpp`` comparison: a noisy block of n^3 hexahedra, a block with a
    squashed boundary, or a rod of n x n x 12 n bent by 180 degrees."""
    if family == "bend":
        t = G.bent_box(n, 12 * n, 180.0, hexes=True)
        return t.rest, t.simplices, t
    V, H = G.hex_mesh(n, n, n)
    return V, H, (G.noisy_interior(V, H, 1.0, seed=0) if family == "noise" else G.squashed_boundary(V, H, 0.6))


def cmd_cpp(args):
    V, H, t = _cpp_case(args.family, args.n)
    p = Problem.hexes(V, H, t.fixed, t.x0[t.fixed])
    S = corner_simplices(p.elements)
    threads = str(os.cpu_count())
    with tempfile.TemporaryDirectory() as tmp:
        init, rest, out, lock = (Path(tmp) / f for f in ("init.mesh", "rest.mesh", "out.mesh", "lock.txt"))
        _write_medit_tets(init, t.x0, S)
        _write_medit_tets(rest, V, S)
        np.savetxt(lock, t.fixed, fmt="%d")
        print(f"{args.family} {args.n}: {len(H)} hexahedra ({len(S)} corner tets), {t.inverted()} invalid at start; "
              f"uptime: {os.popen('uptime').read().strip()}", flush=True)
        cold = {start: _geomopt_run(p, t.x0, start)[1] for start in args.starts}
        rows = []
        for rep in range(args.repeat):
            t0 = time.perf_counter()
            try:
                cp = subprocess.run([args.cpp, str(init), str(rest), str(out)], capture_output=True, text=True,
                                    env={**os.environ, "LOCK_FILE": str(lock), "OMP_NUM_THREADS": threads},
                                    timeout=args.cpp_timeout)
            except subprocess.TimeoutExpired as exc:  # reported as not finished (nan seconds, not certified)
                cp = subprocess.CompletedProcess(exc.cmd, -9, "", "")
                out.unlink(missing_ok=True)
            cpp_wall = time.perf_counter() - t0
            m = re.search(r"running time: ([0-9.eE+-]+) s", cp.stderr)
            cpp_solve = float(m.group(1)) if m else float("nan")
            outer = len(re.findall(r"iteration #", cp.stderr))
            xc = _read_medit_points(out, len(V)) if out.exists() else np.full_like(V, np.nan)
            cc = certify_elements(xc, p.elements)
            rows.append(dict(rep=rep, run="C++ untangle3d", solve_s=round(cpp_solve, 2), call_s=round(cpp_wall, 2),
                             cold_s="", outer=outer, inner="", certified=cc.certified,
                             sj_min=round(cc.quality.min, 4), ratio_solve=1.0, ratio_call=1.0))
            print(json.dumps(rows[-1]), flush=True)
            for start in args.starts:
                r, wall = _geomopt_run(p, t.x0, start)
                cg = certify_elements(r.x, p.elements)
                rows.append(dict(rep=rep, run=f"geomopt (start {start} -> {r.details.start})",
                                 solve_s=round(r.stats.seconds, 2), call_s=round(wall, 2),
                                 cold_s=round(cold[start], 2), outer=r.stats.outer_iterations,
                                 inner=r.stats.iterations, certified=cg.certified and r.success,
                                 sj_min=round(cg.quality.min, 4), ratio_solve=round(r.stats.seconds / cpp_solve, 3),
                                 ratio_call=round(wall / cpp_wall, 3)))
                print(json.dumps(rows[-1]), flush=True)
        print(f"uptime after: {os.popen('uptime').read().strip()}")
    _table(rows, list(rows[0]))


def cmd_gmsh(args):
    import gmsh

    V, H, t = _block(args.n)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("block")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        for _, c in gmsh.model.getEntities(1):
            gmsh.model.mesh.setTransfiniteCurve(c, args.n + 1)
        for _, s in gmsh.model.getEntities(2):
            gmsh.model.mesh.setTransfiniteSurface(s)
            gmsh.model.mesh.setRecombine(2, s)
        gmsh.model.mesh.setTransfiniteVolume(1)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        P = coords.reshape(-1, 3)
        # gmsh's nodes are geomopt's grid vertices (same positions, another order): match them
        key = lambda X: np.round(X * args.n).astype(np.int64) @ np.array([1, args.n + 1, (args.n + 1) ** 2])  # noqa: E731
        ours = np.argsort(key(V))
        of_tag = dict(zip(tags.tolist(), ours[np.argsort(np.argsort(key(P)))].tolist()))
        for tag in tags.tolist():
            gmsh.model.mesh.setNode(tag, t.x0[of_tag[tag]].tolist(), [])
        t0, c0 = time.perf_counter(), time.process_time()
        gmsh.model.mesh.optimize("UntangleMeshGeometry")
        g_wall, g_cpu = time.perf_counter() - t0, time.process_time() - c0
        tags, coords, _ = gmsh.model.mesh.getNodes()
        xg = np.empty_like(V)
        xg[[of_tag[x] for x in tags.tolist()]] = coords.reshape(-1, 3)
    finally:
        gmsh.finalize()
    p = Problem.hexes(V, H, t.fixed, t.x0[t.fixed])
    _, cold = _geomopt_run(p, t.x0)
    r, wall = _geomopt_run(p, t.x0)
    cg, cm = certify_elements(r.x, p.elements), certify_elements(xg, p.elements)
    row = dict(hexes=len(H), invalid0=t.inverted(), gmsh_wall_s=round(g_wall, 2), gmsh_cpu_s=round(g_cpu, 2),
               gmsh_certified=cm.certified, gmsh_sj_min=round(cm.quality.min, 4),
               gmsh_boundary_moved=float(np.abs(xg[t.fixed] - t.x0[t.fixed]).max()),
               geomopt_call_s=round(wall, 3), geomopt_cold_s=round(cold, 2), geomopt_certified=cg.certified,
               geomopt_sj_min=round(cg.quality.min, 4), ratio=round(wall / g_wall, 5))
    print(json.dumps(row))
    _table([row], list(row))


def _gmsh_meshes():
    """Structured hex meshes of non-box shapes made by the gmsh wheel: name -> (V, H): a
    quarter annulus extruded, and a rectangle revolved a quarter turn about an axis (a bent
    rectangular pipe), both transfinite and recombined."""
    import gmsh

    out = {}
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        for name in ("quarter-annulus", "revolved"):
            gmsh.clear()  # the OpenCASCADE shapes of the previous model too
            gmsh.model.add(name)
            if name == "quarter-annulus":
                ring = gmsh.model.occ.cut([(2, gmsh.model.occ.addDisk(0, 0, 0, 2, 2))],
                                          [(2, gmsh.model.occ.addDisk(0, 0, 0, 1, 1))])[0]
                face = gmsh.model.occ.intersect(ring, [(2, gmsh.model.occ.addRectangle(0, 0, 0, 3, 3))])[0]
                sweep = lambda f: gmsh.model.occ.extrude(f, 0, 0, 1, numElements=[8], recombine=True)  # noqa: E731
            else:
                face = [(2, gmsh.model.occ.addRectangle(1, 0, 0, 1, 0.6))]
                gmsh.model.occ.rotate(face, 0, 0, 0, 1, 0, 0, np.pi / 2)  # into the xz plane
                sweep = lambda f: gmsh.model.occ.revolve(f, 0, 0, 0, 0, 0, 1, np.pi / 2, numElements=[16],  # noqa: E731
                                                         recombine=True)
            gmsh.model.occ.synchronize()
            for _, c in gmsh.model.getEntities(1):
                gmsh.model.mesh.setTransfiniteCurve(c, 13)
            gmsh.model.mesh.setTransfiniteSurface(face[0][1])
            gmsh.model.mesh.setRecombine(2, face[0][1])
            sweep(face)
            gmsh.model.occ.synchronize()
            gmsh.model.mesh.generate(3)
            tags, coords, _ = gmsh.model.mesh.getNodes()
            index = np.zeros(int(tags.max()) + 1, np.int64)
            index[tags.astype(np.int64)] = np.arange(len(tags))
            types, _, nodes = gmsh.model.mesh.getElements(3)
            H = np.concatenate([index[n.astype(np.int64)].reshape(-1, 8) for t_, n in zip(types, nodes) if t_ == 5])
            used = np.unique(H)
            remap = np.full(len(tags), -1)
            remap[used] = np.arange(len(used))
            out[f"gmsh-{name}"] = (coords.reshape(-1, 3)[used], remap[H])
    finally:
        gmsh.finalize()
    return out


def cmd_smooth(args):
    """Structured meshes of non-box shapes are perturbed (valid but poor), then smoothed; a mesh
    with invalid hexahedra would be untangled first (boundary fixed)."""
    from geomopt import smooth

    meshes = {"sector-hex": G.sector_mesh(6, 16, 6)}
    try:
        meshes.update(_gmsh_meshes())
    except ImportError:
        print("gmsh wheel not installed: only the generated mesh (pip install '.[gmsh]')", file=sys.stderr)
    rows = []
    for name, (V, H) in meshes.items():
        p0 = Problem.hexes(V, H, rest="reference")  # orients the cells; V may hold invalid ones
        E = p0.elements
        start = certify_elements(V, E)
        untangled = ""
        if not start.certified:  # Gmsh's subdivided cylinder: untangle first, boundary fixed
            b = p0.boundary_vertices()
            r = untangle(p0.with_fixed(b, V[b]), V, progress=False)
            untangled = (f"{start.invalid} invalid -> {r.certificate.inverted} ({r.stats.outer_iterations} outer, "
                         f"{r.stats.seconds:.1f} s)")
            W = r.x
        else:
            W = G.perturb_mesh(V, E, args.perturb, seed=1)
        r = smooth(W, E)
        d, st = r.details, r.stats
        rows.append(dict(mesh=name, hexes=len(H), untangled=untangled, sj_min_before=round(d.before.min, 4),
                         sj_mean_before=round(d.before.mean, 4), below_0_2_before=d.before.below_0_2,
                         sj_min_after=round(d.after.min, 4), sj_mean_after=round(d.after.mean, 4),
                         below_0_2_after=d.after.below_0_2, held=len(d.held), rounds=st.outer_iterations,
                         certified=d.elements.certified, iterations=st.iterations,
                         solve_s=round(st.seconds + st.setup_seconds, 2)))
        print(json.dumps(rows[-1]), flush=True)
    _table(rows, list(rows[0]))


def cmd_energy(args):
    from geomopt.objective.objective import Objective

    h = round((args.m / 8) ** (1 / 3))
    Vh, H = G.hex_mesh(h, h, h)
    k = round((args.m / 6) ** (1 / 3))
    Vt, T = G.box_mesh(k, k, k)
    rng = np.random.default_rng(0)
    rows = []
    for name, p, V in (("hex corners", Problem.hexes(Vh, H), Vh), ("tets", Problem.tets(Vt, T), Vt)):
        obj = Objective(p, "symmetric_dirichlet")
        params = obj.params()
        x = V + 0.01 / h * rng.standard_normal(V.shape)
        jax.block_until_ready(obj.value_and_grad(x, params))
        times = []
        xd = jax.device_put(x)
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            jax.block_until_ready(obj.value_and_grad(xd, params))
            times.append(time.perf_counter() - t0)
        rows.append(dict(kind=name, simplices=p.n_elements, vertices=p.n_vertices,
                         median_s=round(statistics.median(times), 4), min_s=round(min(times), 4)))
        print(json.dumps(rows[-1]), flush=True)
    _table(rows, list(rows[0]))
    print(f"hex corners / tets: {rows[0]['median_s'] / rows[1]['median_s']:.2f}x (median), "
          f"{rows[0]['min_s'] / rows[1]['min_s']:.2f}x (min); uptime: {os.popen('uptime').read().strip()}")


def cmd_oracle(args):
    from fractions import Fraction

    from geomopt.exact.hexvalid import jacobian_det, hex_validity

    cube = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    rng = np.random.default_rng(args.seed)
    X = (cube[None] + rng.uniform(0.05, 0.6, args.m)[:, None, None] * rng.standard_normal((args.m, 8, 3)))
    X, H = X.reshape(-1, 3), np.arange(8 * args.m).reshape(args.m, 8)
    t0 = time.perf_counter()
    r = hex_validity(X, H)
    cert_s = time.perf_counter() - t0
    g = np.linspace(0, 1, args.samples)
    uvw = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    t0 = time.perf_counter()
    smin = np.concatenate([jacobian_det(X, H[i:i + 200], uvw).min(1) for i in range(0, len(H), 200)])
    sample_s = time.perf_counter() - t0

    def exact_det(P, w):  # det J at the witness, in rationals (the product of three exact derivatives)
        P = [[Fraction(float(c)) for c in p] for p in P]
        u = [Fraction(float(t)) for t in w]
        D = []
        for axis in range(3):
            d = [Fraction(0)] * 3
            for c, (a, b, e) in enumerate(cube.astype(int).tolist()):
                idx = (a, b, e)
                if idx[axis]:
                    wgt = Fraction(1)
                    for k in range(3):
                        if k != axis:
                            wgt *= u[k] if idx[k] else 1 - u[k]
                    lo = list(idx)
                    lo[axis] = 0
                    j = cube.astype(int).tolist().index(lo)
                    for k in range(3):
                        d[k] += wgt * (P[c][k] - P[j][k])
            D.append(d)
        a, b, c = D
        return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))

    missed = np.flatnonzero(~r.valid & (smin > 0))
    witnessed = sum(exact_det(X[H[e]], r.witness[e]) <= 0 for e in np.flatnonzero(~r.valid & r.corner_valid))
    row = dict(hexes=args.m, valid=int(r.valid.sum()), invalid=int((~r.valid).sum()),
               corner_valid=int(r.corner_valid.sum()), corner_only=int((r.corner_valid & ~r.valid).sum()),
               valid_but_sampled_nonpositive=int((r.valid & (smin <= 0)).sum()),
               invalid_missed_by_sampling=len(missed),
               corner_only_with_exact_witness=f"{witnessed}/{int((r.corner_valid & ~r.valid).sum())}",
               tests=r.tests, certificate_s=round(cert_s, 2), sampling_s=round(sample_s, 2),
               samples=args.samples ** 3)
    print(json.dumps(row))
    _table([row], list(row))


def cmd_agree(args):
    from geomopt.objective.objective import Objective

    V, Q = G.quad_mesh(24, 24)
    rng = np.random.default_rng(0)
    inner = (V > 0).all(1) & (V < 1).all(1)
    V[inner] += 0.1 / 24 * rng.standard_normal((inner.sum(), 2))
    b = Problem.quads(V, Q).boundary_vertices()
    x = V + 0.05 / 24 * rng.standard_normal(V.shape)
    quad = Problem.quads(V, Q, b, V[b])
    tris = [Problem.planar(V, np.concatenate([Q[:, [0, 1, 3]], Q[:, [2, 3, 1]]]), b, V[b]),
            Problem.planar(V, np.concatenate([Q[:, [1, 2, 0]], Q[:, [3, 0, 2]]]), b, V[b])]
    rows = []
    for energy in ("symmetric_dirichlet", "winslow", "arap", "mips", "dirichlet", "garanzha"):
        oq = Objective(quad, energy)
        params = oq.params()
        vq, gq = oq.value_and_grad(x, params)
        parts = [Objective(t, energy).value_and_grad(x, params) for t in tris]
        vt = sum(float(v) for v, _ in parts)
        gt = sum(np.asarray(g) for _, g in parts)
        rows.append(dict(energy=energy, quads=len(Q), quad_energy=f"{float(vq):.15g}", triangle_energy=f"{vt:.15g}",
                         rel_energy_diff=f"{abs(float(vq) - vt) / abs(vt):.1e}",
                         rel_grad_diff=f"{np.abs(np.asarray(gq) - gt).max() / np.abs(gt).max():.1e}"))
        print(json.dumps(rows[-1]), flush=True)
    _table(rows, list(rows[0]))


def _bad_inputs(tmp):
    """name -> path of a bad quad / hex input."""
    from geomopt import io

    V, Q = G.quad_mesh(3, 3)
    V3, H = G.hex_mesh(2, 2, 2)
    obj = "".join(f"v {x} {y} 0\n" for x, y in V)
    files = {
        "non-planar quads (.vtk)": (np.column_stack([V, V[:, 0] * V[:, 1]]), Q, "quad"),
        "bow-tie quad (.vtk)": (V, np.concatenate([Q[:1, [0, 1, 3, 2]], Q[1:]]), "quad"),
        "quad listed clockwise among ccw (.vtk)": (V, np.concatenate([Q[:1, ::-1], Q[1:]]), "quad"),
        "hex listed mirrored among others (.vtk)": (V3, np.concatenate([H[:1, [0, 3, 2, 1, 4, 7, 6, 5]], H[1:]]),
                                                     "hexahedron"),
    }
    out = {}
    for name, (P, C, kind) in files.items():
        out[name] = io.write_cells(tmp / f"{len(out)}.vtk", P, C, kind)
    texts = {
        "quad repeating a vertex (.obj)": obj + "".join(f"f {a + 1} {b + 1} {b + 1} {d + 1}\n" for a, b, c, d in Q),
        "triangle among quads (.obj)": obj + "f 1 2 6 5\nf 2 3 7\n",
    }
    for name, text in texts.items():
        out[name] = tmp / f"{len(out)}.obj"
        out[name].write_text(text)
    mixed = io.write_cells(tmp / "mixed.mesh", V3, H, "hexahedron")
    mixed.write_text(mixed.read_text().replace("End", "Tetrahedra\n1\n1 2 3 4 0\nEnd"))
    out["tetrahedron beside hexahedra (.mesh)"] = mixed
    rep = tmp / "rep.vtk"
    io.write_cells(rep, V3, H, "hexahedron")
    first = " ".join(map(str, H[0]))
    again = " ".join(map(str, np.r_[H[0, :3], H[0, 2], H[0, 4:]]))
    rep.write_text(rep.read_text().replace(f"8 {first}\n", f"8 {again}\n", 1))
    out["hexahedron repeating a vertex (.vtk)"] = rep
    case = tmp / "twisted_rest"
    case.mkdir()
    twist = V3.copy()
    top = np.flatnonzero(np.isclose(V3[:, 2], 1.0))
    c = V3[top, :2] - 0.5
    twist[top, :2] = 0.5 - c  # the top turned by 180 degrees: the rest hexahedra fold inside
    io.write_cells(case / "rest.vtk", twist, H, "hexahedron")
    io.write_cells(case / "init.vtk", V3, H, "hexahedron")
    out["LIM-style hex case, rest folded inside"] = case
    return out


def cmd_errors(args):
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, path in _bad_inputs(tmp).items():
            for command in ("smooth", "untangle"):
                if command == "smooth" and path.is_dir():
                    continue
                out = tmp / "out.vtk"
                cp = subprocess.run([sys.executable, "-m", "geomopt", command, str(path), "-o", str(out), "--quiet"],
                                    capture_output=True, text=True, env={**os.environ, "PYTHONPATH": os.getcwd()})
                lines = cp.stderr.strip().splitlines()
                rows.append(dict(input=name, command=command, exit=cp.returncode, lines=len(lines),
                                 written=out.exists(), message=(lines[-1] if lines else "").replace(str(tmp) + "/", "")
                                 .replace("|", "/")[:160]))
                print(json.dumps(rows[-1]), flush=True)
    _table(rows, list(rows[0]))


def _table(rows, cols):
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(str(r.get(c, "")) for c in cols) + " |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("families")
    f.add_argument("--sizes", default="1000,10000,100000", type=lambda s: [int(float(x)) for x in s.split(",")])
    f.add_argument("--only", default=None, help="a regular expression: only the families whose name matches")
    f.add_argument("--start", default="auto", choices=["auto", "given", "harmonic"],
                   help="UntangleOptions.start (default auto: the harmonic extension of the boundary when it "
                        "has fewer inverted corners; given: the tangled map itself, the eps loop's own test)")
    c = sub.add_parser("cpp")
    c.add_argument("--cpp", required=True)
    c.add_argument("--n", type=int, default=37)
    c.add_argument("--family", default="noise", choices=["noise", "squash", "bend"])
    c.add_argument("--cpp-timeout", type=float, default=None, help="seconds after which the C++ is stopped")
    c.add_argument("--starts", default="auto,given", type=lambda s: s.split(","),
                   help="geomopt's UntangleOptions.start values to run (default auto,given)")
    c.add_argument("--repeat", type=int, default=1)
    g = sub.add_parser("gmsh")
    g.add_argument("--n", type=int, default=12)
    s = sub.add_parser("smooth")
    s.add_argument("--perturb", type=float, default=0.4)
    e = sub.add_parser("energy")
    e.add_argument("--m", type=int, default=1_000_000)
    e.add_argument("--repeat", type=int, default=20)
    o = sub.add_parser("oracle")
    o.add_argument("--m", type=int, default=10_000)
    o.add_argument("--samples", type=int, default=17)
    o.add_argument("--seed", type=int, default=0)
    sub.add_parser("agree")
    sub.add_parser("errors")
    args = ap.parse_args()
    {"families": cmd_families, "cpp": cmd_cpp, "gmsh": cmd_gmsh, "smooth": cmd_smooth, "energy": cmd_energy,
     "oracle": cmd_oracle, "agree": cmd_agree, "errors": cmd_errors}[args.cmd](args)


if __name__ == "__main__":
    main()

"""Issue 4 "How we will know": LB kernel speed vs the memory roofline, solver convergence, full bakes.

Usage::

    python benchmarks/bench_lb_issue.py [--repeats 3] [--skip-bakes] [--skip-solvers] [--max-sweeps 20000]

One run prints four tables:

1. STREAM triad ``a = b + s*c`` on float32 arrays of 2^26 elements (256 MB
   each): a numba ``parallel=True`` triad (one pass, 12 bytes moved per
   element, the STREAM convention: write-allocate traffic not counted) and the
   numpy expression (two passes through a temporary; its GB/s counts the same
   12 bytes per element, so it understates the memory traffic). The numba
   number is the bandwidth B used for the roofline.
2. Sweep speed of the fused numba kernel (float32, one plain sweep:
   ``_Operator.sweep(residual=False)``) and of the numpy reference step
   ``_reference_step`` (float64, 19 directions) on a *uniformly occupied*
   grid (rho = 0.5 at every node, so every node collides; the dense-sphere
   numbers of bench_lb.py skip empty rows), for 1 (sun, one channel), 3 (sun,
   RGB) and 57 (19 bases, RGB) right-hand sides; below each, where the layout
   allows it (short rows), "in place (AA pair / 2)": the pair of in-place
   sweeps plain iteration runs between measurements (``_Operator.sweep_pair``),
   per sweep. MLUPS counts node x rhs updates. Roofline: each node x rhs update reads and writes 19 float32
   densities (the issue's model; the kernel actually stores 18), 152 bytes,
   so the bandwidth-bound rate is B / 152 bytes; "% roof" is the kernel's
   fraction of it. Where a full N^3 field does not fit in memory the kernel
   is timed on an (N/4) x N x N slab: same rows (the kernel's SIMD runs are
   rows or blocks of rows within an x-slab, and threads split x), so the per-node rate is the
   same; the table says so. The numpy reference at 128^3 is skipped (a
   64^3 57-rhs step already allocates ~10 GB of float64 temporaries); at 64^3
   with 57 rhs it is timed on a 64 x 64 x 16 slab for the same reason.
3. Steady state of the sun (RGB, 3 rhs) on the 64^3 dense sphere of
   bench_lb.py (rho = 0.9 inside radius 0.4 N, Table 1 g) at sigma_a = 0.1,
   0.01, 0.001 (sigma_s = 1 - sigma_a): sweeps and seconds to relative
   residual 1e-4 and 1e-6 for plain iteration ("iterate") and the
   accelerated solvers ("bicgstab", and "auto", which is what ``foliage lb``
   runs).
4. Wall time of a full relightable bake (``bases="all"``: the 18 Kronecker
   bases x RGB solved, the ambient base as their sum, the never-scattered
   field in one exact pass; ``foliage lb``'s ``run_lb`` including reading
   the stage and writing the layer and VDB) of examples/tree_small.usda at
   resolution 64 and 128. Memory: 72 * 54 bytes per node and field; plain
   iteration holds 2 fields (128: 117 x 119 x 130 nodes -> 7.0 GB per
   field). The bake is skipped, and says so, when 2.3 fields do not fit in
   MemAvailable.

The machine may be shared (2 cores here): the load average is printed.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numba
from numba import njit, prange

from foliage_tools.lighting.lb.collision import Medium, leaf_medium
from foliage_tools.lighting.lb import (
    LBParams,
    LBProblem,
    _Operator,
    _reference_step,
    memory_bytes,
    relighting_boundaries,
    solve,
    sun_boundary,
)
from foliage_tools.pipeline.plan import available_memory

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_lb import SUN, TABLE1_G, dense_sphere, median_seconds  # noqa: E402  (the same test problems and timer)

BYTES_PER_UPDATE = 19 * 4 * 2  # 19 float32 densities read + written per node x rhs update


@njit(parallel=True, cache=True)
def _triad(a, b, c, s):  # pragma: no cover - compiled
    for i in prange(a.size):
        a[i] = b[i] + s * c[i]


def triad_table(repeats: int) -> float:
    n = 1 << 26
    b = np.ones(n, np.float32)
    c = np.full(n, 2.0, np.float32)
    a = np.empty(n, np.float32)
    s = np.float32(3.0)
    print(f"\n1. STREAM triad a = b + s*c, float32, {n} elements ({n * 4 / 2**20:.0f} MiB per array), best of {max(repeats, 5)}")
    rows = []
    for name, fn in (("numba parallel triad", lambda: _triad(a, b, c, s)), ("numpy a[:] = b + s*c", lambda: np.add(b, s * c, out=a))):
        fn()
        best = min(_time(fn) for _ in range(max(repeats, 5)))
        gbs = 12 * n / best / 1e9
        rows.append(gbs)
        print(f"   {name:<26}{best * 1e3:>8.1f} ms {gbs:>8.2f} GB/s (12 bytes/element)")
    assert float(a[123]) == 7.0
    bw = rows[0] * 1e9
    print(f"   roofline for the LB update ({BYTES_PER_UPDATE} bytes per node x rhs): {bw / BYTES_PER_UPDATE / 1e6:.1f} MLUPS")
    return bw


def _time(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


CASES = (
    ("1 (sun, 1 channel)", 1, lambda: (sun_boundary(SUN),)),
    ("3 (sun, RGB)", 3, lambda: (sun_boundary(SUN),)),
    ("57 (19 bases, RGB)", 3, relighting_boundaries),
)


def _medium(channels: int) -> Medium:
    m = leaf_medium()
    return Medium(m.sigma_a[:channels], m.sigma_s[:channels], m.g[:channels])


def kernel_table(repeats: int, bw: float) -> None:
    print(f"\n2. Sweep speed, uniformly occupied grid (rho = 0.5 everywhere), median of {repeats} after a warm-up")
    print(f"   {'kernel':<34}{'grid timed':<16}{'rhs':>5}{'ms/sweep':>10}{'MLUPS (node x rhs)':>20}{'% roof':>8}")
    roof = bw / BYTES_PER_UPDATE / 1e6
    rng = np.random.default_rng(1)
    for n in (64, 128):
        for _label, C, bounds in CASES:
            K = len(bounds())
            nrhs = C * K
            shape = (n, n, n)
            field = n**3 * 18 * nrhs * 4
            note = ""
            if 2.5 * field > min(available_memory(), 12e9):
                shape = (n // 4, n, n)
                note = " (slab: full field would be %.1f GB)" % (field / 1e9)
            op = _Operator(LBProblem(np.full(shape, 0.5), _medium(C), bounds()), "float32")
            f = rng.uniform(0, 1, op.state_shape).astype(np.float32)
            out = f.copy()
            dt = median_seconds(lambda op=op, f=f, out=out: op.sweep(f, out, residual=False), repeats)
            mlups = op.nodes * nrhs / dt / 1e6
            gs = "x".join(map(str, shape))
            print(f"   {'numba fused sweep, ' + str(n) + '^3':<34}{gs:<16}{nrhs:>5}{dt * 1e3:>10.1f}{mlups:>20.1f}{100 * mlups / roof:>7.0f}%{note}", flush=True)
            if op.in_place:  # what plain iteration runs between measurements: a pair of in-place (AA) sweeps
                op.set_inflow(f)
                dt = median_seconds(lambda op=op, f=f: op.sweep_pair(f), repeats) / 2
                mlups = op.nodes * nrhs / dt / 1e6
                print(f"   {'  in place (AA pair / 2), ' + str(n) + '^3':<34}{gs:<16}{nrhs:>5}{dt * 1e3:>10.1f}{mlups:>20.1f}"
                      f"{100 * mlups / roof:>7.0f}%{note}", flush=True)
            del f, out, op
        if n == 128:
            print("   numpy reference at 128^3: skipped (a 57-rhs step needs tens of GB of float64 temporaries; "
                  "per-node cost is independent of N, see 64^3)")
            continue
        for _label, C, bounds in CASES:
            K = len(bounds())
            nrhs = C * K
            shape = (n, n, n) if nrhs <= 3 else (n, n, n // 4)
            pb = LBProblem(np.full(shape, 0.5), _medium(C), bounds())
            f19 = rng.uniform(0, 1, shape + (19, K, C))
            f19[..., 0, :, :] = 0.0
            dt = median_seconds(lambda f19=f19, pb=pb: _reference_step(f19, pb), 1)
            nodes = int(np.prod(shape))
            gs = "x".join(map(str, shape))
            note = " (slab: memory)" if shape != (n, n, n) else ""
            print(f"   {'numpy reference (f64), ' + str(n) + '^3':<34}{gs:<16}{nrhs:>5}{dt * 1e3:>10.1f}{nodes * nrhs / dt / 1e6:>20.2f}{'-':>8}{note}", flush=True)
            del f19, pb


def solver_table(max_sweeps: int) -> None:
    n = 64
    rho = dense_sphere(n, 0.9)
    print(f"\n3. Steady state of the sun (RGB, 3 rhs), {n}^3 dense sphere (rho 0.9, {np.count_nonzero(rho) / rho.size:.0%} of nodes), "
          f"max {max_sweeps} sweeps")
    tiny = LBProblem(dense_sphere(6, 0.9), Medium((0.01,) * 3, (0.99,) * 3, TABLE1_G), (sun_boundary(SUN),))
    for solver in ("iterate", "bicgstab", "extrapolate"):
        solve(tiny, LBParams(solver=solver))  # compile
    print(f"   {'sigma_a':>8} {'tol':>7}  {'solver':<10}{'ran':<22}{'sweeps':>8}{'seconds':>9}{'residual':>10}  speed-up vs iterate (s)")
    for sigma_a in (0.1, 0.01, 0.001):
        med = Medium(sigma_a=(sigma_a,) * 3, sigma_s=(1 - sigma_a,) * 3, g=TABLE1_G)
        pb = LBProblem(rho, med, (sun_boundary(SUN),))
        for tol in (1e-4, 1e-6):
            base = None
            for solver in ("iterate", "bicgstab", "auto"):
                r = solve(pb, LBParams(solver=solver, tolerance=tol, max_sweeps=max_sweeps))
                base = r.seconds if base is None else base
                conv = "" if r.converged else "  NOT CONVERGED"
                print(f"   {sigma_a:>8g} {tol:>7.0e}  {solver:<10}{r.solver:<22}{r.iterations:>8d}{r.seconds:>9.2f}{r.residual:>10.1e}"
                      f"  {base / r.seconds:>5.1f}x{conv}", flush=True)


def bake_table() -> None:
    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline.lb import LBBakeParams, run_lb

    example = REPO / "examples" / "tree_small.usda"
    print(f"\n4. Full relightable bake (bases=all: 18 bases x RGB solved, ambient = their sum, unscattered in one pass) of {example.name}, run_lb end to end")
    shapes = {64: (60, 61, 66), 128: (117, 119, 130)}
    for res in (64, 128):
        need = memory_bytes(shapes[res], 54)
        avail = available_memory()
        if need > avail:
            print(f"   resolution {res}: SKIPPED, needs ~{need / 1e9:.1f} GB, MemAvailable {avail / 1e9:.1f} GB")
            continue
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            rep = run_lb(example, Path(d) / "lb.usda", LBBakeParams(optics=parse_leaf_optics(None), resolution=res, bases="all"))
            wall = time.perf_counter() - t0
        p = rep.stats["prototypes"][0]
        print(f"   resolution {res}: grid {p['resolution']}, solver {p['solver']}, {p['iterations']} sweeps (full solve), "
              f"residual {p['residual']:.1e}, converged {p['converged']}, {p['mlups']:.0f} MLUPS, "
              f"bake {p['seconds']:.1f} s (density + solve + unscattered pass), wall {wall:.1f} s", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--max-sweeps", type=int, default=20000)
    ap.add_argument("--skip-solvers", action="store_true")
    ap.add_argument("--skip-bakes", action="store_true")
    args = ap.parse_args(argv)
    print(f"bench_lb_issue: numba {numba.__version__}, {numba.get_num_threads()} threads, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.2f}, MemAvailable {available_memory() / 1e9:.1f} GB")
    t0 = time.perf_counter()
    bw = triad_table(args.repeats)
    kernel_table(args.repeats, bw)
    if not args.skip_solvers:
        solver_table(args.max_sweeps)
    if not args.skip_bakes:
        bake_table()
    print(f"\ntotal {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

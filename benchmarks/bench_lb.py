"""Benchmark the lattice-Boltzmann lighting kernel and solvers on a dense sphere.

Usage::

    python benchmarks/bench_lb.py [--n 64] [--density 0.9] [--reference-n 32] [--repeats 5] [--tolerance 1e-6]

Grid N^3 with a sphere of node density ``--density`` (radius 0.4 N, centred;
~27% of the nodes). Two tables:

1. Sweep speed. The fused numba kernel (float32) for 3 right-hand sides (the
   sun, RGB) and 57 (the 19 relighting bases, RGB), in its three modes: plain
   sweep, sweep + residual, and the (I - T) product used by BiCGSTAB; and the
   numpy reference step (float64, 19 directions) on a ``--reference-n`` grid.
   MLUPS = million lattice-node updates per second: "batch" counts a node
   once per sweep whatever the number of right-hand sides (the rate each
   solution advances); "node x rhs" counts every right-hand side (the total
   work rate). Median over ``--repeats`` sweeps after a warm-up (numba
   compilation excluded).
2. Steady state of the sun (RGB, Table 1 phase asymmetries g) at sigma_a =
   0.1, 0.01, 0.001 (sigma_s = 1 - sigma_a) to ``--tolerance``: sweeps and
   seconds of plain iteration, BiCGSTAB, extrapolated iteration and the
   automatic choice, and the largest difference of each field from the plain
   one (relative to the field's maximum; at tolerance 1e-6 this is dominated
   by the plain field's own error, residual / (1 - q)).

The machine may be shared: the load average is printed before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402

from foliage_tools.lighting.lb.collision import Medium, leaf_medium  # noqa: E402
from foliage_tools.lighting.lb import (  # noqa: E402
    LBParams,
    LBProblem,
    _Operator,
    _reference_step,
    relighting_boundaries,
    solve,
    sun_boundary,
)

SUN = (0.3, 0.2, 1.0)
TABLE1_G = (-0.120, 0.091, -0.333)


def dense_sphere(n: int, density: float, radius: float = 0.4) -> np.ndarray:
    x = np.arange(n) - (n - 1) / 2
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return np.where(X**2 + Y**2 + Z**2 < (radius * n) ** 2, density, 0.0)


def median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up (compiles on first use)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def kernel_table(rho: np.ndarray, repeats: int, ref_n: int, density: float) -> None:
    n = rho.shape[0]
    nodes = rho.size
    print(f"\n1. Sweep speed ({n}^3 = {nodes} nodes, sphere {np.count_nonzero(rho) / nodes:.0%} of them; ms per sweep)")
    print(f"{'kernel':<46}{'rhs':>5}{'ms':>10}{'batch MLUPS':>13}{'node x rhs MLUPS':>18}")
    cases = (("sun, RGB", (sun_boundary(SUN),)), ("19 bases, RGB", relighting_boundaries()))
    rng = np.random.default_rng(1)
    for label, bounds in cases:
        op = _Operator(LBProblem(rho, leaf_medium(), bounds), "float32")
        nrhs = op.C * op.K
        f = rng.uniform(0, 1, op.state_shape).astype(np.float32)
        out = f.copy()
        wt = f.copy()
        for mode, fn in (
            ("numba sweep", lambda: op.sweep(f, out, residual=False)),
            ("numba sweep + residual", lambda: op.sweep(f, out, residual=True)),
            ("numba (I - T) v + 2 dots", lambda: op.apply(f, out, wt)),
        ):
            dt = median_seconds(fn, repeats)
            print(f"{mode + ' (' + label + ')':<46}{nrhs:>5}{dt * 1e3:>10.1f}{nodes / dt / 1e6:>13.2f}{nodes * nrhs / dt / 1e6:>18.1f}")
        f = out = wt = op = None  # free the arrays before the next case
    ref_rho = dense_sphere(ref_n, density)
    for label, bounds in cases:
        pb = LBProblem(ref_rho, leaf_medium(), bounds)
        f19 = rng.uniform(0, 1, ref_rho.shape + (19, len(bounds), 3))
        f19[..., 0, :, :] = 0.0
        dt = median_seconds(lambda: _reference_step(f19, pb), max(1, min(repeats, 2)))
        nrhs = 3 * len(bounds)
        name = f"numpy reference, {ref_n}^3 ({label})"
        print(f"{name:<46}{nrhs:>5}{dt * 1e3:>10.1f}{ref_rho.size / dt / 1e6:>13.2f}{ref_rho.size * nrhs / dt / 1e6:>18.1f}")


def solver_table(rho: np.ndarray, tol: float) -> None:
    n = rho.shape[0]
    print(f"\n2. Steady state of the sun (RGB, 3 rhs), {n}^3, tolerance {tol:g} (relative residual of a plain sweep)")
    # compile every solver's kernels first, so the times below are solve times
    tiny = LBProblem(dense_sphere(6, 0.9), Medium((0.01,) * 3, (0.99,) * 3, TABLE1_G), (sun_boundary(SUN),))
    for solver in ("iterate", "bicgstab", "extrapolate"):
        solve(tiny, LBParams(solver=solver))
    print(f"{'sigma_a':>8}  {'solver':<12}{'chosen':<21}{'sweeps':>8}{'seconds':>9}{'residual':>10}{'node x rhs MLUPS':>18}  {'max |u - u_plain| / max u'}")
    for sigma_a in (0.1, 0.01, 0.001):
        med = Medium(sigma_a=(sigma_a,) * 3, sigma_s=(1 - sigma_a,) * 3, g=TABLE1_G)
        pb = LBProblem(rho, med, (sun_boundary(SUN),))
        plain = None
        for solver in ("iterate", "bicgstab", "extrapolate", "auto"):
            r = solve(pb, LBParams(solver=solver, tolerance=tol, max_sweeps=20_000))
            if plain is None:
                plain = r.energy_density
                diff = "-"
            else:
                diff = f"{np.abs(r.energy_density - plain).max() / np.abs(plain).max():.1e}"
            conv = "" if r.converged else " (not converged)"
            print(
                f"{sigma_a:>8g}  {solver:<12}{r.solver:<21}{r.iterations:>8d}{r.seconds:>9.2f}{r.residual:>10.1e}{r.mlups:>18.1f}  {diff}{conv}",
                flush=True,
            )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=64, help="grid edge N (N^3 nodes)")
    ap.add_argument("--density", type=float, default=0.9, help="node density rho inside the sphere")
    ap.add_argument("--reference-n", type=int, default=32, help="grid edge for the numpy reference step")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tolerance", type=float, default=1e-6)
    ap.add_argument("--skip-solvers", action="store_true")
    args = ap.parse_args(argv)
    print(f"bench_lb: numba {numba.__version__}, {numba.get_num_threads()} threads, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    rho = dense_sphere(args.n, args.density)
    t0 = time.perf_counter()
    kernel_table(rho, args.repeats, args.reference_n, args.density)
    if not args.skip_solvers:
        solver_table(rho, args.tolerance)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

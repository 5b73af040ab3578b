"""Benchmark the Monte Carlo reference (``foliage reference``) on a synthetic crown.

Usage::

    python benchmarks/bench_reference.py [--leaves 2000] [--paths 100000 1000000] [--workers 1 2]
                                         [--optics geist2008] [--repeats 3]

The crown is N square leaf cards (2 triangles each, side ``--side``, uniformly
random orientation) with centres uniform in a unit ball, above a 6-sided
wooden trunk; sun at azimuth 45°, elevation 60° (the default of DESIGN.md),
no sky. For each path count and worker count the table gives the median wall
time over ``--repeats`` runs (scene build included, a warm-up run excluded;
the worker counts are interleaved run by run), sun paths per second, the
speed-up over the first worker count, the process CPU time of the median run,
and the reference's own noise estimate. Results are identical for every
worker count (checked). The machine may be shared: ``load1`` is the highest
1-minute load average seen before the row's runs, since other busy processes
cap the attainable speed-up.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from foliage_tools.lighting.optics import parse_leaf_optics  # noqa: E402
from foliage_tools.lighting.reference import ReferenceInputs, ReferenceParams, solve  # noqa: E402


def synthetic_crown(n: int, rng: np.random.Generator, *, side: float, optics) -> ReferenceInputs:
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centres = d * rng.uniform(size=(n, 1)) ** (1.0 / 3.0) + [0.0, 0.0, 1.5]
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u = q[:, :, 0] * (side / 2)
    v = q[:, :, 1] * (side / 2)
    c00, c10, c11, c01 = centres - u - v, centres + u - v, centres + u + v, centres - u + v
    leaves = np.empty((2 * n, 3, 3))
    leaves[0::2] = np.stack([c00, c10, c11], axis=1)
    leaves[1::2] = np.stack([c00, c11, c01], axis=1)
    ang = 2 * np.pi * np.arange(6) / 6
    ring = 0.1 * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(6)])
    bottom, top = ring, ring + [0.0, 0.0, 1.6]
    trunk = []
    for i in range(6):
        j = (i + 1) % 6
        trunk += [[bottom[i], bottom[j], top[j]], [bottom[i], top[j], top[i]]]
    tris = np.concatenate([leaves, np.array(trunk)])
    leaf_id = np.concatenate([np.repeat(np.arange(n), 2), np.full(len(trunk), -1)])
    az, el = math.radians(45.0), math.radians(60.0)
    sun = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
    return ReferenceInputs(tris, leaf_id, np.full(n, side * side), optics, sun)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--leaves", type=int, default=2000)
    ap.add_argument("--side", type=float, default=0.08, help="leaf card side (crown radius 1)")
    ap.add_argument("--paths", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--optics", default="geist2008", help="--leaf-optics preset or values")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    inputs = synthetic_crown(args.leaves, rng, side=args.side, optics=parse_leaf_optics(args.optics))
    solve(inputs, ReferenceParams(paths=20_000, seed=args.seed, workers=1))  # warm-up (library load, page-in)
    print(
        f"crown: {args.leaves} leaf cards ({2 * args.leaves} triangles) + 12 wood triangles, "
        f"optics {args.optics}, cpus {os.cpu_count()}"
    )
    header = (
        f"{'paths':>9} {'workers':>7} {'load1':>5} {'seconds':>8} {'paths/s':>10} "
        f"{'speedup':>7} {'cpu s':>6} {'noise_rel':>9}"
    )
    print(header)
    print("-" * len(header))
    for paths in args.paths:
        # interleave the worker counts (1, 2, 1, 2, ...) so that both see the
        # same background load on a shared machine
        runs: dict[int, list] = {w: [] for w in args.workers}
        loads: dict[int, list] = {w: [] for w in args.workers}
        for _ in range(args.repeats):
            for workers in args.workers:
                loads[workers].append(os.getloadavg()[0])
                c0 = time.process_time()
                res = solve(inputs, ReferenceParams(paths=paths, seed=args.seed, workers=workers))
                runs[workers].append((res.seconds, time.process_time() - c0, res))
        base = None
        reference = None
        for workers in args.workers:
            ordered = sorted(runs[workers], key=lambda r: r[0])
            seconds, cpu, res = ordered[len(ordered) // 2]
            if reference is None:
                reference = res
            elif not all(np.array_equal(getattr(reference, f), getattr(res, f)) for f in ("e_direct", "e_scattered")):
                print("ERROR: results differ between worker counts", file=sys.stderr)
                return 1
            base = base or seconds
            load = max(loads[workers])
            print(
                f"{paths:>9} {workers:>7} {load:>5.2f} {seconds:>8.3f} {paths / seconds:>10.3g} "
                f"{base / seconds:>7.2f} {cpu:>6.2f} {res.noise_rel:>9.4f}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark the voxelization kernels of ``foliage density`` on synthetic crowns.

Usage::

    python benchmarks/bench_density.py [--leaves 10000 100000 1000000] [--resolution 128] [--repeats 3]

Each crown is N square leaf cards (2 triangles each, side ``0.05 * crown_radius``,
uniformly random orientation) with centres uniformly distributed in a sphere.
Both methods are timed after a warm-up call on a tiny input (numba compilation
excluded); the table gives the median wall time over ``--repeats`` calls and
the throughput in triangles per second, plus the area-conservation error of
``area_per_voxel`` (|sum over voxels - sum of triangle areas| / sum of areas).
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

from foliage_tools.geometry.voxelize import area_per_voxel, grid_for_bounds, subgrid_coverage  # noqa: E402

CROWN_RADIUS = 1.0
CARD_SIDE = 0.05 * CROWN_RADIUS


def leaf_cards(n: int, rng: np.random.Generator, *, radius: float = CROWN_RADIUS, side: float = CARD_SIDE) -> np.ndarray:
    """(2n, 3, 3) float64 triangles of n square cards, centres uniform in a ball, uniformly random orientation."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centres = d * radius * rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
    # uniformly random rotation: QR of a Gaussian matrix, sign-fixed (Haar measure)
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u = q[:, :, 0] * (side / 2)
    v = q[:, :, 1] * (side / 2)
    c00, c10, c11, c01 = centres - u - v, centres + u - v, centres + u + v, centres - u + v
    tris = np.empty((2 * n, 3, 3))
    tris[0::2] = np.stack([c00, c10, c11], axis=1)
    tris[1::2] = np.stack([c00, c11, c01], axis=1)
    return tris


def triangle_areas(tris: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)


def median_seconds(fn, repeats: int):
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--leaves", type=int, nargs="+", default=[10_000, 100_000, 1_000_000], help="leaf-card counts N")
    ap.add_argument("--resolution", type=int, default=128, help="voxels along the longest edge of the crown bounds")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls per method and N (median reported)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.resolution < 1 or min(args.leaves) < 1:
        ap.error("--leaves, --resolution and --repeats must be >= 1")

    rng = np.random.default_rng(args.seed)
    print(f"numba {numba.__version__}, {numba.get_num_threads()} thread(s), threading layer after warm-up: ", end="")
    warm = leaf_cards(16, rng)
    wgrid = grid_for_bounds(warm.reshape(-1, 3).min(0), warm.reshape(-1, 3).max(0), resolution=8)
    t0 = time.perf_counter()
    area_per_voxel(warm, wgrid)
    subgrid_coverage(warm, wgrid)
    print(f"{numba.threading_layer()}; compile {time.perf_counter() - t0:.1f} s (excluded); cpus {os.cpu_count()}")
    print(f"crown radius {CROWN_RADIUS}, card side {CARD_SIDE}, resolution {args.resolution}, median of {args.repeats}")
    print()
    header = f"{'leaves':>9} {'triangles':>10} {'grid':>13} {'method':>8} {'median s':>9} {'tri/s':>11} {'area rel. err':>13}"
    print(header)
    print("-" * len(header))
    for n in args.leaves:
        tris = leaf_cards(n, rng)
        pts = tris.reshape(-1, 3)
        grid = grid_for_bounds(pts.min(0), pts.max(0), resolution=args.resolution)
        shape = "x".join(map(str, grid.shape))
        total = float(triangle_areas(tris).sum())
        sec, area = median_seconds(lambda: area_per_voxel(tris, grid), args.repeats)
        err = abs(float(area.sum()) - total) / total
        print(f"{n:>9} {len(tris):>10} {shape:>13} {'area':>8} {sec:>9.3f} {len(tris) / sec:>11.3g} {err:>13.2e}")
        sec, cov = median_seconds(lambda: subgrid_coverage(tris, grid), args.repeats)
        print(f"{n:>9} {len(tris):>10} {shape:>13} {'subgrid':>8} {sec:>9.3f} {len(tris) / sec:>11.3g} {'':>13}")
        del area, cov
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark the exact direct sunlight (``--direct rays``, foliage_tools.lighting.direct) on generated trees.

Usage::

    python benchmarks/bench_direct.py [--leaves 10000 100000 1000000] [--samples 16 64] [--repeats 3]

Trees come from ``examples/make_tree.py`` (lobed crown, 0.1 m cards, wood
included as occluders), built in memory. Per tree and samples-per-leaf the
table gives the median wall time of :func:`direct.solve` over ``--repeats``
runs (the Embree BVH build included, a warm-up run excluded), shadow rays per
second, and the sampling error the solver reports for itself (relative RMS
over leaves, two halves).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))

from make_tree import build_tree  # noqa: E402

from foliage_tools.lighting.direct import DirectInputs, DirectParams, solve  # noqa: E402


def tree_triangles(leaves: int, seed: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(T, 3, 3) triangles (cards as two triangles, wood polygons fanned) and leaf ids (-1 wood)."""
    g = build_tree(leaves=leaves, leaf_size=0.1, crown="lobes", height=6.0 * (leaves / 5000) ** (1 / 3),
                   crown_radius=2.0 * (leaves / 5000) ** (1 / 3), seed=seed)
    c = g.leaf_points.reshape(-1, 4, 3)
    cards = np.concatenate([c[:, [0, 1, 2]], c[:, [0, 2, 3]]])
    card_ids = np.concatenate([np.arange(c.shape[0]), np.arange(c.shape[0])])
    wood = []
    start = 0
    for n in g.wood_face_vertex_counts:
        idx = g.wood_face_vertex_indices[start:start + n]
        for k in range(1, n - 1):
            wood.append(g.wood_points[[idx[0], idx[k], idx[k + 1]]])
        start += n
    tri = np.concatenate([cards, np.array(wood)])
    ids = np.concatenate([card_ids, np.full(len(wood), -1)])
    return tri, ids, c.shape[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--leaves", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    az, el = math.radians(45.0), math.radians(60.0)
    sun = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
    print(f"cpus {os.cpu_count()}; sun az 45 el 60; median of {args.repeats} runs")
    header = f"{'leaves':>9} {'triangles':>10} {'samples':>7} {'seconds':>8} {'Mrays/s':>8} {'noise_rel':>9} {'mean E':>7}"
    print(header)
    print("-" * len(header))
    for n in args.leaves:
        tri, ids, leaves = tree_triangles(n, args.seed)
        inputs = DirectInputs(tri, ids, leaves, sun)
        solve(inputs, DirectParams(2))  # warm-up
        for k in args.samples:
            runs = sorted((solve(inputs, DirectParams(k, seed=r)) for r in range(args.repeats)), key=lambda r: r.seconds)
            res = runs[len(runs) // 2]
            print(f"{leaves:>9} {len(tri):>10} {k:>7} {res.seconds:>8.3f} {res.rays / res.seconds / 1e6:>8.2f} "
                  f"{res.noise_rel:>9.4f} {res.e_direct.mean():>7.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

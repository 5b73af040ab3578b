"""What the Monte Carlo reference's noise costs: seconds to a per-leaf noise target, per sampling scheme.

Usage::

    python benchmarks/bench_reference_noise.py [--scene ../shared/assets/webots_oak/oak.usda] [--paths 4000000]
                                               [--target 0.01] [--big-leaves 1000000] [--big-target 0.05]

For the scene (geist2008 optics, sun az 45 el 60, sun only), each sampling
scheme runs ``--paths`` sun paths; the table gives wall seconds, the three
noise estimates (relative RMS over leaves from two independent halves:
E_scattered, E_direct, total) and the seconds the scheme would need for
``--target`` on E_scattered (noise falls as 1/sqrt(paths): seconds ×
(noise/target)²). The schemes:

* ``beam, analog``: photons from a rectangle over the scene, absorption as
  the Russian roulette (the reference as it was validated against Cycles);
* ``beam, expected value``: the same photons, absorption by its expected value;
* ``surface, split K``: first hits drawn on the surfaces (shadow rays), split
  into K photons, expected-value absorption (K = 2 is the default).

Then the default scheme with ``noise_target = --target`` (what
``foliage reference --noise`` does): seconds and paths actually traced.
``--big-leaves``: a generated tree of that many leaves (examples/make_tree.py,
lobed crown), a ``--paths`` run of the default scheme, and the paths and
seconds that ``--big-target`` would take by the same scaling (0 skips it).
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
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_direct import tree_triangles  # noqa: E402

from foliage_tools.geometry.sun import direction_from_angles  # noqa: E402
from foliage_tools.lighting import reference as R  # noqa: E402
from foliage_tools.lighting.optics import parse_leaf_optics  # noqa: E402
from foliage_tools.pipeline.world import assemble  # noqa: E402
from foliage_tools.scene.read import read_scene  # noqa: E402

SCHEMES = {
    "beam, analog": dict(sun_sampling="beam", survival_weight=2.0),
    "beam, expected value": dict(sun_sampling="beam"),
    "surface, split 1": dict(split=1),
    "surface, split 2 (default)": dict(split=2),
    "surface, split 4": dict(split=4),
}


def scene_inputs(path: Path, optics) -> R.ReferenceInputs:
    scene, _ = read_scene(path)
    w = assemble(scene)
    sun = direction_from_angles(45.0, 60.0, scene.up_axis)
    return R.ReferenceInputs(w.triangles, w.leaf_of_triangle, w.leaf_area, optics, sun, up=scene.up)


def row(name: str, res: R.ReferenceResult, target: float) -> str:
    predicted = res.seconds * (res.noise_rel / target) ** 2
    return (f"{name:<28} {res.paths:>11,} {res.seconds:>8.2f} {res.noise_rel:>8.4f} {res.noise_rel_direct:>8.4f} "
            f"{res.noise_rel_total:>8.4f} {predicted:>10.1f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=ROOT.parent / "shared" / "assets" / "webots_oak" / "oak.usda")
    ap.add_argument("--paths", type=int, default=4_000_000)
    ap.add_argument("--target", type=float, default=0.01)
    ap.add_argument("--max-paths", type=int, default=400_000_000, help="cap of the --target run")
    ap.add_argument("--big-leaves", type=int, default=1_000_000)
    ap.add_argument("--big-target", type=float, default=0.05)
    args = ap.parse_args(argv)
    optics = parse_leaf_optics("geist2008")
    inputs = scene_inputs(args.scene, optics)
    R.solve(inputs, R.ReferenceParams(paths=100_000))  # warm-up (numba, page-in)
    print(f"{args.scene.name}: {inputs.n_leaves} leaves, {len(inputs.triangles)} triangles, cpus {os.cpu_count()}, "
          f"load1 {os.getloadavg()[0]:.2f}")
    header = (f"{'scheme':<28} {'paths':>11} {'seconds':>8} {'E_scat':>8} {'E_dir':>8} {'total':>8} "
              f"{'s to ' + format(args.target, 'g'):>10}")
    print(header)
    print("-" * len(header))
    for name, kw in SCHEMES.items():
        print(row(name, R.solve(inputs, R.ReferenceParams(paths=args.paths, seed=0, **kw)), args.target), flush=True)
    res = R.solve(inputs, R.ReferenceParams(paths=args.max_paths, seed=0, noise_target=args.target))
    print(row(f"default, --noise {args.target:g}", res, args.target), flush=True)
    if args.big_leaves:
        tri, ids, n = tree_triangles(args.big_leaves, 1)
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        leaf_area = np.bincount(ids[ids >= 0], weights=area[ids >= 0], minlength=n)
        az, el = math.radians(45.0), math.radians(60.0)
        sun = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
        big = R.ReferenceInputs(tri, ids, leaf_area, optics, sun)
        res = R.solve(big, R.ReferenceParams(paths=args.paths, seed=0))
        need = res.paths * (res.noise_rel / args.big_target) ** 2
        print(f"generated tree, {n:,} leaves: {res.paths:,} paths in {res.seconds:.1f} s give E_scattered noise "
              f"{res.noise_rel:.3f}; {args.big_target:g} needs about {need / 1e6:,.0f}M paths, "
              f"{res.seconds * need / res.paths:,.0f} s at this rate")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

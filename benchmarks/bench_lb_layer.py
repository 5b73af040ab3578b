"""LB on the issue's uniform layer against the exact plane-parallel solution, and the first-collision sweep cost.

Usage::

    python benchmarks/bench_lb_layer.py [--resolution 64] [--half 3.0] [--repeats 7]

1. Accuracy (issue #15). The layer of examples/make_layer.py (10 x 10 x 1.5 m, 30 000 cards, LAI 3,
   tau = 1.5) baked per prototype for r = t = 0.1 and 0.45 (two channels of one bake) under suns at
   30, 60 and 85 degrees, per-leaf E_scattered in five depth bins of the inner region |x|, |y| <
   ``--half`` against ``plane_parallel.solve_slab`` (bi-Lambertian phase), for the defaults of
   ``foliage lb`` and for the paper's setting (geist2008 lattice, geist2008 sun boundary, HG phase).
   The finite layer itself reads 2-5 % below the infinite slab there (the Monte Carlo reference on
   this layer; tests/integration/test_lb_layer.py).
2. Sweep cost on the example tree at ``--resolution`` (sun, RGB): best of ``--repeats`` plain
   sweeps for the geist2008 lattice with the sun boundary, the ordinates lattice with the sun
   boundary, and the ordinates lattice with the first-collision sun (its source is added in the
   sweep).

The machine may be shared: the load average is printed before and after.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))

from foliage_tools.lighting import lb  # noqa: E402
from foliage_tools.lighting.lb.collision import density_from_lad, leaf_medium  # noqa: E402
from foliage_tools.lighting.optics import LeafOptics  # noqa: E402
from foliage_tools.lighting.phase import canopy_bilambertian_phase  # noqa: E402
from foliage_tools.lighting.plane_parallel import solve_slab  # noqa: E402
from foliage_tools.params import DensityParams  # noqa: E402
from foliage_tools.pipeline.density import compute_density  # noqa: E402
from foliage_tools.pipeline.lb import LBBakeParams, bake_prototype  # noqa: E402
from foliage_tools.scene.read import read_scene  # noqa: E402

SETTINGS = {
    "default": {},
    "geist2008": {"lattice": "geist2008", "sun_source": "boundary", "phase": "hg"},
}


def accuracy(resolution: int, half: float) -> None:
    from make_layer import build_layer, write_layer_stage

    with tempfile.TemporaryDirectory() as tmp:
        path = write_layer_stage(Path(tmp) / "layer.usdc", build_layer(seed=1), sun=(0.0, 60.0))
        proto = read_scene(path)[0].prototypes[0]
    optics = LeafOptics((0.1, 0.45, 0.3), (0.1, 0.45, 0.3))
    dens = compute_density(proto, DensityParams(resolution=resolution, method="area"))
    c = proto.leaves.centers
    depth = np.clip(0.5 * 3.0 * (1.5 - c[:, 2]) / 1.5, 0.0, 1.5)
    inner = (np.abs(c[:, 0]) < half) & (np.abs(c[:, 1]) < half)
    bins = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    print(f"E_scattered per depth bin (top first), % off the exact slab, --resolution {resolution}, |x|,|y| < {half} m")
    for name, kw in SETTINGS.items():
        sq = []
        for elevation in (30, 60, 85):
            e = math.radians(elevation)
            sun = np.array([math.cos(e), 0.0, math.sin(e)])
            t0 = time.perf_counter()
            bake = bake_prototype(proto, 0, sun, LBBakeParams(optics=optics, resolution=resolution, **kw), dens)
            dt = time.perf_counter() - t0
            for ch, rt in ((0, 0.1), (1, 0.45)):
                sol = solve_slab(tau=1.5, omega=2 * rt, mu0=sun[2], depths=depth,
                                 phase=canopy_bilambertian_phase(reflectance=rt, transmittance=rt))
                exact = sol.actinic_flux_diffuse / 2
                err = np.array([bake.e_scattered[inner & (bins == k), ch].mean() / exact[inner & (bins == k)].mean() - 1
                                for k in range(5)])
                sq.append(err**2)
                print(f"  {name:9s} {elevation:2d} deg r=t={rt:<4} " + " ".join(f"{100 * x:+6.1f}" for x in err)
                      + f"   ({dt:.1f} s, {bake.result.iterations} sweeps)")
        print(f"  {name:9s} RMS over all bins {100 * math.sqrt(np.mean(sq)):.1f} %")


def sweep_cost(resolution: int, repeats: int) -> None:
    proto = read_scene(ROOT / "examples" / "tree_small.usda")[0].prototypes[0]
    dens = compute_density(proto, DensityParams(resolution=resolution, method="area"))
    rho = density_from_lad(dens.density, dens.grid.voxel_size)
    sun = (0.5, 0.5, 0.7)
    cases = {
        "geist2008 + sun boundary": lb.LBProblem(rho, leaf_medium(), (lb.sun_boundary(sun),), lattice="geist2008"),
        "ordinates + sun boundary": lb.LBProblem(rho, leaf_medium(), (lb.sun_boundary(sun),)),
        "ordinates + first-collision": lb.LBProblem(rho, leaf_medium(), (lb.sun_source(sun),)),
    }
    ops = {k: lb._Operator(p, "float32") for k, p in cases.items()}
    fields = {k: op.unscattered(cases[k]) for k, op in ops.items()}
    best = dict.fromkeys(ops, math.inf)
    for _ in range(repeats):  # interleaved, so a load change hits every case alike
        for k, op in ops.items():
            f = fields[k]
            out = f.copy()
            t0 = time.perf_counter()
            op.sweep(f, out, residual=False)
            best[k] = min(best[k], time.perf_counter() - t0)
    print(f"plain sweep, example tree {'x'.join(map(str, rho.shape))}, sun RGB, best of {repeats}:")
    for k, t in best.items():
        print(f"  {k:28s} {1e3 * t:6.1f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--half", type=float, default=3.0)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    print("load average", os.getloadavg())
    sweep_cost(args.resolution, args.repeats + 1)  # the first round compiles
    accuracy(args.resolution, args.half)
    print("load average", os.getloadavg())


if __name__ == "__main__":
    main()

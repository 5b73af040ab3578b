"""Issue 21: the LB grids on disk as float vs half (``foliage lb --grid-precision``) - file size and the error.

Usage::

    python benchmarks/bench_lb_grid_precision.py [--resolution 64] [--scene examples/tree_small.usda]

The relightable bake (``foliage lb --bases all --gather 0``: lbAmbient + lbBase01..18, RGB) runs
twice through ``run_lb``, with ``grid_precision="float"`` and ``"half"``; both ``.vdb`` files are
read back with ``scene.vdb.read_grid``. Reported, half against float:

* the two files' sizes and their ratio;
* per grid (19 grids x RGB): RMS over the nodes of (half - float) relative to the grid's maximum,
  and the largest node error relative to the grid's maximum (binary16: <= 2^-11 = 4.9e-4 of a
  normal value, so of the maximum too);
* per leaf: E_scattered relit from the read-back bases (``lb.relight``; the never-scattered part is
  the bake's exact one, which is not stored) for the scene's sun and 8 suns over the sphere:
  relative RMS over leaves ``sqrt(sum (x - r)^2 / sum r^2)`` and the largest per-leaf relative error.

Both bakes solve the same problem; the float grids read back are checked to equal the half run's
in-memory fields (so only the disk copy differs). Nothing here is a test: the bounds are in
tests/unit/test_vdb_half.py and tests/integration/test_lb_stage.py.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_lb_storage import leaf_errors  # noqa: E402  (the same error measure as the storage bench)

#: Suns (azimuth, elevation in degrees) relit from the bases besides the scene's own (as bench_lb_storage).
EXTRA_SUNS = ((0, 10), (45, 60), (90, 30), (135, 85), (180, 45), (225, 20), (270, 70), (315, 5))
GRIDS = ["lbAmbient"] + [f"lbBase{k:02d}" for k in range(1, 19)]


def bake(scene: Path, res: int, precision: str, out: Path):
    """``run_lb`` with ``grid_precision``; its first prototype's in-memory result (run_lb returns the report only)."""
    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline import lb as plb

    kept = []
    inner = plb.bake_lb

    def keep(*a, **k):
        got = inner(*a, **k)
        kept.extend(got)
        return got

    plb.bake_lb = keep
    try:
        plb.run_lb(scene, out, plb.LBBakeParams(optics=parse_leaf_optics(None), resolution=res, bases="all", gather=0,
                                                 grid_precision=precision))
    finally:
        plb.bake_lb = inner
    return kept[0]


def read_total(vdb: Path, grid) -> np.ndarray:
    """The 19 grids of ``vdb`` as one (nx, ny, nz, 19, 3) array on the bake's lattice (a grid is read over its active
    bounding box, which may be smaller: placed back by its origin)."""
    from foliage_tools.scene.vdb import read_grid

    out = np.zeros(tuple(grid.shape) + (len(GRIDS), 3), np.float32)
    for k, name in enumerate(GRIDS):
        g = read_grid(vdb, name)
        lo = np.rint((np.asarray(g.origin) - np.asarray(grid.origin)) / grid.voxel_size).astype(int)
        sl = tuple(slice(a, a + n) for a, n in zip(lo, g.values.shape[:3]))
        out[sl + (k,)] = g.values
    return out


def main(argv=None) -> int:
    from foliage_tools.lighting import lb
    from foliage_tools.pipeline.lb import sample_trilinear
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake, sun_in_prototype

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--scene", type=Path, default=REPO / "examples" / "tree_small.usda")
    args = ap.parse_args(argv)
    print(f"bench_lb_grid_precision: {args.scene.name}, lb --bases all --resolution {args.resolution} --gather 0")
    with tempfile.TemporaryDirectory() as d:
        files = {p: Path(d) / f"{p}.lb.vdb" for p in ("float", "half")}
        bakes = {p: bake(args.scene, args.resolution, p, files[p].with_suffix(".usda")) for p in files}
        b = bakes["half"]
        size = {p: files[p].stat().st_size for p in files}
        ref, half = read_total(files["float"], b.grid), read_total(files["half"], b.grid)
    same = np.array_equal(ref, b.total.astype(np.float32))
    print(f"   float grids read back == the half run's in-memory fields: {same}")
    print(f"   .vdb: float {size['float'] / 1e6:.1f} MB, half {size['half'] / 1e6:.1f} MB, ratio {size['float'] / size['half']:.2f}")
    diff, top = (half - ref).reshape(-1, len(GRIDS), 3), np.abs(ref).reshape(-1, len(GRIDS), 3).max(0)
    rms = np.sqrt((diff**2).mean(0)) / top
    worst = np.abs(diff).max(0) / top
    print(f"   per grid (19 x RGB), relative to the grid's max: RMS median {np.median(rms):.2e}, worst {rms.max():.2e}; "
          f"largest node error {worst.max():.2e}")
    _, scene, sun = begin_bake("lb", args.scene, None, None, Silent())
    leaves = scene.prototypes[b.index].leaves.centers
    suns = [("scene", sun_in_prototype(scene, b.index, sun, []))]  # the baked sun, in the prototype's frame
    for az, el in EXTRA_SUNS:
        a, e = np.radians(az), np.radians(el)
        suns.append((f"{az}/{el}", np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])))
    errs = []
    for name, direction in suns:
        un = lb.relight(b.unscattered, direction)
        r = np.maximum(sample_trilinear(lb.scattered_leaf_irradiance(lb.relight(ref, direction), un), b.grid, leaves), 0.0)
        x = np.maximum(sample_trilinear(lb.scattered_leaf_irradiance(lb.relight(half, direction), un), b.grid, leaves), 0.0)
        errs.append((name, *leaf_errors(x, r)))
        print(f"   sun {name:>8}: per-leaf E_scattered rel. RMS {errs[-1][1]:.2e}, max {errs[-1][2]:.2e}")
    print(f"   worst of the {len(errs)} suns: rel. RMS {max(e[1] for e in errs):.2e}, max leaf {max(e[2] for e in errs):.2e}")
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issue 21: the LB relighting grids on disk - float vs half, every node vs the nodes the relighting reads - size and error.

Usage::

    python benchmarks/bench_lb_grid_precision.py [--resolution 64] [--scene examples/tree_small.usda] [--haar]

The relightable bake (``foliage lb --bases all --gather 0``: lbAmbient + lbBase01..18, RGB) runs through ``run_lb``
with ``grid_precision`` ``float`` / ``half`` and ``base_extent`` ``lattice`` / ``leaves``; every ``.vdb`` is read back
with ``scene.vdb.read_grid`` (and ``on_lattice``). Reported against the float lattice file:

* each file's size and the ratio;
* per grid (19 grids x RGB), over the nodes the relighting reads (``geometry.voxelize.stencil_mask`` of the leaves'
  corners and centres, the nodes ``leaves`` keeps): RMS of the difference relative to the grid's maximum, and the
  largest node error (binary16: <= 2^-11 = 4.9e-4 of a normal value, so of the maximum too);
* per leaf: E_scattered relit from the read-back bases (``lb.relight``; the never-scattered part is the bake's exact
  one, which is not stored) for the scene's sun and 8 suns over the sphere: relative RMS over leaves
  ``sqrt(sum (x - r)^2 / sum r^2)`` and the largest per-leaf relative error.

``--haar`` (needs PyWavelets, ``pip install PyWavelets``): steele2010 sec. 4.2's Haar compression for comparison,
2 levels (4^3 blocks) per grid and channel of the float lattice, coefficients below a threshold x the grid's
maximum dropped, the rest stored as a sparse half grid (its file size measured), reconstructed and scored the same
way. Nothing here is a test: the bounds are in tests/unit/test_vdb_half.py and tests/integration/test_lb_stage.py.
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


def bake(scene: Path, res: int, precision: str, out: Path, extent: str = "lattice"):
    """``run_lb`` with ``grid_precision`` and ``base_extent``; its first prototype's in-memory result (run_lb returns
    the report only)."""
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
                                                 grid_precision=precision, base_extent=extent))
    finally:
        plb.bake_lb = inner
    return kept[0]


def read_total(vdb: Path, grid) -> np.ndarray:
    """The 19 grids of ``vdb`` as one (nx, ny, nz, 19, 3) array on the bake's lattice (a grid is read over its active
    bounding box, which may be smaller: placed back by its origin)."""
    from foliage_tools.scene.vdb import place_on_lattice, read_grid

    return np.stack([place_on_lattice(read_grid(vdb, name), grid.shape, grid.origin).values for name in GRIDS], axis=3)


def haar_variants(ref: np.ndarray, thresholds, d: Path):
    """(name, reconstruction, bytes) of steele2010 4.2's Haar compression at each threshold (module docstring)."""
    import pywt

    from foliage_tools.scene.vdb import Grid, write_vdb

    shape = np.asarray(ref.shape[:3])
    pad = [(0, int(p)) for p in (-shape) % 4] + [(0, 0), (0, 0)]
    padded = np.pad(ref, pad)
    for thr in thresholds:
        coefs, recon = np.zeros_like(padded), np.zeros_like(padded)
        for k in range(padded.shape[3]):
            top = float(np.abs(padded[..., k, :]).max())
            for c in range(3):
                arr, slices = pywt.coeffs_to_array(pywt.wavedecn(padded[..., k, c], "haar", level=2, mode="periodization"))
                arr[np.abs(arr) < thr * top] = 0.0
                coefs[..., k, c] = arr
                recon[..., k, c] = pywt.waverecn(pywt.array_to_coeffs(arr, slices, output_format="wavedecn"), "haar",
                                                 mode="periodization")
        path = d / f"haar{thr:g}.vdb"
        write_vdb(path, [Grid(n, coefs[..., k, :], (0.0, 0.0, 0.0), 1.0, half=True) for k, n in enumerate(GRIDS)])
        kept = np.count_nonzero(coefs) / coefs.size
        yield f"haar {thr:g} ({kept:.0%} kept)", recon[: shape[0], : shape[1], : shape[2]], path.stat().st_size


def main(argv=None) -> int:
    from foliage_tools.geometry.voxelize import stencil_mask
    from foliage_tools.lighting import lb
    from foliage_tools.pipeline.lb import sample_trilinear
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake, sun_in_prototype

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--scene", type=Path, default=REPO / "examples" / "tree_small.usda")
    ap.add_argument("--haar", action="store_true", help="also steele2010 4.2's Haar compression (needs PyWavelets)")
    args = ap.parse_args(argv)
    print(f"bench_lb_grid_precision: {args.scene.name}, lb --bases all --resolution {args.resolution} --gather 0")
    variants = [("float", "lattice"), ("half", "lattice"), ("float", "leaves"), ("half", "leaves")]
    _, scene, sun = begin_bake("lb", args.scene, None, None, Silent())
    with tempfile.TemporaryDirectory() as d:
        files = {v: Path(d) / f"{v[0]}-{v[1]}.lb.vdb" for v in variants}
        bakes = {v: bake(args.scene, args.resolution, v[0], files[v].with_suffix(".usda"), v[1]) for v in variants}
        b = bakes[("half", "leaves")]
        read = {v: (read_total(files[v], b.grid), files[v].stat().st_size) for v in variants}
        ref, ref_size = read[("float", "lattice")]
        print(f"   float lattice grids read back == the in-memory fields: {np.array_equal(ref, b.total.astype(np.float32))}")
        proto = scene.prototypes[b.index]
        leaves = proto.leaves.centers
        mask = stencil_mask(b.grid.shape, b.grid, np.concatenate([proto.triangles(leaves=True).reshape(-1, 3), leaves]))
        print(f"   nodes the relighting reads: {mask.mean():.1%} of the {'x'.join(map(str, b.grid.shape))} lattice")
        rows = [(f"{p} {e}", *read[(p, e)]) for p, e in variants]
        if args.haar:
            rows += list(haar_variants(ref, (1e-3, 3e-3, 1e-2, 3e-2), Path(d)))
    suns = [("scene", sun_in_prototype(scene, b.index, sun, []))]  # the baked sun, in the prototype's frame
    for az, el in EXTRA_SUNS:
        a, e = np.radians(az), np.radians(el)
        suns.append((f"{az}/{el}", np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])))
    relit = [np.maximum(sample_trilinear(lb.scattered_leaf_irradiance(lb.relight(ref, s), lb.relight(b.unscattered, s)),
                                         b.grid, leaves), 0.0) for _, s in suns]
    top = np.abs(ref).reshape(-1, len(GRIDS), 3).max(0)
    print("   | storage | MB | ratio | grid RMS / max (median, worst) | largest node error / max | per-leaf rel. RMS, worst sun | worst leaf |")
    for name, values, size in rows:
        diff = (values - ref)[mask].reshape(-1, len(GRIDS), 3)
        rms, worst = np.sqrt((diff**2).mean(0)) / top, np.abs(diff).max(0) / top
        errs = [leaf_errors(np.maximum(sample_trilinear(lb.scattered_leaf_irradiance(lb.relight(values, s), lb.relight(b.unscattered, s)),
                                                        b.grid, leaves), 0.0), r) for (_, s), r in zip(suns, relit)]
        print(f"   | {name} | {size / 1e6:.2f} | {ref_size / size:.2f} | {np.median(rms):.2e}, {rms.max():.2e} | {worst.max():.2e} "
              f"| {max(e[0] for e in errs):.2e} | {max(e[1] for e in errs):.2e} |")
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issue 21: LB density storage fp32 vs fp16 - bake seconds, peak memory and the error fp16 makes.

Usage::

    python benchmarks/bench_lb_storage.py [--resolutions 64 96 128] [--scene examples/tree_small.usda]

For each resolution, the relightable bake (``foliage lb --bases all``: 18 Kronecker bases x RGB
solved, ambient = their sum; with fp16 the bases are solved as beams along the lattice directions; ``run_lb`` end to end: density, solve, never-scattered pass, VDB and
layer written) runs once with ``--storage fp32`` and once with ``fp16``, each in its own process
(so its peak resident memory, ``getrusage`` ``ru_maxrss``, is its own), one after the other. Then
the ``--bases sun`` bake (first-collision sun, 3 rhs) at the first resolution, the same way.

Reported, fp16 against the fp32 solve of the same problem:

* per leaf: E_scattered of the scene's sun (the bake's own lattice value, relit from the bases for
  ``all``), and of 8 further suns spread over the sphere (relit from the same bases, so every base
  takes part): relative RMS over leaves ``sqrt(sum (x - r)^2 / sum r^2)`` (DESIGN.md's error
  measure) and the largest per-leaf relative error |x - r| / r over leaves with r > 0;
* per grid (lbBase01..18, lbAmbient; RGB): relative RMS over the nodes, and the largest node
  error relative to the grid's maximum;
* the fp32 field's dynamic range: the smallest per-leaf E_scattered, and the fraction of
  occupied-node energy densities below 2^-22 (where binary16 with the scale 2^8 of
  ``lighting.storage`` goes subnormal).

The seconds are one run each (a 128^3 bake is ~2 minutes here); the machine may be shared, so the
load average is printed before and after. Nothing here is a test: the bounds are in
tests/unit/test_lb_storage.py.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

#: Suns (azimuth, elevation in degrees) relit from the bases besides the scene's own.
EXTRA_SUNS = ((0, 10), (45, 60), (90, 30), (135, 85), (180, 45), (225, 20), (270, 70), (315, 5))


def worker(scene: Path, res: int, bases: str, storage: str, out_npz: Path) -> None:
    """One bake in this process; per-leaf and per-grid values to ``out_npz``, timings as JSON on stdout."""
    from foliage_tools.lighting import lb
    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline import lb as plb
    from foliage_tools.scene.read import read_scene

    kept = []
    inner = plb.bake_lb

    def keep(*a, **k):  # the bake's per-prototype results (run_lb itself returns only the report)
        out = inner(*a, **k)
        kept.extend(out)
        return out

    plb.bake_lb = keep
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        rep = plb.run_lb(scene, Path(d) / "lb.usda", plb.LBBakeParams(optics=parse_leaf_optics(None), resolution=res, bases=bases,
                                                                       storage=storage))
        wall = time.perf_counter() - t0
    b = kept[0]
    proto = read_scene(scene)[0].prototypes[b.index]
    arrays = {"e_scattered": b.e_scattered}
    if bases == "all":
        for n, (az, el) in enumerate(EXTRA_SUNS):
            a, e = np.radians(az), np.radians(el)
            d = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])  # toward the sun, prototype frame
            field = lb.scattered_leaf_irradiance(lb.relight(b.total, d), lb.relight(b.unscattered, d))
            arrays[f"sun{n}"] = np.maximum(plb.sample_trilinear(field, b.grid, proto.leaves.centers), 0.0)
        arrays["total"] = b.total  # (nx, ny, nz, 19, 3) float32
    np.savez(out_npz, **arrays)
    p = rep.stats["prototypes"][0]
    print(json.dumps({"wall": wall, "bake": p["seconds"], "solver": p["solver"], "iterations": p["iterations"],
                      "residual": p["residual"], "converged": p["converged"], "grid": p["resolution"], "mlups": p["mlups"],
                      "maxrss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9}))


def run_worker(scene: Path, res: int, bases: str, storage: str, out_npz: Path) -> dict:
    cmd = [sys.executable, __file__, "--worker", str(scene), str(res), bases, storage, str(out_npz)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"worker {res} {bases} {storage} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def leaf_errors(x: np.ndarray, r: np.ndarray) -> tuple[float, float]:
    """(relative RMS over leaves, largest per-leaf relative error where r > 0), over all channels."""
    rms = float(np.sqrt(np.sum((x - r) ** 2) / np.sum(r**2)))
    pos = r > 0
    return rms, float(np.max(np.abs(x - r)[pos] / r[pos]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolutions", type=int, nargs="+", default=[64, 96, 128])
    ap.add_argument("--scene", type=Path, default=REPO / "examples" / "tree_small.usda")
    ap.add_argument("--worker", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        scene, res, bases, storage, out = args.worker
        worker(Path(scene), int(res), bases, storage, Path(out))
        return 0
    print(f"bench_lb_storage: {args.scene.name}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    rows = []
    with tempfile.TemporaryDirectory() as d:
        cases = [(r, "all") for r in args.resolutions] + [(args.resolutions[0], "sun")]
        for res, bases in cases:
            got = {}
            for storage in ("fp32", "fp16"):
                npz = Path(d) / f"{res}-{bases}-{storage}.npz"
                got[storage] = (run_worker(args.scene, res, bases, storage, npz), dict(np.load(npz)))
                s = got[storage][0]
                print(f"   {bases} {res}: {storage}: grid {'x'.join(map(str, s['grid']))}, {s['solver']}, {s['iterations']} sweeps, "
                      f"residual {s['residual']:.1e}, wall {s['wall']:.1f} s (bake {s['bake']:.1f} s), {s['mlups']:.0f} MLUPS, "
                      f"peak {s['maxrss_gb']:.2f} GB", flush=True)
            (s32, a32), (s16, a16) = got["fp32"], got["fp16"]
            row = {"res": res, "bases": bases, "fp32": s32, "fp16": s16}
            row["leaf"] = leaf_errors(a16["e_scattered"], a32["e_scattered"])
            row["min_leaf"] = float(a32["e_scattered"].min())
            if bases == "all":
                row["suns"] = [leaf_errors(a16[f"sun{n}"], a32[f"sun{n}"]) for n in range(len(EXTRA_SUNS))]
                t32, t16 = a32["total"], a16["total"]
                diff = (t16 - t32).reshape(-1, 19, 3)
                ref = t32.reshape(-1, 19, 3)
                row["grid_rms"] = np.sqrt((diff**2).sum(0) / (ref**2).sum(0))  # (19, 3)
                row["grid_max"] = np.abs(diff).max(0) / np.abs(ref).max(0)
                u = ref[ref.sum(axis=(1, 2)) > 0]
                row["below"] = float(np.mean(u < 2.0**-22))
            rows.append(row)
            del got
    print("\nfp16 vs fp32 storage (one run each; peak = the bake process's max resident set)")
    print(f"   {'bake':<10}{'fp32 s':>8}{'fp16 s':>8}{'ratio':>7}{'fp32 GB':>9}{'fp16 GB':>9}{'ratio':>7}{'sweeps 32/16':>14}"
          f"{'leaf rms':>10}{'leaf max':>10}{'9 suns rms (max)':>20}{'grid rms (max)':>19}{'grid max':>10}")
    for r in rows:
        a, b = r["fp32"], r["fp16"]
        suns = f"{max(e[0] for e in r['suns']):.2e} ({max(e[1] for e in r['suns']):.1e})" if "suns" in r else "-"
        grid = f"{np.median(r['grid_rms']):.1e} ({r['grid_rms'].max():.1e})" if "grid_rms" in r else "-"
        gmax = f"{r['grid_max'].max():.1e}" if "grid_max" in r else "-"
        print(f"   {r['bases'] + ' ' + str(r['res']):<10}{a['wall']:>8.1f}{b['wall']:>8.1f}{a['wall'] / b['wall']:>7.2f}"
              f"{a['maxrss_gb']:>9.2f}{b['maxrss_gb']:>9.2f}{a['maxrss_gb'] / b['maxrss_gb']:>7.2f}"
              f"{str(a['iterations']) + '/' + str(b['iterations']):>14}{r['leaf'][0]:>10.2e}{r['leaf'][1]:>10.1e}{suns:>20}{grid:>19}{gmax:>10}")
    for r in rows:
        extra = f", occupied-node densities below 2^-22: {100 * r['below']:.3f} %" if "below" in r else ""
        print(f"   {r['bases']} {r['res']}: smallest per-leaf E_scattered (fp32) {r['min_leaf']:.2e}{extra}")
    print("   (leaf rms / max: the scene's sun; 9 suns: the worst of the scene's and the 8 relit suns; grid rms: median "
          "(worst) over the 19 grids x RGB; grid max: worst node error / grid max)")
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

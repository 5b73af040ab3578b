"""Issue #16's forest at scale: a 100 x 100 stand of three prototypes, baked end to end, and `plan` of a million.

Writes three procedural trees (examples/make_tree.py: 5 000, 10 000 and 20 000 leaf cards), a stand of
N x N point instances of them with touching crowns (examples/make_forest.py --stand N), runs ``foliage bake``
on it in a child process and prints the seconds of every stage (from its --json report) and the child's peak
resident memory; traces the Monte Carlo reference through the placed stand and prints each method's error per
instance against it; then times ``foliage plan`` on a 1000 x 1000 stand of the same trees.

Usage::

    python benchmarks/bench_forest.py [--side 100] [--plan-side 1000] [--paths 64000000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable
TREES = (("t5k", ["--leaves", "5000", "--seed", "11"]),
         ("t10k", ["--leaves", "10000", "--crown", "cone", "--height", "8", "--seed", "12"]),
         ("t20k", ["--leaves", "20000", "--crown", "lobes", "--height", "7", "--crown-radius", "2.4", "--seed", "13"]))


def _run(args: list[str]) -> tuple[float, subprocess.CompletedProcess]:
    t = time.perf_counter()
    r = subprocess.run(args, capture_output=True, text=True)
    return time.perf_counter() - t, r


def _instance_light(layer: Path, method: str) -> dict[str, np.ndarray]:
    """The instancer's per-instance means (green channel) of a baked layer."""
    from pxr import UsdGeom

    from foliage_tools.scene.read import open_stage

    stage = open_stage(layer)
    instancer = next(p for p in stage.Traverse() if p.IsA(UsdGeom.PointInstancer))
    pv = UsdGeom.PrimvarsAPI(instancer)
    d, s = (np.asarray(pv.GetPrimvar(f"foliage:{method}:{n}").Get(), dtype=np.float64)[:, 1]
            for n in ("instanceDirect", "instanceScattered"))
    return {"direct": d, "scattered": s, "total": d + s}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", type=int, default=100)
    ap.add_argument("--plan-side", type=int, default=1000)
    ap.add_argument("--paths", type=int, default=64_000_000, help="reference sun paths (64M: ~3 %% noise per instance)")
    ap.add_argument("--keep", type=Path, default=None, help="work in this directory and keep it")
    args = ap.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_forest."))
    work.mkdir(parents=True, exist_ok=True)
    trees = []
    for name, opts in TREES:
        out = work / f"{name}.usdc"
        if not out.exists():
            subprocess.run([PY, str(REPO / "examples" / "make_tree.py"), *opts, "--out", str(out)], check=True, capture_output=True)
        trees += ["--tree", str(out)]
    stand = work / f"stand{args.side}.usdc"
    subprocess.run([PY, str(REPO / "examples" / "make_forest.py"), "--stand", str(args.side), *trees, "--out", str(stand)],
                   check=True, capture_output=True)
    foliage = [PY, "-m", "foliage_tools"]
    seconds, r = _run([*foliage, "bake", str(stand), "-o", str(work / "bake"), "--json"])
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6  # kB -> GB, the largest child so far
    if r.returncode not in (0, 1):
        print(r.stderr[-2000:])
        return 1
    report = json.loads(r.stdout)
    stages = report["stats"]["stages"]
    print(f"{args.side ** 2:,} instances of 3 prototypes (5k/10k/20k leaves): foliage bake {seconds:.0f} s, peak {peak:.2f} GB, "
          f"exit {r.returncode}")
    for name, st in stages.items():
        peak_gb = st.get("peak_rss_bytes") and st["peak_rss_bytes"] / 1e9
        print(f"  {name:<8} {st['seconds']:7.1f} s, peak so far {peak_gb:.2f} GB")
    print(f"  (the exact direct light is traced once before the stages: {report['stats']['direct']['seconds']:.1f} s; the "
          "forest lattice runs in the first stage that needs it, smax, and is reused)")
    # the ground truth for every instance: the reference through the placed prototypes (nothing copied)
    seconds, r = _run([*foliage, "reference", str(stand), "-o", str(work / "ref.usda"), "--paths", str(args.paths), "--json"])
    peak_ref = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6
    if r.returncode not in (0, 1):
        print(r.stderr[-2000:])
        return 1
    st = json.loads(r.stdout)["stats"]
    print(f"foliage reference --paths {args.paths:,}: {seconds:.0f} s (peak of all children so far {peak_ref:.2f} GB), "
          f"noise per instance {st['noise_rel_instance']:.3f} (total), per pooled leaf {st['noise_rel']:.3f} (E_scattered)")
    ref = _instance_light(work / "ref.usda", "ref")
    print("per instance against it (relative RMS over instances; mean ratio):")
    for method in ("smax", "spp", "lb"):
        # bake --layer-format auto writes .usdc for 10k instances
        mine = _instance_light(next((work / "bake").glob(f"{stand.stem}.{method}.usd[ac]")), method)
        cells = []
        for part in ("direct", "scattered", "total"):
            a, b = mine[part], ref[part]
            cells.append(f"{part} {np.linalg.norm(a - b) / np.linalg.norm(b):.3f} ({a.mean() / b.mean():.3f})")
        print(f"  {method:<5} " + ", ".join(cells))
    big = work / f"stand{args.plan_side}.usdc"
    subprocess.run([PY, str(REPO / "examples" / "make_forest.py"), "--stand", str(args.plan_side), *trees, "--out", str(big)],
                   check=True, capture_output=True)
    seconds, r = _run([*foliage, "plan", str(big), "--json"])
    st = json.loads(r.stdout)["stats"]
    print(f"foliage plan of {st['instances']:,} instances: {seconds:.1f} s (forest lattice {st['forest']['nodes']:,} nodes, "
          f"traces {st['traced']})")
    if args.keep is None:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

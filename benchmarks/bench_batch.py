"""Benchmark ``foliage batch``: a batch of generated trees on 1 and 2 local workers, then fully cached.

Usage::

    python benchmarks/bench_batch.py [--trees 20] [--leaves 800] [--resolution 32] [--direct-samples 64] [--keep DIR]
    python benchmarks/bench_batch.py --forest --trees 4 --leaves 3000 --resolution 96

With ``--forest`` the trees are the prototypes of one asset instead (a PointInstancer placing each twice), and
``--also K`` adds K of them as assets of their own: a batch where one large asset holds one worker while the
other runs out of work.

Trees come from ``examples/make_tree.py`` (ellipsoid crowns of 0.1 m cards,
one seed per tree, 4-6 m tall), written as USD into a temporary directory.
Each row is one run of the real command (``python -m foliage_tools batch``,
a fresh local Dask cluster each time; its start-up and the workers' imports
are in the wall time): all trees on 1 worker, all trees on 2 workers into a
fresh OUTROOT, then the 2-worker batch again (every tree a cache hit: no
cluster is started). The table gives wall seconds, assets baked and cached,
the median of the per-asset seconds batch.json records, and the speed-up
over 1 worker.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))

from make_tree import build_tree, write_tree  # noqa: E402


def make_trees(where: Path, count: int, leaves: int) -> list[Path]:
    paths = []
    for seed in range(count):
        height = 4.0 + 2.0 * seed / max(1, count - 1)
        g = build_tree(leaves=leaves, leaf_size=0.1, crown="ellipsoid", height=height, crown_radius=height / 3, seed=seed)
        paths.append(write_tree(where / f"tree_{seed:02d}.usda", g))
    return paths


def make_forest(where: Path, trees: list[Path]) -> Path:
    """One asset: a PointInstancer whose prototypes reference ``trees``, each placed twice, 12 m apart."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(where / "forest.usda"))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Forest")
    protos = []
    for k, tree in enumerate(trees):
        proto = UsdGeom.Xform.Define(stage, f"/World/Forest/Prototypes/T{k:02d}")
        proto.GetPrim().GetReferences().AddReference(f"./{tree.relative_to(where).as_posix()}")
        protos.append(proto.GetPath())
    pi.CreatePrototypesRel().SetTargets(protos)
    pi.CreateProtoIndicesAttr([k for k in range(len(trees)) for _ in range(2)])
    pi.CreatePositionsAttr([Gf.Vec3f(12.0 * k, 12.0 * j, 0) for k in range(len(trees)) for j in range(2)])
    stage.GetRootLayer().Save()
    return where / "forest.usda"


def run_batch(trees: list[Path], outroot: Path, workers: int, args) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    cmd = [sys.executable, "-m", "foliage_tools", "batch", *map(str, trees), "-o", str(outroot), "--workers", str(workers),
           "--resolution", str(args.resolution), "--direct-samples", str(args.direct_samples), "--json"]
    started = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - started
    if r.returncode != 0:
        sys.exit(f"foliage batch exited {r.returncode}:\n{r.stderr[-4000:]}")
    report = json.loads(r.stdout)
    entries = report["stats"]["assets"].values()
    baked = [e["seconds"] for e in entries if e["status"] == "baked"]
    return {"wall": wall, "baked": len(baked), "cached": sum(e["status"] == "cached" for e in entries),
            "median": statistics.median(baked) if baked else 0.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trees", type=int, default=20)
    ap.add_argument("--leaves", type=int, default=800, help="leaf cards per tree")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--direct-samples", type=int, default=64)
    ap.add_argument("--keep", type=Path, default=None, help="write trees and outputs here instead of a temporary directory")
    ap.add_argument("--forest", action="store_true", help="one asset of the trees as prototypes (no cached rerun)")
    ap.add_argument("--also", type=int, default=0, help="with --forest: also bake this many of its trees as assets of their own")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        work = args.keep or Path(tmp)
        (work / "trees").mkdir(parents=True, exist_ok=True)
        trees = make_trees(work / "trees", args.trees, args.leaves)
        if args.forest:
            trees = [make_forest(work, trees), *trees[:args.also]]
        rows = [("1 worker", run_batch(trees, work / "out1", 1, args)),
                ("2 workers", run_batch(trees, work / "out2", 2, args))]
        if not args.forest:
            rows.append(("2 workers, rerun (cached)", run_batch(trees, work / "out2", 2, args)))
    what = (f"one forest of {args.trees} prototypes{f' and {args.also} of them alone' if args.also else ''}" if args.forest
            else f"{args.trees} trees")
    print(f"foliage batch: {what} of {args.leaves} leaves, --resolution {args.resolution}, "
          f"--direct-samples {args.direct_samples}, {os.cpu_count()} cores")
    print(f"{'run':<28}{'wall s':>9}{'baked':>7}{'cached':>8}{'median s/asset':>16}{'vs 1 worker':>13}")
    base = rows[0][1]["wall"]
    for name, r in rows:
        print(f"{name:<28}{r['wall']:>9.1f}{r['baked']:>7}{r['cached']:>8}{r['median']:>16.2f}{base / r['wall']:>12.2f}x")


if __name__ == "__main__":
    main()

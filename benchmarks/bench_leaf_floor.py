"""How close can a volume method come to the reference leaf by leaf? The floor of any smooth field of position.

A volume method (LB, SPP, s_max) gives a leaf the light of the medium at its centre: a field of position,
smooth over a voxel. Its per-leaf error cannot fall below how much the *true* E_scattered of a leaf differs
from that of the leaves around it. This measures that floor with the reference itself: each leaf's value is
predicted by the mean of the reference values of its k nearest other leaves (the best a field that knew the
truth everywhere but at the leaf could give, up to its own sampling spread sigma/sqrt(k)), scored with the
bench's relative RMS (bench.metrics.rel_rms, over leaves and channels), beside lb-32 and lb-64.

Usage::

    python benchmarks/bench_leaf_floor.py SCENE [SCENE ...]

geist2008 optics, sun az 45 el 60, the reference to 2 % per-leaf noise (seed 0), as ``foliage bench``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from foliage_tools.bench.metrics import rel_rms  # noqa: E402
from foliage_tools.lighting.optics import parse_leaf_optics  # noqa: E402
from foliage_tools.pipeline.lb import LBBakeParams, bake_lb  # noqa: E402
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference  # noqa: E402
from foliage_tools.pipeline.report import Silent  # noqa: E402
from foliage_tools.pipeline.stage import begin_bake  # noqa: E402

SUN = (45.0, 60.0)
KS = (4, 8, 16, 32)


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    optics = parse_leaf_optics(None)
    print(f"{'scene':<18} {'leaves':>6} {'ref noise':>9} " + " ".join(f"{'floor k=' + str(k):>11}" for k in KS)
          + f" {'lb-32':>7} {'lb-64':>7}")
    for path in argv:
        _, scene, sun = begin_bake("bench", Path(path), None, SUN, Silent())
        if len(scene.instances) != 1:
            print(f"{path}: one tree only (got {len(scene.instances)} instances)")
            continue
        t = time.perf_counter()
        ref = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=64_000_000, noise=0.02, seed=0), Silent()).result
        centres = scene.prototypes[0].leaves.centers
        _, idx = cKDTree(centres).query(centres, max(KS) + 1)
        floors = [rel_rms(ref.e_scattered[idx[:, 1:k + 1]].mean(axis=1), ref.e_scattered) for k in KS]
        lbs = [rel_rms(bake_lb(scene, sun, LBBakeParams(optics=optics, sun=SUN, resolution=r), [], Silent())[0].e_scattered,
                       ref.e_scattered) for r in (32, 64)]
        print(f"{Path(path).stem:<18} {len(centres):>6} {ref.noise_rel:>9.3f} " + " ".join(f"{f:>11.3f}" for f in floors)
              + f" {lbs[0]:>7.3f} {lbs[1]:>7.3f}   ({time.perf_counter() - t:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

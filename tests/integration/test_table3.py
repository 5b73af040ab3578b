"""``foliage spp`` with its defaults in shinya2013's own test (sec. 4.2, Table 3) against the Monte Carlo reference.

The setting of Table 3: one isolated tree, the sun from above, r = t (isotropic phase), albedo 0.95. The metric:
eq. (30), the relative RMS over (depth, thickness) classes of the class-averaged *total* irradiance
(``bench.metrics.binned_rms``; depth and thickness from rays toward the sun, eq. 29). Bound: the paper's own
figure for SPPG, 6.2 %. The reference (2 % noise per leaf, 1.2 % on the total) averages over the ~7 leaves of a
class of the sapling to ~0.5 %, so it cannot carry a score across the bound.

What the command computes (``pipeline.spp.spp_light``): SPPG with its first order marched from the exact direct
light and the final gather (``--gather auto``: 1024 rays per leaf here). Measured
(``benchmarks/bench_sppg_table3.py ... --depths grid --g-variants paper:g16:orders:march,paper:g16:orders:march:gather``,
2026-12-04), tree_small / oak / sapling: 0.010 / 0.017 / 0.041; without the gather 0.013 / 0.038 / 0.085 (the
sapling's leaves, ~0.8 m across, are larger than the march's 0.56 m voxels, so its medium does not homogenise;
README "SPPG in the paper's setting"), so the sapling's case fails without the gather.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.bench.metrics import binned_rms
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bench import depth_thickness
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.spp import SppParams, spp_light
from foliage_tools.pipeline.stage import begin_bake
from tests.conftest import ASSETS, REPO

SUN = (0.0, 90.0)
TABLE3_SPPG = 0.062


def _binned_total(path: Path) -> tuple[float, float]:
    """(the default bake's eq. (30) binned total, the same without the gather)."""
    optics = parse_leaf_optics("0.475,0.475")
    _, scene, sun = begin_bake("spp", path, None, SUN, Silent())
    ref = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=64_000_000, seed=0, noise=0.02), Silent())
    light = spp_light(scene, sun, SppParams(optics=optics, sun=SUN), [], Silent())
    assert light.best_name == "sppg" and light.gathered is not None and light.exact is not None
    world = light.world
    e_direct = np.repeat(light.exact.result.e_direct[:, None], 3, axis=1)
    gathered = light.gathered.result.e_scattered
    volume = from_prototypes(world, {b.index: b.result.sppg.scattered for b in light.bakes})
    assert np.all(np.isfinite(gathered)) and np.all(gathered >= 0)
    total = ref.result.e_direct + ref.result.e_scattered
    depth, thickness = depth_thickness(world, sun.direction)
    return (binned_rms(e_direct + gathered, total, depth, thickness),
            binned_rms(e_direct + volume, total, depth, thickness))


def _asset(rel: str) -> Path:
    path = ASSETS / rel
    if not path.exists():
        pytest.skip(f"third-party assets not present at {ASSETS}")
    return path


def test_the_sapling_within_table3():
    default, volume = _binned_total(_asset("sapling_blendertree/blender_tree.usda"))
    assert default <= TABLE3_SPPG, (default, volume)


@pytest.mark.slow  # the oak's reference takes ~10M paths
@pytest.mark.parametrize("which", ["tree_small", "oak"])
def test_the_crowns_within_table3(which):
    path = REPO / "examples" / "tree_small.usda" if which == "tree_small" else _asset("webots_oak/oak.usda")
    default, volume = _binned_total(path)
    assert default <= TABLE3_SPPG, (default, volume)
    assert volume <= TABLE3_SPPG, (default, volume)  # SPPG without the gather too: measured 0.013 / 0.038

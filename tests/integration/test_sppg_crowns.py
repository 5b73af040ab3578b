"""`foliage spp`'s default bake (SPPG, the first order marched from the exact direct light) per leaf against the Monte
Carlo reference on real crowns, issue #15's bound for a volume method without a gather.

Bound: the issue's, E_scattered relative RMS over leaves <= 25 % (geist2008 optics, sun 45/60, reference at 2 %
noise). The reference's own noise (2 %) adds in quadrature, so it moves the score by < 0.001 at 0.2. Measured
(README "SPPG's first order"): 0.134 / 0.201 / 0.199 on tree_small / the oak / the sapling with the averaged
shifted grids of the march; 0.163 / 0.235 / 0.256 through one grid, so the sapling's case fails without them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.bench.metrics import rel_rms
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_sppg
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.spp import SppParams, bake_spp
from foliage_tools.pipeline.stage import begin_bake
from tests.conftest import ASSETS, REPO

SUN = (45.0, 60.0)


def _per_leaf_error(path: Path) -> float:
    optics = parse_leaf_optics("geist2008")
    _, scene, sun = begin_bake("spp", path, None, SUN, Silent())
    ref = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=64_000_000, seed=0, noise=0.02), Silent())
    exact = bake_direct(scene, sun, DirectChoice(), Silent())
    params = SppParams(optics=optics, sun=SUN)
    assert params.first_order == "march"  # the default bake's first order
    bakes = march_sppg(scene, sun, optics, bake_spp(scene, sun, params, [], Silent()), exact, Silent())
    scattered = from_prototypes(exact.world, {b.index: b.result.sppg.scattered for b in bakes})
    assert np.all(np.isfinite(scattered)) and np.all(scattered >= 0)
    return rel_rms(scattered, ref.result.e_scattered)


def _asset(rel: str) -> Path:
    path = ASSETS / rel
    if not path.exists():
        pytest.skip(f"third-party assets not present at {ASSETS}")
    return path


def test_sppg_per_leaf_on_the_sapling():
    assert _per_leaf_error(_asset("sapling_blendertree/blender_tree.usda")) <= 0.25


@pytest.mark.slow
@pytest.mark.parametrize("where", ["examples/tree_small.usda", "webots_oak/oak.usda"])
def test_sppg_per_leaf_on_the_other_crowns(where):
    path = REPO / where if where.startswith("examples/") else _asset(where)
    assert _per_leaf_error(path) <= 0.25

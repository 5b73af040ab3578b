"""The volume bakes with their first order marched from the exact direct light (`foliage spp`, `lb` and `smax` with
their defaults, no gather) per leaf against the Monte Carlo reference on real crowns: issue #15's bound for a volume
method without a gather.

Bound: the issue's, E_scattered relative RMS over leaves <= 25 % (geist2008 optics, sun 45/60, reference at 2 %
noise). The reference's own noise (2 %) adds in quadrature, so it moves the score by < 0.001 at 0.2. Measured
(README "SPPG's first order", "Averaged shifted grids"), tree_small / the oak / the sapling: spp 0.134 / 0.201 /
0.199, lb 0.132 / 0.202 / 0.192, smax 0.136 / 0.196 / 0.206; through one march grid spp read 0.163 / 0.235 / 0.256,
and before the march lb read 0.257 / 0.280 / 0.290 and smax 0.193 / 0.282 / 0.353, so the sapling's cases fail
without it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.bench.metrics import rel_rms
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_lb, march_sppg
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.lb import LBBakeParams, bake_lb, later_orders, marches
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.smax import SmaxParams, bake_smax
from foliage_tools.pipeline.spp import SppParams, bake_spp
from foliage_tools.pipeline.stage import begin_bake
from tests.conftest import ASSETS, REPO

SUN = (45.0, 60.0)


def _scattered(method: str, scene, sun, optics, exact) -> np.ndarray:
    """(L_world, C) per-leaf E_scattered of ``method``'s default bake, as its command writes it with --gather 0."""
    if method == "spp":
        params = SppParams(optics=optics, sun=SUN)
        assert params.first_order == "march"
        bakes = march_sppg(scene, sun, optics, bake_spp(scene, sun, params, [], Silent()), exact, Silent())
        return from_prototypes(exact.world, {b.index: b.result.sppg.scattered for b in bakes})
    if method == "lb":
        params = LBBakeParams(optics=optics, sun=SUN)
        assert marches(params)
        bakes = bake_lb(scene, sun, params, [], Silent())
        later = {b.index: later_orders(b, scene.prototypes[b.index].leaves.centers) for b in bakes}
        bakes = march_lb(scene, sun, optics, bakes, later, exact, Silent())
        return from_prototypes(exact.world, {b.index: b.e_scattered for b in bakes})
    params = SmaxParams(optics=optics, sun=SUN)
    assert params.scatter == "march"
    bakes = bake_smax(scene, sun, params, [], Silent(), exact=exact)
    return from_prototypes(exact.world, {b.index: b.lighting.e_scattered for b in bakes})


def _per_leaf_errors(path: Path) -> dict[str, float]:
    optics = parse_leaf_optics("geist2008")
    _, scene, sun = begin_bake("spp", path, None, SUN, Silent())
    ref = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=64_000_000, seed=0, noise=0.02), Silent())
    exact = bake_direct(scene, sun, DirectChoice(), Silent())
    out = {}
    for method in ("spp", "lb", "smax"):
        scattered = _scattered(method, scene, sun, optics, exact)
        assert np.all(np.isfinite(scattered)) and np.all(scattered >= 0)
        out[method] = rel_rms(scattered, ref.result.e_scattered)
    return out


def _asset(rel: str) -> Path:
    path = ASSETS / rel
    if not path.exists():
        pytest.skip(f"third-party assets not present at {ASSETS}")
    return path


def test_per_leaf_on_the_sapling():
    errors = _per_leaf_errors(_asset("sapling_blendertree/blender_tree.usda"))
    assert all(e <= 0.25 for e in errors.values()), errors


@pytest.mark.slow
@pytest.mark.parametrize("where", ["examples/tree_small.usda", "webots_oak/oak.usda"])
def test_per_leaf_on_the_other_crowns(where):
    path = REPO / where if where.startswith("examples/") else _asset(where)
    errors = _per_leaf_errors(path)
    assert all(e <= 0.25 for e in errors.values()), errors

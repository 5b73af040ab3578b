"""A stand turned as a whole under a sun turned with it gets the same light per instance (issue #16).

Every instance is lit in its own frame: the prototype's bake sees the sun as the prototype's first instance
does, the exact direct light traces the placed geometry, and only the forest lattice's coarse world grid is
tied to the world axes. A 3 x 3 stand of the example tree (examples/make_forest.py --stand) is written twice,
the second turned 37 degrees about the up axis with every tree, and the sun's azimuth turned by 37 degrees.
Measured: exact direct means equal within 0.05 %, the lone-tree direct factors within 1.2 %, the scattered
means within 1.9 %. ~75 s (four smax bakes of 13 500 leaves): slow.
"""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline import world
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.smax import SmaxParams, run_smax
from foliage_tools.scene.read import open_stage

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "examples"))
SUN, TURN = (30.0, 45.0), 37.0
#: 256 shadow rays per leaf: ~0.1 % sampling error on an instance's mean over 1500 leaves
DIRECT = DirectChoice(samples=256)


def _values(layer: Path) -> tuple[np.ndarray, np.ndarray]:
    from pxr import UsdGeom

    stage = open_stage(layer)
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Grove"))
    return (np.asarray(pv.GetPrimvar("foliage:smax:instanceDirect").Get(), dtype=np.float64)[:, 1],
            np.asarray(pv.GetPrimvar("foliage:smax:instanceScattered").Get(), dtype=np.float64)[:, 1])


@pytest.fixture(scope="module")
def stands(tmp_path_factory):
    from make_forest import ForestLayout, plan_stand, tree_radius_of, write_forest

    d = tmp_path_factory.mktemp("turned")
    tree = d / "tree_small.usda"
    shutil.copy(REPO / "examples" / "tree_small.usda", tree)
    lay = plan_stand(side=3, tree_radius=tree_radius_of(tree), seed=3)
    a = math.radians(TURN)
    rot = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    turned = ForestLayout(lay.tree_positions, lay.tree_angles, lay.tree_scales, lay.grove_positions @ rot.T,
                          lay.grove_angles + TURN, lay.grove_scales)
    optics = parse_leaf_optics(None)
    out = {}
    for name, layout, sun in (("stand", lay, SUN), ("turned", turned, (SUN[0] + TURN, SUN[1]))):
        path = write_forest(d / f"{name}.usda", tree, layout)
        run_smax(path, d / f"{name}.smax.usda", SmaxParams(optics=optics, sun=sun, direct=DIRECT))
        with pytest.MonkeyPatch.context() as mp:  # traced as its lone tree, as a forest above the world budget is
            mp.setattr(world, "WORLD_MAX_TRIANGLES", 0)
            run_smax(path, d / f"{name}.lone.smax.usda", SmaxParams(optics=optics, sun=sun, direct=DIRECT))
        out[name] = d
    return d


@pytest.mark.parametrize("variant", ["smax", "lone.smax"])
def test_a_turned_stand_under_a_turned_sun_gets_the_same_light_per_instance(stands, variant):
    d0, s0 = _values(stands / f"stand.{variant}.usda")
    d1, s1 = _values(stands / f"turned.{variant}.usda")
    print(variant, np.round(d1 / d0 - 1, 4), np.round(s1 / s0 - 1, 4))
    assert d0.shape == (9,)
    if variant == "smax":
        # exact rays through the same geometry: only their sampling differs (~0.1 % per instance mean)
        np.testing.assert_allclose(d1, d0, rtol=0.01)
    # the forest lattice's coarse grid is tied to the world axes (its voxel is 1/16 of a crown): the factors of a
    # turned stand are those of a differently voxelised one
    np.testing.assert_allclose(d1, d0, rtol=0.03)
    np.testing.assert_allclose(s1, s0, rtol=0.03)

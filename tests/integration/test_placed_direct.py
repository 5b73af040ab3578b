"""Each instance's exact direct sunlight traced through the placed forest (lighting.direct.solve_instances).

The independent answer: the per-leaf exact direct light through the copied world (lighting.direct.solve, tested
against closed forms in test_direct.py), averaged over each instance's leaves by area.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.geometry.instanced import InstancedRayScene
from foliage_tools.lighting import direct
from foliage_tools.pipeline.instances import instance_means
from foliage_tools.pipeline.world import assemble, prototype_geometry
from foliage_tools.scene.read import read_scene

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FOREST = EXAMPLES / "forest_small.usda"
SUN = np.array([0.8, -0.5, 0.33])  # a low sun: the neighbours shade each other by up to 75 %


@pytest.fixture(scope="module")
def stand(tmp_path_factory) -> Path:
    """A 4 x 4 stand of the example tree with touching crowns: the neighbours shade each other."""
    import sys

    sys.path.insert(0, str(EXAMPLES))
    from make_forest import plan_stand, tree_radius_of, write_forest

    tree = EXAMPLES / "tree_small.usda"
    return write_forest(tmp_path_factory.mktemp("stand") / "stand.usda", tree,
                        plan_stand(side=4, tree_radius=tree_radius_of(tree), seed=2))


@pytest.mark.parametrize("shear", [False, True])
def test_instance_means_equal_the_copied_worlds(rng, stand, shear):
    scene, _ = read_scene(stand)
    if shear:  # non-uniform placed areas: the points' area weights matter
        m = [i.transform.copy() for i in scene.instances]
        for t in m:
            t[:3, :3] = t[:3, :3] @ (np.eye(3) + 0.3 * rng.uniform(-1, 1, (3, 3)))
        scene = replace(scene, instances=tuple(replace(i, transform=t) for i, t in zip(scene.instances, m)))
    world = assemble(scene)
    flat = direct.solve(direct.DirectInputs(world.triangles, world.leaf_of_triangle, int(world.offsets[-1]), SUN),
                        direct.DirectParams(samples_per_leaf=64, seed=3))
    want = instance_means(world, flat.e_direct)
    tris, leaves = prototype_geometry(scene)
    rays = InstancedRayScene(tris, np.array([i.transform for i in scene.instances]),
                             np.array([i.prototype for i in scene.instances]))
    got = direct.solve_instances(rays, leaves, SUN, samples=4096, seed=4)
    assert 0 < got.noise_rel < 0.02 and got.rays == 4096 * len(scene.instances)
    # both are unbiased: they differ by their sampling errors, the instance means' (estimated by the halves) and
    # the per-leaf run's averaged over ~1500 leaves per instance (far smaller); 4 x the estimate bounds it
    err = np.linalg.norm(got.e_direct - want) / np.linalg.norm(want)
    assert err < 4 * got.noise_rel
    assert np.ptp(want) / want.mean() > 10 * err  # the instances do differ (the shade of the neighbours), resolved


def test_odd_sample_counts_are_refused():
    scene, _ = read_scene(FOREST)
    tris, leaves = prototype_geometry(scene)
    rays = InstancedRayScene(tris, np.array([i.transform for i in scene.instances]), [i.prototype for i in scene.instances])
    with pytest.raises(ValueError, match="even"):
        direct.solve_instances(rays, leaves, SUN, samples=3)


def test_a_bake_of_a_forest_traced_alone_writes_each_instances_traced_direct_mean(tmp_path, stand, monkeypatch):
    from pxr import UsdGeom

    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline import world as world_mod
    from foliage_tools.pipeline.direct import DirectChoice
    from foliage_tools.pipeline.smax import SmaxParams, run_smax
    from foliage_tools.scene.read import open_stage

    scene, _ = read_scene(stand)
    world = assemble(scene)
    sun = (120.0, 20.0)  # azimuth, elevation: a low sun
    from foliage_tools.geometry.sun import choose_sun

    s = choose_sun(scene.lights, scene.up_axis, sun, []).direction
    flat = direct.solve(direct.DirectInputs(world.triangles, world.leaf_of_triangle, int(world.offsets[-1]), s),
                        direct.DirectParams(samples_per_leaf=64, seed=3))
    want = instance_means(world, flat.e_direct)
    monkeypatch.setattr(world_mod, "WORLD_MAX_TRIANGLES", 0)  # the stand is taken as too large to copy
    report = run_smax(stand, tmp_path / "s.smax.usda", SmaxParams(optics=parse_leaf_optics(None), sun=sun,
                                                                  direct=DirectChoice(samples=64)))
    noise = report.stats["direct"]["instances"]["noise_rel"]
    layer = open_stage(tmp_path / "s.smax.usda")
    pv = UsdGeom.PrimvarsAPI(layer.GetPrimAtPath(next(p for p in scene.instancer_sizes)))
    got = np.asarray(pv.GetPrimvar("foliage:smax:instanceDirect").Get(), dtype=np.float64)[:, 1]
    scale = np.asarray(pv.GetPrimvar("foliage:smax:instanceDirectScale").Get(), dtype=np.float64)[:, 1]
    assert np.ptp(want) / want.mean() > 0.3  # a low sun: the stand's shade matters
    # 4096 rays per instance: ~2 % sampling error (test above); 4 x that bounds it, a lone tree's would be off by 30 %+
    assert np.linalg.norm(got - want) / np.linalg.norm(want) < 0.08, noise
    assert np.all(scale < 1.0 + 0.08)  # the stand only shades: each instance at most its lone tree's light

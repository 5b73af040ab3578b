"""World assembly for the ray-traced reference (pipeline.world)."""

import numpy as np

from foliage_tools.pipeline.world import assemble, prototype_means
from foliage_tools.scene.read import read_scene
from tests.helpers.forests import mixed_forest


def test_forest_world_has_every_instance_with_offset_leaf_ids(tmp_path):
    scene, _ = read_scene(mixed_forest(tmp_path))
    world = assemble(scene)
    total = sum(scene.prototypes[i.prototype].leaves.count for i in scene.instances)
    assert world.offsets[-1] == total == world.leaf_area.shape[0]
    # each card is 0.1 x 0.1 and no instance is scaled
    np.testing.assert_allclose(world.leaf_area, 0.01, rtol=1e-5)
    assert set(np.unique(world.leaf_of_triangle)) == set(range(total))
    # instance 2 of the native prototype sits at x = 20: its leaves' triangles are there
    n = [k for k, inst in enumerate(scene.instances) if inst.path == "/World/Tree_2"][0]
    sl = world.instance_slice(n)
    mask = (world.leaf_of_triangle >= sl.start) & (world.leaf_of_triangle < sl.stop)
    assert np.all(np.abs(world.triangles[mask][:, :, 0].mean(axis=1) - 20.0) < 0.5)


def test_prototype_means_average_over_instances(tmp_path):
    scene, _ = read_scene(mixed_forest(tmp_path))
    world = assemble(scene)
    per_leaf = np.arange(world.offsets[-1], dtype=float)
    means = prototype_means(world, per_leaf, len(scene.prototypes), [p.leaves.count for p in scene.prototypes])
    for p, m in enumerate(means):
        expected = np.mean([per_leaf[world.instance_slice(n)] for n, q in enumerate(world.instance_prototype) if q == p], axis=0)
        np.testing.assert_allclose(m, expected)


def test_world_leaf_centres_are_the_prototype_centres_placed_by_each_instance(tmp_path):
    scene, _ = read_scene(mixed_forest(tmp_path))
    world = assemble(scene)
    for n, inst in enumerate(scene.instances):
        c = scene.prototypes[inst.prototype].leaves.centers
        np.testing.assert_allclose(world.leaf_centers[world.instance_slice(n)], (np.c_[c, np.ones(len(c))] @ inst.transform.T)[:, :3])

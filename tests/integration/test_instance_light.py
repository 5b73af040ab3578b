"""Per-instance light on the bundled forest (pipeline.instances): where each value goes, and what it is."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.smax import SmaxParams, run_smax
from foliage_tools.pipeline.stage import begin_bake
from foliage_tools.scene.read import open_stage
from tests.helpers.cli import foliage

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DIRECT = DirectChoice(samples=64)


def _forest_with_a_masked_instance(tmp_path: Path) -> Path:
    for name in ("forest_small.usda", "tree_small.usda"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(tmp_path / "forest_small.usda"))
    UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove")).DeactivateId(4)
    stage.GetRootLayer().Save()
    return tmp_path / "forest_small.usda"


def test_instance_means_land_on_the_instancer_and_the_native_instances(tmp_path):
    from pxr import UsdGeom

    forest = _forest_with_a_masked_instance(tmp_path)
    run_smax(forest, tmp_path / "f.smax.usda", SmaxParams(optics=parse_leaf_optics(None), direct=DIRECT))
    stage = open_stage(tmp_path / "f.smax.usda")
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Grove"))
    grove = pv.GetPrimvar("foliage:smax:instanceDirect")
    assert grove.GetInterpolation() == "vertex"
    grove_d = np.asarray(grove.Get(), dtype=np.float64)
    grove_s = np.asarray(pv.GetPrimvar("foliage:smax:instanceScattered").Get(), dtype=np.float64)
    assert grove_d.shape == grove_s.shape == (12, 3)  # one element per entry of protoIndices
    assert np.all(grove_d[4] == 0) and np.all(grove_s[4] == 0)  # the masked instance
    # independently: the area-weighted mean of the exact per-leaf E_direct over each instance's leaves
    _, scene, sun = begin_bake("smax", forest, None, None, Silent())
    exact = bake_direct(scene, sun, DIRECT, Silent())
    w = exact.world
    means = {}
    for k, inst in enumerate(scene.instances):
        s = w.instance_slice(k)
        means[inst.path] = np.sum(w.leaf_area[s] * exact.result.e_direct[s]) / w.leaf_area[s].sum()
    visible = [i for i in range(12) if i != 4]
    np.testing.assert_allclose(grove_d[visible, 0], [means[f"/World/Grove[{i}]"] for i in visible], rtol=1e-5)
    trees = [p for p in means if p.startswith("/World/Trees/")]
    assert len(trees) == 4
    for path in trees:
        d = np.asarray(stage.GetPrimAtPath(path).GetAttribute("foliage:smax:instanceDirect").Get())
        assert d[0] == np.float32(means[path])
        assert np.all(np.asarray(stage.GetPrimAtPath(path).GetAttribute("foliage:smax:instanceScattered").Get()) > 0)
    # the trees stand apart but not alone: their direct light differs from instance to instance
    vals = np.array(list(means.values()))
    assert vals.std() > 0.003 * vals.mean()
    # the forest lattice's factor (pipeline.forest) scales the lone prototype's scattered light per instance:
    # these trees stand apart (no crowns touch), so their neighbours add a little, never take light away
    scale = np.asarray(pv.GetPrimvar("foliage:smax:instanceScale").Get(), dtype=np.float64)
    assert scale.shape == (12, 3) and np.all(scale[4] == 0)
    assert np.all((scale[visible] > 1.0) & (scale[visible] < 1.3)), scale[visible]
    ratio = grove_s[visible] / scale[visible]  # the prototype's mean scattered light: the same for every instance
    np.testing.assert_allclose(ratio, np.broadcast_to(ratio[0], ratio.shape), rtol=1e-5)
    assert foliage("validate", tmp_path / "f.smax.usda").returncode == 0


def test_the_forest_lattice_is_a_world_space_volume_under_the_default_prim(tmp_path):
    # steele2010 3.2's coarse global lattice, where a renderer reads it: its density holds every instance's leaf
    # area (the deposit conserves it), and its grids are in world coordinates even under a transformed default prim
    from pxr import Gf, Usd, UsdGeom, UsdVol

    from foliage_tools.pipeline.lb import LBBakeParams, run_lb
    from foliage_tools.scene.read import read_scene
    from foliage_tools.scene.vdb import read_grid

    for name in ("forest_small.usda", "tree_small.usda"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    stage = Usd.Stage.Open(str(tmp_path / "forest_small.usda"))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World")).AddTranslateOp().Set(Gf.Vec3d(5.0, -2.0, 0.0))
    stage.GetRootLayer().Save()
    forest = tmp_path / "forest_small.usda"
    # no gather: it traces every instance, and the forest lattice is solved only without one
    run_lb(forest, tmp_path / "f.lb.usda", LBBakeParams(optics=parse_leaf_optics(None), resolution=16, direct=DIRECT, gather=0))
    layer = open_stage(tmp_path / "f.lb.usda")
    vol = UsdVol.Volume(layer.GetPrimAtPath("/World/FoliageForest"))
    assert vol and set(vol.GetFieldPaths()) == {"forestDensity", "forestScattered"}
    world = np.array(UsdGeom.Xformable(vol.GetPrim()).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    np.testing.assert_allclose(world, np.eye(4), atol=1e-12)  # the volume's own frame is the world's
    density = read_grid(tmp_path / "f.lb.forest.vdb", "forestDensity")
    scene, _ = read_scene(forest)
    area = sum(scene.prototypes[i.prototype].leaves.areas.sum() * abs(np.linalg.det(i.transform[:3, :3])) ** (2 / 3)
               for i in scene.instances)
    assert np.sum(density.values, dtype=np.float64) * density.voxel_size**3 == pytest.approx(area, rel=1e-5)
    # the grid covers the instances where they stand, translated with /World
    centres = np.array([i.transform[:3, 3] for i in scene.instances])
    lo = np.asarray(density.origin)
    hi = lo + np.asarray(density.values.shape) * density.voxel_size
    assert np.all(centres[:, :2] > lo[:2]) and np.all(centres[:, :2] < hi[:2])
    scattered = read_grid(tmp_path / "f.lb.forest.vdb", "forestScattered").values
    assert np.all(np.isfinite(scattered)) and scattered.max() > 0

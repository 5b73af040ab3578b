"""Reading stages into Scene: classification, instancing, units, lights, skipped prims."""

import numpy as np
import pytest

from foliage_tools.scene.read import read_scene
from tests.conftest import cards_mesh, write_mesh_stage
from tests.helpers.forests import mixed_forest


def test_oak_has_1831_leaves_and_two_wood_meshes(oak):
    scene, warnings = read_scene(oak)
    assert len(scene.prototypes) == 1 and len(scene.instances) == 1
    proto = scene.prototypes[0]
    assert proto.leaves.count == 1831
    assert sum(len(m.triangles) for m in proto.meshes if m.is_leaf) == 3189
    assert sorted(m.path for m in proto.meshes if not m.is_leaf) == ["/Tree/wood_1", "/Tree/wood_2"]
    assert scene.up_axis == "Z" and scene.meters_per_unit == 1.0
    assert warnings == []


def test_leaf_classification_order(tmp_path):
    c = cards_mesh([(0, 0, 0)])
    path = write_mesh_stage(
        tmp_path / "c.usda",
        {
            "ApiWins": {**c, "isLeaf": False, "api": True},  # FoliageLeafAPI beats isLeaf = false
            "FlagLeaf": {**c, "isLeaf": True},
            "LeafByName": dict(c),  # name contains "Leaf"
            "FoliageFlagFalse": {**c, "isLeaf": False},  # the primvar beats the name
            "Branch": dict(c),  # default: wood
        },
    )
    scene, _ = read_scene(path)
    got = {m.path.split("/")[-1]: (m.is_leaf, m.leaf_reason) for m in scene.prototypes[0].meshes}
    assert got == {
        "ApiWins": (True, "FoliageLeafAPI"),
        "FlagLeaf": (True, "isLeaf primvar"),
        "LeafByName": (True, "name"),
        "FoliageFlagFalse": (False, "isLeaf primvar"),
        "Branch": (False, "default"),
    }


def test_material_name_marks_leaves(tmp_path):
    from pxr import Usd, UsdShade

    path = write_mesh_stage(tmp_path / "m.usda", {"Cards": cards_mesh([(0, 0, 0)])})
    stage = Usd.Stage.Open(str(path))
    mat = UsdShade.Material.Define(stage, "/Tree/Materials/OakLeafMat")
    prim = stage.GetPrimAtPath("/Tree/Cards")
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)
    stage.Save()
    scene, _ = read_scene(path)
    assert scene.prototypes[0].meshes[0].is_leaf
    assert scene.prototypes[0].meshes[0].leaf_reason == "material"


def test_guide_purpose_and_invisible_meshes_are_skipped(tmp_path):
    c = cards_mesh([(0, 0, 0)])
    path = write_mesh_stage(
        tmp_path / "p.usda",
        {"Leaves": {**c, "isLeaf": True}, "GuideLeaves": {**c, "isLeaf": True, "purpose": "guide"}, "HiddenLeaves": {**c, "isLeaf": True, "invisible": True}},
    )
    scene, _ = read_scene(path)
    assert [m.path for m in scene.prototypes[0].meshes] == ["/Tree/Leaves"]


def test_units_and_up_axis_are_recorded(tmp_path):
    path = write_mesh_stage(tmp_path / "cm.usda", {"Leaves": {**cards_mesh([(0, 0, 0)], size=10.0), "isLeaf": True}}, up_axis="Y", meters_per_unit=0.01)
    scene, _ = read_scene(path)
    assert scene.up_axis == "Y" and scene.meters_per_unit == pytest.approx(0.01)
    np.testing.assert_allclose(scene.up, [0, 1, 0])
    # lengths stay in stage units: a 10 cm card is 100 cm²
    assert scene.prototypes[0].leaves.areas[0] == pytest.approx(100.0, rel=1e-6)


def test_instances_share_one_prototype_read(tmp_path):
    scene, _ = read_scene(mixed_forest(tmp_path))
    kinds = sorted((p.kind, p.leaves.count) for p in scene.prototypes)
    # one native prototype for the 3 instanceable references, 2 point-instancer prototypes
    assert kinds == [("instance", 2), ("pointinstancer", 1), ("pointinstancer", 2)]
    native = [i for i, p in enumerate(scene.prototypes) if p.kind == "instance"][0]
    assert len(scene.instances_of(native)) == 3
    assert len([i for i in scene.instances if "Grove" in i.path]) == 4


def test_invisible_point_instances_are_left_out_like_inactive_ones(tmp_path):
    from pxr import Usd, UsdGeom

    path = mixed_forest(tmp_path)
    stage = Usd.Stage.Open(str(path))
    UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove")).InvisIds([3], Usd.TimeCode.Default())  # (no ids: index = id)
    stage.GetRootLayer().Save()
    scene, _ = read_scene(path)
    grove = sorted(i.path for i in scene.instances if "Grove" in i.path)
    assert grove == ["/World/Grove[0]", "/World/Grove[2]", "/World/Grove[4]"]  # 1 inactive, 3 invisible


def test_instance_transforms_place_leaves_in_the_world(tmp_path):
    scene, _ = read_scene(mixed_forest(tmp_path))

    def world_centers(inst):
        c = scene.prototypes[inst.prototype].leaves.centers
        return (np.c_[c, np.ones(len(c))] @ inst.transform.T)[:, :3]

    by_path = {i.path: i for i in scene.instances}
    np.testing.assert_allclose(world_centers(by_path["/World/Tree_2"])[0], [20, 0, 1], atol=1e-6)
    # instance 2 uses prototype A (protoIndices[2] == 0) whose root is translated by 100 in z
    np.testing.assert_allclose(world_centers(by_path["/World/Grove[2]"])[0], [0, 52, 101], atol=1e-6)
    # instance 3 uses prototype B despite the masked instance 1 before it
    np.testing.assert_allclose(world_centers(by_path["/World/Grove[3]"])[0], [0, 53, 2], atol=1e-6)
    assert "/World/Grove[1]" not in by_path


def test_distant_light_direction_points_toward_the_sun(tmp_path):
    from pxr import Usd, UsdLux

    path = write_mesh_stage(tmp_path / "l.usda", {"Leaves": {**cards_mesh([(0, 0, 0)]), "isLeaf": True}})
    stage = Usd.Stage.Open(str(path))
    sun = UsdLux.DistantLight.Define(stage, "/Lights/Sun")
    sun.AddRotateXOp().Set(30.0)  # tilt the -Z travel direction: toward-sun = R_x(30°) · +Z
    UsdLux.DomeLight.Define(stage, "/Lights/Sky")
    stage.Save()
    scene, _ = read_scene(path)
    lights = {l.kind: l for l in scene.lights}
    np.testing.assert_allclose(lights["distant"].direction, [0, -np.sin(np.radians(30)), np.cos(np.radians(30))], atol=1e-9)
    np.testing.assert_allclose(lights["dome"].direction, [0, 0, 1])

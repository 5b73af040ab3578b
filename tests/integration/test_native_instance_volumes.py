"""Issues #16/#17: a native-instance prototype's volume is placed over each of its instances, inside the default prim.

The bundled forest has 4 native instances and a point instancer of 12
copies of one instanceable tree, so all 16 share one native prototype whose
meshes are instance proxies. Its ``FoliageLighting`` volume is authored once
in a ``class`` and placed by one referencing prim per instance
(``pipeline.volumes``). Here the forest's default prim is moved and turned,
so a placement that forgot the default prim's transform (or the instance's)
lands beside the trees; the leaves' world positions are computed with pxr
from the instance prims, not with the code under test.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.params import DensityParams
from foliage_tools.pipeline.density import run_density
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.lb import LBBakeParams, run_lb
from tests.conftest import sha256
from tests.helpers.cli import foliage
from tests.helpers.forests import bake_density_lb, leaf_points_per_instance, moved_bundled_forest, placed_volumes

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
RESOLUTION = 16
CLASS = "/World/FoliageBakes/Prototypes/Tree_00"


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    work = tmp_path_factory.mktemp("natinst")
    forest = moved_bundled_forest(work / "in")
    inputs = {p: sha256(p) for p in (forest, forest.with_name("tree_small.usda"))}
    first = bake_density_lb(forest, work / "a", RESOLUTION)
    second = bake_density_lb(forest, work / "b", RESOLUTION)
    return forest, inputs, first, second


def test_each_instance_gets_a_volume_whose_world_box_holds_its_leaves_and_little_else(baked):
    from pxr import Usd, UsdGeom

    _, _, final, _ = baked
    stage = Usd.Stage.Open(str(final))
    leaves = leaf_points_per_instance(stage)
    volumes = placed_volumes(stage)
    assert set(volumes) == set(leaves) and len(volumes) == 16  # 4 native instances + 12 point-instanced copies
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_])
    for inst, prim in volumes.items():
        bound = cache.ComputeWorldBound(prim)
        to_box = np.array(bound.GetMatrix().GetInverse())
        box = bound.GetRange()
        lo, hi = np.array(box.GetMin()), np.array(box.GetMax())
        local = leaves[inst] @ to_box[:3, :3] + to_box[3, :3]  # the leaves in the volume's (oriented) box frame
        assert np.all(local >= lo - 1e-4) and np.all(local <= hi + 1e-4), inst
        # tight: the box is the leaves' own box plus the grid's margin (one voxel each side, 1/16 of the crown at
        # this resolution), not a box large enough to hold anything
        span = local.max(axis=0) - local.min(axis=0)
        assert np.all(hi - lo <= span * (1 + 4.0 / RESOLUTION) + 1e-6), (inst, hi - lo, span)
        # and it lies over this tree, not over a neighbour (crowns ~2.8 wide, trees >= 3.9 apart)
        others = np.concatenate([p for k, p in leaves.items() if k != inst])
        others_local = others @ to_box[:3, :3] + to_box[3, :3]
        inside = np.all((others_local >= lo) & (others_local <= hi), axis=1)
        assert inside.mean() < 0.02, inst


def test_the_volumes_share_one_class_and_one_vdb_and_nothing_is_drawn_at_the_origin(baked):
    from pxr import Sdf, Usd, UsdVol

    _, _, final, _ = baked
    stage = Usd.Stage.Open(str(final))
    cls = stage.GetPrimAtPath(CLASS)
    assert cls and cls.IsAbstract() and cls.GetSpecifier() == Sdf.SpecifierClass
    drawn = [p for p in stage.Traverse() if p.IsA(UsdVol.Volume)]
    assert all(not p.GetPath().HasPrefix(Sdf.Path(CLASS)) for p in drawn)  # the prototype-space volume is not drawn
    volumes = placed_volumes(stage)
    files = set()
    for prim in volumes.values():
        # the placing prim references the class (an internal reference), it holds no copy of the fields
        refs = prim.GetParent().GetPrimStack()[0].referenceList.explicitItems
        assert [(r.assetPath, r.primPath) for r in refs] == [("", Sdf.Path(CLASS))], prim.GetPath()
        assert {spec.path for spec in prim.GetPrimStack()} == {Sdf.Path(f"{CLASS}/FoliageLighting")}, prim.GetPath()
        fields = UsdVol.Volume(prim).GetFieldPaths()
        assert set(fields) == {"density", "woodFraction", "lbSun"}, prim.GetPath()
        for path in fields.values():
            assert path.HasPrefix(prim.GetPath())  # the relationships follow the reference into the placement
            files.add(Path(UsdVol.OpenVDBAsset(stage.GetPrimAtPath(path)).GetFilePathAttr().Get().resolvedPath))
    assert files == {final.with_suffix(".vdb")}  # one file for the prototype, every grid in it, nothing copied
    assert sorted(p.name for p in final.parent.glob("*.vdb")) == ["f.density.vdb", "f.lb.forest.vdb", "f.lb.vdb"]


def test_everything_the_bake_adds_is_inside_the_default_prim_and_the_inputs_are_unchanged(baked):
    from pxr import Sdf

    forest, inputs, final, _ = baked
    for layer_file in (final.with_name("f.density.usda"), final):
        layer = Sdf.Layer.FindOrOpen(str(layer_file))
        assert [p.name for p in layer.rootPrims] == ["World"], layer_file
        assert layer.defaultPrim == "World"
    assert {p: sha256(p) for p in inputs} == inputs


def test_each_native_instance_carries_its_own_means(baked):
    from pxr import Usd

    _, _, final, _ = baked
    stage = Usd.Stage.Open(str(final))
    for n in range(4):
        prim = stage.GetPrimAtPath(f"/World/Trees/Tree_{n:02d}")
        for name in ("instanceDirect", "instanceScattered"):
            attr = prim.GetAttribute(f"foliage:lb:{name}")
            assert attr.IsCustom() and min(attr.Get()) > 0, (prim.GetPath(), name)


def _masked(text: str) -> str:
    """The layer's text without what differs between two runs by design: the commit id, times, content hashes of
    the .vdb files (their metadata holds the commit) and measured seconds."""
    text = re.sub(r'(string (?:commit|written) = )"[^"]*"', r'\1"…"', text)
    text = re.sub(r'"sha256:[0-9a-f]+"', '"sha256:…"', text)
    return re.sub(r"(foliage:seconds = )[-0-9.e]+", r"\1…", text)


def test_a_rerun_writes_the_same_layers_and_grids(baked):
    from foliage_tools.scene.vdb import grid_names, read_grid

    _, _, first, second = baked
    for name in ("f.density.usda", "f.lb.usda"):
        a, b = (first.with_name(name).read_text(), second.with_name(name).read_text())
        assert "FoliageBakes" in a and _masked(a) == _masked(b), name
    for name in ("f.density.vdb", "f.lb.vdb"):
        names = grid_names(first.with_name(name))
        assert names == grid_names(second.with_name(name))
        for grid in names:
            g, h = read_grid(first.with_name(name), grid), read_grid(second.with_name(name), grid)
            assert g.origin == h.origin and g.voxel_size == h.voxel_size and np.array_equal(g.values, h.values), grid


def test_the_baked_forest_validates(baked):
    _, _, final, _ = baked
    r = foliage("validate", final)
    assert r.returncode == 0, r.stdout + r.stderr


def test_a_later_stage_authors_only_the_placements_that_changed(tmp_path):
    """A stage over an earlier bake leaves the placements it would write the same alone (the reference brings the new
    grids), and re-authors, whole, the one of an instance that moved in between."""
    from pxr import Gf, Sdf, Usd, UsdGeom

    forest = moved_bundled_forest(tmp_path / "in")
    run_density(forest, tmp_path / "a.usda", DensityParams(resolution=RESOLUTION))
    moved = tmp_path / "moved.usda"
    layer = Sdf.Layer.CreateNew(str(moved))
    layer.subLayerPaths.append("./a.usda")
    layer.defaultPrim = "World"
    layer.Save()
    stage = Usd.Stage.Open(str(moved))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Trees/Tree_01")).GetOrderedXformOps()[0].Set(Gf.Vec3d(3.0, -5.0, 0.0))
    stage.GetRootLayer().Save()
    run_density(moved, tmp_path / "b.usda", DensityParams(resolution=RESOLUTION))
    authored = Sdf.Layer.FindOrOpen(str(tmp_path / "b.usda"))
    instances = authored.GetPrimAtPath("/World/FoliageBakes/Instances")
    assert [p.name for p in instances.nameChildren] == ["Trees_Tree_01"]
    result = Usd.Stage.Open(str(tmp_path / "b.usda"))
    volumes = placed_volumes(result)
    leaves = leaf_points_per_instance(result)
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_])
    for inst in ("/World/Trees/Tree_01", "/World/Trees/Tree_02"):
        r = cache.ComputeWorldBound(volumes[inst]).ComputeAlignedRange()
        lo, hi = np.array(r.GetMin()), np.array(r.GetMax())
        assert np.all(leaves[inst] >= lo - 1e-4) and np.all(leaves[inst] <= hi + 1e-4), inst


def test_a_volume_at_the_old_layout_is_named_when_it_is_not_reused(tmp_path):
    """Layers written before the placed volumes kept a native prototype's grids at /FoliageBakes/<name>; a stage on
    such a layer voxelizes again (the grids are not where it reads them) and says so, naming the old prim, instead
    of silently doing the work twice."""
    from foliage_tools.scene.read import read_scene
    from foliage_tools.scene.vdb import Grid
    from foliage_tools.scene.write import LayerEdits, VolumeEdit, stage_metadata, write_layer

    forest = EXAMPLES / "forest_small.usda"
    scene, _ = read_scene(forest)
    proto = next(p for p in scene.prototypes if not p.editable)
    old = f"/FoliageBakes/{re.sub(r'[^A-Za-z0-9_]', '_', proto.name)}/FoliageLighting"
    grids = tuple(Grid(n, np.ones((4, 4, 4), dtype=np.float32), (0.0, 0.0, 0.0), 0.5) for n in ("density", "woodFraction"))
    legacy = tmp_path / "legacy.usda"
    write_layer(forest, legacy, LayerEdits(volumes=[VolumeEdit(path=old, vdb_file=tmp_path / "legacy.vdb", grids=grids,
                                                               attributes={}, purpose="default")]),
                input_stage_meta=stage_metadata(forest))
    report = run_lb(legacy, tmp_path / "lb.usda", LBBakeParams(optics=parse_leaf_optics(None), resolution=RESOLUTION,
                                                                direct=DirectChoice(mode="volume")))
    said = [w for w in report.warnings if "not reused" in w]
    assert len(said) == 1 and f"<{old}>" in said[0] and "earlier foliage-tools versions" in said[0]
    # once `foliage density` has written the current layout over it, its grids are reused without the warning
    run_density(legacy, tmp_path / "d.usda", DensityParams(resolution=RESOLUTION))
    fresh = run_lb(tmp_path / "d.usda", tmp_path / "lb2.usda", LBBakeParams(
        optics=parse_leaf_optics(None), resolution=RESOLUTION, direct=DirectChoice(mode="volume")))
    assert not [w for w in fresh.warnings if "not reused" in w]
    assert [p["density"] for p in fresh.stats["prototypes"]] == ["input"]

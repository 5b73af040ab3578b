"""Issue #17: bake outputs that DCCs load as they are (one .vdb per volume, scalar primvars, custom metadata).

What Blender 5.0 does with them is tested in ``test_blender_roundtrip.py``
(needs the separate bpy venv); these tests check the USD/OpenVDB side that
every DCC relies on, with plain pxr and pyopenvdb.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bake import BakeParams, run_bake
from foliage_tools.pipeline.direct import DirectChoice

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
STAGE_GRIDS = {
    "density": {"density", "woodFraction"},
    "spp": {"sppGFactor", "sppDepth", "sppThickness"},
    "lb": {"lbSun"},
}


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    out = tmp_path_factory.mktemp("dcc") / "out"
    report = run_bake(EXAMPLE, out, BakeParams(optics=parse_leaf_optics(None), resolution=12, direct=DirectChoice(mode="volume")))
    return out, Path(report.stats["result"])


def _fields(stage):
    from pxr import UsdVol

    vol = UsdVol.Volume(stage.GetPrimAtPath("/Tree/FoliageLighting"))
    out = {}
    for name, path in vol.GetFieldPaths().items():
        asset = UsdVol.OpenVDBAsset(stage.GetPrimAtPath(path))
        out[str(name)] = (asset, Path(asset.GetFilePathAttr().Get().resolvedPath))
    return vol, out


def test_each_stage_volume_lives_in_one_file_holding_every_grid_so_far(baked):
    """Blender reads one file per Volume: each layer's fields all name that layer's own .vdb, which holds them all."""
    from pxr import Usd

    from foliage_tools.scene.vdb import grid_names

    out, _ = baked
    expected: set[str] = set()
    for stage_name in ("density", "spp", "lb"):
        expected |= STAGE_GRIDS[stage_name]
        stage = Usd.Stage.Open(str(out / f"tree_small.{stage_name}.usda"))
        _, fields = _fields(stage)
        assert set(fields) == expected, stage_name
        files = {f for _, f in fields.values()}
        assert files == {out / f"tree_small.{stage_name}.vdb"}, stage_name
        assert set(grid_names(out / f"tree_small.{stage_name}.vdb")) == expected, stage_name


def test_carried_grids_are_the_earlier_stages_values_and_classes_say_what_they_are(baked):
    from foliage_tools.scene.vdb import grid_classes, read_grid

    out, _ = baked
    final = out / "tree_small.lb.vdb"
    for name, source in (("density", "density"), ("woodFraction", "density"), ("sppDepth", "spp"), ("sppGFactor", "spp")):
        a = read_grid(out / f"tree_small.{source}.vdb", name)
        b = read_grid(final, name)
        assert a.origin == b.origin and a.voxel_size == b.voxel_size and np.array_equal(a.values, b.values), name
        assert np.any(b.values), name
    classes = grid_classes(final)
    # only the leaf density is a medium to render; the rest is data on the same voxels
    assert classes == {"density": "fog volume", "woodFraction": "unknown", "sppDepth": "unknown", "sppGFactor": "unknown",
                       "sppThickness": "unknown", "lbSun": "unknown"}


def test_volume_is_imported_by_default_and_its_fields_are_not_objects(baked):
    from pxr import Usd, UsdGeom

    _, final = baked
    stage = Usd.Stage.Open(str(final))
    vol, fields = _fields(stage)
    assert UsdGeom.Imageable(vol.GetPrim()).ComputePurpose() == UsdGeom.Tokens.default_
    for name, (asset, _) in fields.items():
        assert UsdGeom.Imageable(asset.GetPrim()).ComputePurpose() == UsdGeom.Tokens.guide, name


def test_per_direction_primvars_equal_the_element_size_8_slices(baked):
    from pxr import Usd, UsdGeom

    _, final = baked
    stage = Usd.Stage.Open(str(final))
    mesh = stage.GetPrimAtPath("/Tree/Leaves")
    faces = len(UsdGeom.Mesh(mesh).GetFaceVertexCountsAttr().Get())
    pv = UsdGeom.PrimvarsAPI(mesh)
    for base in ("smax", "attenuation"):
        packed = np.asarray(pv.GetPrimvar(f"foliage:{base}").Get()).reshape(faces, 8)
        assert np.ptp(packed) > 0, base
        for k in range(8):
            p = pv.GetPrimvar(f"foliage:{base}{k}")
            assert p.GetInterpolation() == "uniform" and p.GetElementSize() == 1, (base, k)
            assert np.array_equal(np.asarray(p.Get()), packed[:, k]), (base, k)


def test_tool_metadata_is_authored_custom(baked):
    """DCC importers keep custom attributes only; the schema's own attributes are authored with ``custom`` set."""
    from pxr import Usd

    _, final = baked
    stage = Usd.Stage.Open(str(final))

    def strongest_custom(prim_path, name):
        attr = stage.GetPrimAtPath(prim_path).GetAttribute(name)
        assert attr.HasAuthoredValue(), (prim_path, name)
        return attr.GetPropertyStack(Usd.TimeCode.Default())[0].custom

    for name in ("foliage:voxelSize", "foliage:method", "foliage:resolution", "foliage:version", "foliage:seconds"):
        assert strongest_custom("/Tree/FoliageLighting", name), name
        assert strongest_custom("/Tree/FoliageLighting/density", name), name
    for name in ("foliage:tau", "foliage:smax:path", "foliage:smax:version"):
        assert strongest_custom("/Tree", name), name
    # the schema still applies and still types them
    assert stage.GetPrimAtPath("/Tree").HasAPI("FoliageEnvelopeAPI")
    assert stage.GetPrimAtPath("/Tree/FoliageLighting").GetAttribute("foliage:resolution").GetTypeName() == "int3"

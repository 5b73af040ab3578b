"""``foliage density`` end to end: area conservation, VDB placement, the output layer, validation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.params import RESOLUTION_RANGE, DensityParams
from foliage_tools.pipeline.density import run_density
from foliage_tools.scene.read import read_scene
from foliage_tools.scene.vdb import read_grid
from tests.conftest import sha256
from tests.helpers.cli import foliage


@pytest.fixture(scope="module")
def oak_density(tmp_path_factory):
    from tests.conftest import OAK

    if not OAK.exists():
        pytest.skip("third-party assets not present")
    out = tmp_path_factory.mktemp("oak") / "oak.density.usda"
    before = sha256(OAK)
    report = run_density(OAK, out, DensityParams(resolution=48))
    assert sha256(OAK) == before, "the input must never change"
    return OAK, out, report


def test_area_method_conserves_leaf_area_on_oak(oak_density):
    # exact clipping: grid sum × voxel volume equals the mesh area up to float32 storage + float64 summation
    _, out, report = oak_density
    p = report.stats["prototypes"][0]
    assert p["leaves"] == 1831
    assert p["area_rel_error"] < 1e-6
    grid = read_grid(out.with_name("oak.density.vdb"), "density")
    # read back from the .vdb (float32): still conserves to float32 round-off
    total = float(grid.values.astype(np.float64).sum()) * grid.voxel_size**3
    assert total == pytest.approx(p["leaf_area_mesh"], rel=1e-5)


def test_grids_read_back_at_the_right_world_positions(oak_density):
    oak, out, report = oak_density
    scene, _ = read_scene(oak)
    leaves = scene.prototypes[0].leaves
    grid = read_grid(out.with_name("oak.density.vdb"), "density")
    # every leaf centre must fall in a voxel holding leaf area (the card's own area is there)
    ijk = np.floor((leaves.centers - np.asarray(grid.origin)) / grid.voxel_size).astype(int)
    assert np.all(ijk >= 0) and np.all(ijk < np.asarray(grid.values.shape))
    assert np.all(grid.values[ijk[:, 0], ijk[:, 1], ijk[:, 2]] > 0)
    # and the active bounding box matches the foliage bounds
    lo = np.asarray(grid.origin)
    hi = lo + np.asarray(grid.values.shape) * grid.voxel_size
    b = scene.prototypes[0].bounds(leaves_only=True)
    assert np.all(lo <= b[0] + 1e-9) and np.all(hi >= b[1] - 1e-9)
    assert np.all(lo > b[0] - grid.voxel_size - 1e-9) and np.all(hi < b[1] + grid.voxel_size + 1e-9)


def test_output_layer_sublayers_the_input_and_adds_only_the_bake(oak_density):
    from pxr import Sdf, Usd, UsdGeom, UsdVol

    oak, out, _ = oak_density
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert len(layer.subLayerPaths) == 1 and not Path(layer.subLayerPaths[0]).is_absolute()
    assert layer.pseudoRoot.GetInfo("upAxis") == "Z" and layer.pseudoRoot.GetInfo("metersPerUnit") == 1.0
    # only overs on the existing prims, plus the new volume
    specs = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: specs.append(p) if p.IsPrimPath() else None)
    defs = {str(p) for p in specs if layer.GetPrimAtPath(p).specifier == Sdf.SpecifierDef}
    assert defs == {"/Tree/FoliageLighting", "/Tree/FoliageLighting/density", "/Tree/FoliageLighting/woodFraction"}
    stage = Usd.Stage.Open(str(out))
    vol = UsdVol.Volume(stage.GetPrimAtPath("/Tree/FoliageLighting"))
    assert vol.GetPrim().HasAPI("FoliageLightingAPI")
    # purpose default, so DCCs import it; its fields are guides, so they are not imported as objects (issue #17)
    assert vol.GetPurposeAttr().Get() == UsdGeom.Tokens.default_
    assert {UsdGeom.Imageable(stage.GetPrimAtPath(p)).GetPurposeAttr().Get() for p in vol.GetFieldPaths().values()} == {UsdGeom.Tokens.guide}
    assert set(vol.GetFieldPaths()) == {"density", "woodFraction"}
    leaf_id = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/leaves_0")).GetPrimvar("foliage:leafId")
    ids = np.asarray(leaf_id.Get())
    assert leaf_id.GetInterpolation() == "uniform" and len(ids) == 3189
    assert set(np.unique(ids)) == set(range(1831))
    assert stage.GetPrimAtPath("/Tree/FoliageLighting").GetAttribute("foliage:resolution").Get()[0] > 0


def test_validate_passes_the_output_and_fails_without_its_grid(oak_density, tmp_path):
    import shutil

    oak, out, _ = oak_density
    ok = foliage("validate", out, "--json")
    assert ok.returncode == 0, ok.stdout
    # a copy of the output whose .vdb is missing
    work = tmp_path / "copy"
    work.mkdir()
    shutil.copy(out, work / out.name)
    layer_text = (work / out.name).read_text().replace(Path(out).parent.as_posix(), ".")
    (work / out.name).write_text(layer_text)
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(work / out.name))
    layer.subLayerPaths[0] = str(oak)  # keep the input reachable from the copy
    layer.Save()
    missing = foliage("validate", work / out.name, "--json")
    assert missing.returncode == 1
    msgs = [f["message"] for f in json.loads(missing.stdout)["stats"]["findings"] if f["rule"] == "volume-grids"]
    assert msgs and all("does not exist" in m for m in msgs)
    # a corrupt .vdb
    (work / "oak.density.vdb").write_bytes(b"not a vdb at all")
    corrupt = foliage("validate", work / out.name, "--json")
    assert corrupt.returncode == 1
    assert any("not a readable OpenVDB file" in f["message"] for f in json.loads(corrupt.stdout)["stats"]["findings"])


def test_subgrid_method_counts_sub_cells(tmp_path, simple_tree):
    report = run_density(simple_tree, tmp_path / "s.usda", DensityParams(resolution=6, method="subgrid"))
    grid = read_grid(tmp_path / "s.vdb", "density")
    vals = grid.values[grid.values > 0]
    # geist2008 sec. 4.2: every value is a whole number of 27ths, at most 1
    np.testing.assert_allclose(vals * 27, np.round(vals * 27), atol=1e-5)
    assert vals.max() <= 1.0 and report.stats["prototypes"][0]["area_rel_error"] is None


def test_failed_write_leaves_no_partial_output(tmp_path, simple_tree, monkeypatch):
    import foliage_tools.scene.write as write

    out = tmp_path / "o.usda"
    out.write_text("#usda 1.0\n# an earlier good output\n")
    before = out.read_text()

    def boom(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(write, "_author", boom)
    with pytest.raises(RuntimeError):
        run_density(simple_tree, out, DensityParams(resolution=4))
    assert out.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.usda", "tree.usda"]


def test_density_output_chains_as_input(tmp_path, simple_tree):
    first = run_density(simple_tree, tmp_path / "a.usda", DensityParams(resolution=4))
    second = run_density(tmp_path / "a.usda", tmp_path / "b.usda", DensityParams(resolution=4))
    assert first.stats["prototypes"][0]["leaves"] == second.stats["prototypes"][0]["leaves"] == 2


def test_forest_bakes_its_shared_prototype_once(tmp_path):
    from pxr import Usd, UsdVol

    forest = Path(__file__).resolve().parents[2] / "examples" / "forest_small.usda"
    report = run_density(forest, tmp_path / "f.usda", DensityParams(resolution=16))
    protos = report.stats["prototypes"]
    assert len(protos) == 1 and protos[0]["leaves"] == 1500
    # a native-instance prototype's meshes are instance proxies: its volume goes into a class under the default
    # prim (placed over every instance: test_native_instance_volumes.py), with a warning saying where
    assert protos[0]["volume"] == "/World/FoliageBakes/Prototypes/Tree_00/FoliageLighting"
    assert any("native instance" in w and "placed over each of its 16 instance(s)" in w for w in report.warnings)
    stage = Usd.Stage.Open(str(tmp_path / "f.usda"))
    assert UsdVol.Volume(stage.GetPrimAtPath(protos[0]["volume"]))
    assert foliage("validate", tmp_path / "f.usda").returncode == 0


def test_a_voxel_size_finer_than_the_resolution_limit_is_refused_before_any_grid(tmp_path, simple_tree):
    """A new user's trial: --voxel-size 0.004 on the example tree allocated a 598x609x666 grid (9.3 GB resident,
    64 s); a voxel size is held to the --resolution limit (params.RESOLUTION_RANGE) along the longest foliage edge."""
    lo, hi = RESOLUTION_RANGE
    out = tmp_path / "d.usda"
    # the two cards span 0.6 units in x: ~600 voxels across at 0.001 (a 12M-voxel grid, which was accepted)
    r = foliage("density", simple_tree, "-o", out, "--voxel-size", "0.001")
    assert r.returncode == 2, r.stderr
    message = " ".join(r.stderr.split())
    for text in ("--voxel-size 0.001", "</Tree>", "resolution 60", f"the limit of {hi}", f"--resolution {lo}-{hi}",
                 "--voxel-size 0.0012 or larger"):
        assert text in message, message
    assert not any(tmp_path.glob("d.*"))
    # the voxel size it suggests is accepted, at most the limit across
    ok = foliage("density", simple_tree, "-o", out, "--voxel-size", "0.0012", "--json")
    assert ok.returncode == 0, ok.stderr
    shape = json.loads(ok.stdout)["stats"]["prototypes"][0]["shape"]
    assert max(shape) - 2 <= hi

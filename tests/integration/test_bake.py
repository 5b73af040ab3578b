"""``foliage bake``: the main job chains the stages, each layer over the previous one."""

from pathlib import Path

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bake import BakeParams, run_bake
from tests.integration.test_cli_errors import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_bake_chains_stages_and_the_last_layer_holds_everything(tmp_path):
    from pxr import Usd, UsdGeom, UsdVol

    report = run_bake(EXAMPLE, tmp_path / "out", BakeParams(optics=parse_leaf_optics(None), resolution=12, with_reference=True,
                                                          reference_paths=50000))
    final = Path(report.stats["result"])
    assert final.name == "tree_small.lb.usda"
    stage = Usd.Stage.Open(str(final))
    leaves = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/Leaves"))
    for name in ("foliage:leafId", "foliage:smax", "foliage:lbIndirect", "foliage:lb:scattered", "foliage:smax:scattered", "foliage:sppIrradiance", "foliage:sppg:scattered"):
        assert leaves.GetPrimvar(name).HasAuthoredValue(), name
    fields = set(UsdVol.Volume(stage.GetPrimAtPath("/Tree/FoliageLighting")).GetFieldPaths())
    assert {"density", "woodFraction", "lbSun", "sppGFactor", "sppDepth", "sppThickness"} <= fields
    assert (tmp_path / "out" / "tree_small.png").stat().st_size > 1000
    assert (tmp_path / "out" / "bench.json").stat().st_size > 100 and (tmp_path / "out" / "bench.png").exists()
    assert foliage("validate", final).returncode == 0


def test_bake_into_a_file_path_is_refused(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    r = foliage("bake", EXAMPLE, "-o", f)
    assert r.returncode == 2

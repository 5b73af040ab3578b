"""``foliage spp`` end to end: grids and primvars of DESIGN.md section 3."""

from pathlib import Path

import numpy as np

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.spp import SppParams, run_spp
from foliage_tools.scene.vdb import grid_names, read_grid
from tests.integration.test_cli_errors import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_spp_writes_grids_and_primvars(tmp_path):
    from pxr import Usd, UsdGeom

    report = run_spp(EXAMPLE, tmp_path / "s.usda", SppParams(optics=parse_leaf_optics(None), resolution=16))
    assert sorted(grid_names(tmp_path / "s.vdb")) == ["sppDepth", "sppGFactor", "sppThickness"]
    g = read_grid(tmp_path / "s.vdb", "sppGFactor").values
    assert np.all((g >= 0) & (g <= 1 + 1e-6))
    # shinya2013 eq. (29): a cell's depth toward the sun never exceeds the thickness of the chord through it.
    # The grids read back over their own active boxes: place the depth grid inside the thickness grid.
    d = read_grid(tmp_path / "s.vdb", "sppDepth")
    w = read_grid(tmp_path / "s.vdb", "sppThickness")
    off = np.round((np.asarray(d.origin) - np.asarray(w.origin)) / w.voxel_size).astype(int)
    assert np.all(off >= 0)
    sub = w.values[tuple(slice(o, o + n) for o, n in zip(off, d.values.shape))]
    assert np.all(d.values <= sub + 1e-5) and d.values.max() > 0
    stage = Usd.Stage.Open(str(tmp_path / "s.usda"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves"))
    pv = UsdGeom.PrimvarsAPI(mesh)
    n_points = len(mesh.GetPointsAttr().Get())
    assert pv.GetPrimvar("foliage:sppIrradiance").GetInterpolation() == "vertex"
    assert len(pv.GetPrimvar("foliage:sppIrradiance").Get()) == n_points == len(pv.GetPrimvar("foliage:gFactor").Get())
    spp = np.asarray(pv.GetPrimvar("foliage:spp:scattered").Get())
    sppg = np.asarray(pv.GetPrimvar("foliage:sppg:scattered").Get())
    ss = np.asarray(pv.GetPrimvar("foliage:ss:scattered").Get())
    # the G-factor only removes light where the crown boundary is nearer than the slab model assumes
    assert np.all(sppg <= spp + 1e-6) and sppg.sum() < spp.sum()
    assert np.all(ss == 0)  # the paper's SS baseline: attenuated direct light only
    assert report.stats["directions"] == 16
    assert foliage("validate", tmp_path / "s.usda").returncode == 0


def test_sun_below_the_horizon_is_a_usage_error(tmp_path):
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--sun", "0,-10", "--resolution", "8")
    assert r.returncode == 2 and "below the horizon" in r.stderr

"""``foliage spp`` end to end: grids and primvars of DESIGN.md section 3."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.spp import SppParams, run_spp
from foliage_tools.scene.vdb import grid_names, read_grid
from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_spp_writes_grids_and_primvars(tmp_path):
    from pxr import Usd, UsdGeom

    # no gather and the slab's first order: the sppg primvars are then G applied to SPP's, which this test checks
    # against spp's (the default first order, marched, is checked below and in tests/unit/test_first_order.py)
    report = run_spp(EXAMPLE, tmp_path / "s.usda", SppParams(optics=parse_leaf_optics(None), resolution=16, gather=0,
                                                             first_order="slab"))
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
    # the report says which depth path ran (grid by default: with the exact direct light the depths serve the
    # scattered light only, where the grid measured better) and which plane-parallel model
    assert report.stats["depth"] == "grid" and report.stats["rays_per_leaf"] is None
    assert report.stats["model"] == "exact" and report.stats["direct"]["mode"] == "rays"
    assert report.stats["prototypes"][0]["instances"] == 1 and report.stats["prototypes"][0]["neighbours"] == 0
    assert foliage("validate", tmp_path / "s.usda").returncode == 0
    assert report.stats["first_order"] == "slab"

    # the default: SPPG's first order marched from the exact direct light; spp's primvars do not change
    report = run_spp(EXAMPLE, tmp_path / "m.usda", SppParams(optics=parse_leaf_optics(None), resolution=16, gather=0))
    assert report.stats["first_order"] == "march"
    stage = Usd.Stage.Open(str(tmp_path / "m.usda"))
    pv = UsdGeom.PrimvarsAPI(UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves")))
    marched = np.asarray(pv.GetPrimvar("foliage:sppg:scattered").Get())
    assert np.array_equal(np.asarray(pv.GetPrimvar("foliage:spp:scattered").Get()), spp)
    assert np.all(np.isfinite(marched)) and np.all(marched >= 0) and not np.allclose(marched, sppg, rtol=0.05)


def test_grid_depth_path_is_a_flag_and_bad_values_are_usage_errors(tmp_path):
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--depth", "grid", "--resolution", "8", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["depth"] == "grid"
    # every option has a config key (its long name)
    (tmp_path / "c.toml").write_text('[spp]\ndepth = "rays"\nrays-per-leaf = 2\n')
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--config", tmp_path / "c.toml", "--resolution", "8", "--json")
    assert r.returncode == 0, r.stderr
    stats = json.loads(r.stdout)["stats"]
    assert (stats["depth"], stats["rays_per_leaf"]) == ("rays", 2)
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--depth", "voxels")
    assert r.returncode == 2 and "--depth" in r.stderr
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--rays-per-leaf", "0")
    assert r.returncode == 2 and "--rays-per-leaf" in r.stderr


def test_g_factor_options_are_flags_recorded_in_the_report_and_bad_values_are_usage_errors(tmp_path):
    """--g-weights, --g-resolution and --g-orders reach the bake (the report says which ran, and they change G) or
    exit 2."""
    runs = {}
    for args in ((), ("--g-weights", "radiance"), ("--g-resolution", "8"), ("--no-g-orders",)):
        r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--resolution", "16", "--json", *args)
        assert r.returncode == 0, r.stderr
        runs[args] = json.loads(r.stdout)["stats"]
    # the exact slab's defaults (pipeline.spp.G_RESOLUTION, G per order)
    assert (runs[()]["g_weights"], runs[()]["g_resolution"], runs[()]["g_orders"]) == ("paper", 16, True)
    assert runs[("--no-g-orders",)]["g_orders"] is False
    assert runs[("--g-weights", "radiance")]["g_weights"] == "radiance"
    assert runs[("--g-resolution", "8")]["g_resolution"] == 8
    means = {k: v["prototypes"][0]["gfactor_mean"] for k, v in runs.items()}
    # each option changes G on this crown (measured differences of 0.02-0.1 in mean G at these settings)
    assert len({round(m, 4) for m in means.values()}) == 4, means
    for bad in (("--g-weights", "uniform"), ("--g-resolution", "2")):
        r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", *bad)
        assert r.returncode == 2 and bad[0] in r.stderr, r.stderr


def test_sun_below_the_horizon_is_a_usage_error(tmp_path):
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "o.usda", "--sun", "0,-10", "--resolution", "8")
    assert r.returncode == 2 and "below the horizon" in r.stderr  # tests/integration/test_sun_horizon.py: every bake


def test_depth_auto_counts_rays_on_small_scenes_and_integrates_the_grid_on_large_ones(monkeypatch):
    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline import spp as spp_mod
    from foliage_tools.scene.read import read_scene

    scene, _ = read_scene(Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda")
    params = spp_mod.SppParams(optics=parse_leaf_optics(None))
    assert params.depth == "auto"
    # with the exact direct light (the default) the depths serve the scattered light only: grid
    assert spp_mod.resolve_depth(scene, params).depth == "grid"
    from foliage_tools.pipeline.direct import DirectChoice

    params = spp_mod.SppParams(optics=parse_leaf_optics(None), direct=DirectChoice(mode="volume"))
    assert spp_mod.resolve_depth(scene, params).depth == "rays"  # 1500 leaves
    monkeypatch.setattr(spp_mod, "AUTO_RAYS_MAX_LEAVES", 1000)
    assert spp_mod.resolve_depth(scene, params).depth == "grid"
    assert spp_mod.resolve_depth(scene, replace(params, depth="rays")).depth == "rays"  # explicit choice kept


def test_spp_reuses_the_density_of_an_earlier_stage_on_the_same_lattice(tmp_path):
    from foliage_tools.params import DensityParams
    from foliage_tools.pipeline.density import run_density

    run_density(EXAMPLE, tmp_path / "d.usda", DensityParams(resolution=12))
    params = SppParams(optics=parse_leaf_optics(None), resolution=12, depth="grid")
    fresh = run_spp(EXAMPLE, tmp_path / "a.usda", params)
    reused = run_spp(tmp_path / "d.usda", tmp_path / "b.usda", params)
    assert fresh.stats["prototypes"][0]["density"] == "computed" and reused.stats["prototypes"][0]["density"] == "input"
    # float32 storage of the grid: the same G-factor up to that round-off
    assert abs(reused.stats["prototypes"][0]["gfactor_mean"] - fresh.stats["prototypes"][0]["gfactor_mean"]) < 1e-5


def test_first_order_march_where_it_cannot_apply_is_a_usage_error():
    # a new user's trial: --no-gfactor took --first-order march and ignored it (the report said march); --model spp
    # asked for --g-orders without saying that --model spp had turned it off
    import pytest

    from foliage_tools.errors import UsageError
    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline.spp import SppParams

    optics = parse_leaf_optics(None)
    with pytest.raises(UsageError, match="--no-gfactor"):
        SppParams(optics=optics, gfactor=False, first_order="march")
    assert SppParams(optics=optics, gfactor=False).first_order == "slab"  # what it bakes, as the report says
    with pytest.raises(UsageError, match="--model spp"):
        SppParams(optics=optics, model="spp", first_order="march")

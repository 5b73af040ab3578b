"""``foliage lb`` end to end: grids, primvars, relighting bases, the per-leaf conversion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.geometry.voxelize import GridSpec
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.lb import LBBakeParams, run_lb, sample_trilinear
from foliage_tools.scene.vdb import grid_names, read_grid
from tests.conftest import sha256
from tests.integration.test_cli_errors import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_trilinear_sampling_is_exact_for_linear_fields():
    grid = GridSpec(origin=(1.0, 2.0, 3.0), voxel_size=0.5, shape=(4, 5, 6))
    c = grid.index_to_world(np.stack(np.meshgrid(*[np.arange(n) for n in grid.shape], indexing="ij"), axis=-1))
    field = 2.0 * c[..., 0] - c[..., 1] + 0.5 * c[..., 2]
    rng = np.random.default_rng(1)
    lo, hi = grid.index_to_world(np.zeros(3)), grid.index_to_world(np.array(grid.shape) - 1)
    pts = rng.uniform(lo, hi, size=(50, 3))
    np.testing.assert_allclose(sample_trilinear(field, grid, pts), 2.0 * pts[:, 0] - pts[:, 1] + 0.5 * pts[:, 2], atol=1e-12)


def test_sun_bake_writes_grid_and_primvars(tmp_path):
    from pxr import Usd, UsdGeom

    before = sha256(EXAMPLE)
    report = run_lb(EXAMPLE, tmp_path / "l.usda", LBBakeParams(optics=parse_leaf_optics(None), resolution=24))
    assert sha256(EXAMPLE) == before
    assert grid_names(tmp_path / "l.vdb") == ["lbSun"]
    g = read_grid(tmp_path / "l.vdb", "lbSun")
    assert g.values.ndim == 4 and np.all(np.isfinite(g.values)) and g.values.min() >= 0
    s = report.stats
    assert s["residual"] < 1e-5 and s["iterations"] > 0 and s["bases"] == "sun"
    stage = Usd.Stage.Open(str(tmp_path / "l.usda"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves"))
    pv = UsdGeom.PrimvarsAPI(mesh)
    ind = pv.GetPrimvar("foliage:lbIndirect")
    assert ind.GetInterpolation() == "vertex" and len(ind.Get()) == len(mesh.GetPointsAttr().Get())
    direct = np.asarray(pv.GetPrimvar("foliage:lb:direct").Get())
    scattered = np.asarray(pv.GetPrimvar("foliage:lb:scattered").Get())
    # sun irradiance 1: a leaf's E_direct <= |n.s| <= 1; scattered light is a small positive fraction of it
    assert np.all(direct <= 1 + 1e-6) and np.all(scattered >= 0)
    assert 0 < scattered.mean() < direct.mean()
    # green leaves scatter most in G (geist2008 Table 1 optics)
    assert scattered[:, 1].mean() > scattered[:, 0].mean() > scattered[:, 2].mean()
    # the medium the grids were solved with is recorded on the volume (sigma_a + sigma_s = 1 at absorption scale 1)
    from foliage_tools.lighting.collision import leaf_medium

    vol = stage.GetPrimAtPath("/Tree/FoliageLighting")
    med = leaf_medium(parse_leaf_optics(None), absorption_scale=1.0)
    for name, expect in (("sigmaA", med.sigma_a), ("sigmaS", med.sigma_s), ("g", med.g)):
        np.testing.assert_allclose(tuple(vol.GetAttribute(f"foliage:lb:{name}").Get()), expect, rtol=1e-6)
    assert vol.GetAttribute("foliage:lb:absorptionScale").Get() == 1.0
    assert foliage("validate", tmp_path / "l.usda").returncode == 0


def test_all_bases_write_the_19_relighting_grids(tmp_path):
    run_lb(EXAMPLE, tmp_path / "a.usda", LBBakeParams(optics=parse_leaf_optics(None), resolution=12, bases="all"))
    names = grid_names(tmp_path / "a.vdb")
    assert sorted(names) == sorted(["lbAmbient"] + [f"lbBase{k:02d}" for k in range(1, 19)])


def test_bad_lb_options_are_usage_errors(tmp_path):
    r = foliage("lb", EXAMPLE, "-o", tmp_path / "o.usda", "--tolerance", "2")
    assert r.returncode == 2 and "--tolerance" in r.stderr
    with pytest.raises(Exception, match="absorption"):
        LBBakeParams(optics=parse_leaf_optics(None), absorption_scale=0)


def test_a_bake_that_cannot_fit_in_memory_stops_before_solving_and_writes_nothing(tmp_path, monkeypatch):
    from foliage_tools.errors import UsageError
    from foliage_tools.pipeline import lb as lb_stage

    monkeypatch.setattr(lb_stage, "available_memory", lambda: 1e3)  # 1 kB free: no grid fits
    out = tmp_path / "lb.usda"
    with pytest.raises(UsageError, match=r"needs ~.* GB.*--resolution.*foliage plan"):
        run_lb(EXAMPLE, out, LBBakeParams(optics=parse_leaf_optics(None), resolution=8))
    assert list(tmp_path.iterdir()) == []

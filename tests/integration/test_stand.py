"""A 5 x 5 stand of touching crowns: per-instance light where each tree stands (issue #16).

The stand (examples/make_forest.py --stand 5: tree_small on a PointInstancer, trunks one crown diameter
apart, random rotations) under the sun at elevation 45 degrees. Every bake writes the leaf-area-weighted
mean E_direct and E_scattered of every instance (pipeline.instances) as primvars of the instancer; the Monte
Carlo reference, which traces every instance, is the truth. The exact direct light (shadow rays through
every instance) puts each tree in its place in the stand; the volume methods' scattered light is the
prototype's, lit alone, unless a final gather (through every instance's leaves) replaces it.

Without a gather, the forest lattice (pipeline.forest, steele2010 3.2) scales each instance's scattered light.
Measured (seed 3 stand, 2M reference paths) before the forest lattice: every instance's total within 1.7 %
(lb --gather 128) and 6.8 % (smax) of the reference; the centre tree's scattered light +25 % (gather) and +4 %
(smax) over the tree alone, against the reference's +30 %.
The fixture takes ~90 s (the reference and the gather over 37 500 leaves): slow.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.lb import LBBakeParams, run_lb
from foliage_tools.pipeline.reference import ReferenceParams, run_reference
from foliage_tools.pipeline import world
from foliage_tools.pipeline.smax import SmaxParams, run_smax
from foliage_tools.pipeline.spp import SppParams, run_spp
from foliage_tools.scene.read import open_stage

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "examples"))
SUN = (30.0, 45.0)
#: 64 shadow rays per leaf: ~6 % sampling error per leaf, ~0.2 % on the mean of an instance's 1500 leaves
DIRECT = DirectChoice(samples=64)
SIDE = 5
CENTRE = SIDE * SIDE // 2


def _instance_values(layer: Path, method: str) -> tuple[np.ndarray, np.ndarray]:
    from pxr import UsdGeom

    stage = open_stage(layer)
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Grove"))
    d = np.asarray(pv.GetPrimvar(f"foliage:{method}:instanceDirect").Get(), dtype=np.float64)
    s = np.asarray(pv.GetPrimvar(f"foliage:{method}:instanceScattered").Get(), dtype=np.float64)
    return d, s


def _tree_values(layer: Path, method: str) -> tuple[np.ndarray, np.ndarray]:
    stage = open_stage(layer)
    prim = stage.GetPrimAtPath("/Tree")
    return (np.asarray(prim.GetAttribute(f"foliage:{method}:instanceDirect").Get(), dtype=np.float64),
            np.asarray(prim.GetAttribute(f"foliage:{method}:instanceScattered").Get(), dtype=np.float64))


pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def stand(tmp_path_factory):
    from make_forest import plan_stand, tree_radius_of, write_forest

    d = tmp_path_factory.mktemp("stand")
    tree = d / "tree_small.usda"
    shutil.copy(REPO / "examples" / "tree_small.usda", tree)
    path = write_forest(d / "stand.usda", tree, plan_stand(side=SIDE, tree_radius=tree_radius_of(tree), seed=3))
    optics = parse_leaf_optics(None)
    out = {}
    for name, scene in (("stand", path), ("alone", tree)):
        paths = 2_000_000 if name == "stand" else 1_000_000
        run_reference(scene, d / f"{name}.ref.usda", ReferenceParams(optics=optics, sun=SUN, paths=paths, seed=5))
        run_lb(scene, d / f"{name}.lb.usda", LBBakeParams(optics=optics, sun=SUN, resolution=32, gather=128, direct=DIRECT))
        run_smax(scene, d / f"{name}.smax.usda", SmaxParams(optics=optics, sun=SUN, direct=DIRECT))
        # SPP's defaults but the gather (eq. 31's neighbour depths, then the forest lattice's factor)
        run_spp(scene, d / f"{name}.spp.usda", SppParams(optics=optics, sun=SUN, direct=DIRECT, gather=0))
        # the lattice alone (no gather), scaled per instance by the forest lattice
        run_lb(scene, d / f"{name}.lbf.usda", LBBakeParams(optics=optics, sun=SUN, resolution=32, direct=DIRECT, gather=0))
        out[name] = d
    # the stand traced as its lone tree, as a forest above world.WORLD_MAX_TRIANGLES is
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(world, "WORLD_MAX_TRIANGLES", 0)
        run_lb(path, d / "stand.lone.lb.usda", LBBakeParams(optics=optics, sun=SUN, resolution=32, direct=DIRECT, gather=0))
        run_lb(path, d / "stand.lone.lbg.usda", LBBakeParams(optics=optics, sun=SUN, resolution=32, gather=128, direct=DIRECT))
        run_smax(path, d / "stand.lone.smax.usda", SmaxParams(optics=optics, sun=SUN, direct=DIRECT))
    return d


def test_every_instance_within_ten_percent_of_the_reference(stand):
    rd, rs = _instance_values(stand / "stand.ref.usda", "ref")
    assert rd.shape == (SIDE * SIDE, 3)
    ref_total = (rd + rs)[:, 1]
    for method, layer in (("lb", "stand.lb.usda"), ("smax", "stand.smax.usda"), ("spp", "stand.spp.usda")):
        d, s = _instance_values(stand / layer, method)
        # the bound; the direct part is exact (its sampling error over an instance's 1500 leaves is
        # ~0.1 %), so what is left is the scattered light (10-15 % of the total here) and its error
        np.testing.assert_allclose((d + s)[:, 1], ref_total, rtol=0.10, err_msg=method)
        np.testing.assert_allclose(d[:, 1], rd[:, 1], rtol=0.01, err_msg=f"{method} direct")


def test_the_centre_tree_is_darker_than_the_same_tree_alone_by_the_references_factor(stand):
    rd, rs = _instance_values(stand / "stand.ref.usda", "ref")
    ad, as_ = _tree_values(stand / "alone.ref.usda", "ref")
    mc = (rd + rs)[CENTRE, 1] / (ad + as_)[1]
    assert mc < 0.97  # the neighbours shade the centre tree: a stand effect to reproduce, not noise
    for method in ("lb", "smax", "spp"):
        d, s = _instance_values(stand / f"stand.{method}.usda", method)
        bd, bs = _tree_values(stand / f"alone.{method}.usda", method)
        factor = (d + s)[CENTRE, 1] / (bd + bs)[1]
        assert factor == pytest.approx(mc, rel=0.10), (method, factor, mc)


def test_the_neighbours_scattered_light_reaches_the_centre_tree(stand):
    # The centre tree gets more scattered light in the stand than alone (its neighbours' lit leaves). The
    # gather traces every instance's leaves, so its first bounce has it; without a gather, the forest lattice
    # (pipeline.forest) scales the lone prototype's scattered light per instance.
    _, rs = _instance_values(stand / "stand.ref.usda", "ref")
    _, as_ = _tree_values(stand / "alone.ref.usda", "ref")
    mc_gain = rs[CENTRE, 1] / as_[1]
    assert mc_gain > 1.1  # measured 1.30: a stand effect to reproduce, not noise
    for method, layer in (("lb", "lb"), ("lb", "lbf"), ("smax", "smax")):
        _, s = _instance_values(stand / f"stand.{layer}.usda", method)
        _, sa = _tree_values(stand / f"alone.{layer}.usda", method)
        # 10 %: the bound for the stand effect (measured: gather 1.25, forest lattice on lb 1.31 and on
        # smax 1.35, each instance's lattice factor within 2.6 % of the reference's)
        assert s[CENTRE, 1] / sa[1] == pytest.approx(mc_gain, rel=0.10), (layer, s[CENTRE, 1] / sa[1], mc_gain)


def test_the_forest_lattice_factor_is_written_per_instance_and_follows_the_reference(stand):
    from pxr import UsdGeom

    _, rs = _instance_values(stand / "stand.ref.usda", "ref")
    _, as_ = _tree_values(stand / "alone.ref.usda", "ref")
    mc = rs[:, 1] / as_[1]
    stage = open_stage(stand / "stand.lbf.usda")  # keep the stage alive while its prims are used
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Grove"))
    scale = np.asarray(pv.GetPrimvar("foliage:lb:instanceScale").Get(), dtype=np.float64)
    assert scale.shape == (SIDE * SIDE, 3)
    # per instance within 6 %: the reference's factor carries its own noise (~1-2 % per instance at 2M paths)
    np.testing.assert_allclose(scale[:, 1], mc, rtol=0.06)
    # the gathered bake needs no factor: it traced the neighbours itself
    gathered = open_stage(stand / "stand.lb.usda")
    assert not UsdGeom.PrimvarsAPI(gathered.GetPrimAtPath("/World/Grove")).GetPrimvar("foliage:lb:instanceScale")


def test_bench_scores_each_instance_of_the_stand(stand):
    from foliage_tools.pipeline.bench import BenchParams, run_bench

    rep = run_bench(stand / "stand.usda", BenchParams(optics=parse_leaf_optics(None), sun=SUN, paths=2_000_000, noise=None,
                                                      methods=("smax", "lb-32")))
    st = rep.stats
    assert st["instances"] == SIDE * SIDE and st["forest"]["grid"][0] > 16
    rows = {m["name"]: m for m in st["methods"]}
    # each instance's mean total against the reference's: the direct part is exact, the scattered part (10-15 %
    # of the total) carries the forest lattice's factor (within 2.6 % per instance) times the prototype's crown
    # mean (the method's error on the tree alone, ~5-20 %) -> a few per cent at most; 5 % is the bound
    for name in ("smax", "lb-32"):
        assert 0 < rows[name]["instance_rel_rms_total"] < 0.05, (name, rows[name]["instance_rel_rms_total"])


def test_a_stand_traced_as_its_lone_tree_keeps_every_instance_within_ten_percent(stand):
    # Above world.WORLD_MAX_TRIANGLES the per-leaf shadow rays and the gather trace each prototype alone and the
    # forest lattice brings the stand's scattered light; each instance's direct mean is traced through every placed
    # instance (pipeline.direct.instance_direct: 4096 rays each, ~2-3 % sampling error per instance, so within 10 %).
    # Against the reference, which traces every instance: the 10 % per instance on the total.
    rd, rs = _instance_values(stand / "stand.ref.usda", "ref")
    for method, layer in (("lb", "stand.lone.lb.usda"), ("lb", "stand.lone.lbg.usda"), ("smax", "stand.lone.smax.usda")):
        d, s = _instance_values(stand / layer, method)
        err_d = d[:, 1] / rd[:, 1] - 1
        err_t = (d + s)[:, 1] / (rd + rs)[:, 1] - 1
        print(layer, "direct", np.round(err_d, 3), "total", np.round(err_t, 3))
        np.testing.assert_allclose(d[:, 1], rd[:, 1], rtol=0.10, err_msg=f"{layer} direct")
        np.testing.assert_allclose((d + s)[:, 1], (rd + rs)[:, 1], rtol=0.10, err_msg=layer)
    # every instance's shade differs: the centre tree darker than a corner one, as the reference has it
    d, _ = _instance_values(stand / "stand.lone.lb.usda", "lb")
    assert (d[CENTRE, 1] < d[0, 1]) == (rd[CENTRE, 1] < rd[0, 1])

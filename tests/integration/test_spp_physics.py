"""SPPG physics on real crowns (shinya2013 issue #5, "How we will know").

* The G-factor falls where the real crown boundary is nearer than the
  plane-parallel (horizontally infinite) slab assumes: leaves in the outer
  shell of the crown get a lower mean G than interior leaves (paper Fig. 6).
  The shell is measured independently of G: each leaf centre's distance to the
  convex hull of all leaf centres, outer 20 % vs inner 50 % of leaves.
* Against the Monte Carlo reference (``pipeline.reference.bake_reference``,
  the same call ``foliage bench`` makes): where plain SPP overestimates the
  scattered light (the outer shell of ``examples/tree_small.usda``), SPPG lies
  below SPP and nearer the reference.
* The ray-count depth path (``lighting.raydepth``) feeds ``solve_sppg`` on a real
  asset and gives finite results with G in [0, 1].

Numbers behind the tolerances (sun of the stage, 64-voxel density grid, 16
directions, default leaf optics; G is deterministic, so its margins are not
noise margins):

==========  ==================  ==================
asset       mean G outer 20 %   mean G inner 50 %
==========  ==================  ==================
tree_small  0.715               0.772
oak         0.779               0.802
==========  ==================  ==================

Scattered irradiance (channel sum), mean over the outer hull-distance quintile
of tree_small, ratio to the reference at 4M paths (per-leaf noise 0.13): SPP
1.28, SPPG 0.92; inner quintiles SPP 0.85-1.05, SPPG 0.67-0.79. At the 1M paths
used here (per-leaf noise ~0.25, ~1.5 % on a 300-leaf quintile mean) seeds 1, 2,
3 give SPP 1.259 / 1.234 / 1.275 and SPPG 0.909 / 0.891 / 0.921 (the test uses
seed 1; the reference is bitwise deterministic for a seed).
On the Oak SPP underestimates every quintile (0.81-0.96), so there is no
overestimating region to test there; whole-crown relative RMS of E_scattered
is worse with G than without on both assets (tree_small 0.43 vs 0.36, oak 0.49
vs 0.42 at 4M paths) — not asserted, reported.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from foliage_tools.lighting import gfactor as gf
from foliage_tools.lighting import raydepth as rd
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.spp import SppParams, bake_spp
from foliage_tools.pipeline.stage import begin_bake, sun_in_prototype

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def _bake(path: Path):
    _, scene, sun = begin_bake("spp", path, None, None, Silent())
    bake = bake_spp(scene, sun, SppParams(optics=parse_leaf_optics(None)), [], Silent())[0]
    return scene, sun, bake


def _hull_distance(points: np.ndarray) -> np.ndarray:
    """Distance of each point inside the convex hull of ``points`` to the hull's surface."""
    eq = ConvexHull(points).equations  # outward unit normals n and offsets b: n·x + b <= 0 inside
    return np.min(-(points @ eq[:, :3].T + eq[:, 3]), axis=1)


def _shell_means(scene, values):
    dist = _hull_distance(scene.prototypes[0].leaves.centers)
    outer = dist <= np.quantile(dist, 0.2)
    inner = dist >= np.quantile(dist, 0.5)
    return values[outer].mean(), values[inner].mean(), dist


@pytest.mark.parametrize("which,margin", [("example", 0.03), ("oak", 0.01)])
def test_gfactor_is_lower_in_the_outer_shell_of_the_crown(which, margin, request):
    path = EXAMPLE if which == "example" else request.getfixturevalue("oak")
    scene, _, bake = _bake(path)
    g = bake.result.gfactor
    assert np.all((g >= 0) & (g <= 1))
    outer, inner, _ = _shell_means(scene, g)
    # measured: example 0.715 vs 0.772, oak 0.779 vs 0.802
    assert outer < inner - margin


def test_sppg_corrects_spp_where_spp_overestimates_the_reference():
    scene, sun, bake = _bake(EXAMPLE)
    ref = bake_reference(scene, sun, ReferenceParams(optics=parse_leaf_optics(None), paths=1_000_000, seed=1, workers=2), Silent())
    r = ref.result.e_scattered.sum(axis=1)
    spp = bake.result.spp.scattered.sum(axis=1)
    sppg = bake.result.sppg.scattered.sum(axis=1)
    dist = _hull_distance(scene.prototypes[0].leaves.centers)
    outer = dist <= np.quantile(dist, 0.2)
    spp_ratio = spp[outer].mean() / r[outer].mean()
    sppg_ratio = sppg[outer].mean() / r[outer].mean()
    # SPP overestimates the outer shell far beyond the ~1.5 % noise of the quintile mean (1.28 at 4M paths)
    assert spp_ratio > 1.15
    # SPPG is below SPP there and nearer the reference (0.92 at 4M paths)
    assert sppg_ratio < spp_ratio
    assert abs(sppg_ratio - 1.0) < abs(spp_ratio - 1.0) - 0.1


def test_ray_count_depths_drive_solve_sppg_on_the_example():
    _, scene, sun = begin_bake("spp", EXAMPLE, None, None, Silent())
    proto = scene.prototypes[0]
    sun_local = sun_in_prototype(scene, 0, sun, [])
    dirs = gf.sample_directions(16)
    ds = rd.leaf_ray_depth_samples(
        proto.triangles(leaves=True), rd.prototype_leaf_ids(proto), sun_direction=sun_local, directions=dirs,
        centers=proto.leaves.centers,
    )
    res = gf.solve_sppg(ds, normals=proto.leaves.normals, optics=parse_leaf_optics(None), sun_direction=sun_local, directions=dirs)
    assert np.all((res.gfactor >= 0) & (res.gfactor <= 1))
    assert np.all(np.isfinite(res.sppg.scattered)) and np.all(res.sppg.scattered <= res.spp.scattered + 1e-15)
    # leaves with no leaf between them and the sun get the full direct sun (|n·l| e^0)
    top = ds.sun_depth == 0
    assert top.sum() > 50
    np.testing.assert_allclose(res.sppg.direct[top, 0], np.abs(proto.leaves.normals[top] @ (sun_local / np.linalg.norm(sun_local))))

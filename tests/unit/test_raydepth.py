"""Ray-count depths (``lighting.raydepth``, shinya2013 eq. (29) through the geometry).

Closed forms: a stack of K parallel cards gives exact counts; a box of
uniformly random, isotropically oriented leaf cards gives a mean count equal to
the grid path's G·LAD integral (one crossing = one unit of optical depth), and
zero-crossing rays in the proportion exp(-depth) (Beer-Lambert).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.geometry.rays import RayScene
from foliage_tools.geometry.voxelize import area_per_voxel, grid_for_bounds
from foliage_tools.lighting.spp import raydepth as rd
from foliage_tools.lighting.depth import DepthSamples, optical_depth, own_leaf_depth
from foliage_tools.lighting.gfactor import sample_directions, solve_sppg
from foliage_tools.lighting.optics import parse_leaf_optics


def cards(centers, normals, size) -> np.ndarray:
    """(2 L, 3, 3) triangles: one square card of edge ``size`` per centre (triangles 2i, 2i+1... in two blocks)."""
    c = np.asarray(centers, float)
    n = np.asarray(normals, float)
    n = n / np.linalg.norm(n, axis=1)[:, None]
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(n, u)
    a = size / 2
    p = [c + a * (su * u + sv * v) for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return np.concatenate([np.stack([p[0], p[1], p[2]], 1), np.stack([p[0], p[2], p[3]], 1)])


def stack(k: int) -> np.ndarray:
    """K horizontal 10 x 10 cards at z = 1 .. K."""
    z = np.arange(1, k + 1, dtype=float)
    return cards(np.stack([np.zeros(k), np.zeros(k), z], 1), np.tile([0.0, 0.0, 1.0], (k, 1)), 10.0)


def test_stack_of_parallel_cards_gives_exact_counts():
    k = 5
    scene = RayScene(stack(k))
    # points between the cards (z = 0.5 .. 5.5), directions up to 40 degrees off vertical stay inside the cards
    pts = np.array([[0.1, -0.2, z + 0.5] for z in range(k + 1)])
    dirs = np.array([[0, 0, 1], [0.5, 0.3, 0.8], [np.sin(0.7), 0, np.cos(0.7)], [0, 0, -1], [-0.2, 0.4, -0.9]])
    c = rd.crossing_counts(scene, pts, dirs)
    above = k - np.arange(k + 1)  # cards above each point
    expected = np.stack([above, above, above, k - above, k - above], axis=1)
    np.testing.assert_array_equal(c, expected)
    # horizontal rays between cards and rays that miss the stack cross nothing
    np.testing.assert_array_equal(rd.crossing_counts(scene, pts, [[1.0, 0.0, 0.0]]), 0)


def test_depth_samples_of_the_stack_are_counts_and_plug_into_solve_sppg():
    k = 4
    scene = RayScene(stack(k))
    sun = np.array([0.3, 0.0, 1.0])
    dirs = sample_directions(8)
    pts = np.array([[0.0, 0.0, 2.5], [0.2, 0.1, 0.5]])
    ds = rd.ray_depth_samples(scene, pts, sun_direction=sun, directions=dirs)
    assert isinstance(ds, DepthSamples)
    np.testing.assert_array_equal(ds.sun_depth, [2, 4])
    np.testing.assert_array_equal(ds.sun_thickness, [4, 4])
    up = dirs[:, 2] > 0
    # the 8 Fibonacci directions reach |v_z| >= 0.125; at that slant a ray from the
    # origin's column may leave the 10 x 10 cards sideways, so check only steep ones
    steep = np.abs(dirs[:, 2]) > 0.5
    np.testing.assert_array_equal(ds.sample_depth[0, up & steep], 2)
    np.testing.assert_array_equal(ds.sample_depth[0, ~up & steep], 2)
    np.testing.assert_array_equal(ds.sample_thickness[:, steep], 4)
    ds2 = rd.ray_depth_samples(scene, pts, sun_direction=sun, directions=dirs, crossing_depth=0.5)
    np.testing.assert_array_equal(ds2.sun_depth, [1, 2])
    res = solve_sppg(ds, normals=[[0, 0, 1], [0, 0, 1]], optics=parse_leaf_optics(None), sun_direction=sun, directions=dirs)
    # direct sun = |n.l| exp(-u): the counts are optical depths
    mu0 = sun[2] / np.linalg.norm(sun)
    np.testing.assert_allclose(res.sppg.direct[:, 0], mu0 * np.exp(-np.array([2.0, 4.0])))


def test_leaf_origins_skip_their_own_leaf():
    k = 3
    tri = stack(k)
    ids = np.concatenate([np.arange(k), np.arange(k)])  # cards() puts the two halves in two blocks
    centers = np.array([[0.0, 0.0, z] for z in (1.0, 2.0, 3.0)])
    up_down = np.array([[0.0, 0.0, 1.0]])
    ds = rd.leaf_ray_depth_samples(tri, ids, sun_direction=[0, 0, 1], directions=up_down, centers=centers)
    np.testing.assert_array_equal(ds.sun_depth, [2, 1, 0])
    np.testing.assert_array_equal(ds.sun_thickness, [2, 2, 2])
    # several origins per leaf, drawn on the leaf itself: same exact counts
    ds4 = rd.leaf_ray_depth_samples(tri, ids, sun_direction=[0, 0, 1], directions=up_down, rays_per_leaf=4, seed=1)
    np.testing.assert_array_equal(ds4.sun_depth, [2, 1, 0])
    np.testing.assert_array_equal(ds4.sun_thickness, [2, 2, 2])


def test_crossing_counts_rejects_bad_input():
    scene = RayScene(stack(1))
    with pytest.raises(ValueError):
        rd.crossing_counts(scene, np.zeros((2, 3)), [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError):
        rd.crossing_counts(scene, np.zeros((2, 3)), [[0.0, 0.0, 1.0]], skip_ids=[0, 0])
    with pytest.raises(RuntimeError, match="max_hits"):
        rd.crossing_counts(RayScene(stack(3)), [[0.0, 0.0, 0.5]], [[0.0, 0.0, 1.0]], max_hits=2)


def random_box(seed: int, n: int = 4000, size: float = 0.05) -> np.ndarray:
    """n square cards of edge ``size``, centres uniform in the unit cube, normals isotropic: LAD = 10, G = 0.5."""
    rng = np.random.default_rng(seed)
    return cards(rng.random((n, 3)), rng.normal(size=(n, 3)), size)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_box_mean_count_equals_grid_optical_depth(seed):
    """E[crossings] = G · LAD · length: the ray path and the grid path are on one optical-depth scale.

    Measured spread of mean(count)/mean(grid depth) - 1 over 30 seeds (10..39)
    with 200 interior points x 16 directions: mean -0.25 %, std 0.85 %,
    max |.| 2.3 %. Tolerance 4 % (~4.7 std).
    """
    tri = random_box(seed)
    pts_all = tri.reshape(-1, 3)
    grid = grid_for_bounds(pts_all.min(0), pts_all.max(0), resolution=32)
    rho = area_per_voxel(tri, grid) / grid.voxel_volume
    rng = np.random.default_rng(100 + seed)
    pts = 0.25 + 0.5 * rng.random((200, 3))
    dirs = sample_directions(16)
    grid_depth = optical_depth(rho, grid, pts, dirs)
    counts = rd.crossing_counts(RayScene(tri), pts, dirs)
    # the analytic value: 0.5 × LAD (10 / unit) × mean chord to the cube's face; the grid path integrates the same
    assert 2.0 < grid_depth.mean() < 4.0
    assert abs(counts.mean() / grid_depth.mean() - 1.0) < 0.04
    # Beer-Lambert: the analytic optical depth G·LAD·chord = 0.5 × 10 × (distance to the cube face)
    # predicts the share of rays crossing no leaf, exp(-depth), and a Poisson dispersion (variance = mean).
    # Measured over seeds 0..5: |P0 - mean exp(-depth)| <= 0.0094 (binomial s.e. of P0 with 3200 rays ~0.005),
    # var/mean of (count - depth) in 0.94..1.00, mean count / analytic - 1 in -3.6 %..+1.2 %.
    with np.errstate(divide="ignore"):
        t = np.where(dirs[None] > 0, (1 - pts[:, None]) / dirs[None], np.where(dirs[None] < 0, -pts[:, None] / dirs[None], np.inf))
    depth = 0.5 * 10.0 * t.min(axis=-1)
    assert abs(counts.mean() / depth.mean() - 1.0) < 0.06
    assert abs(float(np.mean(counts == 0)) - float(np.mean(np.exp(-depth)))) < 0.02
    assert 0.85 < np.var(counts - depth) / depth.mean() < 1.15


def test_counts_from_leaves_skip_the_own_leaf_that_the_grid_path_smears_in():
    """From leaf centres the ray path (own leaf skipped) still measures the medium's G·LAD·chord.

    The grid path at a leaf centre also integrates the leaf's own area smeared
    over the voxels it straddles: measured excess over the grid depth at random
    points, seeds 0-1, cards of edge 0.05: +0.09 (16 voxels, h = 1.3 edges),
    +0.27 (32), +0.46 (64, h = 0.33 edges) optical depth, while the counts stay
    within 2.5 % of the grid depth at random points. Tolerances: 5 % and > 0.25.
    """
    tri = random_box(0)
    n = len(tri) // 2
    ids = np.concatenate([np.arange(n), np.arange(n)])
    centres = 0.5 * (tri[:n, 0] + tri[:n, 2])  # card centre = midpoint of its diagonal
    inner = np.flatnonzero(np.all((centres > 0.25) & (centres < 0.75), axis=1))[:300]
    grid = grid_for_bounds(tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0), resolution=64)
    rho = area_per_voxel(tri, grid) / grid.voxel_volume
    dirs = sample_directions(16)
    at_leaves = optical_depth(rho, grid, centres[inner], dirs).mean()
    at_random = optical_depth(rho, grid, 0.25 + 0.5 * np.random.default_rng(0).random((300, 3)), dirs).mean()
    counts = rd.crossing_counts(RayScene(tri), centres[inner], dirs, skip_ids=inner, id_of_triangle=ids).mean()
    assert abs(counts / at_random - 1.0) < 0.05
    assert at_leaves - at_random > 0.25
    # the grid path with the own leaf taken out (lighting.depth.own_leaf_depth) is back on the counts' scale:
    # measured counts / grid = 1.001 here
    own = own_leaf_depth(grid, tri, ids, centres, dirs)[inner].mean()
    assert abs(counts / (at_leaves - own) - 1.0) < 0.05


def test_leaf_without_area_is_refused_when_sampling_origins_on_leaves():
    tri = stack(2)
    ids = np.array([0, 2, 0, 2])  # leaf 1 has no triangle
    with pytest.raises(ValueError, match="leaf 1"):
        rd.leaf_ray_depth_samples(tri, ids, sun_direction=[0, 0, 1], directions=[[0, 0, 1]], rays_per_leaf=2)


# -- a uniform leaf layer (examples/make_layer.py): counts vs G·LAD·l, and what exp(-count) gets wrong ----------

_EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _make_layer():
    """examples/make_layer.py as a module (examples/ is not a package; tests/unit/test_examples.py does the same)."""
    if "make_layer" not in sys.modules:
        spec = importlib.util.spec_from_file_location("make_layer", _EXAMPLES / "make_layer.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules["make_layer"] = module  # dataclasses look their module up while the class is created
        spec.loader.exec_module(module)
    return sys.modules["make_layer"]


#: The layer of the report: 10 x 10 x 1.5 m, LAI 3 (LAD 2), 30000 cards of 0.1 m, G = 0.5, sun at elevation 60°.
LAYER = {"size": (10.0, 10.0), "thickness": 1.5, "lai": 3.0, "leaf_size": 0.1, "seed": 1}
SUN_ELEVATION = np.radians(60.0)
#: Depth bins below the top, metres. They start 0.1 m down: a card is crossed within its half-diagonal (0.071 m)
#: of its centre, so only points deeper than that see exactly G·LAD·(distance to the top along the ray).
DEPTH_BINS = (0.1, 0.4, 0.7, 1.0, 1.5)
#: Inner region |x|, |y| < 3.5 m: a ray toward the sun from the bottom travels 1.5 / tan 60° = 0.87 m sideways,
#: so no counted ray leaves through a side.
INNER = 3.5


def _standard_error(spread: float, points: int) -> float:
    """Standard error of a bin mean over ``points`` rays (or leaves) of one layer:
    sqrt(spread / points × (1 + points · (2a/3) / A_perp)), the second factor for rays that share blockers.

    The rays of a bin start spread over the inner region's horizontal area A and are parallel, so they
    cross a bundle of cross-section A_perp = A μ0. A card of shadow area s (a |n·v| on a plane
    perpendicular to the rays) that one of them crosses is crossed by another with probability
    s / A_perp, so (cards being a Poisson process) the variance of the bin's total count is
    P λ (1 + (P - 1) E[s²] / (E[s] A_perp)), and E[s²] / E[s] = 2a/3 for isotropic cards
    (|n·v| uniform on [0, 1]). ``spread`` is the per-ray variance (λ for Poisson counts, p(1 - p)
    for a 0/1 visibility, where sharing a blocker inflates the variance by no more than that).
    """
    a = LAYER["leaf_size"] ** 2
    a_perp = (2 * INNER) ** 2 * np.sin(SUN_ELEVATION)
    return float(np.sqrt(spread / points * (1.0 + points * (2.0 * a / 3.0) / a_perp)))


@pytest.fixture(scope="module")
def layer():
    ml = _make_layer()
    g = ml.build_layer(**LAYER)
    tri, ids = g.triangles()
    sun = np.array([np.cos(SUN_ELEVATION), 0.0, np.sin(SUN_ELEVATION)])  # azimuth 0
    sigma_t = 0.5 * g.lad  # G = 0.5 for isotropic cards (raydepth module docstring): 1 crossing per metre
    return g, tri, ids, sun, sigma_t


def test_layer_is_what_make_layer_promises(layer):
    g, tri, ids, _, _ = layer
    assert g.leaf_count == 30000 and tri.shape == (60000, 3, 3) and np.array_equal(ids, np.repeat(np.arange(30000), 2))
    np.testing.assert_allclose(g.lad, 2.0)
    cards = g.points.reshape(-1, 4, 3)
    np.testing.assert_allclose(np.linalg.norm(cards[:, 1] - cards[:, 0], axis=1), 0.1)
    np.testing.assert_allclose(cards.mean(axis=1), g.centres, atol=1e-12)
    assert np.all((g.centres >= g.lo) & (g.centres <= g.hi))
    # isotropic normals: mean |n_z| = 1/2 (G = 0.5), standard error 0.29 / sqrt(30000) = 0.0017
    assert abs(np.abs(g.normals[:, 2]).mean() - 0.5) < 0.007
    again = _make_layer().build_layer(**LAYER)
    assert np.array_equal(again.points, g.points)


def test_mean_crossings_in_a_uniform_layer_equal_g_lad_l_at_every_depth(layer):
    """E[n+] = G·LAD·l (module docstring), from random points and from points on the leaves (own leaf skipped).

    Measured (this layer, bins from 0.1 m down): random points 0.976-1.005 of G·LAD·l, leaf origins (4 per
    leaf) 0.996-1.011; over layer seeds 1-6 every bin within 1.4 of the standard errors below (so the
    4-error bound is loose, not tight: the shared-blocker inflation is an upper bound). A 20 % undercount
    would exceed the bound in every bin. The reported "20 % fewer crossings" is not in the counts: it was
    exp(-mean count) used as the direct light (next test).
    """
    g, tri, ids, sun, sigma_t = layer
    scene = RayScene(tri)
    mu0 = np.sin(SUN_ELEVATION)
    top = LAYER["thickness"]
    rng = np.random.default_rng(7)
    n = 16000
    pts = np.column_stack([rng.uniform(-INNER, INNER, (n, 2)), rng.uniform(0.0, top - DEPTH_BINS[0], n)])
    counts = rd.crossing_counts(scene, pts, [sun])[:, 0]
    lam = sigma_t * (top - pts[:, 2]) / mu0
    inner_leaves = np.flatnonzero(np.all(np.abs(g.centres[:, :2]) < INNER, axis=1))
    k = 4  # origins per leaf, uniform on the card (its two corner vectors span it)
    c = g.points.reshape(-1, 4, 3)[inner_leaves]
    s, t = rng.random((2, inner_leaves.size, k, 1))
    origins = (c[:, None, 0] + s * (c[:, None, 1] - c[:, None, 0]) + t * (c[:, None, 3] - c[:, None, 0])).reshape(-1, 3)
    leaf_counts = rd.crossing_counts(
        scene, origins, [sun], skip_ids=np.repeat(inner_leaves, k), id_of_triangle=ids
    )[:, 0].reshape(-1, k).mean(axis=1)
    leaf_lam = sigma_t * (top - g.centres[inner_leaves, 2]) / mu0  # the origins' mean height is the centre's
    for lo, hi in zip(DEPTH_BINS[:-1], DEPTH_BINS[1:]):
        for what, cnt, lm, depth in (
            ("points", counts, lam, top - pts[:, 2]),
            ("leaves", leaf_counts, leaf_lam, top - g.centres[inner_leaves, 2]),
        ):
            m = (depth >= lo) & (depth < hi)
            expected = lm[m].mean()
            # 4 standard errors of a Poisson mean (variance λ per ray or leaf: an upper bound for the mean of
            # k rays of one leaf), inflated for rays sharing blockers (_standard_error): 0.045-0.092 here
            bound = 4.0 * _standard_error(expected, int(m.sum()))
            assert abs(cnt[m].mean() - expected) < bound, (what, lo, hi, cnt[m].mean(), expected, bound)


def test_leaf_direct_light_is_the_visible_fraction_not_exp_of_the_mean_count(layer):
    """The cause of SPP's too-bright direct sun with ``--depth rays`` (module docstring: Jensen).

    A leaf's direct light is the share of its area whose ray toward the sun crosses no leaf; that share
    averages to exp(-G·LAD·l) (Beer-Lambert), while exp(-mean count over the leaf's rays) averages far above
    it, because the rays of one card cross largely the same leaves. Measured (layer seed 1, 8 rays per
    leaf), per depth bin: visible fraction / exp(-λ) = 0.996, 1.004, 1.007, 1.014; exp(-n̄) / exp(-λ) =
    1.06, 1.15, 1.22, 1.36 (layer seeds 2-6: visible 0.985-1.037, exp(-n̄) 1.054-1.382; the deepest
    excess of exp(-n̄), 0.081-0.088, is 2.5x the 4-error bound asserted last).
    """
    g, tri, ids, sun, sigma_t = layer
    k = 8
    res = rd.leaf_ray_depths(tri, ids, sun_direction=sun, directions=[[0.0, 0.0, 1.0]], rays_per_leaf=k, seed=3, workers=2)
    assert isinstance(res, rd.LeafRayDepths) and res.sun_visible.shape == (g.leaf_count,)
    assert res.sample_visible.shape == (g.leaf_count, 1)
    np.testing.assert_array_equal(res.sun_visible * k, np.round(res.sun_visible * k))  # a share of k rays
    np.testing.assert_array_equal(res.sun_visible[res.depths.sun_depth == 0], 1.0)
    assert np.all(res.sun_visible[res.depths.sun_depth >= 1] < 1)
    inner = np.all(np.abs(g.centres[:, :2]) < INNER, axis=1)
    depth = LAYER["thickness"] - g.centres[:, 2]
    lam = sigma_t * depth / np.sin(SUN_ELEVATION)
    for lo, hi in zip(DEPTH_BINS[:-1], DEPTH_BINS[1:]):
        m = inner & (depth >= lo + 0.05) & (depth < hi)  # origins lie within 0.071 m of the centre's height
        p = np.exp(-lam[m]).mean()
        # 4 standard errors of a mean of 0/1 visibilities (variance p(1 - p) per leaf, an upper bound for
        # the share of k rays), inflated for leaves sharing blockers (_standard_error): 0.033-0.048 here
        bound = 4.0 * _standard_error(p * (1 - p), int(m.sum()))
        assert abs(res.sun_visible[m].mean() - p) < bound, (lo, hi, res.sun_visible[m].mean(), p, bound)
    # the old estimator, |n·s| exp(-n̄): too bright, and more so the deeper the leaf (the reported +4 %..+34 %)
    m = inner & (depth >= 1.0)
    p = np.exp(-lam[m]).mean()
    assert np.exp(-res.depths.sun_depth[m]).mean() - p > 4.0 * _standard_error(p * (1 - p), int(m.sum()))

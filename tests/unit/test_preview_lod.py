"""Level of detail (``foliage preview --lod``): simplified wood, thinned far leaves, the picture kept.

Wood is decimated by fast_simplification (quadric edge collapse); far leaves are dropped
whole and the kept ones enlarged by 1/√f so the leaf area is kept. The checks: triangle
counts drop by the requested factors, leaf area is conserved, per-corner data follows the
kept triangles, and a rendered forest keeps its mean luminance and coverage.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from foliage_tools.errors import UsageError
from foliage_tools.preview.camera import direction_from_angles, orbit_camera
from foliage_tools.preview.lod import LodCache, LodParams, apply_lod, instance_levels, leaf_components, simplify_wood, thin_leaves
from foliage_tools.preview.renderer import DrawMesh, DrawPrototype, DrawScene, Ground, Lighting, Renderer
from foliage_tools.preview.tonemap import luminance

Z = np.array([0.0, 0.0, 1.0])


def cylinder(radius=0.1, height=1.5, around=48, rings=40) -> np.ndarray:
    """(3T, 3) float32 corners of a finely tessellated open tube (a trunk), 2 × around × (rings - 1) triangles."""
    th = np.linspace(0, 2 * np.pi, around, endpoint=False)
    z = np.linspace(0, height, rings)
    pts = np.array([[radius * math.cos(t), radius * math.sin(t), h] for h in z for t in th])
    tris = []
    for j in range(rings - 1):
        for i in range(around):
            a, b = j * around + i, j * around + (i + 1) % around
            tris += [[a, b, b + around], [a, b + around, a + around]]
    return pts[np.array(tris)].reshape(-1, 3).astype(np.float32)


def cards(n=400, seed=7, side=0.18, centre=(0.0, 0.0, 2.2)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = np.asarray(centre) + d * rng.uniform(size=(n, 1)) ** (1 / 3)
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u, v = q[:, :, 0] * side / 2, q[:, :, 1] * side / 2
    a, b, cc, dd = c - u - v, c + u - v, c + u + v, c - u + v
    return np.stack([a, b, cc, a, cc, dd], axis=1).reshape(-1, 3).astype(np.float32)


def tri_areas(corners: np.ndarray) -> np.ndarray:
    t = np.asarray(corners, dtype=np.float64).reshape(-1, 3, 3)
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def test_wood_is_simplified_to_the_requested_fraction_and_keeps_its_shape():
    trunk = cylinder()
    t = len(trunk) // 3
    for fraction in (0.5, 0.25, 0.0625):
        out = simplify_wood(trunk, fraction)
        assert abs(len(out) // 3 - fraction * t) <= 0.05 * fraction * t + 2, (fraction, len(out) // 3)
        # the decimated tube still spans the same box (within 2 % of the height)
        np.testing.assert_allclose(out.min(axis=0), trunk.min(axis=0), atol=0.03)
        np.testing.assert_allclose(out.max(axis=0), trunk.max(axis=0), atol=0.03)
    assert np.array_equal(simplify_wood(trunk, 1.0), trunk)


def test_far_leaves_are_dropped_whole_with_their_area_compensated():
    corners = cards(n=2000)
    leaves = leaf_components(corners)
    assert leaves.max() + 1 == 2000 and np.all(np.bincount(leaves) == 2)  # one component per card
    rng = np.random.default_rng(1)
    indirect = np.repeat(rng.uniform(size=(2000, 3)), 6, axis=0).astype(np.float32)
    smax = np.repeat(rng.uniform(size=(2000, 8)), 6, axis=0).astype(np.float32)
    mesh = DrawMesh(corners=corners, leaf=True, indirect={"lb": indirect}, smax=smax)
    f = 0.25
    thin = thin_leaves(mesh, f)
    kept = thin.triangle_count // 2
    # a binomial(2000, 0.25) count: within 4 standard deviations of 500
    assert abs(kept - 500) < 4 * math.sqrt(2000 * f * (1 - f))
    # every kept card is the same card enlarged by 1/sqrt(f) about its centre: area x 1/f
    np.testing.assert_allclose(tri_areas(thin.corners), tri_areas(corners)[0] / f, rtol=1e-4)
    # so the total leaf area is kept up to the binomial spread
    assert abs(tri_areas(thin.corners).sum() / tri_areas(corners).sum() - 1) < 4 * math.sqrt((1 - f) / (f * 2000))
    # per-corner data follows the kept corners: each kept card's rows are one of the original cards' rows
    rows = {tuple(r) for r in np.round(indirect[::6], 6)}
    assert all(tuple(r) in rows for r in np.round(thin.indirect["lb"][::6], 6))
    assert thin.smax.shape == (len(thin.corners), 8)
    # the kept cards keep their centres: each new card's centroid is an old card's centroid
    old_c = corners.reshape(-1, 6, 3).mean(axis=1)
    new_c = thin.corners.reshape(-1, 6, 3).mean(axis=1)
    d = np.linalg.norm(new_c[:, None] - old_c[None], axis=2).min(axis=1)
    assert d.max() < 1e-5
    assert thin_leaves(mesh, 1.0) is mesh


def forest(count=16, spacing=3.0) -> DrawScene:
    leaves = DrawMesh(corners=cards(n=300, seed=3), leaf=True)
    wood = DrawMesh(corners=cylinder(height=1.6), leaf=False)
    side = math.ceil(math.sqrt(count))
    rng = np.random.default_rng(2)
    t = []
    for k in range(count):
        i, j = divmod(k, side)
        a = rng.uniform(0, 2 * np.pi)
        m = np.eye(4)
        m[:3, :3] = [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
        m[:3, 3] = [(i - side / 2) * spacing, (j - side / 2) * spacing, 0.0]
        t.append(m)
    return DrawScene((DrawPrototype((leaves, wood), np.array(t)),), Z)


def test_lod_cuts_triangles_by_the_expected_factor_and_keeps_the_picture():
    scene = forest()
    bounds = scene.bounds()
    ground = Ground.under(bounds, Z)
    cam = orbit_camera(bounds, width=128, height=128, up_axis="Z", azimuth=30, elevation=25, clip_bounds=ground.bounds(Z))
    params = LodParams(0.25, far_radii=13.0)  # the 4-5 trees nearest the camera stay near
    levels = instance_levels(scene.prototypes[0], cam.position, params.far_radii)
    n_near, n_far = int((levels == 1).sum()), int((levels == 2).sum())
    assert n_near > 0 and n_far > 0, "the test needs both levels"
    cache = LodCache()
    lod = apply_lod(scene, cam.position, params, cache)
    leaf_t, wood_t = 600, len(cylinder()) // 3
    far_leaf_t = next(m for p in lod.prototypes for m in p.meshes if m.leaf and m.triangle_count < leaf_t).triangle_count
    expected = n_near * (leaf_t + 0.25 * wood_t) + n_far * (far_leaf_t + 0.0625 * wood_t)
    assert abs(lod.triangle_count - expected) <= 0.05 * expected
    assert lod.triangle_count < 0.6 * scene.triangle_count
    assert abs(far_leaf_t / leaf_t - 0.25) < 4 * math.sqrt(0.25 * 0.75 / 300)
    # cached per prototype and level: a second split reuses the same meshes
    again = apply_lod(scene, cam.position, params, cache)
    assert all(a is b for pa, pb in zip(lod.prototypes, again.prototypes) for a, b in zip(pa.meshes, pb.meshes))
    light = Lighting(direction_from_angles(45, 60, "Z"), sky_radiance=(0.03, 0.04, 0.05))
    frames = {}
    for name, s in (("full", scene), ("lod", lod)):
        with Renderer(s, samples=4, sky_samples=4) as r:
            frames[name] = r.render(cam, light, ground=ground)
    full, low = frames["full"], frames["lod"]
    # coverage of the trees and mean luminance of the picture within 5 % of full detail
    assert abs(low.tree.mean() / full.tree.mean() - 1) < 0.05
    assert abs(luminance(low.radiance).mean() / luminance(full.radiance).mean() - 1) < 0.05


def test_lod_fraction_must_be_in_zero_one():
    for bad in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(UsageError, match="--lod"):
            LodParams(bad)


def test_the_example_forest_at_lod_keeps_its_picture():
    # examples/forest_small.usda: 16 instances of tree_small (3000 leaf and 2268 wood triangles, the wood
    # made of closed 8-sided prisms that edge collapse cannot reduce, so far wood is pruned to its
    # largest branches). Framed whole, every instance is far: leaves x 0.25, wood to <= 0.0625.
    from pathlib import Path

    from foliage_tools.pipeline.preview import choose_lighting
    from foliage_tools.scene.read import read_scene

    scene, warnings = read_scene(Path(__file__).resolve().parents[2] / "examples" / "forest_small.usda")
    full = DrawScene.from_scene(scene)
    bounds = full.bounds()
    ground = Ground.under(bounds, scene.up)
    cam = orbit_camera(bounds, width=128, height=128, up_axis=scene.up_axis, azimuth=30, elevation=20, clip_bounds=ground.bounds(scene.up))
    lod = apply_lod(full, cam.position, LodParams(0.25))
    wood = next(m for m in full.prototypes[0].meshes if not m.leaf)
    lod_wood = next(m for m in lod.prototypes[0].meshes if not m.leaf)
    assert wood.triangle_count == 2268 and 0 < lod_wood.triangle_count <= 0.0625 * 2268
    # the trunk, the largest part, is kept: the pruned wood still reaches the ground
    up = np.asarray(scene.up, dtype=np.float64)
    assert np.isclose((lod_wood.corners @ up).min(), (wood.corners @ up).min(), atol=1e-5)
    ratio = lod.triangle_count / full.triangle_count
    assert abs(ratio - (0.25 * 3000 + lod_wood.triangle_count) / 5268) < 0.03 and ratio < 0.2
    light = choose_lighting(scene, None, warnings).lighting
    frames = {}
    for name, s in (("full", full), ("lod", lod)):
        with Renderer(s, samples=4, sky_samples=4) as r:
            frames[name] = r.render(cam, light, ground=ground)
    a, b = frames["full"], frames["lod"]
    # measured: coverage -0.9 %, picture mean luminance +0.1 %, crown mean luminance +6 % (thinned crowns
    # show more sunlit leaves); limits 3 %, 3 % and 10 %
    assert abs(b.tree.mean() / a.tree.mean() - 1) < 0.03
    assert abs(luminance(b.radiance).mean() / luminance(a.radiance).mean() - 1) < 0.03
    tree = a.tree > 0.5
    assert abs(luminance(b.radiance)[tree].mean() / luminance(a.radiance)[tree].mean() - 1) < 0.10

"""SPPG bake time against triangle count, and ray-count vs grid optical depth (shinya2013 issue #5).

Part 1 — bake time. Generated trees (``examples/make_tree.build_tree``, arrays
only, no USD round trip) of about 10k, 100k and 1M leaf triangles (two per
card, plus the wood, which both depth paths ignore). Timed: density grid
(area method, 64 voxels along the longest edge, the ``foliage spp`` default)
+ optical depths at every leaf toward the sun and 16 directions + G-factor +
``solve_sppg`` (sun and sky), for both ``foliage spp --depth`` paths: grid
(density integral, own leaf taken out) and rays (16 crossing-count rays per
leaf; not on 1M triangles, where it would take minutes). Numba compilation is
excluded (one warm-up bake on a small tree first). The paper's figure is
beside it: 117 ms for 1M polygons on a 2009 GPU (shinya2013 sec. 6).

Part 2 — depth paths. Per leaf, the optical depth toward the sun from the grid
path (``lighting.depth``) and from leaf crossing counts through the actual
leaf triangles (``lighting.raydepth``; one crossing = one optical depth),
on ``examples/tree_small.usda`` and the Webots oak: median and 95th
percentile of |ray - grid| / grid over leaves with grid depth >= 0.5 (shallower
leaves make the ratio meaningless), for 1 ray per leaf (the paper's single
count) and 16 rays per leaf (area average, Poisson noise / 4), with the grid
path's own-leaf area left in (the plain integral at the leaf centre) and taken
out (what ``foliage spp`` does); then the mean depth of both paths against the
grid resolution. The leaves' own projection function toward the sun,
G(sun) = area-weighted mean |n·sun|, is printed beside: the grid path assumes
0.5 (random leaf angles), the ray path sees the real leaves, so the two differ
by about G(sun)/0.5 once the own leaf is out.

Usage: ``python benchmarks/bench_sppg.py [--quick]`` (``--quick`` skips 1M
and the ray depths of the 100k tree).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
OAK = REPO.parent / "shared" / "assets" / "webots_oak" / "oak.usda"
EXAMPLE = REPO / "examples" / "tree_small.usda"
PAPER_MS_1M = 117.0


def _leaf_triangles(geo) -> np.ndarray:
    quads = geo.leaf_points.reshape(-1, 4, 3)
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def bake_arrays(tri, centers, normals, sun, up, resolution=64, n_dirs=16, depth="grid"):
    """The timed SPPG bake on plain arrays; returns (seconds per stage, result).

    ``depth``: ``grid`` (density integral, own leaf taken out) or ``rays`` (16 crossing-count rays per leaf),
    the two ``foliage spp --depth`` paths."""
    from foliage_tools.geometry.voxelize import area_per_voxel, grid_for_bounds
    from foliage_tools.lighting import depth as dp
    from foliage_tools.lighting import gfactor as gf
    from foliage_tools.lighting.spp import raydepth as rd
    from foliage_tools.lighting.optics import parse_leaf_optics

    optics = parse_leaf_optics(None)
    ids = np.tile(np.arange(len(centers)), len(tri) // len(centers))  # _leaf_triangles: all first halves, then all second
    t = {}
    t0 = time.perf_counter()
    pts = tri.reshape(-1, 3)
    grid = grid_for_bounds(pts.min(0), pts.max(0), resolution=resolution)
    rho = area_per_voxel(tri, grid) / grid.voxel_volume
    t["density"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    dirs = gf.sample_directions(n_dirs, up=up)
    if depth == "rays":
        ds = rd.leaf_ray_depth_samples(tri, ids, sun_direction=sun, directions=dirs, rays_per_leaf=16)
    else:
        ds = dp.depth_samples(rho, grid, sun_direction=sun, directions=dirs, points=centers, leaf_triangles=tri, leaf_of_triangle=ids)
    t["depths"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = gf.solve_sppg(ds, normals=normals, optics=optics, sun_direction=sun, directions=dirs, up=up)
    t["G+solve"] = time.perf_counter() - t0
    t["total"] = sum(t.values())
    return t, res


def tree_arrays(n_leaf_triangles: int, seed: int = 1):
    from make_tree import build_tree

    n = n_leaf_triangles // 2
    # total leaf area of examples/tree_small (1500 cards of 0.1 m: 15 m² in the same 4 m / 1.2 m crown)
    size = 0.1 * np.sqrt(1500 / n)
    geo = build_tree(leaves=n, leaf_size=float(size), crown="ellipsoid", height=4.0, crown_radius=1.2, seed=seed)
    tri = _leaf_triangles(geo)
    quads = geo.leaf_points.reshape(-1, 4, 3)
    centers = quads.mean(axis=1)
    normals = np.cross(quads[:, 1] - quads[:, 0], quads[:, 2] - quads[:, 0])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    return tri, centers, normals


def sun_vector(az=45.0, el=60.0):
    a, e = np.radians(az), np.radians(el)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def part_time(sizes, ray_sizes):
    up = np.array([0.0, 0.0, 1.0])
    sun = sun_vector()
    tri, c, n = tree_arrays(2000)
    bake_arrays(tri, c, n, sun, up)  # warm-up: numba compile / cache load
    print("SPPG bake time (density 64^3-ish grid + depths at leaves, sun + 16 dirs + G + solve_sppg with sky)")
    print("depths: grid = density integral without the own leaf; rays = 16 crossing-count rays per leaf (foliage spp --depth)")
    print(f"{'leaf tris':>10} {'leaves':>8} {'depth':>6} {'density s':>10} {'depths s':>9} {'G+solve s':>10} {'total s':>8}  paper (1M polys, 2009 GPU)")
    for s in sizes:
        tri, c, n = tree_arrays(s)
        for depth in ("grid", "rays") if s in ray_sizes else ("grid",):
            t, res = bake_arrays(tri, c, n, sun, up, depth=depth)
            paper = f"{PAPER_MS_1M / 1000:.3f} s" if s >= 1_000_000 else ""
            print(f"{len(tri):>10} {len(c):>8} {depth:>6} {t['density']:>10.3f} {t['depths']:>9.3f} {t['G+solve']:>10.3f} {t['total']:>8.3f}  {paper}")
            assert np.all(np.isfinite(res.sppg.scattered))


def depth_comparison(path, rays_per_leaf=1, resolution=64, seed=0, own_removed=True):
    """(grid depths, ray depths) per leaf of the first prototype, sun in prototype space.

    ``own_removed``: the grid path without each leaf's own area (what ``foliage spp`` does);
    False gives the plain grid integral at the leaf centre (own leaf included)."""
    from foliage_tools.lighting import depth as dp
    from foliage_tools.lighting import gfactor as gf
    from foliage_tools.lighting.spp import raydepth as rd
    from foliage_tools.params import DensityParams
    from foliage_tools.pipeline.density import compute_density
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake, sun_in_prototype

    report, scene, sun = begin_bake("spp", Path(path), None, None, Silent())
    proto = scene.prototypes[0]
    sun_local = sun_in_prototype(scene, 0, sun, report.warnings)
    dirs = gf.sample_directions(16)
    dens = compute_density(proto, DensityParams(resolution=resolution, method="area"))
    own = {"leaf_triangles": proto.triangles(leaves=True), "leaf_of_triangle": rd.prototype_leaf_ids(proto)} if own_removed else {}
    g = dp.depth_samples(dens.density, dens.grid, sun_direction=sun_local, directions=dirs, points=proto.leaves.centers, **own)
    r = rd.leaf_ray_depth_samples(
        proto.triangles(leaves=True), rd.prototype_leaf_ids(proto), sun_direction=sun_local, directions=dirs,
        rays_per_leaf=rays_per_leaf, centers=proto.leaves.centers if rays_per_leaf == 1 else None, seed=seed,
    )
    return g, r


def leaf_projection_toward_sun(path) -> float:
    """Area-weighted mean |n · sun| of the first prototype's leaves (Ross' G toward the sun, measured)."""
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake, sun_in_prototype

    report, scene, sun = begin_bake("spp", Path(path), None, None, Silent())
    proto = scene.prototypes[0]
    s = sun_in_prototype(scene, 0, sun, report.warnings)
    a = proto.leaves.areas
    return float(np.sum(a * np.abs(proto.leaves.normals @ s)) / np.sum(a))


def relative_stats(g, r, min_depth=0.5):
    gd, rdp = g.sun_depth, r.sun_depth
    keep = gd >= min_depth
    rel = np.abs(rdp[keep] - gd[keep]) / gd[keep]
    return {
        "leaves": int(gd.size), "used": int(keep.sum()),
        "median": float(np.median(rel)), "p95": float(np.percentile(rel, 95)),
        "mean_ratio": float(rdp[keep].mean() / gd[keep].mean()),
        "mean_diff_all": float(np.mean(rdp - gd)),
    }


def part_depth():
    print("\nPer-leaf optical depth toward the sun: ray counts (lighting.raydepth) vs grid integral (lighting.depth, 64 vox)")
    print("relative difference |ray - grid| / grid over leaves with grid depth >= 0.5; grid path with the leaf's own")
    print("area left in ('own in', the plain integral at the leaf centre) and taken out ('own out', what foliage spp does)")
    print("(mean diff: mean of ray - grid over all leaves, in optical depth)")
    print(f"{'asset':>16} {'rays/leaf':>9} {'grid':>8} {'leaves':>7} {'used':>5} {'median':>7} {'p95':>7} {'mean ray/mean grid':>19} {'mean diff':>10}")
    for name, path in (("tree_small", EXAMPLE), ("webots_oak", OAK)):
        if not path.exists():
            print(f"{name:>16}  (missing {path})")
            continue
        g_sun = leaf_projection_toward_sun(path)
        print(f"{name:>16}  leaves' G(sun) = {g_sun:.3f} (the grid path assumes 0.5)")
        for k in (1, 16):
            for own_removed in (False, True):
                g, r = depth_comparison(path, rays_per_leaf=k, own_removed=own_removed)
                s = relative_stats(g, r)
                label = "own out" if own_removed else "own in"
                print(f"{name:>16} {k:>9} {label:>8} {s['leaves']:>7} {s['used']:>5} {s['median']:>7.3f} {s['p95']:>7.3f} "
                      f"{s['mean_ratio']:>19.3f} {s['mean_diff_all']:>10.3f}")


def part_resolution():
    """Mean sun depth per path against the grid resolution: the plain grid path at a leaf centre also
    integrates the leaf's own area smeared over its voxels, which grows as voxels shrink below the leaf;
    with the own leaf taken out the grid path should not drift with resolution."""
    print("\nMean per-leaf sun depth: grid path at 32/64/128 voxels (own leaf in / out) vs ray counts (16 rays per leaf, own leaf skipped)")
    print(f"{'asset':>16} {'grid':>8} {'32 vox':>8} {'64 vox':>8} {'128 vox':>8} {'rays':>6}")
    for name, path in (("tree_small", EXAMPLE), ("webots_oak", OAK)):
        if not path.exists():
            continue
        for own_removed in (False, True):
            vals = []
            for res in (32, 64, 128):
                g, r = depth_comparison(path, rays_per_leaf=16, resolution=res, own_removed=own_removed)
                vals.append(g.sun_depth.mean())
            label = "own out" if own_removed else "own in"
            print(f"{name:>16} {label:>8} {vals[0]:>8.3f} {vals[1]:>8.3f} {vals[2]:>8.3f} {r.sun_depth.mean():>6.3f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the 1M-triangle tree and the ray depths of the 100k one")
    args = ap.parse_args(argv)
    sizes = [10_000, 100_000] if args.quick else [10_000, 100_000, 1_000_000]
    ray_sizes = {10_000} if args.quick else {10_000, 100_000}  # rays on 1M triangles would take ~10 minutes
    part_depth()
    part_resolution()
    print()
    part_time(sizes, ray_sizes)
    return 0


if __name__ == "__main__":
    sys.exit(main())

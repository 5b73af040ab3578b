"""SPP/SPPG in shinya2013's own setting (sec. 4.2, Table 3) and in its own metric, with the terms taken apart.

Setting of Table 3: one isolated tree, "directional light illuminating it from above", r = t (isotropic phase),
albedo 0.95. Metric: eq. (30) over classes of meshes by depth d = n+ and thickness w = n+ + n- "averaging n+ and n-
of the light rays that intersect the mesh" (eq. 29), of the *total* irradiance of a mesh (the MC counts every
intersection). Printed with (<L>^2 - <L0>^2) under the root; ``literal`` below evaluates that form as printed
(signed: negative when the model is darker), ``table3`` the squared difference of class means.

Per scene the reference is traced once (cached in --cache, keyed by scene, optics, sun, noise and paths; delete
the file to trace again), then every variant is scored (``--g-variants``: the sppg rows' G-factor options)::

    python benchmarks/bench_sppg_table3.py examples/tree_small.usda \\
        ../shared/assets/webots_oak/oak.usda ../shared/assets/sapling_blendertree/blender_tree.usda

Columns (binned total, eq. 30): ``exact-direct`` the bench's ``binned_rms_total`` (the exact direct light added to
the method's scattered light, classes from one ray at the leaf centre); ``own-direct`` the method's own direct term
(``binned_rms_total_volume``); ``area-classes`` as ``exact-direct`` with classes from 16 rays per leaf (the paper's
area-averaged counts); ``literal``; and the diagnostics: the SS score (= the scattered share of the total in this
metric, the scale every other score is relative to) and each method's error over that share.
"""

from __future__ import annotations

import argparse
from types import SimpleNamespace
from pathlib import Path

import numpy as np

from foliage_tools.bench.metrics import binned_rms
from foliage_tools.lighting.spp import raydepth as rd
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bench import depth_thickness
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_sppg
from foliage_tools.pipeline.gather import bake_gather, resolve_rays
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.spp import SppParams, bake_spp
from foliage_tools.pipeline.stage import begin_bake
from foliage_tools.pipeline.world import bake_world


def literal_eq30(x, ref, depth, thickness, bins=8) -> float:
    """shinya2013 eq. (30) as printed, sqrt(Σ(<L>² - <L0>²)/Σ<L0>²), signed (−sqrt(−…) when negative)."""
    classes = _classes(depth, thickness, bins)
    mx, mr = _class_means(x, classes), _class_means(ref, classes)
    v = float(np.sum(mx**2 - mr**2) / np.sum(mr**2))
    return float(np.sign(v) * np.sqrt(abs(v)))


def _classes(d, w, bins):
    def q(v):
        edges = np.unique(np.quantile(v, np.linspace(0, 1, bins + 1)[1:-1]))
        return np.searchsorted(edges, v, side="right")

    return np.unique(q(d) * (bins + 1) + q(w), return_inverse=True)[1]


def _class_means(x, inv):
    x2 = np.asarray(x, dtype=np.float64).reshape(len(inv), -1)
    counts = np.bincount(inv)
    return np.stack([np.bincount(inv, weights=x2[:, c]) for c in range(x2.shape[1])], axis=1) / counts[:, None]


def run(path: Path, args) -> None:
    optics = parse_leaf_optics(args.leaf_optics)
    _, scene, sun = begin_bake("bench", path, None, tuple(args.sun), Silent())
    key = f"{path.stem}-ref-{args.leaf_optics}-{args.sun[0]:g},{args.sun[1]:g}-{args.noise:g}-{args.paths}.npz"
    if (args.cache / key).exists():  # the reference of an earlier run (seed 0): only the methods are re-run
        z = np.load(args.cache / key)
        res = SimpleNamespace(e_direct=z["e_direct"], e_scattered=z["e_scattered"], paths=int(z["paths"]),
                              noise_rel=float(z["noise_rel"]), noise_rel_total=float(z["noise_rel_total"]))
        world = bake_world(scene)
    else:
        ref = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=args.paths, seed=0, noise=args.noise), Silent())
        world, res = ref.world, ref.result
        np.savez(args.cache / key, e_direct=res.e_direct, e_scattered=res.e_scattered, paths=res.paths,
                 noise_rel=res.noise_rel, noise_rel_total=res.noise_rel_total)
    ref_direct, ref_scat = res.e_direct, res.e_scattered
    ref_total = ref_direct + ref_scat
    depth, thick = depth_thickness(world, sun.direction)
    lrd = rd.leaf_ray_depths(world.triangles, world.leaf_of_triangle, sun_direction=sun.direction,
                             directions=[sun.direction], rays_per_leaf=16, seed=1)
    ad, at = lrd.depths.sun_depth, lrd.depths.sun_thickness
    exact = bake_direct(scene, sun, DirectChoice(), Silent(), world=world)
    ex_dir = np.repeat(exact.result.e_direct[:, None], 3, axis=1)
    print(f"\n## {path.name}: {int(world.offsets[-1])} leaves, reference {res.paths:,} paths, noise {res.noise_rel:.3f}"
          f" (total {res.noise_rel_total:.3f}); scattered / total (leaf sums) {ref_scat.sum() / ref_total.sum():.3f}")
    print("| method | depths | exact-direct | own-direct | area-classes | literal | / SS | mean G | S/S_ref lowest 5th |")
    print("|---|---|---|---|---|---|---|---|---|")
    low = depth >= np.quantile(depth, 0.8)
    variants = [tuple(v.split(":")) for v in args.g_variants.split(",")]
    for model in ("spp", "exact"):
        for dpath in args.depths.split(","):
            dkind = "rays" if dpath == "rays" else "grid"
            dres = int(dpath.removeprefix("grid")) if dpath.startswith("grid") and dpath != "grid" else None
            for k, (weights, gres, *more) in enumerate(variants):
                gres = int(gres.removeprefix("g"))
                march = "march" in more
                params = SppParams(optics=optics, sun=tuple(args.sun), model=model, depth=dkind, depth_resolution=dres,
                                   g_weights=weights, g_resolution=gres, g_orders="orders" in more,
                                   first_order="march" if march else "slab")
                bakes = bake_spp(scene, sun, params, [], Silent())
                if march:  # the first order from the exact direct light (--first-order march)
                    bakes = march_sppg(scene, sun, optics, bakes, exact, Silent())
                r = {b.index: b.result for b in bakes}
                gathered = None
                if "gather" in more:  # spp's default final gather (--gather auto) on SPPG's light
                    rays = resolve_rays(None, int(world.offsets[-1]), [])
                    gathered = bake_gather(scene, sun, optics, {i: v.sppg.scattered for i, v in r.items()}, rays, Silent(),
                                           world=world)
                g = from_prototypes(world, {i: np.repeat(v.gfactor[:, None], 3, axis=1) for i, v in r.items()})[:, 0]
                for which in ("ss", "spp", "sppg"):
                    own = from_prototypes(world, {i: getattr(v, which).direct for i, v in r.items()})
                    scat = from_prototypes(world, {i: getattr(v, which).scattered for i, v in r.items()})
                    name = f"{which}{'-paper' if model == 'spp' else ''}"
                    if which == "sppg":
                        tags = [t for t in ("orders", "march", "gather") if t in more]
                        name += f" ({', '.join([weights, f'g{gres}', *tags])})"
                        if gathered is not None:
                            scat = gathered.result.e_scattered
                    if (which == "ss" and model == "exact") or (which != "sppg" and k > 0):
                        continue  # ss and spp do not depend on G
                    e = binned_rms(ex_dir + scat, ref_total, depth, thick)
                    ss_share = binned_rms(ex_dir, ref_total, depth, thick)
                    lowr = scat[low].sum() / max(ref_scat[low].sum(), 1e-300)
                    print(f"| {name} | {dpath} | {e:.3f} | {binned_rms(own + scat, ref_total, depth, thick):.3f} | "
                          f"{binned_rms(ex_dir + scat, ref_total, ad, at):.3f} | "
                          f"{literal_eq30(ex_dir + scat, ref_total, depth, thick):+.3f} | {e / ss_share:.2f} | "
                          f"{g.mean():.3f} | {lowr:.2f} |")
            if model == "exact" and dpath == "grid":
                np.savez(args.cache / f"{path.stem}.npz", ref_direct=ref_direct, ref_scat=ref_scat, ex_dir=ex_dir,
                         depth=depth, thick=thick, ad=ad, at=at, g=g,
                         spp=from_prototypes(world, {i: v.spp.scattered for i, v in r.items()}),
                         own=from_prototypes(world, {i: v.spp.direct for i, v in r.items()}),
                         centers=world.leaf_centers)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--sun", type=float, nargs=2, default=(0.0, 90.0), metavar=("AZ", "EL"))
    ap.add_argument("--leaf-optics", default="0.475,0.475")
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--paths", type=int, default=64_000_000)
    ap.add_argument("--depths", default="rays,grid",
                    help="depth paths of the rows: rays, grid (--depth-resolution auto) or gridN (--depth-resolution N)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/bench_sppg_table3"))
    ap.add_argument("--g-variants", default="paper:g0,radiance:g0,paper:g16,radiance:g16",
                    help="G-factor variants of the sppg rows, WEIGHTS:gRES[:orders[:march[:gather]]] (--g-weights, --g-resolution, g0: "
                         "per leaf; --g-orders; --first-order march, else slab; gather: spp's --gather auto on top)")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    for s in args.scenes:
        run(s, args)


if __name__ == "__main__":
    main()

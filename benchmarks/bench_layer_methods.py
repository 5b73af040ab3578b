"""Every method's E_scattered on a uniform leaf layer against the reference on the same (finite) layer, per depth bin.

Usage (the README's layer table)::

    python examples/make_layer.py --out /tmp/layer60.usda --sun 0,60
    python benchmarks/bench_layer_methods.py /tmp/layer60.usda 0.45,0.45 0,60
    python examples/make_layer.py --out /tmp/layer30.usda --sun 0,30
    python benchmarks/bench_layer_methods.py /tmp/layer30.usda 0.1,0.1 0,30 [spp,sppg,spp-paper,lb-64,spp+gather,sppg+gather,lb+gather]

Arguments: the layer, --leaf-optics, --sun, and optionally the methods. An SPP
method takes options after colons: ``sppg:radiance:g16`` is ``--g-weights
radiance --g-resolution 16`` (``:paper``: the default weights; ``:g0``: per-leaf depths; ``:orders`` / ``:once``: ``--g-orders`` /
``--no-g-orders``; ``:march`` / ``:slab``: ``--first-order``; ``lb-64:march``: LB's ``--first-order march``; ``:rN``: ``--depth-resolution N``; the exact slab's defaults are g16, orders and the
automatic depth resolution). The
reference stops at 4 % per-leaf noise (a bin holds ~2000 leaves); bins are
0.3 m of depth over the inner region |x|, |y| < 3.5 m, top to bottom.

The reference is cached next to the layer (``LAYER.ref-OPTICS-SUN.npz``: its
per-leaf E_direct, E_scattered, paths and noise; seed 0), so a second run of
other methods on the same layer, optics and sun skips the minutes of tracing;
delete the file to trace again. The gather methods need the traced world and
rebuild it when the reference came from the cache.
"""
from __future__ import annotations

import sys
import time
from types import SimpleNamespace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from foliage_tools.pipeline.stage import begin_bake  # noqa: E402
from foliage_tools.pipeline.report import Silent  # noqa: E402
from foliage_tools.pipeline.spp import SppParams, bake_spp  # noqa: E402
from foliage_tools.pipeline.lb import LBBakeParams, bake_lb, later_orders, marches  # noqa: E402
from foliage_tools.pipeline.gather import bake_gather  # noqa: E402
from foliage_tools.pipeline.first_order import march_lb, march_sppg  # noqa: E402
from foliage_tools.pipeline.direct import DirectChoice, bake_direct  # noqa: E402
from foliage_tools.pipeline.reference import ReferenceParams, bake_reference  # noqa: E402
from foliage_tools.lighting.optics import parse_leaf_optics  # noqa: E402
from foliage_tools.bench.metrics import rel_rms  # noqa: E402


def main(argv: list[str]) -> int:
    if len(argv) < 3:
        print(__doc__)
        return 2
    path, optics_s, sun_s = argv[0], argv[1], argv[2]
    methods = argv[3].split(",") if len(argv) > 3 else ["spp", "sppg", "spp-paper", "lb-64", "spp+gather", "sppg+gather", "lb+gather"]
    optics = parse_leaf_optics(optics_s); sun_t = tuple(float(x) for x in sun_s.split(","))
    _, scene, sun = begin_bake("spp", Path(path), None, sun_t, Silent())
    t = time.perf_counter()
    cache_path = Path(f"{path}.ref-{optics_s}-{sun_s}.npz")
    if cache_path.exists():
        z = np.load(cache_path)
        ref = SimpleNamespace(e_direct=z["e_direct"], e_scattered=z["e_scattered"], paths=int(z["paths"]), noise_rel=float(z["noise_rel"]))
        world = None
    else:
        refb = bake_reference(scene, sun, ReferenceParams(optics=optics, paths=16_000_000, noise=0.04), Silent())
        ref, world = refb.result, refb.world
        np.savez(cache_path, e_direct=ref.e_direct, e_scattered=ref.e_scattered, paths=ref.paths, noise_rel=ref.noise_rel)
    c = scene.prototypes[0].leaves.centers
    inner = (np.abs(c[:, 0]) < 3.5) & (np.abs(c[:, 1]) < 3.5)
    bins = np.clip(np.digitize(1.5 - c[:, 2], np.linspace(0, 1.5, 6)) - 1, 0, 4)
    def binline(e, r):
        return " ".join(f"{100*(e[inner&(bins==k)].mean()/r[inner&(bins==k)].mean()-1):+.1f}" for k in range(5))
    print(f"== {Path(path).name} {optics_s} sun {sun_s}: reference {ref.paths:,} paths, noise {ref.noise_rel:.3f} ({time.perf_counter()-t:.0f} s)", flush=True)
    d = bake_direct(scene, sun, DirectChoice(), Silent(), world=world)
    print(f"  direct (rays, {d.result.samples_per_leaf}/leaf) {d.result.seconds:.1f}s  E_direct bins vs ref {binline(d.result.e_direct, ref.e_direct[:,0])}", flush=True)
    for m in methods:
        t = time.perf_counter()
        if m.startswith("spp") or m == "sppg":
            base, *opts = m.removesuffix("+gather").split(":")
            model = "spp" if "paper" in base else "exact"
            kw = {}
            for opt in opts:  # sppg:radiance:g16 = --g-weights radiance --g-resolution 16
                if opt in ("paper", "radiance"):
                    kw["g_weights"] = opt
                elif opt in ("orders", "once"):
                    kw["g_orders"] = opt == "orders"
                elif opt in ("march", "slab"):  # the first order of SPPG (--first-order)
                    kw["first_order"] = opt
                elif opt.startswith("r"):  # sppg:r16 = --depth-resolution 16 (the density grid of the depths)
                    kw["depth_resolution"] = int(opt[1:])
                else:
                    kw["g_resolution"] = int(opt.removeprefix("g"))
            params = SppParams(optics=optics, sun=sun_t, model=model, **kw)
            bakes = bake_spp(scene, sun, params, [], Silent())
            if params.first_order == "march":
                bakes = march_sppg(scene, sun, optics, bakes, d, Silent())
            b = bakes[0].result
            e = (b.sppg if m.startswith("sppg") else b.spp).scattered  # spp+gather: on SPP, sppg+gather: on SPPG
        elif m.startswith("lb"):  # lb-64:march = --first-order march
            base, *opts = m.removesuffix("+gather").split(":")
            res = 32 if base == "lb" else int(base.split("-")[1])
            params = LBBakeParams(optics=optics, sun=sun_t, resolution=res, first_order="march" if "march" in opts else "field")
            bakes = bake_lb(scene, sun, params, [], Silent())
            if marches(params):
                later = {b.index: later_orders(b, scene.prototypes[b.index].leaves.centers) for b in bakes}
                bakes = march_lb(scene, sun, optics, bakes, later, d, Silent())
            e = bakes[0].e_scattered
        if m.endswith("+gather"):
            e = bake_gather(scene, sun, optics, {0: e}, 1024, Silent(), world=world).per_prototype[0]
        dt = time.perf_counter() - t
        print(f"  {m:<22} {dt:6.1f}s relRMS {rel_rms(e, ref.e_scattered):.3f}  bins {binline(e[:,1], ref.e_scattered[:,1])}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

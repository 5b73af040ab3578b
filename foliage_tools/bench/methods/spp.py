"""shinya2013's SPP, SPPG and single-scattering (SS) baseline as bench methods.

``spp`` / ``sppg``: the default plane-parallel model, the exact slab solution per leaf (``--model exact``), without and
with the G-factor (G from a 16-voxel grid, once per order of scattering: ``foliage spp``'s defaults); ``spp-paper`` / ``sppg-paper``: the paper's closed form (``--model spp``), which loses about half
the scattered light of a high sun even where the canopy is exactly plane-parallel (lighting/spp/). One bake serves
a model's three rows; each row is timed with its own bake.
"""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_sppg
from foliage_tools.pipeline.spp import SppParams, bake_spp


def with_first_order(ctx: BenchContext, params: SppParams, bakes: list) -> list:
    """``bakes`` with SPPG's first order marched (``--first-order march``) when ``params`` asks for it, as
    ``foliage spp`` writes it."""
    if not (params.gfactor and params.first_order == "march"):
        return bakes
    direct = ctx.direct or bake_direct(ctx.scene, ctx.sun, DirectChoice(), Silent())
    return march_sppg(ctx.scene, ctx.sun, ctx.optics, bakes, direct, Silent())


def _runner(which: str, model: str, g_weights: str = SppParams.g_weights, **g_options):
    def run(ctx: BenchContext) -> MethodOutput:
        params = SppParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation), model=model, g_weights=g_weights,
                           **g_options)
        bakes = with_first_order(ctx, params, bake_spp(ctx.scene, ctx.sun, params, ctx.warnings, Silent()))
        irr = {b.index: getattr(b.result, which) for b in bakes}
        return MethodOutput(
            e_direct={i: v.direct for i, v in irr.items()},
            e_scattered={i: v.scattered for i, v in irr.items()},
            stats={"gfactor_mean": [float(b.result.gfactor.mean()) for b in bakes], "model": model, "g_weights": g_weights, **g_options},
        )

    return run


register("ss", "single scattering baseline (shinya2013 sec. 4.2: attenuated direct light only)")(_runner("ss", "exact"))
register("spp", "exact plane-parallel slab per leaf, no G-factor (--no-gfactor), depths through the depth grid")(_runner("spp", "exact"))
register("sppg", "exact plane-parallel slab per leaf with the G-factor (shinya2013 eqs. 23-28, A.3), first order marched "
         "from the exact direct light (--first-order march)")(_runner("sppg", "exact"))
register("sppg-slab", "sppg with the slab's first order times G (--first-order slab)")(
    _runner("sppg", "exact", first_order="slab"))
register("spp-paper", "shinya2013's simplified plane-parallel closed form (eqs. 17-22, re-derived)")(_runner("spp", "spp"))
register("sppg-paper", "shinya2013's SPP closed form with the G-factor (the paper's SPPG)")(_runner("sppg", "spp"))
register("sppg-radiance", "exact plane-parallel slab per leaf with the radiance-weighted G-factor and the slab's first "
         "order (--g-weights radiance --first-order slab)")(
    _runner("sppg", "exact", "radiance", first_order="slab"))
register("sppg-paper-radiance", "shinya2013's SPP closed form with the radiance-weighted G-factor")(_runner("sppg", "spp", "radiance"))
register("sppg-once", "exact slab with G per leaf, applied once (--g-resolution 0 --no-g-orders)")(
    _runner("sppg", "exact", g_resolution=0, g_orders=False))

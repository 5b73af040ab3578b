"""Final gather over the actual leaves on LB and SPPG (``--gather``) as bench methods."""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.gather import bake_gather
from foliage_tools.pipeline.lb import LBBakeParams, bake_lb
from foliage_tools.pipeline.report import Silent
from foliage_tools.bench.methods.lb import with_first_order as lb_first_order
from foliage_tools.bench.methods.spp import with_first_order
from foliage_tools.pipeline.spp import SppParams, bake_spp

#: Gather rays per leaf of the bench rows (the default of ``--gather`` when it is asked for).
RAYS = 1024
#: LB lattice under the gather: the volume method only supplies the second and later bounces.
LB_RESOLUTION = 32


@register("lb+gather", f"final gather ({RAYS} rays per leaf) on LB at {LB_RESOLUTION}: exact first bounce, LB for the rest")
def run_lb(ctx: BenchContext) -> MethodOutput:
    params = LBBakeParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation), resolution=LB_RESOLUTION)
    bakes = lb_first_order(ctx, params, bake_lb(ctx.scene, ctx.sun, params, ctx.warnings, Silent()))
    g = bake_gather(ctx.scene, ctx.sun, ctx.optics, {b.index: b.e_scattered for b in bakes}, RAYS, Silent())
    return MethodOutput(e_direct={b.index: b.e_direct for b in bakes},
                        e_scattered={b.index: g.per_prototype[b.index] for b in bakes}, stats=g.stats(),
                        scattered_per_instance_leaf=g.result.e_scattered)


def _spp_gather(ctx: BenchContext, variant: str) -> MethodOutput:
    params = SppParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation))
    bakes = with_first_order(ctx, params, bake_spp(ctx.scene, ctx.sun, params, ctx.warnings, Silent()))
    g = bake_gather(ctx.scene, ctx.sun, ctx.optics, {b.index: getattr(b.result, variant).scattered for b in bakes},
                    RAYS, Silent())
    return MethodOutput(e_direct={b.index: getattr(b.result, variant).direct for b in bakes},
                        e_scattered={b.index: g.per_prototype[b.index] for b in bakes}, stats=g.stats(),
                        scattered_per_instance_leaf=g.result.e_scattered)


@register("spp+gather", f"final gather ({RAYS} rays per leaf) on SPP (the exact slab): exact first bounce, SPP for the rest")
def run_spp(ctx: BenchContext) -> MethodOutput:
    return _spp_gather(ctx, "spp")


@register("sppg+gather", f"final gather ({RAYS} rays per leaf) on SPPG: exact first bounce, SPPG for the rest")
def run_sppg(ctx: BenchContext) -> MethodOutput:
    return _spp_gather(ctx, "sppg")

"""Boulanger's per-leaf envelope lighting (boulanger2008 ch. 5) as a bench method."""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.smax import SmaxParams, bake_smax


@register("smax", "Boulanger envelope s_max + one-bounce lighting (boulanger2008 ch. 5)")
def run(ctx: BenchContext) -> MethodOutput:
    params = SmaxParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation))
    bakes = bake_smax(ctx.scene, ctx.sun, params, ctx.warnings, Silent())
    return MethodOutput(
        e_direct={b.index: b.lighting.e_direct for b in bakes},
        e_scattered={b.index: b.lighting.e_scattered for b in bakes},
        stats={"tau": [float(b.envelope.tau) for b in bakes], "path": [b.envelope.path for b in bakes]},
    )

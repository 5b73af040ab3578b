"""shinya2013's SPP, SPPG and single-scattering (SS) baseline as bench methods (one bake serves all three)."""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.spp import SppParams, bake_spp


def _runner(which: str):
    def run(ctx: BenchContext) -> MethodOutput:
        params = SppParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation))
        bakes = bake_spp(ctx.scene, ctx.sun, params, ctx.warnings, Silent())
        irr = {b.index: getattr(b.result, which) for b in bakes}
        return MethodOutput(
            e_direct={i: v.direct for i, v in irr.items()},
            e_scattered={i: v.scattered for i, v in irr.items()},
            stats={"gfactor_mean": [float(b.result.gfactor.mean()) for b in bakes]},
        )

    return run


register("ss", "single scattering baseline (shinya2013 sec. 4.2: attenuated direct light only)")(_runner("ss"))
register("spp", "simplified plane-parallel, depths from ray crossings (shinya2013 eqs. 17-22, 29, re-derived)")(_runner("spp"))
register("sppg", "SPP with the G-factor (shinya2013 eqs. 23-28, A.3, re-derived)")(_runner("sppg"))

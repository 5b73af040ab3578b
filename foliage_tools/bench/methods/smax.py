"""Boulanger's per-leaf envelope lighting (boulanger2008 ch. 5) as bench methods: as ``foliage smax`` bakes it, and
the thesis' one bounce alone."""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.smax import SmaxParams, bake_smax


def _run(ctx: BenchContext, scatter: str) -> MethodOutput:
    params = SmaxParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation), scatter=scatter)
    bakes = bake_smax(ctx.scene, ctx.sun, params, ctx.warnings, Silent(), exact=ctx.direct)
    return MethodOutput(
        e_direct={b.index: b.lighting.e_direct for b in bakes},
        e_scattered={b.index: b.lighting.e_scattered for b in bakes},
        stats={"tau": [float(b.envelope.tau) for b in bakes], "path": [b.envelope.path for b in bakes],
               "recollision_probability": [b.lighting.stats["recollision_probability"] for b in bakes]},
    )


@register("smax", "Boulanger envelope s_max, the first order marched from the exact direct light, the later orders "
                  "by the envelope's recollision probability (foliage smax's default, --scatter march)")
def run(ctx: BenchContext) -> MethodOutput:
    return _run(ctx, "march")


@register("smax-leaves", "Boulanger envelope s_max, the thesis' one bounce with the scatterers lit by the leaves' "
                         "exact lit fractions, every order (foliage smax --scatter leaves)")
def run_leaves(ctx: BenchContext) -> MethodOutput:
    return _run(ctx, "leaves")


@register("smax-paper", "Boulanger envelope s_max + the thesis' one bounce, eq. 5.24 (boulanger2008 ch. 5; "
                        "foliage smax --scatter paper)")
def run_paper(ctx: BenchContext) -> MethodOutput:
    return _run(ctx, "paper")

"""Lattice-Boltzmann lighting (geist2008, steele2010) at several resolutions, as bench methods."""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_lb
from foliage_tools.pipeline.lb import LBBakeParams, bake_lb, later_orders, marches
from foliage_tools.pipeline.report import Silent

RESOLUTIONS = (32, 64)


def with_first_order(ctx: BenchContext, params: LBBakeParams, bakes: list) -> list:
    """``bakes`` with the per-leaf first order marched (``--first-order march``) when ``params`` take it, as
    ``foliage lb`` writes it."""
    if not marches(params):
        return bakes
    later = {b.index: later_orders(b, ctx.scene.prototypes[b.index].leaves.centers) for b in bakes}
    direct = ctx.direct or bake_direct(ctx.scene, ctx.sun, DirectChoice(), Silent())
    return march_lb(ctx.scene, ctx.sun, ctx.optics, bakes, later, direct, Silent())


def _runner(resolution: int, single_scatter: str = "exact", first_order: str = "field"):
    def run(ctx: BenchContext) -> MethodOutput:
        params = LBBakeParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation), resolution=resolution,
                              single_scatter=single_scatter, first_order=first_order)
        bakes = with_first_order(ctx, params, bake_lb(ctx.scene, ctx.sun, params, ctx.warnings, Silent()))
        return MethodOutput(
            e_direct={b.index: b.e_direct for b in bakes},
            e_scattered={b.index: b.e_scattered for b in bakes},
            stats={"iterations": [int(b.result.iterations) for b in bakes], "solver": [b.result.solver for b in bakes]},
        )

    return run


for _res in RESOLUTIONS:
    register(f"lb-{_res}", f"lattice-Boltzmann D3Q19, {_res} nodes along the longest edge (geist2008), exact first "
                           "order of scattering of the homogenised beam (--first-order field)")(_runner(_res))
    register(f"lb-{_res}-march", f"lb-{_res} with the per-leaf first order marched from the exact direct light "
                                 "(--first-order march, foliage lb's default)")(_runner(_res, first_order="march"))
register("lb-64-lattice1", "lattice-Boltzmann D3Q19 at 64 with the lattice's own first order of scattering "
                           "(no single-scattering correction)")(_runner(64, "lattice"))

"""Lattice-Boltzmann lighting (geist2008, steele2010) at several resolutions, as bench methods."""

from foliage_tools.bench.registry import BenchContext, MethodOutput, register
from foliage_tools.pipeline.lb import LBBakeParams, bake_lb
from foliage_tools.pipeline.report import Silent

RESOLUTIONS = (32, 64)


def _runner(resolution: int, single_scatter: str = "exact"):
    def run(ctx: BenchContext) -> MethodOutput:
        params = LBBakeParams(optics=ctx.optics, sun=(ctx.sun.azimuth, ctx.sun.elevation), resolution=resolution,
                              single_scatter=single_scatter)
        bakes = bake_lb(ctx.scene, ctx.sun, params, ctx.warnings, Silent())
        return MethodOutput(
            e_direct={b.index: b.e_direct for b in bakes},
            e_scattered={b.index: b.e_scattered for b in bakes},
            stats={"iterations": [int(b.result.iterations) for b in bakes], "solver": [b.result.solver for b in bakes]},
        )

    return run


for _res in RESOLUTIONS:
    register(f"lb-{_res}", f"lattice-Boltzmann D3Q19, {_res} nodes along the longest edge (geist2008), exact first "
                           "order of scattering")(_runner(_res))
register("lb-64-lattice1", "lattice-Boltzmann D3Q19 at 64 with the lattice's own first order of scattering "
                           "(no single-scattering correction)")(_runner(64, "lattice"))

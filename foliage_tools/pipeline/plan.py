"""``foliage plan``: what a bake would do, with estimated time and memory; writes nothing.

Reads the scene (the only expensive step) and, per prototype with leaves,
works out the grid each stage would build and the work and memory that
follow from it. The seconds are *estimates*: work counts divided by rates
measured by ``make bench`` on the 2-core development machine (the constants
below, each with the benchmark row it comes from). Scale them by how your
machine compares; the memory figures do not depend on the machine.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path


from foliage_tools.errors import UsageError
from foliage_tools.lighting.envelope import AUTO_FAST_THRESHOLD
from foliage_tools.params import DEFAULT_RESOLUTION, DensityParams, check_resolution
from foliage_tools.pipeline.density import density_grid
from foliage_tools.pipeline.direct import auto_samples, instance_samples
from foliage_tools.pipeline.gather import auto_rays
from foliage_tools.pipeline.report import Report
from foliage_tools.pipeline.spp import DEPTH_PATHS, SPP_MAX_PLACEMENTS, depth_path
from foliage_tools.pipeline.world import traced_alone, world_triangles
from foliage_tools.scene.read import read_scene
from foliage_tools.pipeline.stats import PlanForestStats, PlanPrototypeStats, PlanStats

#: All rates from one `make bench` on 2026-11-24 (session 4; AMD EPYC, 2 cores, numba triad 35 GB/s). The
#: previous session's host (94 GB/s) ran most of these 1.4-2x faster: estimates, not promises.
#: LB node x right-hand-side updates per second, many (>= 19) / few right-hand sides (bench_lb_issue.py:
#: fused sweep 57 rhs 113-116 MLUPS, 18-base bake of the example at 128^3 122; 3 rhs 92-102 on a uniform grid,
#: 64-73 for the example tree's sun solve at 64^3 / 128^3).
LB_MLUPS_MANY, LB_MLUPS_FEW = 120e6, 70e6
#: LB sweeps to tolerance 1e-5 with the default solver (auto: ordered sweeps first, lighting.lb.solvers): 7 (4
#: ordered, 3 plain measuring ones) for tree_small's sun and relightable bakes at 64^3 and 128^3, physical
#: absorption (lower absorption needs more); an ordered sweep costs about 2 plain ones (64^3, 18 bases x RGB:
#: 0.25 against 0.12 s), so the 7 cost about 11 plain sweeps.
LB_SWEEPS, LB_PLAIN_SWEEP_EQUIVALENTS = 7, 11
#: The relightable bake with fp16 storage runs 13 (9 at 64^3): its ordered sweeps stop at the storage's rounding
#: level, one measurement after it (lighting.lb.solvers._at_storage_floor); its sweeps are 1.5-2.4x faster per node,
#: so they cost about what fp32's 7 do (bench_lb_storage.py 2026-12-04, 128^3: 29.3-30.5 s against 33.6-35.7 s),
#: and the seconds estimate stays that of fp32.
LB_SWEEPS_FP16_BASES = 13
#: What the bake's process holds besides the LB arrays (Python, numba's compiled kernels, USD): the relightable
#: bake's measured peaks less its 2.02-2.06 fields are 0.31 GB at 64^3 and 0.38-0.43 GB at 96^3-128^3 (fp32,
#: bench_lb_storage.py 2026-12-04). The peak memory adds it (the ray scene's WORLD_BASE_BYTES is the same kind of
#: base); the per-prototype LB memory is the solve's alone.
PROCESS_BYTES = 0.3e9
#: Seconds per leaf of the area density kernel (bench_density.py: 100k leaves 0.23 s, 1M 2.07 s).
DENSITY_S_PER_LEAF = 2.2e-6
#: smax: reference pairs per second (O(N^2), bench_smax.py: 40k leaves 4.1-4.3 s, 100k 25-26 s) and
#: fast path per leaf (near field to 4.3 cells: 40k 0.26 s, 100k 0.62 s).
SMAX_PAIRS_PER_S, SMAX_FAST_S_PER_LEAF = 3.8e8, 6.3e-6
#: smax --scatter leaves: (leaf, scatterer) pairs per second of lighting.scatterer_sun (/tmp timing of 5k, 20k and
#: 100k random leaves on the shared 2-core host at load 5-7, 2026-12-02: 3.3-4.6e7; an idle host is ~2x faster).
SMAX_SCATTER_PAIRS_PER_S = 4.0e7
#: SPP ray-count depths: crossing-counting rays per second (bench_sppg.py: 50k leaves x 16 rays x 34 in 42 s).
SPP_RAYS_PER_S = 6.5e5
#: Monte Carlo reference: sun paths per second on 2 workers (bench_reference.py: 3.9e6 on a 2k-leaf crown;
#: `foliage bench` on the example, setup included: 8M paths in 3.8 s).
REFERENCE_PATHS_PER_S = 2.0e6
#: The reference traced through placed prototypes (a forest above WORLD_MAX_TRIANGLES, geometry.instanced): sun
#: paths per second and resident memory per instance beside the prototypes' ray scenes (`foliage reference --paths
#: 4000000` on bench_forest.py's 100 x 100 stand of 5k/10k/20k-leaf trees: 8.9 s tracing, 10.5 s and 0.63 GB in
#: all; 2026-12-02).
PLACED_REFERENCE_PATHS_PER_S, PLACED_REFERENCE_BYTES_PER_INSTANCE = 4.5e5, 2.0e4
#: Each instance's direct mean through the placed forest (pipeline.direct.instance_direct): shadow rays per second
#: (bench_forest.py's 100 x 100 stand, 4096 per instance: 41M rays in 59 s; 2026-12-02).
PLACED_DIRECT_RAYS_PER_S = 6.9e5
#: Exact direct sunlight (--direct rays): shadow rays per second on 2 threads, BVH build included
#: (bench_direct.py, generated lobed trees).
DIRECT_RAYS_PER_S = 1.2e6
#: Final gather (--gather, pipeline.gather): gather rays per second on 2 threads, each with the shadow ray at its
#: hit (`foliage lb --json` stats.gather: tree_small 1.54M rays in 2.2 s, the oak 1.87M in 2.0-3.4 s; 2026-12-02).
GATHER_RAYS_PER_S = 7.0e5
#: The shadow rays and the reference copy every instance's triangles into one ray scene: peak resident memory
#: ~380 MB + 760 B per world triangle (`foliage reference --paths 200000` on tree_small alone and on a 10 x 10
#: stand of it, 5 268 -> 526 800 triangles: 384 -> 781 MB; 2026-12-02).
WORLD_BASE_BYTES, WORLD_BYTES_PER_TRIANGLE = 3.8e8, 760.0
#: The forest lattice (pipeline.forest), seconds per node of the stand's grid, both solves and the exact first
#: order at its tolerance and directions (benchmarks/bench_forest.py, 100 x 100 stand, 4.0M nodes: ~55 s of the
#: smax stage's 58.6 s, 2026-12-02).
FOREST_S_PER_NODE = 1.4e-5
#: LB per node beside the sweeps, a part per node and a part per node and right-hand side (the never-scattered
#: pass, the beams, the sun bake's exact first order, sampling): fitted to tree_small at 64^3 (241 560 nodes), one
#: prototype's bake with auto's ordered sweeps, 0.88 s for the sun (3 rhs) and 5.3 s for --bases all (54),
#: 2026-12-04, less the sweeps' share; predicts 40 s at 128^3 fp16 --bases all against 44 s measured.
LB_S_PER_NODE, LB_S_PER_NODE_RHS = 2.4e-6, 2.7e-7
#: SPP/SPPG per leaf and instance solved (pipeline.spp.SPP_MAX_PLACEMENTS at most), 16 directions, grid depths
#: (bench_forest.py: 3 prototypes x 32 instances of 5k/10k/20k leaves in 73.9 s, 2026-12-02).
SPP_S_PER_LEAF_PLACEMENT = 6.3e-5
#: shinya2013 eq. (31) neighbour depths: seconds per instance pair (issue #16: 3.3-3.7 ms).
SPP_EQ31_S_PER_PAIR = 3.5e-3


def ray_scene_bytes(triangles: int) -> float:
    """Peak resident memory of a ray scene of ``triangles`` placed triangles (:data:`WORLD_BYTES_PER_TRIANGLE`)."""
    return WORLD_BASE_BYTES + WORLD_BYTES_PER_TRIANGLE * triangles


def available_memory() -> float:
    """Bytes the system can give a new allocation now: MemAvailable (Linux), else free physical pages."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


@dataclass(frozen=True)
class PlanParams:
    resolution: int = DEFAULT_RESOLUTION
    bases: str = "sun"
    storage: str = "fp32"
    """LB density storage (``foliage lb --storage``): fp16 holds the solver's two fields in 2 bytes per value."""
    depth: str = "auto"
    rays_per_leaf: int = 16
    directions: int = 16
    reference_paths: int = 1_000_000

    def __post_init__(self) -> None:
        check_resolution(self.resolution)
        if self.bases not in ("sun", "all"):
            raise UsageError(f"--bases must be sun or all, got {self.bases!r}.")
        if self.storage not in ("fp32", "fp16"):
            raise UsageError(f"--storage must be fp32 or fp16, got {self.storage!r}.")
        if self.depth not in DEPTH_PATHS:
            raise UsageError(f"--depth must be one of {', '.join(DEPTH_PATHS)}, got {self.depth!r}.")
        if self.rays_per_leaf < 1 or self.directions < 1 or self.reference_paths < 1:
            raise UsageError("--rays-per-leaf, --directions and --reference-paths must be >= 1.")


def scatterer_pairs(n: int) -> int:
    """(leaf, scatterer) pairs lighting.scatterer_sun sums for n leaves (all, or the nearest and a subset)."""
    from foliage_tools.lighting.envelope.scatterer_sun import MAX_PAIRS, MIN_FAR, NEAR

    if n * n <= MAX_PAIRS:
        return n * n
    return n * (min(NEAR, n) + min(n, max(MIN_FAR, (MAX_PAIRS - n * min(NEAR, n)) // n)))


def plan(path: Path, params: PlanParams) -> Report[PlanStats]:
    from foliage_tools.pipeline.lb import solve_bytes  # (pipeline.lb imports available_memory from here)

    report: Report[PlanStats] = Report(command="plan", inputs=[str(path)])
    scene, warnings = read_scene(path)
    report.warnings.extend(warnings)
    leaves_total = sum(scene.prototypes[inst.prototype].leaves.count for inst in scene.instances)
    depth = depth_path(scene, params.depth)  # for the default --direct rays
    protos: list[PlanPrototypeStats] = []
    total_s = {"density": 0.0, "smax": 0.0, "spp": 0.0, "lb": 0.0}
    peak = 0.0
    for i, proto in enumerate(scene.prototypes):
        n = int(proto.leaves.count)
        if not n:
            continue
        grid = density_grid(proto, DensityParams(resolution=params.resolution))
        nodes = math.prod(grid.shape)
        rhs = 3 * (18 if params.bases == "all" else 1)
        sweeps = LB_SWEEPS_FP16_BASES if params.bases == "all" and params.storage == "fp16" else LB_SWEEPS
        lb_s = (LB_PLAIN_SWEEP_EQUIVALENTS * nodes * rhs / (LB_MLUPS_MANY if rhs >= 19 else LB_MLUPS_FEW)
                + nodes * (LB_S_PER_NODE + rhs * LB_S_PER_NODE_RHS))
        # as bake_prototype holds it with foliage lb's defaults: the sun bake first-collision and exactly corrected,
        # the relightable one's bases as beams with fp16 (the ordinates lattice)
        sun_bake = params.bases == "sun"
        lb_bytes = solve_bytes(grid.shape, rhs, storage=params.storage, relightable=not sun_bake, first_collision=sun_bake,
                               corrected=sun_bake, beam_bases=not sun_bake and params.storage == "fp16")
        fast = n >= AUTO_FAST_THRESHOLD
        smax_s = (n * SMAX_FAST_S_PER_LEAF if fast else n * n / SMAX_PAIRS_PER_S) + scatterer_pairs(n) / SMAX_SCATTER_PAIRS_PER_S
        instances = len(scene.instances_of(i))
        spp_s = n * DENSITY_S_PER_LEAF + min(max(instances, 1), SPP_MAX_PLACEMENTS) * n * SPP_S_PER_LEAF_PLACEMENT
        if depth == "rays":
            spp_s += instances * n * params.rays_per_leaf * (2 * params.directions + 2) / SPP_RAYS_PER_S
        est = {"density": n * DENSITY_S_PER_LEAF, "smax": smax_s, "spp": spp_s, "lb": lb_s}
        for k, v in est.items():
            total_s[k] += v
        peak = max(peak, lb_bytes + PROCESS_BYTES)
        protos.append({
            "path": proto.path, "leaves": n, "instances": instances, "grid": list(grid.shape),
            "voxel_size": grid.voxel_size, "lb_rhs": rhs, "lb_sweeps_estimate": round(sweeps),
            "lb_memory_bytes": round(lb_bytes), "smax_path": "fast" if fast else "reference",
            "seconds_estimate": est,
        })
    if not protos:
        raise UsageError(f"@{path}@ has no leaves to bake: no leaf meshes were found (see `foliage inspect`).")
    avail = available_memory()
    if peak > avail:
        report.warnings.append(
            f"the LB bake would hold ~{peak / 1e9:.1f} GB, more than the {avail / 1e9:.1f} GB of memory free now: "
            "lower --resolution, or use --bases sun (1/18 of the memory)."
        )
    world_tris = world_triangles(scene)
    # the bakes' shadow rays and gather trace the whole world, or above WORLD_MAX_TRIANGLES each prototype alone
    lone = traced_alone(scene, world_tris)
    instanced = sorted({inst.prototype for inst in scene.instances})
    traced_tris = sum(sum(len(m.triangles) for m in scene.prototypes[i].meshes) for i in instanced) if lone else world_tris
    traced_leaves = sum(scene.prototypes[i].leaves.count for i in instanced) if lone else leaves_total
    world_bytes = ray_scene_bytes(traced_tris)
    if lone:  # the reference traces the placed prototypes, nothing copied (pipeline.reference.placed_inputs)
        total_s["reference"] = params.reference_paths / PLACED_REFERENCE_PATHS_PER_S
        reference_bytes = world_bytes + PLACED_REFERENCE_BYTES_PER_INSTANCE * len(scene.instances)
    else:  # every instance copied into one ray scene
        total_s["reference"] = params.reference_paths / REFERENCE_PATHS_PER_S
        reference_bytes = ray_scene_bytes(world_tris)
    peak = max(peak, world_bytes)
    forest: PlanForestStats | None = None
    if len(scene.instances) > 1:
        from foliage_tools.pipeline import forest as forest_mod
        from foliage_tools.pipeline.spp import EQ31_MAX_INSTANCES

        if len(scene.instances) <= EQ31_MAX_INSTANCES:
            total_s["spp"] += len(scene.instances) * (len(scene.instances) - 1) * SPP_EQ31_S_PER_PAIR
        shape = forest_mod.stand_grid(scene).shape
        nodes = math.prod(int(n) for n in shape)
        # the stand's sun solve (3 right-hand sides) with its beam arrays and exact first order, as a tree's
        forest_bytes = solve_bytes(shape, 3, storage="fp32", relightable=False, first_collision=True, corrected=True,
                                   beam_bases=False)
        forest = {"nodes": nodes, "seconds_estimate_per_stage": nodes * FOREST_S_PER_NODE, "memory_bytes": round(forest_bytes)}
        peak = max(peak, forest_bytes + PROCESS_BYTES)
        # smax, spp and lb each scale their instances by it (once per `foliage bake`)
        total_s["forest"] = nodes * FOREST_S_PER_NODE
    # --direct rays (the default): in each of smax, spp and lb run alone, once in a bake; every traced leaf
    direct_rays = traced_leaves * auto_samples(traced_leaves)
    total_s["direct"] = direct_rays / DIRECT_RAYS_PER_S
    if lone:  # and each instance's mean through every placed instance
        placed_rays = len(scene.instances) * instance_samples(len(scene.instances))
        direct_rays += placed_rays
        total_s["direct"] += placed_rays / PLACED_DIRECT_RAYS_PER_S
    # --gather auto (the default of spp and lb): once in each, over the leaves the shadow rays trace (lb's only
    # for a sun bake: auto does not gather --bases all)
    gather_per_leaf = auto_rays(traced_leaves)
    gather_rays = traced_leaves * gather_per_leaf
    for stage in ("spp", "lb") if params.bases == "sun" else ("spp",):
        total_s[stage] += gather_rays / GATHER_RAYS_PER_S
    report.stats = {
        "resolution": params.resolution, "bases": params.bases, "storage": params.storage, "depth": depth,
        "gather_rays_per_leaf": gather_per_leaf, "gather_rays": int(gather_rays),
        "prototypes": protos, "instances": len(scene.instances), "leaves_total": int(leaves_total),
        "seconds_estimate": total_s, "peak_memory_bytes": round(peak), "direct_rays": int(direct_rays),
        "world_triangles": int(world_tris), "world_memory_bytes": round(world_bytes), "forest": forest,
        "traced": "lone trees" if lone else "every instance", "traced_triangles": int(traced_tris),
        "reference_memory_bytes": round(reference_bytes),
        "note": "seconds are estimates from rates measured on a 2-core machine (foliage_tools/pipeline/plan.py)",
    }
    return report.finish()

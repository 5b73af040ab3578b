"""``foliage spp``: simplified plane-parallel scattering with the G-factor (shinya2013 sec. 3–5).

Per prototype: leaf-area density grid (``density``'s area method). Per
instance: optical depth and thickness of every leaf toward the sun and N
sample directions (eq. 29) -> G-factor (eqs. 23–28, A.3, re-derived in
lighting.gfactor) -> per-leaf SPPG, SPP and single-scattering (SS) irradiance
(sec. 5.4 steps 4–6). Per-leaf results are stored once per prototype: the
mean over its instances (as the Monte Carlo reference reports them).

Depth paths (``SppParams.depth``):

* ``grid`` — the leaf-area density integrated along each ray
  (``lighting.depth``), each leaf's own area taken out so a leaf does not
  shadow itself; G-function 0.5 (spherical leaf angles).
* ``rays`` — leaf crossings counted through the actual leaf triangles with
  Embree (``lighting.raydepth``), own leaf skipped, averaged over
  ``rays_per_leaf`` origins on each leaf; the leaves' real orientations
  replace the spherical G-function.

Neither path lets wood block light (the Monte Carlo reference does); SPP's
direct sun is above the reference's (1.07-1.29 per hull-distance quintile of
tree_small with rays), and the missing wood is one candidate cause (not
measured separately).

Forests (shinya2013 eq. (31)): the depth of a leaf of instance n also counts
the leaves of every other instance along the same world ray — through each
neighbour's prototype grid moved into place (``depth.instance_depth_samples``)
or through the neighbours' triangles (rays: one ray per leaf centre and
direction through one world scene of all instances' leaves, the ray's own
instance skipped) — so one prototype density grid serves all instances. Every
instance is checked against every other (O(instances²) rays; fine for groves,
not for thousands of trees). Neighbours placed by a transform that is not a rotation times a
uniform scale are skipped with a warning (optical depth is not invariant).

Grids sppDepth and sppThickness are toward the sun, sppGFactor is G toward
the sun, per cell of the prototype alone, seen by its first instance (grid
path; the cells are not leaves, there is no own leaf).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Any
from functools import partial
from pathlib import Path

import numpy as np

from foliage_tools import __version__
from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import Sun, to_prototype_space
from foliage_tools.lighting import depth as depth_mod
from foliage_tools.lighting import gfactor as gf
from foliage_tools.lighting.spp import raydepth as rd
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.phase import canopy_bilambertian_phase
from foliage_tools.params import DEFAULT_RESOLUTION, DensityParams, check_resolution
from foliage_tools.pipeline.density import DensityResult, compute_density, density_for_bake, density_grid, vdb_path
from foliage_tools.pipeline.direct import DirectBake, DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_sppg
from foliage_tools.pipeline.spp_neighbours import WORKERS, Neighbours, world_points
from foliage_tools.pipeline.gather import GatherBake, bake_gather, check_gather, resolve_rays
from foliage_tools.pipeline.forest import forest_light
from foliage_tools.pipeline.instances import bake_instance_edits, from_prototypes
from foliage_tools.pipeline.world import World, bake_world
from foliage_tools.pipeline.leafdata import baked_sun_attribute, leaf_primvar_edits, native_instance_warning, vertex_primvar_edits
from foliage_tools.pipeline.report import Progress, Report
from foliage_tools.pipeline.stats import SppPrototypeStats, SppStats, sun_stats
from foliage_tools.pipeline.stage import bake_layer
from foliage_tools.pipeline.volumes import prototype_volume
from foliage_tools.scene.model import Prototype, Scene
from foliage_tools.scene.vdb import Grid
from foliage_tools.scene.write import LayerEdits

log = logging.getLogger(__name__)

#: The depth paths of ``--depth``.
DEPTH_PATHS = ("auto", "grid", "rays")
#: ``--first-order``: SPPG's once-scattered light from a march through the leaves' medium or from the slab (SppParams).
FIRST_ORDERS = ("march", "slab")
#: ``--depth auto`` counts rays while the scene has at most this many leaves (summed over instances) and
#: integrates the grid above: rays cost 0.5-1 ms per leaf and instance at the defaults (bench_sppg.py: 50k leaves
#: 25-56 s on two 2-core hosts; 500k would be 4-10 min against 4-7 s for the grid).
AUTO_RAYS_MAX_LEAVES = 50_000
#: ``--g-resolution`` of the exact slab (shinya2013 sec. 5.1-5.2 keeps G on a ~16³ grid). With ``--g-orders`` it
#: measured better than G per leaf, once, on all three test crowns at their optics (per-leaf E_scattered 0.353 /
#: 0.406 / 0.432 against 0.381 / 0.410 / 0.460) and in shinya2013's own setting (binned total 0.045 / 0.136 against
#: 0.296 / 0.267 on tree_small / the oak), and the same within 1 % in the uniform layer (README, issue #15).
G_RESOLUTION = 16
#: ``--depth-resolution auto``: the per-leaf depths of the grid path are integrated through a leaf-area density
#: grid coarsened (from ``--resolution`` down the ladder ``DEPTH_RESOLUTIONS``) until the voxels that hold a leaf
#: centre hold at least this many on average. A grid that resolves single leaves turns a crown's clumping into a
#: dense medium around every leaf (area-weighted leaf-area density 18.6 m^-1 at 64 voxels against 3.1 at 16 on
#: tree_small), which the slab model, a homogeneous random medium, reads as depth the diffuse light does not see.
#: Measured per-leaf E_scattered at the default optics, 64 voxels -> this rule: tree_small 0.353 -> 0.220, the oak
#: 0.406 -> 0.329, the sapling 0.432 -> 0.309; shinya2013's own setting (albedo 0.95) oak 0.108 -> 0.073; the uniform
#: layer at 60 degrees -6.6 .. -9.2 % -> -1.8 .. -5.3 % per depth bin (README, issue #15).
DEPTH_LEAVES_PER_VOXEL = 4.0
#: The resolutions ``--depth-resolution auto`` tries, finest first (none finer than ``--resolution``).
DEPTH_RESOLUTIONS = (512, 384, 256, 192, 128, 96, 64, 48, 32, 24, 16, 12, 8)


@dataclass(frozen=True)
class SppParams:
    """What ``foliage spp`` bakes."""

    optics: LeafOptics
    sun: tuple[float, float] | None = None
    resolution: int = DEFAULT_RESOLUTION
    """Density grid voxels along the longest foliage edge."""
    directions: int = gf.DEFAULT_DIRECTIONS
    """Sample directions for the G-factor and the sky (the paper used 16–22)."""
    gfactor: bool = True
    """False (``--no-gfactor``): the SPP bake without G; the sppg primvars are then not written."""
    refine: bool = False
    """Integrate the refined radiance of appendix A.1 for the sun's scattered light."""
    model: str | None = None
    """``--model``: ``exact`` (the exact slab solution per leaf, lighting.slab_table) or ``spp`` (shinya2013's closed
    form, eqs. 17-22); None: ``spp`` with ``refine``, else ``exact``."""
    g_weights: str = gf.SPPGParams.g_weights
    """``--g-weights``: how G combines its sample directions (lighting.gfactor): ``paper`` (shinya2013 eq. 27, the
    equal-weight mean) or ``radiance`` (weighted by the plane-parallel single-scattering radiance from each)."""
    g_orders: bool | None = None
    """``--g-orders``: G per order of scattering, G s / (1 - (1 - s) ρ) with s the exact slab's once-scattered
    share and ρ the real medium's recollision probability over the slab's (lighting.gfactor); False: G once
    (shinya2013 eq. 28). The sppGFactor grid stays G. None: True with the
    exact slab, False with the paper's closed form (which already loses half the scattered light: per order it
    measured worse, README)."""
    g_resolution: int | None = None
    """``--g-resolution``: voxels along the longest foliage edge of a coarse leaf-area density grid through which
    the depths of the G-factor alone are measured (shinya2013 sec. 5.1-5.2 keeps G on a ~16³ grid); 0: G from
    each leaf's own depths, the same as the plane-parallel part (lighting.gfactor, "Depth noise"). None:
    ``G_RESOLUTION`` with the exact slab, 0 with the paper's closed form (its measured rows)."""
    depth_resolution: int | None = None
    """``--depth-resolution``: voxels along the longest foliage edge of the leaf-area density grid through which the
    grid path measures each leaf's depths (own and neighbours'); the written grids (sppDepth, sppThickness,
    sppGFactor, sppIrradiance) stay at ``resolution``. None (``auto``): with the exact slab, per prototype, the
    finest of ``DEPTH_RESOLUTIONS`` up to ``resolution`` whose leaf-holding voxels hold ``DEPTH_LEAVES_PER_VOXEL``
    leaves (:func:`depth_resolution`); with the paper's closed form, ``resolution`` (its measured rows)."""
    depth: str = "auto"
    """``rays``: count leaf crossings; ``grid``: integrate the leaf-area density, own leaf removed (module docstring);
    ``auto``: ``grid`` when the direct light comes from shadow rays (``--direct rays``, the default), else rays up to
    ``AUTO_RAYS_MAX_LEAVES`` leaves in the scene and grid above. Ray counts were chosen for their direct term (the
    lower total error on both test crowns, benchmarks/bench_sppg.py); with the exact direct light only the scattered
    part depends on the depths, and there the grid's smooth depths are better: a leaf's 16 ray counts are a noisy
    depth, and the slab solution is concave in it, so the exact model read -11 ... -16 % with ray depths and
    -1 ... +2 % with grid depths in the uniform layer at 60° (r = t = 0.45; per-leaf E_scattered on tree_small,
    the oak and the sapling within 0.01-0.09 of each other either way), at 5-50x less time."""
    rays_per_leaf: int = 16
    """With ``depth="rays"``: origins per leaf (seeded, uniform over its area); counts are averaged."""
    seed: int = 0
    """With ``depth="rays"``: seed of the ray origins (results are reproducible for a seed)."""
    direct: DirectChoice = DirectChoice()
    """``--direct``: what the ``{spp,sppg,ss}:direct`` primvars and the direct part of ``sppIrradiance`` hold
    (exact shadow rays by default, or eq. 17's attenuated beam through the measured depths)."""
    volume_purpose: str = "default"
    """``--volume-purpose`` of the FoliageLighting volume (``scene.write.VOLUME_PURPOSES``)."""
    first_order: str | None = None
    """``--first-order``: where SPPG's once-scattered sun light comes from. ``march``: the leaves' exact direct
    light scattered once and marched through a coarse voxel medium (lighting.first_order), the later orders at
    SPPG's rate (needs ``g_orders``); ``slab``: the exact slab's first order times G (shinya2013 eq. 28's
    reading). None: ``march`` with ``g_orders``, else ``slab``."""
    gather: int | None = None
    """``--gather N``: rays per leaf of a final gather over the actual leaves (pipeline.gather) whose first
    bounce is exact and whose later bounces come from the method it replaces (SPPG; SPP with ``--no-gfactor``); its
    result replaces the ``:scattered`` primvar of SPPG (SPP with ``--no-gfactor``) and the scattered part of
    ``sppIrradiance``. 0: off; None: ``auto`` (pipeline.gather.auto_rays of the traced leaves)."""

    def __post_init__(self) -> None:
        check_resolution(self.resolution)
        if self.directions < 2 or self.directions % 2:
            raise UsageError(f"--directions must be an even number >= 2, got {self.directions}.")
        if self.depth not in DEPTH_PATHS:
            raise UsageError(f"--depth must be one of {', '.join(DEPTH_PATHS)}, got {self.depth!r}.")
        if self.depth_resolution is not None and not (4 <= self.depth_resolution <= 512):
            raise UsageError(f"--depth-resolution must be auto or between 4 and 512, got {self.depth_resolution}.")
        if self.rays_per_leaf < 1:
            raise UsageError(f"--rays-per-leaf must be >= 1, got {self.rays_per_leaf}.")
        check_gather(self.gather)
        if self.first_order is not None and self.first_order not in FIRST_ORDERS:
            raise UsageError(f"--first-order must be one of {', '.join(FIRST_ORDERS)}, got {self.first_order!r}.")
        if self.model is not None and self.model not in gf.MODELS:
            raise UsageError(f"--model must be one of {', '.join(gf.MODELS)}, got {self.model!r}.")
        exact = (self.model or ("spp" if self.refine else "exact")) == "exact"
        if self.g_orders is None:
            object.__setattr__(self, "g_orders", exact)
        if self.first_order == "march" and not self.gfactor:
            raise UsageError("--first-order march is SPPG's first order; --no-gfactor bakes SPP, whose first order is "
                             "the slab's: drop one of the two.")
        if self.first_order is None:
            object.__setattr__(self, "first_order", "march" if self.g_orders and self.gfactor else "slab")
        if self.first_order == "march" and not self.g_orders:
            implied = " (--model spp and --refine take --no-g-orders unless --g-orders is given)" if not exact else ""
            raise UsageError(f"--first-order march takes the later orders from --g-orders{implied}; give --g-orders, "
                             "or --first-order slab.")
        if self.g_resolution is None:
            object.__setattr__(self, "g_resolution", G_RESOLUTION if exact else 0)
        if self.g_resolution and not (4 <= self.g_resolution <= 512):
            raise UsageError(f"--g-resolution must be 0 (per leaf) or between 4 and 512, got {self.g_resolution}.")
        if self.g_weights not in gf.G_WEIGHTS:
            raise UsageError(f"--g-weights must be one of {', '.join(gf.G_WEIGHTS)}, got {self.g_weights!r}.")
        if self.model == "exact" and self.refine:
            raise UsageError("--refine refines shinya2013's closed form (appendix A.1); use it with --model spp.")


@dataclass(frozen=True)
class SppBake:
    index: int
    result: gf.SPPGResult
    """Per-leaf results: the mean over the prototype's instances."""
    grid_depth: np.ndarray
    grid_thickness: np.ndarray
    grid_gfactor: np.ndarray
    origin: tuple
    voxel_size: float
    seconds: float
    instances: int = 1
    """Instances averaged into ``result``."""
    neighbours: int = 0
    """Neighbouring instances whose leaves were added to the depths (shinya2013 eq. 31), summed over instances."""
    instance_results: tuple = ()
    """Per instance of the prototype (``Scene.instances`` order), its own :class:`~foliage_tools.lighting.gfactor.SPPGResult`."""
    seconds_depths: float = 0.0
    """Wall time of the depths (own and neighbours) of all instances."""
    density_source: str = "computed"
    """Where the leaf-area density came from: ``computed`` or ``input`` (see ``density_for_bake``)."""
    depth_resolution: int | None = None
    """The resolution of the grid the per-leaf depths went through (grid path; None: ray depths)."""


def _phases(optics: LeafOptics) -> list:
    """The canopy phase function per channel, as :func:`~foliage_tools.lighting.gfactor.solve_sppg` takes it."""
    return [canopy_bilambertian_phase(reflectance=float(r), transmittance=float(t))
            for r, t in zip(optics.reflectance, optics.transmittance)]


def depth_resolution(proto: Prototype, params: SppParams) -> int:
    """The resolution of the grid the per-leaf depths are integrated through (``SppParams.depth_resolution``).

    ``auto``: with the exact slab, the finest of ``DEPTH_RESOLUTIONS`` up to ``params.resolution`` at which the
    voxels holding a leaf centre hold at least ``DEPTH_LEAVES_PER_VOXEL`` centres on average (the coarsest when
    none does); with the paper's closed form ``params.resolution``.
    """
    if params.depth_resolution is not None:
        return params.depth_resolution
    if gf.SPPGParams(refine=params.refine, model=params.model).resolved_model != "exact":
        return params.resolution  # the paper's closed form keeps its measured rows (as with --g-resolution)
    centres = proto.leaves.centers
    ladder = [r for r in DEPTH_RESOLUTIONS if r < params.resolution]
    for r in [params.resolution, *ladder]:
        grid = density_grid(proto, DensityParams(resolution=r, method="area"))
        ijk = np.clip(np.floor((centres - np.asarray(grid.origin)) / grid.voxel_size).astype(np.int64), 0, np.asarray(grid.shape) - 1)
        occupied = np.unique(np.ravel_multi_index(ijk.T, grid.shape)).size
        if len(centres) >= DEPTH_LEAVES_PER_VOXEL * occupied:
            return r
    return r


def _own_depths(proto: Prototype, dens: DensityResult, sun_local, dirs_local, params: SppParams):
    """Depths of the prototype's leaves through its own leaves (shinya2013 eq. 29), own leaf excluded."""
    tri = proto.triangles(leaves=True)
    ids = rd.prototype_leaf_ids(proto)
    if params.depth == "rays":
        try:
            return rd.leaf_ray_depths(
                tri, ids, sun_direction=sun_local, directions=dirs_local, rays_per_leaf=params.rays_per_leaf,
                centers=proto.leaves.centers if params.rays_per_leaf == 1 else None, seed=params.seed, workers=WORKERS,
            )
        except ValueError as exc:  # a leaf without area cannot host ray origins
            raise UsageError(
                f"prototype <{proto.path}>: {exc}; remove the degenerate leaf, or use --rays-per-leaf 1 or --depth grid."
            ) from exc
    return depth_mod.depth_samples(
        dens.density, dens.grid, sun_direction=sun_local, directions=dirs_local, points=proto.leaves.centers,
        leaf_triangles=tri, leaf_of_triangle=ids,
    )


def _mean_irradiance(items: list[gf.LeafIrradiance]) -> gf.LeafIrradiance:
    return gf.LeafIrradiance(**{f: np.mean([getattr(i, f) for i in items], axis=0) for f in ("direct", "scattered", "sky_direct", "sky_scattered")})


def _mean_result(results: list[gf.SPPGResult]) -> gf.SPPGResult:
    """Per-leaf mean over instances (directions and mu0 of the first instance)."""
    if len(results) == 1:
        return results[0]
    first = results[0]
    return gf.SPPGResult(
        sppg=_mean_irradiance([r.sppg for r in results]), spp=_mean_irradiance([r.spp for r in results]),
        ss=_mean_irradiance([r.ss for r in results]), gfactor=np.mean([r.gfactor for r in results], axis=0),
        directions=first.directions, mu0=first.mu0, refined=first.refined, seconds=sum(r.seconds for r in results),
        model=first.model, orders=None if first.orders is None else np.mean([r.orders for r in results if r.orders is not None], axis=0),
    )


def bake_prototype(
    proto: Prototype, index: int, scene: Scene, sun: Sun, dens: DensityResult, neighbours: Neighbours | None, params: SppParams,
    *, depth_density: DensityResult | None = None,
) -> SppBake:
    """SPP/SPPG of one prototype: per instance (own depths + neighbours' depths), then the mean over instances.

    ``dens``: the density of the written grids; ``depth_density``: the one the grid path's per-leaf depths go
    through (``depth_resolution``; default ``dens``)."""
    depth_density = depth_density or dens
    up_world = np.asarray(scene.up, dtype=np.float64)
    if float(sun.direction @ up_world) <= 0.0:
        raise UsageError(f"prototype <{proto.path}>: the sun is below the horizon; SPP needs a sun above it (--sun AZ,EL with EL > 0).")
    instances = [n for n, inst in enumerate(scene.instances) if inst.prototype == index]
    if len(instances) > SPP_MAX_PLACEMENTS:  # the mean over instances from an even subsample (bake_spp warns)
        instances = [instances[int(k)] for k in np.unique(np.linspace(0, len(instances) - 1, SPP_MAX_PLACEMENTS).round())]
    placements = [scene.instances[n].transform for n in instances] or [np.eye(4)]
    start = time.perf_counter()
    dirs_world = gf.sample_directions(params.directions, up=up_world)
    results, n_neighbours, t_depths = [], 0, 0.0
    coarse = compute_density(proto, DensityParams(resolution=params.g_resolution, method="area")) if params.g_resolution else None
    for k, m in enumerate(placements):
        sun_local = to_prototype_space(sun.direction, m)
        up_local = to_prototype_space(up_world, m)
        dirs_local = np.array([to_prototype_space(d, m) for d in dirs_world])
        t0 = time.perf_counter()
        own = _own_depths(proto, depth_density, sun_local, dirs_local, params)
        vis = {}
        if isinstance(own, rd.LeafRayDepths):
            vis = {"sun_visible": own.sun_visible, "sample_visible": own.sample_visible}
            own = own.depths
        extra = None
        if neighbours is not None and instances:
            extra, count = neighbours.depths(instances[k], world_points(proto.leaves.centers, m), sun.direction, dirs_world)
            n_neighbours += count
        g_depths = None
        if coarse is not None:
            g_depths = depth_mod.depth_samples(coarse.density, coarse.grid, sun_direction=sun_local, directions=dirs_local,
                                               points=proto.leaves.centers)
        t_depths += time.perf_counter() - t0
        results.append(gf.solve_sppg(
            own, normals=proto.leaves.normals, optics=params.optics, sun_direction=sun_local, directions=dirs_local, up=up_local,
            neighbour_depths=extra, params=gf.SPPGParams(refine=params.refine, model=params.model, g_weights=params.g_weights, g_orders=bool(params.g_orders)), g_depths=g_depths, **vis,
        ))
    result = _mean_result(results)
    # cells of the prototype alone, as seen by its first instance
    m = placements[0]
    sun_local = to_prototype_space(sun.direction, m)
    up_local = to_prototype_space(up_world, m)
    dirs_local = np.array([to_prototype_space(d, m) for d in dirs_world])
    cells = depth_mod.depth_samples(dens.density, dens.grid, sun_direction=sun_local, directions=dirs_local)
    g_kw: dict[str, Any] = dict(boundary_depth=cells.sample_depth, directions=dirs_local, light_direction=sun_local,
                                light_depth=cells.sun_depth, light_thickness=cells.sun_thickness, up=up_local)
    if params.g_weights == "paper":
        g_cells = gf.gfactor(**g_kw)
    else:  # the mean over the channels' G, as SPPGResult.gfactor
        g_cells = np.mean([gf.gfactor(**g_kw, weights="radiance", phase=ph) for ph in _phases(params.optics)], axis=0)
    shape = dens.grid.shape
    return SppBake(
        index, result,
        cells.sun_depth.reshape(shape), cells.sun_thickness.reshape(shape), g_cells.reshape(shape),
        tuple(dens.grid.origin), dens.grid.voxel_size, dens.seconds + time.perf_counter() - start,
        instances=len(placements), neighbours=n_neighbours, instance_results=tuple(results), seconds_depths=t_depths,
        density_source=dens.source,
    )


def depth_path(scene: Scene, depth: str, direct_mode: str = "rays") -> str:
    """``--depth`` made concrete for this scene: ``auto`` integrates the grid when the direct light is the exact one
    (``direct_mode`` ``rays``), and otherwise counts rays up to ``AUTO_RAYS_MAX_LEAVES`` leaves (summed over
    instances) and integrates the grid above; ``rays``/``grid`` stay as given."""
    if depth != "auto":
        return depth
    if direct_mode == "rays":
        return "grid"
    leaves = sum(scene.prototypes[inst.prototype].leaves.count for inst in scene.instances)
    return "rays" if leaves <= AUTO_RAYS_MAX_LEAVES else "grid"


#: Peak memory per leaf and sample direction of one prototype's SPP/SPPG (tree_small, --depth grid: 16 directions
#: 0.62 GB, 256 directions 2.90 GB peak resident; 2026-12-02).
SPP_BYTES_PER_LEAF_DIRECTION = 6.4e3
#: Above this many instances eq. (31)'s neighbour depths are skipped (with a warning): they cost every instance
#: against every other, 3.3-3.7 ms a pair measured (issue #16), so 100 instances take ~35 s and 1 000 an hour.
EQ31_MAX_INSTANCES = 100
#: Most instances of a prototype SPP solves in their own frames for the per-leaf mean over instances; above it an
#: evenly spaced subsample of this many (each solve is a whole prototype's: 10 000 instances of three prototypes
#: took over 10 minutes). The per-instance means the stage writes do not depend on it (exact direct light, forest
#: lattice).
SPP_MAX_PLACEMENTS = 32


def resolve_depth(scene: Scene, params: SppParams) -> SppParams:
    """``params`` with ``depth`` made concrete for this scene (:func:`depth_path`)."""
    return replace(params, depth=depth_path(scene, params.depth, params.direct.mode))


def bake_spp(scene: Scene, sun: Sun, params: SppParams, warnings: list[str], progress: Progress) -> list[SppBake]:
    from foliage_tools.pipeline.plan import available_memory

    params = resolve_depth(scene, params)
    baked = scene.leafy_prototypes()
    need = max((p.leaves.count for _, p in baked), default=0) * params.directions * SPP_BYTES_PER_LEAF_DIRECTION
    free = available_memory()
    if need > free:  # refuse before any work, as lb and density do (issue #18 case 7)
        raise UsageError(
            f"--directions {params.directions}: SPP over {max(p.leaves.count for _, p in baked):,} leaves would hold "
            f"~{need / 1e9:,.1f} GB ({SPP_BYTES_PER_LEAF_DIRECTION / 1e3:.1f} kB per leaf and direction), "
            f"{free / 1e9:.1f} GB is available. Use fewer directions (the paper uses 16-64; the default is 16).")
    progress.step(f"SPP/SPPG for {len(baked)} prototype(s), {params.depth} depths", total=len(baked))
    densities = {i: density_for_bake(scene, p, DensityParams(resolution=params.resolution, method="area"), warnings) for i, p in baked}
    # the grid path's depths go through a grid coarse enough to hold DEPTH_LEAVES_PER_VOXEL leaves a voxel
    depth_densities, depth_res = dict(densities), {}
    if params.depth == "grid":
        for i, p in baked:
            depth_res[i] = r = depth_resolution(p, params)
            if r != params.resolution:
                depth_densities[i] = compute_density(p, DensityParams(resolution=r, method="area"))
    neighbours = None
    if 1 < len(scene.instances) <= EQ31_MAX_INSTANCES:
        neighbours = Neighbours(scene, depth_densities, params, warnings)
    elif len(scene.instances) > EQ31_MAX_INSTANCES:
        warnings.append(
            f"{len(scene.instances):,} instances: the neighbour depths of shinya2013 eq. (31) are left out above "
            f"{EQ31_MAX_INSTANCES} (every instance against every other, ~3.5 ms a pair: "
            f"{len(scene.instances) ** 2 * 3.5e-3 / 60:,.0f} min here). Each instance's direct light still sees its "
            "neighbours (--direct rays), and the forest lattice scales its scattered light.")
    out = []
    for i, proto in baked:
        n = len(scene.instances_of(i))
        if n > SPP_MAX_PLACEMENTS:
            warnings.append(f"prototype <{proto.path}>: its per-leaf SPP values are the mean over {SPP_MAX_PLACEMENTS} "
                            f"of its {n:,} instances (evenly spaced), not all of them.")
        bake = bake_prototype(proto, i, scene, sun, densities[i], neighbours, params, depth_density=depth_densities[i])
        out.append(replace(bake, depth_resolution=depth_res.get(i)))
        log.info("spp <%s>: %s depths%s, %d instance(s), %d neighbour(s), mean G %.3f, depths %.2f s, %.2f s", proto.path,
                 params.depth, f" through a {depth_res[i]}-voxel grid" if i in depth_res else "", bake.instances,
                 bake.neighbours, float(np.mean(bake.result.gfactor)), bake.seconds_depths, bake.seconds)
        progress.advance()
    return out


@dataclass(frozen=True)
class SppLight:
    """What ``foliage spp`` writes, before it is written: the bakes (SPPG's sun light marched when
    ``first_order`` is march), the exact direct light (None with ``--direct volume``), the world and the final
    gather (None when off)."""

    bakes: list[SppBake]
    exact: DirectBake | None
    world: World
    gathered: GatherBake | None
    rays: int
    best_name: str


def spp_light(scene: Scene, sun: Sun, params: SppParams, warnings: list[str], progress: Progress) -> SppLight:
    """Every light ``run_spp`` writes: SPP/SPPG per prototype, the exact direct light, the marched first order
    and the final gather, as the command computes them (also what the tests and benchmarks score)."""
    params = resolve_depth(scene, params)
    bakes = bake_spp(scene, sun, params, warnings, progress)
    exact = bake_direct(scene, sun, params.direct, progress) if params.direct.mode == "rays" else None
    best_name = "sppg" if params.gfactor else "spp"
    if params.gfactor and params.first_order == "march":  # its source is the exact direct light, whatever --direct writes
        exact_source = exact or bake_direct(scene, sun, DirectChoice(), progress)
        bakes = march_sppg(scene, sun, params.optics, bakes, exact_source, progress)
    gathered = None
    world = exact.world if exact else bake_world(scene)
    rays = resolve_rays(params.gather, int(world.offsets[-1]), warnings)
    if rays:
        # the later bounces from the method the gather replaces (SPPG with --gfactor): with the depths through the
        # coarse grid (depth_resolution) the gather on SPPG is within 3.4 % in every depth bin of the uniform layer
        # at 30, 60 and 85 degrees (on SPP +4.4 %), and 0.074 / 0.088 / 0.094 per leaf on tree_small / the oak / the
        # sapling (on SPP 0.086 / 0.094 / 0.098; README)
        gathered = bake_gather(scene, sun, params.optics, {b.index: getattr(b.result, best_name).scattered for b in bakes},
                               rays, progress, world=world)
    return SppLight(bakes, exact, world, gathered, rays, best_name)


def spp_layer(scene: Scene, sun: Sun, report: Report, progress: Progress, *, out: Path,
             params: SppParams) -> tuple[LayerEdits, SppStats]:
    """``foliage spp``'s computation and layer (``pipeline.stage.bake_layer`` reads before and writes after)."""
    params = resolve_depth(scene, params)
    edits = LayerEdits()
    protos: list[SppPrototypeStats] = []
    light = spp_light(scene, sun, params, report.warnings, progress)
    bakes, exact, world, gathered, rays, best_name = (light.bakes, light.exact, light.world, light.gathered, light.rays,
                                                      light.best_name)
    for bake in bakes:
        proto = scene.prototypes[bake.index]
        res = bake.result
        grids = (
            Grid("sppGFactor", bake.grid_gfactor.astype(np.float32), bake.origin, bake.voxel_size, {"units": "dimensionless"}),
            Grid("sppDepth", bake.grid_depth.astype(np.float32), bake.origin, bake.voxel_size, {"units": "optical depth toward the sun"}),
            Grid("sppThickness", bake.grid_thickness.astype(np.float32), bake.origin, bake.voxel_size, {"units": "optical thickness along the sun ray"}),
        )
        attrs = {
            "foliage:method": "spp", "foliage:voxelSize": float(bake.voxel_size),
            "foliage:resolution": tuple(int(n) for n in bake.grid_depth.shape),
            "foliage:metersPerUnit": float(scene.meters_per_unit), "foliage:seconds": float(bake.seconds), "foliage:version": __version__,
            "foliage:gatherRays": int(rays),
        }
        edits.volumes.append(prototype_volume(scene, bake.index, vdb_file=vdb_path(out, scene, bake.index), grids=grids,
                                              attributes=attrs, purpose=params.volume_purpose))
        if not proto.editable:
            report.warnings.append(native_instance_warning(proto, "SPP primvars"))
        methods = {"spp": res.spp, "ss": res.ss}
        if params.gfactor:
            methods["sppg"] = res.sppg
        e_direct = exact.per_prototype[bake.index] if exact else None
        scattered = {m: irr.scattered for m, irr in methods.items()}
        if gathered is not None:
            scattered[best_name] = gathered.per_prototype[bake.index]
        for m, irr in methods.items():
            own = irr.direct if e_direct is None else e_direct
            edits.primvars += leaf_primvar_edits(proto, f"foliage:{m}:direct", own, type="color3f")
            edits.primvars += leaf_primvar_edits(proto, f"foliage:{m}:scattered", scattered[m], type="color3f")
        best = getattr(res, best_name)
        best_direct = best.direct if e_direct is None else e_direct
        edits.primvars += vertex_primvar_edits(proto, "foliage:sppIrradiance", best_direct + scattered[best_name], type="color3f")
        edits.primvars += vertex_primvar_edits(proto, "foliage:gFactor", res.gfactor, type="float")
        edits.attributes += baked_sun_attribute(scene, bake.index, "spp", sun.direction)
        protos.append({
            "path": proto.path, "leaves": proto.leaves.count, "cells": int(bake.grid_depth.size), "resolution": list(bake.grid_depth.shape),
            "gfactor_mean": float(np.mean(res.gfactor)), "seconds": bake.seconds,
            "seconds_depths": bake.seconds_depths, "instances": bake.instances, "neighbours": bake.neighbours,
            "density": bake.density_source, "depth_resolution": bake.depth_resolution,
            "e_scattered_mean": {m: v.mean(axis=0).tolist() for m, v in scattered.items()},
        })
    best_of = {b.index: getattr(b.result, best_name) for b in bakes}
    # eq. 31 shades by the neighbours; the lattice adds their scattered light (a gather traced it already)
    forest = forest_light(scene, sun, params.optics, progress=progress) if gathered is None or world.lone else None
    pv, at = bake_instance_edits(
        scene, "spp", world,
        exact.result.e_direct if exact else from_prototypes(world, {i: r.direct for i, r in best_of.items()}),
        gathered.result.e_scattered if gathered else from_prototypes(world, {i: r.scattered for i, r in best_of.items()}),
        forest=forest, exact_direct=exact)
    edits.primvars += pv
    edits.attributes += at
    stats: SppStats = {
        "directions": params.directions, "cells": int(sum(p["cells"] for p in protos)), "refine": params.refine,
        "depth": params.depth, "rays_per_leaf": params.rays_per_leaf if params.depth == "rays" else None,
        "gfactor": params.gfactor, "model": gf.SPPGParams(refine=params.refine, model=params.model).resolved_model,
        "g_weights": params.g_weights, "g_resolution": params.g_resolution, "g_orders": params.g_orders, "first_order": params.first_order,
        "sun": sun_stats(sun),
        "optics": params.optics.as_dict(), "prototypes": protos,
        "direct": exact.stats() if exact else {"mode": "volume"},
        "gather": {**gathered.stats(), "on": best_name} if gathered is not None else {"rays_per_leaf": 0},  # 0: off
        "forest": forest.stats() if forest is not None else None,
    }
    return edits, stats


def run_spp(path: Path, out: Path, params: SppParams, *, progress: Progress | None = None) -> Report[SppStats]:
    return bake_layer("spp", path, out, params.sun, progress,
                      partial(spp_layer, out=out, params=params))

"""The ``stats`` of each command's report: one ``TypedDict`` per command, so mypy checks every key the CLI reads.

These are the ``--json`` contract (``schemas/json/report.schema.json`` lists the keys a consumer may rely on;
``tests/integration/test_json_reports.py`` checks that each command's JSON has exactly the keys and value kinds
declared here). Values are JSON values: lists, not arrays; ``None`` where a figure does not apply.
"""

from collections.abc import Mapping
from typing import Any, NotRequired, TypedDict

from foliage_tools.geometry.sun import Sun

#: ``LeafOptics.as_dict()``: reflectance and transmittance per RGB channel, and the wood's reflectance.
OpticsStats = dict[str, list[float]]
#: ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``
Bounds = list[list[float]]


class SunStats(TypedDict):
    azimuth: float
    elevation: float
    source: str
    """``--sun``, ``--config FILE``, ``default`` or the DistantLight's path in ``<...>``."""


def sun_stats(sun: Sun) -> SunStats:
    return {"azimuth": sun.azimuth, "elevation": sun.elevation, "source": sun.source}


class InstanceDirectStats(TypedDict):
    samples_per_instance: int
    rays: int
    seconds: float
    noise_rel: float


class DirectStats(TypedDict):
    """The exact direct light (``--direct rays``), or ``{"mode": "volume"}`` (the method's own estimate)."""

    mode: str
    samples_per_leaf: NotRequired[int]
    rays: NotRequired[int]
    seconds: NotRequired[float]
    noise_rel: NotRequired[float]
    leaves: NotRequired[int]
    instances: NotRequired[InstanceDirectStats]
    """Each instance's mean through every placed instance (a forest of lone trees)."""
    rel_rms_direct: NotRequired[float | None]
    """``bench`` only: against the reference's direct light."""


class GatherStats(TypedDict):
    """The final gather; ``{"rays_per_leaf": 0}`` when it is off."""

    rays_per_leaf: int
    rays: NotRequired[int]
    seconds: NotRequired[float]
    noise_rel: NotRequired[float]
    first_bounce_share: NotRequired[float | None]
    on: NotRequired[str]
    """The method whose later orders it gathered on (``lb``, or spp's best)."""


class ForestStats(TypedDict):
    """The stand's coarse lattice (steele2010 sec. 3.2) of a forest."""

    grid: list[int]
    voxel_size: float
    seconds: float
    factor_min: list[float]
    factor_max: list[float]
    direct_factor_min: list[float]
    direct_factor_max: list[float]
    calibration: list[float] | None


class LBPrototypeStats(TypedDict):
    path: str
    volume: str
    resolution: list[int]
    voxel_size: float
    solver: str
    iterations: int
    residual: float
    converged: bool
    stalled: bool
    rounding_level: float | None
    """fp16: the relative change one sweep's rounding makes, at which the solve counted as converged (lb.LBResult)."""
    mlups: float
    seconds: float
    density: str
    storage: str
    grid_precision: str
    base_extent: NotRequired[str]
    base_nodes_kept: NotRequired[float]
    e_direct_mean: list[float]
    e_scattered_mean: list[float]
    e_scattered_volume_mean: list[float]
    e_direct_volume_mean: list[float]


class LBStats(TypedDict):
    solver: str
    iterations: int
    residual: float
    tolerance: float
    converged: bool
    """Every prototype's solve converged (each one's own is in ``prototypes``); False: the command exits 1."""
    resolution: list[int]
    bases: str
    mlups: float
    storage: str
    grid_precision: str
    first_order: str
    sun: SunStats
    optics: OpticsStats
    absorption_scale: float
    prototypes: list[LBPrototypeStats]
    direct: DirectStats
    gather: GatherStats
    forest: ForestStats | None


class SppPrototypeStats(TypedDict):
    path: str
    leaves: int
    cells: int
    resolution: list[int]
    gfactor_mean: float
    seconds: float
    seconds_depths: float
    instances: int
    neighbours: int
    density: str
    depth_resolution: int | None
    e_scattered_mean: dict[str, list[float]]
    """Per method written (spp, ss, sppg)."""


class SppStats(TypedDict):
    directions: int
    cells: int
    refine: bool
    depth: str
    rays_per_leaf: int | None
    gfactor: bool
    model: str
    g_weights: str
    g_resolution: int | None
    g_orders: bool | None
    first_order: str | None
    sun: SunStats
    optics: OpticsStats
    prototypes: list[SppPrototypeStats]
    direct: DirectStats
    gather: GatherStats
    forest: ForestStats | None


class SmaxPrototypeStats(TypedDict):
    path: str
    leaves: int
    tau: float
    path_used: str
    smax_mean: float
    e_direct_mean: list[float]
    e_direct_volume_mean: list[float]
    e_scattered_mean: list[float]
    seconds: float
    scatter: str
    recollision_probability: float


class SmaxStats(TypedDict):
    leaves: int
    tau: float | list[float]
    path: str | list[str]
    sun: SunStats
    optics: OpticsStats
    version: str
    prototypes: list[SmaxPrototypeStats]
    direct: DirectStats
    forest: ForestStats | None


class EnergyStats(TypedDict):
    incident: list[float]
    absorbed_leaves: list[float]
    absorbed_wood: list[float]
    escaped: list[float]


class ReferenceStats(TypedDict):
    paths: int
    sky_paths: int
    seed: int
    workers: int
    noise_rel: float
    noise_rel_total: float
    noise_rel_direct: float
    noise_target: float | None
    leaves: int
    noise_rel_instance: float | None
    sun: SunStats
    optics: OpticsStats
    energy: EnergyStats
    e_direct_mean: list[float]
    e_scattered_mean: list[float]
    seconds_tracing: float


class BenchReferenceStats(TypedDict):
    paths: int
    sky_paths: int
    seed: int
    seconds: float
    noise_rel: float
    noise_rel_total: float
    noise_rel_direct: float
    noise_target: float | None


class BenchRow(TypedDict):
    """One method's errors against the reference (``None``: not available, or undefined)."""

    name: str
    available: bool
    description: str
    seconds: float | None
    seconds_volume: NotRequired[float]
    rel_rms_scattered: float | None
    rel_rms_direct: NotRequired[float | None]
    rel_rms_total: float | None
    binned_rms: float | None
    binned_rms_total: float | None
    rel_rms_direct_volume: NotRequired[float | None]
    rel_rms_total_volume: float | None
    binned_rms_total_volume: NotRequired[float | None]
    instance_rel_rms_total: NotRequired[float | None]
    stats: NotRequired[Mapping[str, Any]]
    """The method's own figures (``bench.registry``)."""


class BenchStats(TypedDict):
    sun: SunStats
    optics: OpticsStats
    leaves: int
    reference: BenchReferenceStats
    direct: DirectStats
    instances: int
    forest: ForestStats | None
    methods: list[BenchRow]
    binned_rms_definition: str


class DensityPrototypeStats(TypedDict):
    path: str
    volume: str
    leaves: int
    shape: list[int]
    voxel_size: float
    origin: list[float]
    active_voxels: int
    leaf_area_mesh: float
    leaf_area_grid: float | None
    area_rel_error: float | None
    seconds: float


class DensityStats(TypedDict):
    method: str
    prototypes: list[DensityPrototypeStats]


class InspectPrototypeStats(TypedDict):
    path: str
    kind: str
    instances: int
    leaves: int
    leaf_area: float
    leaf_triangles: int
    wood_triangles: int
    leaf_meshes: list[str]
    wood_meshes: list[str]
    bounds: Bounds


class LightStats(TypedDict):
    path: str
    kind: str
    direction: list[float]
    intensity: float
    color: list[float]


class InspectStats(TypedDict):
    up_axis: str
    meters_per_unit: float
    prototypes: list[InspectPrototypeStats]
    instances: int
    leaves_total: int
    bounds: Bounds | None
    lights: list[LightStats]


class ValidateStats(TypedDict):
    findings: list[dict[str, Any]]
    """``Finding.as_dict()``: severity, code, message and where."""
    errors: int
    warnings: int
    strict: bool
    passed: bool


class PlanPrototypeStats(TypedDict):
    path: str
    leaves: int
    instances: int
    grid: list[int]
    voxel_size: float
    lb_rhs: int
    lb_sweeps_estimate: int
    lb_memory_bytes: int
    smax_path: str
    seconds_estimate: dict[str, float]


class PlanForestStats(TypedDict):
    nodes: int
    seconds_estimate_per_stage: float
    memory_bytes: int


class PlanStats(TypedDict):
    resolution: int
    bases: str
    storage: str
    depth: str
    gather_rays_per_leaf: int
    gather_rays: int
    prototypes: list[PlanPrototypeStats]
    instances: int
    leaves_total: int
    seconds_estimate: dict[str, float]
    """Per stage (density, smax, spp, lb, reference, direct, and forest for a forest)."""
    peak_memory_bytes: int
    direct_rays: int
    world_triangles: int
    world_memory_bytes: int
    forest: PlanForestStats | None
    traced: str
    traced_triangles: int
    reference_memory_bytes: int
    note: str


class PreviewStats(TypedDict):
    methods: list[str]
    format: str
    size: list[int]
    frames: int
    samples: int
    shadow_size: int
    sky_samples: int
    renderer: str
    triangles: int
    lod: dict[str, float | int] | None
    instances: int
    bounds: Bounds
    camera: dict[str, Any]
    sun: dict[str, Any]
    """As :class:`SunStats`, with the ``direction`` drawn and whether it was a ``sweep``."""
    sky: dict[str, Any]
    ground: bool
    exposure: dict[str, Any]
    seconds_per_render: float
    per_method: dict[str, dict[str, float]]


class ImportPartStats(TypedDict):
    prim: str
    name: str
    material: str | None
    leaf: bool
    faces_read: int
    triangles: int
    points: int


class ImportStats(TypedDict):
    up_axis: str
    meters_per_unit: float
    parts: list[ImportPartStats]


class BakeStageStats(TypedDict):
    seconds: float
    outputs: list[str]
    peak_rss_bytes: int | None
    stats: dict[str, Any]
    """That stage's own command's stats (``LBStats`` for ``lb`` ...)."""


class BakeStats(TypedDict):
    result: str
    stages: dict[str, BakeStageStats]
    bench: BenchStats | None
    direct: DirectStats | None


class BatchCounts(TypedDict):
    assets: int
    baked: int
    cached: int
    failed: int


class BatchStats(TypedDict):
    dry_run: bool
    workers: int | None
    scheduler: str | None
    dashboard: str | None
    assets: dict[str, dict[str, Any]]
    """Per asset, its ``batch.json`` entry (``pipeline.batch``), or with ``--dry-run`` what would run and why."""
    counts: NotRequired[BatchCounts]

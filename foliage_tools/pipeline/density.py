"""``foliage density``: per prototype, leaf density and wood fraction on a cropped grid."""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from foliage_tools import __version__
from foliage_tools.errors import InputError, UsageError
from foliage_tools.geometry.voxelize import GridSpec, area_per_voxel, grid_for_bounds, mark_wood_fraction, subgrid_coverage
from foliage_tools.params import RESOLUTION_RANGE, DensityParams
from foliage_tools.pipeline.leafdata import native_instance_warning
from foliage_tools.pipeline.report import Progress, Report, Silent
from foliage_tools.pipeline.stats import DensityPrototypeStats, DensityStats
from foliage_tools.scene.bakeable import MIN_VOXEL
from foliage_tools.scene.model import Prototype, Scene
from foliage_tools.scene.read import read_scene
from foliage_tools.scene.vdb import Grid
from foliage_tools.pipeline.volumes import bakes_root, class_path, prototype_volume, volume_path
from foliage_tools.scene.write import LayerEdits, PrimvarEdit, check_output_path

log = logging.getLogger(__name__)


#: Largest grid a density bake will allocate (float64 work arrays: 8 bytes × 3 per voxel).
MAX_RESOLUTION = 1024
MAX_CELLS = MAX_RESOLUTION**3 // 2


@dataclass(frozen=True)
class DensityResult:
    """Density grids of one prototype."""

    grid: GridSpec
    density: np.ndarray
    """(nx, ny, nz) float64: leaf-area density (1/stage unit) for ``area``; sub-cell fraction (0..1) for ``subgrid``."""
    wood_fraction: np.ndarray
    """(nx, ny, nz) float64 in [0, 1]: wood / (leaf + wood) surface in the voxel."""
    leaf_area_mesh: float
    leaf_area_grid: float
    """Σ density × voxel volume (``area`` method): equals ``leaf_area_mesh`` up to round-off when the grid holds all leaves."""
    seconds: float
    source: str = "computed"
    """``computed`` (voxelized here) or ``input`` (an earlier ``density`` stage's grids, read from the input)."""


def density_grid(proto: Prototype, params: DensityParams) -> GridSpec:
    """The grid every bake voxelizes ``proto`` on: its foliage bounds plus the margin, refused above MAX_CELLS."""
    lo, hi = proto.bounds(leaves_only=True)
    grid = grid_for_bounds(lo, hi, margin_voxels=params.margin_voxels, **params.grid_options())
    if params.voxel_size is not None:  # the grid --resolution N would give is bounded; so is the one a voxel size gives
        _check_voxel_size(proto, params, grid, float(np.max(np.asarray(hi) - np.asarray(lo))))
    if grid.voxel_size < MIN_VOXEL:  # OpenVDB could not store the grid (scene.bakeable.MIN_VOXEL)
        longest = float(np.max(np.asarray(hi) - np.asarray(lo)))
        raise UsageError(
            f"prototype <{proto.path}>: its foliage is {longest:.3g} units across, so this grid's voxels would be "
            f"{grid.voxel_size:.3g}, below the {MIN_VOXEL:g} units OpenVDB stores a grid with. Use a lower --resolution "
            f"(at most {max(1, int(longest / MIN_VOXEL))}) or a --voxel-size of at least {MIN_VOXEL:g}, or scale the asset up.")
    cells = int(np.prod(grid.shape))
    if cells > MAX_CELLS:
        raise UsageError(
            f"prototype <{proto.path}>: a {'x'.join(map(str, grid.shape))} grid ({cells / 1e6:.0f}M voxels) is too large; "
            "use a larger --voxel-size or a lower --resolution."
        )
    return grid


def _check_voxel_size(proto: Prototype, params: DensityParams, grid: GridSpec, longest: float) -> None:
    """UsageError when ``--voxel-size`` puts more voxels along the longest foliage edge than ``--resolution`` may
    (``RESOLUTION_RANGE``): a new user's trial allocated ~9 GB for a 598x609x1005 grid before this check."""
    lo, hi = RESOLUTION_RANGE
    n = max(grid.shape) - 2 * params.margin_voxels  # the voxels across the foliage, as --resolution counts them
    if n <= hi:
        return
    smallest = float(f"{longest / hi:.2g}")
    smallest = smallest if longest / smallest <= hi else float(f"{smallest * 1.05:.2g}")  # rounded up, never below
    raise UsageError(
        f"--voxel-size {params.voxel_size:g} makes too large a grid for prototype <{proto.path}>: its foliage is {longest:.4g} "
        f"units across, so the grid would be {'x'.join(map(str, grid.shape))} voxels, resolution {n} along the longest "
        f"edge, above the limit of {hi} (--resolution {lo}-{hi}). Give --voxel-size {smallest:g} or larger, or "
        f"--resolution N instead (`foliage plan` shows the grid and memory of a resolution)."
    )


def compute_density(proto: Prototype, params: DensityParams) -> DensityResult:
    """Voxelize one prototype (pure numerics on its arrays)."""
    t0 = time.perf_counter()
    leaf = proto.triangles(leaves=True)
    wood = proto.triangles(leaves=False)
    grid = density_grid(proto, params)
    if params.method == "area":
        leaf_area = area_per_voxel(leaf, grid)
        wood_area = area_per_voxel(wood, grid) if len(wood) else np.zeros(grid.shape)
        density = leaf_area / grid.voxel_volume
        wood_fraction = mark_wood_fraction(leaf_area, wood_area)
    else:
        # geist2008 sec. 4.2: density = intersected sub-cells / 27
        density = subgrid_coverage(leaf, grid).astype(np.float64)
        wood_cov = subgrid_coverage(wood, grid).astype(np.float64) if len(wood) else np.zeros(grid.shape)
        wood_fraction = mark_wood_fraction(density, wood_cov)
    mesh_area = float(proto.leaves.areas.sum())
    grid_area = float(density.sum() * grid.voxel_volume) if params.method == "area" else float("nan")
    return DensityResult(grid, density, wood_fraction, mesh_area, grid_area, time.perf_counter() - t0)


def density_for_bake(scene: Scene, proto: Prototype, params: DensityParams, warnings: list[str]) -> DensityResult:
    """The leaf-area density a bake stage needs: the input's own grids when an earlier stage wrote them, else voxelized.

    DESIGN.md section 3: a bake reuses the density an earlier stage wrote. It
    is reused when it lies on the lattice this stage asks for (same voxel
    size, aligned origin, inside the grid: what ``foliage density`` writes
    with the same --resolution or --voxel-size) and holds leaf-area density
    (``--method area``). The grids are stored as float32, so a reused bake
    differs from a fresh one by float32 round-off. Otherwise the density is
    voxelized anew, with a warning that says why the input's was not used.
    """
    grid = density_grid(proto, params)
    t0 = time.perf_counter()
    found, why = _stored_density(Path(scene.path), volume_path(scene, proto), grid)
    if found is not None:
        density, wood = found
        return DensityResult(grid, density, wood, float(proto.leaves.areas.sum()), float(density.sum() * grid.voxel_volume),
                             time.perf_counter() - t0, source="input")
    if why is None and not proto.editable:
        why = _legacy_volume(Path(scene.path), proto)
    if why:
        warnings.append(f"prototype <{proto.path}>: the input's density grid was not reused ({why}); it was voxelized anew. "
                        "Run `foliage density` with the same --resolution as this stage to reuse it.")
    return compute_density(proto, params)


def _legacy_volume(path: Path, proto: Prototype) -> str | None:
    """Why a native-instance prototype's volume at the layout of layers before 2026-12-02 (``/FoliageBakes/<name>``,
    outside the default prim) is not reused, or None when the input has none there."""
    from foliage_tools.scene.stored import volume_fields
    from foliage_tools.scene.write import input_files

    if not any(f.suffix == ".vdb" for f in input_files(path)):
        return None
    old = f"/FoliageBakes/{re.sub(r'[^A-Za-z0-9_]', '_', proto.name)}/FoliageLighting"
    if volume_fields(path, old, ("density",)) is None:
        return None
    return (f"its volume is at <{old}>, where layers of earlier foliage-tools versions put it; bakes now place it over "
            "every instance from a class under the default prim")


def _stored_density(path: Path, volume_at: str, grid: GridSpec) -> tuple[tuple[np.ndarray, np.ndarray] | None, str | None]:
    """(density, wood fraction) on ``grid`` from the input's FoliageLighting volume; (None, reason) or (None, None) if it has none."""
    from foliage_tools.scene.stored import volume_fields
    from foliage_tools.scene.vdb import read_grid
    from foliage_tools.scene.write import input_files, missing_inputs

    if not any(f.suffix == ".vdb" for f in input_files(path)) and not any(u.endswith(".vdb") for u in missing_inputs(path)):
        return None, None  # a raw asset: no grids to reuse (present or missing), no need to compose the stage
    fields = volume_fields(path, volume_at, ("density", "woodFraction"))
    if fields is None:
        return None, None
    arrays = []
    for name, field in fields.items():
        if not field.asset:
            return None, f"<{field.prim}> names no .vdb file"
        if field.resolved is None:
            return None, f"@{field.asset}@, named by <{field.prim}>, does not exist"
        stored = read_grid(field.resolved, field.field_name)
        if name == "density" and stored.metadata.get("densityMethod", "area") != "area":
            return None, f"it holds the {stored.metadata.get('densityMethod')} heuristic, not leaf-area density"
        if abs(stored.voxel_size - grid.voxel_size) > 1e-5 * grid.voxel_size:
            return None, f"its voxel size is {stored.voxel_size:.4g}, this stage's lattice {grid.voxel_size:.4g}"
        offset = (np.asarray(stored.origin) - np.asarray(grid.origin)) / grid.voxel_size
        start = np.round(offset).astype(int)
        end = start + np.asarray(stored.values.shape)
        if np.any(np.abs(offset - start) > 1e-3) or np.any(start < 0) or np.any(end > np.asarray(grid.shape)):
            if not np.any(stored.values):
                arrays.append(np.zeros(grid.shape))  # an all-empty grid has no placement (e.g. no wood)
                continue
            return None, "it lies on another lattice"
        full = np.zeros(grid.shape)
        full[start[0]:end[0], start[1]:end[1], start[2]:end[2]] = stored.values
        arrays.append(full)
    return (arrays[0], arrays[1]), None


#: The area method conserves leaf area to float32 round-off (~1e-7); more lost than this is a grid that does not fit.
AREA_WARN = 1e-3


def vdb_path(out: Path, scene: Scene, index: int) -> Path:
    """``OUT.vdb`` beside the layer; one file per prototype (``OUT.NN_name.vdb``) when there are several."""
    if len(scene.prototypes) == 1:
        return out.with_suffix(".vdb")
    name = re.sub(r"[^A-Za-z0-9_]", "_", scene.prototypes[index].name)
    return out.with_name(f"{out.stem}.{index:02d}_{name}.vdb")


def require_leaves(scene: Scene, path: Path) -> None:
    """Refuse a scene with no leaves; meshes the reader skipped as empty are named as the likely cause."""
    skipped = scene.empty_meshes
    if skipped and not any(p.leaves.count for p in scene.prototypes):
        raise InputError(
            f"@{path}@: no leaves to bake, and the reader skipped: {'; '.join(skipped[:3])}"
            f"{' (and more)' if len(skipped) > 3 else ''}. Fix those meshes (`foliage validate` lists every finding)."
        )
    if not scene.prototypes:
        raise InputError(f"@{path}@ has no mesh geometry to bake; is it a tree asset?")
    if not any(p.leaves.count for p in scene.prototypes):
        meshes = ", ".join(f"<{m.path}>" for p in scene.prototypes for m in p.meshes[:5])
        raise InputError(
            f"@{path}@: no leaves found (meshes read: {meshes}; invisible meshes and guide/proxy purposes are left "
            "out). Mark leaf meshes with FoliageLeafAPI or "
            "primvars:foliage:isLeaf = true, or name them or their material leaf/leaves/foliage/needle."
        )


def leaf_id_edits(scene: Scene, warnings: list[str]) -> list[PrimvarEdit]:
    edits = []
    for proto in scene.prototypes:
        if not proto.editable and proto.leaves.count:
            n = len(scene.instances_of(scene.prototypes.index(proto)))
            warnings.append(native_instance_warning(proto, "primvars:foliage:leafId") + (
                f" Its grids are in the class <{class_path(scene, proto)}>, placed over each of its {n} instance(s) "
                f"under <{bakes_root(scene)}/Instances>."))
            continue
        for mesh, ids in zip(proto.meshes, proto.leaves.face_leaf_ids):
            if mesh.is_leaf:
                edits.append(PrimvarEdit(prim=mesh.path, name="foliage:leafId", values=ids, type="int"))
    return edits


def run_density(path: Path, out: Path, params: DensityParams, *, progress: Progress | None = None) -> Report[DensityStats]:
    from foliage_tools.pipeline.stage import require_consistent_input, write_stage  # stage imports this module

    progress = progress or Silent()
    report: Report[DensityStats] = Report(command="density", inputs=[str(path)])
    check_output_path(path, out, warnings=report.warnings)
    require_consistent_input(path)
    progress.step(f"reading {path}")
    scene, warnings = read_scene(path)
    report.warnings.extend(warnings)
    require_leaves(scene, path)
    edits = LayerEdits(primvars=leaf_id_edits(scene, report.warnings))
    protos: list[DensityPrototypeStats] = []
    baked = scene.leafy_prototypes()
    for _, proto in baked:  # every grid's size is checked before any is allocated
        density_grid(proto, params)
    progress.step(f"voxelizing {len(baked)} prototype(s) ({params.method})", total=len(baked))
    for i, proto in baked:
        res = compute_density(proto, params)
        progress.advance()
        meta = {
            "foliage:method": "density",
            "foliage:densityMethod": params.method,
            "foliage:voxelSize": float(res.grid.voxel_size),
            "foliage:resolution": tuple(int(n) for n in res.grid.shape),
            "foliage:metersPerUnit": float(scene.meters_per_unit),
            "foliage:seconds": float(res.seconds),
            "foliage:version": __version__,
        }
        units = "1/stage_unit (leaf area density)" if params.method == "area" else "fraction of 27 sub-cells"
        grid_meta = {"units": units, "densityMethod": params.method, "metersPerUnit": float(scene.meters_per_unit)}
        grids = (
            Grid("density", res.density.astype(np.float32), res.grid.origin, res.grid.voxel_size, grid_meta),
            Grid("woodFraction", res.wood_fraction.astype(np.float32), res.grid.origin, res.grid.voxel_size, {"units": "fraction"}),
        )
        edits.volumes.append(prototype_volume(scene, i, vdb_file=vdb_path(out, scene, i), grids=grids, attributes=meta,
                                              purpose=params.volume_purpose))
        rel_err = abs(res.leaf_area_grid - res.leaf_area_mesh) / res.leaf_area_mesh if params.method == "area" else None
        if (rel_err is not None and rel_err > AREA_WARN) or not np.any(res.density):
            size = float(np.ptp(proto.leaves.centers, axis=0).max()) if proto.leaves.count else 0.0
            report.warnings.append(
                f"prototype <{proto.path}>: the {'x'.join(map(str, res.grid.shape))} grid (voxel size {res.grid.voxel_size:g}) "
                f"holds {100 * (1 - (rel_err or 1.0)):.1f} % of the leaf area, {np.count_nonzero(res.density)} voxel(s) "
                f"non-zero, for foliage {size:g} across: the voxels are too large (or too small) for float32 densities. "
                "Use --resolution N, or a --voxel-size near the foliage size over 64.")
        log.info("density <%s>: %s grid, voxel %.4g, %d active voxels, %.2f s", proto.path, "x".join(map(str, res.grid.shape)),
                 res.grid.voxel_size, int(np.count_nonzero(res.density)), res.seconds)
        protos.append(
            {
                "path": proto.path,
                "volume": volume_path(scene, proto),
                "leaves": proto.leaves.count,
                "shape": list(res.grid.shape),
                "voxel_size": res.grid.voxel_size,
                "origin": list(res.grid.origin),
                "active_voxels": int(np.count_nonzero(res.density)),
                "leaf_area_mesh": res.leaf_area_mesh,
                "leaf_area_grid": None if rel_err is None else res.leaf_area_grid,
                "area_rel_error": rel_err,
                "seconds": res.seconds,
            }
        )
    stats: DensityStats = {"method": params.method, "prototypes": protos}
    return write_stage(report, path, out, edits, stats, progress)

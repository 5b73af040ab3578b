"""``foliage spp``: simplified plane-parallel scattering with the G-factor (shinya2013 sec. 3–5).

Per prototype: leaf-area density grid (``density``'s area method) -> optical
depth and thickness toward the sun and N sample directions by integrating the
grid (eq. 29, grid path; G-function 0.5) -> G-factor (eqs. 23–28, A.3,
re-derived in lighting.gfactor) -> per-leaf SPPG, SPP and single-scattering
(SS) irradiance (sec. 5.4 steps 4–6). Grids sppDepth and sppThickness are
toward the sun, sppGFactor is G toward the sun, per cell.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from foliage_tools import __version__
from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import Sun, to_prototype_space
from foliage_tools.lighting import depth as depth_mod
from foliage_tools.lighting import gfactor as gf
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.params import DensityParams
from foliage_tools.pipeline.density import compute_density, vdb_path, volume_path
from foliage_tools.pipeline.leafdata import leaf_primvar_edits, native_instance_warning
from foliage_tools.pipeline.report import Progress, Report, Silent
from foliage_tools.pipeline.stage import begin_bake, sun_in_prototype
from foliage_tools.scene.model import Prototype, Scene
from foliage_tools.scene.vdb import Grid
from foliage_tools.scene.write import LayerEdits, PrimvarEdit, VolumeEdit, stage_metadata, write_layer


@dataclass(frozen=True)
class SppParams:
    """What ``foliage spp`` bakes."""

    optics: LeafOptics
    sun: tuple[float, float] | None = None
    resolution: int = 64
    """Density grid voxels along the longest foliage edge."""
    directions: int = gf.DEFAULT_DIRECTIONS
    """Sample directions for the G-factor and the sky (the paper used 16–22)."""
    gfactor: bool = True
    """False (``--no-gfactor``): the SPP bake without G; the sppg primvars are then not written."""
    refine: bool = False
    """Integrate the refined radiance of appendix A.1 for the sun's scattered light."""

    def __post_init__(self) -> None:
        if not (4 <= self.resolution <= 512):
            raise UsageError(f"--resolution must be between 4 and 512, got {self.resolution}.")
        if self.directions < 2 or self.directions % 2:
            raise UsageError(f"--directions must be an even number >= 2, got {self.directions}.")


@dataclass(frozen=True)
class SppBake:
    index: int
    result: gf.SPPGResult
    grid_depth: np.ndarray
    grid_thickness: np.ndarray
    grid_gfactor: np.ndarray
    origin: tuple
    voxel_size: float
    seconds: float


def bake_prototype(proto: Prototype, index: int, sun_local: np.ndarray, up_local: np.ndarray, params: SppParams) -> SppBake:
    dens = compute_density(proto, DensityParams(resolution=params.resolution, method="area"))
    grid = dens.grid
    if float(sun_local @ up_local) <= 0.0:
        raise UsageError(f"prototype <{proto.path}>: the sun is below the horizon; SPP needs a sun above it (--sun AZ,EL with EL > 0).")
    dirs = gf.sample_directions(params.directions, up=up_local)
    leaf_depths = depth_mod.depth_samples(dens.density, grid, sun_direction=sun_local, directions=dirs, points=proto.leaves.centers)
    result = gf.solve_sppg(
        leaf_depths, normals=proto.leaves.normals, optics=params.optics, sun_direction=sun_local, directions=dirs, up=up_local,
        params=gf.SPPGParams(refine=params.refine),
    )
    cells = depth_mod.depth_samples(dens.density, grid, sun_direction=sun_local, directions=dirs)
    g_cells = gf.gfactor(boundary_depth=cells.sample_depth, directions=dirs, light_direction=sun_local,
                         light_depth=cells.sun_depth, light_thickness=cells.sun_thickness, up=up_local)
    shape = grid.shape
    return SppBake(
        index, result,
        cells.sun_depth.reshape(shape), cells.sun_thickness.reshape(shape), g_cells.reshape(shape),
        tuple(grid.origin), grid.voxel_size, dens.seconds + result.seconds,
    )


def bake_spp(scene: Scene, sun: Sun, params: SppParams, warnings: list[str], progress: Progress) -> list[SppBake]:
    baked = [(i, p) for i, p in enumerate(scene.prototypes) if p.leaves.count]
    progress.step(f"SPP/SPPG for {len(baked)} prototype(s)", total=len(baked))
    out = []
    for i, proto in baked:
        insts = scene.instances_of(i)
        if len(insts) > 1:
            warnings.append(f"prototype <{proto.path}>: neighbouring instances' depth (shinya2013 eq. 31) is not added yet.")
        sun_local = sun_in_prototype(scene, i, sun, warnings)
        up_local = to_prototype_space(scene.up, insts[0].transform) if insts else scene.up
        out.append(bake_prototype(proto, i, sun_local, up_local, params))
        progress.advance()
    return out


def _vertex_values(proto: Prototype, per_leaf: np.ndarray, type_: str, name: str) -> list[PrimvarEdit]:
    """Per-leaf values spread to the vertices of each leaf mesh (a vertex takes the value of its leaf)."""
    edits = []
    for i, mesh in enumerate(proto.meshes):
        if not mesh.is_leaf or not proto.editable:
            continue
        tri_leaf = proto.leaves.face_leaf_ids[i][mesh.face_of_triangle]
        vertex_leaf = np.full(mesh.points.shape[0], -1, dtype=np.int64)
        vertex_leaf[mesh.triangles.reshape(-1)] = np.repeat(tri_leaf, 3)
        values = np.zeros((mesh.points.shape[0],) + per_leaf.shape[1:])
        ok = vertex_leaf >= 0
        values[ok] = per_leaf[vertex_leaf[ok]]
        edits.append(PrimvarEdit(prim=mesh.path, name=name, values=values, type=type_, interpolation="vertex"))
    return edits


def run_spp(path: Path, out: Path, params: SppParams, *, progress: Progress | None = None) -> Report:
    progress = progress or Silent()
    report, scene, sun = begin_bake("spp", path, out, params.sun, progress)
    edits = LayerEdits()
    protos = []
    for bake in bake_spp(scene, sun, params, report.warnings, progress):
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
        }
        edits.volumes.append(VolumeEdit(path=volume_path(proto), vdb_file=vdb_path(out, scene, bake.index), grids=grids, attributes=attrs))
        if not proto.editable:
            report.warnings.append(native_instance_warning(proto, "SPP primvars"))
        methods = {"spp": res.spp, "ss": res.ss}
        if params.gfactor:
            methods["sppg"] = res.sppg
        for m, irr in methods.items():
            edits.primvars += leaf_primvar_edits(proto, f"foliage:{m}:direct", irr.direct, type="color3f")
            edits.primvars += leaf_primvar_edits(proto, f"foliage:{m}:scattered", irr.scattered, type="color3f")
        best = res.sppg if params.gfactor else res.spp
        edits.primvars += _vertex_values(proto, best.direct + best.scattered, "color3f", "foliage:sppIrradiance")
        edits.primvars += _vertex_values(proto, res.gfactor, "float", "foliage:gFactor")
        protos.append({
            "path": proto.path, "leaves": proto.leaves.count, "cells": int(bake.grid_depth.size), "resolution": list(bake.grid_depth.shape),
            "gfactor_mean": float(np.mean(res.gfactor)), "seconds": bake.seconds,
            "e_scattered_mean": {m: irr.scattered.mean(axis=0).tolist() for m, irr in methods.items()},
        })
    progress.step(f"writing {out}")
    report.outputs = [str(p) for p in write_layer(path, out, edits, input_stage_meta=stage_metadata(path))]
    report.stats = {
        "directions": params.directions, "cells": int(sum(p["cells"] for p in protos)), "refine": params.refine,
        "gfactor": params.gfactor, "sun": {"azimuth": sun.azimuth, "elevation": sun.elevation, "source": sun.source},
        "optics": params.optics.as_dict(), "prototypes": protos,
    }
    return report.finish()

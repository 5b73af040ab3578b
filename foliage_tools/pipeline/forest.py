"""A forest lit as a forest: steele2010 sec. 3.2's coarse global lattice, as a per-instance scale of the scattered light.

A prototype's volume bake (LB, SPP, s_max) lights the tree alone, so an
instance in a stand gets the scattered light of a lone tree; in a stand the
neighbours scatter light into it (issue #16: +30 % for the centre of a 5 x 5
stand of touching crowns). steele2010 sec. 3.2 solves a coarse lattice over
the whole scene and lets it scale the fine per-tree light. Here:

1. every leaf of every instance deposits its area in the cell of a coarse
   world grid holding its centre (``CELLS_PER_CROWN`` cells across the largest
   prototype, at most ``MAX_NODES`` nodes), giving the leaf-area density of the
   stand; each prototype alone gets the same deposit, on a grid of the same
   voxel size in its own frame;
2. both are solved for the sun as ``foliage lb`` does (first-collision source,
   exact first order, bi-Lambertian phase; ``pipeline.lb``), the scattered
   scalar irradiance u_s = u - u_unscattered sampled at the leaf centres;
3. the factor of instance n is the ratio of the leaf-area-weighted mean u_s
   over its leaves in the stand to that over the prototype's leaves alone,
   per channel:

       f_n = <u_s,stand>_n / <u_s,alone>_p(n);

4. the same ratio of the never-scattered beam (the exact attenuated sun at
   the nodes, ``lb.LBResult.beam_direct``) is the instance's direct factor,
   the neighbours' shade. It is used where the shadow rays trace only the
   lone trees (a forest above ``world.WORLD_MAX_TRIANGLES``); below, the
   rays trace every instance and the direct light needs no factor.

Both solves use the same voxel size and the same deposit, so the coarse grid's
own error in u_s cancels in the ratio to first order; what it keeps is how much
more (or less) scattered light the neighbours bring. For it to cancel, the lone
tree must fall into the cells as its instances do: it is solved turned as up to
``ALONE_ROTATIONS`` of them, on world-aligned grids, and averaged
(``_alone_means``). What does not cancel is the coarse grid's homogenisation
of the stand: at 8 cells per crown the stand's crown means read +6 % where the
lone tree's are right (5 x 5 stand), +2.4 % at 16, 0 at 24. Where MAX_NODES
makes the grid coarser than ``CELLS_PER_CROWN``, that bias is measured on the
instances nearest the stand's centre, solved apart at both cell sizes, and
divided out (``_calibration``).
"""

from __future__ import annotations

import logging
import math
import hashlib
import time
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy import ndimage

from foliage_tools.geometry.sun import Sun
from foliage_tools.geometry.voxelize import GridSpec
from foliage_tools.lighting import lb
from foliage_tools.lighting.lb import single_scatter
from foliage_tools.lighting import stand as placed
from foliage_tools.lighting.lb.collision import density_from_lad, leaf_medium
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.report import Progress, Silent
from foliage_tools.pipeline.stats import ForestStats
from foliage_tools.scene.model import Scene

log = logging.getLogger(__name__)

#: Coarse cells across the largest prototype's longest edge. On the 5 x 5 stand of tests/integration/test_stand.py
#: (tree_small, sun at 45 degrees, 4M-path reference) the factors' mean over the reference's was 1.101 / 1.073 /
#: 1.062 / 1.041 / 1.021 / 0.997 at 4 / 6 / 8 / 12 / 16 / 24 cells (per-instance RMS 0.014 at 24), in 0.4 / 0.1 /
#: 0.2 / 0.5 / 1.1 / 4.8 s (/tmp study script, 2026-12-02; the lone solve turned as the instances, _alone_means).
#: The error falls faster than first order in the cell size, so no Richardson step: 24 cells, capped by MAX_NODES.
CELLS_PER_CROWN = 24
#: The lattice's stopping tolerance and the exact first order's directions (lighting.single_scatter). The factors
#: are ratios of crown means: on the 5 x 5 stand, tolerance 1e-3 moved every factor by < 0.2 % from 1e-5 (in half
#: the sweeps; 1e-2: 4.4 %), and 16 directions by < 0.7 % from 64 (in 40 % of the time).
TOLERANCE, DIRECTIONS = 1e-3, 16
#: Placements of a prototype its lone solve is turned by (``_alone_means``); their spread on the 5 x 5 stand was
#: +-0.7 % of the crown mean, so 8 hold the mean to ~0.3 %.
ALONE_ROTATIONS = 8
#: Where the MAX_NODES cap leaves the stand's grid coarser than CELLS_PER_CROWN, the factors are divided by the
#: grid's own bias, measured on this many instances nearest the stand's centre solved apart at both cell sizes
#: (_calibration): on the 5 x 5 stand the factors read 1.062 of the reference's at 8 cells, 0.997 at 24.
CALIBRATION_INSTANCES = 25
#: Most nodes of the stand's grid: above it the cells grow (and the factor gets cruder; 10 000 crowns get ~5 cells
#: across), so the solve holds ~2-3 GB.
MAX_NODES = 4_000_000


@dataclass(frozen=True)
class ForestLight:
    grid: GridSpec
    """The stand's coarse world grid."""
    scattered: np.ndarray
    """(nx, ny, nz, 3) scattered scalar irradiance of the stand, per unit sun irradiance."""
    lad: np.ndarray
    """(nx, ny, nz) float32 leaf area density of the stand (leaf area per unit volume, stage units⁻¹)."""
    factors: np.ndarray
    """(N, 3) per instance: its scattered light in the stand over the same tree's alone."""
    direct_factors: np.ndarray
    """(N, 3) per instance: its direct light in the stand over the same tree's alone (the neighbours' shade;
    used where the shadow rays trace the lone trees, ``world.bake_world``)."""
    seconds: float
    calibration: np.ndarray | None = None
    """(2C,) the capped grid's bias the factors were divided by (scattered, then direct); None: not capped."""

    def stats(self) -> ForestStats:
        return {"grid": list(self.grid.shape), "voxel_size": self.grid.voxel_size, "seconds": self.seconds,
                "factor_min": self.factors.min(axis=0).tolist(), "factor_max": self.factors.max(axis=0).tolist(),
                "direct_factor_min": self.direct_factors.min(axis=0).tolist(),
                "direct_factor_max": self.direct_factors.max(axis=0).tolist(),
                "calibration": None if self.calibration is None else self.calibration.tolist()}


def forest_volume(scene: Scene, forest: ForestLight, vdb_file, purpose: str, method: str):
    """The stand's lattice as a ``UsdVol.Volume`` in world space under the default prim (``FoliageForest``):
    ``forestDensity`` (leaf area density) and ``forestScattered`` (scattered scalar irradiance per unit sun
    irradiance, RGB). When the default prim is transformed, the volume carries the inverse, so its grids stay in
    world coordinates."""
    from foliage_tools import __version__
    from foliage_tools.scene.vdb import Grid
    from foliage_tools.scene.write import VolumeEdit

    g = forest.grid
    meta = {"foliage:method": method, "foliage:forest": True}
    grids = (Grid("forestDensity", forest.lad, g.origin, g.voxel_size, meta),
             Grid("forestScattered", forest.scattered.astype(np.float32), g.origin, g.voxel_size, meta))
    root = scene.default_prim or ""
    world_from_root = np.asarray(scene.default_prim_transform, dtype=np.float64)
    transform = None if np.allclose(world_from_root, np.eye(4)) else np.linalg.inv(world_from_root)
    attrs = {"foliage:method": method, "foliage:voxelSize": float(g.voxel_size),
             "foliage:resolution": tuple(int(n) for n in g.shape), "foliage:metersPerUnit": float(scene.meters_per_unit),
             "foliage:seconds": float(forest.seconds), "foliage:version": __version__}
    return VolumeEdit(path=f"{root}/FoliageForest", vdb_file=vdb_file, grids=grids, attributes=attrs, purpose=purpose,
                      transform=transform)


def _grid_over(points: np.ndarray, voxel: float) -> GridSpec:
    lo = points.min(axis=0) - voxel
    shape = tuple(int(n) for n in np.maximum(np.ceil((points.max(axis=0) + voxel - lo) / voxel), 2))
    # lo and shape have one entry per axis
    return GridSpec(origin=cast("tuple[float, float, float]", tuple(float(v) for v in lo)), voxel_size=float(voxel),
                    shape=cast("tuple[int, int, int]", shape))


def _solve(lad: np.ndarray, grid: GridSpec, sun_dir: np.ndarray, optics: LeafOptics, tolerance: float,
           directions: int = DIRECTIONS):
    """(u_s, beam): scattered and never-scattered scalar irradiance (nx, ny, nz, C) of the sun through a leaf-area
    density, as ``foliage lb`` solves it."""
    rho = density_from_lad(lad, grid.voxel_size)
    problem = lb.LBProblem(density=rho, medium=leaf_medium(optics, absorption_scale=1.0, phase="bilambertian"),
                           boundaries=(lb.sun_source(sun_dir),))
    res = lb.solve(problem, lb.LBParams(tolerance=tolerance))
    occupied = rho > 0
    near = ndimage.binary_dilation(occupied, structure=np.ones((3, 3, 3), bool))
    total = single_scatter.corrected_energy(problem, res, mask=occupied, fill=near, directions=directions)
    # the exact first order matters here: with the lattice's own, every factor of the 5 x 5 stand read
    # 6-19 % above the reference's (it does not cancel in the ratio)
    assert res.beam_direct is not None  # the sun_source boundary is a beam
    beam = res.beam_direct[..., 0, :]
    return np.maximum(total[..., 0, :] - beam, 0.0), beam


_LAST: list = []  # (key, result): the stages of one `foliage bake` read the same scene under the same sun


def forest_light(scene: Scene, sun: Sun, optics: LeafOptics, *, progress: Progress | None = None,
                 tolerance: float = TOLERANCE) -> ForestLight | None:
    """The per-instance scale of the scattered and direct light (module docstring); None for a scene of one instance.

    The last result is kept: ``foliage bake`` runs smax, spp and lb over one scene, and they need the same lattice.
    """
    if len(scene.instances) < 2:
        return None
    (progress or Silent()).step(f"forest lattice: the stand's light per instance ({len(scene.instances):,} instances)")
    key = (_fingerprint(scene), tuple(np.round(sun.direction, 12)), tuple(optics.reflectance),
           tuple(optics.transmittance), tolerance)
    if _LAST and _LAST[0][0] == key:
        return _LAST[0][1]
    t0 = time.perf_counter()
    result = _forest_light(scene, sun, optics, tolerance)
    log.info("forest lattice: %s instances, %s, %.2f s", f"{len(scene.instances):,}", result.stats(), time.perf_counter() - t0)
    _LAST[:] = [(key, result)]
    return result


def _fingerprint(scene: Scene) -> str:
    """What the lattice depends on: every instance's prototype and transform, every prototype's leaves."""
    h = hashlib.sha1()
    h.update(np.array([i.prototype for i in scene.instances], dtype=np.int64).tobytes())
    h.update(np.stack([np.asarray(i.transform, dtype=np.float64) for i in scene.instances]).tobytes())
    for proto in scene.prototypes:
        h.update(np.ascontiguousarray(proto.leaves.centers, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(proto.leaves.areas, dtype=np.float64).tobytes())
    return h.hexdigest()


def _baked(scene: Scene) -> list[int]:
    """The prototypes with leaves and instances."""
    return [i for i, p in enumerate(scene.prototypes) if p.leaves.count and scene.instances_of(i)]


def _crown(scene: Scene, baked: list[int]) -> float:
    """The longest edge of the largest baked prototype's leaf box (what ``CELLS_PER_CROWN`` divides), at least its
    largest leaf's size (sqrt of its area): a prototype of one leaf, or of leaves in one plane, has a box of no
    extent along some axis, and a voxel of 1e-9 / 24 once made a 944215 x 2 x 2 forest lattice of a two-leaf
    stand 3 m apart (19 s, 2.5 GB)."""
    return max(max(float(np.ptp(leaves.centers, axis=0).max()), float(np.sqrt(leaves.areas.max())))
               for leaves in (scene.prototypes[i].leaves for i in baked))


def _leaf_box_corners(leaves, placements: np.ndarray) -> np.ndarray:
    """(2, 3) world min and max of the placed leaf boxes of one prototype."""
    c = leaves.centers
    lo, hi = c.min(axis=0), c.max(axis=0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = np.einsum("kij,lj->kli", placements[:, :3, :3], box) + placements[:, None, :3, 3]
    return np.array([w.min(axis=(0, 1)), w.max(axis=(0, 1))])


def stand_grid(scene: Scene) -> GridSpec:
    """The stand's coarse world grid: ``CELLS_PER_CROWN`` cells across the largest prototype's leaves, over the
    bounds of every instance's leaf box, coarser when that holds more than ``MAX_NODES`` nodes."""
    baked = _baked(scene)
    voxel = max(_crown(scene, baked), 1e-9) / CELLS_PER_CROWN
    corners = np.concatenate([_leaf_box_corners(scene.prototypes[i].leaves,
                                                np.stack([inst.transform for inst in scene.instances_of(i)]))
                              for i in baked])
    span = np.ptp(corners, axis=0) + 2 * voxel
    if np.prod(np.ceil(span / voxel) + 1) > MAX_NODES:
        voxel = float((np.prod(span) / MAX_NODES) ** (1 / 3))
    grid = _grid_over(corners, voxel)
    while math.prod(grid.shape) > MAX_NODES:  # a flat stand: its few vertical cells and margins round up (Python ints: np.prod overflowed to < 0)
        voxel *= 1.05
        grid = _grid_over(corners, voxel)
    return grid


def _alone_means(leaves, placements: np.ndarray, voxel: float, sun_dir: np.ndarray, optics: LeafOptics,
                 tolerance: float) -> np.ndarray:
    """(1, 2C) crown means of u_s and the beam of the prototype alone, solved turned as its instances are.

    The lone tree is placed by the linear part of up to ``ALONE_ROTATIONS`` of its instances (evenly spaced) on a
    world-aligned grid of the stand's voxel size, and the means are averaged. Turned as the instances are, its
    leaves fall into the cells as theirs do in the stand; in its own frame, on a grid aligned with its axes, they
    did not: on the 5 x 5 stand at 24 cells per crown the unturned tree read 1.052 of the reference's crown mean
    and the turned ones 0.963-0.977 (mean 0.971, the stand's own instances 0.971), so every factor was 8 % low.
    """
    picks = np.unique(np.linspace(0, len(placements) - 1, min(ALONE_ROTATIONS, len(placements))).round().astype(int))
    means = []
    for k in picks:
        turn = placements[k].copy()
        turn[:3, 3] = 0.0
        g = _grid_over(leaves.centers @ turn[:3, :3].T, voxel)
        u, beam = _solve(placed.deposit(g, turn, leaves.centers, leaves.areas), g, sun_dir, optics, tolerance)
        means.append(placed.instance_means(np.concatenate([u, beam], axis=-1), g, turn, leaves.centers, leaves.areas))
    return np.mean(means, axis=0)


def _ratios(scene: Scene, placements: dict[int, np.ndarray], grid: GridSpec, sun_dir: np.ndarray, optics: LeafOptics,
            tolerance: float):
    """Per prototype, (N_i, 2C) stand over alone of u_s and the beam for the placements on ``grid``; and the stand's
    u_s and leaf-area density."""
    lad = np.zeros(grid.shape)
    for i, m in placements.items():
        leaves = scene.prototypes[i].leaves
        placed.deposit(grid, m, leaves.centers, leaves.areas, out=lad)
    stand, stand_beam = _solve(lad, grid, sun_dir, optics, tolerance)
    both = np.concatenate([stand, stand_beam], axis=-1)  # one pass over the placed leaves for the two fields
    out = {}
    for i, m in placements.items():
        leaves = scene.prototypes[i].leaves
        in_stand = placed.instance_means(both, grid, m, leaves.centers, leaves.areas)
        alone = _alone_means(leaves, m, grid.voxel_size, sun_dir, optics, tolerance)
        out[i] = np.divide(in_stand, alone, out=np.ones_like(in_stand), where=alone > 0)
    return out, stand, lad


def _calibration(scene: Scene, baked: list[int], voxel: float, sun_dir: np.ndarray, optics: LeafOptics,
                 tolerance: float) -> np.ndarray:
    """(2C,) how much the stand's grid, coarser than ``CELLS_PER_CROWN`` (the MAX_NODES cap), overstates the
    factors: on the ``CALIBRATION_INSTANCES`` instances nearest the stand's centre, solved apart at that voxel and
    at ``CELLS_PER_CROWN``, the mean ratio of their factors."""
    t = np.stack([inst.transform[:3, 3] for inst in scene.instances])
    near: dict[int, list[np.ndarray]] = {}
    for k in np.argsort(np.linalg.norm(t - t.mean(axis=0), axis=1))[:CALIBRATION_INSTANCES]:
        inst = scene.instances[k]
        if inst.prototype in baked:
            near.setdefault(inst.prototype, []).append(inst.transform)
    window = {i: np.stack(ms) for i, ms in near.items()}
    corners = np.concatenate([_leaf_box_corners(scene.prototypes[i].leaves, m) for i, m in window.items()])
    coarse, _, _ = _ratios(scene, window, _grid_over(corners, voxel), sun_dir, optics, tolerance)
    fine, _, _ = _ratios(scene, window, _grid_over(corners, _crown(scene, baked) / CELLS_PER_CROWN), sun_dir, optics,
                         tolerance)
    r = np.concatenate([coarse[i] / np.where(fine[i] > 0, fine[i], 1.0) for i in window])
    return r.mean(axis=0)


def _forest_light(scene: Scene, sun: Sun, optics: LeafOptics, tolerance: float) -> ForestLight:
    t0 = time.perf_counter()
    baked = _baked(scene)
    grid = stand_grid(scene)
    placements = {i: np.stack([inst.transform for inst in scene.instances_of(i)]) for i in baked}
    ratios, stand, lad = _ratios(scene, placements, grid, sun.direction, optics, tolerance)
    calibrate = _crown(scene, baked) / grid.voxel_size < 0.9 * CELLS_PER_CROWN and len(scene.instances) > CALIBRATION_INSTANCES
    bias = _calibration(scene, baked, grid.voxel_size, sun.direction, optics, tolerance) if calibrate else 1.0
    n, c = len(scene.instances), stand.shape[-1]
    factors, direct_factors = np.ones((n, c)), np.ones((n, c))
    for i in baked:
        ks = [k for k, inst in enumerate(scene.instances) if inst.prototype == i]
        ratio = ratios[i] / bias
        factors[ks], direct_factors[ks] = ratio[:, :c], ratio[:, c:]
    return ForestLight(grid, stand, lad.astype(np.float32), factors, direct_factors, time.perf_counter() - t0,
                       np.asarray(bias) if calibrate else None)

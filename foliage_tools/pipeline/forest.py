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

       f_n = <u_s,stand>_n / <u_s,alone>_p(n).

Both solves use the same voxel size and the same deposit, so the coarse grid's
own error in u_s cancels in the ratio to first order; what it keeps is how much
more (or less) scattered light the neighbours bring. The alone solve uses the
sun as the prototype's first instance sees it: the crown mean of u_s hardly
depends on the azimuth at which a round crown is turned.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from foliage_tools.geometry.sun import Sun
from foliage_tools.geometry.voxelize import GridSpec
from foliage_tools.lighting import lb, single_scatter
from foliage_tools.lighting.collision import density_from_lad, leaf_medium
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.instances import instance_means
from foliage_tools.pipeline.report import Progress, Silent
from foliage_tools.pipeline.stage import first_instance_sun
from foliage_tools.pipeline.world import World
from foliage_tools.scene.model import Scene

#: Coarse cells across the largest prototype's longest edge. On the 5 x 5 stand of tests/integration/test_stand.py
#: every instance's factor was within 2.6 % of the Monte Carlo reference's at 16 (the centre tree 1.31 against
#: 1.30), the centre +9 % off at 8 and +16 % at 4; 0.6 s at 8, 3 s at 16.
CELLS_PER_CROWN = 16
#: Most nodes of the stand's grid: above it the cells grow (and the factor gets cruder; 10 000 crowns get ~5 cells
#: across), so the solve holds ~2-3 GB.
MAX_NODES = 4_000_000


@dataclass(frozen=True)
class ForestLight:
    grid: GridSpec
    """The stand's coarse world grid."""
    scattered: np.ndarray
    """(nx, ny, nz, 3) scattered scalar irradiance of the stand, per unit sun irradiance."""
    factors: np.ndarray
    """(N, 3) per instance: its scattered light in the stand over the same tree's alone."""
    seconds: float

    def stats(self) -> dict:
        return {"grid": list(self.grid.shape), "voxel_size": self.grid.voxel_size, "seconds": self.seconds,
                "factor_min": self.factors.min(axis=0).tolist(), "factor_max": self.factors.max(axis=0).tolist()}


def _deposit(centres: np.ndarray, areas: np.ndarray, lo: np.ndarray, voxel: float, shape) -> np.ndarray:
    """Leaf-area density: each leaf's area in the cell holding its centre, over the cell volume."""
    idx = np.clip(np.floor((centres - lo) / voxel).astype(np.int64), 0, np.asarray(shape) - 1)
    flat = np.ravel_multi_index(tuple(idx.T), shape)
    return np.bincount(flat, weights=areas, minlength=int(np.prod(shape))).reshape(shape) / voxel**3


def _grid_over(points: np.ndarray, voxel: float) -> GridSpec:
    lo = points.min(axis=0) - voxel
    shape = tuple(int(n) for n in np.maximum(np.ceil((points.max(axis=0) + voxel - lo) / voxel), 2))
    return GridSpec(origin=tuple(float(v) for v in lo), voxel_size=float(voxel), shape=shape)


def _scattered(lad: np.ndarray, grid: GridSpec, sun_dir: np.ndarray, optics: LeafOptics, tolerance: float) -> np.ndarray:
    """u_s (nx, ny, nz, C) of the sun through a leaf-area density, as ``foliage lb`` solves it."""
    rho = density_from_lad(lad, grid.voxel_size)
    problem = lb.LBProblem(density=rho, medium=leaf_medium(optics, absorption_scale=1.0, phase="bilambertian"),
                           boundaries=(lb.sun_source(sun_dir),))
    res = lb.solve(problem, lb.LBParams(tolerance=tolerance))
    occupied = rho > 0
    near = ndimage.binary_dilation(occupied, structure=np.ones((3, 3, 3), bool))
    total = single_scatter.corrected_energy(problem, res, mask=occupied, fill=near)
    # the exact first order matters here: with the lattice's own, every factor of the 5 x 5 stand read
    # 6-19 % above the reference's (it does not cancel in the ratio)
    return np.maximum(total[..., 0, :] - res.beam_direct[..., 0, :], 0.0)


_LAST: list = []  # (key, world, result): the stages of one `foliage bake` share the world and the sun


def forest_light(scene: Scene, sun: Sun, optics: LeafOptics, world: World, *, progress: Progress | None = None,
                 tolerance: float = 1e-5) -> ForestLight | None:
    """The per-instance scale of the scattered light (module docstring); None for a scene of one instance.

    The last result is kept: ``foliage bake`` runs smax, spp and lb over one world (its shared direct light's),
    and they need the same lattice.
    """
    if len(scene.instances) < 2:
        return None
    (progress or Silent()).step("forest lattice: the stand's scattered light per instance")
    key = (id(world), tuple(np.round(sun.direction, 12)), tuple(optics.reflectance), tuple(optics.transmittance), tolerance)
    if _LAST and _LAST[0][0] == key and _LAST[0][1] is world:
        return _LAST[0][2]
    result = _forest_light(scene, sun, optics, world, tolerance)
    _LAST[:] = [(key, world, result)]
    return result


def _forest_light(scene: Scene, sun: Sun, optics: LeafOptics, world: World, tolerance: float) -> ForestLight:
    from foliage_tools.pipeline.lb import sample_trilinear  # pipeline.lb bakes with this module's factors

    t0 = time.perf_counter()
    baked = [i for i, p in enumerate(scene.prototypes) if p.leaves.count]
    crown = max(float(np.ptp(scene.prototypes[i].leaves.centers, axis=0).max()) for i in baked)
    voxel = max(crown, 1e-9) / CELLS_PER_CROWN
    span = np.ptp(world.leaf_centers, axis=0) + 2 * voxel
    if np.prod(np.ceil(span / voxel) + 1) > MAX_NODES:
        voxel = float((np.prod(span) / MAX_NODES) ** (1 / 3))
    grid = _grid_over(world.leaf_centers, voxel)
    lo = np.asarray(grid.origin)
    stand = _scattered(_deposit(world.leaf_centers, world.leaf_area, lo, voxel, grid.shape), grid, sun.direction, optics, tolerance)
    in_stand = instance_means(world, sample_trilinear(stand, grid, world.leaf_centers))
    alone = {}
    for i in baked:
        proto = scene.prototypes[i]
        # the prototype's leaf areas in its own frame (world areas of one instance over its scale squared)
        k = next(n for n, inst in enumerate(scene.instances) if inst.prototype == i)
        s2 = abs(np.linalg.det(scene.instances[k].transform[:3, :3])) ** (2 / 3)
        areas = world.leaf_area[world.instance_slice(k)] / s2
        g = _grid_over(proto.leaves.centers, voxel)
        u = _scattered(_deposit(proto.leaves.centers, areas, np.asarray(g.origin), voxel, g.shape), g,
                       first_instance_sun(scene, i, sun.direction), optics, tolerance)
        vals = sample_trilinear(u, g, proto.leaves.centers)
        alone[i] = np.tensordot(areas, vals, axes=(0, 0)) / areas.sum()
    factors = np.ones((len(scene.instances), 3))
    for n, inst in enumerate(scene.instances):
        a = alone.get(inst.prototype)
        if a is not None:
            factors[n] = np.divide(in_stand[n], a, out=np.ones(3), where=a > 0)
    return ForestLight(grid, stand, factors, time.perf_counter() - t0)

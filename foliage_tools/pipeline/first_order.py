"""``--first-order march``: SPPG's and LB's once-scattered sun light from the leaves' exact direct light (lighting.first_order).

Per prototype alone (``marched_once``: each tree lit alone, as the volume
methods light it, the forest lattice adding a forest's neighbours) the leaves'
exact direct light is scattered once
(and the wood's, traced here) and marched through a coarse voxel medium of their triangles; each leaf's
E_scattered is that times SPPG's all-orders-over-first factor at the leaf
(``SPPGResult.orders``, the mean over the prototype's instances), or that
plus the LB lattice's later orders at the leaf. Per prototype the result is
the mean over its instances, as for the other per-leaf values; it replaces
``result.sppg.scattered`` (SPP) or ``e_scattered`` (LB) of each bake.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from foliage_tools.geometry.sun import Sun
from foliage_tools.lighting import direct, first_order
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.direct import DirectBake, DirectChoice, trace_world
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.report import Progress
from foliage_tools.pipeline.world import World, assemble, lone_trees, prototype_means, traced_parts
from foliage_tools.scene.model import Scene

log = logging.getLogger(__name__)


#: Shadow rays per wood triangle for its direct light (at most; fewer, down to 2, above WOOD_RAY_BUDGET rays).
WOOD_SAMPLES, WOOD_RAY_BUDGET = 16, 1 << 22


def wood_direct(triangles: np.ndarray, leaf_of_triangle: np.ndarray, sun_direction: np.ndarray) -> np.ndarray | None:
    """(W,) direct sun irradiance of each wood triangle (leaf id -1), from shadow rays through every triangle;
    None without wood. Wood scatters a share of the first order where leaves are dark: on tree_small at the
    default optics the march without it read 0.85 / 0.90 / 0.75 of the reference's E_scattered per channel, with
    it 0.95 in all three (README "SPPG's first order")."""
    is_wood = leaf_of_triangle < 0
    n = int(np.count_nonzero(is_wood))
    if n == 0:
        return None
    ids = np.full(len(leaf_of_triangle), -1)
    ids[is_wood] = np.arange(n)  # each wood triangle its own "leaf"; the leaves then only block
    k = int(max(2, min(WOOD_SAMPLES, WOOD_RAY_BUDGET // n)) // 2 * 2)
    return direct.solve(direct.DirectInputs(triangles, ids, n, sun_direction), direct.DirectParams(samples_per_leaf=k)).e_direct


def marched_once(scene: Scene, sun: Sun, optics: LeafOptics, direct: DirectBake, progress: Progress,
                 method: str) -> np.ndarray:
    """(L_world, C) once-scattered sun irradiance of every leaf of every instance (lighting.first_order).

    Each prototype is marched alone, lit by its own direct light alone, as the volume methods light it: in a
    forest the neighbours' shade and scattered light come from the exact per-instance direct light and the
    forest lattice's factor (pipeline.forest), which would count them twice if the march also saw the placed
    neighbours (measured on the 5 x 5 stand: the centre tree's scattered light over the tree alone 1.54 with a
    march through the placed stand, against the reference's 1.30). A forest traced as its lone trees already is
    one; a forest copied whole is marched over its lone trees (one instance per prototype, with their own shadow
    rays); a scene of one instance per prototype is marched as it stands."""
    world = direct.world
    if not world.lone and len(scene.instances) > len({inst.prototype for inst in scene.instances}):
        lone_world = replace(assemble(lone_trees(scene)), lone=True)
        lone = trace_world(lone_world, sun, int(direct.result.samples_per_leaf), DirectChoice().seed, progress)
        once_lone = _march_world(lone_world, lone.e_direct, sun, optics, progress, method)
        per_proto = prototype_means(lone_world, once_lone, len(scene.prototypes),
                                    [p.leaves.count for p in scene.prototypes])
        return from_prototypes(world, dict(enumerate(per_proto)))
    return _march_world(world, direct.result.e_direct, sun, optics, progress, method)


def _march_world(world: World, e_direct: np.ndarray, sun: Sun, optics: LeafOptics, progress: Progress,
                 method: str) -> np.ndarray:
    """(L_world, C): the march over each traced part of ``world`` (the whole world, or each lone tree), lit by
    ``e_direct`` (L_world,)."""
    n = int(world.offsets[-1])
    if n == 0:
        return np.zeros((0, len(optics.reflectance)))
    progress.step(f"{method} first order: {n:,} leaves marched through a {first_order.DEFAULT_RESOLUTION}-voxel medium")
    once = np.zeros((n, len(optics.reflectance)))
    seconds = 0.0
    for tris, ids, count, leaves in traced_parts(world):
        if not count:
            continue
        wood = wood_direct(tris, ids, sun.direction)
        res = first_order.solve(first_order.FirstOrderInputs(
            triangles=tris, leaf_of_triangle=ids, leaf_centers=world.leaf_centers[leaves],
            leaf_area=world.leaf_area[leaves], e_direct=e_direct[leaves], optics=optics, sun_direction=sun.direction,
            wood_direct=wood))
        once[leaves] = res.e_once
        seconds += res.seconds
    log.info("%s first order: %s leaves marched, %.2f s", method, f"{n:,}", seconds)
    return once


def march_sppg(scene: Scene, sun: Sun, optics: LeafOptics, bakes: list, direct: DirectBake, progress: Progress) -> list:
    """``bakes`` (pipeline.spp.SppBake, baked with ``g_orders``) with SPPG's sun E_scattered from the march: the
    first order times 1 / (1 - (1 - s) rho), SPPG's later orders (``SPPGResult.orders``)."""
    world = direct.world
    missing = [b.index for b in bakes if b.result.orders is None]
    if missing:
        raise ValueError(f"the first-order march needs SPPG's orders factor (g_orders) for prototypes {missing}")
    if not bakes or int(world.offsets[-1]) == 0:
        return bakes
    once = marched_once(scene, sun, optics, direct, progress, "SPPG")
    per_leaf = once * from_prototypes(world, {b.index: b.result.orders for b in bakes})
    counts = [p.leaves.count for p in scene.prototypes]
    means = prototype_means(world, per_leaf, len(counts), counts)
    return [replace(b, result=replace(b.result, sppg=replace(b.result.sppg, scattered=means[b.index]))) for b in bakes]


def march_lb(scene: Scene, sun: Sun, optics: LeafOptics, bakes: list, later: dict[int, np.ndarray], direct: DirectBake,
             progress: Progress) -> list:
    """``bakes`` (pipeline.lb.LBPrototypeBake, first-collision sun) with E_scattered = the marched first order plus
    ``later[p]``, the lattice's later orders at prototype p's leaves (pipeline.lb.later_orders: the lattice's
    first order taken out, as in Nakajima & Tanaka's correction, and replaced per leaf rather than per node)."""
    world = direct.world
    if not bakes or int(world.offsets[-1]) == 0:
        return bakes
    once = marched_once(scene, sun, optics, direct, progress, "LB")
    counts = [p.leaves.count for p in scene.prototypes]
    means = prototype_means(world, once + from_prototypes(world, later), len(counts), counts)
    return [replace(b, e_scattered=means[b.index]) for b in bakes]

"""``--gather N``: a final gather over the actual leaves on top of a volume bake (lighting.gather).

The volume method (LB or SPP) supplies the light scattered twice or more at
the leaf a gather ray hits; the first bounce comes from the hit point's own
shadow ray. Per prototype the result is the mean over its instances, as for
the other per-leaf values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import Sun
from foliage_tools.lighting import gather
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.report import Progress
from foliage_tools.pipeline.world import World, assemble, prototype_means
from foliage_tools.scene.model import Scene


def check_gather(rays: int) -> None:
    if rays != 0 and (rays < 4 or rays % 4 or rays > gather.MAX_RAYS):
        raise UsageError(f"--gather must be 0 (off) or a multiple of 4 rays per leaf (two halves per face) up to "
                         f"{gather.MAX_RAYS}, got {rays}.")


@dataclass(frozen=True)
class GatherBake:
    world: World
    result: gather.GatherResult
    rays_per_leaf: int
    per_prototype: list[np.ndarray]
    """Per prototype, (L, 3) gathered E_scattered, the mean over its instances."""

    def stats(self) -> dict:
        r = self.result
        return {"rays_per_leaf": self.rays_per_leaf, "rays": r.rays,
                "seconds": r.seconds, "noise_rel": r.noise_rel,
                "first_bounce_share": float(r.e_first.sum() / r.e_scattered.sum()) if r.e_scattered.sum() > 0 else None}


def bake_gather(scene: Scene, sun: Sun, optics: LeafOptics, rest: dict[int, np.ndarray], rays: int, progress: Progress,
                world: World | None = None, seed: int = 0) -> GatherBake:
    """Gathered E_scattered per prototype; ``rest[p]`` is the volume method's (L_p, 3) E_scattered of prototype p."""
    check_gather(rays)
    world = world if world is not None else assemble(scene)
    n = int(world.offsets[-1])
    per_leaf = np.maximum(from_prototypes(world, rest), 0.0)
    progress.step(f"final gather: {rays} rays per leaf over {n:,} leaves")
    res = gather.solve(gather.GatherInputs(world.triangles, world.leaf_of_triangle, n, optics, sun.direction, rest=per_leaf),
                       gather.GatherParams(rays_per_leaf=rays, seed=seed))
    counts = [p.leaves.count for p in scene.prototypes]
    return GatherBake(world, res, rays, prototype_means(world, res.e_scattered, len(counts), counts))

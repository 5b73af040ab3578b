"""``--gather N``: a final gather over the actual leaves on top of a volume bake (lighting.gather).

The volume method (LB or SPP) supplies the light scattered twice or more at
the leaf a gather ray hits; the first bounce comes from the hit point's own
shadow ray. Per prototype the result is the mean over its instances, as for
the other per-leaf values.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import Sun
from foliage_tools.lighting import gather
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.direct import within_budget
from foliage_tools.pipeline.instances import from_prototypes
from foliage_tools.pipeline.report import Progress
from foliage_tools.pipeline.stats import GatherStats
from foliage_tools.pipeline.world import World, bake_world, lone_parts, prototype_means, traced_parts
from foliage_tools.scene.model import Scene

log = logging.getLogger(__name__)


#: ``--gather auto``: rays per leaf, the largest power of two from AUTO_MAX down to AUTO_MIN whose rays over the
#: traced leaves stay within AUTO_RAY_BUDGET, and off above AUTO_RAY_BUDGET / AUTO_MIN leaves. Why these: on the oak
#: (1831 leaves, lb-64, 2 % reference) per-leaf E_scattered relative RMS is 0.280 without a gather, 0.269 / 0.187 /
#: 0.139 / 0.106 / 0.092 / 0.085 / 0.080 at 32 / 64 / 128 / 256 / 512 / 1024 / 2048 rays, i.e. the gather's own
#: sampling error: it pays from 64 rays on; and Embree traces a gather ray with its shadow ray at ~1M per second on
#: 2 cores, so the budget keeps the gather to ~10-20 s on any tree, like the direct light's (pipeline.direct).
AUTO_MIN, AUTO_MAX, AUTO_RAY_BUDGET = 64, 1024, 1 << 24


def auto_rays(leaves: int) -> int:
    """Rays per leaf for ``--gather auto`` over ``leaves`` traced leaves; 0 (off) above the budget."""
    if leaves * AUTO_MIN > AUTO_RAY_BUDGET:
        return 0
    return within_budget(leaves, AUTO_MIN, AUTO_MAX, AUTO_RAY_BUDGET)


def check_gather(rays: int | None) -> None:
    """``rays``: 0 (off), a multiple of 4 up to MAX_RAYS, or None (``auto``)."""
    if rays is not None and rays != 0 and (rays < 4 or rays % 4 or rays > gather.MAX_RAYS):
        raise UsageError(f"--gather must be 'auto', 0 (off) or a multiple of 4 rays per leaf (two halves per face) up "
                         f"to {gather.MAX_RAYS}, got {rays}.")


def resolve_rays(rays: int | None, leaves: int, warnings: list[str]) -> int:
    """``--gather`` made concrete for ``leaves`` traced leaves (``auto``: :func:`auto_rays`, with a warning when it
    turns the gather off)."""
    if rays is not None:
        return rays
    k = auto_rays(leaves)
    if k == 0:
        warnings.append(f"--gather auto: off for {leaves:,} traced leaves (at {AUTO_MIN} rays per leaf they would take "
                        f"more than {AUTO_RAY_BUDGET / 1e6:.0f}M rays); the per-leaf scattered light is the volume "
                        f"method's. Give --gather {AUTO_MIN} (or more) to gather anyway, or --gather 0 to silence this.")
    return k


@dataclass(frozen=True)
class GatherBake:
    world: World
    result: gather.GatherResult
    rays_per_leaf: int
    per_prototype: list[np.ndarray]
    """Per prototype, (L, 3) gathered E_scattered, the mean over its instances."""

    def stats(self) -> GatherStats:
        r = self.result
        return {"rays_per_leaf": self.rays_per_leaf, "rays": r.rays,
                "seconds": r.seconds, "noise_rel": r.noise_rel,
                "first_bounce_share": float(r.e_first.sum() / r.e_scattered.sum()) if r.e_scattered.sum() > 0 else None}


def _joined(parts: list[gather.GatherResult]) -> gather.GatherResult:
    """One result of the lone trees gathered one by one (their leaves in world order)."""
    n = np.array([len(p.e_scattered) for p in parts], dtype=np.float64)
    noise = float(np.sqrt(np.sum(n * np.array([p.noise_rel for p in parts]) ** 2) / max(n.sum(), 1.0)))
    return gather.GatherResult(e_scattered=np.concatenate([p.e_scattered for p in parts]),
                               e_first=np.concatenate([p.e_first for p in parts]), noise_rel=noise,
                               rays=sum(p.rays for p in parts), seconds=sum(p.seconds for p in parts))


def bake_gather(scene: Scene, sun: Sun, optics: LeafOptics, rest: dict[int, np.ndarray], rays: int, progress: Progress,
                world: World | None = None, seed: int = 0) -> GatherBake:
    """Gathered E_scattered per prototype; ``rest[p]`` is the volume method's (L_p, 3) E_scattered of prototype p."""
    check_gather(rays)
    world = world if world is not None else bake_world(scene)
    n = int(world.offsets[-1])
    per_leaf = np.maximum(from_prototypes(world, rest), 0.0)
    alone = " (each prototype alone: the forest lattice adds the stand's light)" if world.lone else ""
    def traced(count: int) -> bool:  # a lone tree without leaves has nothing to gather
        return count > 0 or not world.lone

    total = sum(traced(leaves.stop - leaves.start) for _, leaves in lone_parts(world))
    progress.step(f"final gather: {rays} rays per leaf over {n:,} leaves{alone}", total=total)
    parts = []
    for tris, ids, count, leaves in traced_parts(world):  # one at a time: each holds its triangles
        if not traced(count):
            continue
        parts.append(gather.solve(gather.GatherInputs(tris, ids, count, optics, sun.direction, rest=per_leaf[leaves]),
                                  gather.GatherParams(rays_per_leaf=rays, seed=seed)))
        progress.advance()  # (also where a batch task re-shares its cores)
    res = parts[0] if len(parts) == 1 else _joined(parts)
    log.info("gather: %d rays per leaf over %s leaves, %.2f s", rays, f"{n:,}", res.seconds)
    counts = [p.leaves.count for p in scene.prototypes]
    return GatherBake(world, res, rays, prototype_means(world, res.e_scattered, len(counts), counts))

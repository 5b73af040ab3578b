"""The exact direct sunlight every bake writes by default (``--direct rays``).

E_direct per leaf from shadow rays through every triangle of every instance
(:mod:`foliage_tools.lighting.direct`), so no bake inherits its volume
model's error in the part of the light that is a pure visibility question.
``--direct volume`` keeps the method's own estimate (what the papers do: the
seeds leave direct sunlight to the renderer, steele2010 sec. 5, and their
volume estimates are what ``foliage bench`` shows beside the exact one).

Per-leaf values are stored per prototype: the mean over its instances, as the
Monte Carlo reference stores them. A forest traced as its lone trees (above
``world.WORLD_MAX_TRIANGLES``) gets its per-leaf values from each prototype's
first instance alone, and each instance's mean E_direct from shadow rays
through every placed instance (:func:`instance_direct`, nothing copied).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import Sun
from foliage_tools.lighting import direct
from foliage_tools.pipeline.report import Progress
from foliage_tools.pipeline.stats import DirectStats
from foliage_tools.pipeline.world import World, bake_world, prototype_means, traced_parts
from foliage_tools.scene.model import Scene

log = logging.getLogger(__name__)

#: ``--direct`` choices: shadow rays through the geometry, or the method's own volume estimate.
DIRECT_MODES = ("rays", "volume")

#: ``--direct-samples auto``: shadow rays per leaf, a power of two in [AUTO_MIN, AUTO_MAX], the most whose
#: total over all leaves of all instances stays within AUTO_RAY_BUDGET. The sampling error of a leaf falls
#: about as K^-0.6..-0.75 (stratified points; tree_small: 14 % at 16, 5 % at 64, 2 % at 256 relative RMS
#: over leaves), and Embree traces ~1-2M of these rays per second on 2 cores (bench_direct.py), so the budget keeps the
#: direct term to ~10-15 s on any tree: 1024 rays per leaf up to 16k leaves, 16 at 1M. At 256 the direct
#: term's noise (2-3 %) was the largest part of every method's total error on the test trees.
AUTO_MIN, AUTO_MAX, AUTO_RAY_BUDGET = 16, 1024, 1 << 24


def within_budget(count: int, low: int, high: int, budget: int) -> int:
    """The largest power of two from ``high`` down to ``low`` whose ``count`` multiples stay within ``budget``."""
    k = high
    while k > low and k * count > budget:
        k //= 2
    return k


def auto_samples(leaves: int) -> int:
    """Samples per leaf for ``--direct-samples auto`` (see :data:`AUTO_RAY_BUDGET`)."""
    return within_budget(leaves, AUTO_MIN, AUTO_MAX, AUTO_RAY_BUDGET)


@dataclass(frozen=True, eq=False)
class DirectChoice:
    """``--direct`` and ``--direct-samples``."""

    mode: str = "rays"
    samples: int | None = None
    """Shadow rays per leaf (even, ≥ 2); None: :func:`auto_samples` of the scene's leaf count."""
    seed: int = 0
    precomputed: "DirectBake | None" = None
    """A result already traced for this scene and sun (``bake`` traces once for its three stages); used as is."""

    def __post_init__(self) -> None:
        if self.mode not in DIRECT_MODES:
            raise UsageError(f"--direct must be one of {', '.join(DIRECT_MODES)}, got {self.mode!r}.")
        if self.samples is not None and (self.samples < 2 or self.samples % 2 or self.samples > direct.MAX_SAMPLES):
            raise UsageError(f"--direct-samples must be 'auto' or an even number from 2 to {direct.MAX_SAMPLES} (two "
                             f"halves for the noise estimate), got {self.samples}.")


@dataclass(frozen=True)
class DirectBake:
    world: World
    result: direct.DirectResult
    per_prototype: list[np.ndarray]
    """Per prototype (index = Scene.prototypes), (L, 3) E_direct, the mean over its instances."""
    instances: direct.InstanceDirect | None = None
    """A forest traced as its lone trees: each instance's mean E_direct traced through every placed instance
    (:func:`instance_direct`); None otherwise (the per-leaf values cover every instance)."""

    def stats(self) -> DirectStats:
        r = self.result
        out: DirectStats = {
            "mode": "rays", "samples_per_leaf": r.samples_per_leaf, "rays": r.rays, "seconds": r.seconds,
            "noise_rel": r.noise_rel, "leaves": int(r.e_direct.shape[0]),
        }
        if self.instances is not None:
            i = self.instances
            out["instances"] = {"samples_per_instance": i.samples_per_instance, "rays": i.rays,
                                "seconds": i.seconds, "noise_rel": i.noise_rel}
            out["seconds"] = r.seconds + i.seconds
        return out


def _joined(parts: list[direct.DirectResult]) -> direct.DirectResult:
    """One result of the lone trees traced one by one (their leaves in world order)."""
    n = np.array([len(p.e_direct) for p in parts], dtype=np.float64)
    noise = float(np.sqrt(np.sum(n * np.array([p.noise_rel for p in parts]) ** 2) / max(n.sum(), 1.0)))
    return direct.DirectResult(
        e_direct=np.concatenate([p.e_direct for p in parts]), noise_rel=noise,
        lit_fraction=np.concatenate([p.lit_fraction for p in parts]), rays=sum(p.rays for p in parts),
        samples_per_leaf=parts[0].samples_per_leaf, seconds=sum(p.seconds for p in parts))


def bake_direct(scene: Scene, sun: Sun, choice: DirectChoice, progress: Progress, world: World | None = None) -> DirectBake:
    """Exact E_direct of every leaf of every instance; per prototype, the mean over its instances."""
    if choice.precomputed is not None:
        if [len(p) for p in choice.precomputed.per_prototype] != [p.leaves.count for p in scene.prototypes]:
            raise ValueError("DirectChoice.precomputed was traced for another scene")
        return choice.precomputed
    world = world if world is not None else bake_world(scene)
    n = int(world.offsets[-1])
    samples = choice.samples if choice.samples is not None else auto_samples(n)
    res = trace_world(world, sun, samples, choice.seed, progress)
    counts = [p.leaves.count for p in scene.prototypes]
    per_leaf = np.repeat(res.e_direct[:, None], 3, axis=1)
    instances = instance_direct(scene, sun, progress, seed=choice.seed) if world.lone else None
    return DirectBake(world, res, prototype_means(world, per_leaf, len(counts), counts), instances)


def trace_world(world: World, sun: Sun, samples: int, seed: int, progress: Progress) -> direct.DirectResult:
    """Shadow rays from every leaf of ``world``: the whole world, or each lone tree of a lone world alone."""
    n = int(world.offsets[-1])
    alone = " (each prototype alone: the forest lattice adds the stand's shade)" if world.lone else ""
    progress.step(f"direct sunlight: {samples} shadow rays per leaf through {len(world.triangles):,} triangles{alone}", total=n)
    done = [0]

    def advance(d: int, _total: int) -> None:
        progress.advance(d - done[0])
        done[0] = d

    parts = []
    for tris, ids, count, leaves in traced_parts(world):  # the whole world, or each lone tree of a large forest
        if world.lone and count == 0:
            continue
        base = leaves.start

        def on_progress(d: int, _t: int, base: int = base) -> None:
            advance(base + d, n)

        parts.append(direct.solve(direct.DirectInputs(tris, ids, count, sun.direction),
                                  direct.DirectParams(samples_per_leaf=samples, seed=seed),
                                  progress=on_progress))
    res = parts[0] if len(parts) == 1 else _joined(parts)  # (a lone world has leaves: bake_world)
    log.info("direct: %d shadow rays per leaf over %s leaves, %.2f s", samples, f"{n:,}", res.seconds)
    return res


#: Shadow rays per instance for a forest's instance means: a power of two in [INSTANCE_MIN, INSTANCE_MAX], the most
#: within INSTANCE_RAY_BUDGET over all instances. The instance mean's sampling error is that of independent points,
#: ~K^-1/2 (a 4 x 4 stand of tree_small: 3.5 % relative RMS over instances at 1024, 1.7 % at 4096, 0.6-0.9 % at
#: 16384, unbiased against the copied world's per-leaf rays), so 4096 up to 16k instances.
INSTANCE_MIN, INSTANCE_MAX, INSTANCE_RAY_BUDGET = 256, 4096, 1 << 26


def instance_samples(instances: int) -> int:
    """Shadow rays per instance of :func:`instance_direct` (:data:`INSTANCE_RAY_BUDGET`)."""
    return within_budget(instances, INSTANCE_MIN, INSTANCE_MAX, INSTANCE_RAY_BUDGET)


def instance_direct(scene: Scene, sun: Sun, progress: Progress, *, seed: int = 0) -> direct.InstanceDirect:
    """Each instance's mean E_direct, with shadow rays through every placed instance (geometry.instanced: one
    ray scene per prototype, nothing copied)."""
    from foliage_tools.geometry.instanced import InstancedRayScene
    from foliage_tools.pipeline.world import placed_prototypes

    n = len(scene.instances)
    k = instance_samples(n)
    tris, leaves, transforms, proto = placed_prototypes(scene)
    rays = InstancedRayScene(tris, transforms, proto)
    progress.step(f"direct sunlight of every instance: {k} shadow rays each through {n:,} placed instances", total=n)
    done = [0]

    def advance(d: int, _total: int) -> None:
        progress.advance(d - done[0])
        done[0] = d

    return direct.solve_instances(rays, leaves, sun.direction, samples=k, seed=seed, progress=advance)

"""``foliage reference``: Monte Carlo ground truth per leaf through the actual geometry (DESIGN.md section 3).

Per-leaf primvars are per prototype: for a prototype with several instances
they hold the mean over its instances (``foliage bench`` compares every
instance's own values). Each instance's own means are written as
``foliage:ref:instanceDirect`` / ``:instanceScattered`` (pipeline.instances).

A forest the bakes trace as its lone trees (more than
``world.WORLD_MAX_TRIANGLES`` placed triangles) is traced through its placed
prototypes, one ray scene each (geometry.instanced), so its memory grows with
the prototypes, not the instances; its tallies are then each prototype leaf
pooled over its instances (power over summed area) and each instance's means.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from foliage_tools import __version__
from foliage_tools.errors import FindingsError, UsageError
from foliage_tools.geometry.sun import Sun
from foliage_tools.lighting import reference
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.leafdata import baked_sun_attribute, leaf_primvar_edits, native_instance_warning
from foliage_tools.pipeline.report import Progress, Report
from foliage_tools.pipeline.stats import ReferenceStats, sun_stats
from foliage_tools.pipeline.stage import bake_layer
from foliage_tools.pipeline.instances import bake_instance_edits, instance_edits
from foliage_tools.pipeline.world import (WORLD_MAX_TRIANGLES, World, assemble, placed_prototypes, pooled_leaf_offsets,
                                          prototype_means, traced_alone, world_triangles)
from foliage_tools.scene.model import Scene
from foliage_tools.scene.write import AttributeEdit, LayerEdits

log = logging.getLogger(__name__)


#: Per-leaf noise of the reference's E_scattered (relative RMS between two half-runs, scaled to the
#: whole run) above which the leaves' values are mostly noise: the run warns, never silently
#: under-sampled (DESIGN.md section 4). On the example tree (1500 leaves) 20k paths give 0.87, the
#: default 1M paths 0.25.
NOISE_WARN = 0.5

#: The noise the warning's suggested --paths aim at. The noise falls at best as 1/sqrt(paths); from
#: a very noisy run it falls slower (many leaves were never hit), so the suggestion is a lower bound.
NOISE_TARGET = 0.2


def noise_warnings(paths: int, noise_rel: float, flag: str = "--paths") -> list[str]:
    """A warning when the reference's per-leaf E_scattered noise exceeds :data:`NOISE_WARN`, with the paths that would fix it."""
    if not (noise_rel > NOISE_WARN):
        return []
    need = int(math.ceil(paths * (noise_rel / NOISE_TARGET) ** 2 / 1e5) * 1e5)
    return [
        f"the reference is under-sampled: its per-leaf E_scattered noise is {noise_rel:.2f} (relative RMS between two "
        f"half-runs), so leaf by leaf it is mostly noise. Raise {flag}: the noise falls at best as 1/sqrt(paths), so "
        f"reaching {NOISE_TARGET} takes at least {need:,}."
    ]


#: Sun paths per leaf for a per-leaf E_scattered noise near :data:`NOISE_TARGET` on the example tree
#: (1M paths over 1500 leaves give 0.25; the noise falls as 1/sqrt(paths)).
PATHS_PER_LEAF = 1000


#: A run in which no sun path was scattered onto a leaf reports E_scattered = 0 when that zero is resolved: when the
#: rule of three (no event in n trials: its rate is below 3/n at 95 % confidence; Hanley and Lippman-Hand 1983) bounds
#: the scattered light below this share of the direct light on the leaves. 1 %: below the reference's default
#: per-leaf noise target of a bake (2 %) and every method's measured error, so the zero is as good as any value it
#: would have written.
ZERO_SCATTERED_BOUND = 0.01


def zero_scattered_bound(res: reference.ReferenceResult, optics: LeafOptics) -> float | None:
    """When no sun path was scattered onto a leaf although light can scatter: the 95 % upper bound of the scattered
    light on the leaves as a share of the direct light on them (None otherwise; inf when no path reached a leaf).

    No path of N was scattered onto a leaf, so the share of paths that would be is below 3/N (the rule of three);
    D of them reached a leaf directly, and a scattering keeps at most a path's weight, so the scattered light is
    below about 3/D of the direct light. ``hits`` counts arrivals, all of them direct here.
    """
    can_scatter = bool(np.any(optics.albedo > 0) or np.any(optics.wood_reflectance > 0))
    if not can_scatter or np.any(res.e_scattered > 0) or not math.isfinite(float(res.noise_rel)):
        return None
    direct = int(np.asarray(res.hits).sum())
    return 3.0 / direct if direct else math.inf


def zero_scattered_note(bound: float, paths: int) -> str:
    """What a report says of a resolved zero (:func:`zero_scattered_bound` at or below :data:`ZERO_SCATTERED_BOUND`)."""
    return (f"no sun path of {paths:,} was scattered onto a leaf, so E_scattered is written as 0: at 95 % confidence "
            f"the scattered light on the leaves is below {bound:.2g} of the direct light (no such hit in {paths:,} "
            "paths). Leaves that cannot see each other (a single flat leaf, leaves all in one plane) have exactly 0.")


def unmeasured(res: reference.ReferenceResult, optics: LeafOptics, flag: str = "--paths") -> str | None:
    """Why the reference's E_scattered cannot be used (None when it can).

    The two-halves estimate is 0/0 when no sun path was scattered onto a leaf
    (E_scattered is zero everywhere): it then reads 0, which would pass any
    noise target although the run may hold no information (DESIGN.md section
    4: never silently under-sampled). That zero is a result only when it is
    resolved (:func:`zero_scattered_bound` at most :data:`ZERO_SCATTERED_BOUND`);
    with black leaves and wood nothing can scatter, and zero is exact.
    """
    paths = int(res.paths)
    if not math.isfinite(float(res.noise_rel)):
        return f"no sun path was traced, so E_scattered was not measured. Raise {flag} (at least 100,000)."
    bound = zero_scattered_bound(res, optics)
    if bound is None or bound <= ZERO_SCATTERED_BOUND:
        return None
    if math.isinf(bound):
        need = max(100_000, 10 * paths)
        return (f"none of the {paths:,} sun paths reached a leaf, directly or scattered, so E_scattered is not "
                f"measured. Raise {flag}: at least {need:,}.")
    # the bound falls as 1/paths (3/D, with D the direct arrivals in proportion to the paths); never advise fewer
    # paths than ran
    need = max(2 * paths, int(math.ceil(paths * bound / ZERO_SCATTERED_BOUND / 1e5) * 1e5))
    return (f"none of the {paths:,} sun paths was scattered onto a leaf: that bounds the scattered light only below "
            f"{bound:.2g} of the direct light (95 % confidence), too loose to call it zero, so E_scattered cannot be "
            f"measured from this run. Raise {flag} to at least "
            f"{need:,}: a zero is reported once the bound is below {ZERO_SCATTERED_BOUND:g}.")


def unlit_warnings(res: reference.ReferenceResult, flag: str = "--paths") -> list[str]:
    """A warning when many leaves were reached by no sun path at all (their values are zero for lack of samples)."""
    hits = np.asarray(res.hits)
    none = int(np.count_nonzero(hits == 0))
    if hits.size and none > 0.1 * hits.size:
        return [f"{none:,} of {hits.size:,} leaves were reached by no sun path: their E_direct and E_scattered are zero "
                f"for lack of samples, not of light. Raise {flag} (about {PATHS_PER_LEAF:,} per leaf)."]
    return []


@dataclass(frozen=True)
class ReferenceParams:
    """What ``foliage reference`` traces."""

    optics: LeafOptics
    """Leaf and wood optics (``--leaf-optics``, ``--wood-reflectance``)."""
    sun: tuple[float, float] | None = None
    """``--sun`` azimuth, elevation in degrees; None: the stage's sun or the default."""
    paths: int = 1_000_000
    """Sun photon paths (``--paths``); with ``noise`` the most that will be traced."""
    noise: float | None = None
    """``--noise``: stop once the per-leaf E_scattered noise (relative RMS, two halves) is at or below it."""
    seed: int = 0
    """Seed: results are bitwise reproducible for a seed, whatever the number of workers."""
    workers: int | None = None
    """Threads; None: all cores."""

    def __post_init__(self) -> None:
        if self.paths < 2:
            raise UsageError(f"--paths must be at least 2 (the noise estimate needs two halves), got {self.paths}.")
        if self.seed < 0:
            raise UsageError(f"--seed must be >= 0, got {self.seed}.")
        if self.noise is not None and not (0 < self.noise < 1):
            raise UsageError(f"--noise must be between 0 and 1 (a relative RMS, e.g. 0.01 for 1 %), got {self.noise}.")


@dataclass(frozen=True)
class ReferenceBake:
    world: World | None
    """Every instance copied, its leaves the result's; None when the forest was traced through its placements."""
    result: reference.ReferenceResult
    pooled: np.ndarray | None = None
    """Traced through placements: (P + 1,) first result leaf of each prototype (its leaves pooled over its
    instances; ``result.instance_direct`` / ``instance_scattered`` hold each instance's means)."""

    def prototype_values(self, per_leaf: np.ndarray, counts: list[int]) -> list[np.ndarray]:
        """Per prototype, its leaves' values: the mean over its instances (pooled, or :func:`prototype_means`)."""
        if self.pooled is None:
            assert self.world is not None  # bake_reference copies the world exactly when it does not pool
            return prototype_means(self.world, per_leaf, len(counts), counts)
        return [per_leaf[self.pooled[p]:self.pooled[p + 1]] for p in range(len(counts))]


class _ProgressAdapter:
    """reference.solve's ``progress(done, total)`` -> a progress bar that learns its total on the first call."""

    def __init__(self, progress: Progress, message: str) -> None:
        self.progress = progress
        self.message = message
        self.done: int | None = None

    def __call__(self, done: int, total: int) -> None:
        if self.done is None:
            self.progress.step(self.message, total=total)
            self.done = 0
        self.progress.advance(done - self.done)
        self.done = done


def check_world_fits(scene: Scene) -> None:
    """Refuse, before any work, a scene whose every-instance ray scene would not fit in the memory free now."""
    from foliage_tools.pipeline.plan import available_memory, ray_scene_bytes

    tris = world_triangles(scene)
    need = ray_scene_bytes(tris)
    free = available_memory()
    if need > free:
        raise UsageError(
            f"the Monte Carlo reference traces every instance: {len(scene.instances):,} instances place {tris:,} "
            f"triangles, ~{need / 1e9:.1f} GB, more than the {free / 1e9:.1f} GB free now (its ray scene copies each "
            f"instance, so that every leaf of every instance is tallied; a forest above "
            f"{WORLD_MAX_TRIANGLES:,} placed triangles is traced through its placements instead, pooled per "
            f"prototype leaf). Trace a smaller part of the forest (a stand around the trees you check) or free "
            f"memory; `foliage plan` shows the figure.")


def placed_inputs(scene: Scene, sun: Sun, optics: LeafOptics) -> tuple[reference.ReferenceInputs, np.ndarray]:
    """The reference's inputs for a forest traced through its placed prototypes, nothing copied: each prototype
    leaf pooled over its instances (and each instance's means tallied apart). Also the prototypes' first leaves."""
    tris, leaves, transforms, proto = placed_prototypes(scene)
    pooled = pooled_leaf_offsets(scene)
    placements = reference.Placements(tris, leaves, transforms, proto, pooled[proto])
    area = np.zeros(int(pooled[-1]))
    area[:placements.n_result_leaves] = placements.areas[0]
    inputs = reference.ReferenceInputs(
        triangles=np.zeros((0, 3, 3)), leaf_of_triangle=np.zeros(0, np.int64),
        leaf_area=np.where(area > 0, area, 1.0),  # leaves of a prototype no instance places: never tallied
        optics=optics, sun_direction=sun.direction, up=scene.up, placements=placements)
    return inputs, pooled


def bake_reference(scene: Scene, sun: Sun, params: ReferenceParams, progress: Progress, *,
                   flat: bool = False) -> ReferenceBake:
    """Trace the reference through the scene.

    A forest the bakes trace as lone trees (:func:`~foliage_tools.pipeline.world.traced_alone`) is traced through
    its placed prototypes (:func:`placed_inputs`): memory grows with the prototypes, not the instances. Otherwise,
    or with ``flat`` (``bench``, which compares every leaf of every instance), every instance is copied into one
    ray scene, refused up front when that would not fit (:func:`check_world_fits`).
    """
    # Sun only: every per-leaf output (the reference's primvars, every method's E_direct / E_scattered)
    # is the sun's light, so sky photons would cost time and change nothing written.
    rp = reference.ReferenceParams(paths=params.paths, seed=params.seed, workers=params.workers, noise_target=params.noise)
    goal = f" (until the noise is {params.noise:g})" if params.noise else ""
    if not flat and traced_alone(scene):
        inputs, pooled = placed_inputs(scene, sun, params.optics)
        world = None
        assert inputs.placements is not None  # placed_inputs gives placements
        where = (f"{len(scene.instances):,} placed instances of {len(scene.prototypes)} prototype(s) "
                 f"({sum(len(t) for t in inputs.placements.triangles):,} triangles, not copied)")
    else:
        check_world_fits(scene)
        world = assemble(scene)
        pooled = None
        inputs = reference.ReferenceInputs(
            triangles=world.triangles,
            leaf_of_triangle=world.leaf_of_triangle,
            leaf_area=world.leaf_area,
            optics=params.optics,
            sun_direction=sun.direction,
            up=scene.up,
        )
        where = f"{len(world.triangles):,} triangles"
    message = f"tracing up to {params.paths:,} sun paths{goal} through {where}"
    result = reference.solve(inputs, rp, progress=_ProgressAdapter(progress, message))
    log.info("reference: %s paths, per-leaf noise %.3f (total %.3f), %.1f s", f"{result.paths:,}", result.noise_rel,
             result.noise_rel_total, result.seconds)
    return ReferenceBake(world, result, pooled)


def reference_layer(scene: Scene, sun: Sun, report: Report, progress: Progress, *, path: Path, params: ReferenceParams,
                    traced: ReferenceBake | None) -> tuple[LayerEdits, ReferenceStats]:
    """``foliage reference``'s trace and layer (``pipeline.stage.bake_layer`` reads before and writes after)."""
    bake = traced or bake_reference(scene, sun, params, progress)
    res = bake.result
    counts = [p.leaves.count for p in scene.prototypes]
    direct = bake.prototype_values(res.e_direct, counts)
    scattered = bake.prototype_values(res.e_scattered, counts)
    edits = LayerEdits()
    for i, proto in enumerate(scene.prototypes):
        if not proto.leaves.count:
            continue
        if not proto.editable:
            report.warnings.append(native_instance_warning(proto, "reference primvars"))
        edits.primvars += leaf_primvar_edits(proto, "foliage:ref:direct", direct[i], type="color3f")
        edits.primvars += leaf_primvar_edits(proto, "foliage:ref:scattered", scattered[i], type="color3f")
        edits.attributes += baked_sun_attribute(scene, i, "ref", sun.direction)
        if proto.editable:  # provenance: what the per-leaf values were traced with, and how noisy they are
            edits.attributes.append(AttributeEdit(prim=proto.path, api=None, values={
                "foliage:ref:paths": (int(res.paths), "Int64"),
                "foliage:ref:seed": (int(params.seed), "Int64"),
                "foliage:ref:noiseRel": (float(res.noise_rel), "Float"),
                "foliage:ref:version": (__version__, "String"),
            }))
    why = unmeasured(res, params.optics)
    if why:  # DESIGN.md section 3: a bake that failed its own accuracy check; a reference of zeros must not be used
        raise FindingsError(f"accuracy check failed: @{path}@: {why} Nothing was written.")
    bound = zero_scattered_bound(res, params.optics)
    if bound is not None:
        report.warnings.append(zero_scattered_note(bound, int(res.paths)))
    if res.truncated:
        report.warnings.append(f"{res.truncated} path(s) were abandoned after {reference.ReferenceParams().max_events} events.")
    report.warnings.extend(noise_warnings(int(res.paths), float(res.noise_rel)))
    report.warnings.extend(unlit_warnings(res))
    if params.noise is not None and res.noise_rel > params.noise:  # asked for, not reached: the accuracy check failed
        report.findings.append(
            f"the reference reached --paths {params.paths:,} at E_scattered noise {res.noise_rel:.4f}, above --noise "
            f"{params.noise:g}. The layer was written with that noise in foliage:ref:noiseRel; raise --paths (the noise "
            f"falls as 1/sqrt(paths): about {max(1, int(math.ceil(res.paths * (res.noise_rel / params.noise) ** 2 / 1e6))):,}M "
            "would do)."
        )
    if bake.world is None:  # traced through placements: each instance's own tallies
        # reference.solve tallies them whenever it traces placements
        assert res.instance_direct is not None and res.instance_scattered is not None
        pv, at = instance_edits(scene, "ref", {"instanceDirect": res.instance_direct,
                                               "instanceScattered": res.instance_scattered})
    else:  # where each instance stands
        pv, at = bake_instance_edits(scene, "ref", bake.world, res.e_direct, res.e_scattered)
    edits.primvars += pv
    edits.attributes += at
    stats: ReferenceStats = {
        "paths": int(res.paths),
        "sky_paths": int(res.sky_paths),
        "seed": params.seed,
        "workers": int(res.workers),
        "noise_rel": float(res.noise_rel),
        "noise_rel_total": float(res.noise_rel_total),
        "noise_rel_direct": float(res.noise_rel_direct),
        "noise_target": params.noise,
        "leaves": sum(counts[i.prototype] for i in scene.instances),
        # each instance's own tallies: only a forest traced through its placements has them
        "noise_rel_instance": float(res.noise_rel_instance) if math.isfinite(res.noise_rel_instance) else None,
        "sun": sun_stats(sun),
        "optics": params.optics.as_dict(),
        "energy": {
            "incident": res.incident.tolist(),
            "absorbed_leaves": res.absorbed.sum(axis=0).tolist(),
            "absorbed_wood": np.asarray(res.absorbed_wood).tolist(),
            "escaped": res.escaped.tolist(),
        },
        "e_direct_mean": res.e_direct.mean(axis=0).tolist(),
        "e_scattered_mean": res.e_scattered.mean(axis=0).tolist(),
        "seconds_tracing": float(res.seconds),
    }
    return edits, stats


def run_reference(path: Path, out: Path, params: ReferenceParams, *, progress: Progress | None = None,
                  traced: ReferenceBake | None = None) -> Report[ReferenceStats]:
    """``foliage reference``. ``traced``: this scene's reference with ``params`` already traced (``foliage bake
    --with-reference`` shares the bench's trace)."""
    return bake_layer("reference", path, out, params.sun, progress,
                      partial(reference_layer, path=path, params=params, traced=traced))

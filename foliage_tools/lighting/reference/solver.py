""":func:`solve`, the Monte Carlo reference's entry point.

The paths are split into fixed batches, each seeded from one ``np.random.SeedSequence``, run on a thread pool and
reduced in batch order; two halves of the batches give the noise estimate, which can stop the run at a target.
Sections "Determinism and threads" and "Noise estimate and stopping at a target" of the package docstring
(:mod:`foliage_tools.lighting.reference`) say why and how.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import cast

import numpy as np

from foliage_tools.geometry.instanced import InstancedRayScene
from foliage_tools.geometry.rays import PeriodicRayScene
from foliage_tools.lighting.reference.problem import ReferenceInputs, ReferenceParams, ReferenceResult
from foliage_tools.lighting.reference.sources import (
    _geometry,
    _PlacedSunSource,
    _SkySource,
    _SunSource,
    _SurfaceSunSource,
)
from foliage_tools.lighting.reference.tracer import _SKY_DIRECT, _SKY_SCATTERED, _SUN_DIRECT, _SUN_SCATTERED, _Tally, _Tracer


def _batches(paths: int, batch_size: int) -> list[int]:
    """Batch sizes: at least 2 batches (two halves) when paths > 0, as even as possible."""
    if paths == 0:
        return []
    n = max(2, -(-paths // batch_size))
    return [paths // n + (1 if i < paths % n else 0) for i in range(n)]



def _noise(half_a: np.ndarray, half_b: np.ndarray, n_a: int, n_b: int, area: np.ndarray) -> float:
    """Relative RMS noise of the full run from two halves (see the package docstring)."""
    n = n_a + n_b
    full = (half_a + half_b) / area[:, None]
    a = half_a * (n / n_a) / area[:, None]
    b = half_b * (n / n_b) / area[:, None]
    den = float(np.linalg.norm(full))
    if den == 0.0:
        return 0.0
    return float(np.linalg.norm(a - b)) / (math.sqrt(n / n_a + n / n_b) * den)


def solve(
    inputs: ReferenceInputs,
    params: ReferenceParams = ReferenceParams(),  # noqa: B008  (frozen: one shared default is safe)
    *,
    progress: Callable[[int, int], None] | None = None,
) -> ReferenceResult:
    """Trace sun (and sky) photons through the scene and tally per-leaf irradiance.

    Parameters
    ----------
    inputs : ReferenceInputs
        Triangles, leaf ids and areas, optics, sun, sky.
    params : ReferenceParams
        Path counts, seed, threads, batch size.
    progress : callable, optional
        ``progress(done, total)`` in paths (sun + sky), called from the calling
        thread after each batch, in batch order.

    Returns
    -------
    ReferenceResult
        Tallies as defined in the package docstring, with wall time and the
        two-halves noise estimate.
    """
    start = time.perf_counter()
    if not isinstance(inputs, ReferenceInputs):
        raise TypeError(f"inputs must be a ReferenceInputs, got {type(inputs).__name__}")
    if not isinstance(params, ReferenceParams):
        raise TypeError(f"params must be a ReferenceParams, got {type(params).__name__}")
    has_sky = bool(np.any(inputs.sky_radiance > 0))
    sky_paths = (params.paths if has_sky else 0) if params.sky_paths is None else int(params.sky_paths)
    if has_sky and sky_paths < 2:
        raise ValueError(
            f"sky_radiance is {tuple(inputs.sky_radiance)} but sky_paths = {sky_paths}: give sky_paths >= 2 "
            "or a zero sky radiance"
        )
    if params.paths + sky_paths == 0:
        raise ValueError("nothing to trace: paths and sky_paths are both 0")
    workers = int(params.workers) if params.workers is not None else max(1, os.cpu_count() or 1)
    tracer = _Tracer(inputs, params.max_events, float(params.survival_weight), int(params.split))
    z_top = None
    if tracer.periodic:
        assert isinstance(tracer.scene, PeriodicRayScene)  # _Tracer builds one for a periodic input
        z_top = tracer.scene.z_range[1]
    geo = _geometry(inputs, z_top, tracer.scene.bounds if inputs.placements is not None else None)
    if params.noise_target is None:
        sun_sizes = _batches(params.paths, params.batch_size)
    else:  # whole batches, so a run stopped after n of them equals a run of n x batch_size paths
        n_full, rest = divmod(params.paths, params.batch_size)
        sun_sizes = [params.batch_size] * n_full + ([rest] if rest else [])
        if len(sun_sizes) < 2:
            sun_sizes = _batches(params.paths, params.batch_size)
    sky_sizes = _batches(sky_paths, params.batch_size) if has_sky else []
    sun: _SunSource | _PlacedSunSource | _SurfaceSunSource = _SunSource(geo, inputs.sun_direction, params.paths)
    if params.sun_sampling == "surface" and inputs.placements is not None:
        assert isinstance(tracer.scene, InstancedRayScene)  # _Tracer's scene for placements
        sun = _PlacedSunSource(tracer.scene, inputs.placements, inputs.sun_direction, sun.power)
    elif params.sun_sampling == "surface":
        sun = _SurfaceSunSource(tracer.scene, inputs.triangles, inputs.sun_direction, sun.power)
    sky = _SkySource(geo, inputs.up, inputs.sky_radiance, sky_paths) if has_sky else None
    root_sun, root_sky = np.random.SeedSequence(params.seed).spawn(2)
    # sky batches first, so that a run stopped at its noise target has traced all of them
    tasks: list[tuple[_SunSource | _PlacedSunSource | _SurfaceSunSource | _SkySource | None, np.random.SeedSequence, int, bool, int]]
    tasks = [(sky, s, size, True, i) for i, (s, size) in enumerate(zip(root_sky.spawn(len(sky_sizes)), sky_sizes))]
    tasks += [(sun, s, size, False, i) for i, (s, size) in enumerate(zip(root_sun.spawn(len(sun_sizes)), sun_sizes))]
    total_paths = params.paths + (sky_paths if has_sky else 0)

    def run(task) -> _Tally:
        source, seq, size, is_sky, _ = task
        return tracer.run(source, np.random.default_rng(seq), size, is_sky)

    n_leaves = inputs.n_leaves
    n_inst = tracer.n_instances
    # per half (even / odd batch index): sun tallies in units of power x paths (divided by the
    # sun paths traced at the end, which a noise target decides), sky tallies normalised
    sun_h = [_Tally.zeros(n_leaves, n_inst), _Tally.zeros(n_leaves, n_inst)]
    sky_h = [_Tally.zeros(n_leaves, n_inst), _Tally.zeros(n_leaves, n_inst)]
    half_paths = [0, 0]
    done = 0
    area = inputs.leaf_area
    target = params.noise_target
    sun_done = 0

    def sun_noise(*categories: int) -> float:
        """The two-halves noise of the sun tallies ``categories`` summed (package docstring)."""
        n = half_paths[0] + half_paths[1]
        a, b = (sum(h.incidence.reshape(n_leaves, 4, 3)[:, c] for c in categories) / n for h in sun_h)
        # sums of arrays (every call names a category), not sum()'s int start
        return _noise(cast(np.ndarray, a), cast(np.ndarray, b), half_paths[0], half_paths[1], area)

    pool = ThreadPoolExecutor(max_workers=workers)
    pending: deque = deque()
    queue = iter(tasks)
    try:
        # A bounded window of batches in flight, consumed in submission order:
        # the reduction order is fixed (determinism) and an exception (or
        # Ctrl-C in the progress callback) cancels what has not started.
        for task in itertools.islice(queue, 2 * workers):
            pending.append((task, pool.submit(run, task)))
        while pending:
            task, future = pending.popleft()
            tally = future.result()
            for nxt in itertools.islice(queue, 1):
                pending.append((nxt, pool.submit(run, nxt)))
            _, _, size, is_sky, index = task
            if is_sky:
                sky_h[index % 2].add(tally)
            else:
                sun_h[index % 2].add(tally)
                half_paths[index % 2] += size
                sun_done += 1
            done += size
            if progress is not None:
                progress(done, total_paths)
            if (target is not None and not is_sky and sun_done >= 4 and sun_done % 2 == 0
                    and sun_done < len(sun_sizes) and sun_noise(_SUN_SCATTERED) <= target):
                break  # the sky batches ran first: what is left is sun batches, not needed
    finally:
        for _, future in pending:
            future.cancel()
        pool.shutdown(wait=True)
    sun_paths = half_paths[0] + half_paths[1]
    full = _Tally.zeros(n_leaves, n_inst)
    if sun_paths:
        full.add(sun_h[0].scaled(1.0 / sun_paths))
        full.add(sun_h[1].scaled(1.0 / sun_paths))
    full.add(sky_h[0])
    full.add(sky_h[1])
    inc = full.incidence.reshape(n_leaves, 4, 3) / area[:, None, None]
    if sun_paths:
        noise = sun_noise(_SUN_SCATTERED)
        noise_total = sun_noise(_SUN_DIRECT, _SUN_SCATTERED)
        noise_direct = sun_noise(_SUN_DIRECT)
    else:
        noise = noise_total = noise_direct = math.nan
    incident = np.full(3, sun.power if sun_paths else 0.0)
    escaped = full.escaped.copy()
    instance_direct = instance_scattered = None
    noise_instance = math.nan
    if inputs.placements is not None:
        _, inst_area = inputs.placements.areas
        safe = np.where(inst_area > 0, inst_area, 1.0)[:, None]
        per = full.instances.reshape(n_inst, 4, 3)
        instance_direct = np.where(inst_area[:, None] > 0, per[:, _SUN_DIRECT] / safe, 0.0)
        instance_scattered = np.where(inst_area[:, None] > 0, per[:, _SUN_SCATTERED] / safe, 0.0)
        if sun_paths:
            n = half_paths[0] + half_paths[1]
            a, b = (h.instances.reshape(n_inst, 4, 3)[:, _SUN_DIRECT] + h.instances.reshape(n_inst, 4, 3)[:, _SUN_SCATTERED]
                    for h in sun_h)
            noise_instance = _noise(a / n, b / n, half_paths[0], half_paths[1], safe[:, 0])
    if isinstance(sun, (_SurfaceSunSource, _PlacedSunSource)):
        # the beam's power that reaches no surface leaves the scene: incident - intercepted
        escaped += incident - full.intercepted
        intercepted = full.intercepted
    else:
        intercepted = np.full(3, math.nan)
    if sky is not None:
        incident = incident + sky.power

    def frozen(a):
        a = np.ascontiguousarray(a)
        a.flags.writeable = False
        return a

    return ReferenceResult(
        e_direct=frozen(inc[:, _SUN_DIRECT]),
        e_scattered=frozen(inc[:, _SUN_SCATTERED]),
        e_sky=frozen(inc[:, _SKY_DIRECT]),
        e_sky_scattered=frozen(inc[:, _SKY_SCATTERED]),
        absorbed=frozen(full.absorbed),
        absorbed_wood=frozen(full.absorbed_wood),
        escaped=frozen(escaped),
        incident=frozen(incident),
        hits=frozen(full.hits),
        paths=int(sun_paths),
        sky_paths=int(sky_paths if has_sky else 0),
        seconds=time.perf_counter() - start,
        noise_rel=noise,
        noise_rel_total=noise_total,
        noise_rel_direct=noise_direct,
        intercepted=frozen(intercepted),
        seed=int(params.seed),
        workers=workers,
        truncated=int(full.truncated),
        instance_direct=None if instance_direct is None else frozen(instance_direct),
        instance_scattered=None if instance_scattered is None else frozen(instance_scattered),
        noise_rel_instance=float(noise_instance),
    )

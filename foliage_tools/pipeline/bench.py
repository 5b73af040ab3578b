"""``foliage bench``: every available method against the Monte Carlo reference, speed against error."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from foliage_tools.bench.metrics import binned_rms, rel_rms
from foliage_tools.bench.registry import BenchContext, families, methods, selects
from foliage_tools.errors import UsageError
from foliage_tools.geometry.rays import RayScene, count_crossings
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.forest import forest_light
from foliage_tools.pipeline.instances import from_prototypes, instance_means
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.reference import ReferenceBake, ReferenceParams, bake_reference, noise_warnings, unlit_warnings, unmeasured
from foliage_tools.pipeline.report import Progress, Report, Silent
from foliage_tools.pipeline.stats import BenchRow, BenchStats, sun_stats
from foliage_tools.pipeline.stage import begin_bake
from foliage_tools.pipeline.world import World


@dataclass(frozen=True)
class BenchParams:
    optics: LeafOptics
    sun: tuple[float, float] | None = None
    methods: tuple[str, ...] | None = None
    """Names to run (None: all available)."""
    paths: int = 64_000_000
    """Most reference sun paths (it stops earlier at ``noise``)."""
    noise: float | None = 0.02
    """Reference per-leaf E_scattered noise at which it stops (None: trace ``paths``)."""
    seed: int = 0
    paths_flag: str = "--paths"
    """The option that sets ``paths``, named in the warnings (``bake`` calls it --reference-paths)."""
    noise_flag: str = "--noise"
    direct_samples: int | None = None
    """Shadow rays per leaf of the exact E_direct (``--direct rays``); None: as the bakes' ``auto``."""


def depth_thickness(world: World, sun_dir: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per leaf, crossings toward the sun (n+) and total (n+ + n−) through the geometry (shinya2013 eq. (29))."""
    own = np.arange(len(world.leaf_area))
    counts = count_crossings(
        RayScene(world.triangles), world.leaf_centers, [sun_dir, -np.asarray(sun_dir)],
        skip_ids=own, id_of_triangle=world.leaf_of_triangle,
    )
    return counts[:, 0].astype(float), counts.sum(axis=1).astype(float)


def run_bench(path: Path, params: BenchParams, *, progress: Progress | None = None,
              traced: ReferenceBake | None = None) -> Report[BenchStats]:
    """``foliage bench``. ``traced``: the reference of ``params``' paths, noise and seed already traced with every
    instance copied (``bake_reference(..., flat=True)``; ``foliage bake --with-reference`` traces it once for the
    bench and the reference layer); its seconds are then the trace's own."""
    progress = progress or Silent()
    report, scene, sun = begin_bake("bench", path, None, params.sun, progress)
    all_methods = methods()
    names = [m.name for m in all_methods]

    if params.methods is not None:
        if not params.methods:
            raise UsageError("--methods is empty; give method names or families (`foliage bench --help` lists them), "
                             "or leave the option out to run every method.")
        unknown = [n for n in params.methods if not selects(n, names)]
        if unknown:
            raise UsageError(f"--methods: unknown method(s) {', '.join(unknown)}; known: {', '.join(names)} "
                             f"(or a family, NAME* or a family name no method has: {', '.join(families(names))}).")
    chosen = {n for r in params.methods or () for n in selects(r, names)}
    selected = [m for m in all_methods if params.methods is None or m.name in chosen]

    t0 = time.perf_counter()
    ref = traced or bake_reference(scene, sun, ReferenceParams(optics=params.optics, paths=params.paths, seed=params.seed,
                                                               noise=params.noise), progress, flat=True)  # every leaf compared
    ref_seconds = ref.result.seconds if traced is not None else time.perf_counter() - t0
    world, res = ref.world, ref.result
    assert world is not None  # flat=True copies every instance
    n = int(world.offsets[-1])
    progress.step("depth and thickness of every leaf toward the sun")
    depth, thickness = depth_thickness(world, sun.direction)
    ref_total = res.e_direct + res.e_scattered
    # the exact direct light every bake writes by default (--direct rays), once for all methods
    t0 = time.perf_counter()
    exact = bake_direct(scene, sun, DirectChoice(samples=params.direct_samples), progress, world=world)
    direct_seconds = time.perf_counter() - t0
    exact_direct = np.repeat(exact.result.e_direct[:, None], 3, axis=1)  # per global leaf
    # a forest: each instance's mean light against the reference's, the volume methods' scattered light scaled by
    # the forest lattice as the bakes write it (pipeline.instances, pipeline.forest)
    forest = forest_light(scene, sun, params.optics, progress=progress)
    if forest is not None:
        ref_instances = instance_means(world, ref_total)
        direct_instances = instance_means(world, exact_direct)

    rows: list[BenchRow] = []
    progress.step(f"running {sum(m.available for m in selected)} method(s)", total=len(selected))
    for m in selected:
        if not m.available:
            rows.append({"name": m.name, "available": False, "description": m.description, "seconds": None,
                         "rel_rms_scattered": None, "rel_rms_total": None, "binned_rms": None,
                         "binned_rms_total": None, "rel_rms_total_volume": None})
            progress.advance()
            continue
        ctx = BenchContext(scene=scene, sun=sun, optics=params.optics, warnings=report.warnings, direct=exact)
        t = time.perf_counter()
        assert m.run is not None  # m.available
        out = m.run(ctx)
        seconds_volume = time.perf_counter() - t
        scat = from_prototypes(world, out.e_scattered)
        if out.scattered_per_instance_leaf is not None:
            scat = np.asarray(out.scattered_per_instance_leaf, dtype=np.float64)
        own = from_prototypes(world, out.e_direct)
        errors: dict[str, float | None] = {
            "rel_rms_scattered": rel_rms(scat, res.e_scattered),
            # with the exact direct light (--direct rays, the default of every bake)
            "rel_rms_direct": rel_rms(exact_direct, res.e_direct),
            "rel_rms_total": rel_rms(exact_direct + scat, ref_total),
            "binned_rms": binned_rms(scat, res.e_scattered, depth, thickness),
            # shinya2013 Table 3 bins the irradiance of a mesh, i.e. the total
            "binned_rms_total": binned_rms(exact_direct + scat, ref_total, depth, thickness),
            # with the method's own volume estimate of the direct light (--direct volume, the papers')
            "rel_rms_direct_volume": rel_rms(own, res.e_direct),
            "rel_rms_total_volume": rel_rms(own + scat, ref_total),
            "binned_rms_total_volume": binned_rms(own + scat, ref_total, depth, thickness),
        }
        if forest is not None:
            inst_scat = instance_means(world, scat)
            if out.scattered_per_instance_leaf is None:
                inst_scat = inst_scat * forest.factors
            # over instances: each instance's mean total (exact direct + scattered) against the reference's
            errors["instance_rel_rms_total"] = rel_rms(direct_instances + inst_scat, ref_instances)
        seconds = seconds_volume + direct_seconds
        for key, value in errors.items():
            assert value is not None  # every value is a measured float until this loop nulls it
            if not np.isfinite(value):  # the reference is all zero there: a relative error is undefined
                report.warnings.append(f"{m.name}: {key} is undefined (the reference is zero everywhere); reported as null.")
                errors[key] = None
        # errors' keys are BenchRow's error fields (instance_rel_rms_total only for a forest)
        rows.append(cast(BenchRow, {"name": m.name, "available": True, "description": m.description, "seconds": seconds,
                                    "seconds_volume": seconds_volume, **errors, "stats": out.stats}))
        progress.advance()
    why = unmeasured(res, params.optics, params.paths_flag)
    if why:  # its noise reads 0 then: say so, never silently (the methods' errors against zeros are null above)
        report.warnings.append(f"the reference is not a measurement: {why}")
    report.warnings.extend(noise_warnings(int(res.paths), float(res.noise_rel), params.paths_flag))
    report.warnings.extend(unlit_warnings(res, params.paths_flag))
    if params.noise is not None and res.noise_rel > params.noise:
        report.warnings.append(f"the reference stopped at {params.paths_flag} {params.paths:,} with E_scattered noise "
                               f"{res.noise_rel:.4f}, above {params.noise_flag} {params.noise:g}; raise {params.paths_flag}.")
    # a method's measured error is about sqrt(true² + noise²): below twice the noise it is not resolved
    unresolved = [r["name"] for r in rows if r["available"] and r["rel_rms_scattered"] is not None
                  and r["rel_rms_scattered"] < 2.0 * float(res.noise_rel)]
    if unresolved:
        stopped_at_target = params.noise is not None and res.noise_rel <= params.noise
        fix = (f"Lower {params.noise_flag} (now {params.noise:g}): half the noise takes about 4x the paths."
               if stopped_at_target else
               f"Raise {params.paths_flag}: 4x the paths ({4 * int(res.paths):,}) at best halve the noise.")
        report.warnings.append(
            f"the E_scattered errors of {', '.join(unresolved)} are less than twice the reference's own noise "
            f"({res.noise_rel:.3f}; an exact method would score about that), so they are not resolved. {fix}"
        )
    stats: BenchStats = {
        "sun": sun_stats(sun),
        "optics": params.optics.as_dict(),
        "leaves": n,
        "reference": {
            "paths": int(res.paths), "sky_paths": int(res.sky_paths), "seed": params.seed, "seconds": ref_seconds,
            "noise_rel": float(res.noise_rel), "noise_rel_total": float(res.noise_rel_total),
            "noise_rel_direct": float(res.noise_rel_direct), "noise_target": params.noise,
        },
        "direct": {**exact.stats(), "seconds": direct_seconds, "rel_rms_direct": rel_rms(exact_direct, res.e_direct)},
        "instances": len(scene.instances),
        "forest": forest.stats() if forest is not None else None,
        "methods": rows,
        "binned_rms_definition": "sqrt(sum_b (<x>_b - <ref>_b)^2 / sum_b <ref>_b^2) over 8x8 quantile classes of "
                                 "(crossings toward the sun, total crossings) — shinya2013 eq. (30) read with the square outside; "
                                 "binned_rms on E_scattered, binned_rms_total on E_direct + E_scattered (the paper's Table 3)",
    }
    report.stats = stats
    return report.finish()

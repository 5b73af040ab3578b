"""The skeleton every single-layer bake fills in: check the output, read the scene, choose the sun, compute,
write the layer (and its grids) atomically.

A method is one module: its params, a function ``layer(scene, sun, report, progress) -> (LayerEdits, stats)``
that computes every leafy prototype (``Scene.leafy_prototypes``) and says what to write, and
``run_NAME = bake_layer("NAME", ...)``. ``run_lb``, ``run_spp``, ``run_smax`` and ``run_reference`` are built so;
``run_density`` (no sun) reads the scene itself and ends with :func:`write_stage`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from foliage_tools.errors import InputError, UsageError
from foliage_tools.geometry.sun import Sun, choose_sun, to_prototype_space
from foliage_tools.pipeline.density import require_leaves
from foliage_tools.pipeline.report import Progress, Report, S, Silent
from foliage_tools.scene.bakeable import sun_horizon_problem
from foliage_tools.scene.model import Scene
from foliage_tools.scene.read import read_scene
from foliage_tools.scene.write import LayerEdits, check_output_path, input_files, stage_metadata, write_layer

#: What a method computes from the scene and the sun: the layer's edits and its command's stats.
#: It appends warnings and failed accuracy checks to the report (``report.warnings``, ``report.findings``).
LayerBake = Callable[[Scene, Sun, Report[Any], Progress], tuple[LayerEdits, S]]


def bake_layer(command: str, path: Path, out: Path, sun_flag, progress: Progress | None,
               layer: LayerBake[S]) -> Report[S]:
    """``foliage COMMAND SCENE -o OUT``: read and check (:func:`begin_bake`), ``layer``, then :func:`write_stage`."""
    progress = progress or Silent()
    report, scene, sun = begin_bake(command, path, out, sun_flag, progress)
    edits, stats = layer(scene, sun, report, progress)
    return write_stage(report, path, out, edits, stats, progress)


def write_stage(report: Report[Any], path: Path, out: Path, edits: LayerEdits, stats: S, progress: Progress) -> Report[S]:
    """Write ``edits`` as a layer over ``path`` at ``out`` (all files or none: ``scene.write.write_layer``) and
    finish the report with the files written and ``stats``."""
    progress.step(f"writing {out}")
    report.outputs = [str(p) for p in write_layer(path, out, edits, input_stage_meta=stage_metadata(path))]
    report.stats = stats
    return report.finish()


def begin_bake(command: str, path: Path, out: Path | None, sun_flag, progress: Progress) -> tuple[Report[Any], Scene, Sun]:
    """A report, the scene (with leaves) and the sun; refuses a bad output, or an input mixing two runs, before any work."""
    report: Report[Any] = Report(command=command, inputs=[str(path)])
    if out is not None:
        check_output_path(path, out, writes_grids=command in ("lb", "spp"), warnings=report.warnings)
    require_consistent_input(path)
    progress.step(f"reading {path}")
    scene, warnings = read_scene(path)
    report.warnings.extend(warnings)
    require_leaves(scene, path)
    sun = choose_sun(scene.lights, scene.up_axis, sun_flag, report.warnings)
    require_sun_above_horizon(path, scene, sun)
    return report, scene, sun


def require_sun_above_horizon(path: Path, scene: Scene, sun: Sun) -> None:
    """Every bake lights leaves by a sun above the horizon: one at or below it (a --sun elevation <= 0, or a
    DistantLight pointing up) is refused before any work, the same way by every command and by ``validate``'s sun
    rule (``scene.bakeable.sun_horizon_problem``)."""
    problem = sun_horizon_problem(str(path), sun, scene.up)
    if problem is not None:
        raise UsageError(problem.message)


def sun_in_prototype(scene: Scene, index: int, sun: Sun, warnings: list[str]) -> np.ndarray:
    """The sun direction in a prototype's own frame (DESIGN.md section 4), as seen by its first instance.

    Per-leaf results are stored per prototype, so instances rotated differently
    from the first share its lighting: that is reported as a warning.
    """
    insts = scene.instances_of(index)
    if len({tuple(np.round(to_prototype_space(sun.direction, i.transform), 6)) for i in insts}) > 1:
        warnings.append(
            f"prototype <{scene.prototypes[index].path}> has {len(insts)} instances at several orientations; its per-leaf "
            f"lighting uses the sun as seen by <{insts[0].path}>."
        )
    return first_instance_sun(scene, index, sun.direction)


def first_instance_sun(scene: Scene, index: int, direction: np.ndarray) -> np.ndarray:
    """A world direction toward the sun in prototype ``index``'s frame, as its first instance sees it."""
    insts = scene.instances_of(index)
    return to_prototype_space(direction, insts[0].transform) if insts else np.asarray(direction, dtype=np.float64)


def require_consistent_input(path: Path) -> None:
    """Refuse an input whose layers and grid files come from different runs (``scene.integrity``), naming the stale file."""
    from foliage_tools.scene.integrity import check_layers

    problems = check_layers(input_files(path))
    if problems:
        more = f" ({len(problems) - 1} more such file(s): `foliage validate` lists them.)" if len(problems) > 1 else ""
        raise InputError(f"the input mixes results of different runs: {problems[0]}{more}")

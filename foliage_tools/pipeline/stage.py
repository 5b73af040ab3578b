"""What every bake stage does first: check the output, read the scene, choose the sun."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from foliage_tools.errors import InputError, UsageError
from foliage_tools.geometry.sun import Sun, choose_sun, to_prototype_space
from foliage_tools.pipeline.density import require_leaves
from foliage_tools.pipeline.report import Progress, Report
from foliage_tools.scene.model import Scene
from foliage_tools.scene.read import read_scene
from foliage_tools.scene.write import check_output_path, input_files


def begin_bake(command: str, path: Path, out: Path | None, sun_flag, progress: Progress) -> tuple[Report, Scene, Sun]:
    """A report, the scene (with leaves) and the sun; refuses a bad output, or an input mixing two runs, before any work."""
    report = Report(command=command, inputs=[str(path)])
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
    DistantLight pointing up) is refused before any work, the same way by every command."""
    if float(np.dot(sun.direction, np.asarray(scene.up, dtype=np.float64))) <= 1e-9:
        where = "--sun" if sun.source == "--sun" else f"the DistantLight <{sun.source}> of @{path}@" if sun.source != "default" else "the default sun"
        raise UsageError(f"the sun from {where} is at or below the horizon (elevation {sun.elevation:g} degrees); "
                         "the bakes need a sun above it: give --sun AZ,EL with EL > 0.")


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

"""``foliage bake``: the main job — every stage in sequence, each layer sublayering the previous one.

OUTDIR/<name>.density.usda -> .smax.usda -> .spp.usda -> .lb.usda (the last
holds the whole bake, since each layer sublayers the one before), a preview
image comparing direct light with the LB and s_max bakes, and with ``with_reference`` a bench
report (JSON + plot).

All or nothing, like every command's outputs: the stages write into a
temporary sibling of OUTDIR (same parent, so the relative paths to the input
stay valid) and their files are moved into OUTDIR only when every stage has
succeeded. A failed or interrupted bake leaves OUTDIR as it was (and removes
the directories it created); the error names the stage.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from foliage_tools.errors import FoliageError, OutputError
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.params import DensityParams
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.report import Progress, Report, Silent


@dataclass(frozen=True)
class BakeParams:
    optics: LeafOptics
    sun: tuple[float, float] | None = None
    resolution: int = 64
    """Density and LB grid resolution (voxels along the longest foliage edge)."""
    with_reference: bool = False
    """Also trace the Monte Carlo reference and write the bench report."""
    reference_paths: int = 64_000_000
    """Most reference sun paths (with ``with_reference``); it stops earlier at ``reference_noise``."""
    reference_noise: float | None = 0.02
    """Per-leaf E_scattered noise at which the reference stops (None: trace ``reference_paths``)."""
    direct: DirectChoice = DirectChoice()
    """``--direct`` for every bake stage."""


def _stage(name: str, fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except FoliageError as exc:
        exc.args = (f"bake stage '{name}': {exc}",)
        raise


def run_bake(path: Path, outdir: Path, params: BakeParams, *, progress: Progress | None = None) -> Report:
    progress = progress or Silent()
    report = Report(command="bake", inputs=[str(path)])
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise OutputError(f"@{outdir}@ exists and is not a directory; give a directory for the bake outputs.")
    target = outdir.absolute()
    created = _make_parents(target.parent, outdir)
    try:
        work, staged = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent)), True
    except OSError as exc:
        if not (target.is_dir() and os.access(target, os.W_OK)):
            _remove_empty(created)
            raise OutputError(f"@{outdir}@: cannot write in {target.parent} ({exc.strerror}); choose another output directory.") from None
        # OUTDIR exists and is writable but its parent is not: stage in OUTDIR itself (each file still atomic)
        work, staged = target, False
        report.warnings.append(f"{target.parent} is not writable, so the stages are written straight into {outdir}: "
                               "a bake that fails part-way leaves the stages it finished there.")
    try:
        stages = _run_stages(path, work, params, progress)
        moved = _move_into(work, outdir, path) if staged else {f: f for f in work.iterdir()}
    except BaseException:
        if staged:
            shutil.rmtree(work, ignore_errors=True)
        _remove_empty(created)
        raise
    if staged:
        shutil.rmtree(work, ignore_errors=True)
    final = moved[work / f"{Path(path).stem}.lb.usda"]
    for r in stages.values():
        r.outputs = [str(moved.get(Path(o), o)) for o in r.outputs]
    for name, r in stages.items():
        report.outputs += r.outputs
        report.warnings += [f"{name}: {w}" for w in r.warnings]
        report.findings += [f"{name}: {w}" for w in r.findings]
    report.stats = {
        "result": str(final),
        "stages": {name: {"seconds": r.seconds, "outputs": r.outputs} for name, r in stages.items()},
        "bench": stages["bench"].stats if "bench" in stages else None,
        "direct": stages["smax"].stats.get("direct"),
    }
    return report.finish()


def _run_stages(path: Path, work: Path, params: BakeParams, progress: Progress) -> dict[str, Report]:
    """Every stage in order, each layer over the previous one, all written into ``work``; their reports."""
    from foliage_tools.pipeline.density import run_density
    from foliage_tools.pipeline.lb import LBBakeParams, run_lb
    from foliage_tools.pipeline.preview import PreviewParams, run_preview
    from foliage_tools.pipeline.smax import SmaxParams, run_smax
    from foliage_tools.pipeline.spp import SppParams, run_spp

    stem = Path(path).stem
    stages = {}
    if params.direct.mode == "rays":
        # the exact direct light, traced once for the three stages that write it (the geometry is the input's)
        from dataclasses import replace

        from foliage_tools.pipeline.direct import bake_direct
        from foliage_tools.pipeline.stage import begin_bake

        _, scene, sun = begin_bake("bake", path, None, params.sun, progress)
        params = replace(params, direct=replace(params.direct, precomputed=bake_direct(scene, sun, params.direct, progress)))
    density_out = work / f"{stem}.density.usda"
    stages["density"] = _stage("density", run_density, path, density_out, DensityParams(resolution=params.resolution), progress=progress)
    smax_out = work / f"{stem}.smax.usda"
    stages["smax"] = _stage("smax", run_smax, density_out, smax_out, SmaxParams(optics=params.optics, sun=params.sun, direct=params.direct), progress=progress)
    spp_out = work / f"{stem}.spp.usda"
    stages["spp"] = _stage("spp", run_spp, smax_out, spp_out, SppParams(optics=params.optics, sun=params.sun, resolution=params.resolution, direct=params.direct), progress=progress)
    lb_out = work / f"{stem}.lb.usda"
    stages["lb"] = _stage(
        "lb", run_lb, spp_out, lb_out, LBBakeParams(optics=params.optics, sun=params.sun, resolution=params.resolution, direct=params.direct), progress=progress
    )
    # a picture of the bake: direct light beside direct + LB indirect, same exposure
    stages["preview"] = _stage(
        "preview", run_preview, lb_out, work / f"{stem}.png",
        PreviewParams(compare=("direct", "lb", "spp", "smax"), size=(512, 512), sun=params.sun), progress=progress,
    )
    if params.with_reference:
        from foliage_tools.bench.plot import write_plot
        from foliage_tools.pipeline.bench import BenchParams, run_bench
        from foliage_tools.scene.atomic import atomic_outputs

        bench_params = BenchParams(optics=params.optics, sun=params.sun, paths=params.reference_paths, noise=params.reference_noise,
                                   paths_flag="--reference-paths", noise_flag="--reference-noise", direct_samples=params.direct.samples)
        bench = _stage("bench", run_bench, path, bench_params, progress=progress)
        stages["bench"] = bench
        json_path = work / "bench.json"
        with atomic_outputs([json_path]) as temps:
            temps[json_path].write_text(json.dumps(bench.as_json(), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        bench.outputs += [str(json_path), str(write_plot(work / "bench.png", bench.stats, f"{Path(path).name}"))]
    return stages


def _make_parents(parent: Path, outdir: Path) -> list[Path]:
    """Create the missing directories above OUTDIR; return them deepest first, to remove on failure."""
    missing = []
    d = parent
    while not d.exists():
        missing.append(d)
        d = d.parent
    for d in reversed(missing):
        try:
            d.mkdir()
        except OSError as exc:
            _remove_empty(missing)
            raise OutputError(f"@{outdir}@: cannot create the directory {d} ({exc.strerror}); choose another output directory.") from None
    return missing


def _remove_empty(dirs: list[Path]) -> None:
    for d in dirs:  # deepest first
        try:
            d.rmdir()
        except OSError:
            pass


def _move_into(work: Path, outdir: Path, path: Path) -> dict[Path, Path]:
    """Move the finished files from ``work`` into OUTDIR (grids first, layers last); {work file: final file}."""
    from foliage_tools.scene.write import input_files

    files = sorted(work.iterdir(), key=lambda f: (f.suffix not in (".vdb",), f.suffix in (".usda", ".usdc", ".usd"), f.name))
    used = input_files(path)
    clash = [outdir / f.name for f in files if (outdir / f.name).resolve() in used]
    if clash:
        raise OutputError(f"@{clash[0]}@ is a file the input @{path}@ uses; bake into another directory (inputs are never modified).")
    try:
        outdir.mkdir(exist_ok=True)
        moved = {}
        for f in files:
            os.replace(f, outdir / f.name)
            moved[f] = outdir / f.name
    except OSError as exc:
        raise OutputError(f"@{outdir}@: cannot move the bake into place ({exc.strerror}).") from None
    return moved

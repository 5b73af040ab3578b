"""``foliage bake``: the main job — every stage in sequence, each layer sublayering the previous one.

OUTDIR/<name>.density.usda -> .smax.usda -> .spp.usda -> .lb.usda (the last
holds the whole bake, since each layer sublayers the one before), a preview
image comparing direct light with the LB and s_max bakes, and with ``with_reference`` a bench
report (JSON + plot). Each stage's files are written atomically; if a stage
fails, the earlier stages' complete outputs stay and the error names the stage.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from foliage_tools.errors import FoliageError, OutputError
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.params import DensityParams
from foliage_tools.pipeline.report import Progress, Report, Silent


@dataclass(frozen=True)
class BakeParams:
    optics: LeafOptics
    sun: tuple[float, float] | None = None
    resolution: int = 64
    """Density and LB grid resolution (voxels along the longest foliage edge)."""
    with_reference: bool = False
    """Also trace the Monte Carlo reference and write the bench report."""
    reference_paths: int = 4_000_000


def _stage(name: str, fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except FoliageError as exc:
        exc.args = (f"bake stage '{name}': {exc}",)
        raise


def run_bake(path: Path, outdir: Path, params: BakeParams, *, progress: Progress | None = None) -> Report:
    from foliage_tools.pipeline.density import run_density
    from foliage_tools.pipeline.lb import LBBakeParams, run_lb
    from foliage_tools.pipeline.smax import SmaxParams, run_smax
    from foliage_tools.pipeline.spp import SppParams, run_spp

    progress = progress or Silent()
    report = Report(command="bake", inputs=[str(path)])
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise OutputError(f"@{outdir}@ exists and is not a directory; give a directory for the bake outputs.")
    outdir.mkdir(parents=True, exist_ok=True)
    stem = Path(path).stem
    stages = {}
    density_out = outdir / f"{stem}.density.usda"
    stages["density"] = _stage("density", run_density, path, density_out, DensityParams(resolution=params.resolution), progress=progress)
    smax_out = outdir / f"{stem}.smax.usda"
    stages["smax"] = _stage("smax", run_smax, density_out, smax_out, SmaxParams(optics=params.optics, sun=params.sun), progress=progress)
    spp_out = outdir / f"{stem}.spp.usda"
    stages["spp"] = _stage("spp", run_spp, smax_out, spp_out, SppParams(optics=params.optics, sun=params.sun, resolution=params.resolution), progress=progress)
    lb_out = outdir / f"{stem}.lb.usda"
    stages["lb"] = _stage(
        "lb", run_lb, spp_out, lb_out, LBBakeParams(optics=params.optics, sun=params.sun, resolution=params.resolution), progress=progress
    )
    final = lb_out
    from foliage_tools.pipeline.preview import PreviewParams, run_preview

    # a picture of the bake: direct light beside direct + LB indirect, same exposure
    stages["preview"] = _stage(
        "preview", run_preview, final, outdir / f"{stem}.png",
        PreviewParams(compare=("direct", "lb", "spp", "smax"), size=(512, 512), sun=params.sun), progress=progress,
    )
    if params.with_reference:
        from foliage_tools.bench.plot import write_plot
        from foliage_tools.pipeline.bench import BenchParams, run_bench
        from foliage_tools.scene.atomic import atomic_outputs

        bench = _stage("bench", run_bench, path, BenchParams(optics=params.optics, sun=params.sun, paths=params.reference_paths), progress=progress)
        stages["bench"] = bench
        json_path = outdir / "bench.json"
        with atomic_outputs([json_path]) as temps:
            temps[json_path].write_text(json.dumps(bench.as_json(), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        bench.outputs += [str(json_path), str(write_plot(outdir / "bench.png", bench.stats, f"{Path(path).name}"))]
    for name, r in stages.items():
        report.outputs += r.outputs
        report.warnings += [f"{name}: {w}" for w in r.warnings]
    report.stats = {
        "result": str(final),
        "stages": {name: {"seconds": r.seconds, "outputs": r.outputs} for name, r in stages.items()},
        "bench": stages["bench"].stats if "bench" in stages else None,
    }
    return report.finish()

"""``foliage bake``: the main job — every stage in sequence, each layer sublayering the previous one.

OUTDIR/<name>.density.usda -> .smax.usda -> .spp.usda -> .lb.usda (the last
holds the whole bake, since each layer sublayers the one before), a preview
image comparing direct light with the LB and s_max bakes, and with ``with_reference`` a bench
report (JSON + plot).

All or nothing, as one result (``scene.atomic``): the stages write into a
hidden staging directory inside OUTDIR (``.NAME.bake.tmp-PID-TOKEN``; inside,
not beside it, so an OUTDIR that is a mount point works), and their files
are moved into OUTDIR together only when every stage has succeeded, grids
first and the final layer last, each layer recording the content hash of the
files below it. A failed or interrupted bake leaves OUTDIR as it was (and
removes the directories it created); the error names the stage. OUTDIR's
writability, and output names taken by directories, are checked before any
work.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from foliage_tools.errors import FoliageError, OutputError, UsageError
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline import bake_warnings
from foliage_tools.params import DEFAULT_RESOLUTION, GRID_PRECISIONS, DensityParams
from foliage_tools.pipeline.direct import DirectChoice
from foliage_tools.pipeline.gather import check_gather
from foliage_tools.pipeline.report import Progress, Report, Silent
from foliage_tools.scene.atomic import Commit, recover, run_lock
from foliage_tools.pipeline.stats import BakeStats


@dataclass(frozen=True)
class BakeParams:
    optics: LeafOptics
    sun: tuple[float, float] | None = None
    resolution: int = DEFAULT_RESOLUTION
    """Density and LB grid resolution (voxels along the longest foliage edge)."""
    with_reference: bool = False
    """Also trace the Monte Carlo reference and write the bench report."""
    reference_paths: int = 64_000_000
    """Most reference sun paths (with ``with_reference``); it stops earlier at ``reference_noise``."""
    reference_noise: float | None = 0.02
    """Per-leaf E_scattered noise at which the reference stops (None: trace ``reference_paths``)."""
    direct: DirectChoice = DirectChoice()
    """``--direct`` for every bake stage."""
    volume_purpose: str = "default"
    """``--volume-purpose`` of the FoliageLighting volumes every stage writes."""
    gather: int | None = None
    """``--gather`` of the spp and lb stages (rays per leaf of the final gather; 0: off; None: auto)."""
    grid_precision: str = "float"
    """``--grid-precision`` of the lb stage: its grids on disk as ``float`` or ``half`` (``LBBakeParams.grid_precision``)."""
    portable: bool = False
    """Bake a flattened copy of the input written into OUTDIR (``scene.portable``), so the folder can move on its own."""
    portable_root: Path | None = None
    """With ``portable``: the folder whose files the copy may take (default: the input's folder)."""
    layer_format: str = "auto"
    """``--layer-format``: the layers' file format, ``usda`` (text), ``usdc`` (binary crate) or ``auto``
    (:func:`layer_extension`)."""

    def __post_init__(self) -> None:
        check_gather(self.gather)
        if self.grid_precision not in GRID_PRECISIONS:
            raise UsageError(f"--grid-precision must be one of {', '.join(GRID_PRECISIONS)}, got {self.grid_precision!r}.")
        if self.layer_format not in LAYER_FORMATS:
            raise UsageError(f"--layer-format must be one of {', '.join(LAYER_FORMATS)}, got {self.layer_format!r}.")


#: ``--layer-format`` choices.
LAYER_FORMATS = ("auto", "usda", "usdc")
#: ``auto`` writes binary ``.usdc`` layers from this many prototype leaves or placed instances on: per-leaf and
#: per-instance primvars make text layers large and slow (issue #16: a 1M-leaf bake wrote 981 MB of .usda; its SPP
#: layer is 443 MB as .usda and 112 MB as .usdc), while a small bake stays readable and diffable as text.
LAYER_USDC_LEAVES, LAYER_USDC_INSTANCES = 100_000, 10_000


def layer_extension(path: Path, params: BakeParams) -> str:
    """The extension of the bake's layers: ``params.layer_format``, or for ``auto`` ``usdc`` when the input has
    :data:`LAYER_USDC_LEAVES` prototype leaves or :data:`LAYER_USDC_INSTANCES` instances, else ``usda``."""
    if params.layer_format != "auto":
        return params.layer_format
    from foliage_tools.scene.read import read_scene

    scene = read_scene(path)[0]
    leaves = sum(p.leaves.count for p in scene.prototypes)
    return "usdc" if leaves >= LAYER_USDC_LEAVES or len(scene.instances) >= LAYER_USDC_INSTANCES else "usda"


#: ``--lod`` of the bake's preview of a forest above ``world.WORLD_MAX_TRIANGLES``.
PREVIEW_LOD = 0.25


def _stage(name: str, fn, *args, **kwargs):
    import resource

    try:
        report = fn(*args, **kwargs)
        # the process's peak resident memory when the stage ended (kB on Linux): a stage that raised it is its own
        report.peak_rss_bytes = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024
        return report
    except FoliageError as exc:
        exc.args = (f"bake stage '{name}': {exc}",)
        raise


def planned_outputs(path: Path, params: BakeParams, layer_ext: str = "usda") -> list[str]:
    """The names a bake writes into OUTDIR (one ``.vdb`` per prototype adds ``NN_name`` names: see density.vdb_path)."""
    stem = Path(path).stem
    names = [f"{stem}.{s}.{ext}" for s in ("density", "smax", "spp", "lb") for ext in (layer_ext, "vdb")]
    names.remove(f"{stem}.smax.vdb")
    names.append(f"{stem}.lb.forest.vdb")  # a scene of several instances: the forest lattice (pipeline.forest)
    names.append(f"{stem}.png")
    if params.portable:
        from foliage_tools.scene.portable import input_copy_name

        names.append(input_copy_name(path))  # and its copied asset files (<stem>.input.NAME), known once written
    if params.with_reference:
        names += ["bench.json", "bench.png"]
    return names


def run_bake(path: Path, outdir: Path, params: BakeParams, *, progress: Progress | None = None) -> Report[BakeStats]:
    progress = progress or Silent()
    report: Report[BakeStats] = Report(command="bake", inputs=[str(path)])
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise OutputError(f"@{outdir}@ exists and is not a directory; give a directory for the bake outputs.")
    created = _make_dirs(outdir.absolute(), outdir)
    label = f"{Path(path).stem}.bake"
    try:
        with run_lock(outdir, label):  # one bake of this asset into OUTDIR at a time, from the checks to the commit
            return _locked_bake(path, outdir, params, progress, report, label)
    finally:
        _remove_empty(created)  # what a failed or interrupted bake created (a whole result is never empty)


def _locked_bake(path: Path, outdir: Path, params: BakeParams, progress: Progress, report: Report[BakeStats],
                 label: str) -> Report[BakeStats]:
    ext = layer_extension(path, params)
    names = planned_outputs(path, params, ext)
    _check_outputs(path, outdir, names)
    recover(outdir, names, report.warnings, label=label, allow=portable_copies(path, outdir, params))
    report.warnings += _legacy_staging(outdir)
    commit: Commit | None = None
    try:
        commit = Commit(outdir, label)
        assert commit.staging is not None  # a new Commit's staging directory, until it commits or is discarded
        source, copied = path, []
        if params.portable:
            from foliage_tools.scene.portable import write_portable_input

            progress.step(f"flattening {path} into the output folder (--portable)")
            copied = write_portable_input(path, commit.staging, report.warnings, root=params.portable_root)
            commit.copies.update(p.name for p in copied[:-1])  # the input's files as they are; the layer is ours
            source = copied[-1]
        stages = _run_stages(source, commit.staging, params, progress, stem=Path(path).stem, ext=ext)
        _name_the_input(stages, commit.staging, path)
        moved = _commit(path, outdir, commit, portable_input=source if params.portable else None)
    except BaseException:
        if commit is not None:
            commit.discard()
        raise
    final = moved[f"{Path(path).stem}.lb.{ext}"]
    for r in stages.values():
        r.outputs = [str(moved.get(Path(o).name, o)) for o in r.outputs]
    report.outputs += [str(moved[f.name]) for f in copied]
    for name, r in stages.items():
        report.outputs += r.outputs
        report.findings += [f"{name}: {w}" for w in r.findings]
    # a warning several stages gave (they read the same input) is said once, naming them
    report.warnings += bake_warnings.merge([(name, r.warnings) for name, r in stages.items()])
    report.stats = {
        "result": str(final),
        # each stage's own stats, as its command's --json gives them (LB's sweeps, residual and convergence, the
        # gathers' rays and noise, ...), so a pipeline step can check a bake's quality from the bake's report
        "stages": {name: {"seconds": r.seconds, "outputs": r.outputs, "peak_rss_bytes": r.peak_rss_bytes,
                          "stats": r.stats} for name, r in stages.items()},
        "bench": stages["bench"].stats if "bench" in stages else None,
        "direct": stages["smax"].stats["direct"],
    }
    return report.finish()


def _name_the_input(stages: dict[str, Report], staging: Path, path: Path) -> None:
    """Each stage reads the layer the stage before wrote in the staging folder, so a warning about the input's
    content named that temporary layer (``out/.x.bake.tmp-PID-TOKEN/x.density.usda: mesh ...``), differently in
    each stage, and was repeated once per stage: it names the input instead, so the stages' copies merge."""
    layer = re.compile(re.escape(str(staging)) + r"/[^\s:@'\"]+")
    for r in stages.values():
        r.warnings = [layer.sub(str(path), w) for w in r.warnings]


def _run_stages(path: Path, work: Path, params: BakeParams, progress: Progress, *, stem: str,
                ext: str = "usda") -> dict[str, Report]:
    """Every stage in order, each layer over the previous one, all written into ``work``; their reports."""
    from foliage_tools.pipeline.density import run_density
    from foliage_tools.pipeline.lb import LBBakeParams, run_lb
    from foliage_tools.pipeline.preview import PreviewParams, run_preview
    from foliage_tools.pipeline.smax import SmaxParams, run_smax
    from foliage_tools.pipeline.spp import SppParams, run_spp
    from foliage_tools.pipeline.stage import begin_bake

    stages = {}
    # the input as the stages read it, and its sun: the direct rays, the preview's choices and the reference use it
    _, scene, sun = begin_bake("bake", path, None, params.sun, progress)
    if params.direct.mode == "rays":
        # the exact direct light, traced once for the three stages that write it (the geometry is the input's)
        from dataclasses import replace

        from foliage_tools.pipeline.direct import bake_direct

        params = replace(params, direct=replace(params.direct, precomputed=bake_direct(scene, sun, params.direct, progress)))
    density_out = work / f"{stem}.density.{ext}"
    stages["density"] = _stage("density", run_density, path, density_out, DensityParams(resolution=params.resolution, volume_purpose=params.volume_purpose), progress=progress)
    smax_out = work / f"{stem}.smax.{ext}"
    stages["smax"] = _stage("smax", run_smax, density_out, smax_out, SmaxParams(optics=params.optics, sun=params.sun, direct=params.direct), progress=progress)
    spp_out = work / f"{stem}.spp.{ext}"
    stages["spp"] = _stage("spp", run_spp, smax_out, spp_out, SppParams(optics=params.optics, sun=params.sun, resolution=params.resolution, direct=params.direct, volume_purpose=params.volume_purpose, gather=params.gather), progress=progress)
    lb_out = work / f"{stem}.lb.{ext}"
    stages["lb"] = _stage(
        "lb", run_lb, spp_out, lb_out, LBBakeParams(optics=params.optics, sun=params.sun, resolution=params.resolution, direct=params.direct, volume_purpose=params.volume_purpose, gather=params.gather,
                                             grid_precision=params.grid_precision),
        progress=progress,
    )
    # a picture of the bake: direct light beside direct + each method's indirect, same exposure; per-leaf
    # primvars exist only on editable prototypes (a forest of native instances has none: direct light only)
    from foliage_tools.pipeline.world import traced_alone, world_triangles

    editable = any(p.editable and p.leaves.count for p in scene.prototypes)
    # a forest too large to copy for the rays is also too large to draw in full on a software rasteriser (10 000
    # trees: the sky pass alone ran past 10 minutes): far trees thinned, no sky occlusion, one sample per pixel
    placed = world_triangles(scene)
    big = traced_alone(scene, placed)
    light: dict[str, Any] = {"lod": PREVIEW_LOD, "sky_samples": 0, "samples": 1} if big else {}
    stages["preview"] = _stage(
        "preview", run_preview, lb_out, work / f"{stem}.png",
        PreviewParams(compare=("direct", "lb", "spp", "smax") if editable else ("direct",), size=(512, 512), sun=params.sun,
                      **light),
        progress=progress,
    )
    if big:
        stages["preview"].warnings.append(
            f"the forest places {placed:,} triangles: its preview is drawn with --lod {PREVIEW_LOD} "
            "--sky-samples 0 --samples 1; `foliage preview` of the bake draws it in full.")
    if not editable:
        stages["preview"].warnings.append(
            "every prototype is a native instance, so no leaf mesh holds the bakes' per-leaf primvars: the preview shows "
            "the direct light only (the per-instance means are on the instances; make the prototypes editable for more).")
    if params.with_reference:
        from foliage_tools.bench.plot import write_plot
        from foliage_tools.pipeline.bench import BenchParams, run_bench
        from foliage_tools.scene.atomic import atomic_outputs

        from foliage_tools.pipeline.reference import ReferenceParams, bake_reference, run_reference

        bench_params = BenchParams(optics=params.optics, sun=params.sun, paths=params.reference_paths, noise=params.reference_noise,
                                   paths_flag="--reference-paths", noise_flag="--reference-noise", direct_samples=params.direct.samples)
        ref_params = ReferenceParams(optics=params.optics, sun=params.sun, paths=params.reference_paths, noise=params.reference_noise)
        # one trace for the bench and the reference layer, where both would trace the same copied scene (a forest
        # the bakes trace as lone trees is traced through its placements for the layer, copied whole for the bench)
        traced = None if big else bake_reference(scene, sun, ref_params, progress, flat=True)
        bench = _stage("bench", run_bench, path, bench_params, progress=progress, traced=traced)
        stages["bench"] = bench
        json_path = work / "bench.json"
        with atomic_outputs([json_path]) as temps:
            temps[json_path].write_text(json.dumps(bench.as_json(), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        bench.outputs += [str(json_path), str(write_plot(work / "bench.png", bench.stats, f"{Path(path).name}"))]
        # the reference as a layer over the bake, so `foliage preview NAME.ref.usda --compare direct,lb,reference
        # --error-image` can show where the bake is off
        stages["reference"] = _stage("reference", run_reference, lb_out, work / f"{stem}.ref.{ext}", ref_params,
                                     progress=progress, traced=traced)
    return stages


def _make_dirs(target: Path, outdir: Path) -> list[Path]:
    """Create OUTDIR and the missing directories above it; return them deepest first, to remove on failure."""
    missing = []
    d = target
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


def _legacy_staging(outdir: Path) -> list[str]:
    """Earlier versions staged a bake beside OUTDIR, in ``.OUTDIR.tmp-XXXXXXXX`` (no process id): report, never remove, those."""
    target = outdir.absolute()
    pattern = re.compile(re.escape(f".{target.name}.tmp-") + r"[A-Za-z0-9_]{8}")
    try:
        found = sorted(p for p in target.parent.iterdir() if pattern.fullmatch(p.name) and p.is_dir())
    except OSError:
        return []
    return [f"@{p}@ looks like the staging directory of a bake by an earlier foliage-tools version that was killed; "
            "nothing uses it: remove it once no such bake is running." for p in found]


def portable_copies(path: Path, outdir: Path, params: BakeParams) -> Callable[[str], bool] | None:
    """With --portable, the names of the input's copied asset files (``<stem>.input.NAME``), which a bake's journal
    lists beside its planned outputs; none of them a file the input uses (inputs are never modified)."""
    if not params.portable:
        return None
    from foliage_tools.scene.write import input_files

    prefix, used = f"{Path(path).stem}.input.", None

    def copy(name: str) -> bool:
        nonlocal used
        if not name.startswith(prefix):
            return False
        used = input_files(path) if used is None else used
        return Path(os.path.realpath(outdir / name)) not in used

    return copy


def _check_outputs(path: Path, outdir: Path, names: list[str]) -> None:
    """Before any work: no output may be a directory, or a file the input uses."""
    from foliage_tools.scene.atomic import check_name_fits
    from foliage_tools.scene.write import input_files

    used = input_files(path)
    for name in names:
        f = outdir / name
        check_name_fits(f)  # first: a symbolic link that loops there cannot be resolved below
        if f.is_dir() and not f.is_symlink():
            raise OutputError(f"@{f}@ is a directory, where the bake writes its file {name}; remove or rename it, or bake "
                              "into another directory. Nothing was written.")
        if f.resolve() in used:
            raise OutputError(f"@{f}@ is a file the input @{path}@ uses; bake into another directory (inputs are never modified).")


def _commit(path: Path, outdir: Path, commit: Commit, *, portable_input: Path | None = None) -> dict[str, Path]:
    """Move the finished bake into OUTDIR as one result; {name: final path}.

    The layers were written in the staging directory, so the one that
    sublayers the input (density) refers to it from there: each path leading
    out of the staging directory is rewritten for OUTDIR, and every layer is
    sealed again (its record of the files below it), bottom layer first.
    """
    from foliage_tools.scene.write import input_files, relocate_and_seal

    names = commit.files()
    used = input_files(path)
    clash = [outdir / n for n in names if (outdir / n).resolve() in used]
    if clash:
        raise OutputError(f"@{clash[0]}@ is a file the input @{path}@ uses; bake into another directory (inputs are never modified).")
    # the flattened input (--portable) is the input, not a bake layer: it is moved as written, with the grids
    skip = {portable_input.name} if portable_input is not None else set()
    assert commit.staging is not None  # not committed yet: that is below
    layers = relocate_and_seal(commit.staging, outdir, [n for n in names if Path(n).suffix in (".usda", ".usdc", ".usd") and n not in skip])
    others = [n for n in names if n not in layers]
    finals = commit.commit([*others, *layers])  # grids, images and reports first; the layers bottom-up, the final one last
    return {f.name: f for f in finals}

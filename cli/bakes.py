"""The bake commands: ``lb``, ``spp``, ``smax``, ``reference``, ``bench`` and the main job ``bake``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.markup import escape
from rich.table import Table

from foliage_tools.cli import console
from foliage_tools.cli.common import (
    parse_depth_resolution,
    OUT, SCENE, SEED, parse_direct_samples, bake_options, common_options, direct_choice, direct_options, execute, gather_option,
    leaf_optics_from_flags, run,
    grid_precision_option, setup_logging, volume_purpose_option,
)
from foliage_tools.cli.helpformat import FoliageCommand
from foliage_tools.params import DEFAULT_RESOLUTION, RESOLUTION_RANGE

if TYPE_CHECKING:
    from foliage_tools.pipeline.report import Report
    from foliage_tools.pipeline.stats import BakeStats, BenchStats, LBStats, ReferenceStats, SmaxStats, SppStats


def _eight_directions(ctx: click.Context, param: click.Parameter, value: int) -> int:
    if value != 8:
        raise click.BadParameter(
            f"{value} is not supported: boulanger2008 eq. 5.28 defines 8 sample directions (the cube diagonals, "
            "each binning the octant around it), and primvars:foliage:smax stores 8 values per leaf (elementSize 8). "
            "Leave the option out or pass 8.",
            ctx=ctx, param=param,
        )
    return value


@click.command(cls=FoliageCommand, common=("--output", "--sun"))
@SCENE
@OUT
@click.option("--directions", type=int, default=8, show_default=True, callback=_eight_directions,
              help="Sample directions per leaf: only 8, the cube diagonals of boulanger2008 eq. 5.28.")
@click.option("--path", "path_", type=click.Choice(["auto", "reference", "fast"]), default="auto", show_default=True,
              help="reference: the thesis' O(N²) neighbour binning; fast: exact near sums + FFT far field; "
                   "auto: reference below 20k leaves.")
@click.option("--scatter", type=click.Choice(["march", "leaves", "paper"]), default="march", show_default=True,
              help="How E_scattered is lit. march: each leaf's exact direct light scattered once and marched through the "
                   "leaves, later orders by the envelope's recollision probability; leaves: the thesis' one bounce lit "
                   "by the neighbours' exact lit fractions; paper: eq. 5.24 alone. The docs compare their accuracy.")
@direct_options
@bake_options
@common_options
def smax(scene: Path, out: Path, directions: int, path_: str, scatter: str, direct_mode: str, direct_samples: int, sun: str | None,
         leaf_optics: str | None, wood_reflectance: float | None, as_json: bool, quiet: bool, verbose: int) -> None:
    """Per-leaf envelope distances s_max and Boulanger's tree lighting (boulanger2008 ch. 5).

    For every leaf: s_max toward the 8 directions of eq. 5.28
    (primvars:foliage:smax, uniform, elementSize 8) and exp(-tau*s_max)
    (primvars:foliage:attenuation); the tree's optical thickness tau
    (foliage:tau, FoliageEnvelopeAPI on the tree prim); and per-leaf E_direct /
    E_scattered for the sun (primvars:foliage:smax:direct, :scattered).

    \b
    Example:
      foliage smax examples/tree_small.usda -o tree.smax.usda --sun 120,35
    """
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.smax import SmaxParams, run_smax

    def body() -> int:
        setup_logging(verbose, quiet)
        params = SmaxParams(
            optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
            sun=parse_sun(sun) if sun is not None else None,
            path=path_, direct=direct_choice(direct_mode, direct_samples), scatter=scatter,
        )

        return execute(lambda progress: run_smax(scene, out, params, progress=progress), as_json=as_json, quiet=quiet,
                       render=lambda report: console.print_table(smax_table(report)))

    run(body)


def smax_table(report: Report[SmaxStats]) -> Table:
    """``foliage smax``'s result: one row per prototype."""
    s = report.stats
    table = console.result_table(
        f"s_max in {report.seconds:.2f} s, sun az {s['sun']['azimuth']:.0f}° el {s['sun']['elevation']:.0f}° ({escape(s['sun']['source'])})",
        "prototype", ("leaves", "path", "tau", "mean s_max", "mean E_direct (green)", "mean E_scattered (green)"))
    for p in s["prototypes"]:
        table.add_row(escape(p["path"]), str(p["leaves"]), p["path_used"], f"{p['tau']:.4g}", f"{p['smax_mean']:.4g}",
                      f"{p['e_direct_mean'][1]:.4g}", f"{p['e_scattered_mean'][1]:.4g}")
    return table


@click.command(cls=FoliageCommand, common=("--output", "--paths", "--noise", "--seed", "--sun"))
@SCENE
@OUT
@click.option("--paths", type=click.IntRange(min=2), default=1_000_000, show_default=True,
              help="Sun photon paths (with --noise: the most traced).")
@click.option("--noise", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=None,
              help="Stop at this per-leaf E_scattered noise (relative RMS), e.g. 0.01.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Random seed: the same seed, the same result.")
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Threads [default: all cores]; results do not depend on it.")
@bake_options
@common_options
def reference(scene: Path, out: Path, paths: int, noise: float | None, seed: int, workers: int | None, sun: str | None,
              leaf_optics: str | None, wood_reflectance: float | None, as_json: bool, quiet: bool, verbose: int) -> None:
    """Monte Carlo ground truth: trace sunlight through the actual leaves and wood (Embree).

    Two-sided Lambertian leaves, opaque Lambertian wood, the sun as parallel
    rays of irradiance 1 (the sky is not traced: every per-leaf output is the
    sun's light). The beam's first hits are drawn on the surfaces and kept by
    shadow rays, absorption is taken by its expected value while a photon is
    bright (Russian roulette after that): unbiased, seeded. Writes per-leaf
    E_direct and E_scattered (both faces summed) as
    primvars:foliage:ref:direct / :scattered, and reports its own noise for
    each (relative RMS, from two independent halves).

    \b
    Examples:
      foliage reference examples/tree_small.usda -o tree.ref.usda --paths 4000000 --seed 1
      foliage reference examples/tree_small.usda -o tree.ref.usda --noise 0.01 --paths 100000000
    """
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.reference import ReferenceParams, run_reference

    def body() -> int:
        setup_logging(verbose, quiet)
        params = ReferenceParams(
            optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
            sun=parse_sun(sun) if sun is not None else None,
            paths=paths, seed=seed, workers=workers, noise=noise,
        )

        def render(report: Report[ReferenceStats]) -> None:
            s = report.stats
            console.stdout.print(
                f"{s['paths']:,} sun paths on {s['workers']} worker(s) in {report.seconds:.2f} s; {s['leaves']} leaves; "
                f"noise (rel. RMS over leaves) E_scattered {s['noise_rel']:.4f}, E_direct {s['noise_rel_direct']:.4f}, "
                f"total {s['noise_rel_total']:.4f}", highlight=False, soft_wrap=True)
            console.stdout.print(
                f"mean E_direct (RGB) {', '.join(f'{v:.4g}' for v in s['e_direct_mean'])}; "
                f"mean E_scattered {', '.join(f'{v:.4g}' for v in s['e_scattered_mean'])}", highlight=False, soft_wrap=True)

        return execute(lambda progress: run_reference(scene, out, params, progress=progress), as_json=as_json, quiet=quiet, render=render)

    run(body)


class BenchCommand(FoliageCommand):
    """``foliage bench``, whose help ends with the methods and families of the registry
    (foliage_tools/bench/registry.py), read when the help is shown: a method that lands is listed without
    editing this, and other commands do not pay the seconds its modules take to import."""

    def format_epilog(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        from foliage_tools.bench.registry import families, methods

        found = methods()
        with formatter.section("Methods"):
            formatter.write_dl([(m.name, m.description if m.available else f"not available yet: {m.description}")
                                for m in found])
        with formatter.section("Families (NAME* selects each of its variants; lb, no method's name, too)"):
            formatter.write_dl([(head, ", ".join(members)) for head, members in families([m.name for m in found]).items()])
        super().format_epilog(ctx, formatter)


@click.command(cls=BenchCommand, common=("--methods", "--plot", "--noise", "--sun"))
@SCENE
@click.option("--methods", "methods_", default=None, metavar="NAME,...",
              help="Methods or families (NAME*) to run, listed below [default: all].")
@click.option("--plot", type=click.Path(path_type=Path, dir_okay=False), default=None, help="Also write a speed-vs-error plot (PNG, SVG or PDF).")
@click.option("--paths", type=click.IntRange(min=2), default=64_000_000, show_default=True,
              help="Most reference sun paths (it stops earlier at --noise).")
@click.option("--noise", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=0.02, show_default=True,
              help="Reference noise at which tracing stops.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Reference seed.")
@click.option("--direct-samples", default="auto", show_default=True, callback=parse_direct_samples, metavar="auto|N",
              help="Shadow rays per leaf for the exact E_direct every method is scored with.")
@bake_options
@common_options
def bench(scene: Path, methods_: str | None, plot: Path | None, paths: int, noise: float, seed: int, direct_samples: int | None,
          sun: str | None, leaf_optics: str | None, wood_reflectance: float | None, as_json: bool, quiet: bool, verbose: int) -> None:
    """Speed against error: every available method against the Monte Carlo reference.

    For each method: seconds, relative RMS error of E_scattered and of the
    total (E_direct + E_scattered) over all leaves of all instances, and the
    depth-thickness binned error of shinya2013 eq. 30 — with the reference's
    own noise beside them (an exact method would score about that). The total
    is scored twice: with the exact direct light every bake writes by default
    (--direct rays; its seconds are added to the method's) and with the
    method's own volume estimate (--direct volume). Methods that have not
    landed are listed as unavailable.

    \b
    Example:
      foliage bench examples/tree_small.usda --plot bench.png --json > bench.json
    """
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.bench import BenchParams, run_bench

    def body() -> int:
        setup_logging(verbose, quiet)
        if plot is not None:  # before minutes of tracing, not after
            from foliage_tools.bench.plot import check_plot_path

            check_plot_path(plot)
        params = BenchParams(
            optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
            sun=parse_sun(sun) if sun is not None else None,
            methods=tuple(n.strip() for n in methods_.split(",") if n.strip()) if methods_ is not None else None,
            paths=paths, noise=noise, seed=seed, direct_samples=direct_samples,
        )

        def stage(progress):
            report = run_bench(scene, params, progress=progress)
            if plot is not None:
                from foliage_tools.bench.plot import write_plot

                report.outputs.append(str(write_plot(plot, report.stats, f"{scene.name}: {report.stats['leaves']} leaves")))
            return report

        return execute(stage, as_json=as_json, quiet=quiet, render=lambda report: console.print_table(bench_table(scene, report.stats)))

    run(body)


def count(n: int) -> str:
    """A count the way a table shows it: 6.71M, 20k, 1,500."""
    if n >= 1_000_000:
        return f"{n / 1e6:.3g}M"
    if n >= 10_000:
        return f"{n / 1e3:.3g}k"
    return f"{n:,}"


def bench_table(scene: Path, s: BenchStats) -> Table:
    """``foliage bench``'s result (its report's stats): the reference, the exact direct light, then each method."""
    ref = s["reference"]
    table = console.result_table(
        f"{escape(str(scene))}: {s['leaves']} leaves, sun az {s['sun']['azimuth']:.0f}° el {s['sun']['elevation']:.0f}°",
        "method", ("seconds", "rel. RMS E_scattered", "rel. RMS total", "total, own direct", "binned E_scattered (eq. 30)",
                   "binned total (eq. 30)"))
    table.add_row(f"reference ({count(ref['paths'])} paths)", f"{ref['seconds']:.2f}", f"noise {ref['noise_rel']:.3f}",
                  f"noise {ref['noise_rel_total']:.3f}", "", "", "")
    d = s["direct"]
    table.add_row("direct (rays)", f"{d['seconds']:.3f}", "", f"E_direct {d['rel_rms_direct']:.3f}", "", "", "")
    for m in s["methods"]:
        if not m["available"]:
            table.add_row(escape(m["name"]), "not available", *[""] * 5)
            continue
        errors = (m["rel_rms_scattered"], m["rel_rms_total"], m["rel_rms_total_volume"], m["binned_rms"], m["binned_rms_total"])
        cells = ["n/a" if e is None else f"{e:.3f}" for e in errors]
        table.add_row(escape(m["name"]), f"{m['seconds']:.3f}", *cells)
    return table


@click.command(cls=FoliageCommand, common=("--output", "--resolution", "--bases", "--sun"))
@SCENE
@OUT
@click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True, help="Grid cells along a tree's longest edge.")
@click.option("--bases", type=click.Choice(["sun", "all"]), default="sun", show_default=True,
              help="sun: the scene's sun; all: 18 relighting bases.")
@click.option("--tolerance", type=float, default=1e-5, show_default=True, help="Relative residual at which the steady state is accepted (with --storage fp16 also: once a sweep "
                   "changes the lattice by no more than its rounding, with a warning).")
@click.option("--solver", type=click.Choice(["auto", "iterate", "bicgstab", "extrapolate", "ordered"]), default="auto", show_default=True,
              help="auto: ordered sweeps, then plain ones switching to BiCGSTAB when convergence is slow; the others: "
                   "one method alone.")
@click.option("--absorption-scale", type=float, default=1.0, show_default=True,
              help="sigma_a = scale x (1 - r - t), scale in (0, 1]; 1: the physical leaf (geist2008 used 0.125).")
@click.option("--max-sweeps", type=click.IntRange(min=1), default=20000, show_default=True,
              help="Stop after this many sweeps; short of --tolerance the layer is written and the exit code is 1.")
@click.option("--storage", type=click.Choice(["fp32", "fp16"]), default="fp32", show_default=True,
              help="How the solver stores the lattice between sweeps: fp32, or fp16 (half the memory, float32 arithmetic; "
                   "not with --solver bicgstab).")
@grid_precision_option
@click.option("--base-extent", type=click.Choice(["leaves", "lattice"]), default="leaves", show_default=True,
              help="Where --bases all stores its grids: leaves (only the nodes relighting reads, around every leaf) or "
                   "lattice (every node, for renderers that sample away from the leaves).")
@click.option("--first-order", "first_order", type=click.Choice(["march", "field"]), default=None,
              help="Per-leaf once-scattered light: march (each leaf's exact direct light scattered once and marched "
                   "through the leaves, the lattice's later orders on top) or field (the lattice at the leaf). "
                   "[default: march; field with --bases all]")
@gather_option("LB's scattered light", "primvars:foliage:lb:scattered and lbIndirect (then per leaf)")
@volume_purpose_option
@direct_options
@bake_options
@common_options
def lb(scene: Path, out: Path, resolution: int, bases: str, tolerance: float, solver: str, absorption_scale: float, max_sweeps: int,
       storage: str, grid_precision: str, base_extent: str, first_order: str | None, gather: int | None, volume_purpose: str, direct_mode: str, direct_samples: int, sun: str | None, leaf_optics: str | None, wood_reflectance: float | None,
       as_json: bool, quiet: bool, verbose: int) -> None:
    """Lattice-Boltzmann light bake (geist2008, steele2010) per unique prototype.

    Voxelizes each prototype's leaves (exact leaf-area density; an earlier
    `foliage density` on the same --resolution is reused), solves the
    D3Q19 photon transport to a steady state (starting from the never-scattered
    light, computed exactly in one pass, which also separates direct from
    scattered light) and writes the photon energy density
    grids to OUT.vdb, primvars:foliage:lbIndirect (scattered irradiance at the
    leaf vertices for the scene's sun) and per-leaf E_direct / E_scattered
    (primvars:foliage:lb:direct, :scattered).

    \b
    Example:
      foliage lb examples/tree_small.usda -o tree.lb.usda --resolution 64
      foliage lb examples/tree_small.usda -o tree.lb.usda --bases all   # relightable
      foliage lb examples/tree_small.usda -o tree.lb.usda --gather 0    # the lattice alone, per leaf
    """
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.lb import LBBakeParams, run_lb

    def body() -> int:
        setup_logging(verbose, quiet)
        params = LBBakeParams(
            optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
            sun=parse_sun(sun) if sun is not None else None,
            resolution=resolution, bases=bases, tolerance=tolerance, solver=solver, absorption_scale=absorption_scale,
            max_sweeps=max_sweeps, storage=storage, grid_precision=grid_precision, base_extent=base_extent,
            direct=direct_choice(direct_mode, direct_samples), gather=gather, volume_purpose=volume_purpose,
            first_order=first_order,
        )

        def render(report: Report[LBStats]) -> None:
            table = Table(title=f"lattice-Boltzmann ({bases}) in {report.seconds:.2f} s")
            for col in ("prototype", "grid", "solver", "iterations", "residual", "MLUPS", "mean E_scattered (green)"):
                table.add_column(col, justify="left" if col == "prototype" else "right")
            for p in report.stats["prototypes"]:
                table.add_row(escape(p["path"]), "×".join(map(str, p["resolution"])), p["solver"], str(p["iterations"]),
                              f"{p['residual']:.1e}", f"{p['mlups']:.1f}", f"{p['e_scattered_mean'][1]:.4g}")
            console.print_table(table)

        return execute(lambda progress: run_lb(scene, out, params, progress=progress), as_json=as_json, quiet=quiet, render=render)

    run(body)


def bake_job_options(fn):
    """The options of one bake (``bake``, and ``batch`` for each of its assets)."""
    for option in reversed((
        click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True, help="Grid cells along a tree's longest edge."),
        click.option("--with-reference", is_flag=True, help="Also trace the Monte Carlo reference and score against it."),
        click.option("--reference-paths", type=click.IntRange(min=2), default=64_000_000, show_default=True,
                     help="Most reference sun paths (with --with-reference); it stops earlier at --reference-noise."),
        click.option("--reference-noise", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=0.02, show_default=True,
                     help="Reference per-leaf E_scattered noise at which tracing stops (with --with-reference)."),
        click.option("--layer-format", type=click.Choice(["auto", "usda", "usdc"]), default="auto", show_default=True,
                     help="Layer file format: usda (text), usdc (binary, ~4x smaller) or auto: usdc from 100 000 leaves or "
                          "10 000 instances on."),
        gather_option("the volume method's (SPPG's in the spp stage, LB's in the lb stage)",
                      "primvars:foliage:sppg:scattered and :lb:scattered"),
        grid_precision_option,
        volume_purpose_option,
        direct_options,
        bake_options,
    )):
        fn = option(fn)
    return fn


def bake_params(*, resolution: int, with_reference: bool, reference_paths: int, reference_noise: float, direct_mode: str,
                direct_samples: int | None, sun: str | None, leaf_optics: str | None, wood_reflectance: float | None,
                volume_purpose: str = "default", portable: bool = False, layer_format: str = "auto",
                gather: int | None = None, grid_precision: str = "float", portable_root: Path | None = None):
    """The ``BakeParams`` of the bake options' values."""
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.bake import BakeParams

    return BakeParams(
        optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
        sun=parse_sun(sun) if sun is not None else None,
        resolution=resolution, with_reference=with_reference, reference_paths=reference_paths,
        reference_noise=reference_noise, direct=direct_choice(direct_mode, direct_samples),
        portable=portable or portable_root is not None, portable_root=portable_root, volume_purpose=volume_purpose, layer_format=layer_format, gather=gather, grid_precision=grid_precision,
    )


@click.command(cls=FoliageCommand, common=("--output", "--resolution", "--with-reference", "--portable", "--sun"))
@SCENE
@click.option("-o", "--output", "outdir", required=True, type=click.Path(path_type=Path, file_okay=False), help="Output directory (created if missing).")
@bake_job_options
@click.option("--portable", is_flag=True,
              help="Copy the input into OUTDIR, so the folder can move alone.")
@click.option("--portable-root", type=click.Path(path_type=Path, exists=True, file_okay=False), default=None,
              help="Copy only files under this folder (default: the input's); implies --portable.")
@common_options
def bake(scene: Path, outdir: Path, resolution: int, with_reference: bool, reference_paths: int, reference_noise: float,
         portable: bool, portable_root: Path | None, layer_format: str, gather: int | None, grid_precision: str, volume_purpose: str, direct_mode: str, direct_samples: int, sun: str | None, leaf_optics: str | None, wood_reflectance: float | None,
         as_json: bool, quiet: bool, verbose: int) -> None:
    """The main job: density, s_max, SPP and LB bakes and a preview of SCENE, into OUTDIR.

    Each stage writes a layer that sublayers the previous one, so the last,
    OUTDIR/NAME.lb.usda, holds the whole bake over the untouched input. Per-leaf
    light is relative to a unit sun irradiance normal to the beam.

    \b
    Examples:
      foliage bake examples/tree_small.usda -o out/bake --with-reference
      foliage bake examples/tree_small.usda -o out/ship --portable   # a folder that can move
    """
    from foliage_tools.pipeline.bake import run_bake

    def body() -> int:
        setup_logging(verbose, quiet)
        params = bake_params(resolution=resolution, with_reference=with_reference, reference_paths=reference_paths,
                             reference_noise=reference_noise, direct_mode=direct_mode, direct_samples=direct_samples,
                             sun=sun, leaf_optics=leaf_optics, wood_reflectance=wood_reflectance,
                             volume_purpose=volume_purpose, portable=portable, layer_format=layer_format, gather=gather,
                             grid_precision=grid_precision, portable_root=portable_root)

        def render(report: Report[BakeStats]) -> None:
            d = report.stats["direct"]
            if d is not None and d["mode"] == "rays":  # traced before the stages, once for smax, spp and lb: in none of their seconds
                console.stdout.print(f"{'direct':>8}: {d['seconds']:.2f} s (exact sunlight: {d['samples_per_leaf']:,} "
                                     "shadow rays per leaf, once for smax, spp and lb)", highlight=False, soft_wrap=True)
            for name, st in report.stats["stages"].items():
                console.stdout.print(f"{name:>8}: {st['seconds']:.2f} s", highlight=False)
            b = report.stats["bench"]
            if b:
                ref = b["reference"]
                console.stdout.print(f"reference: {ref['paths']:,} paths, noise {ref['noise_rel']:.3f} (E_scattered), {ref['noise_rel_total']:.3f} (total)", highlight=False)
                for m in b["methods"]:
                    if m["available"] and m["rel_rms_total"] is not None:
                        console.stdout.print(f"  {m['name']:>8}: {m['seconds']:.3f} s, rel. RMS E_scattered {m['rel_rms_scattered']:.3f}, total {m['rel_rms_total']:.3f}", highlight=False)
            console.stdout.print(f"result: {report.stats['result']}", highlight=False)

        return execute(lambda progress: run_bake(scene, outdir, params, progress=progress), as_json=as_json, quiet=quiet, render=render)

    run(body)



@click.command(cls=FoliageCommand, common=("--output", "--resolution", "--directions", "--sun"))
@SCENE
@OUT
@click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True, help="Grid cells along a tree's longest edge.")
@click.option("--directions", type=click.IntRange(min=2), default=16, show_default=True, help="Sample directions of the G-factor and sky.")
@click.option("--no-gfactor", is_flag=True, help="Plain SPP only: no sppg primvars (G is still written as a grid).")
@click.option("--refine", is_flag=True, help="Integrate the refined radiance of shinya2013 appendix A.1 (implies --model spp).")
@click.option("--model", "model", type=click.Choice(["exact", "spp"]), default=None,
              help="The slab model: exact (discrete ordinates, tabulated once per optics) or spp (shinya2013's closed "
                   "form, eqs. 17-22). [default: exact; spp with --refine]")
@click.option("--g-weights", "g_weights", type=click.Choice(["paper", "radiance"]), default="paper", show_default=True,
              help="How G combines its directions' present fractions: paper (plain mean, eq. 27) or radiance "
                   "(weighted by the single-scattering radiance from each).")
@click.option("--g-orders/--no-g-orders", "g_orders", default=None,
              help="Apply G per order of scattering, later orders at the recollision rate (--no-g-orders: once, eq. 28). "
                   "[default: per order with --model exact, once with spp]")
@click.option("--first-order", "first_order", type=click.Choice(["march", "slab"]), default=None,
              help="SPPG's once-scattered sun light: march (each leaf's exact direct light marched through the leaves) "
                   "or slab (the slab's first order times G, eq. 28). [default: march with --g-orders, slab without]")
@click.option("--g-resolution", "g_resolution", type=click.IntRange(min=0), default=None,
              help="Cells along the longest edge of the coarse grid through which G's depths are measured; 0: each "
                   "leaf's own depths. [default: 16 with --model exact, 0 with spp]")
@click.option("--depth-resolution", "depth_resolution", default="auto", show_default=True, metavar="auto|N",
              callback=parse_depth_resolution,
              help="With grid depths: grid cells along the longest foliage edge of the grid the leaves' depths are "
                   "integrated through. auto: the finest up to --resolution with 4 leaves per occupied cell.")
@click.option("--depth", type=click.Choice(["auto", "rays", "grid"]), default="auto", show_default=True,
              help="Leaf optical depths (eq. 29): grid (through the density grid) or rays (leaves crossed, Embree; "
                   "slow on large trees). auto: grid with --direct rays; with --direct volume, rays up to 50k leaves.")
@click.option("--rays-per-leaf", type=click.IntRange(min=1), default=16, show_default=True,
              help="With --depth rays: ray origins per leaf, uniform over its area (seeded).")
@gather_option("SPPG's (SPP's with --no-gfactor)", "primvars:foliage:sppg:scattered (spp with --no-gfactor)")
@volume_purpose_option
@direct_options
@bake_options
@common_options
def spp(scene: Path, out: Path, resolution: int, directions: int, no_gfactor: bool, refine: bool, model: str | None, g_weights: str, g_orders: bool | None, first_order: str | None, g_resolution: int | None, depth_resolution: int | None,
        depth: str, rays_per_leaf: int, gather: int | None, volume_purpose: str, direct_mode: str, direct_samples: int, sun: str | None, leaf_optics: str | None, wood_reflectance: float | None,
        as_json: bool, quiet: bool, verbose: int) -> None:
    """Simplified plane-parallel scattering with the G-factor (shinya2013).

    Measures each leaf's optical depth and thickness toward the sun and N
    sample directions (eq. 29; --depth rays or grid), adding the leaves of
    neighbouring instances in a forest (eq. 31), computes the G-factor per cell and per-leaf
    SPPG, SPP and single-scattering irradiance. Writes grids sppGFactor,
    sppDepth, sppThickness to OUT.vdb, primvars:foliage:sppIrradiance and
    :gFactor (vertex) and per-leaf primvars:foliage:{spp,sppg,ss}:{direct,scattered}.
    The leaf-area density of an earlier `foliage density` on the same
    --resolution is reused. The paper's printed formulas were re-derived (see
    lighting/spp/).

    \b
    Example:
      foliage spp examples/tree_small.usda -o tree.spp.usda --directions 16
    """
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.spp import SppParams, run_spp

    def body() -> int:
        setup_logging(verbose, quiet)
        params = SppParams(
            optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
            sun=parse_sun(sun) if sun is not None else None,
            resolution=resolution, directions=directions, gfactor=not no_gfactor, refine=refine, model=model, g_weights=g_weights, g_orders=g_orders, first_order=first_order, g_resolution=g_resolution,
            depth=depth, depth_resolution=depth_resolution, rays_per_leaf=rays_per_leaf, direct=direct_choice(direct_mode, direct_samples), gather=gather,
            volume_purpose=volume_purpose,
        )

        def render(report: Report[SppStats]) -> None:
            table = Table(title=f"SPP in {report.seconds:.2f} s ({directions} directions, {depth} depths)")
            for col in ("prototype", "leaves", "cells", "mean G-factor", "mean E_scattered SPP (green)", "SPPG (green, as written)"):
                table.add_column(col, justify="left" if col == "prototype" else "right")
            for p in report.stats["prototypes"]:
                e = p["e_scattered_mean"]
                table.add_row(escape(p["path"]), str(p["leaves"]), str(p["cells"]), f"{p['gfactor_mean']:.3f}",
                              f"{e['spp'][1]:.4g}", f"{e['sppg'][1]:.4g}" if "sppg" in e else "-")
            console.print_table(table)

        return execute(lambda progress: run_spp(scene, out, params, progress=progress), as_json=as_json, quiet=quiet, render=render)

    run(body)

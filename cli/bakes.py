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


@click.command()
@SCENE
@OUT
@click.option("--directions", type=int, default=8, show_default=True, callback=_eight_directions,
              help="Sample directions ω_j per leaf. Only 8, the cube diagonals of eq. 5.28, is defined: each bins "
                   "the octant around it, and the primvars hold 8 values per leaf.")
@click.option("--path", "path_", type=click.Choice(["auto", "reference", "fast"]), default="auto", show_default=True,
              help="reference: the thesis' O(N²) neighbour binning (sec. 5.6); fast: exact near sums + FFT far field; "
                   "auto: reference below 20k leaves.")
@click.option("--scatter", type=click.Choice(["march", "leaves", "paper"]), default="march", show_default=True,
              help="How E_scattered is lit. march: the first order of scattering is each leaf's exact direct light "
                   "(the shadow rays, traced even with --direct volume) scattered once and marched through a 32-voxel "
                   "medium of the leaves, as spp and lb take it, the later orders counted by the envelope's "
                   "recollision probability p = 1 - mean exp(-tau s_max): per leaf 0.14 / 0.20 / 0.21 on the README's "
                   "three trees; leaves: the thesis' one bounce with the sun at each leaf's scatterers from the "
                   "neighbours' exact lit fractions, the same later orders (0.19 / 0.28 / 0.35); paper: "
                   "boulanger2008's one bounce alone (eq. 5.24), whose linear envelope darkens the scatterers: "
                   "0.6-0.74 of the reference's scattered light on those trees. Recorded as foliage:smax:scatter on "
                   "the tree prim.")
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


@click.command()
@SCENE
@OUT
@click.option("--paths", type=click.IntRange(min=2), default=1_000_000, show_default=True,
              help="Sun photon paths; with --noise, the most that will be traced. Noise falls as 1/sqrt(paths).")
@click.option("--noise", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=None,
              help="Stop once the per-leaf E_scattered noise (relative RMS over leaves, from two independent halves) is at "
                   "or below this, e.g. 0.01 for 1 %; the result is still fixed by --seed.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Random seed; results are bitwise reproducible for a seed.")
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Threads [default: all cores]; does not change the results.")
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


class BenchCommand(click.Command):
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


@click.command(cls=BenchCommand)
@SCENE
@click.option("--methods", "methods_", default=None, metavar="NAME,...",
              help="Methods to run, by name (that method alone) or family: NAME* (NAME and its variants), or a family name "
                   "no method has (lb). Listed below [default: every available one].")
@click.option("--plot", type=click.Path(path_type=Path, dir_okay=False), default=None, help="Write a log-log speed-vs-error plot (PNG/SVG/PDF).")
@click.option("--paths", type=click.IntRange(min=2), default=64_000_000, show_default=True,
              help="Most reference Monte Carlo sun paths (it stops earlier at --noise).")
@click.option("--noise", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=0.02, show_default=True,
              help="Reference per-leaf E_scattered noise at which tracing stops; 2 % resolves a 5 % error.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Reference seed.")
@click.option("--direct-samples", default="auto", show_default=True, callback=parse_direct_samples, metavar="auto|N",
              help="Shadow rays per leaf for the exact E_direct (--direct rays) every method is scored with (as the bakes).")
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


@click.command()
@SCENE
@OUT
@click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True, help="Lattice nodes along the longest edge of each prototype's foliage bounds.")
@click.option("--bases", type=click.Choice(["sun", "all"]), default="sun", show_default=True,
              help="sun: the geist2008 sun boundary for the scene's sun (grid lbSun); all: the 18 Kronecker bases + ambient "
                   "of steele2010 3.1 for relighting (grids lbBase01..18, lbAmbient; 18x the memory and work of sun: "
                   "~151 bytes per node and right-hand side, 128^3 ~14.5 GB, half that with --storage fp16; `foliage plan` "
                   "shows it first).")
@click.option("--tolerance", type=float, default=1e-5, show_default=True, help="Relative residual at which the steady state is accepted. With --storage fp16 a solve also counts as "
                   "converged, with a warning, once a sweep changes the lattice by no more than its rounding to binary16 "
                   "(~1e-4; README 'LB storage').")
@click.option("--solver", type=click.Choice(["auto", "iterate", "bicgstab", "extrapolate", "ordered"]), default="auto", show_default=True,
              help="auto: ordered sweeps (in place, in alternating node order, so light crosses the whole grid in "
                   "one: ~7 sweeps where plain ones need about the grid's edge), then, if still short, plain ones "
                   "switching to BiCGSTAB when convergence is slow (low absorption). ordered / iterate / bicgstab / "
                   "extrapolate: one method alone (README \"LB solvers\").")
@click.option("--absorption-scale", type=float, default=1.0, show_default=True,
              help="sigma_a = scale x (1 - r - t), scale in (0, 1]. 1 = physical leaf; geist2008 used 0.125.")
@click.option("--max-sweeps", type=click.IntRange(min=1), default=20000, show_default=True,
              help="Stop after this many lattice sweeps. Short of --tolerance the layer is still written, and the "
                   "command exits 1 (a bake that failed its accuracy check).")
@click.option("--storage", type=click.Choice(["fp32", "fp16"]), default="fp32", show_default=True,
              help="How the solver stores the lattice densities between sweeps: fp32, or fp16 (binary16 with float32 "
                   "arithmetic: half the memory at about the same speed; with --bases all every leaf of the example tree was "
                   "within 0.07 % of fp32; not with --solver bicgstab). The grids written are as --grid-precision says either way; README "
                   "'LB storage' gives the measured error.")
@grid_precision_option
@click.option("--base-extent", type=click.Choice(["leaves", "lattice"]), default="leaves", show_default=True,
              help="Where --bases all stores lbAmbient and lbBase01..18: leaves, only at the lattice nodes the relighting "
                   "reads (around every leaf: 17.9 % of tree_small's 64^3 nodes, its .vdb 4.5x smaller, 1.8x at 24^3; "
                   "steele2010 4.2 'we do not store data that will not be accessed'; relit light identical), or "
                   "lattice, every node (for a renderer that samples the bases away from the leaves). No effect with "
                   "--bases sun, whose lbSun keeps every node.")
@click.option("--first-order", "first_order", type=click.Choice(["march", "field"]), default=None,
              help="Where a sun bake's per-leaf once-scattered light (primvars:foliage:lb:scattered) comes from. march "
                   "(the default with --bases sun): each leaf's exact direct light (the shadow rays; the wood's too) "
                   "scattered once by its r and t and marched through a 32-voxel medium of the leaves, plus the "
                   "lattice's later orders at the leaf; field (the only choice with --bases all): the lattice field at "
                   "the leaf, whose first order is that of the homogenised beam. Per-leaf E_scattered error at 64 on "
                   "tree_small / the oak / the sapling 0.13 / 0.20 / 0.19 with march, 0.26 / 0.28 / 0.29 with field; "
                   "both within 10 % of the exact solution in every depth bin of a uniform leaf layer (README 'LB with "
                   "the marched first order'). The grids and lbIndirect stay the field.  [default: march; field with "
                   "--bases all]")
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
        click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True, help="Density and LB grid resolution."),
        click.option("--with-reference", is_flag=True, help="Also trace the Monte Carlo reference: bench.json / bench.png, and NAME.ref.usda over the bake (its "
                          "per-leaf reference light, for `foliage preview NAME.ref.usda --compare lb,reference --error-image`)."),
        click.option("--reference-paths", type=click.IntRange(min=2), default=64_000_000, show_default=True,
                     help="Most reference sun paths (with --with-reference); it stops earlier at --reference-noise."),
        click.option("--reference-noise", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=0.02, show_default=True,
                     help="Reference per-leaf E_scattered noise at which tracing stops (with --with-reference)."),
        click.option("--layer-format", type=click.Choice(["auto", "usda", "usdc"]), default="auto", show_default=True,
                     help="File format of the bake's layers: usda (text), usdc (binary, ~4x smaller and faster for large "
                          "bakes) or auto: usdc from 100 000 prototype leaves or 10 000 instances on, else usda."),
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
                gather: int | None = None, grid_precision: str = "float"):
    """The ``BakeParams`` of the bake options' values."""
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.bake import BakeParams

    return BakeParams(
        optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
        sun=parse_sun(sun) if sun is not None else None,
        resolution=resolution, with_reference=with_reference, reference_paths=reference_paths,
        reference_noise=reference_noise, direct=direct_choice(direct_mode, direct_samples), portable=portable,
        volume_purpose=volume_purpose, layer_format=layer_format, gather=gather, grid_precision=grid_precision,
    )


@click.command()
@SCENE
@click.option("-o", "--output", "outdir", required=True, type=click.Path(path_type=Path, file_okay=False), help="Output directory (created if missing).")
@bake_job_options
@click.option("--portable", is_flag=True,
              help="Write the input, flattened into one layer, into OUTDIR (NAME.input.usda, its textures and other files "
                   "copied beside it) and bake that, so OUTDIR can be moved or shipped on its own. Without it the first "
                   "layer sublayers the input by a relative path, and OUTDIR moves only together with the input.")
@common_options
def bake(scene: Path, outdir: Path, resolution: int, with_reference: bool, reference_paths: int, reference_noise: float,
         portable: bool, layer_format: str, gather: int | None, grid_precision: str, volume_purpose: str, direct_mode: str, direct_samples: int, sun: str | None, leaf_optics: str | None, wood_reflectance: float | None,
         as_json: bool, quiet: bool, verbose: int) -> None:
    """The main job: density, s_max, SPP and LB bakes, a preview (and a speed-vs-error report) into OUTDIR.

    Each stage writes a layer that sublayers the previous one, so the last
    (OUTDIR/NAME.lb.usda) holds the whole bake over the untouched input.

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
                             grid_precision=grid_precision)

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



@click.command()
@SCENE
@OUT
@click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True, help="Density grid voxels along the longest foliage edge.")
@click.option("--directions", type=click.IntRange(min=2), default=16, show_default=True, help="Sample directions for the G-factor and the sky (even; the paper used 16-22).")
@click.option("--no-gfactor", is_flag=True, help="Plain SPP only: skip the sppg primvars (G is still written as a grid).")
@click.option("--refine", is_flag=True, help="Integrate the refined radiance of shinya2013 appendix A.1 for the sun's scattered light "
              "(refines the paper's closed form: implies --model spp).")
@click.option("--model", "model", type=click.Choice(["exact", "spp"]), default=None,
              help="The plane-parallel part of the scattered light. exact: the exact solution of the local slab per leaf "
                   "(the project's discrete-ordinate solver, tabulated once per optics); spp: shinya2013's closed form "
                   "(eqs. 17-22), which loses about half the scattered light of a high sun even in an exactly "
                   "plane-parallel canopy. [default: exact; spp with --refine]")
@click.option("--g-weights", "g_weights", type=click.Choice(["paper", "radiance"]), default="paper", show_default=True,
              help="How the G-factor combines its sample directions. Each direction v has a present fraction F_v: the share "
                   "of the plane-parallel single scattering along v that lies inside the real medium (shinya2013 eq. 26). "
                   "paper: G is their plain mean (eq. 27), every direction counting the same whatever light it carries. "
                   "radiance: each F_v is weighted by the plane-parallel single-scattering radiance arriving from v, so G "
                   "is the share of the point's once-scattered light that is really there (lighting/gfactor/ derives "
                   "it). Measured: it hardly moves G in a uniform layer and lowers it on isolated crowns (tree_small "
                   "0.68 -> 0.59), which helps the exact slab only with bright leaves.")
@click.option("--g-orders/--no-g-orders", "g_orders", default=None,
              help="Apply the G-factor per order of scattering (the default with --model exact; --no-g-orders: once, "
                   "shinya2013 eq. 28, the default with --model spp): G is a share of once-scattered light; each later "
                   "order is lost at the rate light re-meets a leaf, so the scattered light is scaled by "
                   "G s / (1 - (1 - s) rho), s = the exact slab's once-scattered share at the leaf and rho = the real "
                   "medium's recollision probability over the slab's there, instead of by G (lighting/gfactor/). It "
                   "matters for bright leaves (albedo near 1), where s is small (in shinya2013's own test, albedo "
                   "0.95, the exact slab + G on the oak scores 0.065 binned error per order against 0.385 with G once "
                   "on the same grid; README 'The later orders').")
@click.option("--first-order", "first_order", type=click.Choice(["march", "slab"]), default=None,
              help="Where SPPG's once-scattered sun light comes from. march: each leaf's exact direct light (the "
                   "shadow rays) scattered once by its r and t and marched through a 32-voxel medium of the leaves "
                   "to every other leaf, the later orders at --g-orders' rate; slab: the exact slab's first order "
                   "times G (shinya2013 eq. 28). The slab has no sides, so it keeps light a finite crown loses "
                   "sideways: on the oak its first order reads 1.1 -> 2.0x the reference from top to bottom, "
                   "which no G constant over depth can mend. Per-leaf E_scattered error on tree_small / the oak / "
                   "the sapling 0.134 / 0.201 / 0.199 with march, 0.223 / 0.328 / 0.306 with slab; uniform layer "
                   "within -1.3 ... +4.3 % of the reference in every depth bin (README 'SPPG's first order'). "
                   "Costs ~0.3 s on the oak. With march, G (and --g-weights) no longer scales the sun's scattered light; it still "
                   "scales the sky's, and sppGFactor is G. [default: march with --g-orders, slab without]")
@click.option("--g-resolution", "g_resolution", type=click.IntRange(min=0), default=None,
              help="Measure the G-factor's depths through a coarse leaf-area density grid of this many voxels along the "
                   "longest foliage edge (shinya2013 keeps G on a ~16^3 grid), not from each leaf's own depths. G is "
                   "lowered by mere depth noise (a leaf whose depth toward the sun reads long counts the slab as deeper "
                   "than its other directions see): in a uniform leaf layer 16 lifts G from 0.92 to 0.97 in the interior, "
                   "where the true loss through the sides is 2-8 %. On isolated crowns a higher G brightens the exact "
                   "slab, which is already too bright there unless --g-orders. 0: per leaf. [default: 16 with --model exact, "
                   "0 with --model spp]")
@click.option("--depth-resolution", "depth_resolution", default="auto", show_default=True, metavar="auto|N",
              callback=parse_depth_resolution,
              help="With grid depths: voxels along the longest foliage edge of the leaf-area density grid each leaf's "
                   "depths are integrated through (the written grids keep --resolution). auto: per tree, the finest grid "
                   "up to --resolution whose voxels holding a leaf hold 4 leaves on average, so the slab model sees a "
                   "homogeneous medium rather than single leaves: with --first-order slab, where the depths also set the "
                   "first order, per-leaf E_scattered error on tree_small / the oak / the sapling 0.35 / 0.41 / 0.43 at "
                   "64 voxels, 0.22 / 0.33 / 0.31 with auto (README 'The depth grid').")
@click.option("--depth", type=click.Choice(["auto", "rays", "grid"]), default="auto", show_default=True,
              help="How each leaf's optical depth toward the sun and the sample directions is measured (shinya2013 eq. 29). "
                   "grid: integrate the leaf-area density grid (own leaf's area taken out), assuming randomly oriented leaves. "
                   "rays: count the leaves crossed through the actual leaf triangles (Embree), own leaf skipped, averaged over "
                   "--rays-per-leaf points on each leaf; costs rays-per-leaf x (2 x directions + 2) rays per leaf per instance "
                   "(a 50k-leaf tree: 25-56 s against 0.2-0.6 s for grid). "
                   "auto: grid with the exact direct light (--direct rays): the depths then serve the scattered light only, "
                   "where the grid's smooth depths measured better (uniform layer at 60 degrees: -1..+2 % against -11..-16 % "
                   "for ray counts); with --direct volume, rays up to 50k leaves (their visible share is the better direct "
                   "term) and grid above.")
@click.option("--rays-per-leaf", type=click.IntRange(min=1), default=16, show_default=True,
              help="With --depth rays: origins per leaf, uniform over its area (seeded); more rays, less count noise (1/sqrt).")
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

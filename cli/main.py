"""``foliage``: bake the light that scatters through foliage.

Each subcommand maps its flags one-to-one to a pipeline function's keyword
arguments and turns the returned report into output and an exit code
(``cli/common.py`` maps failures to exit codes). Larger commands live in
their own modules and are added to the group at the bottom.
"""

from __future__ import annotations

import sys

from foliage_tools import interrupts

if getattr(sys.modules.get("__main__"), "__file__", "").endswith("/foliage"):  # the `foliage` script: before the imports
    interrupts.install_interrupts()

import errno  # noqa: E402
import signal  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import IO, TYPE_CHECKING, cast  # noqa: E402

import click  # noqa: E402
from rich.markup import escape  # noqa: E402
from rich.table import Table  # noqa: E402

from foliage_tools import __version__  # noqa: E402
from foliage_tools.cli import common, console  # noqa: E402
from foliage_tools.cli.helpformat import FoliageCommand  # noqa: E402
from foliage_tools.cli.common import OUT, SCENE, common_options, config_option, execute, run, setup_logging, volume_purpose_option  # noqa: E402
from foliage_tools.errors import EXIT_BAD_INPUT, EXIT_FINDINGS, EXIT_INTERRUPTED  # noqa: E402
from foliage_tools.params import DEFAULT_RESOLUTION, RESOLUTION_RANGE  # noqa: E402

if TYPE_CHECKING:
    from foliage_tools.pipeline.report import Report
    from foliage_tools.pipeline.stats import DensityStats, PlanStats


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="foliage")
def cli() -> None:
    """Bake the light that scatters through foliage.

    Reads tree assets from USD, computes leaf density and lighting, and writes
    the results as OpenVDB grids and USD primvars in an output layer that
    sublayers the input (the input is never modified).

    \b
    Typical pipeline:
      foliage import tree.obj -o tree.usda      # a mesh file (OBJ, PLY, glTF) into a tree asset
      foliage inspect tree.usda                 # what the bakes will see
      foliage validate tree.usda --strict       # CI asset check
      foliage bake tree.usda -o baked/          # density, smax, spp, lb + preview
      foliage bench tree.usda --plot bench.png  # speed vs error against Monte Carlo
      foliage preview baked/tree.lb.usda -o tree.png --compare direct,lb,spp
      foliage batch trees/ -o baked/                # many assets on Dask, content-hash cached

    Exit codes: 0 ok; 1 validation findings, or a bake that failed its own
    accuracy check (written, with its residual or noise); 2 bad usage, bad
    input or an environment error (disk full, read-only place, out of memory);
    3 internal error (crash log written); 130 interrupted (nothing half-written).
    """


@cli.command(cls=FoliageCommand)
@SCENE
@common_options
def inspect(scene: Path, as_json: bool, quiet: bool, verbose: int) -> None:
    """Show the prototypes, instances, leaves, wood, bounds and lights of SCENE.

    Leaves are connected components of leaf meshes; a mesh is a leaf mesh if
    it has FoliageLeafAPI, primvars:foliage:isLeaf = true, or a name (or
    bound material name) containing leaf/leaves/foliage/needle.

    \b
    Example:
      foliage inspect examples/tree_small.usda --json
    """
    from foliage_tools.pipeline.inspect import inspect as do_inspect

    def body() -> int:
        setup_logging(verbose, quiet)
        report = do_inspect(scene)
        if as_json:
            console.print_json(report.as_json())
            return 0
        console.warn(report.warnings, quiet)
        if not quiet:
            s = report.stats
            table = Table(title=f"{escape(str(scene))}  (up {s['up_axis']}, {s['meters_per_unit']} m/unit)")
            for col in ("prototype", "kind", "inst.", "leaves", "leaf tris", "wood tris", "leaf area", "size"):
                table.add_column(col, justify="left" if col in ("prototype", "kind") else "right", overflow="fold")
            for p in s["prototypes"]:
                lo, hi = p["bounds"]
                size = "×".join(f"{b - a:.3g}" for a, b in zip(lo, hi))
                table.add_row(
                    escape(p["path"]), p["kind"], str(p["instances"]), str(p["leaves"]), str(p["leaf_triangles"]),
                    str(p["wood_triangles"]), f"{p['leaf_area']:.4g}", size,
                )
            console.print_table(table)
            console.stdout.print(f"{s['instances']} instance(s), {s['leaves_total']} leaves placed in the world")
            if s["lights"]:
                for light in s["lights"]:
                    d = ", ".join(f"{v:.3f}" for v in light["direction"])
                    console.stdout.print(f"light <{light['path']}>: {light['kind']}, toward ({d}), intensity {light['intensity']:g}")
            else:
                console.stdout.print("no lights: bakes use the default sun (azimuth 45°, elevation 60°)")
        return 0

    run(body)


@cli.command(cls=FoliageCommand, common=("--strict", "--list-rules"))
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=True), required=False)
@click.option("--strict", is_flag=True, help="Fail on warnings too (exit 1).")
@click.option("--list-rules", is_flag=True, help="List the rules checked, and exit (no SCENE needed).")
@common_options
def validate(scene: Path | None, strict: bool, list_rules: bool, as_json: bool, quiet: bool, verbose: int) -> None:
    """Check SCENE with USD's validators and the foliage rules.

    Exits 1 when an error is found (or a warning, with --strict), 0 when clean.
    Rules: leaf meshes found; finite geometry and valid topology; no degenerate
    triangles (warning); primvar lengths match their interpolation; every
    referenced .vdb exists and holds its named grid with finite values; each
    bake layer's grid files and upstream layers are the ones it was written
    with (content hashes it records: a file from another run is named as
    stale); point instancers' prototypes, protoIndices and per-instance lists
    line up; warnings where the bakes leave geometry out (instancing nested in
    a prototype, meshes without points or faces); plus USD's composition,
    stage-metadata, shading and lux validators. --list-rules names them all.

    \b
    Example (CI):
      foliage validate baked/tree.usda --strict --json > report.json
    """
    from foliage_tools.pipeline.validate import run_validate
    from foliage_tools.scene.validate import rule_docs

    def body() -> int:
        setup_logging(verbose, quiet)
        if list_rules:
            for name, doc in rule_docs():
                console.stdout.print(f"{name}: {doc}", highlight=False)
            return 0
        if scene is None:
            raise click.UsageError("Missing argument 'SCENE' (the USD file to check; --list-rules needs none).")
        report, failed = run_validate(scene, strict=strict)
        if as_json:
            console.print_json(report.as_json())
        elif not quiet:
            for f in report.stats["findings"]:
                colour = {"error": "red", "warning": "yellow"}.get(f["severity"], "cyan")
                console.stdout.print(f"[{colour}]{f['severity']}[/{colour}] {escape('[' + f['rule'] + ']')} {escape(f['message'])}", highlight=False, markup=True, soft_wrap=True)
            s = report.stats
            verdict = "FAILED" if failed else "passed"
            console.stdout.print(f"{scene}: {verdict} ({s['errors']} error(s), {s['warnings']} warning(s){', strict' if strict else ''})", highlight=False)
        return EXIT_FINDINGS if failed else 0

    run(body)


@cli.command(cls=FoliageCommand, common=("--output", "--resolution", "--voxel-size", "--method"))
@SCENE
@OUT
@click.option("--voxel-size", type=float, default=None, help="Voxel edge in stage units, instead of --resolution.")
@click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True,
              help="Grid cells along a tree's longest edge.")
@click.option("--method", type=click.Choice(["area", "subgrid"]), default="area", show_default=True,
              help="area: leaf-area density; subgrid: cells touched.")
@volume_purpose_option
@config_option
@common_options
def density(scene: Path, out: Path, voxel_size: float | None, resolution: int | None, method: str, volume_purpose: str,
            as_json: bool, quiet: bool, verbose: int) -> None:
    """Voxelize each prototype's leaves into a density grid and a wood-fraction grid.

    Writes OUT (a layer that sublayers SCENE) with primvars:foliage:leafId on
    the leaf meshes and a <tree>/FoliageLighting volume whose fields `density`
    and `woodFraction` live in OUT.vdb beside it. Grids are cropped to
    the foliage bounds plus one voxel and stored sparse.

    \b
    Example:
      foliage density examples/tree_small.usda -o tree.density.usda --resolution 64
    """
    from foliage_tools.params import DensityParams
    from foliage_tools.pipeline.density import run_density

    given = click.get_current_context().get_parameter_source("resolution") != click.core.ParameterSource.DEFAULT

    def body() -> int:
        setup_logging(verbose, quiet)
        # --resolution's default gives way to --voxel-size; both given is DensityParams' usage error
        params = DensityParams(voxel_size=voxel_size, resolution=resolution if given or voxel_size is None else None,
                               method=method, volume_purpose=volume_purpose)

        def render(report: Report[DensityStats]) -> None:
            table = Table(title=f"density ({method}) in {report.seconds:.2f} s")
            for col in ("prototype", "leaves", "grid", "voxel size", "active voxels", "area rel. error", "seconds"):
                table.add_column(col, justify="left" if col == "prototype" else "right")
            for p in report.stats["prototypes"]:
                err = "n/a" if p["area_rel_error"] is None else f"{p['area_rel_error']:.1e}"
                table.add_row(p["path"], str(p["leaves"]), "×".join(map(str, p["shape"])), f"{p['voxel_size']:.4g}",
                              str(p["active_voxels"]), err, f"{p['seconds']:.2f}")
            console.print_table(table)

        return execute(lambda progress: run_density(scene, out, params, progress=progress), as_json=as_json, quiet=quiet, render=render)

    run(body)


@cli.command(cls=FoliageCommand, common=("--resolution", "--bases"))
@SCENE
@click.option("--resolution", type=click.IntRange(*RESOLUTION_RANGE), default=DEFAULT_RESOLUTION, show_default=True,
              help="Grid cells along a tree's longest edge.")
@click.option("--bases", type=click.Choice(["sun", "all"]), default="sun", show_default=True,
              help="LB bake to plan for: the sun, or 18 relighting bases.")
@click.option("--storage", type=click.Choice(["fp32", "fp16"]), default="fp32", show_default=True,
              help="LB storage to plan for, as `foliage lb --storage` (fp16 halves the solver's memory).")
@click.option("--depth", type=click.Choice(["auto", "rays", "grid"]), default="auto", show_default=True,
              help="SPP depths to plan for, as `foliage spp --depth`.")
@click.option("--rays-per-leaf", type=click.IntRange(min=1), default=16, show_default=True,
              help="Rays per leaf of SPP's ray depths to plan for, as `foliage spp --rays-per-leaf`.")
@click.option("--reference-paths", type=click.IntRange(min=1), default=1_000_000, show_default=True,
              help="Monte Carlo sun paths to plan for, as `foliage reference --paths`.")
@config_option
@common_options
def plan(scene: Path, resolution: int, bases: str, storage: str, depth: str, rays_per_leaf: int, reference_paths: int,
         as_json: bool, quiet: bool, verbose: int) -> None:
    """Show what a bake of SCENE would do: grids, work, estimated seconds and memory. Writes nothing.

    Per tree: the grid each stage builds, the LB right-hand sides, sweeps and
    memory (the figure that decides whether --resolution 128 --bases all
    fits: ~151 bytes per node and right-hand side with --bases all, ~86 with fp16), which s_max path runs,
    and estimated seconds per stage. Seconds are work divided by rates
    measured on a 2-core machine (listed in foliage_tools/pipeline/plan.py):
    scale them to yours. Memory does not depend on the machine.

    \b
    Example:
      foliage plan examples/tree_small.usda --resolution 128 --bases all
    """
    from foliage_tools.pipeline.plan import PlanParams
    from foliage_tools.pipeline.plan import plan as do_plan

    def body() -> int:
        setup_logging(verbose, quiet)
        params = PlanParams(resolution=resolution, bases=bases, storage=storage, depth=depth, rays_per_leaf=rays_per_leaf,
                            reference_paths=reference_paths)

        def render(report: Report[PlanStats]) -> None:
            s = report.stats
            table = Table(title=f"plan for {scene}: resolution {s['resolution']}, bases {s['bases']}, depth {s['depth']}")
            for col in ("prototype", "inst.", "leaves", "grid", "LB rhs", "sweeps", "LB memory", "smax path"):
                table.add_column(col, justify="left" if col == "prototype" else "right", overflow="fold")
            for p in s["prototypes"]:
                table.add_row(escape(p["path"]), str(p["instances"]), str(p["leaves"]), "x".join(map(str, p["grid"])),
                              str(p["lb_rhs"]), str(p["lb_sweeps_estimate"]), f"{p['lb_memory_bytes'] / 1e9:.2f} GB",
                              p["smax_path"])
            console.print_table(table)
            t = s["seconds_estimate"]
            times = Table(title="estimated seconds (rates measured on a 2-core machine; scale to yours)")
            for col in ("density", "smax", "spp", "lb", "direct (rays; once per bake)", "reference", "peak memory"):
                times.add_column(col, justify="right")
            times.add_row(*(f"{t[k]:.3g}" for k in ("density", "smax", "spp", "lb", "direct", "reference")),
                          f"{s['peak_memory_bytes'] / 1e9:.2f} GB")
            console.print_table(times)
            piped = not console.stdout.is_terminal  # a line per sentence in a pipe or a log, as the tables keep their rows
            k = s["gather_rays_per_leaf"]
            who = "spp and lb include" if s["bases"] == "sun" else "spp includes"  # auto does not gather --bases all
            console.stdout.print(f"{who} the final gather (--gather auto): {k} rays per leaf, "
                                 f"{s['gather_rays']:,} rays" if k else
                                 "--gather auto is off for this many leaves (spp and lb keep their volume method's light)",
                                 highlight=False, soft_wrap=piped)
            if s["forest"] is not None:
                f = s["forest"]
                lone = s["traced"] == "lone trees"
                rays = (f"the per-leaf shadow rays and the gather trace lone trees ({s['traced_triangles']:,} triangles, "
                        f"{s['world_memory_bytes'] / 1e9:.2f} GB) and each instance's direct mean is traced through "
                        "every placed instance (nothing copied)" if lone else
                        f"the shadow rays and gather trace every instance ({s['traced_triangles']:,} triangles, "
                        f"{s['world_memory_bytes'] / 1e9:.2f} GB)")
                how = "through its placed prototypes" if lone else "copying every instance"
                console.stdout.print(
                    f"forest: {s['instances']:,} instances, {s['world_triangles']:,} placed triangles; {rays}; the "
                    f"forest lattice has {f['nodes']:,} nodes (~{f['seconds_estimate_per_stage']:.3g} s, once per "
                    f"bake); the reference would hold {s['reference_memory_bytes'] / 1e9:.2f} GB (it traces {how})",
                    highlight=False, soft_wrap=piped)

        return execute(lambda progress: do_plan(scene, params), as_json=as_json, quiet=quiet, render=render)

    run(body)


def _add_commands() -> None:
    from foliage_tools.cli.bakes import bake, bench, lb, reference, smax, spp
    from foliage_tools.cli.batch import batch
    from foliage_tools.cli.importer import import_model
    from foliage_tools.cli.preview import preview

    for command in (lb, spp, smax, reference, bench, bake, batch, preview, import_model):
        cli.add_command(command)
    common.finite_floats(cli)


_add_commands()


def _note_signal(signum: int) -> None:
    """SIGTERM / SIGHUP are named in the message of the interrupted run (Ctrl-C is just "interrupted")."""
    if signum != signal.SIGINT:
        common.last_signal = signal.Signals(signum).name


def install_interrupt_handlers() -> None:
    """SIGINT, SIGTERM (timeouts, CI cancellation, Kubernetes) and SIGHUP interrupt a run (DESIGN.md section 3).

    ``foliage_tools.interrupts``: exit 130 wherever the signal lands (one inside an import is held until the import is
    over). A signal the caller set to be ignored (``nohup`` ignores SIGHUP) stays ignored.
    """
    interrupts.install_interrupts(_note_signal)
    noted = interrupts.interrupt_noted()
    if noted is not None:  # it came while this module was being imported, before the callback above was set
        _note_signal(noted)


def main() -> None:
    """The ``foliage`` command: click's own handling, except that an interrupt anywhere is exit 130.

    click's standalone mode turns Ctrl-C / SIGINT outside a command body (while a command's modules are
    still being imported, say) into "Aborted!" and exit 1; DESIGN.md section 3 says 130. SIGTERM and
    SIGHUP are interrupts too. An interrupt whose KeyboardInterrupt was lost on its way (swallowed by a
    library) still makes the exit code 130; no commit starts after it (``scene.atomic``).
    """
    install_interrupt_handlers()
    refusal = None if {"-h", "--help", "--version"} & set(sys.argv[1:]) else common.address_space_problem()
    try:
        interrupts.interrupts_ready()
        if refusal:
            console.error(refusal)
            code = 2
            _json_error(code, "MemoryError", refusal)
        else:
            code = cli.main(prog_name="foliage", standalone_mode=False)
    except SystemExit as exc:  # `run` exits with the command's code
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else EXIT_BAD_INPUT)
    except (click.exceptions.Abort, KeyboardInterrupt):
        interrupts.interrupts_done()
        console.stderr.print(common.interrupted_message(None))
        code = EXIT_INTERRUPTED
        _json_error(code, "Interrupted", common.interrupted_message(None))
    except click.ClickException as exc:
        interrupts.interrupts_done()
        try:
            exc.show(file=cast(IO[str], console.PrintableStream(sys.stderr)))  # escape sequences shown escaped
        except OSError:  # stderr is full or gone: the exit code (and --json) still say it
            pass
        code = exc.exit_code
        _json_error(code, type(exc).__name__, exc.format_message())
    except OSError as exc:  # before ``run``: --help or --version to a full stdout, a --config that cannot be read
        if exc.errno in (errno.ENOSPC, errno.EPIPE, errno.EBADF, errno.EIO) and exc.filename is None:
            console.give_up("stdout")  # what was being printed is lost; ``finish`` says so and exits 2
            code = 0
        else:
            code = common.os_failure(exc)
    except (ImportError, MemoryError, RecursionError) as exc:  # while a command loads its modules, before ``run``
        kind, message = common.environment_failure(exc)
        console.error(message)
        code = EXIT_BAD_INPUT
        _json_error(code, kind, message)
    interrupts.interrupts_done()
    if interrupts.interrupt_noted() is not None and code in (0, None, EXIT_FINDINGS):
        how = f"interrupted ({common.last_signal})" if common.last_signal else "interrupted"
        console.stderr.print(f"{how} as the run ended; what it wrote is complete.", highlight=False, soft_wrap=True)
        code = EXIT_INTERRUPTED
    sys.exit(console.finish(code or 0))


def _json_error(code: int, kind: str, message: str) -> None:
    """A usage error found before the command ran (bad option, missing file): still one JSON object with ``--json``."""
    args = sys.argv[1:]
    if "--json" not in args:
        return
    words = [a for a in args if not a.startswith("-")]
    command = words[0] if words and words[0] in cli.commands else None
    try:
        console.print_json(common.error_report(command, words[1:2] if command else [], 0.0, code, kind, message))
    except console.OutputLost:  # stdout is gone: stderr and the exit code say it
        pass


if __name__ == "__main__":
    main()

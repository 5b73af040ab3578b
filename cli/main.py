"""``foliage``: bake the light that scatters through foliage.

Each subcommand maps its flags one-to-one to a pipeline function's keyword
arguments and turns the returned report into output and an exit code. The
error handling below is the one place where failures become exit codes
(DESIGN.md section 3): 0 ok, 1 findings, 2 bad usage or input, 3 internal
error (with a crash log), 130 interrupted.
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import sys
import tempfile
import traceback
from pathlib import Path
from typing import Callable

import click
from rich.markup import escape
from rich.table import Table

from foliage_tools import __version__
from foliage_tools.errors import EXIT_FINDINGS, EXIT_INTERNAL, EXIT_INTERRUPTED, FoliageError
from foliage_tools.cli import console

SCENE = click.argument("scene", type=click.Path(path_type=Path, dir_okay=True))
OUT = click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path), help="Output USD layer (.usda/.usdc); grids go beside it as .vdb files.")
JSON = click.option("--json", "as_json", is_flag=True, help="Print one JSON report on stdout (schemas/json/report.schema.json) instead of tables.")


def _common(fn: Callable) -> Callable:
    fn = click.option("-v", "--verbose", count=True, help="More log output (repeat for debug).")(fn)
    fn = click.option("-q", "--quiet", is_flag=True, help="No progress, warnings or tables; errors still go to stderr.")(fn)
    return JSON(fn)


def crash_log(exc: BaseException) -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "foliage-tools"
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError:
        base = Path(tempfile.gettempdir())
    path = base / f"crash-{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.log"
    path.write_text(
        f"foliage {__version__}\nargv: {sys.argv}\n\n" + "".join(traceback.format_exception(exc)), encoding="utf-8"
    )
    return path


def run(body: Callable[[], int]) -> None:
    """Run a command body, mapping every outcome to an exit code."""
    try:
        code = body()
    except FoliageError as exc:
        console.stderr.print(f"[red]error:[/red] {escape(str(exc))}", highlight=False, markup=True, soft_wrap=True)
        code = exc.exit_code
    except KeyboardInterrupt:
        console.stderr.print("interrupted; no output was written.")
        code = EXIT_INTERRUPTED
    except (click.exceptions.Exit, click.ClickException):
        raise
    except Exception as exc:  # the top-level handler: anything else is our bug
        log = crash_log(exc)
        console.stderr.print(f"[red]internal error:[/red] {type(exc).__name__}: {escape(str(exc))}\nA crash log is at {log}; please attach it to a bug report.", highlight=False, soft_wrap=True)
        code = EXIT_INTERNAL
    sys.exit(code)


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="foliage")
def cli() -> None:
    """Bake the light that scatters through foliage.

    Reads tree assets from USD, computes leaf density and lighting, and writes
    the results as OpenVDB grids and USD primvars in an output layer that
    sublayers the input (the input is never modified).

    \b
    Typical pipeline:
      foliage inspect tree.usda                 # what the bakes will see
      foliage validate tree.usda --strict       # CI asset check
      foliage density tree.usda -o tree.density.usda --resolution 64

    Exit codes: 0 ok, 1 validation findings, 2 bad usage or input,
    3 internal error (crash log written), 130 interrupted.
    """


@cli.command()
@SCENE
@_common
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
        _setup_logging(verbose, quiet)
        report = do_inspect(scene)
        if as_json:
            console.print_json(report.as_json())
            return 0
        console.warn(report.warnings, quiet)
        if not quiet:
            s = report.stats
            table = Table(title=f"{scene}  (up {s['up_axis']}, {s['meters_per_unit']} m/unit)")
            for col in ("prototype", "kind", "inst.", "leaves", "leaf tris", "wood tris", "leaf area", "size"):
                table.add_column(col, justify="left" if col in ("prototype", "kind") else "right", overflow="fold")
            for p in s["prototypes"]:
                lo, hi = p["bounds"]
                size = "×".join(f"{b - a:.3g}" for a, b in zip(lo, hi))
                table.add_row(
                    escape(p["path"]), p["kind"], str(p["instances"]), str(p["leaves"]), str(p["leaf_triangles"]),
                    str(p["wood_triangles"]), f"{p['leaf_area']:.4g}", size,
                )
            console.stdout.print(table)
            console.stdout.print(f"{s['instances']} instance(s), {s['leaves_total']} leaves placed in the world")
            if s["lights"]:
                for light in s["lights"]:
                    d = ", ".join(f"{v:.3f}" for v in light["direction"])
                    console.stdout.print(f"light <{light['path']}>: {light['kind']}, toward ({d}), intensity {light['intensity']:g}")
            else:
                console.stdout.print("no lights: bakes use the default sun (azimuth 45°, elevation 60°)")
        return 0

    run(body)


@cli.command()
@SCENE
@click.option("--strict", is_flag=True, help="Treat warnings (e.g. degenerate triangles) as failures too.")
@click.option("--list-rules", is_flag=True, help="List the rules that are checked and exit.")
@_common
def validate(scene: Path, strict: bool, list_rules: bool, as_json: bool, quiet: bool, verbose: int) -> None:
    """Check SCENE with USD's validators and the foliage rules.

    Exits 1 when an error is found (or a warning, with --strict), 0 when clean.
    Rules: leaf meshes found; finite geometry and valid topology; no degenerate
    triangles (warning); primvar lengths match their interpolation; every
    referenced .vdb exists and holds its named grid with finite values; plus
    USD's composition, stage-metadata, shading and lux validators.

    \b
    Example (CI):
      foliage validate baked/tree.usda --strict --json > report.json
    """
    from foliage_tools.pipeline.validate import run_validate
    from foliage_tools.scene.validate import rule_docs

    def body() -> int:
        _setup_logging(verbose, quiet)
        if list_rules:
            for name, doc in rule_docs():
                console.stdout.print(f"{name}: {doc}", highlight=False)
            return 0
        report, failed = run_validate(scene, strict=strict)
        if as_json:
            console.print_json(report.as_json())
        elif not quiet:
            for f in report.stats["findings"]:
                colour = "red" if f["severity"] == "error" else "yellow"
                console.stdout.print(f"[{colour}]{f['severity']}[/{colour}] {escape('[' + f['rule'] + ']')} {escape(f['message'])}", highlight=False, soft_wrap=True)
            s = report.stats
            verdict = "FAILED" if failed else "passed"
            console.stdout.print(f"{scene}: {verdict} ({s['errors']} error(s), {s['warnings']} warning(s){', strict' if strict else ''})", highlight=False)
        return EXIT_FINDINGS if failed else 0

    run(body)


@cli.command()
@SCENE
@OUT
@click.option("--voxel-size", type=float, default=None, help="Voxel edge length in stage units (exclusive with --resolution).")
@click.option("--resolution", type=int, default=None, help="Voxels along the longest edge of each prototype's foliage bounds [default: 64].")
@click.option("--method", type=click.Choice(["area", "subgrid"]), default="area", show_default=True,
              help="area: exact leaf area per voxel / voxel volume (leaf-area density, 1/unit). "
                   "subgrid: geist2008 sec. 4.2 heuristic, fraction of 27 sub-cells touched (0..1).")
@_common
def density(scene: Path, out: Path, voxel_size: float | None, resolution: int | None, method: str, as_json: bool, quiet: bool, verbose: int) -> None:
    """Voxelize each prototype's leaves into a density grid and a wood-fraction grid.

    Writes OUT (a layer that sublayers SCENE) with primvars:foliage:leafId on
    the leaf meshes and a <tree>/FoliageLighting volume whose fields `density`
    and `woodFraction` live in OUT.density.vdb beside it. Grids are cropped to
    the foliage bounds plus one voxel and stored sparse.

    \b
    Example:
      foliage density examples/tree_small.usda -o out/tree.density.usda --resolution 64
    """
    from foliage_tools.params import DensityParams
    from foliage_tools.pipeline.density import run_density

    def body() -> int:
        _setup_logging(verbose, quiet)
        params = DensityParams(voxel_size=voxel_size, resolution=resolution, method=method)
        with console.RichProgress(enabled=not (quiet or as_json)) as progress:
            report = run_density(scene, out, params, progress=progress)
        if as_json:
            console.print_json(report.as_json())
            return 0
        console.warn(report.warnings, quiet)
        if not quiet:
            table = Table(title=f"density ({method}) in {report.seconds:.2f} s")
            for col in ("prototype", "leaves", "grid", "voxel size", "active voxels", "area rel. error", "seconds"):
                table.add_column(col, justify="left" if col == "prototype" else "right")
            for p in report.stats["prototypes"]:
                err = "n/a" if p["area_rel_error"] is None else f"{p['area_rel_error']:.1e}"
                table.add_row(p["path"], str(p["leaves"]), "×".join(map(str, p["shape"])), f"{p['voxel_size']:.4g}",
                              str(p["active_voxels"]), err, f"{p['seconds']:.2f}")
            console.stdout.print(table)
            for o in report.outputs:
                console.stdout.print(f"wrote {o}", highlight=False)
        return 0

    run(body)


def main() -> None:
    cli(prog_name="foliage")


if __name__ == "__main__":
    main()

"""The bake commands: ``smax`` (and, as they land, ``lb``, ``spp``, ``reference``)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from foliage_tools.cli import console
from foliage_tools.cli.common import OUT, SCENE, bake_options, common_options, leaf_optics_from_flags, run, setup_logging


@click.command()
@SCENE
@OUT
@click.option("--path", "path_", type=click.Choice(["auto", "reference", "fast"]), default="auto", show_default=True,
              help="reference: the thesis' O(N²) neighbour binning (sec. 5.6); fast: exact near sums + FFT far field; "
                   "auto: reference below 20k leaves.")
@bake_options
@common_options
def smax(scene: Path, out: Path, path_: str, sun: str | None, leaf_optics: str | None, wood_reflectance: float | None,
         as_json: bool, quiet: bool, verbose: int) -> None:
    """Per-leaf envelope distances s_max and Boulanger's tree lighting (boulanger2008 ch. 5).

    For every leaf: s_max toward the 8 directions of eq. 5.28
    (primvars:foliage:smax, uniform, elementSize 8) and exp(-tau*s_max)
    (primvars:foliage:attenuation); the tree's optical thickness tau
    (foliage:tau, FoliageEnvelopeAPI on the tree prim); and per-leaf E_direct /
    E_scattered for the sun (primvars:foliage:smax:direct, :scattered).

    \b
    Example:
      foliage smax examples/tree_small.usda -o out/tree.smax.usda --sun 120,35
    """
    from foliage_tools.geometry.sun import parse_sun
    from foliage_tools.pipeline.smax import SmaxParams, run_smax

    def body() -> int:
        setup_logging(verbose, quiet)
        params = SmaxParams(
            optics=leaf_optics_from_flags(leaf_optics, wood_reflectance),
            sun=parse_sun(sun) if sun is not None else None,
            path=path_,
        )
        with console.RichProgress(enabled=not (quiet or as_json)) as progress:
            report = run_smax(scene, out, params, progress=progress)
        if as_json:
            console.print_json(report.as_json())
            return 0
        console.warn(report.warnings, quiet)
        if not quiet:
            s = report.stats
            table = Table(title=f"s_max in {report.seconds:.2f} s, sun az {s['sun']['azimuth']:.0f}° el {s['sun']['elevation']:.0f}° ({escape(s['sun']['source'])})")
            for col in ("prototype", "leaves", "path", "tau", "mean s_max", "mean E_direct (G)", "mean E_scattered (G)"):
                table.add_column(col, justify="left" if col == "prototype" else "right")
            for p in s["prototypes"]:
                table.add_row(escape(p["path"]), str(p["leaves"]), p["path_used"], f"{p['tau']:.4g}", f"{p['smax_mean']:.4g}",
                              f"{p['e_direct_mean'][1]:.4g}", f"{p['e_scattered_mean'][1]:.4g}")
            console.stdout.print(table)
            for o in report.outputs:
                console.stdout.print(f"wrote {o}", highlight=False)
        return 0

    run(body)

"""``foliage import``: a mesh file -> a USD tree asset (pymeshlab)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.markup import escape
from rich.table import Table

from foliage_tools.cli.helpformat import FoliageCommand
from foliage_tools.cli import console
from foliage_tools.cli.common import check_output_name, common_options, execute, run, setup_logging

if TYPE_CHECKING:
    from foliage_tools.pipeline.report import Report
    from foliage_tools.pipeline.stats import ImportStats


@click.command(name="import", cls=FoliageCommand, common=("--output", "--up-axis", "--meters-per-unit", "--leaves", "--all-leaves"))
@click.argument("model", type=click.Path(path_type=Path, dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path, dir_okay=False),
              callback=check_output_name, help="Output USD layer (.usda/.usdc) holding the tree asset.")
@click.option("--up-axis", type=click.Choice(["auto", "Y", "Z"], case_sensitive=False), default="auto", show_default=True,
              help="Up axis to write as upAxis; auto: from the trunk.")
@click.option("--meters-per-unit", type=float, default=1.0, show_default=True,
              help="Metres per model unit (0.01 for centimetres).")
@click.option("--leaves", "leaf_pattern", default=None, metavar="REGEX",
              help="Leaf parts' names [default: leaf|leaves|foliage|needle].")
@click.option("--all-leaves", is_flag=True, help="Every part holds leaves (a file of leaf cards only).")
@click.option("--merge-distance", type=click.FloatRange(min=0), default=None,
              help="Merge vertices closer than this, model units [default: 1e-6 of the bounding-box diagonal, i.e. coincident ones].")
@click.option("--simplify", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=None, metavar="FRACTION",
              help="Simplify the wood parts to this fraction of their faces (quadric edge collapse); leaves are kept as they are.")
@click.option("--no-clean", is_flag=True, help="Skip merging close vertices and removing duplicate / zero-area faces.")
@common_options
def import_model(model: Path, out: Path, up_axis: str, meters_per_unit: float, leaf_pattern: str | None, all_leaves: bool,
                 merge_distance: float | None, simplify: float | None, no_clean: bool, as_json: bool, quiet: bool,
                 verbose: int) -> None:
    """Convert a mesh file (OBJ, PLY, glTF/GLB, STL, OFF, ... whatever pymeshlab reads) into a USD tree asset.

    Writes /Tree (kind component, the default prim) with one mesh per part of
    the file and a UsdPreviewSurface material per source material; leaf
    meshes get FoliageLeafAPI and primvars:foliage:isLeaf = true, wood meshes
    isLeaf = false. Parts are OBJ objects/groups x materials, glTF meshes, or
    the whole file for formats without names. pymeshlab merges coincident
    vertices and removes duplicate and zero-area faces. UVs, normals and
    textures are not carried.

    \b
    Examples:
      foliage import oak.obj -o oak.usda   # up axis from the geometry (Z here)
      foliage import tree.glb -o tree.usda --leaves 'leaf|frond'
      foliage import cards.ply -o cards.usda --all-leaves --meters-per-unit 0.01
    """
    from foliage_tools.pipeline.import_model import DEFAULT_LEAF_PATTERN, ImportParams, run_import
    from foliage_tools.scene.meshfile import CleanOptions

    def body() -> int:
        setup_logging(verbose, quiet)
        params = ImportParams(
            up_axis=up_axis.upper(), meters_per_unit=meters_per_unit, leaf_pattern=leaf_pattern or DEFAULT_LEAF_PATTERN,
            all_leaves=all_leaves, clean=CleanOptions(merge_distance=merge_distance, simplify=simplify, clean=not no_clean),
        )

        def render(report: Report[ImportStats]) -> None:
            table = Table(title=f"{escape(str(model))} -> {escape(str(out))} (up {report.stats['up_axis']}, "
                                f"{report.stats['meters_per_unit']:g} m/unit)")
            for col in ("prim", "part", "kind", "faces read", "triangles", "points"):
                table.add_column(col, justify="right" if col in ("faces read", "triangles", "points") else "left", overflow="fold")
            for p in report.stats["parts"]:
                table.add_row(escape(p["prim"]), escape(p["name"]), "leaves" if p["leaf"] else "wood", str(p["faces_read"]),
                              str(p["triangles"]), str(p["points"]))
            console.print_table(table)

        return execute(lambda progress: run_import(model, out, params, progress=progress), as_json=as_json, quiet=quiet,
                       render=render)

    run(body)

"""``foliage preview``: render SCENE to a PNG or EXR image (or a sequence, or a comparison)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from foliage_tools.cli.helpformat import FoliageCommand
from foliage_tools.cli import console
from foliage_tools.cli.common import (
    OUTPUT_FOLDERS, SCENE, check_output_name, check_sun, common_options, config_notes, config_option, output_folders, run,
    setup_logging,
)

METHOD_CHOICES = ["direct", "lb", "spp", "smax", "reference"]


@click.command(cls=FoliageCommand, common=("--output", "--method", "--compare", "--error-image", "--sun", "--size"))
@SCENE
@click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path), callback=check_output_name,
              help="Image to write: .png (sRGB) or .exr (linear).")
@click.option("--method", type=click.Choice(METHOD_CHOICES), default="direct", show_default=True,
              help="Scattered light to draw: that bake's, or none.")
@click.option("--compare", "compare", metavar="M1,M2,...", default=None,
              help="Methods side by side in one image, e.g. direct,lb.")
@click.option("--error-image", is_flag=True,
              help="Add each method's error against the reference data.")
@click.option("--sun", metavar="AZ,EL", default=None, callback=check_sun,
              help="Sun azimuth,elevation, degrees [default: stage's sun or 45,60].")
@click.option("--size", metavar="WxH", default=None, help="Image size in pixels [default: 1024x1024].")
@click.option("--camera", metavar="/PRIM/PATH", default=None, help="Render through this UsdGeom.Camera of SCENE instead of the orbit camera.")
@click.option("--azimuth", type=float, default=None, help="Orbit camera azimuth, degrees, same convention as --sun [default: 0].")
@click.option("--elevation", type=float, default=None, help="Orbit camera elevation above the horizon, degrees [default: 15].")
@click.option("--distance", type=float, default=None, help="Orbit camera distance from the centre of the trees, stage units [default: frame them].")
@click.option("--fov", type=float, default=35.0, show_default=True, help="Vertical field of view of the orbit camera, degrees.")
@click.option("--ground/--no-ground", default=True, show_default=True, help="Draw a ground plane that receives the trees' shadows.")
@click.option("--frames", type=int, default=None, help="Frames of a sequence made with --orbit and/or --sun-sweep [default: 36].")
@click.option("--orbit", is_flag=True, help="Sequence: the camera circles the trees once.")
@click.option("--sun-sweep", is_flag=True, help="Sequence: the sun circles once at its elevation.")
@click.option("--samples", type=click.Choice(["1", "4", "9", "16"]), default="4", show_default=True,
              help="Antialiasing samples per pixel (a k×k supersampling grid).")
@click.option("--shadow-size", type=int, default=2048, show_default=True, help="Shadow-map resolution (texels per side).")
@click.option("--sky-samples", type=click.IntRange(0, 16), default=16, show_default=True,
              help="Sky directions tested for occlusion by the trees (0: unoccluded sky, faster).")
@click.option("--lod", type=float, default=None, metavar="FRACTION",
              help="Level of detail for large scenes, e.g. --lod 0.25: wood meshes are simplified to FRACTION of their "
                   "triangles (quadric edge collapse); instances farther than 8 tree radii from the camera also keep their "
                   "wood at FRACTION² and only FRACTION of their leaves, each enlarged so the leaf area stays the same "
                   "(leaves are dropped whole, never decimated). Default: full detail.")
@config_option
@common_options
def preview(scene: Path, out: Path, method: str, compare: str | None, error_image: bool, sun: str | None, size: str | None,
            camera: str | None, azimuth: float | None, elevation: float | None, distance: float | None, fov: float, ground: bool,
            frames: int | None, orbit: bool, sun_sweep: bool, samples: str, shadow_size: int, sky_samples: int, lod: float | None,
            as_json: bool, quiet: bool, verbose: int) -> None:
    """Render SCENE with sun, sky and shadows (and baked scattered light) to an image.

    Leaves are two-sided (reflection and transmission, boulanger2008 eq. 5.4,
    wang2005 sec. 3), wood is opaque; the sun casts shadow-mapped shadows on the
    trees and the ground; Reinhard tone mapping for PNG. Needs OpenGL 3.3
    (headless EGL works; Mesa's llvmpipe is enough).

    \b
    Examples:
      foliage preview tree.usda -o tree.png
      foliage preview tree.usda -o tree.exr --sun 120,25 --size 1920x1080
      foliage preview baked.usda -o cmp.png --compare direct,lb,reference --error-image
      foliage preview forest.usda -o turn.png --orbit --frames 72 --size 512x512
      foliage preview forest.usda -o far.png --lod 0.25
    """
    from foliage_tools.pipeline.preview import PreviewParams, parse_methods, parse_size, parse_sun, run_preview

    def body() -> int:
        setup_logging(verbose, quiet)
        params = PreviewParams(
            method=method,
            compare=parse_methods(compare) if compare is not None else (),
            error_image=error_image,
            size=parse_size(size) if size is not None else None,
            camera=camera,
            azimuth=azimuth,
            elevation=elevation,
            distance=distance,
            fov=fov,
            sun=parse_sun(sun) if sun is not None else None,
            ground=ground,
            frames=frames,
            orbit=orbit,
            sun_sweep=sun_sweep,
            samples=int(samples),
            shadow_size=shadow_size,
            sky_samples=sky_samples,
            lod=lod,
        )
        folders = click.get_current_context().meta.get(OUTPUT_FOLDERS, [])
        with output_folders(folders), console.RichProgress(enabled=not (quiet or as_json)) as progress:
            report = run_preview(scene, out, params, progress=progress)
        config_notes(report)
        if as_json:
            console.print_json(report.as_json())
            return 0
        console.warn(report.warnings, quiet)
        if not quiet:
            s = report.stats
            title = (f"preview {s['size'][0]}x{s['size'][1]}, {s['frames']} frame(s), {s['triangles']:,} triangles "
                     f"({s['instances']} instance(s)), {s['seconds_per_render'] * 1000:.0f} ms per render on {s['renderer']}")
            table = Table(title=title)
            for col in ("method", "tree coverage", "mean tree luminance", "rel. RMS vs reference"):
                table.add_column(col, justify="left" if col == "method" else "right")
            for name, m in s["per_method"].items():
                rms = m.get("rel_rms_vs_reference")
                table.add_row(name, f"{m['tree_coverage']:.1%}", f"{m['mean_tree_luminance']:.4g}", "" if rms is None else f"{rms:.3f}")
            console.print_table(table)
            sun_info = s["sun"]
            console.stdout.print(f"sun from {sun_info['source']}: azimuth {sun_info['azimuth']:.1f}°, elevation {sun_info['elevation']:.1f}°", highlight=False)
            outs = report.outputs
            shown = outs if len(outs) <= 3 else [outs[0], "...", outs[-1]]
            for o in shown:
                console.stdout.print(f"wrote {o}", highlight=False)
        return 0

    run(body)

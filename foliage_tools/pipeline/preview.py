"""``foliage preview``: read a scene, render it with the previewer, write PNG or EXR images.

Methods differ only in the scattered light added to the leaves; every method
draws the same direct term (shadow-mapped sun, sky, ground bounce):

| method | scattered irradiance E_scattered read from the leaf meshes | written by |
|---|---|---|
| ``direct`` | none | -- |
| ``lb`` | relit per instance for the current sun from the ``lbBase01..18`` grids of a ``--bases all`` bake (steele2010 sec. 3.1, ``pipeline.baked_light.load_lb_bases``); else ``primvars:foliage:lb:scattered`` (uniform) or ``primvars:foliage:lbIndirect`` (vertex), the baked sun only | ``foliage lb`` |
| ``spp`` | ``primvars:foliage:spp:scattered`` (uniform) or ``primvars:foliage:sppIrradiance`` (vertex) | ``foliage spp`` |
| ``smax`` | evaluated in the vertex shader (boulanger2008 Algorithms 8-14) from ``primvars:foliage:smax`` (uniform, elementSize 8) and the tree's ``foliage:tau``, for the current sun | ``foliage smax`` |
| ``reference`` | ``primvars:foliage:ref:scattered`` (uniform) | ``foliage reference`` |

Output (DESIGN.md section 3): ``.png`` is tone-mapped (Reinhard) and
sRGB-encoded over the sky colour, exposed for the light like an incident-light
meter (an 18 % grey horizontal surface lit by the sun and sky is mid-grey; see
:func:`foliage_tools.preview.exposure.choose_exposure`); ``.exr`` is linear radiance with alpha =
coverage, premultiplied (no sky). A sequence (``frames``) writes
``IMG.0001.png`` ... all or none, with one exposure for all frames.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from foliage_tools.errors import InputError, OutputError, UsageError
from foliage_tools.pipeline.baked_light import baked_sun_mismatches, load_lb_bases, load_method_data, load_smax_data
from foliage_tools.pipeline.report import Progress, Report, Silent
from foliage_tools.geometry.sun import DEFAULT_SUN, angles_from_direction, direction_from_angles, parse_sun  # noqa: F401  (parse_sun re-exported)
from foliage_tools.preview.camera import Camera, camera_from_usd, orbit_camera, usd_camera_size
from foliage_tools.preview.compare import rel_rms
from foliage_tools.preview.exposure import choose_exposure, compose, exposure_source
from foliage_tools.preview.lod import LodParams, apply_lod
from foliage_tools.preview.optics import SurfaceOptics
from foliage_tools.preview.renderer import MAX_SKY_SAMPLES, SAMPLES, DrawScene, Frame, Ground, Lighting, Renderer
from foliage_tools.preview.tonemap import Exposure, luminance
from foliage_tools.scene.model import Scene
from foliage_tools.pipeline.stats import PreviewStats

METHODS = ("direct", "lb", "spp", "smax", "reference")
"""DESIGN.md section 3: azimuth, elevation (degrees) when the stage has no sun and no ``--sun``."""
DEFAULT_SKY_RADIANCE = (0.033, 0.042, 0.055)
"""Sky radiance when the stage has no dome light: a blue sky whose irradiance on a
horizontal surface (π L) is about 0.13, 15 % of the default sun's (sin 60° = 0.87)."""
DEFAULT_SIZE = (1024, 1024)
DEFAULT_SEQUENCE_FRAMES = 36


# -- parameters ------------------------------------------------------------------------


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H); a :class:`UsageError` naming the flag otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text or "")
    if not m:
        raise UsageError(f"--size must be WIDTHxHEIGHT in pixels, e.g. 1024x768; got {text!r}.")
    w, h = int(m.group(1)), int(m.group(2))
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise UsageError(f"--size must be between 1x1 and 16384x16384 pixels, got {w}x{h}.")
    return w, h


def parse_methods(text: str) -> tuple[str, ...]:
    """``"direct,lb"`` -> ("direct", "lb"), each a known method, no repeats."""
    names = tuple(n.strip() for n in (text or "").split(",") if n.strip())
    if not names:
        raise UsageError(f"--compare needs a comma-separated list of methods ({', '.join(METHODS)}); got {text!r}.")
    bad = [n for n in names if n not in METHODS]
    if bad:
        raise UsageError(f"--compare: unknown method(s) {', '.join(bad)}; choose from {', '.join(METHODS)}.")
    if len(set(names)) != len(names):
        raise UsageError(f"--compare lists a method twice: {text!r}.")
    return names


@dataclass(frozen=True)
class PreviewParams:
    """What ``foliage preview`` draws and how. Angles in degrees (DESIGN.md convention)."""

    method: str = "direct"
    """Method whose scattered light is added to the leaves (module table)."""
    compare: tuple[str, ...] = ()
    """Methods to show side by side in one labelled image; overrides ``method``."""
    error_image: bool = False
    """Add a row of false-colour relative luminance error against ``reference``."""
    size: tuple[int, int] | None = None
    """(width, height) pixels; default 1024×1024, or 1024 wide with the aperture's aspect for ``camera``."""
    camera: str | None = None
    """Prim path of a ``UsdGeom.Camera`` in the stage; exclusive with the orbit options."""
    azimuth: float | None = None
    """Orbit camera azimuth [default 0, on the +X side]."""
    elevation: float | None = None
    """Orbit camera elevation [default 15]."""
    distance: float | None = None
    """Orbit camera distance from the centre of the bounds, stage units [default: fit the bounds]."""
    fov: float = 35.0
    """Vertical field of view of the orbit camera."""
    sun: tuple[float, float] | None = None
    """(azimuth, elevation) of the sun; default the stage's DistantLight, else DEFAULT_SUN."""
    ground: bool = True
    """Draw a ground plane under the tree(s), receiving their shadow."""
    frames: int | None = None
    """Frames of a sequence (``orbit`` and/or ``sun_sweep``); default DEFAULT_SEQUENCE_FRAMES."""
    orbit: bool = False
    """Turn the camera once around the up axis over the sequence."""
    sun_sweep: bool = False
    """Turn the sun once around the up axis over the sequence, at its elevation."""
    samples: int = 4
    """Samples per pixel, a k×k supersampling grid: 1, 4, 9 or 16."""
    shadow_size: int = 2048
    """Shadow-map resolution, texels per side."""
    sky_samples: int = 16
    """Sky directions tested for occlusion by the trees (0: the sky reaches everything)."""
    lod: float | None = None
    """Level of detail (:mod:`foliage_tools.preview.lod`): keep this fraction of the wood triangles,
    and of the leaves of far instances (area-compensated); None: full detail."""
    optics: SurfaceOptics = field(default_factory=SurfaceOptics)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise UsageError(f"--method must be one of {', '.join(METHODS)}, got {self.method!r}.")
        if self.compare and self.method != "direct":
            raise UsageError("--method and --compare cannot be combined; list every method in --compare.")
        if self.size is not None:
            w, h = self.size
            if not (isinstance(w, int) and isinstance(h, int) and 1 <= w <= 16384 and 1 <= h <= 16384):
                raise UsageError(f"--size must be between 1x1 and 16384x16384 pixels, got {w}x{h}.")
        orbit_flags = [n for n, v in (("--azimuth", self.azimuth), ("--elevation", self.elevation), ("--distance", self.distance)) if v is not None]
        if self.orbit:
            orbit_flags.append("--orbit")
        if self.camera is not None and orbit_flags:
            raise UsageError(f"--camera cannot be combined with {', '.join(orbit_flags)}: those place the orbit camera.")
        if self.elevation is not None and not (-90.0 <= self.elevation <= 90.0):
            raise UsageError(f"--elevation must be between -90 and 90 degrees, got {self.elevation:g}.")
        if self.azimuth is not None and not math.isfinite(self.azimuth):
            raise UsageError(f"--azimuth must be a finite number of degrees, got {self.azimuth}.")
        if self.distance is not None and not (math.isfinite(self.distance) and self.distance > 0):
            raise UsageError(f"--distance must be a positive number of stage units, got {self.distance:g}.")
        if not (1.0 <= self.fov <= 170.0):
            raise UsageError(f"--fov must be between 1 and 170 degrees, got {self.fov:g}.")
        if self.frames is not None:
            if not self.orbit and not self.sun_sweep:
                raise UsageError("--frames needs --orbit and/or --sun-sweep: it sets the length of a sequence.")
            if not (1 <= self.frames <= 10000):
                raise UsageError(f"--frames must be between 1 and 10000, got {self.frames}.")
        if self.samples not in SAMPLES:
            raise UsageError(f"--samples must be one of {', '.join(map(str, SAMPLES))}, got {self.samples}.")
        if not (256 <= self.shadow_size <= 8192):
            raise UsageError(f"--shadow-size must be between 256 and 8192 texels, got {self.shadow_size}.")
        if not (0 <= self.sky_samples <= MAX_SKY_SAMPLES):
            raise UsageError(f"--sky-samples must be between 0 and {MAX_SKY_SAMPLES}, got {self.sky_samples}.")
        if self.lod is not None:
            LodParams(self.lod)  # validates

    @property
    def methods(self) -> tuple[str, ...]:
        """Methods to render: the comparison, or the one method; plus ``reference`` for the error row."""
        names = self.compare or (self.method,)
        if self.error_image and "reference" not in names:
            names = (*names, "reference")
        return names

    @property
    def sequence(self) -> bool:
        return self.orbit or self.sun_sweep

    @property
    def frame_count(self) -> int:
        return (self.frames or DEFAULT_SEQUENCE_FRAMES) if self.sequence else 1


@dataclass(frozen=True)
class SunAndSky:
    lighting: Lighting
    azimuth: float
    elevation: float
    source: str
    sky_source: str


def choose_lighting(scene: Scene, sun: tuple[float, float] | None, warnings: list[str]) -> SunAndSky:
    """Sun and sky from the flag, else the stage's lights, else the DESIGN.md default sun and a default sky."""
    distant = [light for light in scene.lights if light.kind == "distant"]
    domes = [light for light in scene.lights if light.kind == "dome"]
    if sun is not None:
        az, el = sun
        direction, irradiance, source = direction_from_angles(az, el, scene.up_axis), (1.0, 1.0, 1.0), "--sun"
    elif distant:
        if len(distant) > 1:
            warnings.append(f"{scene.path}: {len(distant)} distant lights; the preview uses <{distant[0].path}> as the sun.")
        direction = np.asarray(distant[0].direction, dtype=np.float64)
        # DESIGN.md section 3: the sun delivers irradiance 1; its colour tints it
        irradiance, source = cast("tuple[float, float, float]", tuple(float(c) for c in distant[0].color)), f"<{distant[0].path}>"
        az, el = angles_from_direction(direction, scene.up_axis)
    else:
        az, el = DEFAULT_SUN
        direction, irradiance, source = direction_from_angles(az, el, scene.up_axis), (1.0, 1.0, 1.0), "default"
    if domes:
        # a dome light's intensity × colour is the sky's radiance (UsdLux)
        sky = cast("tuple[float, float, float]", tuple(float(domes[0].intensity * c) for c in domes[0].color))
        sky_source = f"<{domes[0].path}>"
    else:
        sky, sky_source = DEFAULT_SKY_RADIANCE, "default"
    return SunAndSky(Lighting(direction, irradiance, sky), az, el, source, sky_source)


# -- output ----------------------------------------------------------------------------


def frame_paths(out: Path, count: int, sequence: bool) -> list[Path]:
    if not sequence:
        return [out]
    return [out.with_name(f"{out.stem}.{i:04d}{out.suffix}") for i in range(1, count + 1)]


# -- the stage -------------------------------------------------------------------------


def run_preview(path: Path, out: Path, params: PreviewParams, *, progress: Progress | None = None) -> Report[PreviewStats]:
    """Render ``path`` and write ``out`` (or a numbered sequence beside it). Returns the report."""
    from foliage_tools.scene.image import image_format, image_sequence
    from foliage_tools.scene.read import read_scene

    progress = progress or Silent()
    report: Report[PreviewStats] = Report(command="preview", inputs=[str(path)])
    fmt = image_format(out)
    from foliage_tools.scene.atomic import refuse_link_loop

    refuse_link_loop(Path(out))  # before resolving it
    if Path(out).resolve() == Path(path).resolve():
        raise OutputError(f"@{out}@ is the input file; give another output path.")
    paths = frame_paths(Path(out), params.frame_count, params.sequence)
    from foliage_tools.pipeline.stage import require_consistent_input
    from foliage_tools.scene.atomic import recover

    if Path(out).parent.is_dir():  # what killed runs left for these images: finished or removed
        recover(Path(out).parent, [p.name for p in paths], report.warnings)
    require_consistent_input(Path(path))  # a layer and a grid from different runs would be drawn as one bake

    progress.step(f"reading {path}")
    scene, warnings = read_scene(path)
    report.warnings.extend(warnings)
    if not scene.prototypes or not scene.instances or not any(len(m.triangles) for p in scene.prototypes for m in p.meshes):
        raise InputError(f"@{path}@ has no mesh geometry to preview; is it a tree asset?")
    methods = params.methods
    lb_bases = load_lb_bases(Path(path), scene, report.warnings) if "lb" in methods else {}
    # relightable lb bases serve the trees they cover even where the leaves carry no lb primvars
    # (native-instance prototypes cannot); only without bases are the primvars required
    data = load_method_data(Path(path), scene, tuple(m for m in methods if not (m == "lb" and lb_bases)), report.warnings)
    if lb_bases:
        uncovered = [m.path for p in scene.prototypes for m in p.meshes if m.is_leaf and len(m.triangles) and m.path not in lb_bases]
        if uncovered:
            report.warnings.append(f"{path}: {len(uncovered)} leaf mesh(es) have no LB bases (e.g. <{uncovered[0]}>); "
                                   "their lb light is drawn as 0.")
    smax = load_smax_data(Path(path), scene) if "smax" in methods else None
    if smax is not None:
        unbaked = [m.path for p in scene.prototypes if p.path not in smax for m in p.meshes if m.is_leaf]
        partial = [m.path for p in scene.prototypes if p.path in smax for m in p.meshes if m.is_leaf and m.path not in smax[p.path][1]]
        if unbaked or partial:
            report.warnings.append(
                f"{path}: {len(unbaked) + len(partial)} leaf mesh(es) have no s_max (e.g. <{(unbaked + partial)[0]}>); "
                "the smax method draws their tree without scattered light."
            )
    if "lb" in methods and not lb_bases and params.sun_sweep:
        report.warnings.append(f"{path}: the lb bake has no relighting bases (it was baked with --bases sun), so --sun-sweep "
                               "frames show the baked sun's lb light; bake with `foliage lb --bases all` to relight.")
    draw = DrawScene.from_scene(scene, data, smax, lb_bases)
    bounds = draw.bounds()
    up = scene.up
    ground = Ground.under(bounds, up) if params.ground else None
    clip_bounds = bounds if ground is None else np.stack([np.minimum(bounds[0], ground.bounds(up)[0]), np.maximum(bounds[1], ground.bounds(up)[1])])
    light = choose_lighting(scene, params.sun, report.warnings)
    from_primvars = tuple(m for m in methods if m in ("spp", "reference") or (m == "lb" and not lb_bases))
    report.warnings.extend(baked_sun_mismatches(Path(path), scene, from_primvars, light.lighting.sun_direction))

    usd_cam = None
    if params.camera is not None:
        from foliage_tools.scene.camera_read import read_camera

        usd_cam = read_camera(path, params.camera)
        size = params.size or usd_camera_size(usd_cam.horizontal_aperture, usd_cam.vertical_aperture, DEFAULT_SIZE[0])
    else:
        size = params.size or DEFAULT_SIZE
    width, height = size
    cam_az = 0.0 if params.azimuth is None else params.azimuth
    cam_el = 15.0 if params.elevation is None else params.elevation

    def camera_for(i: int) -> Camera:
        if usd_cam is not None:
            return camera_from_usd(
                transform=usd_cam.transform, projection=usd_cam.projection, focal_length=usd_cam.focal_length,
                horizontal_aperture=usd_cam.horizontal_aperture, vertical_aperture=usd_cam.vertical_aperture,
                horizontal_aperture_offset=usd_cam.horizontal_aperture_offset, vertical_aperture_offset=usd_cam.vertical_aperture_offset,
                clipping_range=usd_cam.clipping_range, width=width, height=height, name=f"@{path}@ <{usd_cam.path}>",
            )
        az = cam_az + (360.0 * i / params.frame_count if params.orbit else 0.0)
        return orbit_camera(
            bounds, width=width, height=height, up_axis=scene.up_axis, azimuth=az, elevation=cam_el,
            distance=params.distance, fovy=params.fov, clip_bounds=clip_bounds,
        )

    def lighting_for(i: int) -> Lighting:
        if not params.sun_sweep:
            return light.lighting
        az = light.azimuth + 360.0 * i / params.frame_count
        return Lighting(direction_from_angles(az, light.elevation, scene.up_axis), light.lighting.sun_irradiance, light.lighting.sky_radiance)

    full_triangles = draw.triangle_count
    if params.lod is not None:
        # the split between near and far instances is made for the first frame's camera
        draw = apply_lod(draw, camera_for(0).position, LodParams(params.lod))
    comparison = bool(params.compare) or params.error_image
    frame_seconds: list[float] = []
    method_stats: dict[str, dict] = {}
    exposure: Exposure | None = None
    progress.step(f"rendering {len(paths)} frame(s) of {', '.join(methods)} at {width}x{height}", total=len(paths))
    with Renderer(draw, samples=params.samples, shadow_size=params.shadow_size, sky_samples=params.sky_samples) as renderer, image_sequence(paths) as write:
        for i, target in enumerate(paths):
            cam, lighting = camera_for(i), lighting_for(i)
            frames = {}
            for m in methods:
                frames[m] = renderer.render(cam, lighting, params.optics, method=None if m == "direct" else m, ground=ground)
                frame_seconds.append(frames[m].seconds)
            if exposure is None:
                _, f0 = exposure_source(frames)
                exposure, exposure_mode = choose_exposure(f0, lighting, up)
            if i == 0:
                method_stats = _method_stats(frames)
            write(target, compose(frames, exposure, fmt, error_image=params.error_image, comparison=comparison))
            progress.advance()
        renderer_name = renderer.renderer_name
        samples = renderer.samples
    assert exposure is not None  # chosen on the first frame
    report.outputs = [str(p) for p in paths]
    report.stats = {
        "methods": list(methods),
        "format": fmt,
        "size": [width, height],
        "frames": len(paths),
        "samples": samples,
        "shadow_size": params.shadow_size,
        "sky_samples": params.sky_samples,
        "renderer": renderer_name,
        "triangles": draw.triangle_count,
        "lod": None if params.lod is None else {"fraction": params.lod, "triangles_full_detail": full_triangles},
        "instances": draw.instance_count,
        "bounds": bounds.tolist(),
        "camera": {"source": params.camera or "orbit", "azimuth": None if usd_cam else cam_az, "elevation": None if usd_cam else cam_el,
                   "position": camera_for(0).position.tolist()},
        "sun": {"azimuth": light.azimuth, "elevation": light.elevation, "direction": np.asarray(light.lighting.sun_direction).tolist(),
                "source": light.source, "sweep": params.sun_sweep},
        "sky": {"radiance": list(light.lighting.sky_radiance), "source": light.sky_source},
        "ground": params.ground,
        "exposure": {"log_average": exposure.log_average, "white": exposure.white, "key": exposure.key, "mode": exposure_mode},
        "seconds_per_render": float(np.median(frame_seconds)),
        "per_method": method_stats,
    }
    return report.finish()


def _method_stats(frames: dict[str, Frame]) -> dict[str, dict]:
    stats = {}
    ref = frames.get("reference")
    for name, f in frames.items():
        # pixels fully on the tree: edge pixels mix in the background and depend on antialiasing
        inside = f.tree > 0.999 if np.any(f.tree > 0.999) else f.tree > 0.5
        s = {
            "tree_coverage": float(f.tree.mean()),
            "mean_tree_luminance": float(luminance(f.radiance)[inside].mean()) if inside.any() else 0.0,
            "seconds": f.seconds,
        }
        if ref is not None and name != "reference":
            s["rel_rms_vs_reference"] = rel_rms(f.radiance, ref.radiance, ref.tree)
        stats[name] = s
    return stats

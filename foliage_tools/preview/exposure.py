"""The pictures ``foliage preview`` writes: the exposure (metered from the light) and the composed panels."""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.preview.compare import false_colour, relative_error, side_by_side
from foliage_tools.preview.draw_model import Frame, Lighting
from foliage_tools.preview.tonemap import REC709_LUMINANCE, Exposure, measure_exposure, photographic_exposure, reinhard, srgb_encode

def exposure_source(frames: dict[str, Frame]) -> tuple[str, Frame]:
    name = "reference" if "reference" in frames else next(iter(frames))
    return name, frames[name]


def _over_sky(frame: Frame) -> np.ndarray:
    """Linear radiance of the picture over the sky colour."""
    return frame.radiance + (1.0 - frame.alpha)[..., None] * np.asarray(frame.sky, np.float32)


def horizontal_illuminance(lighting: Lighting, up: np.ndarray) -> float:
    """Luminance-weighted irradiance of an unshadowed horizontal surface: E_sun max(ω_sun·up, 0) + π L_sky."""
    sun = np.asarray(lighting.sun_direction, dtype=np.float64)
    cos = max(float(sun @ np.asarray(up, dtype=np.float64)) / float(np.linalg.norm(sun)), 0.0)
    sun_lum = float(np.asarray(lighting.sun_irradiance) @ REC709_LUMINANCE)
    sky_lum = float(np.asarray(lighting.sky_radiance) @ REC709_LUMINANCE)
    return sun_lum * cos + math.pi * sky_lum


def choose_exposure(frame: Frame, lighting: Lighting, up: np.ndarray) -> tuple[Exposure, str]:
    """The PNG exposure: metered from the light (:func:`photographic_exposure`), else keyed on the whole picture.

    Returns (exposure, ``"photographic"`` or ``"frame"``). The picture is the
    fallback only when neither sun nor sky lights a horizontal surface (sun
    below the horizon and a black sky); it is then keyed on every pixel over
    the sky, not on the tree alone.
    """
    picture = _over_sky(frame)
    exposure = photographic_exposure(horizontal_illuminance(lighting, up), white_rgb=picture)
    if exposure is not None:
        return exposure, "photographic"
    return measure_exposure(picture, white_rgb=picture), "frame"


def _display(frame: Frame, exposure: Exposure) -> np.ndarray:
    """Tone-mapped, display-linear RGB over the sky."""
    return reinhard(_over_sky(frame), exposure)


def compose(frames: dict[str, Frame], exposure: Exposure, fmt: str, *, error_image: bool, comparison: bool) -> np.ndarray:
    """The pixels to write for one frame: (H, W, C) float32, display-encoded for PNG, linear for EXR."""
    if not comparison:
        frame = next(iter(frames.values()))
        if fmt == "exr":
            return np.concatenate([frame.radiance, frame.alpha[..., None]], axis=2)
        return srgb_encode(_display(frame, exposure))
    if fmt == "exr":
        panels = [_over_sky(frames[n]) for n in frames]
    else:
        panels = [_display(frames[n], exposure) for n in frames]
    rows, labels = [panels], [list(frames)]
    if error_image:
        ref = frames["reference"]
        errs, names = [], []  # one error panel per non-reference method
        for n, f in frames.items():
            if n == "reference":
                continue
            errs.append(false_colour(relative_error(f.radiance, ref.radiance, ref.tree)))
            names.append(f"{n} vs reference (blue -50% .. red +50%)")
        if errs:
            rows.append(errs)
            labels.append(names)
    # labels are white: 1.0 is display white, and a bright radiance for EXR
    image = side_by_side(rows, labels, ink=1.0)
    return srgb_encode(image) if fmt == "png" else image

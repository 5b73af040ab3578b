"""Reinhard et al. (2002) photographic tone reproduction, the operator geist2008 (sec. 4) uses.

Radiance images are linear RGB (Rec. 709 primaries). Tone mapping works on
luminance and scales RGB by the same factor, so hues are kept:

    L̄   = exp(mean(log(δ + L_w)))                  log-average luminance  (Reinhard eq. 1)
    L    = (a / L̄) L_w                              scaled to the key a      (eq. 2)
    L_d  = L (1 + L / L_white²) / (1 + L)           burn out above L_white  (eq. 4)

``L_white`` is the smallest scaled luminance mapped to 1 (eq. 4); taking it
at a high percentile rather than the maximum keeps one glossy pixel from
setting the exposure of the whole image.

An :class:`Exposure` (L̄ and L_white) is measured once and can be reused, so a
sequence of frames, or the panels of a comparison, share one exposure and
differences between them stay visible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

REC709_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Relative luminance weights of linear Rec. 709 RGB."""


def luminance(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB -> (...) relative luminance."""
    return np.asarray(rgb, dtype=np.float64)[..., :3] @ REC709_LUMINANCE


@dataclass(frozen=True)
class Exposure:
    """The image statistics the operator needs: measure once, apply to many images."""

    log_average: float
    """L̄ of Reinhard eq. (1), > 0."""
    white: float
    """L_white of eq. (4) in *scaled* luminance units, > 0 (``inf`` for eq. 3, no burn-out)."""
    key: float = 0.18
    """a of eq. (2): 0.18 is Reinhard's "middle grey"."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.log_average) and self.log_average > 0):
            raise ValueError(f"log-average luminance must be positive and finite, got {self.log_average}")
        if not self.white > 0:
            raise ValueError(f"L_white must be positive, got {self.white}")
        if not (math.isfinite(self.key) and self.key > 0):
            raise ValueError(f"key must be positive and finite, got {self.key}")


def measure_exposure(
    rgb: np.ndarray,
    mask: np.ndarray | None = None,
    *,
    white_rgb: np.ndarray | None = None,
    key: float = 0.18,
    white_percentile: float = 99.5,
    delta: float = 1e-6,
) -> Exposure:
    """Reinhard's L̄ (eq. 1) over the pixels where ``mask`` > 0.5 (all pixels without a mask), and L_white.

    L_white is the ``white_percentile`` of the luminance of ``white_rgb``
    (default: the same masked pixels). Measuring L̄ on the subject (the tree)
    and L_white on the whole picture (ground and sky too) exposes the tree at
    the key while keeping brighter surroundings from burning out to white.
    An image with no (masked) light gets L̄ = δ and L_white = 1: tone mapping
    then leaves black black instead of dividing by zero.
    """
    lum = luminance(rgb)
    if mask is not None:
        lum = lum[np.asarray(mask) > 0.5]
    lum = lum[np.isfinite(lum)]
    if lum.size == 0 or float(lum.max()) <= 0.0:
        return Exposure(log_average=delta, white=1.0, key=key)
    log_average = float(np.exp(np.mean(np.log(delta + np.maximum(lum, 0.0)))))
    if white_rgb is not None:
        wl = luminance(white_rgb).ravel()
        wl = wl[np.isfinite(wl)]
        lum = np.concatenate([lum, wl])
    white = float(np.percentile(lum, white_percentile)) * key / log_average
    return Exposure(log_average=log_average, white=max(white, 1e-6), key=key)


def photographic_exposure(
    illuminance: float,
    *,
    white_rgb: np.ndarray | None = None,
    key: float = 0.18,
    white_percentile: float = 99.5,
) -> Exposure | None:
    """A fixed exposure set by the light, not by the picture: mid-grey is the key.

    ``illuminance`` is the luminance-weighted irradiance E of a horizontal surface
    (sun and sky). A horizontal Lambertian surface of reflectance ``key`` (18 %
    grey) then has radiance L_mid = key E / π, and L̄ = L_mid maps it to the key a
    in Reinhard eq. (2), like an incident-light meter: the exposure does not
    depend on what is in the frame, so a dark crown over a bright ground keeps
    both their brightness (keying on the tree exposed the crown at mid-grey
    and burnt the ground and sky out to white), methods and frames compare as
    they are, and a sun sweep darkens as the sun sets.

    L_white (eq. 4) is the ``white_percentile`` of ``white_rgb``'s scaled
    luminance, but at least 1, the scaled luminance of a white (ρ = 1)
    horizontal surface (E/π times a/L̄ = π/E): only what is brighter than white
    paper in full light burns out. Returns None when ``illuminance`` is not positive (no light to
    meter: the caller measures the picture instead).
    """
    if not (math.isfinite(illuminance) and illuminance > 0.0):
        return None
    log_average = key * illuminance / math.pi
    white = 1.0
    if white_rgb is not None:
        wl = luminance(white_rgb).ravel()
        wl = wl[np.isfinite(wl)]
        if wl.size:
            white = max(white, float(np.percentile(wl, white_percentile)) * key / log_average)
    return Exposure(log_average=log_average, white=white, key=key)


def reinhard(rgb: np.ndarray, exposure: Exposure) -> np.ndarray:
    """Tone-map linear RGB (H, W, 3) to display-linear RGB in [0, 1] (float32).

    For a fixed exposure the displayed luminance L_d is monotonic in the input
    luminance (eq. 4 is increasing), but a single channel can darken when the
    others brighten (the common scale L_d / L_w falls as L_w rises): compare
    methods on linear radiance, not on tone-mapped pixels.
    """
    rgb = np.asarray(rgb, dtype=np.float64)[..., :3]
    lw = np.maximum(luminance(rgb), 0.0)
    scaled = exposure.key / exposure.log_average * lw  # eq. (2)
    inv_white2 = 0.0 if math.isinf(exposure.white) else 1.0 / exposure.white**2
    ld = scaled * (1.0 + scaled * inv_white2) / (1.0 + scaled)  # eq. (4)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lw > 0.0, ld / lw, 0.0)
    return np.clip(rgb * ratio[..., None], 0.0, 1.0).astype(np.float32)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Display-linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1 transfer function)."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(np.float32)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode`."""
    x = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4)).astype(np.float32)

"""Leaf and wood optical properties shared by every method (DESIGN.md section 3, ``--leaf-optics``).

Leaves are two-sided Lambertian scatterers with per-channel (RGB) hemispherical
reflectance r and transmittance t; wood is opaque Lambertian with reflectance
``wood_reflectance``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

#: Named presets. ``geist2008``: Table 1 of geist2008, from Knapp & Carter
#: (1998): the backward-scatter column b_s is the leaf reflectance and the
#: forward-scatter column f_s the transmittance (eq. (10) then gives Table 1's
#: g = (-0.120, 0.091, -0.333)).
PRESETS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "geist2008": ((0.070, 0.125, 0.040), (0.055, 0.150, 0.020)),
    # a brighter, near-infrared-like leaf, useful to make multiple scattering visible in tests
    "bright": ((0.45, 0.45, 0.45), (0.45, 0.45, 0.45)),
}
DEFAULT_PRESET = "geist2008"
DEFAULT_WOOD_REFLECTANCE = 0.2


def _rgb(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape == (1,):
        arr = np.repeat(arr, 3)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr > 1):
        raise ValueError(f"{name} must be 1 or 3 numbers in [0, 1], got {value!r}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class LeafOptics:
    """Two-sided Lambertian leaf and opaque Lambertian wood, per RGB channel."""

    reflectance: np.ndarray
    """(3,) hemispherical reflectance of a leaf face, 0..1."""
    transmittance: np.ndarray
    """(3,) diffuse transmittance through a leaf, 0..1; r + t ≤ 1 per channel."""
    wood_reflectance: np.ndarray = DEFAULT_WOOD_REFLECTANCE  # type: ignore[assignment]  # a number in, (3,) after __post_init__
    """(3,) reflectance of bark, 0..1."""

    if TYPE_CHECKING:  # what the generated __init__ accepts: 1 or 3 numbers each, made (3,) arrays by __post_init__
        def __init__(self, reflectance: ArrayLike, transmittance: ArrayLike,
                     wood_reflectance: ArrayLike = DEFAULT_WOOD_REFLECTANCE) -> None: ...

    def __post_init__(self) -> None:
        r = _rgb(self.reflectance, "leaf reflectance")
        t = _rgb(self.transmittance, "leaf transmittance")
        w = _rgb(self.wood_reflectance, "wood reflectance")
        if np.any(r + t > 1.0 + 1e-12):
            raise ValueError(f"leaf reflectance + transmittance must be ≤ 1 per channel, got {r} + {t}")
        object.__setattr__(self, "reflectance", r)
        object.__setattr__(self, "transmittance", t)
        object.__setattr__(self, "wood_reflectance", w)

    @property
    def albedo(self) -> np.ndarray:
        """(3,) single-scattering albedo of a leaf, r + t."""
        return self.reflectance + self.transmittance

    @property
    def g(self) -> np.ndarray:
        """(3,) geist2008 eq. (10): g = (f_s − b_s)/(f_s + b_s) with f_s = t, b_s = r; 0 where r + t = 0."""
        s = self.albedo
        return np.divide(self.transmittance - self.reflectance, s, out=np.zeros(3), where=s > 0)

    def as_dict(self) -> dict:
        return {"reflectance": self.reflectance.tolist(), "transmittance": self.transmittance.tolist(), "wood_reflectance": self.wood_reflectance.tolist()}


def parse_leaf_optics(spec: str | None, *, wood_reflectance: float | None = None) -> LeafOptics:
    """``PRESET``, ``r,t`` or ``rR,rG,rB,tR,tG,tB`` (the ``--leaf-optics`` flag); ``None`` = the default preset."""
    wood = DEFAULT_WOOD_REFLECTANCE if wood_reflectance is None else wood_reflectance
    spec = DEFAULT_PRESET if spec is None else spec.strip()
    if spec.lower() in PRESETS:  # Bright, GEIST2008: a preset's name in any case
        r, t = PRESETS[spec.lower()]
        return LeafOptics(r, t, wood)
    try:
        values = [float(v) for v in spec.split(",")]
    except ValueError:
        raise ValueError(
            f"--leaf-optics {spec!r}: give a preset ({', '.join(PRESETS)}), 'r,t' or 'rR,rG,rB,tR,tG,tB'"
        ) from None
    if len(values) == 2:
        return LeafOptics(values[0], values[1], wood)
    if len(values) == 6:
        return LeafOptics(values[:3], values[3:], wood)
    raise ValueError(f"--leaf-optics {spec!r}: expected 2 or 6 numbers, got {len(values)}")

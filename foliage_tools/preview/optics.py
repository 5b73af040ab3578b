"""Surface optics the previewer shades with: two-sided leaves, opaque wood, the ground.

The preview's leaf, wood and ground material parameters. The leaf defaults
come from the project-wide preset in ``foliage_tools.lighting.optics`` (the
one the bakes use); the glossy lobe and the ground are preview-only.

All reflectances and transmittances are hemispherical (albedo-like) fractions
in [0, 1] per RGB channel; a Lambertian surface of reflectance ρ lit by
irradiance E has radiance ρ E / π.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from foliage_tools.errors import UsageError
from foliage_tools.lighting.optics import DEFAULT_PRESET, PRESETS

RGB = tuple[float, float, float]

# geist2008 Table 1 splits the leaf scattering into forward (fs) and backward
# (bs) parts using the per-channel transmittance and reflectance *ratios* of
# Knapp & Carter (1998); their magnitudes (about 0.05-0.15) are typical of
# measured green-leaf transmittance and reflectance, so the preview uses them
# directly: reflectance = bs, transmittance = fs.
KNAPP_CARTER_REFLECTANCE: RGB = PRESETS[DEFAULT_PRESET][0]
KNAPP_CARTER_TRANSMITTANCE: RGB = PRESETS[DEFAULT_PRESET][1]


def _check_rgb(name: str, value: RGB, *, upper: float = 1.0) -> None:
    if len(value) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= upper for v in value):
        raise UsageError(f"{name} must be three numbers in [0, {upper:g}], got {value!r}.")


@dataclass(frozen=True)
class LeafOptics:
    """Two-sided leaf material of boulanger2008 eq. (5.4) plus wang2005's glossy lobe.

    "Front" is the side the mesh's right-handed face normal points to.
    """

    reflectance_front: RGB = KNAPP_CARTER_REFLECTANCE
    """ρ_rf: diffuse reflectance of the front face (wang2005 sec. 3, ρ_d)."""
    reflectance_back: RGB = KNAPP_CARTER_REFLECTANCE
    """ρ_rb: diffuse reflectance of the back face. Equal to the front by default, as in
    the Monte Carlo reference's two-sided Lambertian leaves (DESIGN.md section 3)."""
    transmittance_front: RGB = KNAPP_CARTER_TRANSMITTANCE
    """ρ_tf: diffuse transmittance for light entering the front face (wang2005 sec. 3, ρ_t)."""
    transmittance_back: RGB = KNAPP_CARTER_TRANSMITTANCE
    """ρ_tb: diffuse transmittance for light entering the back face."""
    specular: float = 0.04
    """ρ_s of wang2005 eq. (7), the glossy intensity of both faces (Fresnel and
    shadowing folded in). 0 turns the glossy lobe off (pure two-sided Lambertian)."""
    roughness: float = 0.35
    """m of wang2005 eq. (7): RMS microfacet slope of the leaf surface (> 0)."""

    def __post_init__(self) -> None:
        for name in ("reflectance_front", "reflectance_back", "transmittance_front", "transmittance_back"):
            _check_rgb(f"leaf {name.replace('_', ' ')}", getattr(self, name))
        for r_name, t_name in (("reflectance_front", "transmittance_back"), ("reflectance_back", "transmittance_front")):
            r, t = getattr(self, r_name), getattr(self, t_name)
            if any(a + b > 1.0 + 1e-9 for a, b in zip(r, t)):
                raise UsageError(
                    f"leaf {r_name.replace('_', ' ')} {r} plus {t_name.replace('_', ' ')} {t} exceeds 1 in a channel: "
                    "a leaf cannot scatter more light than it receives."
                )
        if not (math.isfinite(self.specular) and 0.0 <= self.specular <= 1.0):
            raise UsageError(f"leaf specular intensity must be in [0, 1], got {self.specular}.")
        if not (math.isfinite(self.roughness) and 0.01 <= self.roughness <= 2.0):
            raise UsageError(f"leaf roughness must be in [0.01, 2], got {self.roughness}.")

    @classmethod
    def lambertian(cls, reflectance: RGB, transmittance: RGB) -> LeafOptics:
        """Both faces alike, no glossy lobe: the leaf model of the Monte Carlo reference."""
        return cls(reflectance, reflectance, transmittance, transmittance, specular=0.0)


@dataclass(frozen=True)
class SurfaceOptics:
    """Everything the preview shades: leaves, wood and the optional ground plane."""

    leaf: LeafOptics = field(default_factory=LeafOptics)
    wood_reflectance: RGB = (0.30, 0.22, 0.15)
    """Opaque Lambertian bark (the example trees' bark colour, darkened slightly)."""
    ground_reflectance: RGB = (0.12, 0.13, 0.08)
    """Lambertian ground: grass and soil, whose visible albedo is about 0.05-0.2."""

    def __post_init__(self) -> None:
        _check_rgb("wood reflectance", self.wood_reflectance)
        _check_rgb("ground reflectance", self.ground_reflectance)

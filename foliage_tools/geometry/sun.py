"""Sun directions: the DESIGN.md angle convention and the choice of sun for a bake.

``--sun AZ,EL``: degrees; azimuth counter-clockwise about the up axis from +X
(toward +Y in a Z-up stage, toward −Z in a Y-up stage), elevation above the
horizon; the sun lies in that direction from the tree. With no flag and no
``DistantLight`` in the stage, the sun is at azimuth 45°, elevation 60°.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from foliage_tools.errors import UsageError

DEFAULT_SUN = (45.0, 60.0)
UP_AXES = ("Y", "Z")


def horizon_frame(up_axis: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(azimuth 0°, azimuth 90°, up) unit vectors of a stage; the three form a right-handed frame."""
    if up_axis == "Z":
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    if up_axis == "Y":
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    raise UsageError(f"up axis must be one of {', '.join(UP_AXES)}, got {up_axis!r}.")


def direction_from_angles(azimuth: float, elevation: float, up_axis: str) -> np.ndarray:
    """(3,) unit vector toward the sun at ``azimuth``/``elevation`` degrees (module convention)."""
    x, y, up = horizon_frame(up_axis)
    az, el = math.radians(azimuth), math.radians(elevation)
    return math.cos(el) * (math.cos(az) * x + math.sin(az) * y) + math.sin(el) * up


def angles_from_direction(direction: np.ndarray, up_axis: str) -> tuple[float, float]:
    """Inverse of :func:`direction_from_angles`: (azimuth in [0, 360), elevation) in degrees."""
    x, y, up = horizon_frame(up_axis)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    el = math.degrees(math.asin(float(np.clip(d @ up, -1.0, 1.0))))
    az = math.degrees(math.atan2(float(d @ y), float(d @ x))) % 360.0
    return az, el


def parse_sun(text: str) -> tuple[float, float]:
    """``"AZ,EL"`` in degrees -> (azimuth, elevation); elevation in [−90, 90]."""
    parts = (text or "").split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        az, el = (float(p) for p in parts)
    except ValueError:
        raise UsageError(f"--sun must be AZIMUTH,ELEVATION in degrees, e.g. 45,60; got {text!r}.") from None
    if not (math.isfinite(az) and math.isfinite(el)):
        raise UsageError(f"--sun angles must be finite numbers, got {text!r}.")
    if not (-90.0 <= el <= 90.0):
        raise UsageError(f"--sun elevation must be between -90 and 90 degrees, got {el:g}.")
    return az % 360.0, el


@dataclass(frozen=True)
class Sun:
    direction: np.ndarray
    """(3,) world unit vector toward the sun."""
    azimuth: float
    elevation: float
    source: str
    """``--sun``, ``<light path>`` or ``default``."""


def choose_sun(lights, up_axis: str, flag: tuple[float, float] | None, warnings: list[str]) -> Sun:
    """The bake's sun: the flag, else the stage's first DistantLight, else the default (module doc)."""
    if flag is not None:
        az, el = flag
        return Sun(direction_from_angles(az, el, up_axis), az, el, "--sun")
    distant = [light for light in lights if light.kind == "distant"]
    if distant:
        if len(distant) > 1:
            warnings.append(f"{len(distant)} distant lights in the stage; <{distant[0].path}> is used as the sun.")
        d = np.asarray(distant[0].direction, dtype=np.float64)
        az, el = angles_from_direction(d, up_axis)
        return Sun(d / np.linalg.norm(d), az, el, f"<{distant[0].path}>")
    az, el = DEFAULT_SUN
    return Sun(direction_from_angles(az, el, up_axis), az, el, "default")


def to_prototype_space(direction: np.ndarray, world_from_proto: np.ndarray) -> np.ndarray:
    """A world direction expressed in a prototype's frame (inverse of the instance's linear part), normalised."""
    lin = np.asarray(world_from_proto, dtype=np.float64)[:3, :3]
    d = np.linalg.solve(lin, np.asarray(direction, dtype=np.float64))
    return d / np.linalg.norm(d)

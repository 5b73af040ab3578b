"""Parameters of the stages: frozen dataclasses, one docstring per field, checked at construction."""

from __future__ import annotations

import math
from dataclasses import dataclass

from foliage_tools.errors import UsageError

DENSITY_METHODS = ("area", "subgrid")
#: ``--resolution`` of the bake commands (density, smax, spp, lb, bake, plan): grid nodes along the longest edge of
#: each prototype's foliage bounds, by default and at most (the CLI's range; ``check_resolution``).
DEFAULT_RESOLUTION = 64
RESOLUTION_RANGE = (4, 512)
#: How ``foliage lb`` stores its grids on disk (``--grid-precision``, of lb and bake): ``float`` (float32) or
#: ``half`` (OpenVDB's saveFloatAsHalf, ``scene.vdb.Grid.half``: half the file, each value within 2^-11; README "LB storage").
GRID_PRECISIONS = ("float", "half")
#: Where ``foliage lb --bases all`` stores its relighting grids (``--base-extent``): ``leaves``, only the nodes
#: the relighting reads (the trilinear stencils of the leaves' corners and centres; steele2010 sec. 4.2 "we do not
#: store data that will not be accessed"), or ``lattice``, every node. README "LB storage".
BASE_EXTENTS = ("leaves", "lattice")


def check_resolution(value: int, option: str = "--resolution") -> None:
    """UsageError unless ``value`` is in ``RESOLUTION_RANGE`` (the one message every stage and the CLI give)."""
    lo, hi = RESOLUTION_RANGE
    if not (lo <= value <= hi):
        raise UsageError(f"{option} must be between {lo} and {hi}, got {value}.")


@dataclass(frozen=True)
class DensityParams:
    """How ``foliage density`` voxelizes each prototype's leaves."""

    voxel_size: float | None = None
    """Voxel edge length in stage units; exclusive with ``resolution``."""
    resolution: int | None = None
    """Voxels along the longest edge of the foliage bounds; exclusive with ``voxel_size``.
    When neither is given, ``DEFAULT_RESOLUTION``."""
    method: str = "area"
    """``area``: exact leaf area per voxel / voxel volume (leaf-area density, 1/stage unit);
    ``subgrid``: geist2008 sec. 4.2, fraction of the 27 sub-cells a leaf touches (0..1)."""
    margin_voxels: int = 1
    """Empty voxels added around the foliage bounds on every side."""
    volume_purpose: str = "default"
    """``--volume-purpose`` of the FoliageLighting volume written (``scene.write.VOLUME_PURPOSES``)."""

    def __post_init__(self) -> None:
        if self.voxel_size is not None and self.resolution is not None:
            raise UsageError("--voxel-size and --resolution cannot be combined; give one of them.")
        if self.voxel_size is not None and not (math.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise UsageError(f"--voxel-size must be a positive number, got {self.voxel_size}.")
        if self.resolution is not None and not (1 <= self.resolution <= 2048):
            raise UsageError(f"--resolution must be between 1 and 2048 voxels, got {self.resolution}.")
        if self.method not in DENSITY_METHODS:
            raise UsageError(f"--method must be one of {', '.join(DENSITY_METHODS)}, got {self.method!r}.")
        if self.volume_purpose not in ("default", "guide"):
            raise UsageError(f"--volume-purpose must be default or guide, got {self.volume_purpose!r}.")
        if self.margin_voxels < 0:
            raise UsageError(f"the margin must be >= 0 voxels, got {self.margin_voxels}.")

    def grid_options(self) -> dict:
        if self.voxel_size is None and self.resolution is None:
            return {"resolution": DEFAULT_RESOLUTION}
        return {"voxel_size": self.voxel_size} if self.voxel_size is not None else {"resolution": self.resolution}

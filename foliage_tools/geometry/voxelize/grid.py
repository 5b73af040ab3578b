"""The voxel grid: :class:`GridSpec`, :func:`grid_for_bounds`, and the nodes trilinear interpolation reads.

Voxel ``(i, j, k)`` of a grid is the cube ``[i, i+1] x [j, j+1] x [k, k+1]`` of
index space (package docstring, "Index space"); the kernels of ``clipping`` and
``subgrid`` take the grid as its origin, voxel size and shape.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np


def _vec3(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be 3 numbers, got {value!r}") from exc
    if arr.shape != (3,):
        raise ValueError(f"{name} must be 3 numbers (x, y, z), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {tuple(arr.tolist())}")
    return arr


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


@dataclass(frozen=True)
class GridSpec:
    """Axis-aligned voxel grid.

    Voxel ``(i, j, k)`` covers ``[origin + (i, j, k) * voxel_size, origin + (i+1, j+1, k+1) * voxel_size]``.

    Parameters
    ----------
    origin : tuple of 3 float
        World position (stage units) of the min corner of voxel ``(0, 0, 0)``.
        Stored as a tuple of Python floats; must be finite.
    voxel_size : float
        Voxel edge length, stage units, ``> 0`` and finite.
    shape : tuple of 3 int
        ``(nx, ny, nz)`` voxels along x, y, z, each ``>= 1``.

    Raises
    ------
    ValueError
        If any field is malformed (non-finite origin, non-positive voxel size,
        non-integer or < 1 shape entries).
    """

    origin: tuple[float, float, float]
    voxel_size: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        origin = _vec3(self.origin, "GridSpec.origin")
        h = self.voxel_size
        if not _is_real(h) or not math.isfinite(float(h)) or float(h) <= 0.0:
            raise ValueError(f"GridSpec.voxel_size must be a finite number > 0, got {h!r}")
        try:
            shape = tuple(self.shape)
        except TypeError as exc:
            raise ValueError(f"GridSpec.shape must be 3 integers (nx, ny, nz), got {self.shape!r}") from exc
        if len(shape) != 3 or not all(_is_int(n) for n in shape):
            raise ValueError(f"GridSpec.shape must be 3 integers (nx, ny, nz), got {self.shape!r}")
        if min(shape) < 1:
            raise ValueError(f"GridSpec.shape entries must be >= 1, got {tuple(int(n) for n in shape)}")
        object.__setattr__(self, "origin", tuple(float(x) for x in origin))
        object.__setattr__(self, "voxel_size", float(h))
        object.__setattr__(self, "shape", tuple(int(n) for n in shape))

    @property
    def voxel_volume(self) -> float:
        """Volume of one voxel, ``voxel_size ** 3`` (stage units cubed)."""
        return self.voxel_size**3

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: min corner and max corner of the whole grid, stage units (unpacks as ``lo, hi``)."""
        lo = np.asarray(self.origin, dtype=np.float64)
        return np.stack([lo, lo + np.asarray(self.shape, dtype=np.float64) * self.voxel_size])

    def index_to_world(self, ijk) -> np.ndarray:
        """World position of voxel centres.

        Parameters
        ----------
        ijk : array_like, shape (..., 3)
            Voxel indices (integers, or fractional index coordinates).

        Returns
        -------
        (..., 3) float64
            ``origin + (ijk + 0.5) * voxel_size``, stage units.
        """
        idx = np.asarray(ijk, dtype=np.float64)
        if idx.ndim == 0 or idx.shape[-1] != 3:
            raise ValueError(f"ijk must have shape (..., 3), got {idx.shape}")
        return np.asarray(self.origin) + (idx + 0.5) * self.voxel_size


def trilinear_stencil(shape, grid: GridSpec, points) -> tuple[np.ndarray, np.ndarray]:
    """Where trilinear interpolation of a node field (values at voxel centres) on ``shape`` reads at ``points``.

    Returns the (P, 3) lower corner node of each point's 2 x 2 x 2 stencil and its (P, 3) weights toward the upper
    nodes. Points outside the node lattice take the nearest boundary nodes (the stencil clamped to the lattice).
    """
    n = np.asarray(shape[:3], dtype=np.int64)
    x = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - np.asarray(grid.origin)) / grid.voxel_size - 0.5
    x = np.clip(x, 0.0, n - 1)
    i0 = np.minimum(np.floor(x).astype(np.int64), n - 2).clip(0)
    return i0, x - i0


def stencil_mask(shape, grid: GridSpec, points) -> np.ndarray:
    """(nx, ny, nz) bool: the nodes trilinear interpolation at ``points`` reads (``trilinear_stencil``)."""
    n = np.asarray(shape[:3], dtype=np.int64)
    i0, _ = trilinear_stencil(shape, grid, points)
    mask = np.zeros(tuple(int(v) for v in n), dtype=bool)
    for d in np.ndindex(2, 2, 2):
        ijk = np.minimum(i0 + np.asarray(d), n - 1)
        mask[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    return mask


def grid_for_bounds(lo, hi, *, voxel_size=None, resolution=None, margin_voxels=1) -> GridSpec:
    """Grid covering an axis-aligned box plus a margin of empty voxels.

    Parameters
    ----------
    lo, hi : array_like, shape (3,)
        Min and max corner of the geometry, stage units (``lo <= hi``, finite).
        Flat boxes (``lo[a] == hi[a]``) are allowed and get one voxel along that axis.
    voxel_size : float, optional
        Voxel edge length, stage units (``> 0``). Exclusive with ``resolution``.
    resolution : int, optional
        Number of voxels along the *longest* edge of ``[lo, hi]`` (``>= 1``);
        ``voxel_size = longest edge / resolution``. Exclusive with ``voxel_size``.
    margin_voxels : int, default 1
        Empty voxels added on every side (``>= 0``).

    Returns
    -------
    GridSpec
        ``shape[a] = n[a] + 2 * margin_voxels`` where ``n[a] = max(1, ceil((hi - lo)[a] / voxel_size))``
        (``n = resolution`` exactly along the longest edge). The ``n[a]`` core
        voxels are centred on ``[lo, hi]``, so a flat box lies in the middle of
        a voxel layer rather than on a voxel face.

    Raises
    ------
    ValueError
        If both or neither of ``voxel_size`` / ``resolution`` are given, either
        is non-positive, ``lo > hi`` on some axis, or ``resolution`` is given for
        a box that is a single point (no edge to divide).
    """
    lo_v = _vec3(lo, "lo")
    hi_v = _vec3(hi, "hi")
    if np.any(lo_v > hi_v):
        raise ValueError(f"lo must be <= hi on every axis, got lo={tuple(lo_v.tolist())}, hi={tuple(hi_v.tolist())}")
    if (voxel_size is None) == (resolution is None):
        raise ValueError("give exactly one of voxel_size= and resolution= (got both)" if voxel_size is not None
                         else "give exactly one of voxel_size= and resolution= (got neither)")
    if not _is_int(margin_voxels) or margin_voxels < 0:
        raise ValueError(f"margin_voxels must be an integer >= 0, got {margin_voxels!r}")
    margin = int(margin_voxels)
    extent = hi_v - lo_v
    if voxel_size is not None:
        if not _is_real(voxel_size) or not math.isfinite(float(voxel_size)) or float(voxel_size) <= 0.0:
            raise ValueError(f"voxel_size must be a finite number > 0 (resolution= is the alternative), got {voxel_size!r}")
        h = float(voxel_size)
        core = [max(1, math.ceil(e / h * (1.0 - 1e-12))) for e in extent]
    else:
        if not _is_int(resolution) or resolution < 1:
            raise ValueError(f"resolution must be an integer >= 1 (voxel_size= is the alternative), got {resolution!r}")
        longest = float(extent.max())
        if longest <= 0.0:
            raise ValueError(
                f"the bounds are a single point ({tuple(lo_v.tolist())}): resolution= cannot set a voxel size; give voxel_size="
            )
        h = longest / int(resolution)
        core = [int(resolution) if e == longest else max(1, math.ceil(e / h * (1.0 - 1e-12))) for e in extent]
    if not (math.isfinite(h) and h > 0.0):
        raise ValueError(f"the bounds give an unusable voxel size {h!r}")
    shape = tuple(n + 2 * margin for n in core)
    centre = 0.5 * (lo_v + hi_v)
    origin = centre - 0.5 * np.asarray(shape, dtype=np.float64) * h
    return GridSpec(origin=tuple(origin.tolist()), voxel_size=h, shape=shape)

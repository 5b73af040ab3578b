"""The 8 sample directions ω_j of boulanger2008 eq. (5.28), the frame they are written in, and their bins.

Every leaf stores s_max(P, ω_j) for these directions. The bin of a vector d
(the ω_j nearest to d) is its octant in the sample frame (``_octant``), for
the reference path (``reference.py``) and the near field (``near_field.py``)
alike.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit


#: Number of sample directions ω_j (boulanger2008 sec. 5.6: N_dir = 8).
N_DIRECTIONS = 8

#: Solid angle of one bin, Ω_j = 4π / N_dir (boulanger2008 eq. (5.1)).
BIN_SOLID_ANGLE = 4.0 * math.pi / N_DIRECTIONS


def _unit_up(up) -> np.ndarray:
    u = np.asarray(up, dtype=float)
    if u.shape != (3,) or not np.all(np.isfinite(u)):
        raise ValueError(f"the up axis must be a finite 3-vector, got {up!r}")
    n = float(np.linalg.norm(u))
    if n == 0.0:
        raise ValueError("the up axis must not be the zero vector")
    return u / n


@lru_cache(maxsize=16)
def _frame_cached(up: tuple[float, float, float]) -> np.ndarray:
    u = np.array(up)
    # paper x axis: world +X made perpendicular to up (world +Y if up is along X)
    ref = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - np.dot(ref, u) * u
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e1, u)  # right-handed (e1, up, e2) like the paper's (x, y, z)
    frame = np.stack([e1, u, e2])
    frame.setflags(write=False)
    return frame


def sample_frame(up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Orthonormal frame (rows e1, up, e2) in which eq. (5.28) is written.

    boulanger2008 uses a Y-up frame (eq. (5.29) tests ``ω_j · y > 0``). The
    paper's x axis is world +X made perpendicular to ``up`` (world +Y when
    ``up`` is along ±X), y is ``up`` and z = x × y, so for ``up = +Y`` the
    frame is the identity and for ``up = +Z`` it is (+X, +Z, -Y).

    Returns a read-only (3, 3) float64 array.
    """
    return _frame_cached(tuple(float(c) for c in _unit_up(up)))


@lru_cache(maxsize=16)
def _directions_cached(up: tuple[float, float, float]) -> np.ndarray:
    xi = math.sqrt(3.0) / 3.0
    # boulanger2008 eq. (5.28): ω_0..ω_3 given, ω_j = -ω_{7-j} for j = 4..7
    local = np.empty((N_DIRECTIONS, 3))
    local[0] = (-xi, -xi, -xi)
    local[1] = (xi, -xi, -xi)
    local[2] = (-xi, -xi, xi)
    local[3] = (xi, -xi, xi)
    for j in range(4, 8):
        local[j] = -local[7 - j]
    dirs = local @ _frame_cached(up)
    dirs.setflags(write=False)
    return dirs


def sample_directions(up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """The 8 sample directions ω_j of boulanger2008 eq. (5.28), in that order.

    Parameters
    ----------
    up : (3,) array_like
        The stage's up axis (any length > 0).

    Returns
    -------
    (8, 3) float64, read-only. Unit vectors; ω_0..ω_3 point below the horizon
    (component -1/√3 along ``up``), ω_4..ω_7 above it, ω_j = -ω_{7-j}. In the
    frame of :func:`sample_frame`, ω_j has signs (x, y, z) with
    j = [x > 0] + 2 [z > 0] + 4 [y > 0], so the bin of a vector d (the ω_j
    nearest to d) is its octant.
    """
    return _directions_cached(tuple(float(c) for c in _unit_up(up)))


@njit(cache=True, inline="always")
def _octant(dx: float, dy: float, dz: float) -> int:
    # bin = nearest ω_j of eq. (5.28) = octant in the sample frame (x=e1, y=up, z=e2)
    b = 0
    if dx > 0.0:
        b += 1
    if dz > 0.0:
        b += 2
    if dy > 0.0:
        b += 4
    return b

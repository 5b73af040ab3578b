"""The fast path's grid: origin, cell size h and node counts, and the cell of a point.

The near field's cell lists (``near_field.py``) and the far field's
cloud-in-cell deposits and interpolations (``far_field.py``) use these.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from foliage_tools.lighting.envelope.directions import BIN_SOLID_ANGLE
from foliage_tools.lighting.envelope.params import EnvelopeParams


#: The far field replaces -ln(1 - o) by o; it is used only where a typical leaf
#: (99th percentile of areas, mean projected area A/2) occludes at most this
#: much of a bin, i.e. beyond r_1 >= sqrt(A_99 / (2 Ω_j · 0.1)): there the two
#: differ by < 5.5%. Dense crowns of large leaves get a coarser grid.
_FAR_FIELD_MAX_OCCLUSION = 0.1


def _grid_for(x: np.ndarray, area: np.ndarray, params: EnvelopeParams) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """Origin, cell size h and node counts of the fast path's grid (nodes at origin + i h)."""
    lo = _axis_min(x)
    ext = _axis_max(x) - lo
    longest = float(ext.max())
    if longest == 0.0:
        longest = 1.0
    # bounding-box volume, with flat/linear crowns thickened to 1% of the longest edge
    vol = float(np.prod(np.maximum(ext, 0.01 * longest)))
    h = (vol * params.fast_leaves_per_cell / x.shape[0]) ** (1.0 / 3.0)
    cap = int(params.fast_max_cells)
    a99 = float(np.percentile(area, 99)) if area.size else 0.0
    h_linear = math.sqrt(a99 / (2.0 * BIN_SOLID_ANGLE * _FAR_FIELD_MAX_OCCLUSION)) / params.fast_blend_start_cells
    h = max(h, h_linear, longest / (cap - 2), longest * 1e-6)
    shape = tuple(math.floor(e / h) + 2 for e in ext)
    return lo, h, shape


@njit(cache=True)
def _cell_index(x, lo, h, shape):
    n = x.shape[0]
    cell = np.empty((n, 3), dtype=np.int64)
    lin = np.empty(n, dtype=np.int64)
    for i in range(n):
        for a in range(3):
            c = math.floor((x[i, a] - lo[a]) / h)
            c = max(c, 0)
            c = min(c, shape[a] - 2)
            cell[i, a] = c
        lin[i] = (cell[i, 0] * shape[1] + cell[i, 1]) * shape[2] + cell[i, 2]
    return cell, lin


@njit(cache=True)
def _cell(x, i, lo, h, shape):
    """Lower node and fractional offsets of point i for cloud-in-cell weights (clamped to the grid)."""
    u = (x[i, 0] - lo[0]) / h
    v = (x[i, 1] - lo[1]) / h
    w = (x[i, 2] - lo[2]) / h
    i0 = min(max(math.floor(u), 0), shape[0] - 2)
    j0 = min(max(math.floor(v), 0), shape[1] - 2)
    k0 = min(max(math.floor(w), 0), shape[2] - 2)
    return i0, j0, k0, u - i0, v - j0, w - k0



def _axis_min(x: np.ndarray) -> np.ndarray:
    # per column: ~20x faster than x.min(axis=0) on a C-ordered (L, 3) array
    return np.array([x[:, a].min() for a in range(x.shape[1])])


def _axis_max(x: np.ndarray) -> np.ndarray:
    return np.array([x[:, a].max() for a in range(x.shape[1])])


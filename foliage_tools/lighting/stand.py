"""The leaves of many placed instances on one coarse world grid, without placing them all in memory.

A forest of N instances of a prototype of L leaves has N x L placed leaves
(10 000 trees of 20 000 leaves: 2e8, 4.8 GB of centres). The forest lattice
(``pipeline.forest``, steele2010 sec. 3.2) needs two things from them, both
computed here leaf by leaf from the prototype's leaves and each instance's
transform:

* :func:`deposit`: the leaf-area density of the stand, each leaf's area
  (scaled by the instance, |det M|^(2/3)) added to the cell holding its
  centre, over the cell volume;
* :func:`instance_means`: per instance, the leaf-area-weighted mean of a node
  field (values at the cell centres) trilinearly interpolated at its leaves,

      <f>_n = sum_k A_k f(M_n x_k) / sum_k A_k.
"""

from __future__ import annotations

import numba
import numpy as np

from foliage_tools.geometry.voxelize import GridSpec


@numba.njit(cache=True)
def _deposit(transforms, centres, areas, lo, h, out):  # pragma: no cover - compiled
    nx, ny, nz = out.shape
    for n in range(transforms.shape[0]):
        m = transforms[n]
        det = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
               + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
        s2 = abs(det) ** (2.0 / 3.0)
        for k in range(centres.shape[0]):
            x = centres[k]
            p0 = m[0, 0] * x[0] + m[0, 1] * x[1] + m[0, 2] * x[2] + m[0, 3]
            p1 = m[1, 0] * x[0] + m[1, 1] * x[1] + m[1, 2] * x[2] + m[1, 3]
            p2 = m[2, 0] * x[0] + m[2, 1] * x[1] + m[2, 2] * x[2] + m[2, 3]
            i = min(max(int(np.floor((p0 - lo[0]) / h)), 0), nx - 1)
            j = min(max(int(np.floor((p1 - lo[1]) / h)), 0), ny - 1)
            q = min(max(int(np.floor((p2 - lo[2]) / h)), 0), nz - 1)
            out[i, j, q] += s2 * areas[k]


@numba.njit(parallel=True, cache=True)
def _means(field, transforms, centres, areas, lo, h, out):  # pragma: no cover - compiled
    nx, ny, nz, nc = field.shape
    total = areas.sum()
    for n in numba.prange(transforms.shape[0]):
        m = transforms[n]
        acc = np.zeros(nc)
        for k in range(centres.shape[0]):
            x = centres[k]
            # index coordinates of the point among the node centres (node i at lo + (i + 1/2) h)
            u = np.empty(3)
            for a in range(3):
                p = m[a, 0] * x[0] + m[a, 1] * x[1] + m[a, 2] * x[2] + m[a, 3]
                u[a] = (p - lo[a]) / h - 0.5
            i0 = np.empty(3, np.int64)
            w = np.empty(3)
            dims = (nx, ny, nz)
            for a in range(3):
                v = min(max(u[a], 0.0), dims[a] - 1.0)  # outside: the boundary node's value
                i = min(int(np.floor(v)), dims[a] - 2) if dims[a] > 1 else 0
                i0[a] = max(i, 0)
                w[a] = v - i0[a]
            for dx in range(2):
                ix = min(i0[0] + dx, nx - 1)
                wx = w[0] if dx else 1.0 - w[0]
                for dy in range(2):
                    iy = min(i0[1] + dy, ny - 1)
                    wy = w[1] if dy else 1.0 - w[1]
                    for dz in range(2):
                        iz = min(i0[2] + dz, nz - 1)
                        wt = areas[k] * wx * wy * (w[2] if dz else 1.0 - w[2])
                        for c in range(nc):
                            acc[c] += wt * field[ix, iy, iz, c]
        for c in range(nc):
            out[n, c] = acc[c] / total if total > 0 else 0.0


def _check(transforms, centres, areas):
    m = np.ascontiguousarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
    c = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
    a = np.ascontiguousarray(areas, dtype=np.float64).reshape(-1)
    if len(a) != len(c):
        raise ValueError(f"{len(c)} leaf centres but {len(a)} areas")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(c)) and np.all(np.isfinite(a)) and np.all(a >= 0)):
        raise ValueError("transforms, centres and areas must be finite, areas >= 0")
    return m, c, a


def deposit(grid: GridSpec, transforms, centres, areas, out: np.ndarray | None = None) -> np.ndarray:
    """Leaf-area density (grid.shape) of the leaves (``centres`` (L, 3), ``areas`` (L,), prototype frame) placed by
    every (4, 4) world-from-prototype matrix of ``transforms``; added to ``out`` when given. A leaf outside the
    grid counts in the nearest boundary cell."""
    m, c, a = _check(transforms, centres, areas)
    h = float(grid.voxel_size)
    cells = np.zeros(grid.shape) if out is None else out
    if m.size and c.size:
        _deposit(m, c, a / h**3, np.asarray(grid.origin, dtype=np.float64), h, cells)
    return cells


def instance_means(field: np.ndarray, grid: GridSpec, transforms, centres, areas) -> np.ndarray:
    """(N, C) per placement, the leaf-area-weighted mean of the node field (nx, ny, nz, C) at its leaves."""
    m, c, a = _check(transforms, centres, areas)
    f = np.ascontiguousarray(field, dtype=np.float64)
    if f.ndim != 4 or f.shape[:3] != tuple(grid.shape):
        raise ValueError(f"field must have shape {tuple(grid.shape)} + (C,), got {f.shape}")
    out = np.zeros((len(m), f.shape[3]))
    if m.size and c.size:
        _means(f, m, c, a, np.asarray(grid.origin, dtype=np.float64), float(grid.voxel_size), out)
    return out

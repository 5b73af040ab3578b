"""The ``subgrid_coverage`` kernel (geist2008 sec. 4.2): sub-cubes marked by an exact triangle/box overlap test.

Sub-cubes are closed boxes (package docstring, "Boundary conventions"); the
x-slabs are shared among threads as for the area kernel ("Threading").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from foliage_tools.geometry.voxelize.clipping import CLIP_CAP, clip_slab, coord_range

#: Padding (in sub-cube units) of candidate ranges derived from clipped
#: polygons in the subgrid kernel: it only adds candidates, the exact
#: triangle/box test decides.
_RANGE_PAD = 1e-9

#: ``subgrid_coverage`` skips triangles with ``|e1 x e2| <= _DEGENERATE * (longest edge)^2``
#: (twice the area over the squared longest edge; coincident or collinear
#: vertices up to round-off): a needle has no surface, but the exact overlap
#: test would still mark every sub-cube along it.
_DEGENERATE = 1e-12


@njit(cache=True)
def _touched_range(pmin, pmax, n, pad):
    """Closed unit boxes ``[j, j+1]`` (``0 <= j < n``) whose range meets ``[pmin - pad, pmax + pad]`` (empty: j1 < j0)."""
    lo = max(np.ceil(pmin - pad) - 1.0, 0.0)
    hi = min(np.floor(pmax + pad), n - 1.0)
    if lo > hi:
        return 0, -1
    return int(lo), int(hi)


@njit(cache=True)
def _tri_box_overlap(tri, cx, cy, cz, hs):
    """Exact triangle / closed axis-aligned cube overlap, separating axis theorem (Akenine-Möller 2001).

    ``tri`` (>= 3, 3) holds the triangle in rows 0..2; the cube has centre
    ``(cx, cy, cz)`` and half-size ``hs``. Touching counts as overlap. Tests the
    13 axes: 3 box normals, the triangle normal, and the 9 cross products of
    box axes with triangle edges (a degenerate, zero axis never separates).
    """
    v0x = tri[0, 0] - cx
    v0y = tri[0, 1] - cy
    v0z = tri[0, 2] - cz
    v1x = tri[1, 0] - cx
    v1y = tri[1, 1] - cy
    v1z = tri[1, 2] - cz
    v2x = tri[2, 0] - cx
    v2y = tri[2, 1] - cy
    v2z = tri[2, 2] - cz
    # box normals: the triangle's AABB against the box
    if min(v0x, v1x, v2x) > hs or max(v0x, v1x, v2x) < -hs:
        return False
    if min(v0y, v1y, v2y) > hs or max(v0y, v1y, v2y) < -hs:
        return False
    if min(v0z, v1z, v2z) > hs or max(v0z, v1z, v2z) < -hs:
        return False
    e0x = v1x - v0x
    e0y = v1y - v0y
    e0z = v1z - v0z
    e1x = v2x - v1x
    e1y = v2y - v1y
    e1z = v2z - v1z
    e2x = v0x - v2x
    e2y = v0y - v2y
    e2z = v0z - v2z
    # triangle plane against the box
    nx = e0y * e1z - e0z * e1y
    ny = e0z * e1x - e0x * e1z
    nz = e0x * e1y - e0y * e1x
    dist = nx * v0x + ny * v0y + nz * v0z
    r = hs * (abs(nx) + abs(ny) + abs(nz))
    if dist > r or dist < -r:
        return False
    # the 9 edge axes a = u x e (u = box axis x, y, z)
    for q in range(3):
        if q == 0:
            ex, ey, ez = e0x, e0y, e0z
        elif q == 1:
            ex, ey, ez = e1x, e1y, e1z
        else:
            ex, ey, ez = e2x, e2y, e2z
        # x x e = (0, -ez, ey)
        p0 = -ez * v0y + ey * v0z
        p1 = -ez * v1y + ey * v1z
        p2 = -ez * v2y + ey * v2z
        rad = hs * (abs(ez) + abs(ey))
        if min(p0, p1, p2) > rad or max(p0, p1, p2) < -rad:
            return False
        # y x e = (ez, 0, -ex)
        p0 = ez * v0x - ex * v0z
        p1 = ez * v1x - ex * v1z
        p2 = ez * v2x - ex * v2z
        rad = hs * (abs(ez) + abs(ex))
        if min(p0, p1, p2) > rad or max(p0, p1, p2) < -rad:
            return False
        # z x e = (-ey, ex, 0)
        p0 = -ey * v0x + ex * v0y
        p1 = -ey * v1x + ex * v1y
        p2 = -ey * v2x + ex * v2y
        rad = hs * (abs(ey) + abs(ex))
        if min(p0, p1, p2) > rad or max(p0, p1, p2) < -rad:
            return False
    return True


@njit(parallel=True, cache=True)
def _subgrid_kernel(tris, origin, h, nx, ny, nz, nthreads):
    # geist2008 sec. 4.2: 3x3x3 subgrid heuristic. Coordinates are in
    # sub-cube units (3 per voxel); bit (3*sa + sb)*3 + sc of mask[i, j, k]
    # records whether sub-cube (sa, sb, sc) of voxel (i, j, k) is intersected.
    mask = np.zeros((nx, ny, nz), dtype=np.int32)
    sx = 3 * nx
    sy = 3 * ny
    sz = 3 * nz
    ntri = tris.shape[0]
    for t in prange(nthreads):
        tri = np.empty((CLIP_CAP, 3))
        tmp = np.empty((CLIP_CAP, 3))
        px = np.empty((CLIP_CAP, 3))
        py = np.empty((CLIP_CAP, 3))
        for it in range(ntri):
            for v in range(3):
                for d in range(3):
                    tri[v, d] = (tris[it, v, d] - origin[d]) / h * 3.0
            xmin, xmax = coord_range(tri, 3, 0)
            a0, a1 = _touched_range(xmin, xmax, sx, 0.0)
            if a1 < a0:
                continue
            ax = tri[1, 0] - tri[0, 0]
            ay = tri[1, 1] - tri[0, 1]
            az = tri[1, 2] - tri[0, 2]
            bx = tri[2, 0] - tri[0, 0]
            by = tri[2, 1] - tri[0, 1]
            bz = tri[2, 2] - tri[0, 2]
            cx = ay * bz - az * by
            cy = az * bx - ax * bz
            cz = ax * by - ay * bx
            e2 = max(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz)
            e2 = max(e2, (bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
            if math.sqrt(cx * cx + cy * cy + cz * cz) <= _DEGENERATE * e2:
                continue  # zero-area triangle (up to round-off): marks nothing
            for a in range(a0, a1 + 1):
                i = a // 3
                if i % nthreads != t:
                    continue
                # Candidates: the triangle's piece in the closed x-slab [a, a+1],
                # then its piece in each touched column [a, a+1] x [b, b+1]. The
                # ranges only prune; the exact SAT test decides every sub-cube.
                mx = clip_slab(tri, 3, px, tmp, 0, a, xmin, xmax)
                if mx == 0:
                    continue
                ymin, ymax = coord_range(px, mx, 1)
                b0, b1 = _touched_range(ymin, ymax, sy, _RANGE_PAD)
                for b in range(b0, b1 + 1):
                    my = clip_slab(px, mx, py, tmp, 1, b, ymin - _RANGE_PAD, ymax + _RANGE_PAD)
                    if my == 0:
                        # rounding may lose a piece that only touches the column; fall back to the slab's range
                        zmin, zmax = coord_range(px, mx, 2)
                    else:
                        zmin, zmax = coord_range(py, my, 2)
                    c0, c1 = _touched_range(zmin, zmax, sz, _RANGE_PAD)
                    j = b // 3
                    for c in range(c0, c1 + 1):
                        if _tri_box_overlap(tri, a + 0.5, b + 0.5, c + 0.5, 0.5):
                            bit = ((a - 3 * i) * 3 + (b - 3 * j)) * 3 + (c - 3 * (c // 3))
                            mask[i, j, c // 3] |= np.int32(1 << bit)
    out = np.empty((nx, ny, nz), dtype=np.float64)
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                x = mask[i, j, k]
                cnt = 0
                while x != 0:
                    x &= x - 1
                    cnt += 1
                out[i, j, k] = cnt / 27.0
    return out

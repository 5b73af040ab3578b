"""Voxelize triangle soups onto an axis-aligned grid.

Two density estimators for the ``foliage density`` stage:

* :func:`area_per_voxel` -- the exact area of the triangles inside each voxel
  (polygon clipping), so that ``sum(area) == total triangle area``.
* :func:`subgrid_coverage` -- the heuristic of geist2008 sec. 4.2: every voxel
  is split into 3x3x3 sub-cubes, and its density is the fraction of sub-cubes
  that some triangle intersects (exact triangle/box overlap test).

Pure numpy + numba; no USD, no file I/O.

Index space
-----------
The kernels work in *index space* ``u = (p - origin) / voxel_size`` in which
voxel ``(i, j, k)`` is the unit cube ``[i, i+1] x [j, j+1] x [k, k+1]`` and all
voxel faces lie on integer planes (the subgrid kernel scales this by 3 so that
sub-cube faces are on integer planes). Every comparison against a face is made
on these transformed coordinates, so the assignment of geometry to voxels is
consistent between the binning and the clipping.

Boundary conventions
--------------------
``area_per_voxel``: on each axis voxel ``i`` owns the half-open slab
``[i, i+1)``, except the last voxel, which also owns the upper face of the grid.
This only matters for a polygon lying *exactly in* a face plane (any other
contact with a face has zero area): it is counted once, in the voxel on the
``+`` side of the face (or in the last voxel for the grid's upper face).

``subgrid_coverage``: sub-cubes are *closed* boxes, as in Akenine-Möller's
triangle/box test (touching counts as overlap). A triangle lying exactly in a
sub-cube face therefore marks the sub-cubes on both sides of it, and a triangle
edge lying exactly in a face marks the neighbour as well.

Zero-area triangles contribute to neither estimator (``area_per_voxel``
computes their area, exactly 0 or round-off; ``subgrid_coverage`` skips
triangles whose area is below ``1e-12 / 2`` of their squared longest edge).

Threading
---------
Both kernels are ``numba.njit(parallel=True)``. Thread ``t`` of ``T`` owns the
voxel x-slabs ``i`` with ``i % T == t``: every thread scans all triangles and
clips each one only against its own slabs, so threads never write the same
voxel (no races, no per-thread copies of the grid) and the round-robin
assignment balances the load for any smooth distribution of leaves.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

__all__ = ["GridSpec", "area_per_voxel", "grid_for_bounds", "mark_wood_fraction", "subgrid_coverage"]

#: Capacity of the fixed-size polygon buffers of the clipping kernels. A
#: triangle clipped by the 6 planes of a box has at most 9 vertices; the clip
#: routine never writes past this capacity (a numerically non-convex sliver
#: could otherwise produce more crossings than exact arithmetic allows).
CLIP_CAP = 16

#: Padding (in sub-cube units) of candidate ranges derived from clipped
#: polygons in the subgrid kernel: it only adds candidates, the exact
#: triangle/box test decides.
_RANGE_PAD = 1e-9

#: ``subgrid_coverage`` skips triangles with ``|e1 x e2| <= _DEGENERATE * (longest edge)^2``
#: (twice the area over the squared longest edge; coincident or collinear
#: vertices up to round-off): a needle has no surface, but the exact overlap
#: test would still mark every sub-cube along it.
_DEGENERATE = 1e-12


# --------------------------------------------------------------------------
# Grid description
# --------------------------------------------------------------------------


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


# --------------------------------------------------------------------------
# Numba kernels
# --------------------------------------------------------------------------


@njit(cache=True)
def _clip(src, n, dst, axis, c, keep_above):
    """Sutherland-Hodgman clip of the convex polygon ``src[:n]`` by one axis-aligned half-space.

    Keeps ``p[axis] >= c`` (``keep_above``) or ``p[axis] <= c``: the half-space
    is closed, so points on the plane are kept. Writes ``dst`` and returns its
    vertex count. Intersection points are computed from the edge's endpoint
    with the smaller coordinate, so both sides of a plane get bitwise equal
    points from the same edge, and their ``axis`` coordinate is set to ``c``
    exactly.
    """
    if n == 0:
        return 0
    m = 0
    prev = n - 1
    dprev = src[prev, axis] - c
    if not keep_above:
        dprev = -dprev
    for cur in range(n):
        dcur = src[cur, axis] - c
        if not keep_above:
            dcur = -dcur
        crossing = (dprev < 0.0 and dcur > 0.0) or (dprev > 0.0 and dcur < 0.0)
        if crossing and m < CLIP_CAP:
            if src[prev, axis] <= src[cur, axis]:
                a = prev
                b = cur
            else:
                a = cur
                b = prev
            t = (c - src[a, axis]) / (src[b, axis] - src[a, axis])
            for d in range(3):
                dst[m, d] = src[a, d] + t * (src[b, d] - src[a, d])
            dst[m, axis] = c
            m += 1
        if dcur >= 0.0 and m < CLIP_CAP:
            for d in range(3):
                dst[m, d] = src[cur, d]
            m += 1
        prev = cur
        dprev = dcur
    return m


@njit(cache=True, inline="always")
def projection_axes(tri):
    """(k1, k2, factor) for a triangle in rows 0..2 of ``tri``: the area of any planar piece of it is
    ``projected_area(piece, k1, k2) * factor`` -- the area of its projection on the plane normal to the
    dominant axis k of the normal n, times |n| / |n_k| (and the 1/2 of the shoelace sum). factor is 0
    for a zero-area triangle."""
    ax = tri[1, 0] - tri[0, 0]
    ay = tri[1, 1] - tri[0, 1]
    az = tri[1, 2] - tri[0, 2]
    bx = tri[2, 0] - tri[0, 0]
    by = tri[2, 1] - tri[0, 1]
    bz = tri[2, 2] - tri[0, 2]
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    norm = math.sqrt(cx * cx + cy * cy + cz * cz)
    if norm == 0.0:
        return 1, 2, 0.0
    k = 0
    nk = abs(cx)
    if abs(cy) > nk:
        k = 1
        nk = abs(cy)
    if abs(cz) > nk:
        k = 2
        nk = abs(cz)
    return (k + 1) % 3, (k + 2) % 3, 0.5 * norm / nk


@njit(cache=True, inline="always")
def projected_area(poly, n, k1, k2):
    """Twice the area of the convex polygon ``poly[:n]`` projected on axes (k1, k2) (shoelace, absolute)."""
    s = 0.0
    for q in range(1, n - 1):
        ux = poly[q, k1] - poly[0, k1]
        uy = poly[q, k2] - poly[0, k2]
        vx = poly[q + 1, k1] - poly[0, k1]
        vy = poly[q + 1, k2] - poly[0, k2]
        s += ux * vy - uy * vx
    return abs(s)


@njit(cache=True)
def clip_slab(src, n, dst, tmp, axis, j, pmin, pmax):
    """Clip ``src[:n]`` (coordinate range ``[pmin, pmax]`` along ``axis``) to the closed slab ``[j, j+1]``.

    Only the planes the polygon actually crosses are applied; the result is
    always in ``dst`` (``tmp`` is scratch). Returns the vertex count.
    """
    lo = float(j)
    hi = lo + 1.0
    if pmin < lo:
        if pmax > hi:
            m = _clip(src, n, tmp, axis, lo, True)
            return _clip(tmp, m, dst, axis, hi, False)
        return _clip(src, n, dst, axis, lo, True)
    if pmax > hi:
        return _clip(src, n, dst, axis, hi, False)
    for q in range(n):
        for d in range(3):
            dst[q, d] = src[q, d]
    return n


@njit(cache=True)
def coord_range(poly, n, axis):
    lo = poly[0, axis]
    hi = lo
    for q in range(1, n):
        v = poly[q, axis]
        if v < lo:
            lo = v
        if v > hi:
            hi = v
    return lo, hi


@njit(cache=True)
def owned_range(pmin, pmax, n):
    """Voxels ``[j0, j1]`` that own area of a polygon spanning ``[pmin, pmax]`` along one axis (empty: j1 < j0).

    Half-open convention: voxel ``j`` owns ``[j, j+1)``, the last voxel also its
    upper face. A polygon with ``pmin == pmax`` lies in a plane and goes to the
    single voxel owning that plane.
    """
    if pmin == pmax:
        f = np.floor(pmin)
        if f == n and pmin == n:
            f = n - 1.0
        if f < 0.0 or f > n - 1.0:
            return 0, -1
        return int(f), int(f)
    lo = max(np.floor(pmin), 0.0)
    hi = min(np.ceil(pmax) - 1.0, n - 1.0)
    if lo > hi:
        return 0, -1
    return int(lo), int(hi)


@njit(cache=True)
def _touched_range(pmin, pmax, n, pad):
    """Closed unit boxes ``[j, j+1]`` (``0 <= j < n``) whose range meets ``[pmin - pad, pmax + pad]`` (empty: j1 < j0)."""
    lo = max(np.ceil(pmin - pad) - 1.0, 0.0)
    hi = min(np.floor(pmax + pad), n - 1.0)
    if lo > hi:
        return 0, -1
    return int(lo), int(hi)


@njit(cache=True)
def _first_owned(j0, t, nthreads):
    """Smallest ``j >= j0`` with ``j % nthreads == t``."""
    return j0 + (t - j0) % nthreads


@njit(parallel=True, cache=True)
def _area_kernel(tris, origin, h, nx, ny, nz, nthreads):
    out = np.zeros((nx, ny, nz), dtype=np.float64)
    ntri = tris.shape[0]
    h2 = h * h
    for t in prange(nthreads):
        tri = np.empty((CLIP_CAP, 3))
        tmp = np.empty((CLIP_CAP, 3))
        px = np.empty((CLIP_CAP, 3))
        py = np.empty((CLIP_CAP, 3))
        pz = np.empty((CLIP_CAP, 3))
        for it in range(ntri):
            for v in range(3):
                for d in range(3):
                    tri[v, d] = (tris[it, v, d] - origin[d]) / h
            xmin, xmax = coord_range(tri, 3, 0)
            i0, i1 = owned_range(xmin, xmax, nx)
            if i1 < i0:
                continue
            first = _first_owned(i0, t, nthreads)
            if first > i1:
                continue
            k1, k2, factor = projection_axes(tri)
            if factor == 0.0:
                continue  # zero-area triangle: contributes nothing
            scale = h2 * factor
            for i in range(first, i1 + 1, nthreads):
                mx = clip_slab(tri, 3, px, tmp, 0, i, xmin, xmax)
                if mx < 3:
                    continue
                ymin, ymax = coord_range(px, mx, 1)
                j0, j1 = owned_range(ymin, ymax, ny)
                for j in range(j0, j1 + 1):
                    my = clip_slab(px, mx, py, tmp, 1, j, ymin, ymax)
                    if my < 3:
                        continue
                    zmin, zmax = coord_range(py, my, 2)
                    l0, l1 = owned_range(zmin, zmax, nz)
                    for l in range(l0, l1 + 1):
                        mz = clip_slab(py, my, pz, tmp, 2, l, zmin, zmax)
                        if mz < 3:
                            continue
                        out[i, j, l] += projected_area(pz, mz, k1, k2) * scale
    return out


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


# --------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------


def _check_triangles(triangles) -> np.ndarray:
    try:
        tris = np.asarray(triangles, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"triangles must be a numeric (T, 3, 3) array of vertex positions: {exc}") from exc
    if tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise ValueError(f"triangles must have shape (T, 3, 3) (T triangles x 3 vertices x xyz), got {tris.shape}")
    finite = np.isfinite(tris).all(axis=(1, 2))
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise ValueError(
            f"triangles must be finite: {bad.size} triangle(s) hold NaN or infinite coordinates (first: index {int(bad[0])})"
        )
    return np.ascontiguousarray(tris)


def _check_grid(grid) -> GridSpec:
    if not isinstance(grid, GridSpec):
        raise TypeError(f"grid must be a GridSpec, got {type(grid).__name__}")
    return grid


def _run(kernel, triangles, grid) -> np.ndarray:
    """Check the inputs and run one of the voxel kernels on all threads (zeros for no triangles)."""
    tris = _check_triangles(triangles)
    grid = _check_grid(grid)
    nx, ny, nz = grid.shape
    if tris.shape[0] == 0:
        return np.zeros(grid.shape, dtype=np.float64)
    origin = np.asarray(grid.origin, dtype=np.float64)
    return kernel(tris, origin, grid.voxel_size, nx, ny, nz, numba.get_num_threads())


def area_per_voxel(triangles: np.ndarray, grid: GridSpec) -> np.ndarray:
    """Exact area of the triangles inside each voxel.

    Every triangle is sliced by the voxel x-planes, each piece by the y-planes,
    then the z-planes (Sutherland-Hodgman on fixed-size buffers) and the area
    of each final piece is added to its voxel, so the result partitions the
    triangles' area: ``out.sum()`` equals the total area of the triangles (to
    round-off, ~1e-15 relative) when all of them lie inside the grid. Parts of
    triangles outside the grid are dropped. A polygon lying exactly in a voxel
    face plane is counted once, in the voxel on the ``+`` side of that face (the
    last voxel for the grid's upper face). Zero-area triangles contribute 0.

    Parameters
    ----------
    triangles : array_like, shape (T, 3, 3)
        Vertex positions (stage units) of T triangles, float (converted to
        float64). T may be 0.
    grid : GridSpec
        The voxel grid.

    Returns
    -------
    numpy.ndarray, shape ``grid.shape``, float64
        Triangle area inside each voxel, stage units squared (divide by
        ``grid.voxel_volume`` for a leaf-area density in 1/stage unit).

    Raises
    ------
    ValueError
        If ``triangles`` is not (T, 3, 3) or holds non-finite coordinates.
    TypeError
        If ``grid`` is not a :class:`GridSpec`.
    """
    return _run(_area_kernel, triangles, grid)


def subgrid_coverage(triangles: np.ndarray, grid: GridSpec) -> np.ndarray:
    """Fraction of each voxel's 27 sub-cubes that the triangles intersect (geist2008 sec. 4.2).

    geist2008 sec. 4.2: "Each grid node is refined into a 3x3x3 subgrid. If any
    triangle intersects a node of the subgrid, then that subgrid node is marked
    as intersected. The density of the grid node is then the ratio of the number
    of its intersected subgrid nodes to 27." A subgrid node is taken to be the
    closed sub-cube of side ``voxel_size / 3``; intersection is decided by an
    exact triangle/box separating-axis test (Akenine-Möller), not by bounding
    boxes. Touching counts: a triangle lying exactly in a sub-cube face marks
    the sub-cubes on both sides. Zero-area triangles (twice the area
    ``<= 1e-12 * longest edge**2``: coincident or collinear vertices, up to
    round-off) mark nothing.

    Parameters
    ----------
    triangles : array_like, shape (T, 3, 3)
        Vertex positions (stage units) of T triangles, float (converted to
        float64). T may be 0.
    grid : GridSpec
        The voxel grid.

    Returns
    -------
    numpy.ndarray, shape ``grid.shape``, float64
        Dimensionless coverage in ``{0, 1/27, 2/27, ..., 1}``.

    Raises
    ------
    ValueError
        If ``triangles`` is not (T, 3, 3) or holds non-finite coordinates.
    TypeError
        If ``grid`` is not a :class:`GridSpec`.
    """
    return _run(_subgrid_kernel, triangles, grid)


def mark_wood_fraction(leaf_area: np.ndarray, wood_area: np.ndarray) -> np.ndarray:
    """Share of wood in each voxel's surface: ``wood / (leaf + wood)``, 0 where both are 0.

    Parameters
    ----------
    leaf_area, wood_area : array_like, same shape
        Non-negative, finite per-voxel amounts of leaf and wood surface, in the
        same units (areas from :func:`area_per_voxel`, or coverages from
        :func:`subgrid_coverage`).

    Returns
    -------
    numpy.ndarray, same shape, float64
        Values in ``[0, 1]``; always finite.

    Raises
    ------
    ValueError
        If the shapes differ or either input holds negative or non-finite values.
    """
    leaf = np.asarray(leaf_area, dtype=np.float64)
    wood = np.asarray(wood_area, dtype=np.float64)
    if leaf.shape != wood.shape:
        raise ValueError(f"leaf_area and wood_area must have the same shape, got {leaf.shape} and {wood.shape}")
    for name, arr in (("leaf_area", leaf), ("wood_area", wood)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
        if np.any(arr < 0.0):
            raise ValueError(f"{name} must be >= 0, got a minimum of {float(arr.min())}")
    total = leaf + wood
    out = np.zeros(leaf.shape, dtype=np.float64)
    np.divide(wood, total, out=out, where=total > 0.0)
    return out

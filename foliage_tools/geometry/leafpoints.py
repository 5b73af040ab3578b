"""Stratified points on leaves: uniform over each leaf's area, from shifted rank-1 lattices.

Used by the shadow rays of the exact direct light (:mod:`foliage_tools.lighting.direct`)
and the final gather (:mod:`foliage_tools.lighting.gather`).

A leaf is the set of its triangles of positive area. A point of the unit
square (u, v) is mapped onto the leaf: u walks the leaf's cumulative triangle
area (which triangle, then rescaled to [0, 1) inside it), and (u', v) is
mapped onto that triangle by Heitz's low-distortion map (Heitz 2019, "A
Low-Distortion Map Between Triangle and Square"), which is area-preserving
and keeps a lattice's stratification far better than folding the square
along its diagonal. A uniform point of the square gives a uniform point of
the leaf, so a randomly shifted lattice (Roberts' R2 sequence, generator
(1/φ₂, 1/φ₂²) with φ₂ the plastic number, Cranley–Patterson shift) gives
points that are each uniform and together evenly spread.

Pure numpy.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LeafSampler", "check_scene", "lattice"]

#: Roberts' R2 generator: 1/φ₂ and 1/φ₂² with φ₂ the real root of x³ = x + 1 (the plastic number).
_PLASTIC = 1.324717957244746
_R2 = np.array([1.0 / _PLASTIC, 1.0 / _PLASTIC**2])


def lattice(n: int) -> np.ndarray:
    """(n, 2) points of the R2 rank-1 lattice in [0, 1)² (before a shift)."""
    return np.mod(np.arange(n)[:, None] * _R2[None, :], 1.0)


def check_scene(triangles, leaf_of_triangle, n_leaves: int, sun_direction) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """Validated (T, 3, 3) float64 triangles, (T,) int64 leaf ids (-1 wood), the leaf count and the unit sun direction."""
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ValueError(f"triangles must have shape (T, 3, 3), got {tri.shape}")
    if not np.all(np.isfinite(tri)):
        raise ValueError("triangles contain NaN or infinite coordinates")
    leaf = np.asarray(leaf_of_triangle)
    if leaf.shape != (tri.shape[0],) or not np.issubdtype(leaf.dtype, np.integer):
        raise ValueError(f"leaf_of_triangle must be (T,) = ({tri.shape[0]},) integers, got {leaf.shape} {leaf.dtype}")
    n = int(n_leaves)
    if n < 0 or (leaf.size and (leaf.min() < -1 or leaf.max() >= n)):
        raise ValueError(f"leaf_of_triangle must be -1 (wood) or below n_leaves = {n}")
    sun = np.asarray(sun_direction, dtype=np.float64).reshape(-1)
    norm = float(np.linalg.norm(sun)) if sun.shape == (3,) else 0.0
    if sun.shape != (3,) or not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"sun_direction must be 3 finite numbers, not all zero, got {sun_direction!r}")
    tri.flags.writeable = False
    leaf = leaf.astype(np.int64)
    leaf.flags.writeable = False
    return tri, leaf, n, sun / norm


class LeafSampler:
    """Maps points of the unit square onto the leaves (module docstring)."""

    def __init__(self, triangles: np.ndarray, leaf_of_triangle: np.ndarray, n_leaves: int) -> None:
        tri = triangles
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        idx = np.flatnonzero((leaf_of_triangle >= 0) & (area > 0.0))
        self.triangles = tri
        self.order = idx[np.argsort(leaf_of_triangle[idx], kind="stable")]
        self.cum = np.cumsum(area[self.order])
        owner = leaf_of_triangle[self.order]
        self.start = np.searchsorted(owner, np.arange(n_leaves), side="left")
        self.stop = np.searchsorted(owner, np.arange(n_leaves), side="right")
        cum = self.cum if self.cum.size else np.zeros(1)
        self.base = np.where(self.start > 0, cum[np.maximum(self.start - 1, 0)], 0.0)
        self.total = np.where(self.stop > self.start, cum[np.maximum(self.stop - 1, 0)] - self.base, 0.0)
        self.has_area = self.total > 0.0
        """(L,) bool: leaves with a triangle of positive area (the others get no points)."""

    def points(self, ids: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangle index and point for square points ``u`` (n, ..., 2) on leaves ``ids`` (n,), all with area.

        Returns (t, p): (n, ...) triangle indices into the scene and (n, ..., 3) points.
        """
        extra = (None,) * (u.ndim - 2)
        start, stop = self.start[ids][(slice(None),) + extra], self.stop[ids][(slice(None),) + extra]
        target = self.base[ids][(slice(None),) + extra] + u[..., 0] * self.total[ids][(slice(None),) + extra]
        pos = np.clip(np.searchsorted(self.cum, target, side="right"), start, stop - 1)
        lo = np.where(pos > 0, self.cum[np.maximum(pos - 1, 0)], 0.0)
        s = np.clip((target - lo) / np.maximum(self.cum[pos] - lo, 1e-300), 0.0, 1.0)
        v = u[..., 1]
        upper = v > s  # Heitz 2019's square -> triangle map, as barycentrics of v0, v1 (v2 the rest)
        b0 = np.where(upper, 0.5 * s, s - 0.5 * v)
        b1 = np.where(upper, v - 0.5 * s, 0.5 * v)
        t = self.order[pos]
        v2 = self.triangles[t, 2]
        p = v2 + b0[..., None] * (self.triangles[t, 0] - v2) + b1[..., None] * (self.triangles[t, 1] - v2)
        return t, p

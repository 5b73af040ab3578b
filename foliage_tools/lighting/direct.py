"""Exact direct sunlight per leaf: shadow rays through the actual geometry.

The unscattered sun irradiance of DESIGN.md section 3 (E_direct: both faces
summed, area-averaged, sun irradiance 1 on a plane perpendicular to it) is a
geometric quantity. For a leaf of one-sided area A made of triangles k with
unit normals n_k,

    E_direct = (1/A) ∫_leaf |n(x)·s| V(x) dA(x),

where V(x) is 1 when the ray from x toward the sun s leaves the scene without
hitting a triangle (leaf or wood, of any instance) and 0 otherwise. A
two-sided leaf receives the beam on whichever face looks at the sun, so only
|n·s| enters. The integral is estimated from K points per leaf, uniform over
its area; each needs one occlusion query (Embree's "any hit"), so a leaf costs
K rays and no method's volume model enters.

Sampling (stratified, seeded)
-----------------------------
The K points of a leaf are two independent halves of K/2. Each half is a
randomly shifted rank-1 lattice on the unit square (Roberts' R2 sequence,
generator (1/φ₂, 1/φ₂²), φ₂ the plastic number, Cranley–Patterson shift
drawn per leaf and half): the first coordinate picks the triangle by the
leaf's cumulative triangle area and is rescaled to [0, 1) inside it, the pair
is then mapped onto the triangle by Heitz's low-distortion map. Every point
is uniform over the leaf's area (a random shift makes each point uniform), so
each half's mean is an unbiased estimate; the lattice spreads the points
evenly, so a leaf half in shadow is resolved with far less noise than K
independent points would give.

Noise estimate: the halves are independent, so as in
:mod:`foliage_tools.lighting.reference`, the relative RMS sampling error of
the full estimate x = (a + b)/2 over leaves is estimated as
``‖a - b‖ / ‖a + b‖``.

Shadow-ray origins start ``offset_distance`` off the surface on the sun's
side (:mod:`foliage_tools.geometry.rays`). A point whose triangle is edge-on
to the sun (n·s = 0) contributes 0 and casts no ray.

Pure numerics (numpy + Embree through :mod:`foliage_tools.geometry.rays`): no
files, no printing.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from foliage_tools.geometry.rays import PeriodicRayScene, RayScene

__all__ = ["DirectInputs", "DirectParams", "DirectResult", "solve"]

#: Roberts' R2 generator: 1/φ₂ and 1/φ₂² with φ₂ the real root of x³ = x + 1 (the plastic number).
_PLASTIC = 1.324717957244746
_R2 = np.array([1.0 / _PLASTIC, 1.0 / _PLASTIC**2])

#: Leaves per unit of work (seeding, threading): bounds the memory of one chunk
#: (K points × 6 doubles each) and fixes the random streams whatever the workers.
_CHUNK_LEAVES = 1 << 14


@dataclass(frozen=True, eq=False)
class DirectInputs:
    """The scene as shadow rays see it: world-space triangles with leaf ids."""

    triangles: np.ndarray
    """(T, 3, 3) float64 vertices, world space (stage units): every leaf and wood triangle of every instance."""
    leaf_of_triangle: np.ndarray
    """(T,) int: leaf index 0..L-1 of each triangle, -1 for wood (an occluder only)."""
    n_leaves: int
    """L, the number of leaves (a leaf with no triangle of positive area gets E_direct = 0)."""
    sun_direction: np.ndarray
    """(3,) direction *toward* the sun (normalised on construction)."""
    period: tuple[float, float] | None = None
    """If set, (px, py): one cell of an infinite layer repeated along x and y (z up), for tests."""
    cell_origin: tuple[float, float] = (0.0, 0.0)
    """Lower (x, y) corner of the periodic cell."""

    def __post_init__(self) -> None:
        tri = np.asarray(self.triangles, dtype=np.float64)
        if tri.ndim != 3 or tri.shape[1:] != (3, 3):
            raise ValueError(f"triangles must have shape (T, 3, 3), got {tri.shape}")
        if not np.all(np.isfinite(tri)):
            raise ValueError("triangles contain NaN or infinite coordinates")
        leaf = np.asarray(self.leaf_of_triangle)
        if leaf.shape != (tri.shape[0],) or not np.issubdtype(leaf.dtype, np.integer):
            raise ValueError(f"leaf_of_triangle must be (T,) = ({tri.shape[0]},) integers, got {leaf.shape} {leaf.dtype}")
        n = int(self.n_leaves)
        if n < 0 or (leaf.size and (leaf.min() < -1 or leaf.max() >= n)):
            raise ValueError(f"leaf_of_triangle must be -1 (wood) or below n_leaves = {n}")
        sun = np.asarray(self.sun_direction, dtype=np.float64).reshape(-1)
        norm = float(np.linalg.norm(sun)) if sun.shape == (3,) else 0.0
        if sun.shape != (3,) or not math.isfinite(norm) or norm == 0.0:
            raise ValueError(f"sun_direction must be 3 finite numbers, not all zero, got {self.sun_direction!r}")
        if self.period is not None and sun[2] <= 0.0:
            raise ValueError(f"a periodic layer needs the sun above the horizon, got sun_direction = {tuple(sun)}")
        for a in (tri, leaf):
            a.flags.writeable = False
        object.__setattr__(self, "triangles", tri)
        object.__setattr__(self, "leaf_of_triangle", leaf.astype(np.int64))
        object.__setattr__(self, "n_leaves", n)
        object.__setattr__(self, "sun_direction", sun / norm)


@dataclass(frozen=True)
class DirectParams:
    """How many shadow rays per leaf, and the seed."""

    samples_per_leaf: int = 64
    """K: points per leaf (even, ≥ 2: two halves for the noise estimate). The sampling error
    of a half-lit leaf falls faster than 1/sqrt(K) (stratified points)."""
    seed: int = 0
    """Seed of ``np.random.SeedSequence``; results are bitwise reproducible for a seed."""
    workers: int | None = None
    """Threads; None: ``os.cpu_count()``. Does not change the results."""

    def __post_init__(self) -> None:
        k = self.samples_per_leaf
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2 or k % 2:
            raise ValueError(f"samples_per_leaf must be an even integer >= 2 (two halves), got {k!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.workers is not None and (isinstance(self.workers, bool) or int(self.workers) < 1):
            raise ValueError(f"workers must be None or >= 1, got {self.workers!r}")


@dataclass(frozen=True, eq=False)
class DirectResult:
    """Per-leaf exact direct sunlight (see the module docstring)."""

    e_direct: np.ndarray
    """(L,) unscattered sun irradiance, both faces summed, area-averaged (sun irradiance 1); the same in every channel."""
    noise_rel: float
    """Estimated relative RMS sampling error of ``e_direct`` over leaves (two halves; 0 if all leaves are dark)."""
    lit_fraction: np.ndarray
    """(L,) fraction of the leaf's sample points that see the sun (its triangles edge-on to it count as unlit)."""
    rays: int
    """Shadow rays traced."""
    samples_per_leaf: int
    seconds: float
    """Wall time of :func:`solve`."""


def _leaf_table(tri: np.ndarray, leaf: np.ndarray, n_leaves: int):
    """Triangles of positive area sorted by leaf: (order, cumulative area, per-leaf start/stop/area)."""
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ok = (leaf >= 0) & (area > 0.0)
    idx = np.flatnonzero(ok)
    order = idx[np.argsort(leaf[idx], kind="stable")]
    cum = np.cumsum(area[order])
    owner = leaf[order]
    start = np.searchsorted(owner, np.arange(n_leaves), side="left")
    stop = np.searchsorted(owner, np.arange(n_leaves), side="right")
    base = np.where(start > 0, cum[np.maximum(start - 1, 0)] if cum.size else 0.0, 0.0)
    total = np.where(stop > start, cum[np.maximum(stop - 1, 0)] - base if cum.size else 0.0, 0.0)
    return order, cum, start, stop, base, total


def solve(
    inputs: DirectInputs,
    params: DirectParams = DirectParams(),
    *,
    progress: Callable[[int, int], None] | None = None,
) -> DirectResult:
    """Exact E_direct of every leaf from stratified shadow rays (module docstring).

    Parameters
    ----------
    inputs : DirectInputs
    params : DirectParams
    progress : callable, optional
        ``progress(done, total)`` in leaves, from the calling thread, in order.

    Returns
    -------
    DirectResult
    """
    start_time = time.perf_counter()
    if not isinstance(inputs, DirectInputs) or not isinstance(params, DirectParams):
        raise TypeError("solve(inputs: DirectInputs, params: DirectParams)")
    tri, leaf, n_leaves = inputs.triangles, inputs.leaf_of_triangle, inputs.n_leaves
    sun = inputs.sun_direction
    k = int(params.samples_per_leaf)
    half = k // 2
    workers = int(params.workers) if params.workers is not None else max(1, os.cpu_count() or 1)
    if inputs.period is not None:
        scene = PeriodicRayScene(tri, period=inputs.period, origin=inputs.cell_origin)
        normals = scene.normals
    else:
        scene = RayScene(tri)
        normals = scene.normals
    offset = scene.offset_distance()
    cos_s = normals @ sun
    order, cum, start, stop, base, total = _leaf_table(tri, leaf, n_leaves)
    has_area = total > 0.0
    chunks = [(a, min(a + _CHUNK_LEAVES, n_leaves)) for a in range(0, n_leaves, _CHUNK_LEAVES)]
    seeds = np.random.SeedSequence(params.seed).spawn(len(chunks))
    lattice = np.mod(np.arange(half)[:, None] * _R2[None, :], 1.0)  # (K/2, 2), before the shift

    def run(c: int) -> tuple[np.ndarray, np.ndarray]:
        a, b = chunks[c]
        rng = np.random.default_rng(seeds[c])
        ids = np.arange(a, b)
        ids = ids[has_area[a:b]]
        out = np.zeros((b - a, 2))
        lit = np.zeros(b - a)
        if ids.size == 0:
            return out, lit
        shift = rng.random((ids.size, 2, 2))  # (leaf, half, coordinate)
        u = np.mod(lattice[None, None, :, :] + shift[:, :, None, :], 1.0)  # (n, 2, K/2, 2)
        u1 = u[..., 0].reshape(ids.size, k)
        u2 = u[..., 1].reshape(ids.size, k)
        # the first coordinate walks the leaf's cumulative area: which triangle, and where in it
        target = base[ids, None] + u1 * total[ids, None]
        pos = np.searchsorted(cum, target, side="right")
        pos = np.clip(pos, start[ids, None], stop[ids, None] - 1)
        t_lo = np.where(pos > 0, cum[np.maximum(pos - 1, 0)], 0.0)
        t_area = cum[pos] - t_lo
        s = np.clip((target - t_lo) / np.where(t_area > 0, t_area, 1.0), 0.0, 1.0)
        # Heitz 2019, "A Low-Distortion Map Between Triangle and Square": area-preserving and keeps the
        # lattice's stratification far better than folding the square along its diagonal
        upper = u2 > s
        b0 = np.where(upper, 0.5 * s, s - 0.5 * u2)
        b1 = np.where(upper, u2 - 0.5 * s, 0.5 * u2)
        t = order[pos]  # (n, K) triangle of each point
        v2 = tri[t, 2]
        p = v2 + b0[..., None] * (tri[t, 0] - v2) + b1[..., None] * (tri[t, 1] - v2)
        c_s = cos_s[t]
        toward = c_s != 0.0
        side = np.where(c_s >= 0.0, 1.0, -1.0)[..., None] * normals[t]
        origins = (p + offset * side)[toward]
        visible = np.zeros((ids.size, k), dtype=bool)
        if origins.shape[0]:
            blocked = scene.occluded(origins, np.broadcast_to(sun, origins.shape))
            visible[toward] = ~blocked
        value = np.abs(c_s) * visible
        local = ids - a
        out[local, 0] = value[:, :half].mean(axis=1)
        out[local, 1] = value[:, half:].mean(axis=1)
        lit[local] = visible.mean(axis=1)
        return out, lit

    halves = np.zeros((n_leaves, 2))
    lit_fraction = np.zeros(n_leaves)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        done = 0
        for c, (vals, lit) in enumerate(pool.map(run, range(len(chunks)))):
            a, b = chunks[c]
            halves[a:b] = vals
            lit_fraction[a:b] = lit
            done = b
            if progress is not None:
                progress(done, n_leaves)
    e = halves.mean(axis=1)
    den = float(np.linalg.norm(halves[:, 0] + halves[:, 1]))
    noise = float(np.linalg.norm(halves[:, 0] - halves[:, 1])) / den if den > 0 else 0.0
    rays = int(np.count_nonzero(has_area)) * k
    for arr in (e, lit_fraction):
        arr.flags.writeable = False
    return DirectResult(e, noise, lit_fraction, rays, k, time.perf_counter() - start_time)

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
The K points of a leaf are two independent halves of K/2, each a randomly
shifted rank-1 lattice mapped onto the leaf's area
(:class:`foliage_tools.geometry.leafpoints.LeafSampler`): every point is
uniform over the leaf, so each half's mean is an unbiased estimate, and the
lattice spreads the points evenly, so a leaf half in shadow is resolved with
less noise than K independent points would give (measured on tree_small's
0.1 m cards, mostly half-shadowed: relative RMS error 14 % at K = 16, 5 % at
64, 2 % at 256, against independent points' K^-1/2).

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

import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from foliage_tools.geometry.instanced import cofactors
from foliage_tools.geometry.leafpoints import LeafSampler, check_scene, lattice
from foliage_tools.geometry.rays import PeriodicRayScene, RayScene

__all__ = ["DirectInputs", "DirectParams", "DirectResult", "InstanceDirect", "solve", "solve_instances"]

#: Sample points per unit of work (seeding, threading): bounds the memory of one chunk (~100 bytes a point)
#: and fixes the random streams whatever the workers.
_CHUNK_POINTS = 1 << 20
#: Most samples per leaf (a chunk must hold one leaf).
MAX_SAMPLES = 1 << 16


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
        tri, leaf, n, sun = check_scene(self.triangles, self.leaf_of_triangle, self.n_leaves, self.sun_direction)
        if self.period is not None and sun[2] <= 0.0:
            raise ValueError(f"a periodic layer needs the sun above the horizon, got sun_direction = {tuple(sun)}")
        object.__setattr__(self, "triangles", tri)
        object.__setattr__(self, "leaf_of_triangle", leaf)
        object.__setattr__(self, "n_leaves", n)
        object.__setattr__(self, "sun_direction", sun)


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
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2 or k % 2 or k > MAX_SAMPLES:
            raise ValueError(f"samples_per_leaf must be an even integer in [2, {MAX_SAMPLES}] (two halves), got {k!r}")
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
    scene: PeriodicRayScene | RayScene
    if inputs.period is not None:
        scene = PeriodicRayScene(tri, period=inputs.period, origin=inputs.cell_origin)
    else:
        scene = RayScene(tri)
    normals = scene.normals
    offset = scene.offset_distance()
    cos_s = normals @ sun
    sampler = LeafSampler(tri, leaf, n_leaves)
    has_area = sampler.has_area
    per_chunk = max(1, _CHUNK_POINTS // k)
    chunks = [(a, min(a + per_chunk, n_leaves)) for a in range(0, n_leaves, per_chunk)]
    seeds = np.random.SeedSequence(params.seed).spawn(len(chunks))
    base_lattice = lattice(half)  # (K/2, 2), before the shift

    def run(c: int) -> tuple[np.ndarray, np.ndarray]:
        a, b = chunks[c]
        rng = np.random.default_rng(seeds[c])
        ids = np.arange(a, b)
        ids = ids[has_area[a:b]]
        out = np.zeros((b - a, 2))
        lit = np.zeros(b - a)
        if ids.size == 0:
            return out, lit
        shift = rng.random((ids.size, 2, 1, 2))  # (leaf, half, -, coordinate)
        u = np.mod(base_lattice[None, None, :, :] + shift, 1.0).reshape(ids.size, k, 2)
        t, p = sampler.points(ids, u)  # (n, K) triangle and (n, K, 3) point of each sample
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


@dataclass(frozen=True, eq=False)
class InstanceDirect:
    """Each placed instance's mean exact direct sunlight (:func:`solve_instances`)."""

    e_direct: np.ndarray
    """(N,) leaf-area-weighted mean E_direct over each instance's leaves (sun irradiance 1)."""
    noise_rel: float
    """Relative RMS sampling error of ``e_direct`` over instances (two independent halves)."""
    rays: int
    samples_per_instance: int
    seconds: float


def solve_instances(scene, leaf_of_triangle, sun_direction, *, samples: int, seed: int = 0,
                    progress: Callable[[int, int], None] | None = None) -> InstanceDirect:
    """Mean E_direct of every instance of an :class:`~foliage_tools.geometry.instanced.InstancedRayScene`.

    The mean over an instance's leaves weighted by their areas is (1/A) ∫ |n·s| V dA over all its leaf area, so
    it is estimated from ``samples`` points spread over that area, each with one shadow ray through every
    instance (the same integral as the module docstring's, over an instance instead of a leaf). Points are drawn
    over the prototype's leaf area in two independent halves, each a systematic sample of the cumulative
    triangle areas with its own random shift and a uniform point in the triangle; under a non-uniform scale or
    shear the placed area of a triangle is |cof(A) a| (a: its area vector), so each point is weighted by its
    triangle's placed-over-prototype area ratio and the estimate is Σ w |n·s| V / Σ w.

    Parameters
    ----------
    scene : InstancedRayScene
        The placed prototypes (leaves and wood: wood shades, only leaves are sampled).
    leaf_of_triangle : sequence of (T_p,) int arrays
        Per prototype, the leaf of each triangle (-1 for wood).
    sun_direction : (3,) toward the sun.
    samples : int
        Points per instance (even, >= 2).
    """
    t0 = time.perf_counter()
    if samples < 2 or samples % 2:
        raise ValueError(f"samples must be an even number >= 2, got {samples}")
    sun = np.asarray(sun_direction, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    n = scene.n_instances
    half = samples // 2
    halves = np.zeros((n, 2))
    lin = scene.linear
    cof = cofactors(lin)
    offset = scene.offset_distance()
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    per_chunk = max(1, _CHUNK_POINTS // samples)
    done = 0
    for p, (proto, leaf) in enumerate(zip(scene.scenes, leaf_of_triangle)):
        leaf_tris = np.flatnonzero(np.asarray(leaf) >= 0)
        insts = np.flatnonzero(scene.prototype_of == p)
        if insts.size == 0 or leaf_tris.size == 0:
            continue
        tri = proto.triangles[leaf_tris]
        a_vec = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        cum = np.cumsum(np.linalg.norm(a_vec, axis=1))
        for lo in range(0, insts.size, per_chunk):
            chunk = insts[lo:lo + per_chunk]
            k = chunk.size
            shift = rng.random((k, 2, 1))
            target = ((np.arange(half)[None, None, :] + shift) / half * cum[-1]).reshape(k, samples)
            which = np.minimum(np.searchsorted(cum, target, side="right"), cum.size - 1)  # (k, samples)
            uv = rng.random((k, samples, 2))
            fold = uv.sum(axis=2) > 1.0
            uv[fold] = 1.0 - uv[fold]
            v0 = tri[which, 0]
            local = v0 + uv[..., :1] * (tri[which, 1] - v0) + uv[..., 1:] * (tri[which, 2] - v0)
            inst = np.repeat(chunk, samples)
            ids = leaf_tris[which.ravel()]
            world = np.einsum("kij,kj->ki", lin[inst], local.reshape(-1, 3)) + scene.translation[inst]
            normal = scene.world_normals(inst, ids)
            cos = normal @ sun
            # the placed-over-prototype area of each point's triangle (1 for rotations and uniform scales, up to
            # the scale squared, which cancels in the ratio)
            placed = np.linalg.norm(np.einsum("kij,kj->ki", cof[inst], a_vec[which.ravel()]), axis=1)
            weight = (placed / np.linalg.norm(a_vec[which.ravel()], axis=1)).reshape(k, samples)
            toward = cos != 0.0
            visible = np.zeros(inst.size, dtype=bool)
            origins = world[toward] + offset * np.sign(cos[toward])[:, None] * normal[toward]
            visible[toward] = ~scene.occluded(origins, np.broadcast_to(sun, origins.shape))
            value = (np.abs(cos) * visible).reshape(k, samples) * weight
            for h in range(2):
                s = slice(h * half, (h + 1) * half)
                halves[chunk, h] = value[:, s].sum(axis=1) / weight[:, s].sum(axis=1)
            done += k
            if progress is not None:
                progress(done, n)
    e = halves.mean(axis=1)
    den = float(np.linalg.norm(halves[:, 0] + halves[:, 1]))
    noise = float(np.linalg.norm(halves[:, 0] - halves[:, 1])) / den if den > 0 else 0.0
    e.flags.writeable = False
    return InstanceDirect(e, noise, int(done * samples), samples, time.perf_counter() - t0)

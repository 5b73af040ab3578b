"""Final gather: each leaf's scattered light from rays through the actual leaves (issue #15, beyond the seeds).

For a two-sided Lambertian leaf j, the irradiance from scattered light on its
two faces is

    E_scattered(j) = Σ_faces ∫_hemisphere L(x, ω) cos θ dω = Σ_faces π E_cos[L],

the expectation over cosine-distributed directions about each face normal.
A gather ray from a point x on leaf j along ω finds the surface point y it
sees; the radiance y sends back along -ω is its outgoing Lambertian radiance
on the side the ray arrives from (σ), from the light on its two faces:

    L(y) = (r E_σ(y) + t E_-σ(y)) / π       (leaf; wood: ρ E_σ(y) / π, opaque)

and E at y splits into the unscattered sun and the light scattered at least
once:

* **first bounce, exact in expectation**: the sun delivers |n_y·s| V(y) to
  the face of y that looks at the sun (V from a shadow ray at y, Embree, as
  in :mod:`foliage_tools.lighting.direct`), nothing to the other face. So a
  ray arriving on the sun's side sees r |n·s| V / π (reflected), one from the
  other side t |n·s| V / π (transmitted); wood reflects ρ |n·s| V / π on the
  sun side only.
* **higher orders, from a volume method** (LB or SPP): ``rest[k]`` is that
  method's E_scattered of the hit leaf k (both faces summed), taken as split
  evenly between the faces: L = (r + t) rest[k] / (2π). Wood hits take no
  higher orders (the methods give none for wood).

A ray that escapes sees no radiance (sun only: the sky is not part of
E_scattered, DESIGN.md section 3). The estimator of one leaf is the mean of
π L over its K rays per face, summed over the two faces: it needs no photon to
find the leaf, so every leaf gets the same number of samples, and the first
bounce -- most of the scattered light for dark leaves -- inherits nothing from
a volume model. Points on the leaf and directions are stratified (shifted
rank-1 lattices, :mod:`~foliage_tools.geometry.leafpoints`); two
independent halves give the sampling error ``noise_rel`` (relative RMS over
leaves and channels).

Pure numerics (numpy + Embree through :mod:`foliage_tools.geometry.rays`).
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from foliage_tools.geometry.rays import RayScene
from foliage_tools.geometry.leafpoints import LeafSampler, check_scene, lattice
from foliage_tools.lighting.optics import LeafOptics

__all__ = ["GatherInputs", "GatherParams", "GatherResult", "solve"]

#: Gather rays per unit of work (seeding, threading, memory: ~200 bytes a ray).
_CHUNK_RAYS = 1 << 19
#: Most rays per leaf (a chunk must hold one leaf).
MAX_RAYS = 1 << 16


@dataclass(frozen=True, eq=False)
class GatherInputs:
    """World-space triangles with leaf ids, the optics, the sun and the volume method's scattered light."""

    triangles: np.ndarray
    """(T, 3, 3) float64 vertices of every leaf and wood triangle of every instance."""
    leaf_of_triangle: np.ndarray
    """(T,) int leaf id 0..L-1, -1 for wood."""
    n_leaves: int
    optics: LeafOptics
    sun_direction: np.ndarray
    """(3,) toward the sun (normalised here)."""
    rest: np.ndarray | None = None
    """(L, 3) E_scattered of a volume method (both faces summed) for the higher orders; None: first bounce only."""

    def __post_init__(self) -> None:
        tri, leaf, n, sun = check_scene(self.triangles, self.leaf_of_triangle, self.n_leaves, self.sun_direction)
        if not isinstance(self.optics, LeafOptics):
            raise TypeError(f"optics must be a LeafOptics, got {type(self.optics).__name__}")
        if self.rest is not None:
            rest = np.asarray(self.rest, dtype=np.float64)
            if rest.shape != (n, 3) or not np.all(np.isfinite(rest)) or np.any(rest < 0):
                raise ValueError(f"rest must be ({n}, 3) finite and >= 0, got {rest.shape}")
            object.__setattr__(self, "rest", rest)
        object.__setattr__(self, "triangles", tri)
        object.__setattr__(self, "leaf_of_triangle", leaf)
        object.__setattr__(self, "n_leaves", n)
        object.__setattr__(self, "sun_direction", sun)


@dataclass(frozen=True)
class GatherParams:
    rays_per_leaf: int = 256
    """Gather rays per leaf (both faces together; even, ≥ 4: two halves per face). Each costs one more
    shadow ray where it hits something."""
    seed: int = 0
    workers: int | None = None
    """Threads; None: all cores. Does not change the results."""

    def __post_init__(self) -> None:
        k = self.rays_per_leaf
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 4 or k % 4 or k > MAX_RAYS:
            raise ValueError(f"rays_per_leaf must be a multiple of 4 (two halves per face) up to {MAX_RAYS}, got {k!r}")


@dataclass(frozen=True, eq=False)
class GatherResult:
    e_scattered: np.ndarray
    """(L, 3) irradiance from scattered sunlight, both faces summed."""
    e_first: np.ndarray
    """(L, 3) its first-bounce part (light scattered exactly once), exact in expectation."""
    noise_rel: float
    """Relative RMS sampling error of ``e_scattered`` over leaves and channels (two halves)."""
    rays: int
    seconds: float


def _cosine(axis: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Cosine-distributed directions about unit ``axis`` (..., 3) (Malley's method; Duff et al. 2017 basis)."""
    sg = np.where(axis[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sg + axis[..., 2])
    b = axis[..., 0] * axis[..., 1] * a
    t1 = np.stack([1.0 + sg * axis[..., 0] ** 2 * a, sg * b, -sg * axis[..., 0]], axis=-1)
    t2 = np.stack([b, sg + axis[..., 1] ** 2 * a, -axis[..., 1]], axis=-1)
    r = np.sqrt(u1)
    phi = 2.0 * math.pi * u2
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    return (r * np.cos(phi))[..., None] * t1 + (r * np.sin(phi))[..., None] * t2 + z[..., None] * axis


def solve(inputs: GatherInputs, params: GatherParams = GatherParams()) -> GatherResult:
    """Scattered light of every leaf by a final gather (module docstring)."""
    start = time.perf_counter()
    tri, leaf, n_leaves, sun = inputs.triangles, inputs.leaf_of_triangle, inputs.n_leaves, inputs.sun_direction
    opt = inputs.optics
    k = int(params.rays_per_leaf)
    q = k // 4  # rays per face and half
    workers = int(params.workers) if params.workers is not None else max(1, os.cpu_count() or 1)
    scene = RayScene(tri)
    normals = scene.normals
    offset = scene.offset_distance()
    cos_s = normals @ sun
    is_wood = leaf < 0
    # per triangle, what a ray arriving on the sun's side / the other side sees of the first bounce (× |n·s| V / π)
    front = np.where(is_wood[:, None], opt.wood_reflectance[None, :], opt.reflectance[None, :])
    back = np.where(is_wood[:, None], 0.0, opt.transmittance[None, :])
    rest = inputs.rest
    sampler = LeafSampler(tri, leaf, n_leaves)
    has_area = sampler.has_area
    per_chunk = max(1, _CHUNK_RAYS // k)
    chunks = [(a, min(a + per_chunk, n_leaves)) for a in range(0, n_leaves, per_chunk)]
    seeds = np.random.SeedSequence(params.seed).spawn(len(chunks))
    base_lattice = lattice(q)

    def run(c: int):
        a, b = chunks[c]
        rng = np.random.default_rng(seeds[c])
        ids = np.arange(a, b)[has_area[a:b]]
        out = np.zeros((b - a, 2, 3))  # (leaf, half, channel): full scattered estimate of each half
        first = np.zeros((b - a, 3))
        if ids.size == 0:
            return out, first
        n = ids.size
        # (leaf, face, half, q) points: a position lattice and a direction lattice, independently shifted
        up = np.mod(base_lattice + rng.random((n, 2, 2, 1, 2)), 1.0)
        ud = np.mod(base_lattice + rng.random((n, 2, 2, 1, 2)), 1.0)
        t, p = sampler.points(ids, up)
        face = np.where(np.arange(2)[None, :, None, None] == 0, 1.0, -1.0)
        axis = face[..., None] * normals[t]
        d = _cosine(axis, ud[..., 0], ud[..., 1])
        o = p + offset * axis
        hit, dist = scene.intersect(o.reshape(-1, 3), d.reshape(-1, 3))
        radiance_pi = np.zeros((hit.size, 3))  # π L seen by each ray
        first_pi = np.zeros((hit.size, 3))
        ok = hit >= 0
        if np.any(ok):
            h = hit[ok]
            dd = d.reshape(-1, 3)[ok]
            y = o.reshape(-1, 3)[ok] + dist[ok, None] * dd
            cs = cos_s[h]
            # the hit face is the one facing the ray's origin: it is the sun's side when n·s and n·(-d) agree
            sun_side = (cs * -(np.einsum("ij,ij->i", normals[h], dd))) > 0.0
            lit = np.zeros(h.size, dtype=bool)
            cand = cs != 0.0
            if np.any(cand):
                side = np.where(cs[cand] >= 0.0, 1.0, -1.0)[:, None] * normals[h[cand]]
                origins = y[cand] + offset * side
                lit[cand] = ~scene.occluded(origins, np.broadcast_to(sun, origins.shape))
            coeff = np.where(sun_side[:, None], front[h], back[h])
            first_pi[ok] = coeff * (np.abs(cs) * lit)[:, None]
            radiance_pi[ok] = first_pi[ok]
            if rest is not None:
                kl = leaf[h]
                isl = kl >= 0
                albedo = opt.reflectance + opt.transmittance
                radiance_pi[np.flatnonzero(ok)[isl]] += 0.5 * albedo[None, :] * rest[kl[isl]]
        # E = Σ_faces mean(π L): per half, (mean over its q rays) summed over the two faces
        rp = radiance_pi.reshape(n, 2, 2, q, 3).mean(axis=3).sum(axis=1)  # (n, half, 3)
        fp = first_pi.reshape(n, 2, 2, q, 3).mean(axis=3).sum(axis=1).mean(axis=1)
        local = ids - a
        out[local] = rp
        first[local] = fp
        return out, first

    halves = np.zeros((n_leaves, 2, 3))
    e_first = np.zeros((n_leaves, 3))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for c, (vals, fp) in enumerate(pool.map(run, range(len(chunks)))):
            a, b = chunks[c]
            halves[a:b] = vals
            e_first[a:b] = fp
    e = halves.mean(axis=1)
    den = float(np.linalg.norm(halves[:, 0] + halves[:, 1]))
    noise = float(np.linalg.norm(halves[:, 0] - halves[:, 1])) / den if den > 0 else 0.0
    return GatherResult(e, e_first, noise, int(np.count_nonzero(has_area)) * k, time.perf_counter() - start)

"""Optical depth and thickness from leaf intersection counts (shinya2013 eq. (29), ray path).

For a point x and a direction v (toward the light), shinya2013 eq. (29) counts
the leaves a ray crosses through the actual geometry: n+ toward v and n-
toward -v, and sets the depth d = n+/σt and the thickness w = (n+ + n-)/σt.
These d and w are *lengths* in a medium of extinction coefficient σt; the
plane-parallel formulas use the optical depths σt·d and σt·w, so

    optical depth u = n+,     optical thickness U = n+ + n-.

Why one crossing is one unit of optical depth (the scale of the grid path,
:mod:`~foliage_tools.lighting.depth`, which integrates G·LAD along the ray):
take opaque leaves of one-sided area a, centres placed at random with n per
unit volume (one-sided leaf-area density LAD = n a) and orientations drawn
from a distribution with projection function G(v) = E|n_leaf · v| (Ross;
0.5 for spherical = isotropic orientations). A leaf is crossed by a ray
segment of length l when its centre lies in a slab-shaped volume of
cross-section a |n_leaf · v| around the segment, so the expected number of
crossings is

    E[n] = n · E[a |n_leaf · v|] · l = G(v) · LAD · l,

exactly the grid path's optical depth. Crossings of a random (Poisson)
medium are Poisson distributed, and an opaque leaf stops the ray, so the
expected transmittance P(n = 0) = exp(-E[n]) = exp(-G·LAD·l) is Beer-Lambert
with σt = G·LAD: σt is the expected number of crossings per unit length, and σt·d = n+
needs no scale factor (``crossing_depth`` = 1). A single ray's count is one
sample of that Poisson variable; :func:`leaf_ray_depth_samples` can average
several rays started at random points on each leaf.

The mean count is the optical depth, not a leaf's transmittance. Per ray an
opaque leaf transmits 1 when n = 0 and 0 otherwise; the direct sun on one
leaf is the fraction of its area whose ray crosses nothing, whose mean is
exp(-λ), λ = G·LAD·l. The K rays from one card cross largely the same
leaves (a card's shadow is as wide as the card), so the per-leaf mean count
n̄ keeps a leaf-to-leaf spread that more rays do not remove, and since exp is
convex the leaf average of exp(-n̄) exceeds exp(-λ) (Jensen). Measured in
examples/make_layer.py's default layer (10 × 10 × 1.5 m, LAI 3, 0.1 m cards,
sun at elevation 60°; inner leaves of the deepest fifth, λ = 1.56): the mean
of n̄ is 1.56 (unbiased), but its variance over leaves is 0.74 at K = 16 and
0.72 at K = 64 (independent rays would give λ/K = 0.10 and 0.02), so exp(-n̄)
averages to 0.289 against exp(-λ) = 0.212 (+36 %; weighted by |n·s|, the
+34 % that ``foliage spp --depth rays`` gave there against Beer-Lambert),
while the visible fraction averages to 0.216 (+2 %, within that bin's
sampling noise). :func:`leaf_ray_depths` returns the visible fraction
(``sun_visible``, ``sample_visible``) beside the depths, from the same rays:
E_direct = |n·s| × visible fraction.

Counting rules: every triangle hit is one crossing (a leaf card of two
coplanar triangles is crossed through one of them); hits on triangles of the
leaf a ray starts on are not counted (``skip_ids``). Geometry that doubles
leaves (a front and a back copy of each card) would count twice: such an
asset needs its copies removed first.

Pure numpy + embreex (through :class:`~foliage_tools.geometry.rays.RayScene`);
no files, no printing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from foliage_tools.geometry.rays import RayScene, unit_rows
from foliage_tools.geometry.rays import count_crossings as crossing_counts  # one implementation, in geometry.rays
from foliage_tools.lighting.depth import DepthSamples

__all__ = [
    "CROSSING_DEPTH",
    "LeafRayDepths",
    "crossing_counts",
    "leaf_ray_depth_samples",
    "leaf_ray_depths",
    "prototype_leaf_ids",
    "ray_depth_samples",
]

#: Optical depth of one leaf crossing (see the module docstring: σt · n/σt).
CROSSING_DEPTH = 1.0


def ray_depth_samples(
    scene: RayScene,
    points,
    *,
    sun_direction,
    directions,
    skip_ids=None,
    id_of_triangle=None,
    crossing_depth: float = CROSSING_DEPTH,
    workers: int = 1,
) -> DepthSamples:
    """Optical depth and chord thickness per point from crossing counts (shinya2013 eq. (29)).

    ``sample_depth[p, j]`` = crossing_depth · n+ toward ``directions[j]``,
    ``sample_thickness`` = crossing_depth · (n+ + n-); likewise toward the sun.
    ``crossing_depth`` = 1 puts the counts on the optical-depth scale of the
    grid path (module docstring). Directions point toward the light.
    """
    if not np.isfinite(crossing_depth) or crossing_depth < 0:
        raise ValueError(f"crossing_depth must be finite and >= 0, got {crossing_depth}")
    sun = unit_rows(sun_direction, "sun_direction")
    if sun.shape[0] != 1:
        raise ValueError("sun_direction must be one direction (3,)")
    dirs = unit_rows(directions, "directions")
    all_dirs = np.concatenate([sun, dirs, -sun, -dirs])
    c = crossing_counts(scene, points, all_dirs, skip_ids=skip_ids, id_of_triangle=id_of_triangle, workers=workers)
    return _to_samples(c.astype(np.float64) * crossing_depth, dirs.shape[0])


def _to_samples(depth: np.ndarray, n: int) -> DepthSamples:
    toward, away = depth[:, : n + 1], depth[:, n + 1 :]
    return DepthSamples(
        sun_depth=toward[:, 0],
        sun_thickness=toward[:, 0] + away[:, 0],
        sample_depth=toward[:, 1:],
        sample_thickness=toward[:, 1:] + away[:, 1:],
    )


def prototype_leaf_ids(proto) -> np.ndarray:
    """(T,) leaf id of every triangle of ``proto.triangles(leaves=True)``, in that order (-1: degenerate face)."""
    ids = [
        proto.leaves.face_leaf_ids[i][m.face_of_triangle] for i, m in enumerate(proto.meshes) if m.is_leaf
    ]
    return np.concatenate(ids).astype(np.int64) if ids else np.zeros(0, np.int64)


@dataclass(frozen=True)
class LeafRayDepths:
    """Per-leaf depths and visible fractions from one set of crossing counts (:func:`leaf_ray_depths`)."""

    depths: DepthSamples
    """Mean counts per leaf as optical depths (what :func:`leaf_ray_depth_samples` returns)."""
    sun_visible: np.ndarray
    """(L,) fraction of the leaf's ray origins whose ray toward the sun crosses no leaf (own leaf skipped)."""
    sample_visible: np.ndarray
    """(L, N) the same toward each sample direction."""


def leaf_ray_depth_samples(
    triangles,
    leaf_of_triangle,
    *,
    sun_direction,
    directions,
    rays_per_leaf: int = 1,
    centers=None,
    seed: int = 0,
    crossing_depth: float = CROSSING_DEPTH,
    workers: int = 1,
) -> DepthSamples:
    """Per-leaf depths from crossings through the leaf triangles (:func:`leaf_ray_depths`, depths only).

    The depths are mean counts: use them as optical depths, not through
    exp(-depth) as a leaf's share of direct light (module docstring; the
    visible fraction is :attr:`LeafRayDepths.sun_visible`).
    """
    return leaf_ray_depths(
        triangles, leaf_of_triangle, sun_direction=sun_direction, directions=directions, rays_per_leaf=rays_per_leaf,
        centers=centers, seed=seed, crossing_depth=crossing_depth, workers=workers,
    ).depths


def leaf_ray_depths(
    triangles,
    leaf_of_triangle,
    *,
    sun_direction,
    directions,
    rays_per_leaf: int = 1,
    centers=None,
    seed: int = 0,
    crossing_depth: float = CROSSING_DEPTH,
    workers: int = 1,
) -> LeafRayDepths:
    """Per-leaf depths and visible fractions from crossings through the leaf triangles, not counting the leaf itself.

    Parameters
    ----------
    triangles : (T, 3, 3)
        Leaf triangles (e.g. ``Prototype.triangles(leaves=True)``).
    leaf_of_triangle : (T,) int
        Leaf id per triangle (:func:`prototype_leaf_ids`); ids 0..L-1, -1 ignored as origins.
    rays_per_leaf : int
        1: one ray per direction from each leaf's ``centers`` (area-weighted
        centroid, computed here when not given). K > 1: K origins drawn
        uniformly (seeded) on each leaf's triangles, counts averaged — the
        area average of DESIGN.md sec. 3 (the count variance shrinks by much
        less than K: the rays of one card cross largely the same leaves).

    Returns
    -------
    LeafRayDepths
        Mean counts × ``crossing_depth`` as depths, and the fraction of each
        leaf's origins with zero crossings toward the sun and each direction
        (with K = 1: 0 or 1 per leaf).
    """
    tri = np.asarray(triangles, dtype=np.float64)
    ids = np.asarray(leaf_of_triangle, dtype=np.int64).reshape(-1)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3) or ids.shape != (tri.shape[0],):
        raise ValueError("triangles must be (T, 3, 3) with one leaf id per triangle")
    if rays_per_leaf < 1:
        raise ValueError(f"rays_per_leaf must be >= 1, got {rays_per_leaf}")
    ok = ids >= 0
    n_leaves = int(ids[ok].max()) + 1 if np.any(ok) else 0
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    scene = RayScene(tri)
    sun = unit_rows(sun_direction, "sun_direction")
    dirs = unit_rows(directions, "directions")
    all_dirs = np.concatenate([sun, dirs, -sun, -dirs])
    if rays_per_leaf == 1:
        if centers is None:
            cen = tri.mean(axis=1)
            leaf_area = np.bincount(ids[ok], weights=area[ok], minlength=n_leaves)
            centers = np.stack(
                [np.bincount(ids[ok], weights=area[ok] * cen[ok, k], minlength=n_leaves) for k in range(3)], axis=1
            ) / np.maximum(leaf_area, 1e-300)[:, None]
        origins = np.asarray(centers, dtype=np.float64)
        owner = np.arange(origins.shape[0])
    else:
        rng = np.random.default_rng(seed)
        tri_idx = np.flatnonzero(ok)
        # per leaf, K triangles chosen with probability ∝ area, then a uniform point on each
        order = tri_idx[np.argsort(ids[tri_idx], kind="stable")]
        leaf_sorted = ids[order]
        cum = np.cumsum(area[order])
        start = np.searchsorted(leaf_sorted, np.arange(n_leaves), side="left")
        stop = np.searchsorted(leaf_sorted, np.arange(n_leaves), side="right")
        base = np.where(start > 0, cum[np.maximum(start - 1, 0)], 0.0)
        total = cum[np.maximum(stop - 1, 0)] - base
        empty = (stop == start) | ~(total > 0.0)
        if np.any(empty):
            raise ValueError(f"leaf {int(np.flatnonzero(empty)[0])} has no triangle of positive area to start rays on")
        owner = np.repeat(np.arange(n_leaves), rays_per_leaf)
        target = base[owner] + rng.random(owner.size) * total[owner]
        pick = order[np.minimum(np.searchsorted(cum, target, side="right"), len(order) - 1)]
        r1, r2 = rng.random(owner.size), rng.random(owner.size)
        s = np.sqrt(r1)
        v = tri[pick]
        origins = (1 - s)[:, None] * v[:, 0] + (s * (1 - r2))[:, None] * v[:, 1] + (s * r2)[:, None] * v[:, 2]
    c = crossing_counts(scene, origins, all_dirs, skip_ids=owner, id_of_triangle=ids, workers=workers)
    k = 1 if rays_per_leaf == 1 else rays_per_leaf
    visible = (c[:, : dirs.shape[0] + 1] == 0).reshape(-1, k, dirs.shape[0] + 1).mean(axis=1)
    mean = c.astype(np.float64).reshape(-1, k, c.shape[1]).mean(axis=1)
    return LeafRayDepths(
        depths=_to_samples(mean * crossing_depth, dirs.shape[0]), sun_visible=visible[:, 0], sample_visible=visible[:, 1:]
    )

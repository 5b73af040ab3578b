"""Monte Carlo reference: light transport through the actual leaf and wood triangles.

The ground truth every other method is compared with (DESIGN.md sections 3
and 4). Photons are traced with Embree (:mod:`foliage_tools.geometry.rays`)
through the scene's triangles; leaves are two-sided Lambertian scatterers
(reflectance r and transmittance t per RGB channel), wood is opaque
Lambertian (reflectance ρ); there is no ground.

Sources
-------
* **Sun**: a parallel beam along ``-sun_direction`` with irradiance 1 on a
  plane perpendicular to it. By default (``sun_sampling="surface"``) its
  first hits are drawn on the surfaces themselves: points on every triangle
  (leaf and wood) with density ∝ |n·s| per unit area, by systematic sampling
  over the triangles' projected areas A|n·s| (so a triangle's count per
  batch is its expected count rounded up or down), each kept only if a
  shadow ray toward the sun escapes; each carries P / paths per channel,
  P = Σ A|n·s|. That is exactly the beam's first-hit distribution (power
  density |n·s| on the lit parts), spread evenly over the leaves, which
  lowers E_direct's noise (on the Webots oak 0.024 against the beam's 0.042
  at 2M paths; each costs one shadow ray, the shadowed ones are dropped). The
  first hits are split (``split`` photons of 1/split the power each, their
  own events) so one shadow ray serves several paths. With
  ``sun_sampling="beam"`` photon origins are uniform over a rectangle
  perpendicular to the sun that covers the projection of the scene's
  bounding box (enlarged by 1e-3 of its diagonal), placed beyond the scene;
  every photon carries ``area(rectangle) / paths``. Both are unbiased for
  the same tallies (a test checks that they agree leaf by leaf).
* **Sky** (optional): radiance ``sky_radiance`` (RGB, sr⁻¹ per unit sun
  irradiance) from every direction of the hemisphere about ``up``, zero from
  below. A direction ω is drawn uniformly on the hemisphere (pdf 1/2π) and the
  photon's origin uniformly on a disc of radius R perpendicular to ω (R: the
  bounding sphere), placed outside the scene; power per photon
  ``L · 2π · πR² / sky_paths``. (Each direction contributes a parallel beam
  of irradiance L dω on the disc, so a horizontal plane receives π L, the
  uniform-sky irradiance.)
* In a **periodic** layer (``period`` set, ``up`` = +z) photons enter through
  the top of one cell: sun photons at uniform (x, y) with power
  ``μ0 · px · py / paths`` (μ0 = sun·up, the horizontal irradiance), sky
  photons with cosine-distributed directions and power ``π L px py / sky_paths``.

Scattering and weights (why RGB weights, and why no bounce cap)
---------------------------------------------------------------
Each photon carries an RGB power vector W, so the three channels share one
geometric path: one set of rays instead of three, and the channels' errors
are correlated, which keeps colour ratios smooth. At a hit with per-channel
reflectance r, transmittance t (wood: r = ρ, t = 0) let

    a_r = Σ_c W_c r_c,   a_t = Σ_c W_c t_c,   a_a = Σ_c W_c (1 - r_c - t_c).

While the photon is bright (Σ_c W_c at least ``survival_weight`` times its
launch weight), absorption is taken by its expected value: W (1 - r - t) is
deposited and the photon is reflected or transmitted with probabilities
a_r/(a_r + a_t), a_t/(a_r + a_t), its weight becoming W r (a_r + a_t)/a_r or
W t (a_r + a_t)/a_t. Below that weight one of the three events is drawn with
probabilities ∝ a_r, a_t, a_a (the analog scheme): the weight becomes
W r (a/a_r), W t (a/a_t), or W (1 - r - t) (a/a_a) is deposited and the
path ends, with a = a_r + a_t + a_a = Σ_c W_c. In both, each channel's
expectation is exactly the analog one (E[W'] = W r + W t, E[absorbed] =
W (1 - r - t)), so the estimator is unbiased; the analog event *is* the
Russian roulette, so there is no bounce cap, and every event passes on or
deposits exactly the channel sum it received: each photon's launched power
ends up, in full, either absorbed somewhere or escaped, and weights never
exceed the launch weight -- no fireflies. Per channel, energy balance holds
in expectation; summed over the channels it holds per path, exactly up to
rounding. Why expected-value absorption pays: with dark leaves (albedo
0.06-0.28 for geist2008) the analog scheme ends ~85 % of paths at their
first hit, so few photons carry the scattered light whose per-leaf tally is
the quantity of interest; on the Webots oak it cut E_scattered's variance
per path by ~7x. (A safety limit,
``max_events``, abandons paths that have scattered 1e5 times -- reachable only
in closed geometry with albedo 1 -- and reports them in ``truncated``.) The
price of one path for three channels: a channel much darker than the others
(blue in the geist2008 preset) is sampled through paths chosen for the
brighter ones, so its relative noise is larger than if it were traced alone.

A reflected photon leaves into the hemisphere on its incident side, a
transmitted one into the other, both cosine-distributed about the leaf
normal (Lambertian). New rays start ``offset_distance`` off the surface on
the side they leave to (see :mod:`foliage_tools.geometry.rays`).

Tallies (per leaf, RGB; powers in sun-irradiance × stage-unit²)
--------------------------------------------------------------
Every time a photon arrives at a leaf, its power W (before the event) is added
to one of four tallies, chosen by the photon's source and whether it has been
scattered before; each is divided by the leaf's one-sided area:

* ``e_direct``: sun photons on their first hit. Power intercepted by the leaf
  from the unscattered beam / area = the unscattered sun irradiance on both
  faces summed, area-averaged (DESIGN.md section 3); an unshadowed leaf with
  normal n gets |n·s|.
* ``e_scattered``: sun photons scattered at least once (by leaves or wood):
  irradiance from scattered sunlight, both faces summed, area-averaged.
* ``e_sky``: sky photons on their first hit (unscattered sky light; an
  isolated leaf of any orientation gets π L).
* ``e_sky_scattered``: sky photons scattered at least once.

DESIGN.md's E_direct is *unscattered sun* light, so unscattered sky light is
kept out of both E_direct and E_scattered, and E_scattered is sunlight only:
a sun-only method compares with (e_direct, e_scattered) whatever the sky.
:attr:`ReferenceResult.e_total` sums all four.

Also tallied: ``absorbed`` power per leaf, ``absorbed_wood``, ``escaped``
power (photons that leave the scene, including those that never hit
anything: with the surface source, the beam's power that reaches no surface,
``incident - intercepted``), and ``incident`` (power launched = rectangle/disc
areas times irradiance). ``absorbed.sum(0) + absorbed_wood + escaped = incident`` in
expectation per channel, and exactly (to rounding) summed over channels.

Determinism and threads
-----------------------
Paths are split into fixed batches (sizes depend only on ``paths`` and
``batch_size``), each with its own generator from
``np.random.SeedSequence(seed).spawn``; batches run on a thread pool and their
tallies are reduced in batch order. Results are therefore bitwise identical
for a seed, whatever the number of workers. The per-bounce work runs without
the GIL (Embree's traversal in embreex, the numba kernel that tallies and
scatters, numpy's random fills), so batches overlap on several cores.

Noise estimate and stopping at a target
---------------------------------------
The batches are split into two independent halves A (even batch indices,
N_A paths) and B (odd, N_B). Let a and b be the E_scattered estimates of each
half alone (each normalised as a full estimate) and x = (N_A a + N_B b)/N the
full-run result. Per element, Var(a) = v N/N_A and Var(b) = v N/N_B, where v
is the variance of x, so E‖a - b‖² = N (1/N_A + 1/N_B) Σ v. The full run's
relative RMS noise, in the same form as the error measure of DESIGN.md
(sqrt(Σ (x - E x)²/Σ (E x)²)), is therefore estimated as

    noise_rel = ‖a - b‖ / (sqrt(N/N_A + N/N_B) ‖x‖),

which for equal halves is ‖a - b‖ / (2‖x‖) = ‖a - b‖ / ‖a + b‖ (the form of
:func:`foliage_tools.bench.metrics.noise_floor`).
An exact method would show a relative RMS error ≈ noise_rel against this reference.
The same estimate is reported for E_direct (``noise_rel_direct``) and the total.
With ``noise_target`` the run stops after the first even number of sun
batches (≥ 4) whose E_scattered estimate is at or below the target; the
batches are whole ``batch_size`` batches checked in order, so the result is
the same as that many paths traced without a target.

Caveats: it is an estimate from a single pair of halves, so its own relative
spread is about 1/sqrt(2K) for K effectively independent leaf values (a few %
for hundreds of leaves, but meaningless for a handful: with one lit leaf it
can be off by a factor of several); and ‖x‖ contains the noise too, so at
large noise (≳ 20 %) it reads a few % low.

Pure numerics: no files, no printing.
"""

from __future__ import annotations

import functools
import itertools
import math
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import cast

import numpy as np
from numba import njit

from foliage_tools.geometry.instanced import InstancedRayScene, cofactors
from foliage_tools.geometry.rays import PeriodicRayScene, RayScene
from foliage_tools.lighting.optics import LeafOptics

__all__ = ["Placements", "ReferenceInputs", "ReferenceParams", "ReferenceResult", "solve"]

#: Tally categories (index into the per-leaf incidence tallies).
_SUN_DIRECT, _SUN_SCATTERED, _SKY_DIRECT, _SKY_SCATTERED = range(4)

#: Relative enlargement of the sun rectangle / sky disc beyond the scene's
#: bounds, so that float rounding never lets geometry at the very edge miss.
_SOURCE_MARGIN = 1e-3


def _unit(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {v!r}")
    n = float(np.linalg.norm(a))
    if n == 0.0:
        raise ValueError(f"{name} must not be the zero vector")
    a = a / n
    a.flags.writeable = False
    return a


def _set_frozen(obj, **fields) -> None:
    """Set a frozen dataclass's fields after validation, each array made read-only."""
    for name, value in fields.items():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        object.__setattr__(obj, name, value)


@dataclass(frozen=True, eq=False)
class Placements:
    """A forest as a few prototypes placed many times, traced without copying them (:mod:`foliage_tools.geometry.instanced`).

    Leaf k of instance n tallies into leaf ``leaf_offset[n] + k`` of the result: with every instance's own
    offsets the result is per leaf of the world, with the prototype's offsets for all its instances it pools each
    prototype leaf over its instances (power over area summed over them), so the tallies grow with the prototypes,
    not the instances. Each instance's own means are tallied as well (:attr:`ReferenceResult.instance_direct`).
    """

    triangles: Sequence[np.ndarray]
    """Per prototype, (T_p, 3, 3) float64 vertices in the prototype's frame."""
    leaf_of_triangle: Sequence[np.ndarray]
    """Per prototype, (T_p,) int leaf index of each triangle within the prototype, -1 for wood."""
    transforms: np.ndarray
    """(N, 4, 4) world-from-prototype matrices, column-vector convention."""
    prototype_of: np.ndarray
    """(N,) prototype of each instance."""
    leaf_offset: np.ndarray
    """(N,) the result's leaf index of each instance's leaf 0."""

    def __post_init__(self) -> None:
        tris = tuple(np.asarray(t, dtype=np.float64) for t in self.triangles)
        leaves = tuple(np.asarray(v).astype(np.int64) for v in self.leaf_of_triangle)
        if len(tris) != len(leaves):
            raise ValueError(f"{len(tris)} prototypes' triangles but {len(leaves)} leaf_of_triangle arrays")
        for p, (t, v) in enumerate(zip(tris, leaves)):
            if t.ndim != 3 or t.shape[1:] != (3, 3) or not np.all(np.isfinite(t)):
                raise ValueError(f"prototype {p}: triangles must be finite with shape (T, 3, 3), got {t.shape}")
            if v.shape != (t.shape[0],) or (v.size and v.min() < -1):
                raise ValueError(f"prototype {p}: leaf_of_triangle must be (T,) = ({t.shape[0]},) ids >= -1")
        proto = np.asarray(self.prototype_of, dtype=np.int64).reshape(-1)
        offset = np.asarray(self.leaf_offset, dtype=np.int64).reshape(-1)
        m = np.asarray(self.transforms, dtype=np.float64)
        if m.shape != (proto.size, 4, 4) or offset.shape != proto.shape:
            raise ValueError(f"transforms {m.shape}, prototype_of {proto.shape} and leaf_offset {offset.shape} must "
                             "describe the same N instances: (N, 4, 4), (N,), (N,)")
        if proto.size and (proto.min() < 0 or proto.max() >= len(tris)):
            raise ValueError(f"prototype_of must index the {len(tris)} prototypes")
        for a in (*tris, *leaves):
            a.flags.writeable = False
        _set_frozen(self, triangles=tris, leaf_of_triangle=leaves, prototype_of=proto, leaf_offset=offset, transforms=m)

    @property
    def n_instances(self) -> int:
        return int(self.prototype_of.shape[0])

    def leaf_counts(self) -> list[int]:
        """Leaves of each prototype (1 + its largest leaf id)."""
        return [int(v.max()) + 1 if v.size and v.max() >= 0 else 0 for v in self.leaf_of_triangle]

    @property
    def n_result_leaves(self) -> int:
        """Leaves the result tallies into: past the last instance's last leaf."""
        counts = self.leaf_counts()
        return max((int(o) + counts[p] for o, p in zip(self.leaf_offset, self.prototype_of)), default=0)

    @functools.cached_property
    def areas(self) -> tuple[np.ndarray, np.ndarray]:
        """One-sided world leaf areas: (:attr:`n_result_leaves`,) of the result's leaves (summed over the instances
        tallying into each) and (N,) of each instance. A placed triangle's area is |cof(A) a| (a: its area vector
        in the prototype, cof(A) = det(A) A⁻ᵀ)."""
        leaf_area = np.zeros(self.n_result_leaves)
        inst_area = np.zeros(self.n_instances)
        cof = cofactors(self.transforms[:, :3, :3])
        for p, (t, v) in enumerate(zip(self.triangles, self.leaf_of_triangle)):
            sel = np.flatnonzero(self.prototype_of == p)
            on = v >= 0
            if sel.size and on.any():
                a = 0.5 * np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[on]
                _placed_areas(np.ascontiguousarray(cof[sel]), sel, a, v[on], self.leaf_offset, leaf_area, inst_area)
        return leaf_area, inst_area


@njit(cache=True, nogil=True)
def _placed_areas(cof, instances, a, leaf, leaf_offset, leaf_area, inst_area):
    """Add |cof_n a_t| of every leaf triangle t placed by every instance n to its result leaf and its instance."""
    for q in range(instances.shape[0]):
        n = instances[q]
        total = 0.0
        for t in range(a.shape[0]):
            x = cof[q, 0, 0] * a[t, 0] + cof[q, 0, 1] * a[t, 1] + cof[q, 0, 2] * a[t, 2]
            y = cof[q, 1, 0] * a[t, 0] + cof[q, 1, 1] * a[t, 1] + cof[q, 1, 2] * a[t, 2]
            z = cof[q, 2, 0] * a[t, 0] + cof[q, 2, 1] * a[t, 1] + cof[q, 2, 2] * a[t, 2]
            area = math.sqrt(x * x + y * y + z * z)
            leaf_area[leaf_offset[n] + leaf[t]] += area
            total += area
        inst_area[n] += total


@dataclass(frozen=True, eq=False)
class ReferenceInputs:
    """The scene as the Monte Carlo reference sees it (world space, plain arrays)."""

    triangles: np.ndarray
    """(T, 3, 3) float64 triangle vertices, world space (stage units)."""
    leaf_of_triangle: np.ndarray
    """(T,) int: leaf index 0..L-1 of each triangle, -1 for wood."""
    leaf_area: np.ndarray
    """(L,) one-sided area of each leaf (stage units²), > 0. Its length is the number of leaves L."""
    optics: LeafOptics
    """Leaf reflectance / transmittance and wood reflectance (RGB)."""
    sun_direction: np.ndarray
    """(3,) direction *toward* the sun (normalised on construction)."""
    sky_radiance: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # array-like in, ndarray after __post_init__
    """(3,) uniform radiance of the upper hemisphere about ``up``, per unit sun irradiance (sr⁻¹), ≥ 0."""
    up: np.ndarray = (0.0, 0.0, 1.0)  # type: ignore[assignment]  # array-like in, ndarray after __post_init__
    """(3,) the up direction (normalised on construction); defines the sky hemisphere."""
    period: tuple[float, float] | None = None
    """If set, (px, py): the geometry is one cell of an infinite layer repeated along x and y
    (requires ``up`` = +z and the sun above the horizon). For tests against plane-parallel solvers."""
    cell_origin: tuple[float, float] = (0.0, 0.0)
    """Lower (x, y) corner of the periodic cell."""
    placements: Placements | None = None
    """If set, the scene is these placed prototypes, traced without copies; ``triangles`` and
    ``leaf_of_triangle`` must then be empty, and ``leaf_area`` holds the area of each result leaf
    (summed over the instances that tally into it)."""

    def __post_init__(self) -> None:
        tri = np.asarray(self.triangles, dtype=np.float64)
        if self.placements is not None:
            if not isinstance(self.placements, Placements):
                raise TypeError(f"placements must be a Placements, got {type(self.placements).__name__}")
            if len(tri) or self.period is not None:
                raise ValueError("placements replace triangles (give an empty (0, 3, 3) array) and cannot be periodic")
            need = self.placements.n_result_leaves
            if need > np.asarray(self.leaf_area).size:
                raise ValueError(f"placements tally into {need} leaves but leaf_area has {np.asarray(self.leaf_area).size}")
        if tri.ndim != 3 or tri.shape[1:] != (3, 3):
            raise ValueError(f"triangles must have shape (T, 3, 3), got {tri.shape}")
        if not np.all(np.isfinite(tri)):
            raise ValueError("triangles contain NaN or infinite coordinates")
        leaf = np.asarray(self.leaf_of_triangle)
        if leaf.shape != (tri.shape[0],) or not np.issubdtype(leaf.dtype, np.integer):
            raise ValueError(
                f"leaf_of_triangle must be (T,) = ({tri.shape[0]},) integers, got {leaf.shape} {leaf.dtype}"
            )
        area = np.asarray(self.leaf_area, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(area)) or np.any(area <= 0):
            raise ValueError("leaf_area must be positive and finite for every leaf")
        leaf = leaf.astype(np.int64)
        if leaf.size and (leaf.min() < -1 or leaf.max() >= area.size):
            raise ValueError(
                f"leaf_of_triangle must be -1 (wood) or a leaf index below L = {area.size} (len(leaf_area)), "
                f"got values in [{leaf.min()}, {leaf.max()}]"
            )
        if not isinstance(self.optics, LeafOptics):
            raise TypeError(f"optics must be a LeafOptics, got {type(self.optics).__name__}")
        sky = np.asarray(self.sky_radiance, dtype=np.float64).reshape(-1)
        if sky.shape == (1,):
            sky = np.repeat(sky, 3)
        if sky.shape != (3,) or not np.all(np.isfinite(sky)) or np.any(sky < 0):
            raise ValueError(f"sky_radiance must be 1 or 3 finite numbers >= 0, got {self.sky_radiance!r}")
        sun = _unit(self.sun_direction, "sun_direction")
        up = _unit(self.up, "up")
        _set_frozen(self, triangles=tri, leaf_of_triangle=leaf, leaf_area=area, sky_radiance=sky, sun_direction=sun, up=up)
        if self.period is not None:
            p = tuple(float(v) for v in np.asarray(self.period, dtype=np.float64).reshape(-1))
            if len(p) != 2 or not all(math.isfinite(v) and v > 0 for v in p):
                raise ValueError(f"period must be two positive numbers (px, py), got {self.period!r}")
            if abs(up[2] - 1.0) > 1e-12:
                raise ValueError(f"a periodic layer (period={p}) needs up = (0, 0, 1), got up = {tuple(up)}")
            if sun[2] <= 0.0:
                raise ValueError(
                    f"a periodic layer (period={p}) needs the sun above the horizon, got sun_direction = {tuple(sun)}"
                )
            object.__setattr__(self, "period", p)
            object.__setattr__(self, "cell_origin", tuple(float(v) for v in self.cell_origin))

    @property
    def n_leaves(self) -> int:
        return int(self.leaf_area.shape[0])


@dataclass(frozen=True)
class ReferenceParams:
    """How many photons, how they are split, and the seed."""

    paths: int = 1_000_000
    """Sun photon paths (≥ 2, or 0 for a sky-only run)."""
    sky_paths: int | None = None
    """Sky photon paths; None: ``paths`` if the sky radiance is non-zero, else 0.
    Ignored (no sky photons) when the sky radiance is zero."""
    seed: int = 0
    """Seed of ``np.random.SeedSequence``; results are bitwise reproducible for a seed."""
    workers: int | None = None
    """Threads; None: ``os.cpu_count()``. Does not change the results."""
    batch_size: int = 1 << 15
    """Paths per batch (the unit of work, of seeding and of the two-halves noise split).
    Changing it changes the random streams, hence the results (not their expectation)."""
    max_events: int = 100_000
    """Scattering events after which a path is abandoned and counted in ``truncated``
    (only reachable in closed geometry with albedo 1; never silently: the result reports it)."""
    sun_sampling: str = "surface"
    """``surface``: the beam's first hits drawn on the surfaces and kept by a shadow ray
    (``_SurfaceSunSource``, the default); ``beam``: photons from a rectangle over the scene's
    bounds, traced to their first hit. Both estimate the same tallies without bias."""
    survival_weight: float = 0.1
    """Absorption is taken by its expected value (W(1 - r - t) deposited, the rest goes on) while
    a photon's channel sum is at least this fraction of its launch weight, and drawn (analog, the
    path's Russian roulette) below it. ≥ 0; above 1 every event is analog."""
    split: int = 2
    """Surface sun source: each first hit goes on as this many photons of 1/split its power
    (independent scattering events), so the shadow ray that found it serves several paths. ≥ 1."""
    noise_target: float | None = None
    """If set, stop once the two-halves estimate of ``noise_rel`` (E_scattered) is at or below it,
    checked after every second sun batch from the fourth on, in batch order (so the stopping point,
    and the result, are still fixed by the seed); ``paths`` is then the most that will be traced."""

    def __post_init__(self) -> None:
        if isinstance(self.split, bool) or not isinstance(self.split, (int, np.integer)) or self.split < 1:
            raise ValueError(f"split must be an integer >= 1, got {self.split!r}")
        if self.sun_sampling not in ("surface", "beam"):
            raise ValueError(f"sun_sampling must be 'surface' or 'beam', got {self.sun_sampling!r}")
        if not (isinstance(self.survival_weight, (int, float)) and math.isfinite(self.survival_weight)
                and self.survival_weight >= 0):
            raise ValueError(f"survival_weight must be a finite number >= 0, got {self.survival_weight!r}")
        if self.noise_target is not None and not (
            isinstance(self.noise_target, (int, float)) and 0 < self.noise_target < math.inf
        ):
            raise ValueError(f"noise_target must be None or a positive number, got {self.noise_target!r}")
        for name in ("paths", "seed", "batch_size", "max_events"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise TypeError(f"{name} must be an integer, got {v!r}")
        if self.paths < 0 or self.paths == 1:
            raise ValueError(f"paths must be 0 or >= 2 (the noise estimate needs two halves), got {self.paths}")
        if self.sky_paths is not None and (
            isinstance(self.sky_paths, bool) or not isinstance(self.sky_paths, (int, np.integer)) or self.sky_paths < 0
        ):
            raise ValueError(f"sky_paths must be None or an integer >= 0, got {self.sky_paths!r}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {self.batch_size}")
        if self.max_events < 1:
            raise ValueError(f"max_events must be >= 1, got {self.max_events}")
        if self.workers is not None and (
            isinstance(self.workers, bool) or not isinstance(self.workers, (int, np.integer)) or self.workers < 1
        ):
            raise ValueError(f"workers must be None or an integer >= 1, got {self.workers!r}")


@dataclass(frozen=True, eq=False)
class ReferenceResult:
    """Per-leaf irradiance tallies of the Monte Carlo reference (see the module docstring)."""

    e_direct: np.ndarray
    """(L, 3) unscattered sun irradiance, both faces summed, area-averaged (sun irradiance = 1)."""
    e_scattered: np.ndarray
    """(L, 3) irradiance from sunlight scattered at least once, both faces summed, area-averaged."""
    e_sky: np.ndarray
    """(L, 3) unscattered sky irradiance, both faces summed, area-averaged."""
    e_sky_scattered: np.ndarray
    """(L, 3) irradiance from sky light scattered at least once, both faces summed, area-averaged."""
    absorbed: np.ndarray
    """(L, 3) power absorbed by each leaf (sun + sky; irradiance × stage-unit²)."""
    absorbed_wood: np.ndarray
    """(3,) power absorbed by wood."""
    escaped: np.ndarray
    """(3,) power leaving the scene (including photons that hit nothing)."""
    incident: np.ndarray
    """(3,) power launched by the sources (sun rectangle area + sky disc power)."""
    hits: np.ndarray
    """(L,) int64 number of sun-photon arrivals at each leaf (direct + scattered): a leaf with few
    hits has a noisy estimate."""
    paths: int
    """Sun paths traced."""
    sky_paths: int
    """Sky paths traced."""
    seconds: float
    """Wall time of :func:`solve`."""
    noise_rel: float
    """Estimated relative RMS noise of ``e_scattered`` over leaves and channels,
    sqrt(Σ Var)/‖E_scattered‖ (two halves, see the module docstring; 0 if E_scattered is
    identically 0, NaN without sun paths). Unreliable for very few leaves."""
    noise_rel_total: float
    """The same for ``e_direct + e_scattered``."""
    noise_rel_direct: float
    """The same for ``e_direct``."""
    intercepted: np.ndarray
    """(3,) power of the unscattered beam's first hits (sun irradiance × stage-unit²): with the
    surface source, the estimate of what the foliage and wood intercept; with the beam source,
    ``e_direct`` integrated over the leaves plus the wood's first hits are not separated (NaN)."""
    seed: int
    """The seed used."""
    workers: int
    """Threads used (does not affect the values)."""
    truncated: int
    """Paths abandoned (``max_events`` reached, or a periodic ray crossing too many cells); 0 normally."""
    instance_direct: np.ndarray | None = None
    """With placements: (N, 3) each instance's leaf-area-weighted mean E_direct; else None."""
    instance_scattered: np.ndarray | None = None
    """With placements: (N, 3) each instance's leaf-area-weighted mean E_scattered; else None."""
    noise_rel_instance: float = math.nan
    """With placements: the two-halves relative RMS noise of ``instance_direct + instance_scattered``."""

    @property
    def e_total(self) -> np.ndarray:
        """(L, 3) all irradiance: e_direct + e_scattered + e_sky + e_sky_scattered."""
        return self.e_direct + self.e_scattered + self.e_sky + self.e_sky_scattered


# --------------------------------------------------------------------------
# sampling helpers
# --------------------------------------------------------------------------


def _onb(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit normals n (K, 3) to orthonormal bases.

    Duff et al. 2017, "Building an Orthonormal Basis, Revisited", JCGT 6(1), listing 3.
    """
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t1 = np.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0]], axis=1)
    t2 = np.stack([b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], axis=1)
    return t1, t2


def _cosine_directions(axis: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Cosine-distributed unit directions about unit ``axis`` (K, 3) (Malley's method:
    uniform on the unit disc, projected up to the hemisphere)."""
    r = np.sqrt(u1)
    phi = 2.0 * math.pi * u2
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    t1, t2 = _onb(axis)
    return (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + z[:, None] * axis


def _uniform_hemisphere(axis: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions uniform (pdf 1/2π) on the hemisphere about one unit ``axis`` (3,)."""
    z = u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    t1, t2 = _onb(axis[None, :])
    return (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + z[:, None] * axis[None, :]


# --------------------------------------------------------------------------
# sources: (origins, directions, weights) for k photons
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Geometry:
    """What the sources need to know about the scene."""

    centre: np.ndarray  # (3,) bounding-box centre
    corners: np.ndarray  # (8, 3) bounding-box corners
    radius: float  # bounding-sphere radius (about centre), with margin
    period: tuple[float, float] | None
    cell_origin: tuple[float, float]
    z_top: float


class _SunSource:
    """Parallel beam along -s, irradiance 1 perpendicular to it."""

    def __init__(self, geo: _Geometry, sun: np.ndarray, paths: int) -> None:
        self.sun = sun
        self.geo = geo
        if geo.period is None:
            u, v = _onb(sun[None, :])
            self.u, self.v = u[0], v[0]
            rel = geo.corners - geo.centre
            pu, pv, ps = rel @ self.u, rel @ self.v, rel @ sun
            margin = _SOURCE_MARGIN * max(2.0 * geo.radius, 1e-30)
            self.lo = np.array([pu.min(), pv.min()]) - margin
            self.hi = np.array([pu.max(), pv.max()]) + margin
            self.height = ps.max() + margin
            area = float(np.prod(self.hi - self.lo))
        else:
            px, py = geo.period
            area = float(sun[2]) * px * py  # horizontal irradiance μ0 on the cell
        self.power = area  # per channel
        # per photon: the whole beam's power; solve() divides the sun tallies by the paths traced
        self.weight = area

    def emit(self, rng: np.random.Generator, k: int):
        uv = rng.random((k, 2))
        if self.geo.period is None:
            a = self.lo + uv * (self.hi - self.lo)
            o = self.geo.centre + a[:, :1] * self.u + a[:, 1:] * self.v + self.height * self.sun
        else:
            px, py = self.geo.period
            o = np.empty((k, 3))
            o[:, 0] = self.geo.cell_origin[0] + uv[:, 0] * px
            o[:, 1] = self.geo.cell_origin[1] + uv[:, 1] * py
            o[:, 2] = self.geo.z_top
        d = np.broadcast_to(-self.sun, (k, 3)).copy()
        w = np.full((k, 3), self.weight)
        return o, d, w


class _SurfaceSunSource:
    """The sun beam's first hits, sampled on the surfaces themselves (splitting the beam at its first hit).

    The unscattered beam of irradiance 1 deposits, on a surface point x of a
    triangle with normal n, the power density |n·s| V(x) (V: 1 when the ray
    from x toward the sun escapes, else 0). Points are drawn on all triangles
    (leaves and wood) with density ∝ |n·s| per unit area -- systematic
    sampling over the triangles' projected areas A|n·s|, so a triangle's count
    is its expected count rounded up or down, and a uniform point inside --
    and each carries P / k (P = Σ A|n·s|); a shadow ray toward the sun keeps
    the points with V = 1 as first hits. Over the beam's rectangle this draws
    the same first hits as :class:`_SunSource` (an unbiased estimate of the
    same tallies) but spends no ray on photons that miss the foliage and
    spreads the first hits evenly over the lit leaves, which removes most of
    E_direct's noise and of the first-scattered source's.
    """

    def __init__(self, scene, triangles: np.ndarray, sun: np.ndarray, incident: float) -> None:
        self.scene = scene
        self.sun = sun
        self.tri = triangles
        normals = scene.normals
        self.cos = normals @ sun
        area = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
        self.cum = np.cumsum(area * np.abs(self.cos))
        self.projected = float(self.cum[-1]) if self.cum.size else 0.0
        self.side = np.where(self.cos >= 0.0, 1.0, -1.0)[:, None] * normals
        self.offset = scene.offset_distance()
        self.power = incident  # per channel: the beam's power over the source area (energy balance)

    def first_hits(self, rng: np.random.Generator, k: int):
        """(tri, points, directions, weights) of the k drawn points that see the sun, and the weight per point."""
        weight = self.projected  # per point, like _SunSource: solve() divides by the paths traced
        if self.projected <= 0.0 or k == 0:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), weight
        target = (np.arange(k) + rng.random()) * (self.projected / k)
        t = np.minimum(np.searchsorted(self.cum, target, side="right"), self.cum.size - 1)
        uv = rng.random((k, 2))
        fold = uv.sum(axis=1) > 1.0
        uv[fold] = 1.0 - uv[fold]
        v0 = self.tri[t, 0]
        p = v0 + uv[:, :1] * (self.tri[t, 1] - v0) + uv[:, 1:] * (self.tri[t, 2] - v0)
        origins = p + self.offset * self.side[t]
        seen = ~self.scene.occluded(origins, np.broadcast_to(self.sun, origins.shape))
        d = np.broadcast_to(-self.sun, (int(seen.sum()), 3)).copy()
        return t[seen], p[seen], d, np.full((d.shape[0], 3), weight), weight


class _PlacedSunSource:
    """:class:`_SurfaceSunSource` over placed prototypes, without a per-instance triangle list.

    The beam deposits on instance i the power P_i = Σ_t |a'_t·s| over its placed triangles, whose area
    vectors are a'_t = cof(A_i) a_t (a_t: the prototype triangle's area vector), so P_i = Σ_t |a_t·σ_i| with
    σ_i = cof(A_i)ᵀ s = det(A_i) A_i⁻¹ s. Points are drawn in two stages: instances by systematic sampling over
    P_i (each gets its expected count k P_i / P rounded up or down), then within the instance a prototype
    triangle with probability A_t / A (its share of the prototype's area) and a uniform point on it (uniform
    in the world too: the map is affine). A point's weight is P · A |n_t·σ_i| / P_i, the ratio of the target
    density (∝ |a'_t·s|) to the one drawn, so the expected power of each triangle is its |a'_t·s| V as in
    :class:`_SurfaceSunSource`; the weights average P per point and vary with |n·s| within an instance.
    """

    def __init__(self, scene: InstancedRayScene, placements: Placements, sun: np.ndarray, incident: float) -> None:
        self.scene = scene
        self.sun = sun
        self.pl = placements
        sigma = np.einsum("nji,j->ni", cofactors(placements.transforms[:, :3, :3]), sun)  # cof(A)ᵀ s
        self.sigma = sigma
        self.area_vec, self.cum_area = [], []
        proj = np.zeros(placements.n_instances)
        for p, tri in enumerate(placements.triangles):
            a = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            self.area_vec.append(a)
            self.cum_area.append(np.cumsum(np.linalg.norm(a, axis=1)))
            sel = np.flatnonzero(placements.prototype_of == p)
            for chunk in np.array_split(sel, max(1, sel.size // 256)):
                if chunk.size and len(a):
                    proj[chunk] = np.abs(a @ sigma[chunk].T).sum(axis=0)
        self.proj = proj
        self.cum = np.cumsum(proj)
        self.projected = float(self.cum[-1]) if self.cum.size else 0.0
        self.offset = scene.offset_distance()
        self.power = incident

    def first_hits(self, rng: np.random.Generator, k: int):
        """((instance, triangle), points, directions, weights) of the drawn points that see the sun, and the mean weight."""
        weight = self.projected
        none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        if self.projected <= 0.0 or k == 0:
            return none, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), weight
        target = (np.arange(k) + rng.random()) * (self.projected / k)
        inst = np.minimum(np.searchsorted(self.cum, target, side="right"), self.cum.size - 1)
        pick, uv = rng.random(k), rng.random((k, 2))
        fold = uv.sum(axis=1) > 1.0
        uv[fold] = 1.0 - uv[fold]
        tri = np.zeros(k, np.int64)
        local = np.zeros((k, 3))
        w = np.zeros(k)
        for p, (verts, a, cum) in enumerate(zip(self.pl.triangles, self.area_vec, self.cum_area)):
            sel = np.flatnonzero(self.pl.prototype_of[inst] == p)
            if sel.size == 0:
                continue
            t = np.minimum(np.searchsorted(cum, pick[sel] * cum[-1], side="right"), cum.size - 1)
            tri[sel] = t
            v0 = verts[t, 0]
            local[sel] = v0 + uv[sel, :1] * (verts[t, 1] - v0) + uv[sel, 1:] * (verts[t, 2] - v0)
            i = inst[sel]
            w[sel] = self.projected * cum[-1] * np.abs(np.einsum("kj,kj->k", a[t], self.sigma[i])) / (
                np.linalg.norm(a[t], axis=1) * self.proj[i])
        lin = self.pl.transforms[inst, :3, :3]
        p = np.einsum("kij,kj->ki", lin, local) + self.pl.transforms[inst, :3, 3]
        n = self.scene.world_normals(inst, tri)
        side = np.where(n @ self.sun >= 0.0, 1.0, -1.0)[:, None] * n
        origins = p + self.offset * side
        seen = ~self.scene.occluded(origins, np.broadcast_to(self.sun, origins.shape))
        d = np.broadcast_to(-self.sun, (int(seen.sum()), 3)).copy()
        return (inst[seen], tri[seen]), p[seen], d, np.repeat(w[seen, None], 3, axis=1), weight


class _SkySource:
    """Uniform radiance L over the hemisphere about ``up``."""

    def __init__(self, geo: _Geometry, up: np.ndarray, radiance: np.ndarray, paths: int) -> None:
        self.geo = geo
        self.up = up
        if geo.period is None:
            # ∫_hemisphere L dω over a disc πR² perpendicular to each direction
            self.power = radiance * 2.0 * math.pi * math.pi * geo.radius**2
        else:
            px, py = geo.period
            self.power = radiance * math.pi * px * py  # horizontal irradiance π L on the cell
        self.weight = self.power / paths if paths else np.zeros(3)

    def emit(self, rng: np.random.Generator, k: int):
        u = rng.random((k, 4))
        w = np.broadcast_to(self.weight, (k, 3)).copy()
        if self.geo.period is None:
            omega = _uniform_hemisphere(self.up, u[:, 0], u[:, 1])
            t1, t2 = _onb(omega)
            r = self.geo.radius * np.sqrt(u[:, 2])
            phi = 2.0 * math.pi * u[:, 3]
            o = (
                self.geo.centre
                + self.geo.radius * (1.0 + _SOURCE_MARGIN) * omega
                + (r * np.cos(phi))[:, None] * t1
                + (r * np.sin(phi))[:, None] * t2
            )
        else:
            omega = _cosine_directions(np.broadcast_to(self.up, (k, 3)), u[:, 0], u[:, 1])
            px, py = self.geo.period
            o = np.empty((k, 3))
            o[:, 0] = self.geo.cell_origin[0] + u[:, 2] * px
            o[:, 1] = self.geo.cell_origin[1] + u[:, 3] * py
            o[:, 2] = self.geo.z_top
        return o, -omega, w


# --------------------------------------------------------------------------
# the path loop of one batch
# --------------------------------------------------------------------------


@njit(nogil=True, cache=True)
def _process_hits(
    tri, pts, d, w, scattered, leaf_of_tri, normals, refl, trans, absp, u, offset, first_category, count_hits, w_min,
    incidence, absorbed, absorbed_wood, escaped, hits, o_out, d_out, w_out,
):
    """Tally one bounce of k photons and draw their events; survivors are written compactly.

    For photon i: a miss adds w[i] to ``escaped``; a hit on a leaf adds w[i]
    to ``incidence[leaf * 4 + category]`` (category: first_category + scattered),
    then, while Σ_c w_c ≥ ``w_min``, W(1 - r - t) is deposited and reflect or
    transmit is drawn with probabilities ∝ Σ_c w_c r_c, Σ_c w_c t_c; below it,
    one of reflect / transmit / absorb is drawn with probabilities
    proportional to Σ_c w_c r_c, Σ_c w_c t_c, Σ_c w_c (1 - r_c - t_c) (module
    docstring), using u[i, 0]; a survivor gets a cosine-distributed direction
    from u[i, 1:3] (Malley's method, Duff et al. 2017 basis) about the normal on
    the side it leaves to, and starts ``offset`` off the surface on that side.
    Runs without the GIL so that batches on several threads overlap.
    Returns the number of survivors.
    """
    k = tri.shape[0]
    m = 0
    for i in range(k):
        j = tri[i]
        if j < 0:
            for c in range(3):
                escaped[c] += w[i, c]
            continue
        leaf = leaf_of_tri[j]
        if leaf >= 0:
            key = leaf * 4 + first_category + (1 if scattered[i] else 0)
            for c in range(3):
                incidence[key, c] += w[i, c]
            if count_hits:
                hits[leaf] += 1
        a_r = 0.0
        a_t = 0.0
        a_a = 0.0
        for c in range(3):
            a_r += w[i, c] * refl[j, c]
            a_t += w[i, c] * trans[j, c]
            a_a += w[i, c] * absp[j, c]
        total = a_r + a_t + a_a
        if total <= 0.0:
            # nothing left to carry: the weight underflowed to zero in every channel (a bounce off a subnormal
            # reflectance); the event draw below would divide 0 by 0, and there is nothing to deposit
            continue
        if total >= w_min:
            # expected-value absorption: deposit W(1 - r - t) and go on with the rest
            for c in range(3):
                dep = w[i, c] * absp[j, c]
                if leaf >= 0:
                    absorbed[leaf, c] += dep
                else:
                    absorbed_wood[c] += dep
            if a_r + a_t <= 0.0:
                continue
            mode = 0 if u[i, 0] * (a_r + a_t) < a_r else 1
            # u (a_r + a_t) rounds up to a_r when they are subnormal (a wood reflectance of 5e-324): never pick
            # an event of zero weight, whose weight factor would divide by zero
            if mode == 1 and a_t <= 0.0:
                mode = 0
            keep = a_r + a_t
        else:
            # analog absorption: the event is the Russian roulette
            x = u[i, 0] * total
            if x < a_r:
                mode = 0
            elif x < a_r + a_t:
                mode = 1
            else:
                mode = 2
            if mode == 2 and a_a <= 0.0:  # the same rounding at the top of the range
                mode = 0 if a_t <= 0.0 else 1
            elif mode == 1 and a_t <= 0.0:
                mode = 0
            if mode == 2:
                f = total / a_a
                for c in range(3):
                    dep = w[i, c] * absp[j, c] * f
                    if leaf >= 0:
                        absorbed[leaf, c] += dep
                    else:
                        absorbed_wood[c] += dep
                continue
            keep = total
        nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
        # side the photon came from: against its direction
        side = 1.0 if nx * d[i, 0] + ny * d[i, 1] + nz * d[i, 2] <= 0.0 else -1.0
        if mode == 1:
            side = -side
        ax, ay, az = side * nx, side * ny, side * nz
        if mode == 0:
            f = keep / a_r
            for c in range(3):
                w_out[m, c] = w[i, c] * refl[j, c] * f
        else:
            f = keep / a_t
            for c in range(3):
                w_out[m, c] = w[i, c] * trans[j, c] * f
        # orthonormal basis about (ax, ay, az): Duff et al. 2017, JCGT 6(1), listing 3
        sg = 1.0 if az >= 0.0 else -1.0
        aa = -1.0 / (sg + az)
        bb = ax * ay * aa
        t1x, t1y, t1z = 1.0 + sg * ax * ax * aa, sg * bb, -sg * ax
        t2x, t2y, t2z = bb, sg + ay * ay * aa, -ay
        rr = math.sqrt(u[i, 1])
        phi = 2.0 * math.pi * u[i, 2]
        zz = math.sqrt(max(0.0, 1.0 - u[i, 1]))
        cx, cy = rr * math.cos(phi), rr * math.sin(phi)
        d_out[m, 0] = cx * t1x + cy * t2x + zz * ax
        d_out[m, 1] = cx * t1y + cy * t2y + zz * ay
        d_out[m, 2] = cx * t1z + cy * t2z + zz * az
        o_out[m, 0] = pts[i, 0] + offset * ax
        o_out[m, 1] = pts[i, 1] + offset * ay
        o_out[m, 2] = pts[i, 2] + offset * az
        m += 1
    return m



@dataclass
class _Tally:
    incidence: np.ndarray  # (4 L, 3): [leaf * 4 + category]
    absorbed: np.ndarray  # (L, 3)
    absorbed_wood: np.ndarray  # (3,)
    escaped: np.ndarray  # (3,)
    hits: np.ndarray  # (L,) int64
    truncated: int
    intercepted: np.ndarray  # (3,) surface sun source: power of the first hits drawn
    instances: np.ndarray  # (4 N, 3): [instance * 4 + category], placements only (N = 0 otherwise)

    @classmethod
    def zeros(cls, n_leaves: int, n_instances: int = 0) -> _Tally:
        return cls(
            np.zeros((4 * n_leaves, 3)), np.zeros((n_leaves, 3)), np.zeros(3), np.zeros(3),
            np.zeros(n_leaves, dtype=np.int64), 0, np.zeros(3), np.zeros((4 * n_instances, 3)),
        )

    def scaled(self, f: float) -> _Tally:
        """A copy with every power multiplied by f (counts unchanged)."""
        return _Tally(self.incidence * f, self.absorbed * f, self.absorbed_wood * f, self.escaped * f,
                      self.hits.copy(), self.truncated, self.intercepted * f, self.instances * f)

    def add(self, other: _Tally) -> None:
        self.incidence += other.incidence
        self.absorbed += other.absorbed
        self.absorbed_wood += other.absorbed_wood
        self.escaped += other.escaped
        self.hits += other.hits
        self.truncated += other.truncated
        self.intercepted += other.intercepted
        self.instances += other.instances


class _Tracer:
    """Everything a batch needs, shared read-only between threads."""

    def __init__(self, inputs: ReferenceInputs, max_events: int, ev_fraction: float, split: int = 1) -> None:
        self.ev_fraction = ev_fraction
        self.split = split
        self.periodic = inputs.period is not None
        self.placements = inputs.placements
        self.n_leaves = inputs.n_leaves
        self.n_instances = 0
        opt = inputs.optics
        # r + t = 1 in floating point leaves residues of ~1e-16: albedo 1 absorbs exactly nothing
        # (rows: 0 wood (ρ, 0), 1 leaf (r, t))
        self.r2 = np.stack([opt.wood_reflectance, opt.reflectance])
        self.t2 = np.stack([np.zeros(3), opt.transmittance])
        a2 = 1.0 - self.r2 - self.t2
        self.a2 = np.where(a2 > 1e-12, a2, 0.0)
        self.scene: InstancedRayScene | PeriodicRayScene | RayScene
        if self.placements is not None:
            pl = self.placements
            self.scene = InstancedRayScene(pl.triangles, pl.transforms, pl.prototype_of)
            self.n_instances = pl.n_instances
        elif self.periodic:
            self.scene = PeriodicRayScene(inputs.triangles, period=inputs.period, origin=inputs.cell_origin)
        else:
            self.scene = RayScene(inputs.triangles)
        self.offset = self.scene.offset_distance()
        if self.placements is None:
            assert not isinstance(self.scene, InstancedRayScene)  # built above from the triangles when there are no placements
            self.normals = self.scene.normals
            self.leaf = inputs.leaf_of_triangle
            # per-triangle r and t: leaves (r, t), wood (ρ, 0)
            kind = (self.leaf >= 0).astype(np.int64)
            self.r, self.t, self.a = self.r2[kind], self.t2[kind], self.a2[kind]
        self.max_events = max_events

    def first_hits(self, o, d):
        """(hits, hit points, truncated) for rays; ``hits`` is the triangle id (-1 for escapes) or, with
        placements, the (instance, prototype triangle) pair (-1, -1 for escapes)."""
        if self.periodic:
            h = self.scene.intersect(o, d)
            return h.tri_id, h.points, h.truncated
        if self.placements is not None:
            inst, tri, t = self.scene.intersect(o, d)
            pts = o + np.where(inst >= 0, t, 0.0)[:, None] * d
            return (inst, tri), pts, None
        tri, t = self.scene.intersect(o, d)
        pts = o + np.where(tri >= 0, t, 0.0)[:, None] * d
        return tri, pts, None

    def surfaces(self, hits):
        """What ``_process_hits`` reads of the surfaces hit: (ids, leaf of id, normals, r, t, a).

        Over copied triangles the ids are the triangles; with placements each hit gets its own id 0..k-1 and
        rows of its own (its result leaf, its world normal, its optics), so nothing grows with the instances.
        """
        if self.placements is None:
            return hits, self.leaf, self.normals, self.r, self.t, self.a
        inst, tri = hits
        pl = self.placements
        hit = inst >= 0
        ids = np.where(hit, np.arange(inst.size), -1)
        i, t = np.where(hit, inst, 0), np.where(hit, tri, 0)
        local = np.full(inst.size, -1, np.int64)
        for p, leaf_ids in enumerate(pl.leaf_of_triangle):
            sel = np.flatnonzero(hit & (pl.prototype_of[i] == p))
            local[sel] = leaf_ids[t[sel]]
        leaf = np.where(local >= 0, pl.leaf_offset[i] + local, -1)
        normals = self.scene.world_normals(i, t)
        kind = (local >= 0).astype(np.int64)
        return ids, leaf, normals, self.r2[kind], self.t2[kind], self.a2[kind]

    def tally_instances(self, hits, leaf, w, scattered, first_category, out) -> None:
        """Add each photon arriving at a leaf to its instance's tally (placements only)."""
        if self.placements is None:
            return
        inst = hits[0]
        on = np.flatnonzero(leaf >= 0)
        key = inst[on] * 4 + first_category + scattered[on].astype(np.int64)
        for c in range(3):
            out[:, c] += np.bincount(key, weights=w[on, c], minlength=out.shape[0])

    def run(self, source, rng: np.random.Generator, k: int, sky: bool) -> _Tally:
        tally = _Tally.zeros(self.n_leaves, self.n_instances)
        escaped = np.zeros(3)
        first_category = _SKY_DIRECT if sky else _SUN_DIRECT
        surface = isinstance(source, (_SurfaceSunSource, _PlacedSunSource))
        split = self.split if surface else 1
        o_out, d_out, w_out = (np.empty((k * split, 3)) for _ in range(3))
        if surface:
            tri0, pts0, d, w, weight = source.first_hits(rng, k)
            tally.intercepted += w.sum(axis=0)
            if split > 1:
                # splitting at the first hit: each first hit goes on as `split` photons of 1/split its power,
                # each with its own scattering event and direction (the shadow ray is paid once)
                rep = (lambda a: tuple(np.repeat(x, split) for x in a)) if isinstance(tri0, tuple) else \
                    (lambda a: np.repeat(a, split))
                tri0, pts0, d, w = rep(tri0), np.repeat(pts0, split, 0), np.repeat(d, split, 0), \
                    np.repeat(w / split, split, 0)
            o = pts0
            w_min = 3.0 * weight * self.ev_fraction / split
        else:
            o, d, w = source.emit(rng, k)
            w_min = float(w[0].sum()) * self.ev_fraction if k else 0.0
        scattered = np.zeros(o.shape[0], dtype=bool)
        for event in range(self.max_events + 1):
            n = o.shape[0]
            if n == 0:
                break
            if surface and event == 0:
                tri, pts, trunc = tri0, pts0, None
            else:
                tri, pts, trunc = self.first_hits(o, d)
            if trunc is not None and np.any(trunc):
                tally.truncated += int(trunc.sum())
                keep = ~trunc
                d, w, scattered, tri, pts = d[keep], w[keep], scattered[keep], tri[keep], pts[keep]
                n = tri.shape[0]
            u = rng.random((n, 3))
            ids, leaf, normals, refl, trans, absp = self.surfaces(tri)
            self.tally_instances(tri, leaf, w, scattered, first_category, tally.instances)
            m = _process_hits(
                ids, pts, d, w, scattered, leaf, normals, refl, trans, absp, u, self.offset,
                first_category, not sky, w_min, tally.incidence, tally.absorbed, tally.absorbed_wood, escaped,
                tally.hits, o_out, d_out, w_out,
            )
            o, d, w = o_out[:m].copy(), d_out[:m].copy(), w_out[:m].copy()
            scattered = np.ones(m, dtype=bool)
        else:
            tally.truncated += int(o.shape[0])
        tally.escaped += escaped
        return tally


# --------------------------------------------------------------------------
# public entry point
# --------------------------------------------------------------------------


def _batches(paths: int, batch_size: int) -> list[int]:
    """Batch sizes: at least 2 batches (two halves) when paths > 0, as even as possible."""
    if paths == 0:
        return []
    n = max(2, -(-paths // batch_size))
    return [paths // n + (1 if i < paths % n else 0) for i in range(n)]


def _geometry(inputs: ReferenceInputs, z_top: float | None, bounds: np.ndarray | None = None) -> _Geometry:
    tri = inputs.triangles
    if bounds is not None:
        lo, hi = bounds
    elif tri.shape[0]:
        lo = tri.reshape(-1, 3).min(axis=0)
        hi = tri.reshape(-1, 3).max(axis=0)
    else:
        lo = hi = np.zeros(3)
    centre = 0.5 * (lo + hi)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    half_diag = 0.5 * float(np.linalg.norm(hi - lo))
    radius = max(half_diag, 1e-30) * (1.0 + _SOURCE_MARGIN)
    return _Geometry(centre, corners, radius, inputs.period, inputs.cell_origin, z_top if z_top is not None else hi[2])


def _noise(half_a: np.ndarray, half_b: np.ndarray, n_a: int, n_b: int, area: np.ndarray) -> float:
    """Relative RMS noise of the full run from two halves (see the module docstring)."""
    n = n_a + n_b
    full = (half_a + half_b) / area[:, None]
    a = half_a * (n / n_a) / area[:, None]
    b = half_b * (n / n_b) / area[:, None]
    den = float(np.linalg.norm(full))
    if den == 0.0:
        return 0.0
    return float(np.linalg.norm(a - b)) / (math.sqrt(n / n_a + n / n_b) * den)


def solve(
    inputs: ReferenceInputs,
    params: ReferenceParams = ReferenceParams(),
    *,
    progress: Callable[[int, int], None] | None = None,
) -> ReferenceResult:
    """Trace sun (and sky) photons through the scene and tally per-leaf irradiance.

    Parameters
    ----------
    inputs : ReferenceInputs
        Triangles, leaf ids and areas, optics, sun, sky.
    params : ReferenceParams
        Path counts, seed, threads, batch size.
    progress : callable, optional
        ``progress(done, total)`` in paths (sun + sky), called from the calling
        thread after each batch, in batch order.

    Returns
    -------
    ReferenceResult
        Tallies as defined in the module docstring, with wall time and the
        two-halves noise estimate.
    """
    start = time.perf_counter()
    if not isinstance(inputs, ReferenceInputs):
        raise TypeError(f"inputs must be a ReferenceInputs, got {type(inputs).__name__}")
    if not isinstance(params, ReferenceParams):
        raise TypeError(f"params must be a ReferenceParams, got {type(params).__name__}")
    has_sky = bool(np.any(inputs.sky_radiance > 0))
    sky_paths = (params.paths if has_sky else 0) if params.sky_paths is None else int(params.sky_paths)
    if has_sky and sky_paths < 2:
        raise ValueError(
            f"sky_radiance is {tuple(inputs.sky_radiance)} but sky_paths = {sky_paths}: give sky_paths >= 2 "
            "or a zero sky radiance"
        )
    if params.paths + sky_paths == 0:
        raise ValueError("nothing to trace: paths and sky_paths are both 0")
    workers = int(params.workers) if params.workers is not None else max(1, os.cpu_count() or 1)
    tracer = _Tracer(inputs, params.max_events, float(params.survival_weight), int(params.split))
    z_top = None
    if tracer.periodic:
        assert isinstance(tracer.scene, PeriodicRayScene)  # _Tracer builds one for a periodic input
        z_top = tracer.scene.z_range[1]
    geo = _geometry(inputs, z_top, tracer.scene.bounds if inputs.placements is not None else None)
    if params.noise_target is None:
        sun_sizes = _batches(params.paths, params.batch_size)
    else:  # whole batches, so a run stopped after n of them equals a run of n x batch_size paths
        n_full, rest = divmod(params.paths, params.batch_size)
        sun_sizes = [params.batch_size] * n_full + ([rest] if rest else [])
        if len(sun_sizes) < 2:
            sun_sizes = _batches(params.paths, params.batch_size)
    sky_sizes = _batches(sky_paths, params.batch_size) if has_sky else []
    sun: _SunSource | _PlacedSunSource | _SurfaceSunSource = _SunSource(geo, inputs.sun_direction, params.paths)
    if params.sun_sampling == "surface" and inputs.placements is not None:
        assert isinstance(tracer.scene, InstancedRayScene)  # _Tracer's scene for placements
        sun = _PlacedSunSource(tracer.scene, inputs.placements, inputs.sun_direction, sun.power)
    elif params.sun_sampling == "surface":
        sun = _SurfaceSunSource(tracer.scene, inputs.triangles, inputs.sun_direction, sun.power)
    sky = _SkySource(geo, inputs.up, inputs.sky_radiance, sky_paths) if has_sky else None
    root_sun, root_sky = np.random.SeedSequence(params.seed).spawn(2)
    # sky batches first, so that a run stopped at its noise target has traced all of them
    tasks: list[tuple[_SunSource | _PlacedSunSource | _SurfaceSunSource | _SkySource | None, np.random.SeedSequence, int, bool, int]]
    tasks = [(sky, s, size, True, i) for i, (s, size) in enumerate(zip(root_sky.spawn(len(sky_sizes)), sky_sizes))]
    tasks += [(sun, s, size, False, i) for i, (s, size) in enumerate(zip(root_sun.spawn(len(sun_sizes)), sun_sizes))]
    total_paths = params.paths + (sky_paths if has_sky else 0)

    def run(task) -> _Tally:
        source, seq, size, is_sky, _ = task
        return tracer.run(source, np.random.default_rng(seq), size, is_sky)

    n_leaves = inputs.n_leaves
    n_inst = tracer.n_instances
    # per half (even / odd batch index): sun tallies in units of power x paths (divided by the
    # sun paths traced at the end, which a noise target decides), sky tallies normalised
    sun_h = [_Tally.zeros(n_leaves, n_inst), _Tally.zeros(n_leaves, n_inst)]
    sky_h = [_Tally.zeros(n_leaves, n_inst), _Tally.zeros(n_leaves, n_inst)]
    half_paths = [0, 0]
    done = 0
    area = inputs.leaf_area
    target = params.noise_target
    sun_done = 0

    def sun_noise(*categories: int) -> float:
        """The two-halves noise of the sun tallies ``categories`` summed (module docstring)."""
        n = half_paths[0] + half_paths[1]
        a, b = (sum(h.incidence.reshape(n_leaves, 4, 3)[:, c] for c in categories) / n for h in sun_h)
        # sums of arrays (every call names a category), not sum()'s int start
        return _noise(cast(np.ndarray, a), cast(np.ndarray, b), half_paths[0], half_paths[1], area)

    pool = ThreadPoolExecutor(max_workers=workers)
    pending: deque = deque()
    queue = iter(tasks)
    try:
        # A bounded window of batches in flight, consumed in submission order:
        # the reduction order is fixed (determinism) and an exception (or
        # Ctrl-C in the progress callback) cancels what has not started.
        for task in itertools.islice(queue, 2 * workers):
            pending.append((task, pool.submit(run, task)))
        while pending:
            task, future = pending.popleft()
            tally = future.result()
            for nxt in itertools.islice(queue, 1):
                pending.append((nxt, pool.submit(run, nxt)))
            _, _, size, is_sky, index = task
            if is_sky:
                sky_h[index % 2].add(tally)
            else:
                sun_h[index % 2].add(tally)
                half_paths[index % 2] += size
                sun_done += 1
            done += size
            if progress is not None:
                progress(done, total_paths)
            if (target is not None and not is_sky and sun_done >= 4 and sun_done % 2 == 0
                    and sun_done < len(sun_sizes) and sun_noise(_SUN_SCATTERED) <= target):
                break  # the sky batches ran first: what is left is sun batches, not needed
    finally:
        for _, future in pending:
            future.cancel()
        pool.shutdown(wait=True)
    sun_paths = half_paths[0] + half_paths[1]
    full = _Tally.zeros(n_leaves, n_inst)
    if sun_paths:
        full.add(sun_h[0].scaled(1.0 / sun_paths))
        full.add(sun_h[1].scaled(1.0 / sun_paths))
    full.add(sky_h[0])
    full.add(sky_h[1])
    inc = full.incidence.reshape(n_leaves, 4, 3) / area[:, None, None]
    if sun_paths:
        noise = sun_noise(_SUN_SCATTERED)
        noise_total = sun_noise(_SUN_DIRECT, _SUN_SCATTERED)
        noise_direct = sun_noise(_SUN_DIRECT)
    else:
        noise = noise_total = noise_direct = math.nan
    incident = np.full(3, sun.power if sun_paths else 0.0)
    escaped = full.escaped.copy()
    instance_direct = instance_scattered = None
    noise_instance = math.nan
    if inputs.placements is not None:
        _, inst_area = inputs.placements.areas
        safe = np.where(inst_area > 0, inst_area, 1.0)[:, None]
        per = full.instances.reshape(n_inst, 4, 3)
        instance_direct = np.where(inst_area[:, None] > 0, per[:, _SUN_DIRECT] / safe, 0.0)
        instance_scattered = np.where(inst_area[:, None] > 0, per[:, _SUN_SCATTERED] / safe, 0.0)
        if sun_paths:
            n = half_paths[0] + half_paths[1]
            a, b = (h.instances.reshape(n_inst, 4, 3)[:, _SUN_DIRECT] + h.instances.reshape(n_inst, 4, 3)[:, _SUN_SCATTERED]
                    for h in sun_h)
            noise_instance = _noise(a / n, b / n, half_paths[0], half_paths[1], safe[:, 0])
    if isinstance(sun, (_SurfaceSunSource, _PlacedSunSource)):
        # the beam's power that reaches no surface leaves the scene: incident - intercepted
        escaped += incident - full.intercepted
        intercepted = full.intercepted
    else:
        intercepted = np.full(3, math.nan)
    if sky is not None:
        incident = incident + sky.power

    def frozen(a):
        a = np.ascontiguousarray(a)
        a.flags.writeable = False
        return a

    return ReferenceResult(
        e_direct=frozen(inc[:, _SUN_DIRECT]),
        e_scattered=frozen(inc[:, _SUN_SCATTERED]),
        e_sky=frozen(inc[:, _SKY_DIRECT]),
        e_sky_scattered=frozen(inc[:, _SKY_SCATTERED]),
        absorbed=frozen(full.absorbed),
        absorbed_wood=frozen(full.absorbed_wood),
        escaped=frozen(escaped),
        incident=frozen(incident),
        hits=frozen(full.hits),
        paths=int(sun_paths),
        sky_paths=int(sky_paths if has_sky else 0),
        seconds=time.perf_counter() - start,
        noise_rel=noise,
        noise_rel_total=noise_total,
        noise_rel_direct=noise_direct,
        intercepted=frozen(intercepted),
        seed=int(params.seed),
        workers=workers,
        truncated=int(full.truncated),
        instance_direct=None if instance_direct is None else frozen(instance_direct),
        instance_scattered=None if instance_scattered is None else frozen(instance_scattered),
        noise_rel_instance=float(noise_instance),
    )

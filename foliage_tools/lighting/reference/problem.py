"""What the Monte Carlo reference is given and gives back, each validated on construction.

:class:`ReferenceInputs` is the scene as plain arrays (or as :class:`Placements`, prototypes placed many times and
traced without copies), :class:`ReferenceParams` the path counts, seed and sampling choices, :class:`ReferenceResult`
the tallies, whose definitions are in the package docstring (:mod:`foliage_tools.lighting.reference`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from foliage_tools.geometry.instanced import cofactors
from foliage_tools.lighting.optics import LeafOptics


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
    """Per-leaf irradiance tallies of the Monte Carlo reference (see the package docstring)."""

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
    sqrt(Σ Var)/‖E_scattered‖ (two halves, see the package docstring; 0 if E_scattered is
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

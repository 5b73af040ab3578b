"""Per-leaf distances to the crown envelope, s_max, and the tree's optical thickness τ.

boulanger2008 (thesis, ch. 5) models a tree as leaves of area A, number density
ρ and uniformly distributed orientation inside an envelope. Light crossing a
layer of thickness s is attenuated by exp(-τ s) with τ = (A/2) ρ (eq. (5.5)),
and every leaf stores, for the 8 sample directions ω_j of eq. (5.28), the
distance s_max(P, ω_j) from its centre P to the envelope. This module computes
those distances and τ from the leaves themselves.

The paper's method (sec. 5.6), the **reference path**
------------------------------------------------------
For every leaf P, every other leaf P' goes to the bin j of the sample
direction nearest to PP' -- for the cube diagonals of eq. (5.28) the bins are
exactly the 8 octants of the sample frame, each of solid angle Ω_j = 4π/8.
P' occludes the fraction

    o(P, P') = min(A' |N' · PP'^| / |PP'|², ...) / Ω_j

of its bin (solid angle it subtends / the bin's solid angle, clamped below 1
by ``EnvelopeParams.max_occlusion``); the bin's visibility is the product of
(1 - o) over its leaves, so the bin's optical depth is

    D(P, j) = -ln V(P, j) = Σ_{P' in bin j} -ln(1 - o(P, P')),            (1)

which "asymptotically converges to" τ s_max(P, ω_j). The paper sorts each bin
by distance before multiplying; a product does not depend on the order, so we
skip the sort (same result, O(N²) instead of O(N² log N)). τ comes from the
bins (``EnvelopeParams.tau_estimator``), then s_max = D / τ, so
``attenuation = exp(-τ s_max) = V`` exactly.

Note what (1) measures: every leaf of the octant contributes, so D/τ is the
*solid-angle average over the octant* of the depth to the envelope, not the
depth along the single ray ω_j. For a leaf at the centre of a spherical crown
both are the radius; inside a uniform ball (|P| < R/2) they differ by less
than ±5% for 90% of the bins.

Estimating τ
------------
``farthest`` is the paper's: per bin τ_b = D / s_far with s_far the distance
of the bin's farthest leaf, averaged over all bins. s_far estimates the
*largest* depth over the octant while D measures its *mean*, so τ comes out
low, and more so as leaves get denser (the farthest leaf moves out to the
envelope): on a uniform ball with τ = 2, it gives 1.78 (1.5k leaves), 1.55
(6k), 1.36 (20k). ``moments`` (the default) uses, per bin, twice the
occlusion-weighted mean distance of its leaves, ℓ_b = 2 Σ o r / D: for leaves
filling the bin out to d(ω), E[Σ o r] = τ <d²>/2 and E[D] = τ <d>, so ℓ_b
estimates <d²>/<d> (not the max), and τ = Σ_b D_b / Σ_b ℓ_b. On the same
balls it gives 1.79-1.86 from 1.5k to 100k leaves (the residual -7..-10% is
the spread of d over an octant, <d²>/<d> >= <d>).

The **fast path** (particle-particle / particle-mesh splitting)
---------------------------------------------------------------
Sum (1) is split with a smooth weight w(r) that falls from 1 at r_1 to 0 at
r_2 (a C¹ smoothstep):

* near field, r < r_2: the exact terms w(r) · -ln(1 - o), summed over the
  leaves of neighbouring cells (cell list of cell size r_2/2). Each unordered
  pair is visited once and adds to both leaves (o(P, P') uses A' and N', o(P',
  P) uses A and N, in opposite octants), see ``_near_kernel``;
* far field, r > r_1: the leaves are far, so -ln(1 - o) ≈ o, which is linear
  in the leaves: (1 - w(r)) o. Every leaf's mean projected area
  A' ḡ_j(N') (``_octant_projection``: |N'·d| averaged over the directions d
  of the octant) is deposited on the nodes of a grid of step h
  (cloud-in-cell), the sum over nodes of mass × (1 - w(|v|)) 1_{octant j}(v)
  / (Ω_j |v|²) is a discrete convolution done with FFTs (one kernel
  spectrum, reflected for the 8 octants; the zero padding is not transformed
  and only the kept corner is transformed back), and the result is
  interpolated trilinearly back to every leaf. A leaf's own mass is
  subtracted exactly (r_1 >= √2 h leaves only the cell diagonals, see
  ``_interpolate``).

S1 = Σ o r (for τ) is split the same way with a 1/r kernel, sharing the
deposit and forward transform. τ from the fast sums is multiplied by a
calibration, exact/fast τ on ``fast_tau_leaves`` probe leaves whose bins are
also summed exactly (the fast sums are a control variate: over random probe
sets of 64 leaves at 40k leaves the calibrated τ scatters by 0.3%, the
probes' own τ by 1.7%).

Accuracy. On uniform balls (τ R = 2) the fast path's s_max differs from the
reference's by a median 2.8% (95th percentile 12%) at 1.5k leaves, 2.0% (9%)
at 6k, 1.7% (7%) at 20k, 1.2% (6.0%) at 40k and 0.9% (4.7%) at 100k, with τ
within 0.6% (``benchmarks/bench_smax.py``; bins with s_max >= 0.05 R). At
40k leaves (1000 leaves summed exactly; each cause alone, by all-pairs sums
that include only it) the 95th percentile splits into: the octant-mean
projected area in place of |N'·d^|, 3.3%; the grid's blur of the bin planes
(a leaf within ~h of a plane through P is shared between octants), 3.7%; the
rest of the grid error (cloud-in-cell interpolation of the 1/r² kernel),
~2.6%; the linearisation -ln(1 - o) ≈ o, 0.17% (at r_1 = 1.5 h). The errors concentrate on the
short bins: a leaf near the envelope sees, toward the outside, a thin sliver
of crown along the bin planes, and the blur leaks depth into it from the
full neighbouring octants (signed median +8% for s_max in [0.05, 0.1) R, +4%
in [0.1, 0.2) R, -0.5% beyond 0.4 R). Neither grid nor split radius removes
this at an affordable cost (95th percentile 4.2% with 8x the grid nodes,
5.6% with 1.7x the near pairs). Cost: O(N ρ r_2³) near pairs, O(M log M) for
M grid nodes and O(N_probe N) for the probes.

Pure numpy + numba + scipy; no USD, no files, no printing.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import scipy.fft
from numba import njit, prange

__all__ = [
    "AUTO_FAST_THRESHOLD",
    "BIN_SOLID_ANGLE",
    "N_DIRECTIONS",
    "EnvelopeParams",
    "EnvelopeResult",
    "sample_directions",
    "sample_frame",
    "solve",
]

#: Number of sample directions ω_j (boulanger2008 sec. 5.6: N_dir = 8).
N_DIRECTIONS = 8

#: Solid angle of one bin, Ω_j = 4π / N_dir (boulanger2008 eq. (5.1)).
BIN_SOLID_ANGLE = 4.0 * math.pi / N_DIRECTIONS

#: ``path="auto"`` uses the reference path below this many leaves and the fast
#: path from it on. Measured on uniform balls (``benchmarks/bench_smax.py``):
#: the fast path's s_max error against the reference falls with N (median 2.8%
#: at 1.5k, 2.0% at 6k, 1.7% at 20k, 1.2% at 40k leaves; the 95th percentile
#: 12%, 9%, 7%, 6%) while the reference's O(N²) cost grows (1.5 s at 20k
#: leaves, 6.4 s at 40k on 2 shared cores). Below 20k the reference is
#: affordable and is the method itself; from 20k on the fast path's median
#: error is below ~1.7%.
AUTO_FAST_THRESHOLD = 20000

TAU_ESTIMATORS = ("moments", "farthest")
PATHS = ("auto", "reference", "fast")

# A visibility product below this is folded into a running logarithm so that
# very thick crowns cannot underflow it (float64 min normal ~ 2.2e-308).
_RENORMALISE_BELOW = 1e-280


# --------------------------------------------------------------------------
# Sample directions
# --------------------------------------------------------------------------


def _unit_up(up) -> np.ndarray:
    u = np.asarray(up, dtype=float)
    if u.shape != (3,) or not np.all(np.isfinite(u)):
        raise ValueError(f"the up axis must be a finite 3-vector, got {up!r}")
    n = float(np.linalg.norm(u))
    if n == 0.0:
        raise ValueError("the up axis must not be the zero vector")
    return u / n


@lru_cache(maxsize=16)
def _frame_cached(up: tuple[float, float, float]) -> np.ndarray:
    u = np.array(up)
    # paper x axis: world +X made perpendicular to up (world +Y if up is along X)
    ref = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - np.dot(ref, u) * u
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e1, u)  # right-handed (e1, up, e2) like the paper's (x, y, z)
    frame = np.stack([e1, u, e2])
    frame.setflags(write=False)
    return frame


def sample_frame(up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Orthonormal frame (rows e1, up, e2) in which eq. (5.28) is written.

    boulanger2008 uses a Y-up frame (eq. (5.29) tests ``ω_j · y > 0``). The
    paper's x axis is world +X made perpendicular to ``up`` (world +Y when
    ``up`` is along ±X), y is ``up`` and z = x × y, so for ``up = +Y`` the
    frame is the identity and for ``up = +Z`` it is (+X, +Z, -Y).

    Returns a read-only (3, 3) float64 array.
    """
    return _frame_cached(tuple(float(c) for c in _unit_up(up)))


@lru_cache(maxsize=16)
def _directions_cached(up: tuple[float, float, float]) -> np.ndarray:
    xi = math.sqrt(3.0) / 3.0
    # boulanger2008 eq. (5.28): ω_0..ω_3 given, ω_j = -ω_{7-j} for j = 4..7
    local = np.empty((N_DIRECTIONS, 3))
    local[0] = (-xi, -xi, -xi)
    local[1] = (xi, -xi, -xi)
    local[2] = (-xi, -xi, xi)
    local[3] = (xi, -xi, xi)
    for j in range(4, 8):
        local[j] = -local[7 - j]
    dirs = local @ _frame_cached(up)
    dirs.setflags(write=False)
    return dirs


def sample_directions(up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """The 8 sample directions ω_j of boulanger2008 eq. (5.28), in that order.

    Parameters
    ----------
    up : (3,) array_like
        The stage's up axis (any length > 0).

    Returns
    -------
    (8, 3) float64, read-only. Unit vectors; ω_0..ω_3 point below the horizon
    (component -1/√3 along ``up``), ω_4..ω_7 above it, ω_j = -ω_{7-j}. In the
    frame of :func:`sample_frame`, ω_j has signs (x, y, z) with
    j = [x > 0] + 2 [z > 0] + 4 [y > 0], so the bin of a vector d (the ω_j
    nearest to d) is its octant.
    """
    return _directions_cached(tuple(float(c) for c in _unit_up(up)))


# --------------------------------------------------------------------------
# Parameters and result
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class EnvelopeParams:
    """How :func:`solve` computes s_max and τ."""

    path: str = "auto"
    """``reference`` (boulanger2008 sec. 5.6, O(N²)), ``fast`` (near field exact +
    far field on a grid, O(N)), or ``auto``: reference below ``auto_threshold``
    leaves, fast from it on."""
    auto_threshold: int = AUTO_FAST_THRESHOLD
    """Leaf count from which ``path="auto"`` switches to the fast path."""
    max_occlusion: float = 0.99
    """Upper clamp of one leaf's occlusion o of its bin (dimensionless, in (0, 1)).
    The paper's o lies in ]0, 1]; o = 1 would make the bin's visibility 0 and
    s_max infinite, so a neighbour touching P adds at most -ln(1 - max_occlusion)
    to the bin's optical depth."""
    tau_estimator: str = "moments"
    """How τ is found from the bins. ``farthest``: the paper's (boulanger2008 sec. 5.6),
    the mean over all bins of D / s_far with s_far the farthest leaf of the bin;
    since s_far exceeds the bin's mean depth, τ comes out low, more so the more
    leaves (-11% at 1.5k, -32% at 20k leaves in a uniform ball). ``moments``:
    Σ D / Σ (2 Σ o r / D), the bin length from the occlusion-weighted mean distance
    of its leaves (-7% to -10% in a uniform ball, independent of the leaf count).
    The lighting depends only on τ s_max = D, which neither choice changes."""
    fast_leaves_per_cell: float = 1.0
    """Fast path: mean number of leaves per grid cell over the leaves' bounding box;
    sets the cell size h."""
    fast_max_cells: int = 96
    """Fast path: cap on grid cells along any axis (memory/FFT size bound)."""
    fast_blend_start_cells: float = 2.3
    """Fast path: r_1 in grid cells, where the near field starts to hand over to the
    far field. Must be >= √2: then the only grid offset within a cell that the far
    kernel sees is the cell diagonal, and a leaf's own mass is removed exactly.
    With r_2 = 2.5, r_1 = 2.3 (a short blend) costs no more pairs than 1.5 and
    gives a smaller error (95th percentile at 40k leaves 6.1% instead of 7.4%):
    the near field is exact over more of the pairs it computes anyway."""
    fast_split_cells: float = 2.5
    """Fast path: r_2 in grid cells, beyond which only the far field counts (> r_1)."""
    fast_tau_leaves: int = 64
    """Fast path: leaves (seeded subsample) whose bins are also summed exactly (cost
    N per leaf; 64 keep the calibrated τ within ~0.3% at 40k leaves, ~1% at 2k). With
    ``tau_estimator="moments"`` they calibrate the fast sums' τ (ratio exact/fast on
    the same leaves); with ``farthest`` they alone give τ. All leaves when there
    are fewer."""
    seed: int = 0
    """Seed of the fast path's τ subsample."""

    def __post_init__(self) -> None:
        if self.path not in PATHS:
            raise ValueError(f"path must be one of {', '.join(PATHS)}, got {self.path!r}")
        if self.tau_estimator not in TAU_ESTIMATORS:
            raise ValueError(f"tau_estimator must be one of {', '.join(TAU_ESTIMATORS)}, got {self.tau_estimator!r}")
        if not (0.0 < self.max_occlusion < 1.0):
            raise ValueError(f"max_occlusion must lie in (0, 1), got {self.max_occlusion}")
        if int(self.auto_threshold) != self.auto_threshold or self.auto_threshold < 0:
            raise ValueError(f"auto_threshold must be an integer >= 0, got {self.auto_threshold}")
        if not (math.isfinite(self.fast_leaves_per_cell) and self.fast_leaves_per_cell > 0):
            raise ValueError(f"fast_leaves_per_cell must be > 0, got {self.fast_leaves_per_cell}")
        if int(self.fast_max_cells) != self.fast_max_cells or self.fast_max_cells < 4:
            raise ValueError(f"fast_max_cells must be an integer >= 4, got {self.fast_max_cells}")
        if not (self.fast_blend_start_cells >= math.sqrt(2.0)):
            raise ValueError(f"fast_blend_start_cells must be >= sqrt(2), got {self.fast_blend_start_cells}")
        if not (self.fast_split_cells > self.fast_blend_start_cells):
            raise ValueError(
                f"fast_split_cells ({self.fast_split_cells}) must exceed fast_blend_start_cells "
                f"({self.fast_blend_start_cells})"
            )
        if self.fast_split_cells >= self.fast_max_cells:
            raise ValueError(
                f"fast_split_cells ({self.fast_split_cells}) must be smaller than fast_max_cells ({self.fast_max_cells})"
            )
        if int(self.fast_tau_leaves) != self.fast_tau_leaves or self.fast_tau_leaves < 1:
            raise ValueError(f"fast_tau_leaves must be an integer >= 1, got {self.fast_tau_leaves}")


@dataclass(frozen=True)
class EnvelopeResult:
    """s_max, attenuation and τ of one tree, with how they were computed."""

    smax: np.ndarray
    """(L, 8) float32, stage units: distance from each leaf centre to the envelope
    toward ω_j (order of :func:`sample_directions`). 0 for an empty bin."""
    attenuation: np.ndarray
    """(L, 8) float32 in [0, 1]: exp(-τ s_max) (boulanger2008 eq. (5.30)); 1 for an empty
    bin, 0 where τ s_max > ~103 (float32 underflow)."""
    tau: float
    """Optical thickness of the tree, 1/stage unit (boulanger2008 eq. (5.5))."""
    directions: np.ndarray
    """(8, 3) float64, the ω_j the columns refer to."""
    path: str
    """``reference`` or ``fast``: the path actually used."""
    seconds: float
    """Wall time of :func:`solve`."""
    stats: dict = field(default_factory=dict)
    """``leaves``, ``tau_estimator``, ``empty_bins``; fast path also ``grid`` (node
    counts), ``cell_size``, ``blend_start`` (r_1) and ``near_radius`` (r_2) in stage
    units, ``near_pairs``, ``tau_sample_leaves`` and ``tau_correction``."""


# --------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------


def _check_leaves(centres, normals, areas) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    c = np.ascontiguousarray(centres, dtype=np.float64)
    n = np.ascontiguousarray(normals, dtype=np.float64)
    a = np.ascontiguousarray(areas, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"leaf centres must have shape (L, 3), got {c.shape}")
    if n.shape != c.shape:
        raise ValueError(f"leaf normals must have the shape of the centres {c.shape}, got {n.shape}")
    if a.shape != (c.shape[0],):
        raise ValueError(f"leaf areas must have shape ({c.shape[0]},), got {a.shape}")
    for name, arr in (("centres", c), ("normals", n), ("areas", a)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"leaf {name} contain NaN or infinite values")
    if np.any(a < 0):
        raise ValueError("leaf areas must be >= 0")
    norm = np.linalg.norm(n, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        raise ValueError("leaf normals must be unit vectors (|n| - 1 > 1e-3 found)")
    return c, n / norm[:, None], a


def solve(centres, normals, areas, *, up=(0.0, 0.0, 1.0), params: EnvelopeParams | None = None) -> EnvelopeResult:
    """s_max(P, ω_j) for every leaf and the 8 directions, and the tree's τ.

    Parameters
    ----------
    centres : (L, 3) float, stage units
        Leaf centres P.
    normals : (L, 3) float
        Unit leaf normals (the sign does not matter here).
    areas : (L,) float, stage units²
        One-sided leaf areas.
    up : (3,) float
        The stage's up axis; fixes the sample directions (:func:`sample_directions`).
    params : EnvelopeParams

    Returns
    -------
    EnvelopeResult
        ``smax`` and ``attenuation`` (L, 8) float32, ``tau`` float, all finite.
        On the reference path a bin holding no other leaf gets s_max = 0 and
        attenuation 1 (the fast path's grid blurs the bin planes, so such a bin
        may get a small value); a tree with fewer than two leaves gets τ = 0.
    """
    t0 = time.perf_counter()
    params = params or EnvelopeParams()
    c, n, a = _check_leaves(centres, normals, areas)
    frame = sample_frame(up)
    dirs = sample_directions(up)
    # positions and normals in the sample frame: the bin of d is its octant there
    x = np.ascontiguousarray(c @ frame.T)
    nl = np.ascontiguousarray(n @ frame.T)
    n_leaves = c.shape[0]
    path = params.path
    if path == "auto":
        path = "reference" if n_leaves < params.auto_threshold else "fast"

    stats: dict = {"leaves": n_leaves, "tau_estimator": params.tau_estimator}
    if path == "reference":
        depth, far, s1 = _reference_depths(x, nl, a, np.arange(n_leaves, dtype=np.int64), params.max_occlusion)
        tau = _estimate_tau(depth, far, s1, params.tau_estimator)
    else:
        depth, s1, fast_stats = _fast_depths(x, nl, a, params)
        stats.update(fast_stats)
        probes = _tau_probes(n_leaves, params.fast_tau_leaves, params.seed)
        pdepth, pfar, ps1 = _reference_depths(x, nl, a, probes, params.max_occlusion)
        stats["tau_sample_leaves"] = int(probes.shape[0])
        if params.tau_estimator == "moments":
            # τ from all leaves' fast sums, times a correction measured on the
            # probes (exact / fast on the same leaves): removes the fast sums'
            # bias (the grid blurs the bin planes, which leaks a little light
            # path into the outward bins of leaves at the envelope)
            tau = _estimate_tau(depth, None, s1, "moments")
            fast_on_probes = _estimate_tau(depth[probes], None, s1[probes], "moments")
            if fast_on_probes > 0.0:
                correction = _estimate_tau(pdepth, None, ps1, "moments") / fast_on_probes
                stats["tau_correction"] = float(correction)
                tau *= correction
        else:
            # s_far (a maximum) has no far-field form: the probes alone
            tau = _estimate_tau(pdepth, pfar, ps1, "farthest")

    if tau > 0.0:
        # (the clip only matters for absurd inputs: lengths beyond float32's range)
        smax = np.minimum(depth / tau, float(np.finfo(np.float32).max)).astype(np.float32)
    else:
        smax = np.zeros_like(depth, dtype=np.float32)
    attenuation = np.exp(-tau * smax.astype(np.float64)).astype(np.float32)
    stats["empty_bins"] = int(np.count_nonzero(depth == 0.0))
    return EnvelopeResult(
        smax=smax,
        attenuation=attenuation,
        tau=float(tau),
        directions=dirs,
        path=path,
        seconds=time.perf_counter() - t0,
        stats=stats,
    )


def _estimate_tau(depth: np.ndarray, far: np.ndarray | None, s1: np.ndarray, estimator: str) -> float:
    """τ from per-bin optical depths D, farthest-leaf distances and S1 = Σ o r (see ``tau_estimator``)."""
    if estimator == "farthest":
        used = far > 0.0
        if not np.any(used):
            return 0.0
        # boulanger2008 sec. 5.6: "For each leaf and each associated bin, we
        # first set s_max to the distance of the farthest leaf within the bin
        # and use the attenuation term to compute a value of τ. The resulting
        # τ values are averaged to get the final value of τ for the whole tree."
        return float(np.mean(depth[used] / far[used]))
    used = (depth > 0.0) & (s1 > 0.0)
    if not np.any(used):
        return 0.0
    # For leaves filling a bin out to d(ω), E[Σ o r] = τ <d²>/2 and E[D] = τ <d>
    # (<.> = mean over the bin's solid angle), so 2 S1 / D estimates
    # <d²>/<d> >= <d>: a length per bin. Pooled over all bins.
    length = 2.0 * s1[used] / depth[used]
    return float(np.sum(depth[used]) / np.sum(length))


def _tau_probes(n_leaves: int, count: int, seed: int) -> np.ndarray:
    if count >= n_leaves:
        return np.arange(n_leaves, dtype=np.int64)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n_leaves, size=count, replace=False)).astype(np.int64)


# --------------------------------------------------------------------------
# Reference path: all pairs
# --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _octant(dx: float, dy: float, dz: float) -> int:
    # bin = nearest ω_j of eq. (5.28) = octant in the sample frame (x=e1, y=up, z=e2)
    b = 0
    if dx > 0.0:
        b += 1
    if dz > 0.0:
        b += 2
    if dy > 0.0:
        b += 4
    return b


@njit(parallel=True, cache=True)
def _reference_kernel(x, nl, area, probes, inv_omega, max_occ, depth, far, s1):
    n_leaves = x.shape[0]
    for k in prange(probes.shape[0]):
        p = probes[k]
        vis = np.ones(8)
        logv = np.zeros(8)
        fmax = np.zeros(8)
        m1 = np.zeros(8)
        px = x[p, 0]
        py = x[p, 1]
        pz = x[p, 2]
        for q in range(n_leaves):
            dx = x[q, 0] - px
            dy = x[q, 1] - py
            dz = x[q, 2] - pz
            r2 = dx * dx + dy * dy + dz * dz
            if r2 == 0.0:  # P itself (and exact duplicates: no direction, no bin)
                continue
            r = math.sqrt(r2)
            b = _octant(dx, dy, dz)
            # subtended solid angle A'|N'.d^|/r² over the bin's solid angle
            o = area[q] * abs(nl[q, 0] * dx + nl[q, 1] * dy + nl[q, 2] * dz) / (r2 * r) * inv_omega
            o = min(o, max_occ)
            v = vis[b] * (1.0 - o)
            if v < _RENORMALISE_BELOW:
                logv[b] += math.log(v)
                v = 1.0
            vis[b] = v
            fmax[b] = max(fmax[b], r)
            m1[b] += o * r
        for b in range(8):
            depth[k, b] = -(math.log(vis[b]) + logv[b])
            far[k, b] = fmax[b]
            s1[k, b] = m1[b]


def _reference_depths(x, nl, area, probes, max_occlusion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bin of the leaves ``probes``: optical depth D = -ln V (eq. (1) above), s_far and S1 = Σ o r."""
    shape = (probes.shape[0], N_DIRECTIONS)
    depth, far, s1 = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    if x.shape[0] > 1:
        _reference_kernel(x, nl, area, probes, 1.0 / BIN_SOLID_ANGLE, float(max_occlusion), depth, far, s1)
    # -ln(1) can come out as -0.0
    return np.maximum(depth, 0.0), far, s1


# --------------------------------------------------------------------------
# Fast path: near field by cell lists, far field by FFT on a grid
# --------------------------------------------------------------------------


#: The far field replaces -ln(1 - o) by o; it is used only where a typical leaf
#: (99th percentile of areas, mean projected area A/2) occludes at most this
#: much of a bin, i.e. beyond r_1 >= sqrt(A_99 / (2 Ω_j · 0.1)): there the two
#: differ by < 5.5%. Dense crowns of large leaves get a coarser grid.
_FAR_FIELD_MAX_OCCLUSION = 0.1


def _grid_for(x: np.ndarray, area: np.ndarray, params: EnvelopeParams) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """Origin, cell size h and node counts of the fast path's grid (nodes at origin + i h)."""
    lo = x.min(axis=0)
    ext = x.max(axis=0) - lo
    longest = float(ext.max())
    if longest == 0.0:
        longest = 1.0
    # bounding-box volume, with flat/linear crowns thickened to 1% of the longest edge
    vol = float(np.prod(np.maximum(ext, 0.01 * longest)))
    h = (vol * params.fast_leaves_per_cell / x.shape[0]) ** (1.0 / 3.0)
    cap = int(params.fast_max_cells)
    a99 = float(np.percentile(area, 99)) if area.size else 0.0
    h_linear = math.sqrt(a99 / (2.0 * BIN_SOLID_ANGLE * _FAR_FIELD_MAX_OCCLUSION)) / params.fast_blend_start_cells
    h = max(h, h_linear, longest / (cap - 2), longest * 1e-6)
    shape = tuple(math.floor(e / h) + 2 for e in ext)
    return lo, h, shape


@njit(cache=True)
def _cell_index(x, lo, h, shape):
    n = x.shape[0]
    cell = np.empty((n, 3), dtype=np.int64)
    lin = np.empty(n, dtype=np.int64)
    for i in range(n):
        for a in range(3):
            c = math.floor((x[i, a] - lo[a]) / h)
            c = max(c, 0)
            c = min(c, shape[a] - 2)
            cell[i, a] = c
        lin[i] = (cell[i, 0] * shape[1] + cell[i, 1]) * shape[2] + cell[i, 2]
    return cell, lin


@njit(cache=True, inline="always")
def _neg_log1m(o: float) -> float:
    """-ln(1 - o) for 0 <= o < 1; a Taylor series below 0.05 (error < o⁷/7 < 1.2e-10) saves log1p."""
    if o < 0.05:
        return o * (1.0 + o * (0.5 + o * (1.0 / 3.0 + o * (0.25 + o * (0.2 + o / 6.0)))))
    return -math.log1p(-o)


@njit(cache=True, inline="always")
def _axis_gap(p: float, lo: float, hi: float) -> float:
    if p < lo:
        return lo - p
    if p > hi:
        return p - hi
    return 0.0


_NEAR_BLOCK = 128


@njit(parallel=True, cache=True, error_model="numpy")
def _near_kernel(x, an, cell, start, lo, h, shape, r1, r2, inv_omega, max_occ, depth, s1):
    """Exact near-field sums: w(r) -ln(1 - o) into ``depth`` and w(r) o r into ``s1``.

    Leaves are sorted by cell (``start``: CSR offsets of cells of size
    ``h`` >= r_2/2, so neighbours lie at most 2 cells away); ``an`` is area ×
    unit normal. Every unordered pair is visited once, from its lower sorted
    index p, and adds to both leaves: o(p, q) = A_q |N_q·d^|/(Ω r²) to p's bin
    b of d = q - p, o(q, p) = A_p |N_p·d^|/(Ω r²) to q's bin 7 - b (the
    opposite octant). A leaf p in the slab of cells i along the first axis
    has its partners q > p in slabs i..i+2, so slabs taken 3 apart never
    write to the same leaf: three passes, each parallel over its slabs,
    without locks. Each term is w -ln(1 - o), the log of the reference path's
    visibility factor (eq. (1): a sum of logs instead of the log of a
    product, so nothing to renormalise), with the smoothstep w = 1 within r_1
    (clamped, no branch). The candidates of a row of cells are first
    compacted (branch-free) to those within r_2.
    """
    n_leaves = x.shape[0]
    acc = np.zeros((n_leaves, 8))
    acc1 = np.zeros((n_leaves, 8))
    r2sq = r2 * r2
    inv_span = 1.0 / (r2 - r1)
    nx = shape[0] - 1  # slabs 0 .. shape[0] - 2 hold leaves
    slab = shape[1] * shape[2]
    pairs = np.zeros(nx, dtype=np.int64)
    for phase in range(3):
        n_phase = (nx - phase + 2) // 3
        for s in prange(n_phase):
            i_home = phase + 3 * s
            buf = np.empty(_NEAR_BLOCK, dtype=np.int64)
            npairs = 0
            for p in range(start[i_home * slab], start[(i_home + 1) * slab]):
                px = x[p, 0]
                py = x[p, 1]
                pz = x[p, 2]
                k_lo = max(cell[p, 2] - 2, 0)
                k_hi = min(cell[p, 2] + 2, shape[2] - 2)
                for i in range(i_home, min(i_home + 2, shape[0] - 2) + 1):
                    gx = _axis_gap(px, lo[0] + i * h, lo[0] + (i + 1) * h)
                    gx *= gx
                    if gx >= r2sq:
                        continue
                    for j in range(max(cell[p, 1] - 2, 0), min(cell[p, 1] + 2, shape[1] - 2) + 1):
                        gy = _axis_gap(py, lo[1] + j * h, lo[1] + (j + 1) * h)
                        if gx + gy * gy >= r2sq:
                            continue
                        row = (i * shape[1] + j) * shape[2]
                        q_end = start[row + k_hi + 1]
                        for q_start in range(max(start[row + k_lo], p + 1), q_end, _NEAR_BLOCK):
                            cnt = 0
                            for q in range(q_start, min(q_start + _NEAR_BLOCK, q_end)):
                                dx = x[q, 0] - px
                                dy = x[q, 1] - py
                                dz = x[q, 2] - pz
                                rsq = dx * dx + dy * dy + dz * dz
                                buf[cnt] = q
                                cnt += (rsq < r2sq) & (rsq > 0.0)  # duplicates of P excluded
                            npairs += cnt
                            for c in range(cnt):
                                q = buf[c]
                                dx = x[q, 0] - px
                                dy = x[q, 1] - py
                                dz = x[q, 2] - pz
                                rsq = dx * dx + dy * dy + dz * dz
                                r = math.sqrt(rsq)
                                # boulanger2008 sec. 5.6: subtended solid angle A'|N'.d^|/r² over Ω_j
                                scale = inv_omega / (rsq * r)
                                o_pq = min(abs(an[q, 0] * dx + an[q, 1] * dy + an[q, 2] * dz) * scale, max_occ)
                                o_qp = min(abs(an[p, 0] * dx + an[p, 1] * dy + an[p, 2] * dz) * scale, max_occ)
                                b = _octant(dx, dy, dz)
                                t = min(max((r2 - r) * inv_span, 0.0), 1.0)
                                w = t * t * (3.0 - 2.0 * t)
                                acc[p, b] += w * _neg_log1m(o_pq)
                                acc1[p, b] += w * o_pq * r
                                acc[q, 7 - b] += w * _neg_log1m(o_qp)
                                acc1[q, 7 - b] += w * o_qp * r
            pairs[i_home] = npairs
    depth[:] = acc
    s1[:] = acc1
    return 2 * pairs.sum()


@njit(cache=True)
def _cell(x, i, lo, h, shape):
    """Lower node and fractional offsets of point i for cloud-in-cell weights (clamped to the grid)."""
    u = (x[i, 0] - lo[0]) / h
    v = (x[i, 1] - lo[1]) / h
    w = (x[i, 2] - lo[2]) / h
    i0 = min(max(math.floor(u), 0), shape[0] - 2)
    j0 = min(max(math.floor(v), 0), shape[1] - 2)
    k0 = min(max(math.floor(w), 0), shape[2] - 2)
    return i0, j0, k0, u - i0, v - j0, w - k0


@njit(cache=True)
def _deposit(x, mass, lo, h, shape, grid):
    """Cloud-in-cell deposit of per-leaf masses (L, 4) onto 4 node grids."""
    for i in range(x.shape[0]):
        i0, j0, k0, fu, fv, fw = _cell(x, i, lo, h, shape)
        for di in range(2):
            wu = fu if di else 1.0 - fu
            for dj in range(2):
                wv = fv if dj else 1.0 - fv
                for dk in range(2):
                    wk = fw if dk else 1.0 - fw
                    wt = wu * wv * wk
                    for g in range(mass.shape[1]):
                        grid[g, i0 + di, j0 + dj, k0 + dk] += wt * mass[i, g]


@njit(parallel=True, cache=True)
def _interpolate(x, lo, h, shape, field, mass, kdiag, floor, out):
    """Far-field sums at the leaves, added to ``out`` (L, 8), from node fields (8, nx, ny, nz).

    Trilinear (cloud-in-cell) interpolation of octant j's field; a value below
    ``floor`` is float32 FFT round-off in an empty bin and counts as 0. Then
    the leaf's own mass is removed: it was deposited on the 8 nodes of its
    cell and is read back through the same nodes, and with r_1 >= √2 h the
    kernel vanishes on all offsets within a cell except the 8 cell diagonals,
    one per octant, each with weight Π f(1 - f): ``kdiag`` × that × the
    leaf's mass for octant pair min(j, 7 - j).
    """
    for i in prange(x.shape[0]):
        i0, j0, k0, fu, fv, fw = _cell(x, i, lo, h, shape)
        fu = min(max(fu, 0.0), 1.0)
        fv = min(max(fv, 0.0), 1.0)
        fw = min(max(fw, 0.0), 1.0)
        own = kdiag * fu * (1.0 - fu) * fv * (1.0 - fv) * fw * (1.0 - fw)
        for b in range(field.shape[0]):
            val = 0.0
            for di in range(2):
                wu = fu if di else 1.0 - fu
                for dj in range(2):
                    wv = fv if dj else 1.0 - fv
                    for dk in range(2):
                        wk = fw if dk else 1.0 - fw
                        val += wu * wv * wk * field[b, i0 + di, j0 + dj, k0 + dk]
            if val < floor:
                val = 0.0
            out[i, b] += val - own * mass[i, min(b, 7 - b)]


@lru_cache(maxsize=4)
def _octant_quadrature(order: int = 4) -> np.ndarray:
    """Directions and weights (Q, 4) of a product rule on the octant x, y, z > 0 (weights sum to 1).

    Uniform in solid angle: Gauss-Legendre in μ = y ∈ (0, 1) and in φ ∈ (0, π/2).
    """
    mu, wmu = np.polynomial.legendre.leggauss(order)
    mu = 0.5 * (mu + 1.0)
    ph, wph = np.polynomial.legendre.leggauss(order)
    ph = 0.25 * math.pi * (ph + 1.0)
    m, p = np.meshgrid(mu, ph, indexing="ij")
    s = np.sqrt(1.0 - m * m)
    d = np.stack([s * np.cos(p), m, s * np.sin(p)], axis=-1).reshape(-1, 3)
    wt = (wmu[:, None] * wph[None, :]).reshape(-1)
    out = np.concatenate([d, (wt / wt.sum())[:, None]], axis=1)
    out.setflags(write=False)
    return out


@njit(parallel=True, cache=True)
def _octant_projection_kernel(nl, area, quad, out):
    for i in prange(nl.shape[0]):
        for j in range(4):
            sx = 1.0 if j & 1 else -1.0
            sz = 1.0 if j & 2 else -1.0
            acc = 0.0
            for k in range(quad.shape[0]):
                acc += quad[k, 3] * abs(sx * nl[i, 0] * quad[k, 0] - nl[i, 1] * quad[k, 1] + sz * nl[i, 2] * quad[k, 2])
            out[i, j] = area[i] * acc


def _octant_projection(nl: np.ndarray, area: np.ndarray) -> np.ndarray:
    """(L, 4) A × mean of |N·d| over the directions d of octant j (= of octant 7 - j), j = 0..3.

    The far field uses this octant-averaged projected area in place of
    A |N·d^| (the leaf's actual direction from P is not known on the grid).
    """
    out = np.empty((nl.shape[0], 4))
    _octant_projection_kernel(nl, area, np.ascontiguousarray(_octant_quadrature()), out)
    return out


def _far_kernel_spectrum(shape, pad, h, r1, r2, power):
    """rFFT (complex64) of the far-field kernel of octant 0 (x, y, z < 0), for correlation.

    (1 - w(r)) / (Ω r^power) times the octant membership (1/2 per zero component:
    the node sits on a bin plane); power 2 gives the linearised optical depth of
    eq. (1), power 1 gives S1 = Σ o r. Correlation D(x) = Σ_v K(v) m(x + v) is a
    convolution with K(-v), whose support -v >= 0 fills the corner [0, s) of
    the wrap-around array.
    """
    ii, jj, kk = np.meshgrid(*[np.arange(s, dtype=np.float64) for s in shape], indexing="ij", sparse=True)
    frac = np.where(ii == 0, 0.5, 1.0) * np.where(jj == 0, 0.5, 1.0) * np.where(kk == 0, 0.5, 1.0)
    r = h * np.sqrt(ii * ii + jj * jj + kk * kk)
    t = np.clip((r2 - r) / (r2 - r1), 0.0, 1.0)
    weight = np.where(r > r1, frac * (1.0 - t * t * (3.0 - 2.0 * t)), 0.0)
    kern = (weight / (BIN_SOLID_ANGLE * np.maximum(r, r1) ** power)).astype(np.float32)
    return _rfftn_padded(kern[None], pad)[0]


def _rfftn_padded(grid: np.ndarray, pad) -> np.ndarray:
    """``scipy.fft.rfftn(grid, s=pad, axes=(1, 2, 3))`` without transforming the zero padding.

    The input fills only the corner [0, s) of the padded box, so each 1-D pass
    runs over the rows that are not all zero: the last axis on s0 s1 rows, the
    middle one on s0 (p2/2+1) rows, the first one on p1 (p2/2+1) rows.
    """
    out = scipy.fft.rfft(grid, n=pad[2], axis=3, workers=-1)
    out = scipy.fft.fft(out, n=pad[1], axis=2, workers=-1, overwrite_x=True)
    return scipy.fft.fft(out, n=pad[0], axis=1, workers=-1, overwrite_x=True)


def _irfftn_cropped(spec: np.ndarray, pad, shape) -> np.ndarray:
    """``scipy.fft.irfftn(spec, s=pad, axes=(1, 2, 3))[:, :s0, :s1, :s2]`` computing only the kept corner.

    The inverse passes are separable, so cropping each axis right after its
    pass gives the same values while the later passes run on fewer rows.
    """
    out = scipy.fft.ifft(spec, axis=1, workers=-1)[:, : shape[0]]
    out = scipy.fft.ifft(out, axis=2, workers=-1, overwrite_x=True)[:, :, : shape[1]]
    return scipy.fft.irfft(out, n=pad[2], axis=3, workers=-1)[..., : shape[2]]


def _far_field(x, mass, lo, h, shape, r1, r2, powers) -> list[np.ndarray]:
    """Far-field sums Σ_{q != P} m_q (1 - w) 1_{octant j} / (Ω r^power) at the leaves, on a grid of step h.

    One (L, 8) array per entry of ``powers``; the masses are deposited and
    transformed once for all of them.
    """
    shape_arr = np.array(shape, dtype=np.int64)
    grid = np.zeros((4,) + tuple(shape), dtype=np.float32)
    _deposit(x, mass, lo, h, shape_arr, grid)
    pad = tuple(scipy.fft.next_fast_len(2 * s - 1, real=True) for s in shape)
    mspec = _rfftn_padded(grid, pad)
    del grid
    specs = np.empty((N_DIRECTIONS,) + mspec.shape[1:], dtype=mspec.dtype)
    results = []
    for power in powers:
        _octant_spectra(mspec, _far_kernel_spectrum(shape, pad, h, r1, r2, power), specs)
        fields = np.ascontiguousarray(_irfftn_cropped(specs, pad, shape))
        # kernel on the cell diagonal √3 h, for the leaf's own mass (see _interpolate)
        diag = math.sqrt(3.0) * h
        t = min(max((r2 - diag) / (r2 - r1), 0.0), 1.0)
        kdiag = (1.0 - t * t * (3.0 - 2.0 * t)) / (BIN_SOLID_ANGLE * diag**power)
        # float32 FFT round-off (~1e-7 of the largest value) would leave empty bins
        # slightly non-zero: what is below 1e-6 of the largest counts as 0
        floor = 1e-6 * float(np.abs(fields).max(initial=0.0))
        out = np.zeros((x.shape[0], N_DIRECTIONS))
        _interpolate(x, lo, h, shape_arr, fields, mass, kdiag, floor, out)
        results.append(out)
    return results


@njit(parallel=True, cache=True)
def _octant_spectra(mspec, kspec, out):
    """out[j] = mspec[min(j, 7 - j)] × spectrum of octant j's kernel, from octant 0's ``kspec``.

    Octant j's kernel is octant 0's reflected along the axes where j is
    positive (x if j&1, y if j&4, z if j&2): k_j(u) = k_0(S u), whose spectrum
    is F[k_0](S ξ). The last axis of an rFFT holds only ξ3 >= 0, so a flip of
    it uses F(ξ1, ξ2, -ξ3) = conj F(-ξ1, -ξ2, ξ3), true for any real kernel.
    """
    p0, p1, n2 = kspec.shape
    for i0 in prange(p0):
        a0 = np.int64(i0)  # prange's index may be unsigned: keep the reflected index an integer
        for j in range(8):
            pair = j if j < 4 else 7 - j
            conj = (j & 2) != 0
            neg0 = ((j & 1) != 0) != conj
            neg1 = ((j & 4) != 0) != conj
            k0 = (p0 - a0) % p0 if neg0 else a0
            for i1 in range(p1):
                k1 = (p1 - i1) % p1 if neg1 else i1
                for i2 in range(n2):
                    kv = kspec[k0, k1, i2]
                    if conj:
                        kv = kv.conjugate()
                    out[j, i0, i1, i2] = mspec[pair, i0, i1, i2] * kv


def _near_sums(x, nl, area, lo, r1, r2, max_occlusion) -> tuple[np.ndarray, np.ndarray, int]:
    """Near-field D and S1 (L, 8) of every leaf, and the number of (ordered) pairs within r_2.

    Σ over the other leaves q within r_2 of w(r) -ln(1 - o) and w(r) o r, w
    the smoothstep from 1 at r_1 to 0 at r_2; a cell list with cells of r_2/2
    (neighbours at most 2 cells away), leaves sorted by cell.
    """
    hn = 0.5 * r2
    nshape = np.array([math.floor(e / hn) + 2 for e in (x.max(axis=0) - lo)], dtype=np.int64)
    cell, lin = _cell_index(x, lo, hn, nshape)
    n_cells = int(np.prod(nshape))
    order = np.argsort(lin, kind="stable")
    start = np.zeros(n_cells + 1, dtype=np.int64)
    np.cumsum(np.bincount(lin, minlength=n_cells), out=start[1:])
    depth_s = np.empty((x.shape[0], N_DIRECTIONS))
    s1_s = np.empty_like(depth_s)
    pairs = _near_kernel(
        np.ascontiguousarray(x[order]), np.ascontiguousarray((nl * area[:, None])[order]), cell[order], start, lo,
        hn, nshape, r1, r2, 1.0 / BIN_SOLID_ANGLE, float(max_occlusion), depth_s, s1_s,
    )
    depth = np.empty_like(depth_s)
    s1 = np.empty_like(s1_s)
    depth[order] = depth_s
    s1[order] = s1_s
    return depth, s1, int(pairs)


def _fast_depths(x, nl, area, params: EnvelopeParams) -> tuple[np.ndarray, np.ndarray, dict]:
    """Optical depth D and S1 = Σ o r of every bin of every leaf: exact near field + FFT far field."""
    n_leaves = x.shape[0]
    if n_leaves < 2:
        return np.zeros((n_leaves, N_DIRECTIONS)), np.zeros((n_leaves, N_DIRECTIONS)), {}
    lo, h, shape = _grid_for(x, area, params)
    r2 = params.fast_split_cells * h
    r1 = params.fast_blend_start_cells * h
    stats = {"grid": list(shape), "cell_size": h, "near_radius": r2, "blend_start": r1}

    depth, s1, pairs = _near_sums(x, nl, area, lo, r1, r2, float(params.max_occlusion))
    stats["near_pairs"] = pairs

    # far field: mean projected area per octant pair, deposited on the nodes
    mass = _octant_projection(nl, area)
    # larger leaves than the grid was sized for (above the 99th percentile):
    # cap their far-field occlusion at r_1 to the most one leaf can give, -ln(1 - max_occlusion)
    np.minimum(mass, -math.log1p(-params.max_occlusion) * BIN_SOLID_ANGLE * r1 * r1, out=mass)
    # optical depth (kernel 1/r², eq. (1) linearised) and S1 = Σ o r (kernel 1/r)
    far_depth, far_s1 = _far_field(x, mass, lo, h, shape, r1, r2, (2, 1))
    depth += far_depth
    s1 += far_s1
    return np.maximum(depth, 0.0), np.maximum(s1, 0.0), stats

"""The **fast path** (particle-particle / particle-mesh splitting): near field by cell lists, far field by FFT.

Sum (1) of the reference path (``reference.py``) is split with a smooth weight
w(r) that falls from 1 at r_1 to 0 at r_2 (a C¹ smoothstep):

* near field, r < r_2: the exact terms w(r) · -ln(1 - o), summed over the
  leaves of neighbouring cells (cell list of cell size r_2/2). Each unordered
  pair is visited once and adds to both leaves (o(P, P') uses A' and N', o(P',
  P) uses A and N, in opposite octants), see ``_near_kernel``;
* far field, r > r_1: the leaves are far, so -ln(1 - o) ≈ o, which is linear
  in the leaves: (1 - w(r)) o. The grid does not know P, so a leaf's
  projected area A' |N'·d^| toward P is replaced, over the directions d of
  octant j, by its least-squares linear fit a_j + β_j·|d| (``_octant_projection``;
  one fit per octant pair j, 7 - j). The 4 coefficients are deposited on the
  nodes of a grid (cloud-in-cell), the sum over nodes of mass × (1 - w(|v|))
  1_{octant j}(v) (1, |v_x|, |v_y|, |v_z|)/|v| / (Ω_j |v|²) is a discrete
  convolution done with FFTs (4 kernel spectra, reflected for the 8
  octants; the zero padding is not transformed and only the kept corner is
  transformed back), and the result is interpolated trilinearly back to
  every leaf. A leaf's own mass is subtracted exactly (r_1 >= √2 h leaves
  only the cell diagonals, see ``_interpolate``).
* two grids (``EnvelopeParams.fast_fine_grid``, the default): the grid's
  error is largest just beyond r_1, where 1/r² varies most across a cell and
  the blur of the bin planes (below) is widest relative to r. So the far
  field from r_1 to the mid range r_m (8 -> 10 cells, smoothstep) is summed on
  a grid of step h/2 with the fit (its FFTs only need the padding of the
  kernel's reach r_m, not of the whole grid), and beyond r_m on the grid of
  step h with the fit's mean over the octant, a + Σ β/2 (where the grid is
  accurate and the fit matters less).

S1 = Σ o r (for τ) is split the same way with a 1/r kernel. τ from the fast
sums is multiplied by a calibration, exact/fast τ on ``fast_tau_leaves``
probe leaves whose bins are also summed exactly (the fast sums are a control
variate: over random probe sets of 64 leaves at 40k leaves the calibrated τ
scatters by 0.3%, the probes' own τ by 1.7%). With two grids the sums for τ
(D and S1 from r_1 on) come from the grid of step h alone: a bin's length 2
S1 / D needs both sums blurred alike (D from two grids and S1 from one
made nearly empty bins absurdly long, τ -12% at 40k leaves).

Accuracy. On uniform balls (τ R = 2) the fast path's s_max differs from the
reference's by a median 0.8% (95th percentile 2.6%) at 1.5k leaves, 0.6%
(2.1%) at 6k, 0.8% (2.0%) at 20k, 0.5% (1.7%) at 40k and 0.45% (1.5%) at
100k, with τ within 0.7% (``benchmarks/bench_smax.py``; bins with s_max >=
0.05 R), with the near field out to r_2 = 4.3 h (the default). At 40k
leaves (1000 leaves summed exactly, all-pairs sums that include only one cause) the
projection alone gives a 95th percentile of 1.3% with the fit, 3.3% with the
octant mean; the rest is the grid: cloud-in-cell interpolation of the 1/r²
kernel and the blur of the bin planes (a leaf within ~h of a plane through
P is shared between octants), mostly from r_1 to ~4 h (measured by shells on
one grid: the 95th percentile of the grid error of a shell falls from 6% of
the depth for 2.3-3.3 h to 0.8% beyond 10 h, for bins with s_max in [0.2,
0.4) R); the linearisation -ln(1 - o) ≈ o adds 0.17% (at r_1 = 1.5 h). The
errors concentrate on the short bins: a leaf near the envelope sees, toward
the outside, a thin sliver of crown along the bin planes, and the blur leaks
depth into it from the full neighbouring octants. The figures for other
settings (r_2 = 2.5 h, one grid, the octant-mean projected area before the
fit) and what was tried without gain are in ``docs/envelope_notes.md``.
Cost: O(N ρ r_2³) near pairs, O(M log M) for M grid nodes (the fine
grid has 8x the nodes of the coarse one: with it the fast path takes ~2x
the time of one grid) and O(N_probe N) for the probes.
"""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.lighting.envelope.directions import BIN_SOLID_ANGLE, N_DIRECTIONS
from foliage_tools.lighting.envelope.far_field import _far_field
from foliage_tools.lighting.envelope.grid import _axis_max, _cell_index, _grid_for
from foliage_tools.lighting.envelope.near_field import _near_sums
from foliage_tools.lighting.envelope.params import EnvelopeParams
from foliage_tools.lighting.envelope.projection import _octant_projection


def _fast_depths(x, nl, area, params: EnvelopeParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Optical depth D of every bin of every leaf (exact near field + FFT far field), and for τ D and S1 = Σ o r.

    The sums for τ are D itself on a single grid; with ``fast_fine_grid`` they
    come from the coarse grid alone (see there).
    """
    n_leaves = x.shape[0]
    if n_leaves < 2:
        zero = np.zeros((n_leaves, N_DIRECTIONS))
        return zero, zero, zero, {}
    lo, h, shape = _grid_for(x, area, params)
    # work on the leaves sorted by grid cell: the deposits, interpolations and near-field
    # sums then touch memory in order (random order costs much more in cache and page misses,
    # measured in docs/envelope_notes.md); results go back to the caller's order
    _, lin = _cell_index(x, lo, h, np.array(shape, dtype=np.int64))
    order = np.argsort(lin, kind="stable")
    x, nl, area = x[order], nl[order], area[order]
    r2 = params.fast_split_cells * h
    r1 = params.fast_blend_start_cells * h
    stats = {"grid": list(shape), "cell_size": h, "near_radius": r2, "blend_start": r1}

    depth, s1, pairs = _near_sums(x, nl, area, lo, r1, r2, float(params.max_occlusion))
    stats["near_pairs"] = pairs

    # far field: per leaf and octant pair, the linear fit of the projected area
    mass = _octant_projection(nl, area)
    # larger leaves than the grid was sized for (above the 99th percentile):
    # cap their mean far-field occlusion at r_1 to the most one leaf can give, -ln(1 - max_occlusion)
    # (the fit's mean over the octant is a + (β_x + β_y + β_z)/2: |d_k| averages 1/2 there)
    mean = mass[:, :, 0] + 0.5 * mass[:, :, 1:].sum(axis=2)
    cap = -math.log1p(-params.max_occlusion) * BIN_SOLID_ANGLE * r1 * r1
    scale = cap / np.maximum(mean, cap)
    mass *= scale[:, :, None]
    mean = np.ascontiguousarray((mean * scale)[:, :, None])
    near_band = (params.fast_blend_start_cells, params.fast_split_cells, math.inf, math.inf)
    # the fine grid: fast_fine_ratio × the cell size, at most fast_max_cells cells along an axis
    ext = _axis_max(x) - lo
    h_fine = max(params.fast_fine_ratio * h, float(ext.max()) / (params.fast_max_cells - 2))
    if params.fast_fine_grid and h_fine <= 0.75 * h:
        # optical depth (kernel 1/r², eq. (1) linearised): from r_1 to the mid range on the
        # fine grid with the projection fit, beyond it on the grid of step h with the fit's
        # octant mean. For τ, depth and S1 = Σ o r (kernel 1/r) from r_1 on, on the grid of
        # step h alone: a bin's length 2 S1 / D needs both sums blurred alike (a bin nearly
        # empty on one grid but not on the other would get an absurd length)
        shape_fine = tuple(math.floor(e / h_fine) + 2 for e in ext)
        mid = (params.fast_mid_start_cells, params.fast_mid_end_cells)
        stats["fine_grid"] = list(shape_fine)
        stats["mid_range"] = [mid[0] * h, mid[1] * h]
        fine_band = tuple(b * h / h_fine for b in near_band[:2] + mid)
        (far_depth,) = _far_field(x, mass, lo, h_fine, shape_fine, [(fine_band, 2)])
        coarse_band = mid + (math.inf, math.inf)
        coarse_depth, tau_far, far_s1 = _far_field(x, mean, lo, h, shape, [(coarse_band, 2), (near_band, 2), (near_band, 1)])
        far_depth += coarse_depth
        tau_depth = np.maximum(depth + tau_far, 0.0)
        depth += far_depth
    else:
        # one grid of step h with the projection fit: optical depth and S1 = Σ o r
        far_depth, far_s1 = _far_field(x, mass, lo, h, shape, [(near_band, 2), (near_band, 1)])
        depth += far_depth
        tau_depth = None
    s1 += far_s1

    def unsorted(a: np.ndarray) -> np.ndarray:  # back to the caller's leaf order
        out = np.empty_like(a)
        out[order] = a
        return out

    depth = unsorted(np.maximum(depth, 0.0))
    return depth, depth if tau_depth is None else unsorted(tau_depth), unsorted(np.maximum(s1, 0.0)), stats

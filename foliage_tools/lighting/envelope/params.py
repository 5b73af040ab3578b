"""What :func:`~foliage_tools.lighting.envelope.solve` takes and gives back: :class:`EnvelopeParams` and :class:`EnvelopeResult`.

The parameters choose the path (reference or fast), τ's estimator
(``tau.py``) and the fast path's grid and near/far blend (``fast.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


#: ``path="auto"`` uses the reference path below this many leaves and the fast
#: path from it on. Measured on uniform balls (``benchmarks/bench_smax.py``):
#: the fast path's s_max error against the reference (median 0.8% at 1.5k,
#: 0.6% at 6k, 0.8% at 20k, 0.5% at 40k leaves; the 95th percentile 2.6%,
#: 2.1%, 2.0%, 1.7%) while the reference's O(N²) cost grows (the timings of
#: both paths at 20k and 40k leaves: ``docs/envelope_notes.md``). Below 20k the
#: reference is affordable and is the method itself; from 20k on the fast path's
#: 95th percentile error is at most ~2%.
AUTO_FAST_THRESHOLD = 20000

TAU_ESTIMATORS = ("moments", "farthest")
PATHS = ("auto", "reference", "fast")


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
    """Fast path: cap on grid cells along any axis (memory/FFT size bound), for the
    coarse grid and for the fine grid of ``fast_fine_grid`` (which is dropped when
    the cap leaves it less than 4/3 finer than the coarse one)."""
    fast_blend_start_cells: float = 4.0
    """Fast path: r_1 in grid cells, where the near field starts to hand over to the
    far field. Must be >= √2: then the only grid offset within a cell that the far
    kernel sees is the cell diagonal, and a leaf's own mass is removed exactly.
    A short blend (r_2 - r_1 = 0.2-0.3) costs no more pairs than a long one and
    gives a smaller error: the near field is exact over more of the pairs it
    computes anyway. The near field's reach sets the accuracy: the s_max error
    at 40k leaves (``tests/unit/test_envelope_fast.py``' measure, crown seeds
    1-5, median / 95th percentile, with the fine grid) is 0.70-0.74% / 3.4-3.6%
    at r_1/r_2 = 2.3/2.5, 0.46-0.49% / 1.87-1.95% at 3.7/4.0 and 0.43-0.46% /
    1.66-1.82% at 4.0/4.3 (the default); one grid: 0.95-1.05% / 5.3-5.7%, 0.74-0.80%
    / 2.9-3.3% and 0.52-0.55% / 3.0-3.4%. The pairs grow as r_2³: at 40k leaves
    4.5M, 17.6M and 21.6M (the fast path's time for each: ``docs/envelope_notes.md``)."""
    fast_split_cells: float = 4.3
    """Fast path: r_2 in grid cells, beyond which only the far field counts (> r_1)."""
    fast_fine_grid: bool = True
    """Fast path: compute the far field from r_1 to the mid range on a second grid of
    half the cell size (``fast_fine_ratio``; 8x the nodes, FFTs only as large as the mid range needs)
    and leave the grid of cell size h only the far field beyond it. The grid
    errors are largest just beyond r_1, in cells: this lowers the 95th
    percentile of the s_max error from 5.3% to 3.5% at 40k leaves (4.2% to 2.8%
    at 100k) for ~2x the fast path's time (measured: ``docs/envelope_notes.md``).
    False: one grid, about the cost of the octant-mean version with its error
    lowered from 6.0% / 4.7% by the projection fit."""
    fast_fine_ratio: float = 0.5
    """Fast path with ``fast_fine_grid``: the fine grid's cell size over h, in (0, 0.75].
    95th percentile of the s_max error at 40k / 100k leaves: 0.5: 3.5% / 2.8%;
    0.6: 4.1% / 3.2%; 0.67: 4.2% / 3.3%; ``fast_fine_grid=False``: 5.3% / 4.2%
    (the fast path's time for each: ``docs/envelope_notes.md``)."""
    fast_mid_start_cells: float = 8.0
    """Fast path with ``fast_fine_grid``: where the fine grid starts handing over to the
    coarse one, in (coarse) cells; must exceed ``fast_split_cells``."""
    fast_mid_end_cells: float = 10.0
    """Fast path with ``fast_fine_grid``: beyond this (coarse cells) only the coarse grid
    counts; must exceed ``fast_mid_start_cells``. The fine grid's FFT sizes are its
    node counts + 2 × this (5-smooth): at 40k leaves 70 + 20 -> 90 per axis, the
    same as with 6 -> 8 (95th percentile 3.64%) or 4 -> 5 (4.2%, sizes 80)."""
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
        if not (0.0 < self.fast_fine_ratio <= 0.75):
            raise ValueError(f"fast_fine_ratio must lie in (0, 0.75], got {self.fast_fine_ratio}")
        if not (self.fast_mid_start_cells > self.fast_split_cells):
            raise ValueError(
                f"fast_mid_start_cells ({self.fast_mid_start_cells}) must exceed fast_split_cells "
                f"({self.fast_split_cells})"
            )
        if not (self.fast_mid_end_cells > self.fast_mid_start_cells and math.isfinite(self.fast_mid_end_cells)):
            raise ValueError(
                f"fast_mid_end_cells ({self.fast_mid_end_cells}) must be finite and exceed fast_mid_start_cells "
                f"({self.fast_mid_start_cells})"
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
    units, ``near_pairs``, ``tau_sample_leaves`` and ``tau_correction``; with the fine
    grid ``fine_grid`` (node counts) and ``mid_range`` (where it hands over to the
    coarse grid, stage units)."""

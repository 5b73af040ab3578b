"""Estimating τ, the tree's optical thickness, from the bins (``EnvelopeParams.tau_estimator``).

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
"""

from __future__ import annotations

import numpy as np


def _estimate_tau(depth: np.ndarray, far: np.ndarray | None, s1: np.ndarray, estimator: str) -> float:
    """τ from per-bin optical depths D, farthest-leaf distances and S1 = Σ o r (see ``tau_estimator``)."""
    if estimator == "farthest":
        assert far is not None  # every "farthest" call passes the farthest-leaf distances
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

"""The paper's method (boulanger2008 sec. 5.6), the **reference path**: all pairs of leaves, O(N²).

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
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from foliage_tools.lighting.envelope.directions import BIN_SOLID_ANGLE, N_DIRECTIONS, _octant


# A visibility product below this is folded into a running logarithm so that
# very thick crowns cannot underflow it (float64 min normal ~ 2.2e-308).
_RENORMALISE_BELOW = 1e-280


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

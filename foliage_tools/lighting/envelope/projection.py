"""The far field's projected areas: per leaf and octant pair, the linear fit of A |N·d^| over the octant.

The grid of the far field does not know the leaf P that looks at a leaf q,
so q's projected area toward P is replaced by this fit
(``_octant_projection``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit, prange


#: Gauss-Legendre order (per angle) of the octant quadrature behind the projection fit
#: (order 4 to 8 give the same s_max errors to 0.01%).
_PROJECTION_ORDER = 4


@lru_cache(maxsize=4)
def _octant_quadrature(order: int = _PROJECTION_ORDER) -> np.ndarray:
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


@lru_cache(maxsize=4)
def _projection_fit_matrix(order: int = _PROJECTION_ORDER) -> np.ndarray:
    """(4, Q) weighted least-squares operator: values f(e_q) at the octant quadrature -> (a, β_x, β_y, β_z).

    Minimises Σ_q w_q (f(e_q) - a - β·e_q)² over the octant's directions e
    (e > 0), i.e. the L² fit over the octant's solid angle of a linear function.
    """
    quad = _octant_quadrature(order)
    e1 = np.concatenate([np.ones((quad.shape[0], 1)), quad[:, :3]], axis=1)
    ew = e1 * quad[:, 3:]
    fit = np.linalg.solve(e1.T @ ew, ew.T)
    fit.setflags(write=False)
    return fit


@njit(parallel=True, cache=True)
def _octant_projection_kernel(nl, area, quad, fit, out):
    nq = quad.shape[0]
    for i in prange(nl.shape[0]):
        f = np.empty((4, nq))
        for k in range(nq):
            # octant j (y < 0; x > 0 if j & 1, z > 0 if j & 2): d = S_j e with e in the positive octant
            px = nl[i, 0] * quad[k, 0]
            py = -nl[i, 1] * quad[k, 1]
            pz = nl[i, 2] * quad[k, 2]
            f[0, k] = area[i] * abs(-px + py - pz)
            f[1, k] = area[i] * abs(px + py - pz)
            f[2, k] = area[i] * abs(-px + py + pz)
            f[3, k] = area[i] * abs(px + py + pz)
        for j in range(4):
            for c in range(4):
                acc = 0.0
                for k in range(nq):
                    acc += fit[c, k] * f[j, k]
                out[i, j, c] = acc


def _octant_projection(nl: np.ndarray, area: np.ndarray) -> np.ndarray:
    """(L, 4, 4): per octant pair j = 0..3 the linear fit (a, β_x, β_y, β_z) of A |N·d| over octant j.

    boulanger2008 sec. 5.6: a leaf q occludes A |N·d^|/r² of the solid angle
    around P, d^ = (q - P)/r. The far field cannot use the exact d^ (the
    grid does not know P), so over the directions d^ of octant j it uses the
    least-squares linear fit A |N·d^| ≈ a + Σ_k β_k |d^_k| (L² over the
    octant's solid angle). |N·d| is the same on octant j and on 7 - j (d -> -d)
    and so is |d_k|: one fit per octant pair. The far field then needs 4
    deposits per pair (a, β) and 4 kernels (1, |v_x|/r, |v_y|/r, |v_z|/r)
    times (1 - w) / (Ω r^power). Compared with the octant-mean projected area
    (a only, β = 0), the projection's own error (all-pairs far sums with only
    this approximation, 40k leaves) falls from a 95th percentile of 3.3% of
    the depth to 1.3%; the fast path's s_max error from 6.0% to 5.3% on one
    grid (the rest is the grid's).
    """
    out = np.empty((nl.shape[0], 4, 4))
    _octant_projection_kernel(
        nl, area, np.ascontiguousarray(_octant_quadrature()), np.ascontiguousarray(_projection_fit_matrix()), out
    )
    return out

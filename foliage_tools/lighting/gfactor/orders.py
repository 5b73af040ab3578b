"""G per order of scattering (``SPPGParams.g_orders``): the exact slab's once-scattered share s, the recollision
ratio ρ of the real medium over the slab, and G s / (1 - (1 - s) ρ). Package docstring
(:mod:`foliage_tools.lighting.gfactor`), "Orders of scattering".
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from foliage_tools.lighting.gfactor.factor import _face_distance
from foliage_tools.lighting.gfactor.models import _exact_leaf_irradiance


#: Albedo of the single-scattering tables of ``g_orders``: the exact slab's E at ω = ε, times ω/ε, is its
#: once-scattered part to O(ε) relative.
_ONCE_ALBEDO = 1e-4


def _once_scattered_share(u, big_u, mu, weights, albedo, phases, total) -> np.ndarray:
    """(L, C) s = E_1 / E: the once-scattered share of the exact slab's E_scattered (``g_orders``, package docstring).

    E_1 is the exact slab solution at albedo ε = 1e-4 scaled by ω/ε (single scattering is linear in ω for a fixed
    phase). Where E = 0 (no medium), s = 1: G is then left as it is.
    """
    eps = _ONCE_ALBEDO
    once = _exact_leaf_irradiance(u, big_u, mu, weights, np.full_like(albedo, eps), phases) * (albedo / eps)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(total > 0.0, once / np.where(total > 0.0, total, 1.0), 1.0)
    return np.clip(share, 0.0, 1.0)


@njit(cache=True)
def _slab_lengths(vn, mu0, light_depth, light_thickness):
    """(P, N) L_v of every point toward every direction (``_face_distance``, as ``_gfactor_kernel`` takes it)."""
    out = np.empty((light_depth.shape[0], vn.shape[0]))
    for p in range(light_depth.shape[0]):
        t0 = mu0 * light_depth[p]
        below = mu0 * (light_thickness[p] - light_depth[p]) if light_thickness[p] != math.inf else math.inf
        for q in range(vn.shape[0]):
            out[p, q] = _face_distance(vn[q], t0, below)
    return out


def recollision_ratio(boundary_depth, vn, mu0: float, light_depth, light_thickness) -> np.ndarray:
    """(P,) ρ = p_real / p_slab in [0, 1], p = 1 - mean_v exp(-depth toward v) (package docstring, "Orders of
    scattering"); 1 where the slab holds no medium (p_slab = 0)."""
    h = np.asarray(boundary_depth, dtype=np.float64)
    p_real = 1.0 - np.exp(-h).mean(axis=1)
    lengths = _slab_lengths(np.ascontiguousarray(vn, dtype=np.float64), float(mu0),
                            np.ascontiguousarray(light_depth, dtype=np.float64),
                            np.ascontiguousarray(light_thickness, dtype=np.float64))
    p_slab = 1.0 - np.exp(-lengths).mean(axis=1)
    ratio = np.divide(p_real, p_slab, out=np.ones_like(p_real), where=p_slab > 0.0)
    return np.clip(ratio, 0.0, 1.0)


def _all_over_first(share, rho) -> np.ndarray:
    """1 / (1 - (1 - s) ρ): all orders over the first, the later ones at the slab's ratio times ρ (package
    docstring, "Orders of scattering"; the first order's G taken out of ``_orders_g``)."""
    den = 1.0 - (1.0 - share) * np.asarray(rho, dtype=np.float64)
    return np.where(den > 0.0, 1.0 / np.where(den > 0.0, den, 1.0), 1.0)


def _orders_g(g, share, rho) -> np.ndarray:
    """G s / (1 - (1 - s) ρ): the first order keeps G, each later one ρ of the slab's ratio (package docstring)."""
    rho = np.asarray(rho, dtype=np.float64)
    den = 1.0 - (1.0 - share) * rho
    return np.where(den > 0.0, g * share / np.where(den > 0.0, den, 1.0), g)

"""The plane-parallel part of the scattered light per leaf (``SPPGParams.model``): the exact slab's tables looked up
per leaf (:mod:`~foliage_tools.lighting.spp.slab_table`) and the SPP closed form's refined radiance (shinya2013 app. A.1)
integrated over each leaf's two faces. Package docstring (:mod:`foliage_tools.lighting.gfactor`), "Geometry and
normalisation".
"""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.lighting.gfactor.directions import _frame
from foliage_tools.lighting.gfactor.params import EXACT_STREAMS, SPPGParams
from foliage_tools.lighting.spp.slab_table import slab_table
from foliage_tools.lighting.spp import forward_fraction, refined_parts


#: Leaves per block in the refined leaf integral (bounds temporary memory).
_REFINE_BLOCK = 4096


def _refined_leaf_irradiance(
    u, big_u, nl, sun, upv, mu0, phases, albedo, t_sun, params: SPPGParams
) -> np.ndarray:
    """∫ I_refined(s) |n · s| dΩ per leaf and channel (shinya2013 eq. (32) with a two-sided Lambertian leaf)."""
    inward = -upv
    s0 = -sun  # propagation direction of the beam
    horiz = s0 - (s0 @ inward) * inward
    if np.linalg.norm(horiz) < 1e-12:
        ex, ey = _frame(inward)
    else:
        ex = horiz / np.linalg.norm(horiz)
        ey = np.cross(inward, ex)
    xg, wg = np.polynomial.legendre.leggauss(params.refine_polar_nodes)
    mu_h = 0.5 * (xg + 1.0)
    w_h = 0.5 * wg
    mu = np.concatenate([mu_h, -mu_h])  # cosine to the inward normal
    w_mu = np.concatenate([w_h, w_h])
    n_az = params.refine_azimuth_nodes
    phi = (np.arange(n_az) + 0.5) * (2.0 * math.pi / n_az)
    w_phi = 2.0 * math.pi / n_az
    sin_t = np.sqrt(1.0 - mu * mu)
    dirs = (
        mu[:, None, None] * inward
        + (sin_t[:, None] * np.cos(phi)[None, :])[:, :, None] * ex
        + (sin_t[:, None] * np.sin(phi)[None, :])[:, :, None] * ey
    )  # (M, A, 3)
    cos_scat = np.clip(dirs @ s0, -1.0, 1.0)  # (M, A)
    n_ch = albedo.shape[0]
    p_scat = np.stack([np.asarray(phases[c](cos_scat), dtype=np.float64) for c in range(n_ch)])  # (C, M, A)
    t_ray = np.stack([forward_fraction(phases[c], np.abs(mu)) for c in range(n_ch)])  # (C, M)
    n_leaves = u.shape[0]
    out = np.empty((n_leaves, n_ch))
    for start in range(0, n_leaves, _REFINE_BLOCK):
        sl = slice(start, min(start + _REFINE_BLOCK, n_leaves))
        cos_n = np.abs(np.einsum("lk,mak->lma", nl[sl], dirs))  # (B, M, A)
        a_iso = cos_n.sum(axis=2) * w_phi  # (B, M)
        a_beam = np.einsum("lma,cma->lmc", cos_n, p_scat) * (w_phi / (4.0 * math.pi))  # (B, M, C)
        parts = refined_parts(
            u[sl, None, None],
            big_u[sl, None, None],
            mu0=mu0,
            mu=mu[None, :, None],
            albedo=albedo[None, None, :],
            forward_fraction_sun=t_sun[None, None, :],
            forward_fraction_ray=t_ray.T[None, :, :],
        )  # (B, M, C)
        out[sl] = np.einsum("m,lmc->lc", w_mu, parts.iso * a_iso[:, :, None] + parts.beam * a_beam)
    return out


def _exact_leaf_irradiance(u, big_u, mu, weights, albedo, phases) -> np.ndarray:
    """Exact plane-parallel E_scattered per leaf and channel for a light of cosine ``mu`` (package docstring).

    Slant depth u and thickness U along the light (shinya2013 eq. (29)) are the
    vertical optical depth and thickness t = μ u, τ = μ U of the local slab;
    ``weights`` = :func:`~foliage_tools.lighting.spp.slab_table.leaf_weights` of |n · up| per leaf.
    """
    t = mu * np.asarray(u, dtype=np.float64)
    tau = mu * np.asarray(big_u, dtype=np.float64)
    out = np.empty((t.shape[0], albedo.shape[0]))
    for c in range(albedo.shape[0]):
        table = slab_table(omega=float(albedo[c]), phase=phases[c], mu0=float(mu), n_streams=EXACT_STREAMS)
        out[:, c] = table.leaf_irradiance(t, tau, weights=weights)
    return out

""":func:`solve_sppg`: SPPG, SPP and SS irradiance per leaf for the sun and a uniform sky (shinya2013 sec. 5.4
steps 4-6), from the depths through the plane-parallel part, the G-factor and its orders. Package docstring
(:mod:`foliage_tools.lighting.gfactor`).
"""

from __future__ import annotations

import time

import numpy as np

from foliage_tools.lighting.depth import DepthSamples
from foliage_tools.lighting.gfactor.directions import _unit, sky_weights
from foliage_tools.lighting.gfactor.factor import gfactor
from foliage_tools.lighting.gfactor.models import _exact_leaf_irradiance, _refined_leaf_irradiance
from foliage_tools.lighting.gfactor.orders import _all_over_first, _once_scattered_share, _orders_g, recollision_ratio
from foliage_tools.lighting.gfactor.params import EXACT_STREAMS, LeafIrradiance, SPPGParams, SPPGResult
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.phase import canopy_bilambertian_phase
from foliage_tools.lighting.spp.slab_table import leaf_weights
from foliage_tools.lighting.spp import forward_fraction, spp_field


def _check_normals(normals, n: int) -> np.ndarray:
    nl = np.asarray(normals, dtype=np.float64)
    if nl.shape != (n, 3) or not np.all(np.isfinite(nl)):
        raise ValueError(f"normals must be finite with shape ({n}, 3), got {nl.shape}")
    norm = np.linalg.norm(nl, axis=1)
    if np.any(norm == 0.0):
        raise ValueError("normals must be non-zero (leaf normals)")
    return nl / norm[:, None]


def solve_sppg(
    depths: DepthSamples,
    *,
    normals,
    optics: LeafOptics,
    sun_direction,
    directions,
    up=(0.0, 0.0, 1.0),
    neighbour_depths: DepthSamples | None = None,
    params: SPPGParams | None = None,
    sun_visible=None,
    sample_visible=None,
    g_depths: DepthSamples | None = None,
) -> SPPGResult:
    """SPPG, SPP and SS irradiance per leaf for the sun and a uniform sky (shinya2013 sec. 5.4 steps 4-6).

    Parameters
    ----------
    depths : DepthSamples
        Optical depths of the L leaf centres toward the sun and the N sample
        directions (grid path: :func:`~foliage_tools.lighting.depth.depth_samples`
        with ``points`` = leaf centres; or from intersection counts).
    normals : array_like (L, 3)
        Leaf normals (either orientation; both faces are summed).
    optics : LeafOptics
        Leaf reflectance and transmittance per channel. The canopy is taken as
        spherically distributed bi-Lambertian leaves: albedo r + t and
        :func:`~foliage_tools.lighting.phase.canopy_bilambertian_phase` per channel.
    sun_direction : array_like (3,)
        Direction toward the sun; must be above the horizon.
    directions : array_like (N, 3)
        The sample directions of ``depths`` (:func:`sample_directions`).
    up : array_like (3,)
        The stage's up axis (slab normal).
    neighbour_depths : DepthSamples, optional
        Optical depths through neighbouring instances along the same rays
        (shinya2013 eq. (31); :func:`~foliage_tools.lighting.depth.instance_depth_samples`),
        added to ``depths``.
    params : SPPGParams, optional
        ``model`` chooses the plane-parallel part: the exact slab solution
        (default) or the paper's SPP closed form.
    sun_visible : array_like (L,), optional
        Fraction of each leaf that sees the sun through its own prototype's
        leaves (ray path); E_direct = |n · l| × that × exp(-neighbour depth)
        instead of |n · l| exp(-u).
    sample_visible : array_like (L, N), optional
        The same per sample direction, for the sky's direct light.
    g_depths : DepthSamples, optional
        Depths of the same L points from which the G-factors are computed
        (plus ``neighbour_depths``) instead of ``depths``: e.g. through a
        coarse density grid, whose smooth depths do not bias G low the way
        per-leaf depth noise does (package docstring, "Depth noise").

    Returns
    -------
    SPPGResult
    """
    start = time.perf_counter()
    params = SPPGParams() if params is None else params
    if not isinstance(depths, DepthSamples):
        # ValueError, not TypeError: the project reports all bad inputs as ValueError
        raise ValueError(f"depths must be a DepthSamples, got {type(depths).__name__}")  # noqa: TRY004
    if not isinstance(optics, LeafOptics):
        raise ValueError(f"optics must be a LeafOptics, got {type(optics).__name__}")  # noqa: TRY004
    nb = neighbour_depths
    if neighbour_depths is not None:
        depths = depths + neighbour_depths
    if g_depths is None:
        g_depths = depths
    else:
        if not isinstance(g_depths, DepthSamples):
            raise ValueError(f"g_depths must be a DepthSamples, got {type(g_depths).__name__}")  # noqa: TRY004
        if (g_depths.n_points, g_depths.n_directions) != (depths.n_points, depths.n_directions):
            raise ValueError("g_depths must hold the same points and directions as depths")
        if neighbour_depths is not None:
            g_depths = g_depths + neighbour_depths
    upv = _unit(up, "up")
    sun = _unit(sun_direction, "sun_direction")
    mu0 = float(sun @ upv)
    if mu0 <= 0.0:
        raise ValueError(f"the sun must be above the horizon (elevation > 0), cosine to up = {mu0:.3g}")
    dirs = np.asarray(directions, dtype=np.float64)
    if dirs.shape != (depths.n_directions, 3):
        raise ValueError(f"directions must have shape ({depths.n_directions}, 3) like depths, got {dirs.shape}")
    norms = np.linalg.norm(dirs, axis=1)
    if not np.all(np.isfinite(norms)) or np.any(norms == 0.0):
        raise ValueError("directions must be finite non-zero vectors")
    dirs = dirs / norms[:, None]
    n_leaves = depths.n_points
    nl = _check_normals(normals, n_leaves)

    albedo = np.asarray(optics.albedo, dtype=np.float64)
    phases = [
        canopy_bilambertian_phase(reflectance=float(r), transmittance=float(t))
        for r, t in zip(optics.reflectance, optics.transmittance)
    ]
    n_ch = albedo.shape[0]

    # --- sun ---------------------------------------------------------------
    u = depths.sun_depth
    big_u = depths.sun_thickness
    t_sun = np.array([float(forward_fraction(ph, mu0)) for ph in phases])
    if sun_visible is None:
        direct = np.abs(nl @ sun) * np.exp(-u)
    else:
        direct = np.abs(nl @ sun) * np.asarray(sun_visible, dtype=np.float64) * np.exp(-(0.0 if nb is None else nb.sun_depth))
    direct3 = np.repeat(direct[:, None], n_ch, axis=1)

    def g_of(light, light_depth, light_thickness) -> np.ndarray:
        """(L, C) G toward ``light``: one column per channel (its phase) with radiance weights."""
        kw = dict(boundary_depth=g_depths.sample_depth, directions=dirs, light_direction=light,
                  light_depth=light_depth, light_thickness=light_thickness, up=upv)
        if params.g_weights == "paper":
            return np.repeat(gfactor(**kw)[:, None], n_ch, axis=1)
        return np.stack([gfactor(**kw, weights="radiance", phase=ph) for ph in phases], axis=1)

    g_sun = g_of(sun, g_depths.sun_depth, g_depths.sun_thickness)
    model = params.resolved_model
    leaf_w = leaf_weights(np.abs(nl @ upv), EXACT_STREAMS) if model == "exact" or params.g_orders else None
    if model == "exact":
        scat = _exact_leaf_irradiance(u, big_u, mu0, leaf_w, albedo, phases)
    elif params.refine:
        scat = _refined_leaf_irradiance(u, big_u, nl, sun, upv, mu0, phases, albedo, t_sun, params)
    else:
        scat = spp_field(u[:, None], big_u[:, None], albedo=albedo[None, :], forward_fraction=t_sun[None, :]).leaf_irradiance

    def share_rho(uu, ww, mu, e_model, g_light_depth, g_light_thickness) -> tuple[np.ndarray, np.ndarray]:
        """The exact slab's once-scattered share (L, C) and the recollision ratio through G's depths (L, 1)."""
        exact = e_model if model == "exact" else _exact_leaf_irradiance(uu, ww, mu, leaf_w, albedo, phases)
        share = _once_scattered_share(uu, ww, mu, leaf_w, albedo, phases, exact)
        rho = recollision_ratio(g_depths.sample_depth, dirs @ upv, mu, g_light_depth, g_light_thickness)
        return share, rho[:, None]

    def orders(g, uu, ww, mu, e_model, g_light_depth, g_light_thickness) -> np.ndarray:
        """``g_orders``: G per order of scattering, from the exact slab's once-scattered share and the recollision
        ratio through G's depths."""
        if not params.g_orders:
            return g
        return _orders_g(g, *share_rho(uu, ww, mu, e_model, g_light_depth, g_light_thickness))

    sun_orders = None
    if params.g_orders:
        share, rho = share_rho(u, big_u, mu0, scat, g_depths.sun_depth, g_depths.sun_thickness)
        g_sun = _orders_g(g_sun, share, rho)
        sun_orders = _all_over_first(share, rho)

    # --- sky -----------------------------------------------------------------
    sky_direct = np.zeros((n_leaves, n_ch))
    sky_spp = np.zeros((n_leaves, n_ch))
    sky_sppg = np.zeros((n_leaves, n_ch))
    if params.sky:
        weights = sky_weights(dirs, up=upv)
        mus = dirs @ upv
        for j in np.flatnonzero(weights > 0.0):
            uj = depths.sample_depth[:, j]
            wj = depths.sample_thickness[:, j]
            if model == "exact":
                ej = _exact_leaf_irradiance(uj, wj, float(mus[j]), leaf_w, albedo, phases)
            else:
                tj = np.array([float(forward_fraction(ph, mus[j])) for ph in phases])
                ej = spp_field(uj[:, None], wj[:, None], albedo=albedo[None, :], forward_fraction=tj[None, :]).leaf_irradiance
            gd, gw = g_depths.sample_depth[:, j], g_depths.sample_thickness[:, j]
            gj = orders(g_of(dirs[j], gd, gw), uj, wj, float(mus[j]), ej, gd, gw)
            if sample_visible is None:
                vis_j = np.exp(-uj)
            else:
                vis_j = np.asarray(sample_visible, dtype=np.float64)[:, j] * np.exp(-(0.0 if nb is None else nb.sample_depth[:, j]))
            sky_direct += (weights[j] * np.abs(nl @ dirs[j]) * vis_j)[:, None]
            sky_spp += weights[j] * ej
            sky_sppg += weights[j] * gj * ej

    zeros = np.zeros((n_leaves, n_ch))
    result = SPPGResult(
        sppg=LeafIrradiance(direct=direct3, scattered=g_sun * scat, sky_direct=sky_direct, sky_scattered=sky_sppg),
        spp=LeafIrradiance(direct=direct3, scattered=scat, sky_direct=sky_direct, sky_scattered=sky_spp),
        ss=LeafIrradiance(direct=direct3, scattered=zeros, sky_direct=sky_direct, sky_scattered=zeros.copy()),
        gfactor=g_sun.mean(axis=1),
        directions=dirs,
        mu0=mu0,
        refined=bool(params.refine),
        seconds=time.perf_counter() - start,
        model=model,
        orders=sun_orders,
    )
    return result

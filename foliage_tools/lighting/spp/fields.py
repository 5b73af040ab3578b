"""The public SPP fields (:mod:`foliage_tools.lighting.spp`; derivation in the package docstring).

:class:`SPPField` from :func:`spp_field` (the closed form) and
:func:`spp_single_scattering` (its first order in ω); :class:`RefinedParts`
from :func:`refined_parts` (app. A.1's refinement) and
:func:`refined_radiance` (the parts combined with the phase function);
the checks of their inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from foliage_tools.lighting.phase import PhaseFunction
from foliage_tools.lighting.spp.forward import forward_fraction
from foliage_tools.lighting.spp.kernels import _refined_kernel, _spp_kernel


# --------------------------------------------------------------------------
# public SPP API
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class SPPField:
    """SPP radiance field at given depths, per unit beam irradiance.

    All arrays share the broadcast shape of the inputs of :func:`spp_field`.
    """

    direct: np.ndarray
    """Unscattered beam, exp(-u): its irradiance on a plane perpendicular to the beam."""
    down: np.ndarray
    """a = ∫_{Ω+} I_diffuse dΩ: diffuse light going deeper (radiance a/2π on Ω+)."""
    up: np.ndarray
    """b = ∫_{Ω-} I_diffuse dΩ: diffuse light going back toward the lit face."""

    @property
    def actinic_diffuse(self) -> np.ndarray:
        """a + b = ∫ I_diffuse dΩ over the sphere."""
        return self.down + self.up

    @property
    def leaf_irradiance(self) -> np.ndarray:
        """Diffuse irradiance on a flat leaf, both faces summed: (a + b)/2 for every orientation.

        ∫_{hemisphere} |n · s| dΩ = π for any unit n and either hemisphere of the
        slab normal, so a radiance a/2π on Ω+ and b/2π on Ω- gives (a + b)/2
        whatever the leaf normal n.
        """
        return 0.5 * (self.down + self.up)


def _as_array(name: str, value) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number or array") from None
    if np.any(np.isnan(arr)):
        raise ValueError(f"{name} must not contain NaN")
    return arr


def _check_slab(depth, thickness, albedo, fwd):
    depth = _as_array("depth", depth)
    thickness = _as_array("thickness", thickness)
    albedo = _as_array("albedo", albedo)
    fwd = _as_array("forward_fraction", fwd)
    if np.any(thickness < 0.0):
        raise ValueError("thickness (slant optical thickness) must be >= 0 (inf allowed)")
    if np.any(depth < 0.0):
        raise ValueError("depth (slant optical depth) must be >= 0")
    if np.any(albedo < 0.0) or np.any(albedo > 1.0):
        raise ValueError("albedo (single-scattering albedo) must be in [0, 1]")
    if np.any(fwd < 0.0) or np.any(fwd > 1.0):
        raise ValueError("forward_fraction T must be in [0, 1]")
    depth, thickness, albedo, fwd = np.broadcast_arrays(depth, thickness, albedo, fwd)
    if np.any(depth > thickness):
        raise ValueError("depth must not exceed thickness (both slant optical depths along the beam)")
    return depth, thickness, albedo, fwd


def spp_field(depth, thickness, *, albedo, forward_fraction) -> SPPField:
    """SPP solution (shinya2013 eqs. (17)-(22), re-derived: see the package docstring).

    Parameters
    ----------
    depth : array_like
        Slant optical depth u from the lit face along the beam (shinya2013
        eq. (29): n+ for intersection counts), 0 <= u <= thickness.
    thickness : array_like
        Slant optical thickness U of the slab along the beam, 0 .. inf.
    albedo : array_like
        Single-scattering albedo ω in [0, 1] (1 is exact: conservative scattering).
    forward_fraction : array_like
        T(μ0) in [0, 1], e.g. :func:`forward_fraction` (phase, μ0).

    All inputs broadcast together.

    Returns
    -------
    SPPField
        Beam, a and b per unit beam irradiance (radiance sr⁻¹ on each hemisphere
        is a/2π, b/2π).
    """
    d, w, om, tf = _check_slab(depth, thickness, albedo, forward_fraction)
    shape = d.shape
    flat = [np.array(x, dtype=np.float64).ravel() for x in (d, w, om, tf)]
    a = np.empty(flat[0].shape)
    b = np.empty(flat[0].shape)
    _spp_kernel(*flat, a, b)  # type: ignore[call-arg]  # numba's Dispatcher stub does not type a jitted function's arguments
    direct = np.exp(-d)
    return SPPField(direct=direct.reshape(shape), down=a.reshape(shape), up=b.reshape(shape))


def spp_single_scattering(depth, thickness, *, albedo, forward_fraction) -> SPPField:
    """First-order (once-scattered) part of the SPP field: the ω -> 0 limit of :func:`spp_field`.

    a1 = ωT u e^{-u},  b1 = ωR e^{-u} (1 - e^{-2(U-u)}) / 2
    (solutions of eq. (i) of the package docstring to first order in ω).
    """
    d, w, om, tf = _check_slab(depth, thickness, albedo, forward_fraction)
    e = np.exp(-d)
    # written so that inf - inf and inf * 0 never occur (depth = thickness = inf gives 0)
    rest = np.subtract(w, d, out=np.full(d.shape, np.inf), where=np.isfinite(w))
    b = om * (1.0 - tf) * e * 0.5 * -np.expm1(-2.0 * rest)
    a = om * tf * np.multiply(d, e, out=np.zeros(d.shape), where=e > 0.0)
    return SPPField(direct=e, down=a, up=b)


@dataclass(frozen=True)
class RefinedParts:
    """Refined diffuse radiance = ``iso + beam * p(cos Θ) / 4π`` (sr⁻¹ per unit beam irradiance).

    Θ is the scattering angle between the beam's propagation direction and the
    ray direction; p is the phase function in the 1/4π normalisation of
    :mod:`~foliage_tools.lighting.phase`.
    """

    iso: np.ndarray
    """Part from the SPP diffuse field: ω ∫ kernel (S+ a + S- b); depends on μ only."""
    beam: np.ndarray
    """ω ∫ kernel e^{-u'}: the exact single scattering of the beam, without p/4π."""


def refined_parts(depth, thickness, *, mu0, mu, albedo, forward_fraction_sun, forward_fraction_ray) -> RefinedParts:
    """Refined SPP radiance in a ray direction (shinya2013 sec. 3.5 and app. A.1, re-derived).

    Parameters
    ----------
    depth, thickness : array_like
        Slant optical depth and thickness along the beam (as :func:`spp_field`).
    mu0 : array_like
        Cosine of the beam to the inward slab normal, 0 < μ0 <= 1.
    mu : array_like
        Cosine of the ray direction to the *inward* normal (> 0: going deeper,
        < 0: going back toward the lit face), μ != 0.
    albedo : array_like
        ω in [0, 1].
    forward_fraction_sun, forward_fraction_ray : array_like
        T(μ0) and T(|μ|) of the phase function (:func:`forward_fraction`).

    Returns
    -------
    RefinedParts
    """
    d, w, om, tf = _check_slab(depth, thickness, albedo, forward_fraction_sun)
    mu0 = _as_array("mu0", mu0)
    mu = _as_array("mu", mu)
    tr = _as_array("forward_fraction_ray", forward_fraction_ray)
    if np.any(mu0 <= 0.0) or np.any(mu0 > 1.0):
        raise ValueError("mu0 (cosine of the beam to the slab normal) must be in (0, 1]")
    if np.any(mu == 0.0) or np.any(np.abs(mu) > 1.0):
        raise ValueError("mu (ray cosine to the inward normal) must be in [-1, 1] and non-zero")
    if np.any(tr < 0.0) or np.any(tr > 1.0):
        raise ValueError("forward_fraction_ray must be in [0, 1]")
    arrays = np.broadcast_arrays(d, w, om, tf, mu0, mu, tr)
    shape = arrays[0].shape
    d, w, om, tf, m0, m, tr = [np.array(x, dtype=np.float64).ravel() for x in arrays]
    c = m0 / np.abs(m)
    upward = m < 0.0
    iso = np.empty(d.shape)
    beam = np.empty(d.shape)
    _refined_kernel(d, w, om, tf, c, upward, tr, iso, beam)
    return RefinedParts(iso=iso.reshape(shape), beam=beam.reshape(shape))


def refined_radiance(depth, thickness, *, mu0, mu, phi, albedo, phase: PhaseFunction) -> np.ndarray:
    """Refined diffuse radiance at (μ, φ): :func:`refined_parts` combined with the phase function.

    ``phi`` is the ray azimuth relative to the azimuth of the beam's propagation
    direction; the scattering cosine is cos Θ = μ μ0 + sqrt(1-μ²) sqrt(1-μ0²) cos φ
    (μ to the inward normal, so μ > 0 is forward-going). Returns sr⁻¹ per unit
    beam irradiance; the beam itself (a delta) is not included.
    """
    mu0 = _as_array("mu0", mu0)
    mu = _as_array("mu", mu)
    phi = _as_array("phi", phi)
    if np.any(mu0 <= 0.0) or np.any(mu0 > 1.0):
        raise ValueError("mu0 (cosine of the beam to the slab normal) must be in (0, 1]")
    if np.any(np.abs(mu) > 1.0) or np.any(mu == 0.0):
        raise ValueError("mu (ray cosine to the inward normal) must be in [-1, 1] and non-zero")
    t_sun = forward_fraction(phase, mu0)
    t_ray = forward_fraction(phase, np.abs(mu))
    parts = refined_parts(
        depth, thickness, mu0=mu0, mu=mu, albedo=albedo, forward_fraction_sun=t_sun, forward_fraction_ray=t_ray
    )
    cos_t = mu * mu0 + np.sqrt(np.maximum(0.0, 1.0 - mu * mu)) * np.sqrt(np.maximum(0.0, 1.0 - mu0 * mu0)) * np.cos(phi)
    p = np.asarray(phase(np.clip(cos_t, -1.0, 1.0)), dtype=float)
    return parts.iso + parts.beam * p / (4.0 * math.pi)

"""The G-factor itself (shinya2013 eqs. (23)-(27), re-derived): the numba kernel of the present fractions F_v and
their weights, and :func:`gfactor`. The derivation ("The G-factor") and the weighting ("Weighting the directions")
are in the package docstring (:mod:`foliage_tools.lighting.gfactor`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from foliage_tools.lighting.gfactor.directions import _unit
from foliage_tools.lighting.gfactor.params import G_WEIGHTS


@njit(cache=True)
def _present_fraction(c, h, length):
    """F of the package docstring: share of the plane-parallel single scattering present."""
    if h >= length or length == 0.0:
        return 1.0
    if length != math.inf and abs(c) * length < 1e-8:
        # nearly coincident rates: first-order expansion of the ratio (error ~(cL)² <= 1e-16),
        # also avoids 0/0 when c L underflows
        return h / length * (1.0 + 0.5 * c * (length - h))
    if c > 0.0:
        return math.expm1(-c * h) / math.expm1(-c * length) if length != math.inf else -math.expm1(-c * h)
    if c == 0.0:
        return h / length
    a = -c  # c < 0 only for v_n > μ0, where L = t0 / v_n is finite unless d0 = inf
    if length == math.inf:
        return 0.0
    return math.exp(-a * (length - h)) * math.expm1(-a * h) / math.expm1(-a * length)


@njit(cache=True)
def _log_path_integral(a, length):
    """log ∫_0^L e^{-a l} dl for a >= 0 (-inf for L = 0; inf for a = 0, L = inf)."""
    if length == 0.0:
        return -math.inf
    if length == math.inf:
        return -math.log(a) if a > 0.0 else math.inf
    x = a * length
    if x < 1e-8:
        return math.log(length) + math.log1p(-0.5 * x)
    return math.log(-math.expm1(-x)) - math.log(a)


@njit(cache=True)
def _log_pp_single_scattering(c, length, d0):
    """log of δI(P, P) along one direction, without the common factor ω σ/(4π) and the phase (package docstring).

    δI(P, P) ∝ ∫_0^L e^{-l} e^{-(d0 - l v_n/μ0)} dl = e^{-d0} ∫_0^L e^{-c l} dl for c >= 0 and, for c < 0 (the
    ray climbs toward the lit face faster than the beam's depth falls), e^{-L} ∫_0^L e^{-|c| l} dl, since then
    |c| L = d0 - L: only decaying exponentials, finite for any depth.
    """
    if c >= 0.0:
        if d0 == math.inf:
            return -math.inf
        return -d0 + _log_path_integral(c, length)
    return -length + _log_path_integral(-c, length)


@njit(cache=True)
def _face_distance(v, t0, below):
    """L: optical distance from a point to its slab's face along a direction of cosine ``v`` to up (the top face,
    ``t0`` above, for v > 0; the bottom one, ``below`` under, for v < 0; inf along the horizon)."""
    if v > 0.0:
        return t0 / v
    if v < 0.0:
        return below / -v
    return math.inf


@njit(cache=True)
def _gfactor_kernel(h, vn, mu0, d0, w0, log_phase, weighted, out):
    n_pts, n_dir = h.shape
    frac = np.empty(n_dir)
    logw = np.empty(n_dir)
    for p in range(n_pts):
        t0 = mu0 * d0[p]
        below = mu0 * (w0[p] - d0[p]) if w0[p] != math.inf else math.inf
        acc = 0.0
        top = -math.inf
        for q in range(n_dir):
            v = vn[q]
            length = _face_distance(v, t0, below)
            c = 1.0 - v / mu0
            frac[q] = _present_fraction(c, h[p, q], length)
            acc += frac[q]
            if weighted:
                logw[q] = log_phase[q] + _log_pp_single_scattering(c, length, d0[p])
                if logw[q] > top:
                    top = logw[q]
        if not weighted or top == -math.inf or top == math.inf:
            # eq. (27); also where no direction carries plane-parallel single scattering (a point
            # with no medium along any direction: G = 1 there, as with the paper's mean)
            out[p] = acc / n_dir
            continue
        num = 0.0
        den = 0.0
        for q in range(n_dir):
            w = math.exp(logw[q] - top)
            num += w * frac[q]
            den += w
        out[p] = num / den


def gfactor(*, boundary_depth, directions, light_direction, light_depth, light_thickness, up=(0.0, 0.0, 1.0),
            weights: str = "paper", phase=None) -> np.ndarray:
    """Geometric compensation factor G per point (shinya2013 eqs. (26)-(27), re-derived).

    Parameters
    ----------
    boundary_depth : array_like (P, N)
        Optical depth h from each point to the medium's boundary toward each
        sample direction (``DepthSamples.sample_depth``).
    directions : array_like (N, 3)
        The sample directions (unit vectors).
    light_direction : array_like (3,)
        Direction toward the light; must be above the horizon (· up > 0).
    light_depth, light_thickness : array_like (P,)
        Slant optical depth and chord thickness of each point along the light.
    up : array_like (3,)
        Slab normal (the stage's up axis).
    weights : {"paper", "radiance"}
        How the directions' present fractions F_v are combined (package
        docstring): ``"paper"``, eq. (27)'s equal-weight mean; ``"radiance"``,
        each F_v weighted by the plane-parallel single-scattering radiance
        δI(P, P) arriving from v (the ratio of the summed eq. (24) integrals).
    phase : callable, optional
        With ``weights="radiance"``: the phase function p(cos Θ) (1/4π
        normalisation) of the light scattered toward P, evaluated at
        cos Θ = light_direction · v; None: isotropic. Ignored for ``"paper"``.

    Returns
    -------
    numpy.ndarray (P,)
        G in [0, 1]; 1 where the medium is plane-parallel around the point.
    """
    if weights not in G_WEIGHTS:
        raise ValueError(f"weights must be one of {', '.join(G_WEIGHTS)}, got {weights!r}")
    upv = _unit(up, "up")
    light = _unit(light_direction, "light_direction")
    mu0 = float(light @ upv)
    if mu0 <= 0.0:
        raise ValueError(f"the light must be above the horizon (cosine to up = {mu0:.3g})")
    h = np.asarray(boundary_depth, dtype=np.float64)
    dirs = np.asarray(directions, dtype=np.float64)
    d0 = np.asarray(light_depth, dtype=np.float64)
    w0 = np.asarray(light_thickness, dtype=np.float64)
    if dirs.ndim != 2 or dirs.shape[1] != 3 or h.ndim != 2 or h.shape[1] != dirs.shape[0]:
        raise ValueError(f"boundary_depth (P, N) and directions (N, 3) disagree: {h.shape}, {dirs.shape}")
    if d0.shape != (h.shape[0],) or w0.shape != d0.shape:
        raise ValueError("light_depth and light_thickness must have shape (P,)")
    for name, arr in (("boundary_depth", h), ("light_depth", d0), ("light_thickness", w0)):
        if np.any(np.isnan(arr)) or np.any(arr < 0.0):
            raise ValueError(f"{name} must be >= 0 (inf allowed)")
    if np.any(d0 > w0):
        raise ValueError("light_depth must not exceed light_thickness")
    vn = np.ascontiguousarray(dirs @ upv)
    log_phase = np.zeros(dirs.shape[0])
    if weights == "radiance" and phase is not None:
        pv = np.asarray(phase(np.clip(dirs @ light, -1.0, 1.0)), dtype=np.float64).reshape(dirs.shape[0])
        if np.any(~np.isfinite(pv)) or np.any(pv < 0.0):
            raise ValueError("the phase function must be finite and >= 0")
        with np.errstate(divide="ignore"):
            log_phase = np.log(pv)
    out = np.empty(h.shape[0])
    _gfactor_kernel(np.ascontiguousarray(h), vn, mu0, np.ascontiguousarray(d0), np.ascontiguousarray(w0),
                    np.ascontiguousarray(log_phase), weights == "radiance", out)
    return out

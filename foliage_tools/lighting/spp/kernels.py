"""Numba kernels of the SPP closed form (:mod:`foliage_tools.lighting.spp`; derivation in the package docstring).

Scalar convolutions of decaying exponentials that stay exact through every
coincidence of rates (:func:`_e2`, :func:`_e3` and their helpers), the SPP
field (a, b) at a point (:func:`_spp_point`), the refined radiance's
(iso, beam) at a point (:func:`_refined_point`), and their loops over
flat arrays (:func:`_spp_kernel`, :func:`_refined_kernel`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_INF = math.inf
_TWO_PI = 2.0 * math.pi
#: Terms of the series for the second divided difference of φ1 (see _psi).
_PSI_TERMS = 18
_MOMENTS = 2 * _PSI_TERMS  # moments M_0 .. M_{2*_PSI_TERMS - 1}


# --------------------------------------------------------------------------
# scalar kernels: convolutions of decaying exponentials, stable at coincidence
# --------------------------------------------------------------------------


@njit(cache=True)
def _mul(k, length):
    """k * length with 0 * inf taken as 0 (a zero rate over an infinite path)."""
    if k == 0.0:
        return 0.0
    return k * length


@njit(cache=True)
def _phi1(x):
    """(1 - e^{-x}) / x for x >= 0; 1 at x = 0, 0 at x = inf (expm1: no cancellation)."""
    if x == 0.0:
        return 1.0
    if x == _INF:
        return 0.0
    return -math.expm1(-x) / x


@njit(cache=True)
def _h(k, length):
    """h(k, L) = ∫_0^L e^{-2ks} ds = (1 - e^{-2kL}) / (2k); L at k = 0, 1/(2k) at L = inf."""
    if length == _INF:
        if k == 0.0:
            return _INF
        return 0.5 / k
    return length * _phi1(2.0 * k * length)


@njit(cache=True)
def _e2(a, b, length):
    """E2(a, b, L) = ∫_0^L e^{-a (L - x)} e^{-b x} dx for rates a, b >= 0, L in [0, inf].

    = e^{-lo L} L φ1((hi - lo) L) with lo/hi the smaller/larger rate: only
    decaying exponentials, continuous (and exact) at a = b.
    """
    lo = min(a, b)
    hi = max(a, b)
    if length == _INF:
        if lo > 0.0:
            return 0.0
        if hi > 0.0:
            return 1.0 / hi
        return _INF
    if length == 0.0:
        return 0.0
    return math.exp(-lo * length) * length * _phi1((hi - lo) * length)


@njit(cache=True)
def _moments(x, out):
    """out[n] = M_n(x) = ∫_0^1 s^n e^{-x s} ds, n = 0 .. len(out)-1, x >= 0.

    For x <= 50 the highest moment comes from the positive series
    M_n = e^{-x} Σ_j x^j n!/(n+j+1)! (Kummer's form of the incomplete gamma
    function; every term positive) and the others from the downward recurrence
    M_{n-1} = (x M_n + e^{-x}) / n; for x > 50 (> n) from the upward recurrence
    M_n = (n M_{n-1} - e^{-x}) / x, M_0 = (1 - e^{-x})/x. Both recurrences are
    used in their stable direction.
    """
    nmax = out.shape[0] - 1
    ex = math.exp(-x)
    if x <= 50.0:
        term = 1.0 / (nmax + 1.0)
        total = term
        j = 0
        while True:
            j += 1
            term *= x / (nmax + 1.0 + j)
            total += term
            if term <= 1e-17 * total:
                break
        out[nmax] = ex * total
        for n in range(nmax, 0, -1):
            out[n - 1] = (x * out[n] + ex) / n
    else:
        out[0] = -math.expm1(-x) / x
        for n in range(1, nmax + 1):
            out[n] = (n * out[n - 1] - ex) / x


@njit(cache=True)
def _psi(x, y):
    """Ψ(x, y) = (φ1(x) - φ1(y)) / (y - x) for 0 <= x <= y (Ψ(x, x) = -φ1'(x) = M_1(x)).

    Ψ is the integral of e^{-x s2 - y s3} over the unit simplex s1+s2+s3 = 1.
    Close arguments (y - x <= 2, or y <= 2x) use the series
    Ψ = Σ_j M_{2j+1}(m) (δ/2)^{2j} / (2j+1)!, m = (x+y)/2, δ = y - x
    (expansion of ∫_0^1 s e^{-ms} sinh(δs/2)/(δ/2) ds); its terms fall at least
    like 9^{-j}. Otherwise φ1(x) - φ1(y) >= 0.2 φ1(x), so the difference is safe.
    """
    d = y - x
    if d <= 2.0 or y <= 2.0 * x:
        m = 0.5 * (x + y)
        if m == _INF:
            return 0.0
        mom = np.empty(_MOMENTS)
        _moments(m, mom)
        hh = 0.25 * d * d
        coef = 1.0
        total = 0.0
        for j in range(_PSI_TERMS):
            total += coef * mom[2 * j + 1]
            coef *= hh / ((2 * j + 2.0) * (2 * j + 3.0))
        return total
    return (_phi1(x) - _phi1(y)) / d


@njit(cache=True)
def _e3(r_a, r_b, r_c, length):
    """E3 = ∫∫∫_{x1+x2+x3=L} e^{-r_a x1 - r_b x2 - r_c x3} (2-D simplex) for rates >= 0.

    The divided difference of E2 in one rate: E2(a, b1, L) - E2(a, b2, L) =
    (b2 - b1) E3(a, b1, b2, L). With r1 <= r2 <= r3 the sorted rates,
    E3 = e^{-r1 L} L² Ψ((r2 - r1) L, (r3 - r1) L); L = inf gives 0 if r1 > 0,
    else 1 / (r2 r3).
    """
    r1 = min(r_a, min(r_b, r_c))
    r3 = max(r_a, max(r_b, r_c))
    r2 = r_a + r_b + r_c - r1 - r3
    r2 = min(max(r2, r1), r3)  # rounding in the sum above
    if length == _INF:
        if r1 > 0.0:
            return 0.0
        if r2 > 0.0:
            return 1.0 / (r2 * r3)
        return _INF
    if length == 0.0:
        return 0.0
    t = math.exp(-r1 * length) * length
    if t == 0.0:
        return 0.0
    return t * (length * _psi((r2 - r1) * length, (r3 - r1) * length))


# --------------------------------------------------------------------------
# SPP field and refinement (scalar kernels)
# --------------------------------------------------------------------------


@njit(cache=True)
def _constants(omega, t_fwd):
    """(P, Q, P+Q, s, k, rho, 1-k) of the package docstring; P+Q = 0 means no coupling."""
    r_bwd = 1.0 - t_fwd
    sa = 1.0 - omega
    p = sa + omega * r_bwd  # = 1 - ωT, written without cancellation
    q = omega * r_bwd
    ppq = sa + 2.0 * q
    if ppq == 0.0:
        return p, q, ppq, 0.0, 0.0, 0.0, 1.0
    s = math.sqrt(sa / ppq)
    k = ppq * s
    rho = q / (p + k)
    one_minus_k = (omega * t_fwd * (2.0 - omega * t_fwd) + q * q) / (1.0 + k)
    return p, q, ppq, s, k, rho, one_minus_k


@njit(cache=True)
def _spp_point(u, big_u, omega, t_fwd):
    """(a, b) at slant depth u of a slab of slant thickness U (package docstring)."""
    p, _q, ppq, s, k, rho, omk = _constants(omega, t_fwd)
    if ppq == 0.0:
        # ω = 1 and R = 0: nothing is scattered backward and nothing absorbed:
        # A = 1, B = 0.
        return -math.expm1(-u), 0.0
    gk = math.exp(-_mul(k, u))
    first = gk * -math.expm1(-_mul(omk, u))
    if big_u == _INF:
        return first, rho * gk
    c = ppq * (1.0 + s) ** 2 / (p + k) ** 2
    d = c + 2.0 * rho * rho * _h(k, big_u)
    v = big_u - u
    a = first - gk * 2.0 * rho * rho * math.exp(-2.0 * k * v) * _h(k, u) / d
    b = gk * 2.0 * rho * _h(k, v) / d
    # a >= 0 analytically (da/du(0) = ωT + ωR B(0) >= 0 and the ODE keeps it
    # non-negative); clip rounding-level negatives.
    return max(a, 0.0), b


@njit(cache=True)
def _spp_kernel(u, big_u, omega, t_fwd, a_out, b_out):
    for i in range(u.shape[0]):
        a_out[i], b_out[i] = _spp_point(u[i], big_u[i], omega[i], t_fwd[i])


@njit(cache=True)
def _refined_point(u, big_u, omega, t_sun, c, upward, t_ray):
    """(iso, beam): refined diffuse radiance = iso + beam * p(s·s0)/(4π) (package docstring).

    c = μ0/|μ| is the ray's attenuation rate per unit slant depth; ``t_ray`` the
    fraction of the phase function that the ray direction s scatters into its
    own hemisphere (T(|μ|)).
    """
    p, _q, ppq, s, k, rho, omk = _constants(omega, t_sun)
    r_ray = 1.0 - t_ray
    finite = big_u != _INF
    if finite and ppq > 0.0:
        cc = ppq * (1.0 + s) ** 2 / (p + k) ** 2
        d = cc + 2.0 * rho * rho * _h(k, big_u)
    else:
        d = _INF
    if not upward:
        # ∫_0^u c e^{-c(u-x)} f(x) dx for the source terms f
        k_beam = c * _e2(c, 1.0, u)
        # f = e^{-kx} - e^{-x} = (1-k) E2(k, 1, x): the divided difference
        k_g1e = c * omk * _e3(c, k, 1.0, u)
        if ppq == 0.0:
            k_a = k_g1e  # A = 1 (see _spp_point)
            k_b = 0.0
        elif finite:
            v = big_u - u
            # f = A - e^{-kx} = -(2ρ²/D) e^{-k(2U-x)} h(k, x)
            k_ag1 = -(2.0 * rho * rho / d) * c * math.exp(-2.0 * k * v - k * u) * _e3(c + k, 2.0 * k, 0.0, u)
            # f = e^{-kx} h(k, U-x)
            k_g2 = c * (_e2(c, k, u) * _h(k, v) + math.exp(-2.0 * k * v) * _e3(k, c, c + 2.0 * k, u))
            k_a = k_g1e + k_ag1
            k_b = 2.0 * rho / d * k_g2
        else:
            k_a = k_g1e
            k_b = rho * c * _e2(c, k, u)
        iso = omega / _TWO_PI * (t_ray * k_a + r_ray * k_b)
    else:
        # ∫_u^U c e^{-c(x-u)} f(x) dx, x = u + y, y in [0, V]
        v = big_u - u if finite else _INF
        k_beam = c * math.exp(-u) * _e2(c + 1.0, 0.0, v)
        k_g1e = c * omk * (_e2(k, 1.0, u) * _e2(c + k, 0.0, v) + math.exp(-u) * _e3(c + k, c + 1.0, 0.0, v))
        gk = math.exp(-_mul(k, u))
        if ppq == 0.0:
            k_a = k_g1e
            k_b = 0.0
        elif finite:
            k_ag1 = -(2.0 * rho * rho / d) * c * math.exp(-k * big_u) * (
                _h(k, u) * _e2(k, c, v) + math.exp(-2.0 * k * u) * _e3(k, c, c + 2.0 * k, v)
            )
            k_a = k_g1e + k_ag1
            k_b = 2.0 * rho / d * c * gk * _e3(c + k, 2.0 * k, 0.0, v)
        else:
            k_a = k_g1e
            k_b = rho * c * gk * _e2(c + k, 0.0, v)
        iso = omega / _TWO_PI * (r_ray * k_a + t_ray * k_b)
    return iso, omega * k_beam


@njit(cache=True)
def _refined_kernel(u, big_u, omega, t_sun, c, upward, t_ray, iso_out, beam_out):
    for i in range(u.shape[0]):
        iso_out[i], beam_out[i] = _refined_point(u[i], big_u[i], omega[i], t_sun[i], c[i], upward[i], t_ray[i])

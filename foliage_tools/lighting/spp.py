"""Simplified plane-parallel (SPP) scattering model of shinya2013 (sec. 3, app. A.1).

The model
---------
A homogeneous slab is lit by a collimated beam whose propagation direction
``s0`` makes the angle θ0 (μ0 = cos θ0) with the inward slab normal. The
radiance is split into the unscattered beam, ``δ(s - s0) exp(-u)``, and a
diffuse part that the SPP model takes uniform on each hemisphere:
``a(u) / 2π`` on Ω+ (directions going deeper into the slab) and ``b(u) / 2π``
on Ω- (going back toward the lit side). ``a`` and ``b`` are the hemispherical
integrals ``∫_{Ω±} I_diffuse dΩ``.

Two simplifications make this closed-form (shinya2013 eqs. (8)-(12)):
the direction cosine of every diffuse ray is replaced by ±μ0 (eq. (8)), and the
phase function by a constant on each hemisphere (eq. (9)) whose weights are

    T = ∫_{Ω+} p(s0 · s') dΩ',   R = 1 - T,

the fractions of the (1/4π-normalised) phase function that the incident
direction scatters into its own (forward) and the opposite (backward)
hemisphere of the slab normal (:func:`forward_fraction`).

Coordinates: everything here uses the *slant* optical depth along the beam,
``u = σt z / μ0`` (z: geometric depth below the lit face), and the slant
optical thickness ``U = σt w / μ0``. These are exactly the depth and thickness
of shinya2013 eq. (29) (n+ and n+ + n- counted along the light direction), so
the SPP field depends on (u, U, ω, T) only; μ0 enters through T(μ0) alone. The
refinement (app. A.1), which follows rays in other directions, needs μ0 too.

Derivation (independent of the paper's printed formulas; see the notes below)
------------------------------------------------------------------------------
With p ≈ T U+ + R U- (U± = 1/2π on Ω±, so that ∫ p dΩ' = T + R = 1), eq. (11)
and (12) integrated over each hemisphere give, for the *total* hemispherical
integrals A = a + exp(-u) (the beam belongs to Ω+) and B = b,

    dA/du = -P A + Q B,     -dB/du = -P B + Q A,              (i)
    P = 1 - ωT,   Q = ωR,

with the boundary conditions of eq. (21): A(0) = 1 (no diffuse light enters
the lit face) and B(U) = 0 (none enters the far face). The unscattered beam
needs no particular solution (this is what eq. (18)-(20) are about): it only
moves weight between a and the beam inside A. Eigen-solutions of (i) are
exp(∓k u) with k = λ μ0 / σt,

    k = sqrt((P - Q)(P + Q)) = sqrt((1 - ω)(1 - ω + 2ωR))      (eq. (17))

and (A, B) ∝ (1, ρ) for exp(-k u), (ρ, 1) for exp(-k (U - u)), where

    ρ = Q / (P + k)   (0 <= ρ <= 1).

Imposing the boundary conditions and keeping only decaying exponentials:

    A(u) = exp(-k u) [C + 2ρ² h(k, U - u)] / D,
    B(u) = exp(-k u) 2ρ h(k, U - u) / D,
    D    = C + 2ρ² h(k, U),
    h(k, L) = (1 - exp(-2kL)) / (2k)   (-> L as k -> 0),
    C    = (P + Q)(1 + s)² / (P + k)²,   s = sqrt((1 - ω)/(P + Q)),

which is the textbook form (1 - ρ² e^{-2kU} etc.) divided by s (P + Q) so
that it stays exact at ω = 1 (k = 0, ρ = 1: A and B become linear in u).
Every term is non-negative, so nothing cancels. The diffuse part of A is
evaluated without the subtraction A - exp(-u):

    a(u) = exp(-k u) (1 - exp(-(1 - k) u)) - exp(-k u) 2ρ² e^{-2k(U-u)} h(k, u) / D,
    1 - k = (ωT(2 - ωT) + ω²R²) / (1 + k),

so a is accurate to rounding relative to itself as ω -> 0, where it tends to
the single-scattering value ωT u e^{-u} (and b to ωR e^{-u}(1 - e^{-2(U-u)})/2).
For U = ∞: A = exp(-k u), B = ρ exp(-k u).

Since k <= 1 always (1 - k² >= 0 above), the diffuse modes never decay faster
than the beam; the two exponents coincide (λ = σt/μ0) only at ω = 0, where ρ = 0
and the formulas above are regular.

Refinement (app. A.1)
---------------------
The SPP field is put back into the exact transfer equation as a source
(eq. (3)/(4)): for a ray of direction cosine μ (to the inward normal) the
refined diffuse radiance is the line integral of ω J e^{-optical path}, with

    J(u, s) = S+(s) a(u) + S-(s) b(u) + p(s · s0)/(4π) e^{-u},
    S±(s)   = ∫ p(s, s') U±(s') dΩ' = (fraction of p(s, ·) in Ω±) / 2π,

using the exact phase function. In slant units the ray kernel is
c e^{-c |u - u'|}, c = μ0/|μ|. Each term is a convolution of decaying
exponentials, evaluated with the overflow- and cancellation-free functions
:func:`_e2` (two exponentials) and :func:`_e3` (three), which are continuous
through every coincidence of rates (c = k, c = 1, c = k ± 2k ...). The result
is ``iso + beam · p(s · s0) / 4π``: ``iso`` depends on μ only, ``beam``
multiplies the phase function at the scattering angle from the sun.

Accuracy: why SPP loses half the scattered light of a high sun (issue #15)
-------------------------------------------------------------------------
This is the model's error, not a coefficient's. Derivation: with every
diffuse ray at cosine ±μ0 (eq. (8)) the hemispherical (horizontal) fluxes of
the SPP field are F↓ = μ0 a, F↑ = μ0 b, and eq. (i) is the exact energy
balance d(F↓ - F↑)/dt = -(1 - ω)(A + B) (t = μ0 u), so SPP gets the *fluxes*
about right (within -5 .. +13 % of the exact F↓ + F↑ for τ = 1.5, r = t = 0.1
to 0.45, elevations 30-85°). But its scalar (actinic) flux, the path length of
light per unit volume, is then A + B - e^{-u} = (F↓ + F↑)/μ0, whereas the
exact diffuse field is nearly isotropic, ∫ I dΩ ≈ 2 (F↓ + F↑) (exactly 2 for
isotropic radiance; 1.9-2.7 measured). Per-leaf E_scattered (both faces,
uniform normals) is half the scalar flux, so

    E_spp / E_exact ≈ (F_spp / F_exact) · 2(F↓ + F↑)/∫I dΩ |_exact · 1/(2μ0),

~0.5 at μ0 = 0.87 and ~0.9-1.1 at μ0 = 1/2. Measured on five depth bins of
τ = 1.5 (r = t = 0.45): elevation 60° -52, -52, -50, -47, -40 %; 85° -57, -59,
-57, -54, -48 %; 30° -18 .. 0 % (r = t = 0.1: -17 .. +9 %). Eq. (10)'s uniform
hemispheres contradict eq. (8) (a uniform radiance a/2π carries flux a/2, not
μ0 a); reading the SPP solution as fluxes instead, E = μ0 (a + b), moves the
error to -17 .. +4 % (60°, r = t = 0.45) but +8 .. +57 % (60°, r = t = 0.1).
No reading of eqs. (8)-(22) gets within ~10 % at every depth, sun and albedo;
the leaf conversion (a + b)/2, T, R (= 1/2 for r = t) and the 1/4π
normalisation are exact (tests). shinya2013 Table 1 still reports 1.3-5.5 %
because it divides an RMS *radiance* difference by the total *power*
(∫ I dΩ including the beam, i.e. 4π times a radiance): the same SPP fields
score 1.8-4.7 % in that metric (benchmarks/bench_spp_tables.py) and 20-48 %
as a relative error of the scalar flux. The per-leaf default of
:func:`~foliage_tools.lighting.gfactor.solve_sppg` is therefore the exact
slab solution (:mod:`~foliage_tools.lighting.slab_table`); this closed form
stays available as ``SPPGParams(model="spp")``.

Differences from the printed paper (each checked by substitution in the tests)
-----------------------------------------------------------------------------
* eq. (9)/(10)/(11): with U± = 1/2π as in eq. (10), T = ∫U+ p dΩ' gives
  T + R = 1/2π, not 1, and eq. (11) lacks the 1/2π of U±. Consistent form:
  T = ∫_{Ω+} p dΩ' (a fraction, T + R = 1) and eq. (11)
  μ0 dI/dz = -σt I + (σs/2π)(T ∫_{Ω+} I dΩ' + R ∫_{Ω-} I dΩ').
* eq. (18): the beam-type (Type II) solution decays as exp(-σt z / cos θ0), not
  exp(-σt z) (z is the normal depth in eq. (11)).
* eq. (19): the growing mode exp(+λz) has the hemisphere weights swapped,
  (β U+ + α U-), not (α U+ + β U-) (substitute -λ in eq. (14)). App. A.1's
  separate α1, β1, α2, β2 agree with this.
* eq. (20): c2 = -∫_{Ω+} i0 dΩ' (= -1 for a unit beam); the division by T is
  wrong (∫F+ = 0 requires ∫ c2 U+ = -∫ i0).
* eq. (22): with the swapped weights, c3 = +β E1 c2 / (α² E3 - β² E1) (the
  printed sign violates I(w, s) = 0 on Ω-), and E3 = exp(λw) overflows: the
  form above (decaying exponentials only) replaces it.
* app. A.1: E(z; λ, σ) = exp((λ-σ)z)/(λ-σ) is only meaningful in differences
  E(z1) - E(z0) (its λ -> σ limit is z only there), and those differences
  cancel catastrophically near coincidence and overflow for (λ - σ) z >> 1;
  γ2 must be σt/cos θ0 (the beam), not σ; the σs factor of eq. (3) is missing in
  eq. (A.2). Replaced by the convolution form above.

Pure numpy + numba; no files, no printing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .phase import HenyeyGreenstein, PhaseFunction

__all__ = [
    "RefinedParts",
    "SPPField",
    "forward_fraction",
    "refined_parts",
    "refined_radiance",
    "spp_field",
    "spp_single_scattering",
]

_INF = math.inf
_TWO_PI = 2.0 * math.pi
#: Gauss-Legendre nodes per piece of the graded mesh in :func:`forward_fraction`
#: (~1e-12 for Henyey-Greenstein up to |g| = 0.95 and μ down to 1e-6, checked
#: against an independent Legendre series in the tests).
FORWARD_FRACTION_NODES = 24
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
    """(P, Q, P+Q, s, k, rho, 1-k) of the module docstring; P+Q = 0 means no coupling."""
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
    """(a, b) at slant depth u of a slab of slant thickness U (module docstring)."""
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
    """(iso, beam): refined diffuse radiance = iso + beam * p(s·s0)/(4π) (module docstring).

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


# --------------------------------------------------------------------------
# forward fraction T(μ) of a phase function
# --------------------------------------------------------------------------


def _hg_forward_cdf(g: float, x: np.ndarray) -> np.ndarray:
    """(1/2)∫_x^1 p_HG(x') dx' in a form without cancellation at g -> 0."""
    q = 1.0 + g * g - 2.0 * g * x
    sq = np.sqrt(q)
    return (1.0 + g) * (1.0 - x) / (sq * (sq + 1.0 - g))


def _graded_breakpoints(a: float, b: float, h0: float) -> np.ndarray:
    """Breakpoints of [a, b] graded geometrically (ratio 4) toward both ends from a first width h0."""
    mid = 0.5 * (a + b)
    offsets = [0.0]
    x = h0
    while x < mid - a:
        offsets.append(x)
        x *= 4.0
    off = np.asarray(offsets)
    return np.unique(np.concatenate([a + off, [mid], b - off]))


def _composite_nodes(breaks: np.ndarray, nodes: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre on each piece after the map t -> (1 - cos πt)/2 (nodes cluster at piece ends).

    The map turns the square-root behaviour of the azimuth fraction at the ends of
    its support into a smooth function, and is harmless elsewhere.
    """
    t = 0.5 * (nodes + 1.0)
    smap = 0.5 * (1.0 - np.cos(math.pi * t))
    dsmap = 0.25 * math.pi * np.sin(math.pi * t) * weights
    lo = breaks[:-1, None]
    width = np.diff(breaks)[:, None]
    return (lo + width * smap).ravel(), (width * dsmap).ravel()


def _azimuth_fraction(theta: np.ndarray, mu: float, sin_t: float) -> np.ndarray:
    """Fraction of the cone of scattering angle Θ about s that lies in s's hemisphere.

    s' · n = cos Θ μ + sin Θ sin θ cos ψ > 0  <=>  cos ψ > -κ, κ = cot Θ μ / sin θ;
    the fraction of ψ is arccos(-κ)/π (clipped to [0, 1]).
    """
    kappa = np.cos(theta) * mu / (np.sin(theta) * sin_t)
    return np.arccos(np.clip(-kappa, -1.0, 1.0)) / math.pi


def _forward_fraction_scalar(phase: PhaseFunction, mu: float, nodes: np.ndarray, weights: np.ndarray) -> float:
    """T(μ) = (1/2)∫ p(cos Θ) f(Θ) sin Θ dΘ, f the azimuth fraction (1 for Θ < π/2 - θ, 0 beyond π/2 + θ).

    The scales of the integrand are the distance ε = π/2 - θ = arcsin μ of the
    kinks from the ends of [0, π] (f varies on the scale ε there) and the width
    of the phase function's peaks (at Θ = 0 or π): meshes graded geometrically
    toward the kinks resolve both.
    """
    sin_t = math.sqrt(max(0.0, 1.0 - mu * mu))
    eps = math.asin(min(1.0, max(0.0, mu)))  # π/2 - θ
    if isinstance(phase, HenyeyGreenstein):
        # region Θ < ε (cone entirely in the forward hemisphere): closed-form CDF
        part1 = float(_hg_forward_cdf(phase.g, np.array(sin_t)))
    else:
        th, wt = _composite_nodes(_graded_breakpoints(0.0, eps, min(1e-3, 0.25 * eps)), nodes, weights) if eps > 0 else (np.zeros(0), np.zeros(0))
        part1 = 0.5 * float(np.sum(np.asarray(phase(np.cos(th)), dtype=float) * np.sin(th) * wt))
    if sin_t == 0.0:
        return part1
    lo, hi = eps, math.pi - eps
    h0 = max(eps, 1e-12) if eps > 0.0 else 1e-12
    th, wt = _composite_nodes(_graded_breakpoints(lo, hi, min(h0, 0.25 * (hi - lo))), nodes, weights)
    f = _azimuth_fraction(th, mu, sin_t)
    part2 = 0.5 * float(np.sum(np.asarray(phase(np.cos(th)), dtype=float) * f * np.sin(th) * wt))
    return part1 + part2


def forward_fraction(phase: PhaseFunction, mu) -> np.ndarray:
    """Fraction T of the phase function scattered into the incident direction's hemisphere.

    T(μ) = ∫_{Ω+} p(s · s') dΩ' / 4π for a direction s at cosine μ to the slab
    normal, Ω+ the hemisphere that contains s (shinya2013 eq. (9)-(10), in the
    normalisation T + R = 1 of the module docstring). T(1) is the forward
    hemisphere fraction of the phase function; T(0) = 1/2 for every phase
    function (the slab plane then splits the scattering cone symmetrically).

    Parameters
    ----------
    phase : PhaseFunction
        Rotationally symmetric phase function (1/4π normalisation), integrated
        in the scattering angle on a graded mesh (Henyey-Greenstein: the part
        entirely inside the forward hemisphere in closed form).
    mu : array_like
        |cos| of the direction to the slab normal, 0 <= μ <= 1.

    Returns
    -------
    numpy.ndarray
        T, same shape as ``mu``, in [0, 1].
    """
    if not isinstance(phase, PhaseFunction):
        # ValueError, not TypeError: the project reports all bad inputs as ValueError
        raise ValueError(f"phase must be a PhaseFunction, got {type(phase).__name__}")  # noqa: TRY004
    mu = np.asarray(mu, dtype=float)
    if not np.all(np.isfinite(mu)) or np.any(mu < 0.0) or np.any(mu > 1.0):
        raise ValueError("mu (cosine to the slab normal) must be in [0, 1]")
    nodes, weights = np.polynomial.legendre.leggauss(FORWARD_FRACTION_NODES)
    uniq, inverse = np.unique(mu.ravel(), return_inverse=True)
    vals = np.array([_forward_fraction_scalar(phase, float(m), nodes, weights) for m in uniq])
    return np.clip(vals[inverse].reshape(mu.shape), 0.0, 1.0)


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
    """SPP solution (shinya2013 eqs. (17)-(22), re-derived: see the module docstring).

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
    (solutions of eq. (i) of the module docstring to first order in ω).
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

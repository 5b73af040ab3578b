"""Forward fraction T(μ) of a phase function (:mod:`foliage_tools.lighting.spp`, shinya2013 eq. (9)-(10)).

:func:`forward_fraction` and its quadrature: Gauss-Legendre on meshes graded
toward the kinks of the azimuth fraction, Henyey-Greenstein's fully forward
part in closed form.
"""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.lighting.phase import HenyeyGreenstein, PhaseFunction

#: Gauss-Legendre nodes per piece of the graded mesh in :func:`forward_fraction`
#: (~1e-12 for Henyey-Greenstein up to |g| = 0.95 and μ down to 1e-6, checked
#: against an independent Legendre series in the tests).
FORWARD_FRACTION_NODES = 24


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
    normalisation T + R = 1 of the package docstring). T(1) is the forward
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

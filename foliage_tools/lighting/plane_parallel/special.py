"""Small, overflow-free scalar helpers and the normalised associated Legendre functions.

exp(-k t) with 0 * inf = 0, (1 - e^{-x})/x, sinh(x)/x and the convolution of two
decaying exponentials, all safe for tau = inf; and Λ_l^m(x) by the stable
recurrence. Used by the eigen-decomposition (:mod:`foliage_tools.lighting.plane_parallel.eigen`)
and the mode solutions (:mod:`foliage_tools.lighting.plane_parallel.modes`).
"""

from __future__ import annotations

import math

import numpy as np


# --------------------------------------------------------------------------
# small, overflow-free scalar helpers
# --------------------------------------------------------------------------


def _phi1(x: np.ndarray) -> np.ndarray:
    """(1 - exp(-x)) / x for x >= 0, = 1 at x = 0 (via expm1, no cancellation)."""
    x = np.asarray(x, dtype=float)
    small = x == 0.0
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0, -np.expm1(-xs) / xs)


def _shc(x: np.ndarray) -> np.ndarray:
    """sinh(x) / x, = 1 at x = 0."""
    x = np.asarray(x, dtype=float)
    small = x == 0.0
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0, np.sinh(xs) / xs)


def _decay(k, t) -> np.ndarray:
    """exp(-k t) for k >= 0, t >= 0 (t may be inf), with 0 * inf taken as 0."""
    k, t = np.broadcast_arrays(np.asarray(k, dtype=float), np.asarray(t, dtype=float))
    x = np.zeros(k.shape)
    np.multiply(k, t, out=x, where=k != 0.0)
    return np.exp(-x)


def _conv2(a, b, length) -> np.ndarray:
    """E2(a, b, L) = ∫_0^L exp(-a (L - s)) exp(-b s) ds for a, b >= 0, L in [0, inf].

    Convolution of two decaying exponentials, = (e^{-bL} - e^{-aL})/(a - b), with
    the limit L e^{-aL} at a = b; evaluated as e^{-lo L} L φ1((hi - lo) L) so it
    neither overflows nor cancels.
    """
    a, b, length = np.broadcast_arrays(
        np.asarray(a, dtype=float),
        np.asarray(b, dtype=float),
        np.asarray(length, dtype=float),
    )
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    finite = np.isfinite(length)
    lf = np.where(finite, length, 0.0)
    out_finite = np.exp(-lo * lf) * lf * _phi1((hi - lo) * lf)
    hi_safe = np.where(hi > 0.0, hi, 1.0)
    out_inf = np.where(lo == 0.0, 1.0 / hi_safe, 0.0)
    return np.where(finite, out_finite, out_inf)


def _norm_assoc_legendre(m: int, lmax: int, x) -> np.ndarray:
    """Normalised associated Legendre functions Λ_l^m(x), l = 0..lmax.

    Λ_l^m = sqrt((l-m)!/(l+m)!) P_l^m (without the Condon-Shortley phase, which
    cancels in the products used here), via the stable upward recurrence
    sqrt((l+1)² - m²) Λ_{l+1} = (2l+1) x Λ_l - sqrt(l² - m²) Λ_{l-1}
    (as in DISORT's routine LEPOLY; T&S ch. 6). Rows l < m are zero.
    Returns shape (lmax + 1,) + x.shape.
    """
    x = np.asarray(x, dtype=float)
    out = np.zeros((lmax + 1,) + x.shape)
    if m > lmax:
        return out
    s = np.sqrt(np.maximum(0.0, 1.0 - x * x))
    pmm = np.ones(x.shape)
    for i in range(1, m + 1):
        pmm = pmm * (math.sqrt((2 * i - 1) / (2 * i)) * s)
    out[m] = pmm
    if m + 1 <= lmax:
        out[m + 1] = math.sqrt(2 * m + 1) * x * pmm
    for l in range(m + 1, lmax):
        out[l + 1] = (
            (2 * l + 1) * x * out[l] - math.sqrt(l * l - m * m) * out[l - 1]
        ) / math.sqrt((l + 1) ** 2 - m * m)
    return out

"""Rotationally symmetric phase functions for the plane-parallel solver.

Convention (used everywhere in :mod:`foliage_tools.lighting`): a phase function
``p(cos Θ)`` of the scattering angle Θ (angle between the propagation
directions before and after scattering, Θ = 0 is forward) is normalised so that

    (1/4π) ∫_{4π} p dΩ = 1,   i.e.   (1/2) ∫_{-1}^{1} p(x) dx = 1,

and it is expanded in Legendre polynomials as

    p(x) = Σ_l (2l + 1) χ_l P_l(x),   χ_l = (1/2) ∫_{-1}^{1} p(x) P_l(x) dx,

so χ_0 = 1 and χ_1 = g is the asymmetry parameter (Chandrasekhar 1960,
*Radiative Transfer*, §2 and §17; Thomas & Stamnes 1999, *Radiative Transfer in
the Atmosphere and Ocean*, §6.1).

Provided:

* :func:`hg_phase` -- Henyey & Greenstein (1941), shinya2013 eq. (2); χ_l = g**l.
* :func:`canopy_bilambertian_phase` -- the area scattering phase function of a
  canopy of two-sided Lambertian leaves with a spherical (uniform) leaf-normal
  distribution (Ross 1981, *The Radiation Regime and Architecture of Plant
  Stands*, ch. 5; Shultis & Myneni 1988, JQSRT 39, 115).
* :func:`rayleigh_phase` -- p = (3/4)(1 + x²) (Chandrasekhar 1960, §17).
* :func:`tabulated_phase` -- any p(x) given at sample points, interpolated
  linearly in x.

Pure numpy; no files, no printing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "BiLambertianCanopyPhase",
    "HenyeyGreenstein",
    "PhaseFunction",
    "RayleighPhase",
    "TabulatedPhase",
    "canopy_bilambertian_phase",
    "hg_phase",
    "legendre_table",
    "rayleigh_phase",
    "tabulated_phase",
]

#: Leaf-projection ("G") function of a spherical leaf-angle distribution: the
#: mean projected leaf area per unit one-sided leaf area, the same in every
#: direction (Ross 1981, ch. 2). The optical depth of a canopy layer of leaf
#: area index LAI is therefore tau = 0.5 * LAI.
SPHERICAL_G_FUNCTION = 0.5


def legendre_table(x: np.ndarray, n: int) -> np.ndarray:
    """Legendre polynomials P_0 .. P_{n-1} at ``x``.

    Bonnet's recurrence (l + 1) P_{l+1} = (2l + 1) x P_l - l P_{l-1}
    (Abramowitz & Stegun 1964, eq. 8.5.3 with m = 0).

    Returns an array of shape ``(n,) + x.shape``.
    """
    x = np.asarray(x, dtype=float)
    out = np.empty((n,) + x.shape)
    if n > 0:
        out[0] = 1.0
    if n > 1:
        out[1] = x
    for l in range(1, n - 1):
        out[l + 1] = ((2 * l + 1) * x * out[l] - l * out[l - 1]) / (l + 1)
    return out


def _check_n_moments(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(
            f"the number of Legendre moments must be an integer >= 1, got {n!r}"
        )
    return int(n)


@dataclass(frozen=True)
class PhaseFunction:
    """A rotationally symmetric phase function ``p(cos Θ)``, (1/4π)∫p dΩ = 1.

    Subclasses implement :meth:`__call__`; :meth:`legendre_moments` defaults to
    Gauss-Legendre quadrature in the scattering angle Θ (not in cos Θ: the
    integrand p(cos Θ) P_l(cos Θ) sin Θ is smooth in Θ for the phase functions
    here, so the quadrature converges spectrally), which subclasses override
    when a closed form exists.
    """

    def __call__(self, cos_theta) -> np.ndarray:  # pragma: no cover - abstract
        """Phase function value (dimensionless, 1/4π normalisation) at cos Θ."""
        raise NotImplementedError

    def legendre_moments(self, n: int) -> np.ndarray:
        """Legendre coefficients χ_0 .. χ_{n-1} with p = Σ (2l+1) χ_l P_l(cos Θ).

        Parameters
        ----------
        n : int
            Number of moments (>= 1).

        Returns
        -------
        numpy.ndarray, shape (n,)
            χ_l = (1/2) ∫ p(x) P_l(x) dx; χ_0 = 1 for a normalised function.
        """
        n = _check_n_moments(n)
        n_quad = 2 * n + 96
        nodes, weights = np.polynomial.legendre.leggauss(n_quad)
        theta = 0.5 * math.pi * (nodes + 1.0)  # map [-1, 1] -> [0, π]
        w = 0.5 * math.pi * weights * np.sin(theta)  # dx = sin Θ dΘ
        x = np.cos(theta)
        values = np.asarray(self(x), dtype=float)
        return 0.5 * legendre_table(x, n) @ (w * values)

    @property
    def asymmetry(self) -> float:
        """Asymmetry parameter g = <cos Θ> = χ_1."""
        return float(self.legendre_moments(2)[1])


@dataclass(frozen=True)
class HenyeyGreenstein(PhaseFunction):
    """Henyey-Greenstein phase function with asymmetry ``g`` in (-1, 1).

    p(x) = (1 - g²) / (1 + g² - 2 g x)^{3/2}  (Henyey & Greenstein 1941;
    shinya2013 eq. (2) times 4π for the 1/4π normalisation used here).
    """

    g: float

    def __call__(self, cos_theta) -> np.ndarray:
        x = np.asarray(cos_theta, dtype=float)
        g = self.g
        return (1.0 - g * g) / (1.0 + g * g - 2.0 * g * x) ** 1.5

    def legendre_moments(self, n: int) -> np.ndarray:
        """χ_l = g**l exactly (Henyey & Greenstein 1941)."""
        n = _check_n_moments(n)
        return self.g ** np.arange(n, dtype=float)

    @property
    def asymmetry(self) -> float:
        return float(self.g)


@dataclass(frozen=True)
class RayleighPhase(PhaseFunction):
    """Rayleigh phase function p(x) = (3/4)(1 + x²); χ = (1, 0, 1/10, 0, ...)."""

    def __call__(self, cos_theta) -> np.ndarray:
        x = np.asarray(cos_theta, dtype=float)
        return 0.75 * (1.0 + x * x)

    def legendre_moments(self, n: int) -> np.ndarray:
        n = _check_n_moments(n)
        chi = np.zeros(n)
        chi[0] = 1.0
        if n > 2:
            chi[2] = 0.1  # (3/4)(1 + x²) = P_0 + P_2 / 2 = Σ (2l+1) χ_l P_l
        return chi


@dataclass(frozen=True)
class BiLambertianCanopyPhase(PhaseFunction):
    """Area scattering phase function of a canopy of bi-Lambertian leaves.

    Leaves are flat, two-sided Lambertian scatterers with hemispherical
    reflectance ``reflectance`` (r) and transmittance ``transmittance`` (t),
    with normals distributed uniformly over the sphere ("spherical" leaf-angle
    distribution). With β the scattering angle (cos β = Ω'·Ω) the area
    scattering phase function is (Ross 1981, ch. 5; Shultis & Myneni 1988)

        Γ(β) = r/(3π) (sin β - β cos β) + t/(3π) (sin β + (π - β) cos β)

    in Ross' normalisation (1/π)∫Γ dΩ = ω G with ω = r + t and G = 1/2. In the
    1/4π normalisation used here, p = 4Γ/(ωG):

        p(β) = 8/(3π) [ r̂ (sin β - β cos β) + t̂ (sin β + (π - β) cos β) ],

    with r̂ = r/(r+t), t̂ = t/(r+t). Derivation: a photon travelling along Ω'
    meets leaves of normal n at a rate ∝ |Ω'·n| and leaves in direction Ω with
    probability density (r or t)|Ω·n|/π, r if Ω and Ω' are on opposite sides
    of the leaf (reflection), t otherwise; averaging over n uniform on the
    sphere gives Γ (checked by quadrature over n in the tests). The
    reflection term alone is the Lambertian-sphere phase function of van de
    Hulst (1980), asymmetry -4/9; in general g = χ_1 = 4 (t - r) / (9 (r + t)).

    Note: with r = t the phase function is symmetric (g = 0) but *not*
    isotropic: p(0) = p(π) = 4/3, p(π/2) = 8/(3π).

    Attributes
    ----------
    reflectance, transmittance : float
        Leaf hemispherical reflectance r and transmittance t, r, t >= 0,
        r + t <= 1.

    Use with :func:`~foliage_tools.lighting.plane_parallel.solve_slab` as
    ``omega=phase.omega`` and ``tau = 0.5 * LAI`` (:data:`SPHERICAL_G_FUNCTION`).
    """

    reflectance: float
    transmittance: float

    @property
    def omega(self) -> float:
        """Single-scattering albedo of the canopy, ω = r + t."""
        return float(self.reflectance + self.transmittance)

    @property
    def g_function(self) -> float:
        """Ross' G-function of the spherical leaf distribution (0.5, all directions)."""
        return SPHERICAL_G_FUNCTION

    def _weights(self) -> tuple[float, float]:
        total = self.reflectance + self.transmittance
        if total <= 0.0:
            # Black leaves: ω = 0, so the shape is irrelevant; use r̂ = t̂ so the
            # object stays a valid, normalised phase function.
            return 0.5, 0.5
        return self.reflectance / total, self.transmittance / total

    def __call__(self, cos_theta) -> np.ndarray:
        x = np.clip(np.asarray(cos_theta, dtype=float), -1.0, 1.0)
        beta = np.arccos(x)
        sin_b = np.sqrt(np.maximum(0.0, 1.0 - x * x))
        r_hat, t_hat = self._weights()
        # Ross (1981) / Shultis & Myneni (1988) closed form, 1/4π normalised.
        return (8.0 / (3.0 * math.pi)) * (
            r_hat * (sin_b - beta * x) + t_hat * (sin_b + (math.pi - beta) * x)
        )


@dataclass(frozen=True)
class TabulatedPhase(PhaseFunction):
    """Phase function given at samples of cos Θ, linear in cos Θ between them.

    Build with :func:`tabulated_phase`. Moments are integrated exactly for the
    piecewise-linear function (Gauss-Legendre on each interval with enough
    points for the polynomial degree).
    """

    cos_theta: tuple[float, ...]
    values: tuple[float, ...]

    def __call__(self, cos_theta) -> np.ndarray:
        x = np.asarray(cos_theta, dtype=float)
        return np.interp(x, np.asarray(self.cos_theta), np.asarray(self.values))

    def legendre_moments(self, n: int) -> np.ndarray:
        n = _check_n_moments(n)
        grid = np.asarray(self.cos_theta)
        vals = np.asarray(self.values)
        # linear × P_l has degree <= n: q Gauss points are exact to degree 2q-1.
        q = n // 2 + 2
        nodes, weights = np.polynomial.legendre.leggauss(q)
        a, b = grid[:-1, None], grid[1:, None]
        half = 0.5 * (b - a)
        x = (a + b) * 0.5 + half * nodes[None, :]
        frac = (x - a) / (b - a)
        px = vals[:-1, None] + frac * (vals[1:, None] - vals[:-1, None])
        w = half * weights[None, :]
        return 0.5 * legendre_table(x.ravel(), n) @ (w * px).ravel()


def hg_phase(g: float) -> HenyeyGreenstein:
    """Henyey-Greenstein phase function.

    Parameters
    ----------
    g : float
        Asymmetry parameter <cos Θ>, -1 < g < 1 (0: isotropic, > 0: forward).

    Returns
    -------
    HenyeyGreenstein
        ``p(x) = (1 - g²)/(1 + g² - 2gx)^{3/2}``, Legendre moments ``g**l``.
    """
    g = _as_real("g", g)
    if not -1.0 < g < 1.0:
        raise ValueError(f"Henyey-Greenstein asymmetry g must be in (-1, 1), got {g}")
    return HenyeyGreenstein(g=g)


def canopy_bilambertian_phase(
    *, reflectance: float, transmittance: float
) -> BiLambertianCanopyPhase:
    """Phase function of a spherical-leaf canopy of bi-Lambertian leaves.

    Parameters
    ----------
    reflectance, transmittance : float
        Leaf hemispherical reflectance r and transmittance t (dimensionless,
        r >= 0, t >= 0, r + t <= 1).

    Returns
    -------
    BiLambertianCanopyPhase
        The phase function (1/4π normalisation); its ``omega`` attribute is the
        canopy single-scattering albedo r + t and ``g_function`` = 0.5, so a
        layer of leaf area index LAI has optical depth ``0.5 * LAI``.
    """
    r = _as_real("reflectance", reflectance)
    t = _as_real("transmittance", transmittance)
    if r < 0.0 or t < 0.0:
        raise ValueError(
            f"leaf reflectance and transmittance must be >= 0, got r={r}, t={t}"
        )
    if r + t > 1.0 + 1e-12:
        raise ValueError(
            f"leaf reflectance + transmittance must be <= 1 (energy), got r + t = {r + t}"
        )
    return BiLambertianCanopyPhase(reflectance=r, transmittance=t)


def rayleigh_phase() -> RayleighPhase:
    """Rayleigh phase function p(x) = (3/4)(1 + x²)."""
    return RayleighPhase()


def tabulated_phase(cos_theta, values, *, normalize: bool = True) -> TabulatedPhase:
    """Phase function from samples, linear in cos Θ between samples.

    Parameters
    ----------
    cos_theta : array_like, shape (K,)
        Strictly increasing samples of cos Θ from -1 to 1 inclusive (K >= 2).
    values : array_like, shape (K,)
        p at the samples, >= 0.
    normalize : bool
        Rescale so that (1/2)∫p dx = 1 (default). If False the samples must
        already be normalised to 1e-3.

    Returns
    -------
    TabulatedPhase
    """
    x = np.asarray(cos_theta, dtype=float)
    v = np.asarray(values, dtype=float)
    if x.ndim != 1 or v.shape != x.shape or x.size < 2:
        raise ValueError(
            "cos_theta and values must be 1-D arrays of the same length >= 2"
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
        raise ValueError("cos_theta and values must be finite")
    if np.any(np.diff(x) <= 0.0) or x[0] != -1.0 or x[-1] != 1.0:
        raise ValueError("cos_theta must increase strictly from -1 to 1 inclusive")
    if np.any(v < 0.0):
        raise ValueError("phase function values must be >= 0")
    norm = 0.5 * float(
        np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(x))
    )  # exact for linear pieces
    if norm <= 0.0:
        raise ValueError("phase function values integrate to zero")
    if normalize:
        v = v / norm
    elif abs(norm - 1.0) > 1e-3:
        raise ValueError(
            f"phase function is not normalised: (1/2)∫p d(cosΘ) = {norm:.6g}, expected 1"
        )
    return TabulatedPhase(
        cos_theta=tuple(float(a) for a in x), values=tuple(float(a) for a in v)
    )


def _as_real(name: str, value) -> float:
    if isinstance(value, bool):
        # ValueError, not TypeError: the project reports all bad inputs as ValueError
        raise ValueError(f"{name} must be a real number, got {value!r}")  # noqa: TRY004
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if math.isnan(out):
        raise ValueError(f"{name} must not be NaN")
    return out

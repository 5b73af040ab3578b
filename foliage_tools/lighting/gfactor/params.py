"""Options and results of the SPP/SPPG bake: the plane-parallel models, G's weightings, the exact tables' streams and
the default number of sample directions; :class:`SPPGParams`, and :class:`LeafIrradiance` and :class:`SPPGResult`
(what :func:`~foliage_tools.lighting.gfactor.solve_sppg` returns). What the options mean is in the package docstring
(:mod:`foliage_tools.lighting.gfactor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: Plane-parallel models of ``SPPGParams.model`` (package docstring).
MODELS = ("exact", "spp")
#: How G combines the sample directions (``SPPGParams.g_weights``, package docstring): shinya2013 eq. (27)'s
#: equal-weight mean, or weighted by each direction's plane-parallel single-scattering radiance.
G_WEIGHTS = ("paper", "radiance")
#: Streams per hemisphere of the exact plane-parallel tables (``model="exact"``): against 32 streams the
#: leaf irradiance differs by <= 1.3e-3 for tilted leaves and <= 4e-5 for the mean over orientations
#: (measured, τ = 3, albedo 0.2-1, μ0 0.3-1), below the tables' 3e-3 interpolation error, at half the cost of 16.
EXACT_STREAMS = 8
#: Default number of sample directions (shinya2013 sec. 5.1: "typically 16").
DEFAULT_DIRECTIONS = 16


@dataclass(frozen=True)
class SPPGParams:
    """Options of the SPP/SPPG bake (``foliage spp``)."""

    refine: bool = False
    """Integrate the refined radiance of shinya2013 app. A.1 over each leaf's
    two faces for the sun's scattered light (``--refine``); the sky always uses
    the plain SPP field. Applies to ``model="spp"`` only (and selects it when
    ``model`` is None)."""
    model: str | None = None
    """Plane-parallel part of the scattered light: ``"exact"`` (the exact slab
    solution looked up per leaf, :mod:`~foliage_tools.lighting.spp.slab_table`) or
    ``"spp"`` (shinya2013's closed form, eqs. (17)-(22)). None: ``"spp"`` if
    ``refine`` else ``"exact"``."""
    sky: bool = True
    """Compute the uniform-sky terms (shinya2013 sec. 5.4 step 4)."""
    refine_polar_nodes: int = 8
    """Gauss-Legendre nodes in the cosine, per hemisphere, of the refined leaf integral."""
    refine_azimuth_nodes: int = 16
    """Equally spaced azimuths of the refined leaf integral."""
    g_weights: str = "paper"
    """How G combines its sample directions (:data:`G_WEIGHTS`, package docstring): ``"paper"``, shinya2013
    eq. (27)'s equal-weight mean of the present fractions; ``"radiance"``, each weighted by the plane-parallel
    single-scattering radiance from that direction (then G is per channel: the phase differs with r and t)."""

    g_orders: bool = False
    """Apply G per order of scattering (package docstring, "Orders of scattering"): with s the exact slab's
    once-scattered share of E_scattered and ρ the real medium's recollision probability over the slab's, the
    scattered light is scaled by G s / (1 - (1 - s) ρ) instead of G (shinya2013 eq. (28) applies G once). False:
    the paper's."""

    def __post_init__(self) -> None:
        if self.g_weights not in G_WEIGHTS:
            raise ValueError(f"SPPGParams.g_weights must be one of {', '.join(G_WEIGHTS)}, got {self.g_weights!r}")
        if self.model is not None and self.model not in MODELS:
            raise ValueError(f"SPPGParams.model must be one of {', '.join(MODELS)} or None, got {self.model!r}")
        if self.model == "exact" and self.refine:
            raise ValueError("SPPGParams.refine (shinya2013 app. A.1) refines the SPP closed form: use model='spp'")
        for name in ("refine_polar_nodes", "refine_azimuth_nodes"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 256:
                raise ValueError(f"SPPGParams.{name} must be an integer in [1, 256], got {v!r}")

    @property
    def resolved_model(self) -> str:
        """The model used: ``model``, or ``"spp"`` with ``refine`` and ``"exact"`` without."""
        if self.model is not None:
            return self.model
        return "spp" if self.refine else "exact"


@dataclass(frozen=True)
class LeafIrradiance:
    """Per-leaf irradiance of one method, both leaf faces summed, per RGB channel (L, 3)."""

    direct: np.ndarray
    """Unscattered sun (sun irradiance 1 perpendicular to its direction)."""
    scattered: np.ndarray
    """Sun light scattered at least once."""
    sky_direct: np.ndarray
    """Unscattered skylight (uniform sky, horizontal irradiance 1); zero if the sky was not computed."""
    sky_scattered: np.ndarray
    """Skylight scattered at least once; zero if the sky was not computed."""


@dataclass(frozen=True)
class SPPGResult:
    """Result of :func:`solve_sppg`."""

    sppg: LeafIrradiance
    """The plane-parallel model with the G-factor (the paper's method with ``model="spp"``)."""
    spp: LeafIrradiance
    """The plane-parallel model alone (G = 1): exact slab or SPP closed form (``model``)."""
    ss: LeafIrradiance
    """The paper's single-scattering baseline (scattered = 0)."""
    gfactor: np.ndarray
    """(L,) G toward the sun (with ``g_weights="radiance"`` or ``g_orders`` the mean over the channels' G; with
    ``g_orders`` the factor applied, G s / (1 - (1 - s) ρ))."""
    directions: np.ndarray
    """(N, 3) the sample directions used."""
    mu0: float
    """Cosine of the sun to the up axis."""
    refined: bool
    """Whether the sun's scattered light used the refinement."""
    seconds: float
    """Wall time of the call."""
    model: str = "exact"
    """The plane-parallel model of ``spp`` and ``sppg`` (``SPPGParams.resolved_model``)."""
    orders: np.ndarray | None = None
    """(L, C) with ``g_orders``: the sun's E_scattered over its first order in the real medium,
    1 / (1 - (1 - s) ρ) (what ``lighting.first_order``'s once-scattered light is multiplied by); None without."""

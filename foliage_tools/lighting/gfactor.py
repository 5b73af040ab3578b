"""G-factor, SPPG and single-scattering (SS) irradiance per leaf (shinya2013 sec. 4, 5.2-5.4, app. A.2).

Inputs are optical depths (:class:`~foliage_tools.lighting.depth.DepthSamples`)
from the density grid (:mod:`~foliage_tools.lighting.depth`) or from leaf
intersection counts, optionally plus contributions of neighbouring instances
(shinya2013 eq. (31)); outputs are the per-leaf quantities of DESIGN.md sec. 3.

Geometry and normalisation
--------------------------
The local plane-parallel slab has its lit face normal to the stage's ``up``
axis (canopies are layered horizontally, and this is the geometry in which a
horizontally infinite uniform canopy is exactly plane-parallel, G = 1). A light
from direction ``l`` (unit, toward the light, l · up = μ0 > 0) has slant depth
``u`` = optical depth toward ``l`` and slant thickness ``U`` = optical chord
through the point along ``l`` (:mod:`~foliage_tools.lighting.spp`).

* Sun: irradiance 1 on a plane perpendicular to it (DESIGN.md sec. 3).
* Sky: uniform radiance 1/π over the upper hemisphere (horizontal irradiance 1,
  as :func:`~foliage_tools.lighting.plane_parallel.solve_slab_diffuse`),
  represented by the upper sample directions as distant lights of weights
  ``W_j`` (:func:`sky_weights`) with Σ W_j μ_j = 1 (shinya2013 sec. 5.4 step 4).

Per leaf of unit normal n, both faces summed:

* ``direct``  = |n · l_sun| exp(-u_sun) (unscattered sun). Evaluated at the leaf
  centre: the area average of DESIGN.md is approximated by the centre value.
* ``scattered``, plane-parallel part (``SPPGParams.model``):

  - ``"exact"`` (the default, issue #15): the exact plane-parallel solution of
    the same slab (:mod:`~foliage_tools.lighting.slab_table`: the project's
    discrete-ordinate solver, tabulated once per optics and light cosine over
    a ladder of thicknesses), looked up per leaf at the vertical optical
    depth t = μ0 u and thickness τ = μ0 U, and integrated against the leaf's
    |n · s| (azimuthal mean; both faces). In a horizontally infinite uniform
    canopy this *is* the answer (to ~0.3 % interpolation).
  - ``"spp"``: the paper's closed form, (a + b)/2 of the SPP field, which is
    independent of the leaf orientation
    (:attr:`~foliage_tools.lighting.spp.SPPField.leaf_irradiance`); with
    ``refine`` the refined radiance (app. A.1) is integrated against |n · s|
    over the sphere instead. Its eq. (8) (every diffuse ray at cosine ±μ0)
    makes it lose ~half of the scattered light of a high sun even where the
    slab is exactly plane-parallel: τ = 1.5, r = t = 0.45, elevation 60°,
    five depth bins: -52, -52, -50, -47, -40 % against the exact solution;
    85°: -57 .. -48 %; 30° (2μ0 = 1): -18 .. 0 %
    (:mod:`~foliage_tools.lighting.slab_table` explains why).
* SPPG: ``scattered`` × G (shinya2013 eq. (28) with I0 = the attenuated direct
  light, which contains no scattered light: I_G = G I_pp + (1 - G) I0 leaves the
  direct part unchanged and scales the scattered part by G), for either model
  ("exact PP + G" with the default).
* SS: the paper's single-scattering baseline (sec. 4.2: "reflection/transmission
  of the direct light, I0, was simply calculated"): a leaf receives only the
  attenuated direct light, so its ``scattered`` is zero (the light it sends to
  the eye is then scattered once).

The G-factor (re-derived from shinya2013 eqs. (23)-(27))
--------------------------------------------------------
For a point P at slant depth d0 toward the light (vertical optical depth
t0 = μ0 d0) in a slab of slant thickness w0, consider a sample direction v
with v_n = v · up. Along the ray P + l v (l: optical path length) the direct
light in the plane-parallel slab is exp(-(d0 - l v_n / μ0)), so the light
scattered once toward P from that ray is proportional to

    ∫_0^{L} exp(-l) exp(-(d0 - l v_n/μ0)) dl ∝ ∫_0^{L} exp(-c l) dl,   c = 1 - v_n / μ0,

where L is the optical distance to the slab face the ray meets
(L = t0 / v_n for v_n > 0, (τ - t0)/|v_n| = μ0 (w0 - d0)/|v_n| for v_n < 0,
inf for v_n = 0). The real medium ends at optical distance h = the depth of P
toward v (the boundary B1 of Fig. 4(a)); the part of the plane-parallel single
scattering actually present is

    F_v = ∫_0^{min(h, L)} e^{-c l} dl / ∫_0^{L} e^{-c l} dl
        = (1 - e^{-c h}) / (1 - e^{-c L})                         (c > 0)
        = h / L                                                   (c = 0)
        = e^{-|c|(L - h)} (1 - e^{-|c| h}) / (1 - e^{-|c| L})     (c < 0)

(only decaying exponentials; continuous through c = 0, i.e. v_n = μ0, the
coincidence λ = σ of app. A.2), F_v = 1 when h >= L or L = 0, and

    G = 1 - (1/N) Σ_v G_v = (1/N) Σ_v F_v                          (eq. (27))

with G_v = 1 - F_v = δI(P, B1)/δI(P, P) (eq. (26)). The phase function and the
factor e^{-d0} cancel in the ratio. This differs from the printed app. A.2:
(A.3) writes G_si as a *product* (1 - E(h; ...))(1 - E(z0; ...)) of terms that
have units of length when the rates coincide, while eq. (26) defines a ratio of
two integrals; and the prefactor of δI(P, B1) is the direct light at P,
exp(-σt z0 / cos θ0), not exp(-σt z0 / cos θ).

Weighting the directions (``SPPGParams.g_weights``)
---------------------------------------------------
What SPPG scales (eq. (28)) is an *irradiance*: a leaf of normal n receives
E = ∫ I(P, s) |n · s| dΩ, with I(P, s) the radiance of eq. (23). Over the
canopy's spherical leaf distribution |n · s| averages to 1/2, so the mean leaf
receives (1/2) ∫ I(P, s) dΩ, and with the sample directions as an equal-area
quadrature (Δω = 4π/N each) the share of its plane-parallel single scattering
that the real medium holds is a ratio of sums of the eq. (24) integrals:

    G_rad = 1 - Σ_i δI(P, B1; s_i) / Σ_i δI(P, P; s_i) = Σ_i w_i F_i / Σ_i w_i,
    w_i = δI(P, P; s_i) ∝ p(l · s_i) e^{-d0} ∫_0^{L_i} e^{-c_i l} dl

(c ≥ 0; for c < 0, e^{-L} ∫_0^L e^{-|c| l} dl, the same integral written with
decaying exponentials: |c| L = d0 - L). Here p is the canopy phase function
(1/4π normalisation, :func:`~foliage_tools.lighting.phase.canopy_bilambertian_phase`)
at the scattering angle between the beam and the ray toward P, cos Θ = l · s_i;
the factor ω σ/(4π) is common to all directions and cancels. This is where we
depart from eq. (27): the paper averages the ratios, G = 1 - (1/N) Σ_i G_si,
which equals the ratio of the sums only when every direction carries the same
plane-parallel light. ``g_weights="paper"`` keeps eq. (27); ``"radiance"`` is
G_rad, evaluated per channel (p depends on r and t; for r = t it is the same
shape in every channel). A direction with no plane-parallel path (L = 0) has
w = 0; a point where every w is 0 (no medium in any direction) keeps eq. (27)'s
mean (G = 1 there). Not weighted: the leaf's own |n · s_i| (16 directions are
too few to resolve a leaf's cosine lobe; the weighting above is for the mean
orientation, the one the plane-parallel part is exact for).

What the weights do, measured (2026-12-02; commands in README "The G-factor's
weights and depths"): a horizontal direction (c = 1, L = ∞) has
w = p e^{-d0}, a direction toward the sun (c → 0) w ≈ p e^{-d0} d0, a downward
one (c > 1) less than either, so G_rad leans toward the up-sun directions. In
the uniform layer the two agree (mean G over the inner region 0.918 paper,
0.919 radiance, grid depths; the sun-60° bins of ``sppg`` move from
-9.8 … -6.5 % to -9.2 … -7.0 %): the weighting is not what takes the layer's
6-10 %. On the isolated tree_small crown in the paper's setting G_rad is lower
(mean 0.586 against 0.678), which helps the exact slab there (binned total
0.296/0.258 -> 0.242/0.204, ray/grid depths) and hurts the paper's closed form
(0.147/0.157 -> 0.177/0.191).

Depth noise (``g_depths``; ``foliage spp --g-resolution``)
----------------------------------------------------------
F_v is concave in the depths where h ~ L (F = 1 for h >= L, < 1 below), so
per-leaf depth noise alone lowers G: the mean of F over noisy h is below F of
the mean h. In the uniform layer's inner region (sun 60°, the grid path: the
64-voxel leaf-area density holds under one 0.1 m card per voxel) the mean grid
depths toward each of the 16 directions are within 1 % of the exact depths of
a uniform box, yet G from them is 0.918 (0.919 radiance) against 0.994
(0.992) from the box's exact depths; with the exact light depths d0 and the
grid's h it is still 0.904 (0.926). This bias, not the open sides, is the 6-10
% of issue #15's finding 1. shinya2013 (sec. 5.1-5.2) keeps G and the depths
on a ~16³ grid per instance; ``solve_sppg(g_depths=...)`` takes the depths of
G apart from those of the plane-parallel part, and ``foliage spp
--g-resolution N`` measures them through a coarse density grid of N voxels
along the longest foliage edge (0, the default: each leaf's own depths).

Orders of scattering (``SPPGParams.g_orders``; ``foliage spp --g-orders``)
--------------------------------------------------------------------------
Eqs. (24)-(27) take I' = I0 (app. A.2): G is the present share of the
*once*-scattered light. The later orders are not lost at the same rate: what
sets how much of order n reaches order n + 1 is the chance that light a leaf
scatters meets another leaf, the recollision probability p of the spectral
invariant (order n+1 = ω p × order n; reviewed by Wang et al. 2018, Remote
Sens. 10(11), 1805; ``boulanger.higher_orders`` uses it for s_max). With the
slab's orders in a constant ratio a (E_{n+1} = a E_n, so its once-scattered
share is s = E_1/E = 1 - a) and the real medium's ratio a ρ, ρ = p_real /
p_slab at the point, the present light is

    E_present = G E_1 Σ_n (a ρ)^{n-1} = E G s / (1 - (1 - s) ρ),

    p = 1 - (1/N) Σ_v e^{-h_v}  (real: h_v the depth to the medium's boundary
    toward v; slab: h_v = L_v, the distance to the slab's face, as for F_v),

ρ clipped to [0, 1] (depth noise can put the real p above the slab's; the
real medium never holds light longer than the infinite slab around it). It
is G for s = 1 (albedo -> 0) and for ρ = 1 (an interior point of a uniform
layer: the slab's own orders), 1 for G = ρ = 1, and never above G. s is taken
from the exact slab at the leaf (its solution at albedo ε = 1e-4 scaled by
ω/ε is its once-scattered part) for either ``model``; p from the same depths
as G. This departs from eq. (28), which applies the single-scattering G to
all orders. (Session 12's form took ρ = G, each order keeping the share G of
the one before: G s / (1 - G (1 - s)). p per point, not the crown mean the
spectral invariant is usually quoted with: the mean over a finite layer's
leaves includes its edges and darkened the inner region by 8-13 %.)
Measured in README "The G-factor's weights and depths".

Sample directions: a spherical Fibonacci set (González 2010, "Measurement of
areas on a sphere using Fibonacci and latitude-longitude lattices"), z_i =
1 - (2i+1)/N about ``up`` with golden-angle azimuths: equal-area, no direction
exactly horizontal for even N, and symmetric in v_n, so half of them serve as
sky directions. The paper does not give its 16-22 directions.

Pure numpy + numba; no files, no printing.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from .depth import DepthSamples
from .optics import LeafOptics
from .phase import canopy_bilambertian_phase
from .slab_table import leaf_weights, slab_table
from .spp import forward_fraction, refined_parts, spp_field

__all__ = [
    "DEFAULT_DIRECTIONS",
    "EXACT_STREAMS",
    "G_WEIGHTS",
    "MODELS",
    "LeafIrradiance",
    "SPPGParams",
    "SPPGResult",
    "gfactor",
    "sample_directions",
    "sky_weights",
    "solve_sppg",
]

#: Plane-parallel models of ``SPPGParams.model`` (module docstring).
MODELS = ("exact", "spp")
#: How G combines the sample directions (``SPPGParams.g_weights``, module docstring): shinya2013 eq. (27)'s
#: equal-weight mean, or weighted by each direction's plane-parallel single-scattering radiance.
G_WEIGHTS = ("paper", "radiance")
#: Streams per hemisphere of the exact plane-parallel tables (``model="exact"``): against 32 streams the
#: leaf irradiance differs by <= 1.3e-3 for tilted leaves and <= 4e-5 for the mean over orientations
#: (measured, τ = 3, albedo 0.2-1, μ0 0.3-1), below the tables' 3e-3 interpolation error, at half the cost of 16.
EXACT_STREAMS = 8
#: Default number of sample directions (shinya2013 sec. 5.1: "typically 16").
DEFAULT_DIRECTIONS = 16
#: Leaves per block in the refined leaf integral (bounds temporary memory).
_REFINE_BLOCK = 4096


def _unit(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or not np.any(a != 0.0):
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {v!r}")
    return a / np.linalg.norm(a)


def _frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``up`` to a right-handed orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return e1, e2


def sample_directions(n: int = DEFAULT_DIRECTIONS, *, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Spherical Fibonacci directions about ``up`` (module docstring).

    Parameters
    ----------
    n : int
        Number of directions, even, >= 2 (the sky uses the n/2 upper ones).
    up : array_like (3,)
        The stage's up axis.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Unit vectors; ``directions @ up = 1 - (2i + 1)/n``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2 or n % 2:
        raise ValueError(f"the number of sample directions must be an even integer >= 2, got {n!r}")
    upv = _unit(up, "up")
    e1, e2 = _frame(upv)
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))  # golden angle
    return (r * np.cos(phi))[:, None] * e1 + (r * np.sin(phi))[:, None] * e2 + z[:, None] * upv


def sky_weights(directions, *, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Beam irradiance W_j of each sample direction standing for a uniform sky.

    Equal weights (the Fibonacci directions have equal solid angles) on the
    directions above the horizon, zero below, scaled so that Σ W_j μ_j = 1: the
    horizontal irradiance of a uniform sky of radiance 1/π.
    """
    d = np.asarray(directions, dtype=np.float64)
    mu = d @ _unit(up, "up")
    upper = mu > 0.0
    if not np.any(upper):
        raise ValueError("no sample direction is above the horizon; cannot represent the sky")
    w = np.where(upper, 1.0, 0.0)
    return w / float(np.sum(w * np.where(upper, mu, 0.0)))


# --------------------------------------------------------------------------
# G-factor
# --------------------------------------------------------------------------


@njit(cache=True)
def _present_fraction(c, h, length):
    """F of the module docstring: share of the plane-parallel single scattering present."""
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
    """log of δI(P, P) along one direction, without the common factor ω σ/(4π) and the phase (module docstring).

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
        How the directions' present fractions F_v are combined (module
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


# --------------------------------------------------------------------------
# per-leaf irradiance
# --------------------------------------------------------------------------


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
    solution looked up per leaf, :mod:`~foliage_tools.lighting.slab_table`) or
    ``"spp"`` (shinya2013's closed form, eqs. (17)-(22)). None: ``"spp"`` if
    ``refine`` else ``"exact"``."""
    sky: bool = True
    """Compute the uniform-sky terms (shinya2013 sec. 5.4 step 4)."""
    refine_polar_nodes: int = 8
    """Gauss-Legendre nodes in the cosine, per hemisphere, of the refined leaf integral."""
    refine_azimuth_nodes: int = 16
    """Equally spaced azimuths of the refined leaf integral."""
    g_weights: str = "paper"
    """How G combines its sample directions (:data:`G_WEIGHTS`, module docstring): ``"paper"``, shinya2013
    eq. (27)'s equal-weight mean of the present fractions; ``"radiance"``, each weighted by the plane-parallel
    single-scattering radiance from that direction (then G is per channel: the phase differs with r and t)."""

    g_orders: bool = False
    """Apply G per order of scattering (module docstring, "Orders of scattering"): with s the exact slab's
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


def _check_normals(normals, n: int) -> np.ndarray:
    nl = np.asarray(normals, dtype=np.float64)
    if nl.shape != (n, 3) or not np.all(np.isfinite(nl)):
        raise ValueError(f"normals must be finite with shape ({n}, 3), got {nl.shape}")
    norm = np.linalg.norm(nl, axis=1)
    if np.any(norm == 0.0):
        raise ValueError("normals must be non-zero (leaf normals)")
    return nl / norm[:, None]


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
    """Exact plane-parallel E_scattered per leaf and channel for a light of cosine ``mu`` (module docstring).

    Slant depth u and thickness U along the light (shinya2013 eq. (29)) are the
    vertical optical depth and thickness t = μ u, τ = μ U of the local slab;
    ``weights`` = :func:`~foliage_tools.lighting.slab_table.leaf_weights` of |n · up| per leaf.
    """
    t = mu * np.asarray(u, dtype=np.float64)
    tau = mu * np.asarray(big_u, dtype=np.float64)
    out = np.empty((t.shape[0], albedo.shape[0]))
    for c in range(albedo.shape[0]):
        table = slab_table(omega=float(albedo[c]), phase=phases[c], mu0=float(mu), n_streams=EXACT_STREAMS)
        out[:, c] = table.leaf_irradiance(t, tau, weights=weights)
    return out


#: Albedo of the single-scattering tables of ``g_orders``: the exact slab's E at ω = ε, times ω/ε, is its
#: once-scattered part to O(ε) relative.
_ONCE_ALBEDO = 1e-4


def _once_scattered_share(u, big_u, mu, weights, albedo, phases, total) -> np.ndarray:
    """(L, C) s = E_1 / E: the once-scattered share of the exact slab's E_scattered (``g_orders``, module docstring).

    E_1 is the exact slab solution at albedo ε = 1e-4 scaled by ω/ε (single scattering is linear in ω for a fixed
    phase). Where E = 0 (no medium), s = 1: G is then left as it is.
    """
    eps = _ONCE_ALBEDO
    once = _exact_leaf_irradiance(u, big_u, mu, weights, np.full_like(albedo, eps), phases) * (albedo / eps)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(total > 0.0, once / np.where(total > 0.0, total, 1.0), 1.0)
    return np.clip(share, 0.0, 1.0)


@njit(cache=True)
def _slab_lengths(vn, mu0, light_depth, light_thickness):
    """(P, N) L_v of every point toward every direction (``_face_distance``, as ``_gfactor_kernel`` takes it)."""
    out = np.empty((light_depth.shape[0], vn.shape[0]))
    for p in range(light_depth.shape[0]):
        t0 = mu0 * light_depth[p]
        below = mu0 * (light_thickness[p] - light_depth[p]) if light_thickness[p] != math.inf else math.inf
        for q in range(vn.shape[0]):
            out[p, q] = _face_distance(vn[q], t0, below)
    return out


def recollision_ratio(boundary_depth, vn, mu0: float, light_depth, light_thickness) -> np.ndarray:
    """(P,) ρ = p_real / p_slab in [0, 1], p = 1 - mean_v exp(-depth toward v) (module docstring, "Orders of
    scattering"); 1 where the slab holds no medium (p_slab = 0)."""
    h = np.asarray(boundary_depth, dtype=np.float64)
    p_real = 1.0 - np.exp(-h).mean(axis=1)
    lengths = _slab_lengths(np.ascontiguousarray(vn, dtype=np.float64), float(mu0),
                            np.ascontiguousarray(light_depth, dtype=np.float64),
                            np.ascontiguousarray(light_thickness, dtype=np.float64))
    p_slab = 1.0 - np.exp(-lengths).mean(axis=1)
    ratio = np.divide(p_real, p_slab, out=np.ones_like(p_real), where=p_slab > 0.0)
    return np.clip(ratio, 0.0, 1.0)


def _all_over_first(share, rho) -> np.ndarray:
    """1 / (1 - (1 - s) ρ): all orders over the first, the later ones at the slab's ratio times ρ (module
    docstring, "Orders of scattering"; the first order's G taken out of ``_orders_g``)."""
    den = 1.0 - (1.0 - share) * np.asarray(rho, dtype=np.float64)
    return np.where(den > 0.0, 1.0 / np.where(den > 0.0, den, 1.0), 1.0)


def _orders_g(g, share, rho) -> np.ndarray:
    """G s / (1 - (1 - s) ρ): the first order keeps G, each later one ρ of the slab's ratio (module docstring)."""
    rho = np.asarray(rho, dtype=np.float64)
    den = 1.0 - (1.0 - share) * rho
    return np.where(den > 0.0, g * share / np.where(den > 0.0, den, 1.0), g)


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
        per-leaf depth noise does (module docstring, "Depth noise").

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

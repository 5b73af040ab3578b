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
    the same slab (:mod:`~foliage_tools.lighting.spp.slab_table`: the project's
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
    (:mod:`~foliage_tools.lighting.spp.slab_table` explains why).
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

Modules
-------
* ``params`` -- :data:`MODELS`, :data:`G_WEIGHTS`, :data:`EXACT_STREAMS`,
  :data:`DEFAULT_DIRECTIONS`; :class:`SPPGParams`, :class:`LeafIrradiance`
  and :class:`SPPGResult`;
* ``directions`` -- :func:`sample_directions` and :func:`sky_weights` (the
  spherical Fibonacci set above), with the unit-vector and frame helpers;
* ``factor`` -- :func:`gfactor` and its numba kernel: the present fractions
  F_v and the weights of "The G-factor" and "Weighting the directions";
* ``models`` -- the plane-parallel part per leaf: the exact slab's tables and
  the SPP closed form's refined leaf integral ("Geometry and normalisation");
* ``orders`` -- the once-scattered share s, the recollision ratio ρ
  (:func:`recollision_ratio`) and G per order ("Orders of scattering");
* ``solver`` -- :func:`solve_sppg`: the sun and sky terms of SPPG, SPP and SS.

Pure numpy + numba; no files, no printing.
"""

from __future__ import annotations

from foliage_tools.lighting.gfactor.directions import sample_directions, sky_weights
from foliage_tools.lighting.gfactor.factor import gfactor
from foliage_tools.lighting.gfactor.orders import recollision_ratio as recollision_ratio
from foliage_tools.lighting.gfactor.params import (
    DEFAULT_DIRECTIONS,
    EXACT_STREAMS,
    G_WEIGHTS,
    MODELS,
    LeafIrradiance,
    SPPGParams,
    SPPGResult,
)
from foliage_tools.lighting.gfactor.solver import solve_sppg

# private parts that tests/unit/test_gfactor.py reaches as ``gf._name`` (re-exported so that they keep working; the
# code itself imports them from their modules)
from foliage_tools.lighting.gfactor.models import _exact_leaf_irradiance as _exact_leaf_irradiance
from foliage_tools.lighting.gfactor.orders import _once_scattered_share as _once_scattered_share
from foliage_tools.lighting.gfactor.orders import _orders_g as _orders_g

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

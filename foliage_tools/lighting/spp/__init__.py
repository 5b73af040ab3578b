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
slab solution (:mod:`~foliage_tools.lighting.spp.slab_table`); this closed form
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

Modules
-------
* ``kernels`` -- numba: the scalar kernels (convolutions of decaying
  exponentials, :func:`_e2`, :func:`_e3`), the closed form (a, b) and the
  refinement's (iso, beam) at a point, and their loops over arrays;
* ``forward`` -- :func:`forward_fraction`, the phase function's forward
  fraction T(μ), and its quadrature on graded meshes;
* ``fields`` -- the public fields: :class:`SPPField`, :func:`spp_field`,
  :func:`spp_single_scattering`, :class:`RefinedParts`,
  :func:`refined_parts`, :func:`refined_radiance`, and their input checks;
* ``raydepth`` -- optical depth and thickness from leaf intersection counts
  along rays through the actual geometry (eq. (29), ray path);
* ``slab_table`` -- the exact plane-parallel scattered light per leaf,
  tabulated in slab thickness (the ``exact`` model of SPP and SPPG).

Pure numpy + numba; no files, no printing.
"""

from __future__ import annotations

from foliage_tools.lighting.spp.fields import (
    RefinedParts,
    SPPField,
    refined_parts,
    refined_radiance,
    spp_field,
    spp_single_scattering,
)
from foliage_tools.lighting.spp.forward import FORWARD_FRACTION_NODES as FORWARD_FRACTION_NODES
from foliage_tools.lighting.spp.forward import forward_fraction

# private kernels that tests/unit/test_spp.py reaches as ``spp._name``
# (re-exported so that they keep working; the code itself imports them from their modules)
from foliage_tools.lighting.spp.kernels import _constants as _constants
from foliage_tools.lighting.spp.kernels import _e2 as _e2
from foliage_tools.lighting.spp.kernels import _e3 as _e3

__all__ = [
    "RefinedParts",
    "SPPField",
    "forward_fraction",
    "refined_parts",
    "refined_radiance",
    "spp_field",
    "spp_single_scattering",
]

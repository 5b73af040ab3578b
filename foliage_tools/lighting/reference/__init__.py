"""Monte Carlo reference: light transport through the actual leaf and wood triangles.

The ground truth every other method is compared with (DESIGN.md sections 3
and 4). Photons are traced with Embree (:mod:`foliage_tools.geometry.rays`)
through the scene's triangles; leaves are two-sided Lambertian scatterers
(reflectance r and transmittance t per RGB channel), wood is opaque
Lambertian (reflectance ρ); there is no ground.

Sources
-------
* **Sun**: a parallel beam along ``-sun_direction`` with irradiance 1 on a
  plane perpendicular to it. By default (``sun_sampling="surface"``) its
  first hits are drawn on the surfaces themselves: points on every triangle
  (leaf and wood) with density ∝ |n·s| per unit area, by systematic sampling
  over the triangles' projected areas A|n·s| (so a triangle's count per
  batch is its expected count rounded up or down), each kept only if a
  shadow ray toward the sun escapes; each carries P / paths per channel,
  P = Σ A|n·s|. That is exactly the beam's first-hit distribution (power
  density |n·s| on the lit parts), spread evenly over the leaves, which
  lowers E_direct's noise (on the Webots oak 0.024 against the beam's 0.042
  at 2M paths; each costs one shadow ray, the shadowed ones are dropped). The
  first hits are split (``split`` photons of 1/split the power each, their
  own events) so one shadow ray serves several paths. With
  ``sun_sampling="beam"`` photon origins are uniform over a rectangle
  perpendicular to the sun that covers the projection of the scene's
  bounding box (enlarged by 1e-3 of its diagonal), placed beyond the scene;
  every photon carries ``area(rectangle) / paths``. Both are unbiased for
  the same tallies (a test checks that they agree leaf by leaf).
* **Sky** (optional): radiance ``sky_radiance`` (RGB, sr⁻¹ per unit sun
  irradiance) from every direction of the hemisphere about ``up``, zero from
  below. A direction ω is drawn uniformly on the hemisphere (pdf 1/2π) and the
  photon's origin uniformly on a disc of radius R perpendicular to ω (R: the
  bounding sphere), placed outside the scene; power per photon
  ``L · 2π · πR² / sky_paths``. (Each direction contributes a parallel beam
  of irradiance L dω on the disc, so a horizontal plane receives π L, the
  uniform-sky irradiance.)
* In a **periodic** layer (``period`` set, ``up`` = +z) photons enter through
  the top of one cell: sun photons at uniform (x, y) with power
  ``μ0 · px · py / paths`` (μ0 = sun·up, the horizontal irradiance), sky
  photons with cosine-distributed directions and power ``π L px py / sky_paths``.

Scattering and weights (why RGB weights, and why no bounce cap)
---------------------------------------------------------------
Each photon carries an RGB power vector W, so the three channels share one
geometric path: one set of rays instead of three, and the channels' errors
are correlated, which keeps colour ratios smooth. At a hit with per-channel
reflectance r, transmittance t (wood: r = ρ, t = 0) let

    a_r = Σ_c W_c r_c,   a_t = Σ_c W_c t_c,   a_a = Σ_c W_c (1 - r_c - t_c).

While the photon is bright (Σ_c W_c at least ``survival_weight`` times its
launch weight), absorption is taken by its expected value: W (1 - r - t) is
deposited and the photon is reflected or transmitted with probabilities
a_r/(a_r + a_t), a_t/(a_r + a_t), its weight becoming W r (a_r + a_t)/a_r or
W t (a_r + a_t)/a_t. Below that weight one of the three events is drawn with
probabilities ∝ a_r, a_t, a_a (the analog scheme): the weight becomes
W r (a/a_r), W t (a/a_t), or W (1 - r - t) (a/a_a) is deposited and the
path ends, with a = a_r + a_t + a_a = Σ_c W_c. In both, each channel's
expectation is exactly the analog one (E[W'] = W r + W t, E[absorbed] =
W (1 - r - t)), so the estimator is unbiased; the analog event *is* the
Russian roulette, so there is no bounce cap, and every event passes on or
deposits exactly the channel sum it received: each photon's launched power
ends up, in full, either absorbed somewhere or escaped, and weights never
exceed the launch weight -- no fireflies. Per channel, energy balance holds
in expectation; summed over the channels it holds per path, exactly up to
rounding. Why expected-value absorption pays: with dark leaves (albedo
0.06-0.28 for geist2008) the analog scheme ends ~85 % of paths at their
first hit, so few photons carry the scattered light whose per-leaf tally is
the quantity of interest; on the Webots oak it cut E_scattered's variance
per path by ~7x. (A safety limit,
``max_events``, abandons paths that have scattered 1e5 times -- reachable only
in closed geometry with albedo 1 -- and reports them in ``truncated``.) The
price of one path for three channels: a channel much darker than the others
(blue in the geist2008 preset) is sampled through paths chosen for the
brighter ones, so its relative noise is larger than if it were traced alone.

A reflected photon leaves into the hemisphere on its incident side, a
transmitted one into the other, both cosine-distributed about the leaf
normal (Lambertian). New rays start ``offset_distance`` off the surface on
the side they leave to (see :mod:`foliage_tools.geometry.rays`).

Tallies (per leaf, RGB; powers in sun-irradiance × stage-unit²)
--------------------------------------------------------------
Every time a photon arrives at a leaf, its power W (before the event) is added
to one of four tallies, chosen by the photon's source and whether it has been
scattered before; each is divided by the leaf's one-sided area:

* ``e_direct``: sun photons on their first hit. Power intercepted by the leaf
  from the unscattered beam / area = the unscattered sun irradiance on both
  faces summed, area-averaged (DESIGN.md section 3); an unshadowed leaf with
  normal n gets |n·s|.
* ``e_scattered``: sun photons scattered at least once (by leaves or wood):
  irradiance from scattered sunlight, both faces summed, area-averaged.
* ``e_sky``: sky photons on their first hit (unscattered sky light; an
  isolated leaf of any orientation gets π L).
* ``e_sky_scattered``: sky photons scattered at least once.

DESIGN.md's E_direct is *unscattered sun* light, so unscattered sky light is
kept out of both E_direct and E_scattered, and E_scattered is sunlight only:
a sun-only method compares with (e_direct, e_scattered) whatever the sky.
:attr:`ReferenceResult.e_total` sums all four.

Also tallied: ``absorbed`` power per leaf, ``absorbed_wood``, ``escaped``
power (photons that leave the scene, including those that never hit
anything: with the surface source, the beam's power that reaches no surface,
``incident - intercepted``), and ``incident`` (power launched = rectangle/disc
areas times irradiance). ``absorbed.sum(0) + absorbed_wood + escaped = incident`` in
expectation per channel, and exactly (to rounding) summed over channels.

Determinism and threads
-----------------------
Paths are split into fixed batches (sizes depend only on ``paths`` and
``batch_size``), each with its own generator from
``np.random.SeedSequence(seed).spawn``; batches run on a thread pool and their
tallies are reduced in batch order. Results are therefore bitwise identical
for a seed, whatever the number of workers. The per-bounce work runs without
the GIL (Embree's traversal in embreex, the numba kernel that tallies and
scatters, numpy's random fills), so batches overlap on several cores.

Noise estimate and stopping at a target
---------------------------------------
The batches are split into two independent halves A (even batch indices,
N_A paths) and B (odd, N_B). Let a and b be the E_scattered estimates of each
half alone (each normalised as a full estimate) and x = (N_A a + N_B b)/N the
full-run result. Per element, Var(a) = v N/N_A and Var(b) = v N/N_B, where v
is the variance of x, so E‖a - b‖² = N (1/N_A + 1/N_B) Σ v. The full run's
relative RMS noise, in the same form as the error measure of DESIGN.md
(sqrt(Σ (x - E x)²/Σ (E x)²)), is therefore estimated as

    noise_rel = ‖a - b‖ / (sqrt(N/N_A + N/N_B) ‖x‖),

which for equal halves is ‖a - b‖ / (2‖x‖) = ‖a - b‖ / ‖a + b‖ (the form of
:func:`foliage_tools.bench.metrics.noise_floor`).
An exact method would show a relative RMS error ≈ noise_rel against this reference.
The same estimate is reported for E_direct (``noise_rel_direct``) and the total.
With ``noise_target`` the run stops after the first even number of sun
batches (≥ 4) whose E_scattered estimate is at or below the target; the
batches are whole ``batch_size`` batches checked in order, so the result is
the same as that many paths traced without a target.

Caveats: it is an estimate from a single pair of halves, so its own relative
spread is about 1/sqrt(2K) for K effectively independent leaf values (a few %
for hundreds of leaves, but meaningless for a handful: with one lit leaf it
can be off by a factor of several); and ‖x‖ contains the noise too, so at
large noise (≳ 20 %) it reads a few % low.

Modules
-------
* ``problem`` -- :class:`ReferenceInputs` (with :class:`Placements`),
  :class:`ReferenceParams` and :class:`ReferenceResult`, validated on
  construction;
* ``sampling`` -- orthonormal bases and cosine / uniform hemisphere
  directions;
* ``sources`` -- the sun beam, its first hits drawn on the surfaces (copied
  triangles or placed prototypes) and the sky ("Sources" above);
* ``tracer`` -- the path loop of one batch: the numba kernel that tallies a
  bounce and draws the events ("Scattering and weights", "Tallies"), a
  batch's tally and the tracer;
* ``solver`` -- :func:`solve`: the batches, their seeds and threads, the
  two-halves noise estimate and the stop at a target ("Determinism and
  threads", "Noise estimate and stopping at a target").

Pure numerics: no files, no printing.
"""

from __future__ import annotations

from foliage_tools.lighting.reference.problem import Placements, ReferenceInputs, ReferenceParams, ReferenceResult
from foliage_tools.lighting.reference.solver import solve

# the private part that tests/unit/test_reference.py reaches as ``reference._Tracer`` (re-exported so that it
# keeps working; the code itself imports it from its module)
from foliage_tools.lighting.reference.tracer import _Tracer as _Tracer

__all__ = ["Placements", "ReferenceInputs", "ReferenceParams", "ReferenceResult", "solve"]

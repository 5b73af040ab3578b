"""Exact (discrete-ordinate) solution of radiative transfer in a homogeneous slab.

This is the reference solver for the plane-parallel problem of shinya2013
sec. 3.1 (eqs. (5) and (7)): a homogeneous, infinitely wide slab of optical
thickness ``tau`` (0 .. +inf), single-scattering albedo ``omega`` and a
rotationally symmetric phase function, lit from above by a collimated beam
(:func:`solve_slab`) or by a uniform isotropic sky (:func:`solve_slab_diffuse`),
over a black or Lambertian floor. The project's approximate SPP model and the
lattice-Boltzmann slab test are validated against it.

Method
------
Discrete ordinates with double-Gauss quadrature (Sykes 1951; Stamnes et al.
1988, "Numerically stable algorithm for discrete-ordinate-method radiative
transfer in multiple scattering and emitting layered media", Appl. Opt. 27,
2502 -- "DISORT" below; Thomas & Stamnes 1999, *Radiative Transfer in the
Atmosphere and Ocean*, chs. 6 and 8, "T&S" below). References are to the
topic in those texts; section/equation numbers were not re-checked against
the printed texts, the formulas are re-derived in the comments:

* azimuthal Fourier expansion of the phase function and radiance (DISORT
  ; T&S ch. 6), so each Fourier order m solves an independent
  2N-stream system; fluxes only need m = 0;
* for each m, the 2N x 2N homogeneous system is reduced to an N x N
  eigenproblem for k² with the sum/difference trick (Stamnes & Swanson 1981,
  J. Atmos. Sci. 38, 387; DISORT), here written in a symmetric form
  (Cholesky factor of the "difference" matrix) so that ``scipy.linalg.eigh``
  applies and the k² are real and non-negative;
* the direct-beam particular solution is Z exp(-t/mu0) with Z from one linear
  solve (DISORT; T&S ch. 8);
* boundary conditions are solved with *scaled* exponentials exp(-k t) and
  exp(-k (tau - t)) (Stamnes & Conklin 1984, JQSRT 31, 273; DISORT), so nothing can
  overflow for tau = 1e4, 1e5 or inf;
* radiances at arbitrary ("user") directions are obtained by integrating the
  source function analytically along the line of sight (DISORT; T&S
  ch. 8), which reproduces the nodal values exactly.

Numerical special cases (documented because results depend on them):

* **Conservative scattering (omega = 1).** For m = 0 one eigenvalue k -> 0 as
  omega -> 1 and the pair exp(±k t) degenerates into {1, t}. This package uses
  *no* omega = 1 - epsilon trick: (i) the smallest eigenvalue of the m = 0
  problem is computed for 1 - omega < 1e-4 by a deflated Schur-complement
  iteration around the exact null vector of the conservative operator, so k²
  has full *relative* accuracy down to omega = 1 exactly (k = 0); (ii) for
  finite tau, modes with k tau < 1 use the basis (exp(-kt) + exp(-k(tau-t)))/2
  and (exp(-kt) - exp(-k(tau-t)))/k, which tend to 1 and tau - 2t as k -> 0, so
  the boundary-value problem stays well conditioned and exact at omega = 1.
* **mu0 at a resonance.** The particular solution is singular when 1/mu0
  equals an eigenvalue k_j (for omega -> 0 these are the quadrature nodes).
  When |k_j mu0 - 1| < 1e-5 the diffuse field is computed at two perturbed
  incidence cosines and combined to second order: the mean of mu0 (1 ± h), or
  if mu0 (1 + h) > 1 the extrapolation 2 f(mu0 (1-h)) - f(mu0 (1-2h)), with
  h = 4e-5. The diffuse field is a smooth (analytic) function of mu0, so the
  error is O(h²) ~ 1e-9 relative; the direct beam always uses the exact mu0.
* **tau = 0** is returned exactly (no diffuse field except floor reflection);
  **omega = 0** gives an exactly zero scattered field.

Normalisation
-------------
Optical depth t is measured downward from the slab top (0 <= t <= tau). A
direction is given by mu = cos(polar angle) measured from the *upward*
vertical (mu > 0 upward, mu < 0 downward) and an azimuth phi measured from
the azimuth of the incident beam's propagation direction (so phi = 0 on the
upward side is the specular/forward-reflection plane half).

* Beam (:func:`solve_slab`): collimated beam of irradiance 1 on a plane
  perpendicular to the beam, i.e. horizontal irradiance ``mu0`` on the slab top.
  All fluxes and radiances are per unit beam irradiance (radiance in sr⁻¹).
* Sky (:func:`solve_slab_diffuse`): isotropic downward radiance 1/π at the
  top, i.e. horizontal irradiance 1.

``reflectance``, ``transmittance_*``, ``absorptance`` and ``floor_absorptance``
are divided by the incident *horizontal* flux (mu0 for the beam, 1 for the
sky), so that reflectance + absorptance + floor_absorptance = 1.

Modules
-------
* ``constants`` -- the resonance tolerance and step, the conservative-refinement
  threshold, the largest number of streams and the "too peaked" message;
* ``special`` -- small, overflow-free scalar helpers (exp(-k t), (1 - e^{-x})/x,
  sinh(x)/x, the convolution of two exponentials) and the normalised
  associated Legendre functions;
* ``eigen`` -- the problem setup (double-Gauss nodes and weights, Legendre
  moments; ``_Setup``) and the eigen-decomposition of one Fourier order
  (``_eigen``), with the deflated refinement of the conservative eigenvalue
  ("Conservative scattering" above);
* ``modes`` -- one Fourier order: the particular beam solution, the
  boundary-value solution and its evaluation at depths and at any direction
  (``_ModeSolution``), and the resonance treatment (:func:`resonance_offsets`,
  "mu0 at a resonance" above);
* ``solution`` -- the result, :class:`SlabSolution` (fluxes, profiles,
  radiances; "Normalisation" above), and the lazily solved Fourier orders
  behind its ``radiance`` (``_Field``);
* ``solver`` -- the entry points :func:`solve_slab` and
  :func:`solve_slab_diffuse`: input checks, tau = 0, fluxes, depth profiles,
  absorptance.
"""

from __future__ import annotations

from foliage_tools.lighting.plane_parallel.constants import CONSERVATIVE_REFINE_BELOW as CONSERVATIVE_REFINE_BELOW
from foliage_tools.lighting.plane_parallel.constants import MAX_STREAMS as MAX_STREAMS
from foliage_tools.lighting.plane_parallel.constants import RESONANCE_STEP as RESONANCE_STEP
from foliage_tools.lighting.plane_parallel.constants import RESONANCE_TOLERANCE as RESONANCE_TOLERANCE
from foliage_tools.lighting.plane_parallel.modes import resonance_offsets as resonance_offsets
from foliage_tools.lighting.plane_parallel.solution import SlabSolution
from foliage_tools.lighting.plane_parallel.solver import solve_slab, solve_slab_diffuse

# private parts that foliage_tools/lighting/spp/slab_table.py and tests/unit/test_plane_parallel.py reach as
# ``plane_parallel._name`` (re-exported so that they keep working; the code itself imports them from their modules)
from foliage_tools.lighting.plane_parallel.eigen import _eigen as _eigen
from foliage_tools.lighting.plane_parallel.eigen import _Setup as _Setup
from foliage_tools.lighting.plane_parallel.special import _norm_assoc_legendre as _norm_assoc_legendre

__all__ = ["SlabSolution", "solve_slab", "solve_slab_diffuse"]

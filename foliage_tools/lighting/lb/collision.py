"""The collision operator Omega of the lattice-Boltzmann lighting model, and what feeds it.

Omega (geist2008 eqs. (2), (5)-(9))
-----------------------------------
One lattice update is ``f_m(r + c_m, t+1) = f_m(r, t) + Omega_m . f(r, t)``
(geist2008 eq. (2)) with a 19x19 matrix per node. For unit density

    Omega_00 = -1,  Omega_0j = sigma_a                      (j > 0)       eq. (5)
    Omega_i0 = w_i                                          (i > 0)       eqs. (6), (7)
    Omega_ij = sigma_s q_ij(g) - sigma_t delta_ij           (i, j > 0)    eqs. (6)-(9)

with ``w_i`` = 1/12 (axial) or 1/24 (non-axial) and ``q_ij(g) = w_i pn_ij(g)``
the normalised Henyey-Greenstein weight of eqs. (8)-(9) (``q_ij = w_i`` at
g = 0, the isotropic eqs. (6)-(7)). "The entries of Omega were then multiplied
by the density of the medium at each lattice site" (geist2008 sec. 2.2), so a
node of density rho uses ``rho * Omega``: rho = 0 passes light through.

Conservation: every column of Omega sums to zero, for every rho, sigma and g
(column 0: -1 + sum w_i = 0; column j > 0: sigma_a + sigma_s - sigma_t = 0).
Absorption moves the fraction rho*sigma_a of each directional density into the
rest direction f_0; geist2008 sec. 3 then zeroes f_0 at every node on every
iteration ("the significant loss of light energy from the visible spectrum"),
which is where energy leaves the system. The solver therefore only carries
the 18 moving directions, whose block ``Omega[1:, 1:]`` has column sums
``-rho*sigma_a`` (exactly zero when sigma_a = 0). We zero f_0 at every node,
green or brown: wood absorbs too, through its own sigma_a.

Henyey-Greenstein limit g -> ±1
-------------------------------
The weights ``q_ij = m_i p_ij / sum_k m_k p_kj`` (m = multiplicity, p of eq.
(9)) are a 0/0 limit at |g| = 1: p_jj -> inf (g -> 1) and every other p -> 0.
The common factor (1 - g^2) of eq. (9) cancels, and dividing by the smallest
``D_kj = 1 - 2 g mu_kj + g^2`` of the column gives ratios ``(D_min/D_ij)^(3/2)``
in [0, 1] that are finite for every g and exactly 0/1 at |g| = 1. D is
evaluated without cancellation as ``(1-g)^2 + 2g(1-mu)`` for g >= 0 and
``(1+g)^2 - 2g(1+mu)`` for g < 0. The limit is a delta: g = 1 keeps the
scattered light in its direction (with sigma_a = 0, Omega = 0: the
pass-through noted under geist2008 eq. (9)); g = -1 sends it back along -c_j
(the "brown" wood nodes of geist2008 sec. 3). At |g| = 1 - 1e-9 the off-peak
ratios are ~1e-27, so the limit is continuous to machine precision.

Leaf optics (geist2008 sec. 3 and Table 1)
------------------------------------------
From leaf reflectance r and transmittance t per channel: ``sigma_a =
absorption_scale * (1 - r - t)`` (the paper scales Knapp-Carter absorptance by
0.125), ``sigma_s = 1 - sigma_a`` (so sigma_t = 1), and ``g = (fs - bs) / (fs +
bs)`` with forward scatter fs = t and backward scatter bs = r (eq. (10)). The
preset ``GEIST2008_LEAF`` reproduces Table 1 to its three printed digits.
``absorption_scale=1`` gives the physical single-scattering albedo
``sigma_s = r + t`` instead.

Node density
------------
rho is a per-step interaction probability. From leaf-area density LAD (one-
sided leaf area per volume, 1/length) and the voxel edge dx we use

    rho = 1 - exp(-G * LAD * dx),   G = 0.5 (spherical leaf-angle distribution)

which is G*LAD*dx to first order and makes the lattice's per-step
transmittance of unscattered light along an axial direction, 1 - rho*sigma_t
with sigma_t = 1, equal to Beer-Lambert ``exp(-G LAD dx)`` exactly; it also
keeps rho < 1, so the stability bound rho*sigma_t <= 1 holds whenever
sigma_t <= 1. The ``subgrid`` density of geist2008 sec. 4.2 (covered fraction
of 27 sub-cells) is already in [0, 1] and is used as rho directly.

Step lengths: the ``ordinates`` lattice (default) and ``geist2008``
-----------------------------------------------------------------
geist2008 (eqs. (2), (6), (7)) multiplies the whole of Omega by one node
density, so a step along a non-axial direction c_i (length |c_i| dx =
sqrt(2) dx) is attenuated like an axial one (dx): a diagonal beam crosses a
slab as if at normal incidence (exp(-tau) instead of exp(-tau sqrt 2)). That
is ``lattice="geist2008"``, kept to reproduce the paper. ``lattice="ordinates"``
reads the lattice as a discrete-ordinate scheme and corrects both places where
the step length enters:

* Extinction. A beam along c_j crosses |c_j| dx of medium per step, so the
  probability that it meets a leaf in the step is

      rho_j = 1 - exp(-G LAD |c_j| dx) = 1 - (1 - rho)^|c_j|        (``step_density``)

  (rho_j = rho axial, ``diagonal_density(rho)`` non-axial), replacing the
  common factor rho of geist2008 sec. 2.2 by a per-column factor: the update
  is ``f_i <- f_i + sum_j A_ij rho_j f_j`` with A = ``unit_moving_block``.
* In-scattering (the sigma_s terms of eqs. (6)-(9)). In a steady beam f_i is
  the irradiance carried by ordinate i; one lattice line per node carries it,
  and the lines of direction c_i are |c_i| times denser across the beam than
  axial ones (one line per node, nodes |c_i| dx apart along the line), so a
  line stands for the cross-section a_i = dx^2 / |c_i| and carries the power
  f_i a_i. The power a node takes out of beam j is ``sigma_t rho_j f_j a_j``;
  scattering the share sigma_s P_ij of it into i and dividing by a_i gives

      A_ij = sigma_s P_ij |c_i| / |c_j| - sigma_t delta_ij            (i, j > 0)

  so the power-weighted column sums ``sum_i A_ij / |c_i| = -sigma_a / |c_j|``
  vanish at sigma_a = 0: the conserved quantity is the power
  ``sum_i f_i / |c_i|`` (the net flux through a horizontal plane is
  ``sum_i f_i n_iz``, n_iz = c_iz / |c_i|), no longer the density sum. The
  update stays non-negative with weighted column sums 1 - sigma_a rho_j <= 1
  when rho_j sigma_t <= 1, so it cannot grow (stable in the weighted 1-norm).
  To first order in dx both terms are those of the discrete-ordinate
  transport equation ``n_i . grad f_i = -sigma f_i + sigma_s sum_j P_ij f_j``
  integrated over a step of length |c_i| dx.
* Weights. P_ij = w_i p(n_i . n_j) / sum_k w_k p(n_k . n_j) is eq. (8) with
  the quadrature weights of the ordinates, ``lattice.ORDINATE_WEIGHTS`` (1/30
  axial, 1/15 non-axial: fourth-moment isotropy of the unit directions, see
  ``lattice``), instead of geist2008's 1/12, 1/24 (fourth-moment isotropy of
  the velocities c_i, the right condition for the geist2008 steps).

Phase functions
---------------
``Medium.phase`` picks p of eq. (8): ``"hg"``, the Henyey-Greenstein p of eq.
(9) with the g of eq. (10); or ``"bilambertian"``, the area scattering phase
function of randomly oriented two-sided Lambertian leaves (Ross 1981; the
phase function the Monte Carlo reference and the exact slab solver use,
``phase.BiLambertianCanopyPhase``), p(beta) ~ r^ (sin b - b cos b) + t^ (sin b
+ (pi - b) cos b), written with the same g: r^ = (1 - g) / 2 = r / (r + t),
t^ = (1 + g) / 2. (HG with g = (t - r)/(t + r) is more forward-peaked than the
leaves: the bi-Lambertian asymmetry is 4/9 of that g.) The discrete weights of
a direction d off the lattice (the first-collision source of ``lb``) are the
same eq. (8) ratios with n_j replaced by d (``source_weights``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from foliage_tools.lighting.lb.lattice import DIRECTIONS, MULTIPLICITY, ORDINATE_WEIGHTS, STEP_LENGTHS, UNIT_DIRECTIONS, WEIGHTS
from foliage_tools.lighting.optics import LeafOptics, parse_leaf_optics

__all__ = [
    "GEIST2008_ABSORPTION_SCALE",
    "GEIST2008_LEAF",
    "LATTICES",
    "LEAF_ANGLE_G",
    "LeafOptics",
    "Medium",
    "PHASES",
    "brown",
    "density_from_lad",
    "diagonal_density",
    "hg_weights",
    "lattice_weights",
    "leaf_medium",
    "omega",
    "omega_isotropic",
    "phase_weights",
    "source_weights",
    "step_density",
    "unit_moving_block",
]

#: Lattice readings (module docstring): ``ordinates`` (true step lengths, ordinate weights) or the paper's ``geist2008``.
LATTICES = ("ordinates", "geist2008")
#: Discrete phase functions of eq. (8): Henyey-Greenstein (geist2008 eq. (9)) or the bi-Lambertian leaf canopy.
PHASES = ("hg", "bilambertian")

#: Ross G-function of a spherical (uniformly random) leaf-angle distribution:
#: mean projected area of a unit leaf onto a plane normal to any direction.
LEAF_ANGLE_G = 0.5

#: geist2008 sec. 3: Knapp-Carter absorptances are scaled by this factor.
GEIST2008_ABSORPTION_SCALE = 0.125


#: geist2008 Table 1: fs = transmittance, bs = reflectance (Knapp-Carter, R G B).
#: (The project-wide LeafOptics and its presets live in foliage_tools.lighting.optics.)
GEIST2008_LEAF = parse_leaf_optics("geist2008")


@dataclass(frozen=True)
class Medium:
    """Per-channel scattering coefficients of one material at unit density."""

    sigma_a: tuple[float, ...]
    """Absorbed fraction of an interaction, per channel (>= 0)."""
    sigma_s: tuple[float, ...]
    """Scattered fraction of an interaction, per channel (>= 0)."""
    g: tuple[float, ...]
    """Asymmetry per channel in [-1, 1] (> 0 forward, < 0 backward): eq. (10)'s g = (t - r) / (t + r)."""
    phase: str = "hg"
    """``hg`` (geist2008 eq. (9)) or ``bilambertian`` (two-sided Lambertian leaves, r^ = (1 - g) / 2)."""

    def __post_init__(self) -> None:
        if self.phase not in PHASES:
            raise ValueError(f"phase must be one of {', '.join(PHASES)}, got {self.phase!r}")
        vals = {}
        for name in ("sigma_a", "sigma_s", "g"):
            v = tuple(float(x) for x in np.atleast_1d(np.asarray(getattr(self, name), dtype=np.float64)))
            object.__setattr__(self, name, v)
            vals[name] = v
        n = {len(v) for v in vals.values()}
        if len(n) != 1 or 0 in n:
            raise ValueError(f"sigma_a, sigma_s and g need the same nonzero number of channels, got {[len(v) for v in vals.values()]}")
        if not all(math.isfinite(x) and x >= 0.0 for x in vals["sigma_a"] + vals["sigma_s"]):
            raise ValueError(f"sigma_a and sigma_s must be finite and >= 0, got {vals['sigma_a']}, {vals['sigma_s']}")
        if not all(math.isfinite(x) and -1.0 <= x <= 1.0 for x in vals["g"]):
            raise ValueError(f"g must be in [-1, 1], got {vals['g']}")

    @property
    def channels(self) -> int:
        return len(self.sigma_a)

    @property
    def sigma_t(self) -> tuple[float, ...]:
        """sigma_t = sigma_a + sigma_s (geist2008 sec. 2.2)."""
        return tuple(a + s for a, s in zip(self.sigma_a, self.sigma_s))

    def unscattered(self) -> Medium:
        """The medium seen by never-scattered light: sigma_s -> 0, sigma_a -> sigma_t.

        Its per-step attenuation is 1 - rho*sigma_t, the diagonal of the full
        operator without the scattered-back-into-the-beam term, so solving with
        it gives the unscattered ("direct") part of the full solution.
        """
        return Medium(sigma_a=self.sigma_t, sigma_s=tuple(0.0 for _ in self.sigma_s), g=self.g, phase=self.phase)


def leaf_medium(optics: LeafOptics = GEIST2008_LEAF, *, absorption_scale: float = GEIST2008_ABSORPTION_SCALE,
                phase: str = "hg") -> Medium:
    """(sigma_a, sigma_s, g) per channel from leaf optics (geist2008 sec. 3, eq. (10)).

    ``sigma_a = absorption_scale * (1 - r - t)``, ``sigma_s = 1 - sigma_a``,
    ``g = (t - r) / (t + r)``. The default reproduces geist2008 Table 1
    (sigma_a = 0.109, 0.091, 0.118; g = -0.120, 0.091, -0.333).
    ``absorption_scale = 1`` gives sigma_s = r + t, the physical leaf albedo.
    ``phase`` is the discrete phase function (``PHASES``; module docstring).
    """
    if not (math.isfinite(absorption_scale) and 0.0 < absorption_scale <= 1.0):
        raise ValueError(f"absorption_scale must be in (0, 1], got {absorption_scale}")
    r = np.asarray(optics.reflectance)
    t = np.asarray(optics.transmittance)
    sigma_a = absorption_scale * (1.0 - r - t)  # geist2008 sec. 3: absorptance x 0.125
    sigma_a = np.clip(sigma_a, 0.0, None)
    sigma_s = 1.0 - sigma_a  # geist2008 sec. 3: sigma_s = 1 - sigma_a
    g = optics.g  # geist2008 eq. (10), fs = t, bs = r (0 where r + t = 0)
    return Medium(sigma_a=tuple(sigma_a), sigma_s=tuple(sigma_s), g=tuple(g), phase=phase)


def brown(medium: Medium) -> Medium:
    """The same medium scattering backward only: g = -1 (geist2008 sec. 3, "brown" nodes)."""
    return replace(medium, g=tuple(-1.0 for _ in medium.g))


def density_from_lad(lad, voxel_size: float, *, G: float = LEAF_ANGLE_G) -> np.ndarray:
    """Lattice node density rho = 1 - exp(-G * LAD * dx) from leaf-area density.

    Parameters
    ----------
    lad : array_like, (nx, ny, nz)
        One-sided leaf area per volume (1 / length unit), >= 0.
    voxel_size : float
        Voxel edge dx in the same length unit (the lattice spacing).
    G : float
        Mean projection of unit leaf area (0.5 for a spherical leaf-angle
        distribution).

    Returns
    -------
    rho : float64 array in [0, 1): the probability that light crossing one
        (axial) lattice step interacts with a leaf. ``1 - rho`` is exactly the
        Beer-Lambert transmittance ``exp(-G LAD dx)`` of that step.
    """
    lad = np.asarray(lad, dtype=np.float64)
    if not (math.isfinite(voxel_size) and voxel_size > 0):
        raise ValueError(f"voxel_size must be a positive number, got {voxel_size}")
    if not (math.isfinite(G) and G > 0):
        raise ValueError(f"G must be a positive number, got {G}")
    if lad.size and (not np.all(np.isfinite(lad)) or lad.min() < 0):
        raise ValueError("leaf-area density must be finite and >= 0 everywhere")
    return -np.expm1(-G * lad * voxel_size)


def _one_minus_mu() -> tuple[np.ndarray, np.ndarray]:
    """1 - mu_ij and 1 + mu_ij for the 18 moving directions, mu = n_i . n_j, exact at mu = ±1."""
    c = DIRECTIONS[1:].astype(np.float64)
    dots = c @ c.T
    norms2 = (c**2).sum(axis=1)
    # sqrt(|ci|^2 |cj|^2) is 1, sqrt2 or 2: exact when mu = ±1, so 1 -+ mu is exactly 0 there
    mu = dots / np.sqrt(np.outer(norms2, norms2))
    return 1.0 - mu, 1.0 + mu


_OMM, _OPM = _one_minus_mu()
_OMM.flags.writeable = False
_OPM.flags.writeable = False
_M18 = MULTIPLICITY[1:].astype(np.float64)


def hg_weights(g: float) -> np.ndarray:
    """(18, 18) q_ij(g) = w_i pn_ij(g), the normalised HG weights of geist2008 eqs. (8)-(9).

    Row/column k is lattice direction k + 1. Each column is a probability
    distribution over outgoing directions i (sums to 1, entries >= 0). The
    factor (1 - g^2) of eq. (9) cancels in the normalisation of eq. (8); what
    remains is evaluated as ratios to the column's smallest denominator, exact
    and continuous up to and including |g| = 1 (see the module docstring).
    """
    g = float(g)
    if not (math.isfinite(g) and -1.0 <= g <= 1.0):
        raise ValueError(f"g must be in [-1, 1], got {g}")
    # geist2008 eq. (9) relative to each column's peak, cancellation-free (``_hg_relative``)
    p = _hg_relative(_OMM, _OPM, g)
    num = _M18[:, None] * p  # 24 w_i p_ij
    return num / num.sum(axis=0, keepdims=True)  # geist2008 eq. (8): w_i pn_ij


def lattice_weights(lattice: str) -> np.ndarray:
    """(18,) quadrature weights of the moving directions: geist2008's 1/12, 1/24 or the ordinates' 1/30, 1/15."""
    _check_lattice(lattice)
    return np.asarray((WEIGHTS if lattice == "geist2008" else ORDINATE_WEIGHTS)[1:], dtype=np.float64)


def _check_lattice(lattice: str) -> None:
    if lattice not in LATTICES:
        raise ValueError(f"lattice must be one of {', '.join(LATTICES)}, got {lattice!r}")


def _check_phase(phase: str, g: float) -> float:
    if phase not in PHASES:
        raise ValueError(f"phase must be one of {', '.join(PHASES)}, got {phase!r}")
    g = float(g)
    if not (math.isfinite(g) and -1.0 <= g <= 1.0):
        raise ValueError(f"g must be in [-1, 1], got {g}")
    return g


def _bilambertian(mu: np.ndarray, g: float) -> np.ndarray:
    """Bi-Lambertian canopy phase function (phase.BiLambertianCanopyPhase) up to its constant, r^ = (1 - g)/2."""
    mu = np.clip(mu, -1.0, 1.0)
    beta = np.arccos(mu)
    sin_b = np.sqrt(np.maximum(0.0, 1.0 - mu * mu))
    r_hat, t_hat = 0.5 * (1.0 - g), 0.5 * (1.0 + g)
    return r_hat * (sin_b - beta * mu) + t_hat * (sin_b + (math.pi - beta) * mu)


def _hg_relative(one_minus_mu: np.ndarray, one_plus_mu: np.ndarray, g: float) -> np.ndarray:
    """HG p(mu) / max over axis 0, finite for every g including |g| = 1.

    The denominator D = 1 - 2 g mu + g^2 of geist2008 eq. (9) is formed from 1 -+ mu without
    cancellation, and (D_min / D)^(3/2) is 1 at the peak, also when D_min = 0 (|g| = 1).
    """
    if g >= 0.0:
        D = (1.0 - g) ** 2 + 2.0 * g * one_minus_mu
    else:
        D = (1.0 + g) ** 2 - 2.0 * g * one_plus_mu
    dmin = D.min(axis=0, keepdims=True)
    ratio = np.divide(np.broadcast_to(dmin, D.shape), D, out=np.ones_like(D), where=D > 0.0)
    return ratio**1.5


def phase_weights(g: float, phase: str = "hg", lattice: str = "ordinates") -> np.ndarray:
    """(18, 18) P_ij: share of the power scattered out of direction j that goes into direction i.

    geist2008 eq. (8) with the lattice's quadrature weights w (``lattice_weights``) and the
    phase function ``phase`` (``PHASES``): P_ij = w_i p(n_i . n_j) / sum_k w_k p(n_k . n_j).
    Each column is a distribution (>= 0, sums to 1). ``phase_weights(g, "hg", "geist2008")`` is
    ``hg_weights(g)``.
    """
    g = _check_phase(phase, g)
    _check_lattice(lattice)
    if phase == "hg" and lattice == "geist2008":
        return hg_weights(g)
    w = lattice_weights(lattice)
    p = _hg_relative(_OMM, _OPM, g) if phase == "hg" else _bilambertian(1.0 - _OMM, g)
    num = w[:, None] * p
    return num / num.sum(axis=0, keepdims=True)


def source_weights(direction, g: float, phase: str = "hg", lattice: str = "ordinates") -> np.ndarray:
    """(18,) q_i(d): share of the power scattered out of a beam travelling along ``direction`` that goes into c_i.

    eq. (8) for an incident direction d that need not be a lattice direction (the
    first-collision source of ``lb``): q_i = w_i p(n_i . d) / sum_k w_k p(n_k . d). For d = n_j
    it is column j of ``phase_weights``.
    """
    g = _check_phase(phase, g)
    _check_lattice(lattice)
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(d))
    if not (math.isfinite(norm) and norm > 0.0):
        raise ValueError(f"direction must be a finite nonzero 3-vector, got {tuple(d)}")
    mu = UNIT_DIRECTIONS[1:] @ (d / norm)
    # exact 1 -+ mu on a lattice direction, as in _one_minus_mu
    omm = np.where(np.isclose(mu, 1.0, rtol=0, atol=1e-15), 0.0, 1.0 - mu)
    opm = np.where(np.isclose(mu, -1.0, rtol=0, atol=1e-15), 0.0, 1.0 + mu)
    w = lattice_weights(lattice)
    p = _hg_relative(omm[:, None], opm[:, None], g)[:, 0] if phase == "hg" else _bilambertian(1.0 - omm, g)
    num = w * p
    return num / num.sum()


def diagonal_density(rho) -> np.ndarray:
    """rho_d = 1 - (1 - rho)^sqrt(2): the interaction probability of a non-axial step (module docstring).

    With rho = 1 - exp(-G LAD dx) (``density_from_lad``) this is 1 - exp(-G LAD sqrt(2) dx), the
    Beer-Lambert loss over the sqrt(2) dx of a diagonal step. rho must lie in [0, 1]; rho_d >= rho.
    """
    rho = np.asarray(rho, dtype=np.float64)
    if rho.size and (not np.all(np.isfinite(rho)) or rho.min() < 0.0 or rho.max() > 1.0):
        raise ValueError("rho must be finite and in [0, 1] for the diagonal step density")
    with np.errstate(divide="ignore"):
        return -np.expm1(math.sqrt(2.0) * np.log1p(-rho))


def step_density(rho, lattice: str = "ordinates") -> np.ndarray:
    """(..., 18) rho_j per moving direction: rho (axial) and ``diagonal_density(rho)`` (non-axial) for
    ``ordinates``, rho for all 18 for ``geist2008`` (the paper's one factor per node)."""
    _check_lattice(lattice)
    rho = np.asarray(rho, dtype=np.float64)
    rd = diagonal_density(rho) if lattice == "ordinates" else rho
    return np.concatenate([np.repeat(rho[..., None], 6, axis=-1), np.repeat(rd[..., None], 12, axis=-1)], axis=-1)


def omega(rho: float, sigma_a: float, sigma_s: float, g: float = 0.0) -> np.ndarray:
    """(19, 19) collision matrix of one node and channel, geist2008 eqs. (5)-(9), times rho.

    Entry (i, j) moves density from direction j into direction i. All columns
    sum to 0 (absorbed light is booked into f_0, which the solver then removes).
    """
    for name, v in (("rho", rho), ("sigma_a", sigma_a), ("sigma_s", sigma_s)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {v}")
    sigma_t = sigma_a + sigma_s
    om = np.empty((19, 19))
    om[0, 0] = -1.0  # geist2008 eq. (5)
    om[0, 1:] = sigma_a  # geist2008 eq. (5): absorption into the rest direction
    om[1:, 0] = WEIGHTS[1:]  # geist2008 eqs. (6)-(7): 1/12 axial, 1/24 non-axial
    om[1:, 1:] = sigma_s * hg_weights(g)  # geist2008 eqs. (6)-(9): sigma_s pn_ij / 12 or / 24
    om[np.arange(1, 19), np.arange(1, 19)] -= sigma_t  # geist2008 eqs. (6)-(7): -sigma_t on the diagonal
    return rho * om  # geist2008 sec. 2.2: entries multiplied by the node density


def omega_isotropic(rho: float, sigma_a: float, sigma_s: float) -> np.ndarray:
    """geist2008 eqs. (5)-(7) written out literally (isotropic scattering), times rho."""
    sigma_t = sigma_a + sigma_s
    om = np.zeros((19, 19))
    om[0, 0] = -1.0
    om[0, 1:] = sigma_a
    for i in range(1, 19):
        den = 12.0 if i <= 6 else 24.0
        om[i, 0] = 1.0 / den
        for j in range(1, 19):
            om[i, j] = sigma_s / den - (sigma_t if i == j else 0.0)
    return rho * om


def unit_moving_block(medium: Medium, lattice: str = "ordinates") -> np.ndarray:
    """(C, 18, 18) float64: the moving block A of the collision for each channel of ``medium``.

    ``f_post_i = f_i + sum_j A_ij rho_j f_j`` over the moving directions, with rho_j =
    ``step_density(rho, lattice)``, is geist2008 eq. (2)'s collision followed by the removal of
    f_0 (geist2008 sec. 3). ``geist2008``: A = Omega[1:, 1:] at rho = 1 (eqs. (5)-(9), with
    ``medium.phase``), and rho_j = rho. ``ordinates``: A_ij = sigma_s P_ij |c_i| / |c_j| -
    sigma_t delta_ij with the ordinate weights (module docstring).
    """
    _check_lattice(lattice)
    out = []
    for a, s, g in zip(medium.sigma_a, medium.sigma_s, medium.g):
        P = phase_weights(g, medium.phase, lattice)
        if lattice == "ordinates":
            L = STEP_LENGTHS[1:]
            P = P * (L[:, None] / L[None, :])  # power a_j taken from beam j, handed to beam i as power a_i
        out.append(s * P - (a + s) * np.eye(18))
    return np.stack(out)

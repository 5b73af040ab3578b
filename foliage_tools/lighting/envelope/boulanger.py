"""Boulanger's tree lighting: direct sky, direct sun and one-bounce sun light per leaf.

boulanger2008 (thesis, ch. 5) lights every leaf P of a tree from the 8
distances s_max(P, ω_j) to the crown envelope (:mod:`foliage_tools.lighting.envelope`)
and the tree's optical thickness τ, assuming leaves of uniformly distributed
position and orientation inside the envelope:

* sky and ground, attenuated toward each ω_j (eqs. (5.6), (5.29), (5.30));
* the sun, attenuated along the interpolated envelope distance s̃_max(P, ω_l)
  (eqs. (5.7), (5.8)), which is continuous in the sun direction ω_l;
* light of the sun scattered once by the neighbouring leaves (eqs. (5.11),
  (5.18), (5.24)-(5.26), (5.33)), with the averages over leaf orientation of
  Appendix B (eqs. (B.5), (B.6)).

Two departures from the thesis, each an option of :func:`solve` (the paper's
model is the default there; ``foliage smax`` uses both, ``--scatter paper``
the thesis alone): the sun at the scatterers from the leaves' exact lit
fractions instead of eq. (5.24)'s linear envelope
(:mod:`foliage_tools.lighting.envelope.scatterer_sun`, which measures why), and the
light scattered more than once (:func:`higher_orders`), which the thesis
leaves out.

The thesis returns outgoing radiance; here every term is returned as the
**irradiance** on the leaf's two faces, which is what the project compares
across methods (DESIGN.md sec. 3): the radiance leaving a face follows from
:func:`outgoing_radiance` (eq. (5.4)). Equation (5.3) reads
L_o = Σ_j ∫_{Ω_j} F L dω with F = (ρ/π) M(N·ω) on the front side, so the
front-face irradiance of a term is the same sum with ρ/π dropped:
E_front = Σ_j ∫_{Ω_j} M(N·ω) L dω, and E_back uses M(-N·ω).

The sun delivers ``sun_irradiance`` on a plane perpendicular to it; ``sun_direction``
points *toward* the sun. Sky radiance is in the same units per steradian.
The lighting depends on s_max and τ only through τ s_max (with A ρ = 2 τ from
eq. (5.5) in G1), so it is the same for any split of the two.

Pure numpy; no USD, no files, no printing.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from foliage_tools.lighting.envelope import (
    BIN_SOLID_ANGLE,
    N_DIRECTIONS,
    sample_directions,
    sample_frame,
)

__all__ = [
    "BoulangerParams",
    "LightingResult",
    "av_r",
    "av_t",
    "direction_weights",
    "g1",
    "g2",
    "g3",
    "interpolated_smax",
    "outgoing_radiance",
    "higher_orders",
    "recollision_probability",
    "relative_expm1",
    "sky_irradiance",
    "sky_radiance_per_direction",
    "solve",
    "sun_direct_irradiance",
    "sun_indirect_irradiance",
]


# --------------------------------------------------------------------------
# Parameters and result
# --------------------------------------------------------------------------


def _rgb(value, name: str, *, allow_none: bool = False) -> tuple[float, float, float] | None:
    if value is None:
        if allow_none:
            return None
        raise ValueError(f"{name} is required")
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,):
        raise ValueError(f"{name} must be a number or an RGB triple, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must be finite and >= 0, got {arr.tolist()}")
    return cast("tuple[float, float, float]", tuple(float(v) for v in arr))  # shape (3,), checked above


@dataclass(frozen=True)
class BoulangerParams:
    """Light and leaf material of :func:`solve` (boulanger2008 sec. 5.2.2-5.2.3)."""

    sun_direction: tuple[float, float, float]
    """Unit-free 3-vector pointing from the tree toward the sun (normalised here)."""
    reflectance: tuple[float, float, float]
    """ρ_rf: RGB fraction of the light reaching the front face that is reflected (Lambertian)."""
    transmittance: tuple[float, float, float]
    """ρ_tf: RGB fraction of the light reaching the front face that leaves the back face."""
    reflectance_back: tuple[float, float, float] | None = None
    """ρ_rb for light reaching the back face; ``None``: same as ``reflectance``."""
    transmittance_back: tuple[float, float, float] | None = None
    """ρ_tb for light reaching the back face; ``None``: same as ``transmittance``."""
    sun_irradiance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB irradiance of the sun on a plane perpendicular to it (DESIGN.md: 1)."""
    sky_radiance: tuple = (0.0, 0.0, 0.0)
    """Sky radiance (same units as ``sun_irradiance`` per steradian): an RGB triple for a
    uniform sky (the ground below reflects it, see ``ground_reflectance``), or 8 RGB
    triples, the mean radiance over the bin of each ω_j (eq. (5.29)), used as given."""
    ground_reflectance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """RGB albedo of the ground; with a uniform ``sky_radiance`` L the directions below
    the horizon see ground_reflectance × L (eq. (5.29)). Must be 0 when 8 triples are given."""

    def __post_init__(self) -> None:
        sun = np.asarray(self.sun_direction, dtype=float)
        if sun.shape != (3,) or not np.all(np.isfinite(sun)) or not np.any(sun != 0):
            raise ValueError(f"sun_direction must be a finite non-zero 3-vector, got {self.sun_direction!r}")
        object.__setattr__(self, "sun_direction", tuple(float(v) for v in sun / np.linalg.norm(sun)))
        for name in ("reflectance", "transmittance", "sun_irradiance", "ground_reflectance"):
            object.__setattr__(self, name, _rgb(getattr(self, name), name))
        for name in ("reflectance_back", "transmittance_back"):
            object.__setattr__(self, name, _rgb(getattr(self, name), name, allow_none=True))
        for rname, tname in (("reflectance", "transmittance"), ("reflectance_back", "transmittance_back")):
            r = np.asarray(getattr(self, rname) or self.reflectance)
            t = np.asarray(getattr(self, tname) or self.transmittance)
            if np.any(r + t > 1.0 + 1e-12):
                raise ValueError(
                    f"{rname} + {tname} must not exceed 1 in any channel (a leaf cannot scatter more "
                    f"than it receives), got {(r + t).tolist()}"
                )
        if max(self.ground_reflectance) > 1.0:
            raise ValueError(f"ground_reflectance must be <= 1, got {list(self.ground_reflectance)}")
        sky = np.asarray(self.sky_radiance, dtype=float)
        if sky.shape == (3,) or sky.ndim == 0:
            object.__setattr__(self, "sky_radiance", _rgb(sky, "sky_radiance"))
        elif sky.shape == (N_DIRECTIONS, 3):
            if not np.all(np.isfinite(sky)) or np.any(sky < 0):
                raise ValueError("sky_radiance must be finite and >= 0")
            if any(self.ground_reflectance):
                raise ValueError(
                    "ground_reflectance cannot be combined with a per-direction sky_radiance "
                    "(give the ground's radiance in the lower directions instead)"
                )
            object.__setattr__(self, "sky_radiance", tuple(tuple(float(v) for v in row) for row in sky))
        else:
            raise ValueError(f"sky_radiance must be an RGB triple or 8 of them, got shape {sky.shape}")

    @property
    def optics(self) -> np.ndarray:
        """(4, 3) rows ρ_rf, ρ_tf, ρ_rb, ρ_tb."""
        rb = self.reflectance_back if self.reflectance_back is not None else self.reflectance
        tb = self.transmittance_back if self.transmittance_back is not None else self.transmittance
        return np.array([self.reflectance, self.transmittance, rb, tb], dtype=float)


@dataclass(frozen=True)
class LightingResult:
    """Per-leaf irradiance (both faces summed unless named ``*_front``), (L, 3) float32 RGB."""

    e_direct: np.ndarray
    """Unscattered sun irradiance, both faces (only the lit face receives it)."""
    e_scattered: np.ndarray
    """Sun light scattered by neighbouring leaves: once (the paper's only scattered term), or every order with
    ``solve(..., all_orders=True)``."""
    e_sky: np.ndarray
    """Direct sky and ground light. Not part of ``e_scattered``: the project's
    comparisons (DESIGN.md sec. 3) light the tree by the sun alone."""
    e_direct_front: np.ndarray
    """Front-face part of ``e_direct`` (the back face gets the rest)."""
    e_scattered_front: np.ndarray
    """Front-face part of ``e_scattered``."""
    e_sky_front: np.ndarray
    """Front-face part of ``e_sky``."""
    seconds: float
    """Wall time of :func:`solve`."""
    stats: dict = field(default_factory=dict)
    """``leaves``, ``sun_smax_mean`` (mean s̃_max toward the sun), ``g3_min``, ``recollision_probability`` (the
    p of :func:`higher_orders` with ``all_orders``; None without, where no p enters the result), ``scatterer_sun``
    (``envelope``: eq. (5.24); ``leaves``: the lit fractions), ``all_orders``."""


# --------------------------------------------------------------------------
# The equations
# --------------------------------------------------------------------------


def relative_expm1(x) -> np.ndarray:
    """(1 - exp(-x)) / x, equal to 1 at x = 0 and accurate for |x| -> 0 (uses expm1)."""
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-8
    safe = np.where(small, 1.0, x)
    # 1 - x/2 + x²/6 is exact to double precision below 1e-8
    return np.where(small, 1.0 - 0.5 * x, -np.expm1(-safe) / safe)


def av_t(alpha) -> np.ndarray:
    """Mean over uniform normals N of M(N·a) M(N·b), a and b at angle α: eq. (B.5), α ∈ [0, π].

    boulanger2008 eq. (B.5): (1/(6π)) ((π - α) cos α + sin α). "Transmission"
    average: light arriving on one face and seen from the other side.
    """
    a = np.clip(np.asarray(alpha, dtype=float), 0.0, math.pi)
    return ((math.pi - a) * np.cos(a) + np.sin(a)) / (6.0 * math.pi)


def av_r(alpha) -> np.ndarray:
    """eq. (B.6): (1/(6π)) (sin α - α cos α) = Av_t(π - α), the "reflection" average."""
    a = np.clip(np.asarray(alpha, dtype=float), 0.0, math.pi)
    return (np.sin(a) - a * np.cos(a)) / (6.0 * math.pi)


def direction_weights(light_dir, directions) -> np.ndarray:
    """M(ω_l · ω_j) for the 8 sample directions (eq. (5.31)); for eq. (5.28) their sum is >= 4/√6."""
    return np.maximum(np.asarray(directions) @ np.asarray(light_dir, dtype=float), 0.0)


def interpolated_smax(smax, light_dir, directions) -> np.ndarray:
    """s̃_max(P, ω_l) of eq. (5.7): the cosine-lobe blend of the 8 s_max toward ω_l.

    Parameters
    ----------
    smax : (L, 8) float, stage units
    light_dir : (3,) unit vector
    directions : (8, 3) sample directions

    Returns (L,) float64, continuous in ``light_dir`` (the reason for eq. (5.7)).
    """
    wgt = direction_weights(light_dir, directions)
    # for the cube diagonals of eq. (5.28) the weights sum to >= 4/√6 (sun midway
    # between two ω_j): never a division by zero
    return np.asarray(smax, dtype=float) @ wgt / wgt.sum()


def g1(alpha, rho_bar, rho_t, leaf_density, n_dir: int = N_DIRECTIONS) -> np.ndarray:
    """G1(j, ω_l) of eq. (5.18): 2ρ [ρ̄ (sin α - α cos α) + π (ρ_tf + ρ_tb) cos α] / (3π N_dir).

    Written as (4 ρ / N_dir)(ρ_r Av_r + ρ_t Av_t) -- eq. (5.16) divided by s_i² Δs_j,
    equal to eq. (5.18) by eqs. (B.5)-(B.6) -- where ρ_r = ρ̄ - ρ_t; both terms
    are >= 0 on [0, π].

    Parameters
    ----------
    alpha : angle(s) between ω_j and ω_l, radians
    rho_bar : ρ_rf + ρ_rb + ρ_tf + ρ_tb (eq. (5.19)), scalar or per channel
    rho_t : ρ_tf + ρ_tb
    leaf_density : number of leaves per unit volume ρ (1/stage unit³)
    """
    rho_t = np.asarray(rho_t, dtype=float)
    rho_r = np.asarray(rho_bar, dtype=float) - rho_t
    return 4.0 * leaf_density / n_dir * (rho_r * av_r(alpha) + rho_t * av_t(alpha))


def g2(light_dir, directions, tau: float) -> float:
    """G2(ω_l) = τ / Σ_j' M(ω_l · ω_j') of eq. (5.25)."""
    return float(tau) / float(direction_weights(light_dir, directions).sum())


def g3(light_dir, directions, tau: float) -> np.ndarray:
    """G3(j, ω_l) of eq. (5.26), (8,): τ [1 - Σ_j' M(ω_l·ω_j')(ω_j·ω_j') / Σ_j' M(ω_l·ω_j')].

    The bracket is 1 minus a weighted mean of cosines, so G3 ∈ [0, 2τ]; for the
    cube diagonals it lies in [τ/3, 5τ/3] (G3 -> 0 only as τ -> 0).
    """
    dirs = np.asarray(directions, dtype=float)
    wgt = direction_weights(light_dir, dirs)
    return float(tau) * (1.0 - (dirs @ dirs.T) @ wgt / wgt.sum())


def sky_radiance_per_direction(sky_radiance, ground_reflectance, directions, up) -> np.ndarray:
    """(8, 3) radiance L_sky(ω_j) of eq. (5.29) for a uniform sky.

    Directions above the horizon see the sky; those below see the ground,
    whose radiance is ground_reflectance × L_sky (a Lambertian ground lit by a
    uniform sky of radiance L receives π L and sends back ρ_g L per steradian).
    """
    sky = np.broadcast_to(np.asarray(sky_radiance, dtype=float), (3,))
    ground = np.broadcast_to(np.asarray(ground_reflectance, dtype=float), (3,))
    above = (np.asarray(directions) @ np.asarray(up, dtype=float)) > 0.0
    return np.where(above[:, None], sky[None, :], (ground * sky)[None, :])


def sky_irradiance(normals, attenuation, radiance, directions) -> tuple[np.ndarray, np.ndarray]:
    """Direct sky/ground irradiance of the front and back faces, eq. (5.6) without F.

    E_front = (4π/N_dir) Σ_j M(N·ω_j) e^{-τ s_max(P, ω_j)} L_sky(ω_j); back: M(-N·ω_j).

    Parameters
    ----------
    normals : (L, 3); attenuation : (L, 8) = exp(-τ s_max) (eq. (5.30));
    radiance : (8, 3) L_sky(ω_j); directions : (8, 3)

    Returns two (L, 3) arrays.
    """
    cos = np.asarray(normals, dtype=float) @ np.asarray(directions, dtype=float).T
    incoming = np.asarray(attenuation, dtype=float)[:, :, None] * np.asarray(radiance, dtype=float)[None]
    front = BIN_SOLID_ANGLE * np.einsum("lj,ljc->lc", np.maximum(cos, 0.0), incoming)
    back = BIN_SOLID_ANGLE * np.einsum("lj,ljc->lc", np.maximum(-cos, 0.0), incoming)
    return front, back


def sun_direct_irradiance(normals, smax, tau, light_dir, directions) -> tuple[np.ndarray, np.ndarray]:
    """Unit-sun direct irradiance of the front and back faces, eq. (5.8) without F.

    E_front = M(N·ω_l) e^{-τ s̃_max(P, ω_l)}, E_back = M(-N·ω_l), s̃_max of eq. (5.7).
    Returns two (L,) arrays (multiply by the sun's irradiance).
    """
    att = np.exp(-float(tau) * interpolated_smax(smax, light_dir, directions))
    cos = np.asarray(normals, dtype=float) @ np.asarray(light_dir, dtype=float)
    return np.maximum(cos, 0.0) * att, np.maximum(-cos, 0.0) * att


def sun_indirect_irradiance(normals, smax, tau, light_dir, optics, directions, *,
                            scatterer_sun=None) -> tuple[np.ndarray, np.ndarray]:
    """Unit-sun irradiance of the front and back faces from one bounce on neighbour leaves.

    eq. (5.11) gives E_front = A Σ_j M(N·ω_j) L_o_sample(P, j) (back: M(-N·ω_j)),
    with L_o_sample = G1 I(P, j) (eq. (5.21)) and I of eq. (5.20). The paper's
    linear envelope (eqs. (5.22)-(5.23)) gives eq. (5.24):

        L_o_sample = G1 E_sun exp(-G2 Σ_j' M(ω_l·ω_j') s_max(P, ω_j')) (1 - exp(-G3 s_j)) / G3
                   = G1 E_sun exp(-τ s̃_max(P, ω_l)) s_j φ(G3 s_j),   φ(x) = (1 - e^{-x})/x,

    the second form (:func:`relative_expm1`) staying finite as G3 -> 0 (-> G1 s_j).
    The thesis precomputes G1/G3 per tree (eq. (5.33)); keeping G1 and
    s φ(G3 s) apart is the same product without the 0/0. A G1 uses A ρ = 2 τ
    (eq. (5.5)), so only τ enters.

    With ``scatterer_sun`` (T̄_j of :mod:`foliage_tools.lighting.envelope.scatterer_sun`,
    the sun's transmission at the scatterers of each octant from the leaves'
    exact lit fractions) eq. (5.20) is evaluated as I = T̄_j E_sun s_j φ(τ s_j)
    instead: no linear envelope, no eq. (5.7) attenuation.

    Parameters
    ----------
    normals : (L, 3); smax : (L, 8); tau : float; light_dir : (3,) toward the sun;
    optics : (4, 3) rows ρ_rf, ρ_tf, ρ_rb, ρ_tb; directions : (8, 3);
    scatterer_sun : (L, 8) in [0, 1] or None (the paper's eq. (5.24))

    Returns two (L, 3) arrays (multiply by the sun's irradiance).
    """
    dirs = np.asarray(directions, dtype=float)
    smax = np.asarray(smax, dtype=float)
    optics = np.asarray(optics, dtype=float)
    tau = float(tau)
    alpha = np.arccos(np.clip(dirs @ np.asarray(light_dir, dtype=float), -1.0, 1.0))
    rho_t = optics[1] + optics[3]
    rho_bar = optics.sum(axis=0)
    # A G1 = (A ρ) G1 / ρ with A ρ = 2 τ: (8, 3)
    area_g1 = 2.0 * tau * g1(alpha[:, None], rho_bar[None, :], rho_t[None, :], 1.0)
    if scatterer_sun is None:
        # eq. (5.24) times exp(-τ s̃_max) common to all j: (L, 8)
        sun_att = np.exp(-tau * interpolated_smax(smax, light_dir, dirs))
        path = sun_att[:, None] * smax * relative_expm1(g3(light_dir, dirs, tau)[None, :] * smax)
    else:
        t_bar = np.asarray(scatterer_sun, dtype=float)
        if t_bar.shape != smax.shape or not np.all(np.isfinite(t_bar)) or np.any((t_bar < 0) | (t_bar > 1)):
            raise ValueError(f"scatterer_sun must be {smax.shape} values in [0, 1]")
        path = t_bar * smax * relative_expm1(tau * smax)  # eq. (5.20) with the scatterers' own sun
    sample = path[:, :, None] * area_g1[None, :, :]  # A L_o_sample: (L, 8, 3)
    cos = np.asarray(normals, dtype=float) @ dirs.T
    front = np.einsum("lj,ljc->lc", np.maximum(cos, 0.0), sample)
    back = np.einsum("lj,ljc->lc", np.maximum(-cos, 0.0), sample)
    return front, back


def recollision_probability(attenuation) -> float:
    """p: the chance that light a leaf scatters meets another leaf, 1 - the mean over leaves and octants of
    eq. (5.30)'s exp(-τ s_max) (a uniformly random direction of octant j escapes with that probability)."""
    att = np.asarray(attenuation, dtype=float)
    return float(1.0 - att.mean()) if att.size else 0.0


def higher_orders(albedo, p: float) -> np.ndarray:
    """1 / (1 - ω p): the scattered light of every order over the first (beyond boulanger2008, which stops at one).

    Light scattered k times is intercepted again with probability p and re-scattered with the leaf albedo ω;
    if every order is spread over the crown like the one before (the "spectral invariant" of canopy
    radiative transfer, reviewed by Wang et al. 2018, Remote Sens. 10(11), 1805), order k+1 receives ω p of
    order k, so all orders together receive Σ_k (ω p)^k = 1/(1 - ω p) times the first. Finite for ω p < 1,
    which holds for any leaf (ω <= 1) of a crown that lets some light out (p < 1).
    """
    w = np.clip(np.asarray(albedo, dtype=float), 0.0, 1.0)
    return 1.0 / (1.0 - w * min(max(float(p), 0.0), 1.0 - 1e-9))


def outgoing_radiance(front_irradiance, back_irradiance, optics) -> tuple[np.ndarray, np.ndarray]:
    """Radiance leaving the front and back sides of two-sided Lambertian leaves, eq. (5.4).

    L_front = (ρ_rf E_front + ρ_tb E_back) / π, L_back = (ρ_rb E_back + ρ_tf E_front) / π.
    With ρ_r + ρ_t <= 1 per face, π (L_front + L_back) <= E_front + E_back.
    """
    rf, tf, rb, tb = np.asarray(optics, dtype=float)
    ef = np.asarray(front_irradiance, dtype=float)
    eb = np.asarray(back_irradiance, dtype=float)
    return (rf * ef + tb * eb) / math.pi, (rb * eb + tf * ef) / math.pi


# --------------------------------------------------------------------------
# Everything for one tree
# --------------------------------------------------------------------------


def solve(normals, smax, tau, *, up=(0.0, 0.0, 1.0), params: BoulangerParams, scatterer_sun=None,
          all_orders: bool = False) -> LightingResult:
    """Per-leaf direct, scattered and sky irradiance of one tree (boulanger2008 sec. 5.3-5.4).

    The paper's model with the defaults; ``scatterer_sun`` (:mod:`foliage_tools.lighting.envelope.scatterer_sun`) takes
    the sun at the scatterers from the leaves' exact lit fractions (:func:`sun_indirect_irradiance`) and
    ``all_orders`` scales the one-bounce light by :func:`higher_orders` for the light scattered more than once.

    Parameters
    ----------
    normals : (L, 3) float
        Unit leaf normals; N_P is the front face.
    smax : (L, 8) float, stage units
        s_max(P, ω_j) in the order of :func:`~foliage_tools.lighting.envelope.sample_directions`.
    tau : float >= 0, 1/stage unit
        Optical thickness of the tree.
    up : (3,) float
        The stage's up axis (must be the one s_max was computed with).
    params : BoulangerParams

    Returns
    -------
    LightingResult
        (L, 3) float32 arrays, finite and >= 0.
    """
    t0 = time.perf_counter()
    n = np.asarray(normals, dtype=float)
    s = np.asarray(smax, dtype=float)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"normals must have shape (L, 3), got {n.shape}")
    if s.shape != (n.shape[0], N_DIRECTIONS):
        raise ValueError(f"smax must have shape ({n.shape[0]}, {N_DIRECTIONS}), got {s.shape}")
    if not (np.all(np.isfinite(n)) and np.all(np.isfinite(s))) or np.any(s < 0):
        raise ValueError("normals and smax must be finite, smax >= 0")
    if not (math.isfinite(tau) and tau >= 0):
        raise ValueError(f"tau must be finite and >= 0, got {tau}")
    norm = np.linalg.norm(n, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        raise ValueError("normals must be unit vectors")
    n = n / norm[:, None]
    dirs = sample_directions(up)
    sun = np.asarray(params.sun_direction)
    sun_rgb = np.asarray(params.sun_irradiance)
    optics = params.optics

    d_front, d_back = sun_direct_irradiance(n, s, tau, sun, dirs)
    s_front, s_back = sun_indirect_irradiance(n, s, tau, sun, optics, dirs, scatterer_sun=scatterer_sun)
    attenuation = np.exp(-tau * s)  # eq. (5.30), for the recollision probability and the sky
    # p serves the higher orders only: the thesis' one bounce (all_orders False) has none, so it reports none
    p_recollide = recollision_probability(attenuation) if all_orders else None
    if all_orders:  # ω = ρ̄ / 2, the albedo of a face averaged over the two (eq. (5.19))
        assert p_recollide is not None  # computed just above when all_orders
        orders = higher_orders(optics.sum(axis=0) / 2.0, p_recollide)
        s_front, s_back = s_front * orders, s_back * orders
    sky = np.asarray(params.sky_radiance, dtype=float)
    if sky.ndim == 1:
        sky = sky_radiance_per_direction(sky, params.ground_reflectance, dirs, sample_frame(up)[1])
    k_front, k_back = sky_irradiance(n, attenuation, sky, dirs)

    f32 = np.float32
    return LightingResult(
        e_direct=((d_front + d_back)[:, None] * sun_rgb).astype(f32),
        e_scattered=((s_front + s_back) * sun_rgb).astype(f32),
        e_sky=(k_front + k_back).astype(f32),
        e_direct_front=(d_front[:, None] * sun_rgb).astype(f32),
        e_scattered_front=(s_front * sun_rgb).astype(f32),
        e_sky_front=k_front.astype(f32),
        seconds=time.perf_counter() - t0,
        stats={
            "leaves": int(n.shape[0]),
            "sun_smax_mean": float(interpolated_smax(s, sun, dirs).mean()) if n.shape[0] else 0.0,
            "g3_min": float(g3(sun, dirs, tau).min()),
            "recollision_probability": p_recollide,
            "scatterer_sun": "leaves" if scatterer_sun is not None else "envelope",
            "all_orders": bool(all_orders),
        },
    )

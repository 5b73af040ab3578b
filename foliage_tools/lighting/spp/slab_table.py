"""Exact plane-parallel scattered light per leaf, tabulated in slab thickness ("exact PP", issue #15).

Why this exists
---------------
The SPP closed form (:mod:`~foliage_tools.lighting.spp`, shinya2013 eqs. (8)-(22))
replaces the direction cosine of *every diffuse ray* by ±μ0 (eq. (8)). The
diffuse field then streams along the sun's cosine: for a high sun (μ0 -> 1)
it crosses the slab almost vertically, so per unit depth it travels a path
μ0⁻¹ instead of the ~2 of a nearly isotropic field. The scalar (actinic) flux
∫ I dΩ is the path length of light per unit volume, so it comes out ~2μ0 too
small, and so does every leaf's scattered irradiance (for uniform leaf
normals the mean over leaves is half the actinic flux). Nothing is lost in
the conversion to leaf irradiance ((a + b)/2 is exact for hemispherically
uniform radiance, :attr:`~foliage_tools.lighting.spp.SPPField.leaf_irradiance`)
nor in T, R or the 1/4π normalisation: SPP's *hemispherical fluxes*
μ0 a, μ0 b are about right (energy balance), its actinic flux is not.
Measured against the exact solver (τ = 1.5, r = t = 0.45, elevation 60°,
five depth bins): -52, -52, -50, -47, -40 %; at elevation 85°: -57 .. -48 %;
at 30° (μ0 = 1/2, where 2μ0 = 1) only -18 .. 0 %. That is the model, not a
coefficient: reading the SPP solution as fluxes instead (E = μ0 (a + b))
gives -17 .. +4 % at 60° for r = t = 0.45 but +8 .. +57 % for r = t = 0.1, and
the paper's own Table 1 metric hides the error (:mod:`~foliage_tools.lighting.spp`,
"Accuracy"; tests/unit/test_spp.py::test_spp_loses_the_scattered_light_of_a_high_sun).

The model here
--------------
The exact discrete-ordinate solution of the same slab
(:mod:`~foliage_tools.lighting.plane_parallel`, the project's solver: the
same eigen-decomposition, ``plane_parallel._eigen``, and the same particular
solution and boundary conditions, black floor, no sky) is solved once per
(single-scattering albedo, phase function, incidence cosine μ0) for a
geometric ladder of slab thicknesses τ_j (:data:`TAU_MIN` .. :data:`TAU_MAX`,
ratio :data:`TAU_RATIO`, plus τ = inf), all thicknesses in one batched linear
solve, and cached (:func:`slab_table`). For one leaf at vertical optical
depth t in a slab of vertical optical thickness τ (t = μ0 u, τ = μ0 U for the
slant depth u and thickness U along the light, shinya2013 eq. (29)), the
azimuthally averaged (Fourier order 0) diffuse radiance I0(t, ±μ_i) at the
quadrature nodes is evaluated *exactly in t* (a sum of exponentials) at the
two ladder thicknesses that bracket τ, and the leaf irradiance

    E(ν) = 2π Σ_i w_i [I0(t, μ_i) + I0(t, -μ_i)] K(μ_i, ν),
    K(μ, ν) = (1/2π) ∫_0^{2π} |μν + sqrt(1-μ²) sqrt(1-ν²) cos φ| dφ
            = μν                                      if μν >= sqrt(1-μ²) sqrt(1-ν²),
            = (2/π) (μν arcsin(μν/β) + sqrt(β² - μ²ν²)),  β = sqrt(1-μ²) sqrt(1-ν²), otherwise,

(ν = |cos| of the leaf normal to the slab normal; both faces summed; the
kernel is the azimuthal mean of |n · s|) is interpolated between them:

* t <= τ/2: at the same distance t from the lit face, linearly in τ (the
  dependence on the far face is smooth and saturates; for thin slabs the
  field is linear in τ);
* t > τ/2: at the same distance τ - t from the far face, log-linearly in τ
  (the field there decays like exp(-k τ) with the slab).

With the ladder ratio 1.1 the interpolation error is <= 3e-3 relative
(measured on random (t, τ) for albedos 0.2-1 and μ0 0.05-1; bound asserted in
tests/unit/test_spp.py). Below :data:`TAU_MIN` the field is scaled linearly
in τ at the same relative depth t/τ (single scattering of a slab much thinner
than the smallest stream cosine); above :data:`TAU_MAX` (far thicker than any
crown or forest) the semi-infinite solution is used at depth t.

What is left out: the azimuthal (Fourier order >= 1) part of the diffuse
radiance, i.e. how a tilted leaf's irradiance depends on its azimuth relative
to the sun. It is zero for horizontal leaves and for the mean over any
azimuthally uniform set of leaves (so E averaged over uniform normals is
exactly actinic/2), and measured at most 2-6 % for single leaves with r ≈ t,
up to 14 % for transmission-dominated leaves (r = 0.05, t = 0.45) tilted 45°
toward or away from a sun at 30°. SPP leaves out all orientation dependence
(horizontal vs vertical leaves differ by ~40 % at 30°).

Cost: a table is one batched solve of ~240 systems of 2N x 2N (10-30 ms
with N = 8-16; the eigen-decomposition is cached per albedo and phase
function); a leaf costs ~2 exponentials per stream and ladder slab. The
per-leaf default of :func:`~foliage_tools.lighting.gfactor.solve_sppg` (sun +
8 sky directions, 3 channels: 27 tables, N = 8) takes ~1 s for 30 000 leaves
on the 2-core test machine, against ~0.4 s for the SPP closed form.

Pure numpy + numba; no files, no printing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from foliage_tools.lighting.phase import PhaseFunction
from foliage_tools.lighting.plane_parallel import (
    _eigen,
    _norm_assoc_legendre,
    _Setup,
    resonance_offsets,
)

__all__ = [
    "DEFAULT_STREAMS",
    "TAU_MAX",
    "TAU_MIN",
    "TAU_RATIO",
    "SlabTable",
    "leaf_kernel",
    "leaf_weights",
    "slab_table",
]

#: Streams per hemisphere of the tabulated solutions (plane_parallel's default; fluxes to ~1e-8;
#: ``gfactor.solve_sppg`` uses ``gfactor.EXACT_STREAMS``).
DEFAULT_STREAMS = 16
#: Thinnest and thickest tabulated slab (vertical optical thickness) and the ladder ratio.
TAU_MIN = 1e-6
TAU_MAX = 1e4
TAU_RATIO = 1.1
#: Tables kept by :func:`slab_table` (one per albedo, phase function, μ0 and stream count).
CACHE_SIZE = 256


def _ladder() -> np.ndarray:
    n = int(math.ceil(math.log(TAU_MAX / TAU_MIN) / math.log(TAU_RATIO) - 1e-9))
    return TAU_MIN * np.exp(np.linspace(0.0, math.log(TAU_MAX / TAU_MIN), n + 1))


_TAUS = _ladder()


def leaf_kernel(mu, nu) -> np.ndarray:
    """K(μ, ν): azimuthal mean of |n · s| for cos(s, up) = ±μ and |cos(n, up)| = ν (module docstring).

    K(μ, 1) = μ (horizontal leaf: the hemispherical flux), ∫_0^1 K(μ, ν) dν = 1/2
    for every μ (mean over uniform normals: half the scalar flux).
    """
    mu = np.abs(np.asarray(mu, dtype=np.float64))
    nu = np.abs(np.asarray(nu, dtype=np.float64))
    a = mu * nu
    b = np.sqrt(np.maximum(0.0, 1.0 - mu * mu)) * np.sqrt(np.maximum(0.0, 1.0 - nu * nu))
    inside = a < b
    bs = np.where(inside, b, 1.0)
    ratio = np.clip(np.where(inside, a / bs, 0.0), -1.0, 1.0)
    mixed = (2.0 / math.pi) * (a * np.arcsin(ratio) + np.sqrt(np.maximum(0.0, bs * bs - a * a)))
    return np.where(inside, mixed, a)


def leaf_weights(leaf_cosine, n_streams: int = DEFAULT_STREAMS) -> np.ndarray:
    """K(μ_i, ν) at the double-Gauss nodes μ_i of ``n_streams`` per hemisphere: shape (L, N).

    ``leaf_cosine`` (L,): ν = |cos| of each leaf normal to the slab normal.
    """
    nu = np.asarray(leaf_cosine, dtype=np.float64).ravel()
    if np.any(np.isnan(nu)) or np.any(np.abs(nu) > 1.0):
        raise ValueError("leaf_cosine must be in [-1, 1]")
    x, _ = np.polynomial.legendre.leggauss(int(n_streams))
    return leaf_kernel(0.5 * (x + 1.0)[None, :], nu[:, None])


@dataclass(frozen=True, eq=False)
class _Part:
    """Solution for one incidence cosine (several only at a resonance, see :func:`slab_table`)."""

    weight: float
    mu0: float
    zsum: np.ndarray  # (N,) Z+ + Z- of the particular solution Z exp(-t/μ0)
    a: np.ndarray  # (M, N) coefficients of exp(-k t) (or c1 of the (C, D) basis, _solve_ladder)
    b: np.ndarray  # (M, N) coefficients of exp(-k (τ - t)) (or c2)
    a_inf: np.ndarray  # (N,) semi-infinite slab: coefficients of exp(-k t)


@dataclass(frozen=True, eq=False)
class SlabTable:
    """Exact diffuse field of one slab optics and incidence, tabulated in thickness (module docstring).

    Build with :func:`slab_table`; evaluate with :meth:`leaf_irradiance`,
    :meth:`actinic_diffuse` or :meth:`flux_sum`. All values are per unit beam
    irradiance (irradiance 1 on a plane perpendicular to the beam).
    """

    omega: float
    mu0: float
    n_streams: int
    mu: np.ndarray  # (N,) double-Gauss nodes
    w: np.ndarray  # (N,) weights, sum 1
    k: np.ndarray  # (N,) eigenvalues of Fourier order 0
    x: np.ndarray  # (N, N) columns X_j: I+ + I- of mode j
    taus: np.ndarray  # (M,) the thickness ladder
    small: np.ndarray  # (M, N) modes solved in the (C, D) basis (k τ < 1)
    parts: tuple

    # -- evaluation ---------------------------------------------------------
    def _evaluate(self, depth, thickness, weights) -> np.ndarray:
        """Σ_i c_i(t, τ) weights_i, interpolated in τ (module docstring); weights (L, N).

        c_i = 2π w_i (I0(t, μ_i) + I0(t, -μ_i)). Per leaf: the ladder slab(s) and
        the depth in each (numpy), the exact field there (:func:`_node_values`),
        the interpolation (numpy).
        """
        t = depth
        tau = thickness
        taus = self.taus
        m = taus.size
        inf = np.isinf(tau)
        pos = (tau > 0.0) & ~np.isinf(t)
        thin = pos & (tau < taus[0])
        thick = pos & ~inf & (tau > taus[-1])
        # semi-infinite slab, and slabs thicker than the ladder (their far face is > TAU_MAX/2 away
        # from any point of the lit half; in the far half the light is below e^{-k TAU_MAX/2}, 0 in double
        # precision unless ω = 1 exactly): the semi-infinite solution (node m) at depth t.
        deep = (inf | thick) & pos
        mid = pos & ~deep & ~thin
        # inputs outside each branch replaced by harmless finite values (t = τ = inf gives no inf - inf)
        t_mid = np.where(mid, t, 0.0)
        tau_mid = np.where(mid, tau, taus[0])
        j = np.clip(np.searchsorted(taus, tau_mid, side="right") - 1, 0, m - 2)
        lo, hi = taus[j], taus[j + 1]
        f = np.clip((tau_mid - lo) / (hi - lo), 0.0, 1.0)
        t = np.where(pos, t, 0.0)
        below = tau_mid - t_mid
        top = t <= below
        t_lo = np.minimum(np.where(top, t, np.maximum(lo - below, 0.0)), lo)
        t_hi = np.minimum(np.where(top, t, np.maximum(hi - below, 0.0)), hi)
        # thinner than the ladder: linear in τ at the same relative depth (single scattering of a
        # slab thinner than the smallest stream cosine, which is > 100 TAU_MIN): node 0 at t τ_0/τ
        tau_thin = np.where(thin, tau, taus[0])
        thin_t = np.where(thin, t / tau_thin * taus[0], 0.0)
        node_a = np.where(deep, m, np.where(thin, 0, j)).astype(np.int64)
        t_a = np.where(deep, t, np.where(thin, thin_t, t_lo))
        node_b = np.where(mid, j + 1, node_a).astype(np.int64)
        t_b = np.where(mid, t_hi, t_a)
        ww = np.asarray(weights, dtype=np.float64) * ((2.0 * math.pi) * self.w)[None, :]
        vx = np.ascontiguousarray(ww @ self.x)
        out = np.zeros(t.shape)
        for part in self.parts:
            args = (taus, self.small, part.a, part.b, part.a_inf, self.k, part.mu0, vx, np.ascontiguousarray(ww @ part.zsum))
            v_a = np.empty(t.shape)
            v_b = np.empty(t.shape)
            _node_values(node_a, t_a, *args, v_a)
            _node_values(node_b, t_b, *args, v_b)
            lin = (1.0 - f) * v_a + f * v_b
            ok = (v_a > 0.0) & (v_b > 0.0)
            logv = np.exp((1.0 - f) * np.log(np.where(ok, v_a, 1.0)) + f * np.log(np.where(ok, v_b, 1.0)))
            res = np.where(mid & ~top & ok, logv, lin)
            res = np.where(thin, v_a * (tau_thin / taus[0]), res)
            out += part.weight * np.where(pos, res, 0.0)
        return np.maximum(out, 0.0)

    def _check(self, depth, thickness):
        t = np.asarray(depth, dtype=np.float64)
        tau = np.asarray(thickness, dtype=np.float64)
        t, tau = np.broadcast_arrays(t, tau)
        if np.any(np.isnan(t)) or np.any(np.isnan(tau)) or np.any(t < 0.0) or np.any(tau < 0.0):
            raise ValueError("depth and thickness (vertical optical depths) must be >= 0 (inf allowed)")
        if np.any(t > tau):
            raise ValueError("depth must not exceed thickness (vertical optical depths of the slab)")
        return t, tau

    def leaf_irradiance(self, depth, thickness, leaf_cosine=None, *, weights=None) -> np.ndarray:
        """Scattered irradiance on a leaf, both faces summed (DESIGN.md sec. 3's E_scattered).

        Parameters
        ----------
        depth, thickness : array_like
            Vertical optical depth t below the lit face and vertical optical
            thickness τ of the slab (0 <= t <= τ <= inf), broadcast together.
        leaf_cosine : array_like or None
            |cos| of the leaf normal to the slab normal (broadcast with depth);
            None: the mean over uniformly distributed normals (= actinic / 2).
        weights : array_like (L, N), optional
            ``leaf_weights(leaf_cosine, n_streams)`` computed beforehand (to
            evaluate many tables for the same leaves); replaces ``leaf_cosine``.
            L is the size of the broadcast depth.

        Returns
        -------
        numpy.ndarray
            E per unit beam irradiance, the Fourier-order-0 value (module docstring).
        """
        t, tau = self._check(depth, thickness)
        shape = t.shape
        t, tau = t.ravel(), tau.ravel()
        if weights is not None:
            wts = np.asarray(weights, dtype=np.float64)
            if wts.shape != (t.size, self.mu.size):
                raise ValueError(f"weights must have shape ({t.size}, {self.mu.size}), got {wts.shape}")
        elif leaf_cosine is None:
            wts = np.full((t.size, self.mu.size), 0.5)
        else:
            nu = np.broadcast_to(np.asarray(leaf_cosine, dtype=np.float64), shape).ravel()
            wts = leaf_weights(nu, self.n_streams)
        return self._evaluate(t, tau, wts).reshape(shape)

    def actinic_diffuse(self, depth, thickness) -> np.ndarray:
        """Diffuse scalar (actinic) flux ∫ I dΩ at depth t of a slab τ (solve_slab's actinic_flux_diffuse)."""
        t, tau = self._check(depth, thickness)
        shape = t.shape
        w = np.ones((t.size, self.mu.size))
        return self._evaluate(t.ravel(), tau.ravel(), w).reshape(shape)

    def flux_sum(self, depth, thickness) -> np.ndarray:
        """Downward + upward diffuse flux (the scattered irradiance of a horizontal leaf, both faces)."""
        t, tau = self._check(depth, thickness)
        shape = t.shape
        w = np.broadcast_to(self.mu[None, :], (t.size, self.mu.size))
        return self._evaluate(t.ravel(), tau.ravel(), w).reshape(shape)


@njit(cache=True)
def _node_values(node, t, taus, small, a, b, a_inf, k, mu0, vx, vz, out):
    """out[l] = Σ_i w2pi_i (I0(t_l, μ_i) + I0(t_l, -μ_i)) weights[l, i] in ladder slab node[l] (m: semi-infinite).

    I0 + I0 at the nodes = X g(t) + (Z+ + Z-) e^{-t/μ0} with g_j = a_j e^{-k_j t} + b_j e^{-k_j (τ - t)}
    (only decaying exponentials), or 2 a_j C_j + b_j D_j for modes in the (C, D) basis (k τ < 1,
    so |k (t - τ/2)| < 1/2: nothing overflows); see :func:`_solve_ladder`. The weights come
    contracted: vx[l] = (w2pi ⊙ weights[l]) X, vz[l] = (w2pi ⊙ weights[l]) · (Z+ + Z-).
    """
    m = taus.shape[0]
    n = k.shape[0]
    for p in range(node.shape[0]):
        jj = node[p]
        tt = t[p]
        acc = vz[p] * math.exp(-tt / mu0)
        if jj >= m:
            for q in range(n):
                acc += vx[p, q] * a_inf[q] * math.exp(-k[q] * tt)
        else:
            tau = taus[jj]
            far = max(tau - tt, 0.0)
            for q in range(n):
                kq = k[q]
                e1 = math.exp(-kq * tt)
                bq = b[jj, q]
                e2 = math.exp(-kq * far) if bq != 0.0 else 0.0
                if small[jj, q]:
                    s = tt - 0.5 * tau
                    ks = kq * s
                    shc = 1.0 if ks == 0.0 else math.sinh(ks) / ks
                    d = -2.0 * math.exp(-0.5 * kq * tau) * s * shc
                    g = a[jj, q] * (e1 + math.exp(-kq * far)) + bq * d
                else:
                    g = a[jj, q] * e1 + bq * e2
                acc += vx[p, q] * g
        out[p] = acc


def _particular(setup: _Setup, eig, mu0: float) -> np.ndarray:
    """Z of the beam's particular solution Z exp(-t/μ0), Fourier order 0 (as plane_parallel._ModeSolution)."""
    n = setup.n
    lam0 = _norm_assoc_legendre(0, 2 * n - 1, np.array(mu0))
    src = setup.omega / (4.0 * math.pi) * eig.coef * eig.parity * lam0
    q_plus = eig.lam.T @ src
    q_minus = eig.lam.T @ (src * eig.parity)
    if not (np.any(q_plus != 0.0) or np.any(q_minus != 0.0)):
        return np.zeros(2 * n)
    s = np.concatenate([-q_plus / setup.mu, q_minus / setup.mu])
    return np.linalg.solve(eig.a_sys + np.eye(2 * n) / mu0, -s)


def _solve_ladder(eig, n: int, z: np.ndarray, mu0: float, taus: np.ndarray, small: np.ndarray):
    """Boundary-value coefficients for every ladder slab at once (black floor, no diffuse light entering).

    Mode j of Fourier order 0 (plane_parallel._eigen): exp(-k t) (X ± kŶ)/2 on (I+, I-)
    and exp(-k (τ - t)) (X ∓ kŶ)/2; with S = (X, X), A = (Ŷ, -Ŷ) the pair is
    rewritten for k τ < 1 as c1 [S C + (k²/2) A D] + c2 [S D/2 + A C],
    C = (e^{-kt} + e^{-k(τ-t)})/2, D = (e^{-kt} - e^{-k(τ-t)})/k (-> τ - 2t),
    exactly as plane_parallel does, so ω = 1 (k = 0) is regular. Conditions:
    I-(0) = -Z- (no diffuse light enters the top), I+(τ) = -Z+ e^{-τ/μ0}.
    """
    k, xx, yy = eig.k, eig.x, eig.yhat
    s_vec = np.concatenate([xx, xx], axis=0)  # (2N, N): column j is S_j
    a_vec = np.concatenate([yy, -yy], axis=0)
    tau = taus[:, None]

    def columns(t):
        t = np.broadcast_to(np.asarray(t, dtype=np.float64), taus.shape)[:, None]
        e1 = np.exp(-k * t)
        e2 = np.exp(-k * (tau - t))
        c = 0.5 * (e1 + e2)
        sh = np.where(small, t - 0.5 * tau, 0.0)
        ks = k * sh
        shc = np.where(ks == 0.0, 1.0, np.sinh(ks) / np.where(ks == 0.0, 1.0, ks))
        d = -2.0 * np.exp(-k * np.where(small, 0.5 * tau, 0.0)) * sh * shc
        sm = small[:, None, :]
        col_a = np.where(
            sm,
            s_vec[None] * c[:, None, :] + 0.5 * (k * k)[None, None, :] * a_vec[None] * d[:, None, :],
            e1[:, None, :] * (s_vec[None] + k[None, None, :] * a_vec[None]) / 2.0,
        )
        col_b = np.where(
            sm,
            0.5 * s_vec[None] * d[:, None, :] + a_vec[None] * c[:, None, :],
            e2[:, None, :] * (s_vec[None] - k[None, None, :] * a_vec[None]) / 2.0,
        )
        return col_a, col_b

    m = taus.size
    a0, b0 = columns(0.0)
    at, bt = columns(taus)
    mat = np.zeros((m, 2 * n, 2 * n))
    mat[:, :n, :n] = a0[:, n:, :]
    mat[:, :n, n:] = b0[:, n:, :]
    mat[:, n:, :n] = at[:, :n, :]
    mat[:, n:, n:] = bt[:, :n, :]
    rhs = np.concatenate([np.broadcast_to(-z[n:], (m, n)), -z[None, :n] * np.exp(-tau / mu0)], axis=1)
    scale = np.max(np.abs(mat), axis=1, keepdims=True)
    scale = np.where(scale > 0.0, scale, 1.0)
    coef = np.linalg.solve(mat / scale, rhs[..., None])[..., 0] / scale[:, 0, :]
    # semi-infinite slab: only exp(-k t) modes, condition at the top
    top = (xx - k[None, :] * yy) / 2.0  # I- part of (X + kŶ, X - kŶ)/2
    a_inf = np.linalg.solve(top, -z[n:])
    return coef[:, :n], coef[:, n:], a_inf


@functools.lru_cache(maxsize=64)
def _order0(omega: float, phase: PhaseFunction, n: int):
    """plane_parallel's Fourier-order-0 setup and eigen-decomposition (independent of τ and μ0)."""
    x, wgl = np.polynomial.legendre.leggauss(n)
    mu = 0.5 * (x + 1.0)
    w = 0.5 * wgl
    chi = np.asarray(phase.legendre_moments(2 * n), dtype=np.float64).copy()
    if chi.shape != (2 * n,) or not np.all(np.isfinite(chi)) or abs(chi[0] - 1.0) > 1e-6:
        raise ValueError("phase function is not normalised (chi_0 != 1) or its moments are invalid")
    chi[0] = 1.0
    setup = _Setup(n=n, mu=mu, w=w, chi=chi, omega=omega, tau=1.0, floor_albedo=0.0, mu0=None)
    return setup, _eigen(setup, 0)


@functools.lru_cache(maxsize=CACHE_SIZE)
def _cached(omega: float, phase: PhaseFunction, mu0: float, n: int) -> SlabTable:
    setup, eig = _order0(omega, phase, n)
    mu, w = setup.mu, setup.w
    taus = _TAUS
    small = eig.k[None, :] * taus[:, None] < 1.0

    # a resonance 1/μ0 = k_j makes the particular solution singular: as plane_parallel, combine
    # two incidences perturbed by ±h (the diffuse field is analytic in μ0; error O(h²) ~ 1e-9)
    pts, wts = ([mu0], [1.0]) if omega == 0.0 else resonance_offsets(mu0, eig.k)
    parts = []
    for m0, wt in zip(pts, wts):
        z = _particular(setup, eig, m0)
        a, b, a_inf = _solve_ladder(eig, n, z, m0, taus, small)
        parts.append(_Part(weight=wt, mu0=m0, zsum=z[:n] + z[n:], a=a, b=b, a_inf=a_inf))
    return SlabTable(
        omega=omega, mu0=mu0, n_streams=n, mu=mu, w=w, k=eig.k, x=eig.x, taus=taus, small=small, parts=tuple(parts)
    )


def slab_table(*, omega: float, phase: PhaseFunction, mu0: float, n_streams: int = DEFAULT_STREAMS) -> SlabTable:
    """The exact slab solution for (ω, phase, μ0), tabulated over the thickness ladder (cached).

    Parameters
    ----------
    omega : float
        Single-scattering albedo in [0, 1] (1 is exact).
    phase : PhaseFunction
        Rotationally symmetric, 1/4π-normalised (e.g.
        :func:`~foliage_tools.lighting.phase.canopy_bilambertian_phase`); must be
        hashable (the phase classes of :mod:`~foliage_tools.lighting.phase` are).
    mu0 : float
        Cosine of the beam to the slab normal, 0 < μ0 <= 1.
    n_streams : int
        Streams per hemisphere (1..64).

    Returns
    -------
    SlabTable
    """
    if not isinstance(phase, PhaseFunction):
        raise ValueError(f"phase must be a PhaseFunction, got {type(phase).__name__}")  # noqa: TRY004
    omega = float(omega)
    mu0 = float(mu0)
    if not 0.0 <= omega <= 1.0:
        raise ValueError(f"omega (single-scattering albedo) must be in [0, 1], got {omega}")
    if not 0.0 < mu0 <= 1.0:
        raise ValueError(f"mu0 (cosine of the beam to the slab normal) must be in (0, 1], got {mu0}")
    if isinstance(n_streams, bool) or not isinstance(n_streams, (int, np.integer)) or not 1 <= n_streams <= 64:
        raise ValueError(f"n_streams must be an integer in [1, 64], got {n_streams!r}")
    return _cached(omega, phase, mu0, int(n_streams))

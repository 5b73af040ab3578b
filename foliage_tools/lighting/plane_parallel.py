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
  omega -> 1 and the pair exp(±k t) degenerates into {1, t}. This module uses
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .phase import PhaseFunction, _as_real

__all__ = ["SlabSolution", "solve_slab", "solve_slab_diffuse"]

#: Relative distance |k mu0 - 1| under which the particular solution is treated
#: as resonant (see module docstring).
RESONANCE_TOLERANCE = 1e-5
#: Relative perturbation of mu0 used at a resonance.
RESONANCE_STEP = 4e-5
#: Below this 1 - omega, the smallest m = 0 eigenvalue is refined by the
#: deflated iteration (relative accuracy near conservative scattering).
CONSERVATIVE_REFINE_BELOW = 1e-4
_PEAKED_MESSAGE = (
    "the phase function is too strongly peaked for this number of streams (its Legendre series "
    "truncated after 2 * n_streams terms makes Fourier order {m} indefinite); increase n_streams "
    "(about 0.6 / (1 - |g|) streams are needed for Henyey-Greenstein)"
)
#: Largest number of streams per hemisphere accepted.
MAX_STREAMS = 256


# --------------------------------------------------------------------------
# small, overflow-free scalar helpers
# --------------------------------------------------------------------------


def _phi1(x: np.ndarray) -> np.ndarray:
    """(1 - exp(-x)) / x for x >= 0, = 1 at x = 0 (via expm1, no cancellation)."""
    x = np.asarray(x, dtype=float)
    small = x == 0.0
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0, -np.expm1(-xs) / xs)


def _shc(x: np.ndarray) -> np.ndarray:
    """sinh(x) / x, = 1 at x = 0."""
    x = np.asarray(x, dtype=float)
    small = x == 0.0
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0, np.sinh(xs) / xs)


def _decay(k, t) -> np.ndarray:
    """exp(-k t) for k >= 0, t >= 0 (t may be inf), with 0 * inf taken as 0."""
    k, t = np.broadcast_arrays(np.asarray(k, dtype=float), np.asarray(t, dtype=float))
    x = np.zeros(k.shape)
    np.multiply(k, t, out=x, where=k != 0.0)
    return np.exp(-x)


def _conv2(a, b, length) -> np.ndarray:
    """E2(a, b, L) = ∫_0^L exp(-a (L - s)) exp(-b s) ds for a, b >= 0, L in [0, inf].

    Convolution of two decaying exponentials, = (e^{-bL} - e^{-aL})/(a - b), with
    the limit L e^{-aL} at a = b; evaluated as e^{-lo L} L φ1((hi - lo) L) so it
    neither overflows nor cancels.
    """
    a, b, length = np.broadcast_arrays(
        np.asarray(a, dtype=float),
        np.asarray(b, dtype=float),
        np.asarray(length, dtype=float),
    )
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    finite = np.isfinite(length)
    lf = np.where(finite, length, 0.0)
    out_finite = np.exp(-lo * lf) * lf * _phi1((hi - lo) * lf)
    hi_safe = np.where(hi > 0.0, hi, 1.0)
    out_inf = np.where(lo == 0.0, 1.0 / hi_safe, 0.0)
    return np.where(finite, out_finite, out_inf)


def _norm_assoc_legendre(m: int, lmax: int, x) -> np.ndarray:
    """Normalised associated Legendre functions Λ_l^m(x), l = 0..lmax.

    Λ_l^m = sqrt((l-m)!/(l+m)!) P_l^m (without the Condon-Shortley phase, which
    cancels in the products used here), via the stable upward recurrence
    sqrt((l+1)² - m²) Λ_{l+1} = (2l+1) x Λ_l - sqrt(l² - m²) Λ_{l-1}
    (as in DISORT's routine LEPOLY; T&S ch. 6). Rows l < m are zero.
    Returns shape (lmax + 1,) + x.shape.
    """
    x = np.asarray(x, dtype=float)
    out = np.zeros((lmax + 1,) + x.shape)
    if m > lmax:
        return out
    s = np.sqrt(np.maximum(0.0, 1.0 - x * x))
    pmm = np.ones(x.shape)
    for i in range(1, m + 1):
        pmm = pmm * (math.sqrt((2 * i - 1) / (2 * i)) * s)
    out[m] = pmm
    if m + 1 <= lmax:
        out[m + 1] = math.sqrt(2 * m + 1) * x * pmm
    for l in range(m + 1, lmax):
        out[l + 1] = (
            (2 * l + 1) * x * out[l] - math.sqrt(l * l - m * m) * out[l - 1]
        ) / math.sqrt((l + 1) ** 2 - m * m)
    return out


# --------------------------------------------------------------------------
# problem setup and the per-Fourier-order eigen-decomposition
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Setup:
    n: int  # streams per hemisphere
    mu: np.ndarray  # (N,) positive Gauss nodes on (0, 1)
    w: np.ndarray  # (N,) weights, sum 1
    chi: np.ndarray  # (2N,) Legendre moments, chi[0] = 1
    omega: float
    tau: float
    floor_albedo: float
    mu0: float | None  # None: isotropic sky illumination


@dataclass(frozen=True)
class _Eigen:
    """Homogeneous solutions of Fourier order m: modes exp(∓k t) with
    I+ = (X ± k Ŷ)/2, I- = (X ∓ k Ŷ)/2 (columns j)."""

    m: int
    k: np.ndarray  # (N,) >= 0
    x: np.ndarray  # (N, N) columns X_j = G+ + G-
    yhat: np.ndarray  # (N, N) columns Ŷ_j = (alpha - beta)^{-1} X_j, so G+ - G- = k Ŷ
    a_sys: np.ndarray  # (2N, 2N) system matrix: dI/dt = a_sys I (+ source)
    lam: np.ndarray  # (2N, N) Λ_l^m at the nodes
    coef: np.ndarray  # (2N,) (2l+1) chi_l
    parity: np.ndarray  # (2N,) (-1)^(l+m)


def _eigen(setup: _Setup, m: int) -> _Eigen:
    n, mu, w, omega = setup.n, setup.mu, setup.w, setup.omega
    lmax = 2 * n - 1
    ell = np.arange(lmax + 1)
    lam = _norm_assoc_legendre(m, lmax, mu)  # (L+1, N)
    coef = (2 * ell + 1) * setup.chi
    parity = np.where((ell + m) % 2 == 0, 1.0, -1.0)
    # p^m(mu_i, ±mu_j) = Σ_l (2l+1) chi_l Λ_l^m(mu_i) Λ_l^m(±mu_j), Λ(-x) = (-1)^{l+m} Λ(x)
    # (addition theorem; DISORT eq. for the Fourier components of the phase function).
    even = lam.T @ ((coef * (parity > 0))[:, None] * lam)  # (p(mu,mu') + p(mu,-mu'))/2
    odd = lam.T @ ((coef * (parity < 0))[:, None] * lam)  # (p(mu,mu') - p(mu,-mu'))/2
    sw = np.sqrt(w)
    eye = np.eye(n)
    # Stamnes & Swanson (1981): alpha ± beta = -M^{-1} W^{-1/2} S± W^{1/2} with the
    # symmetric S± = I - omega W^{1/2} (even|odd) W^{1/2}.
    # conservative part K (for m = 0: positive semi-definite, null vector √w)
    k_hat = eye - sw[:, None] * even * sw[None, :]
    s_plus = (1.0 - omega) * eye + omega * k_hat
    s_minus = eye - omega * sw[:, None] * odd * sw[None, :]
    rm = 1.0 / np.sqrt(mu)
    t_plus = rm[:, None] * s_plus * rm[None, :]
    t_minus = rm[:, None] * s_minus * rm[None, :]
    try:
        chol = np.linalg.cholesky(t_minus)
    except np.linalg.LinAlgError:
        raise ValueError(_PEAKED_MESSAGE.format(m=m)) from None
    # D = (alpha-beta)(alpha+beta) is similar to T- T+ = L (L^T T+ L) L^{-1}: k² = eig(L^T T+ L).
    h = chol.T @ t_plus @ chol
    h = 0.5 * (h + h.T)
    k2, eta = np.linalg.eigh(h)
    if k2[0] < -1e-9 * max(k2[-1], 1.0):
        # An indefinite "sum" matrix: the truncated phase function is too far from
        # positive for these streams (e.g. HG g <= -0.99 with 16 streams).
        raise ValueError(_PEAKED_MESSAGE.format(m=m))
    k2 = np.maximum(k2, 0.0)  # rounding only (the conservative k = 0 is refined below)
    xi = chol @ eta  # eigenvectors of T- T+
    # T-^{-1} xi = L^{-T} eta
    txi = scipy.linalg.solve_triangular(chol.T, eta, lower=False)
    if m == 0 and 1.0 - omega < CONSERVATIVE_REFINE_BELOW:
        j = int(np.argmin(k2))
        k2j, xij = _refine_conservative(mu, w, omega, k_hat, t_minus, chol)
        k2[j] = k2j
        xi[:, j] = xij
        txi[:, j] = scipy.linalg.cho_solve((chol, True), xij)
    scale_x = 1.0 / np.sqrt(mu * w)
    x = scale_x[:, None] * xi
    yhat = -scale_x[:, None] * txi
    norm = np.max(np.abs(x), axis=0)
    x = x / norm
    yhat = yhat / norm
    k = np.sqrt(k2)
    # Full 2N system (for the particular solution): dI+/dt = -alpha I+ - beta I-,
    # dI-/dt = beta I+ + alpha I-  (shinya2013 eq. (7) discretised; DISORT).
    p_same = even + odd
    p_opp = even - odd
    alpha = (omega * 0.5 * p_same * w[None, :] - eye) / mu[:, None]
    beta = (omega * 0.5 * p_opp * w[None, :]) / mu[:, None]
    a_sys = np.block([[-alpha, -beta], [beta, alpha]])
    return _Eigen(
        m=m, k=k, x=x, yhat=yhat, a_sys=a_sys, lam=lam, coef=coef, parity=parity
    )


def _refine_conservative(mu, w, omega, k_hat, t_minus, chol):
    """Smallest k² of the m = 0 problem, to full relative accuracy near omega = 1.

    Generalised symmetric form: (eps M^{-1} + omega M^{-1/2} K M^{-1/2}) y = k² T-^{-1} y,
    eps = 1 - omega, where the conservative operator K has the exact null vector
    √w (phase function normalised, chi_0 = 1, and double-Gauss quadrature exact
    for the truncated expansion). In an orthonormal basis whose first vector is
    the null vector e = M^{1/2} √w / |.|, the k² ~ eps eigenvalue solves the
    Schur-complement fixed point
        k² = eps (Mt_00 + Mt_0p z) / (Tt_00 + Tt_0p z),
        (omega Kt_pp + eps Mt_pp - k² Tt_pp) z = k² Tt_p0 - eps Mt_p0,
    in which no quantity is a difference of O(1) numbers, so k² is exact to
    rounding relative to itself (and exactly 0 at omega = 1).
    Returns (k², xi) with xi the eigenvector of T- T+.
    """
    eps = 1.0 - omega
    n = mu.size
    e = np.sqrt(mu * w)
    e = e / np.linalg.norm(e)
    q, _ = np.linalg.qr(e[:, None], mode="complete")  # columns 1.. span e's complement
    q[:, 0] = e
    perp = q[:, 1:]
    rm = 1.0 / np.sqrt(mu)
    kt = rm[:, None] * k_hat * rm[None, :]
    kt_pp = perp.T @ kt @ perp
    mt = q.T @ (np.diag(1.0 / mu)) @ q
    tinv = scipy.linalg.cho_solve((chol, True), np.eye(n))
    tt = q.T @ tinv @ q
    if n == 1 or eps == 0.0:
        z = np.zeros(n - 1)
        k2 = eps * mt[0, 0] / tt[0, 0]
    else:
        k2 = eps * mt[0, 0] / tt[0, 0]
        z = np.zeros(n - 1)
        for _ in range(50):
            mat = omega * kt_pp + eps * mt[1:, 1:] - k2 * tt[1:, 1:]
            z = np.linalg.solve(mat, k2 * tt[1:, 0] - eps * mt[1:, 0])
            k2_new = eps * (mt[0, 0] + mt[0, 1:] @ z) / (tt[0, 0] + tt[0, 1:] @ z)
            done = abs(k2_new - k2) <= 1e-15 * abs(k2_new)
            k2 = k2_new
            if done:
                break
    xi = q @ np.concatenate([[1.0], z])
    return max(float(k2), 0.0), xi / np.linalg.norm(xi)


# --------------------------------------------------------------------------
# one Fourier order: boundary-value solution, evaluation at depths/directions
# --------------------------------------------------------------------------


class _ModeSolution:
    """Diffuse radiance of Fourier order m as a sum of scalar basis functions.

    I(t) = Σ top_vec e^{-k t} + Σ bot_vec e^{-k (tau - t)} + Σ d_vec D_k(t), with
    D_k(t) = (e^{-kt} - e^{-k(tau-t)})/k (-> tau - 2t at k = 0); the particular
    beam solution Z e^{-t/mu0} is one of the "top" terms.
    """

    def __init__(self, setup: _Setup, eig: _Eigen, mu0: float | None):
        self.setup = setup
        self.eig = eig
        self.mu0 = mu0
        n = setup.n
        m = eig.m
        tau = setup.tau
        omega = setup.omega
        mu, w = setup.mu, setup.w
        lmax = 2 * n - 1
        fac = 1.0 if m == 0 else 2.0
        # direct-beam source Q^m(mu) = (omega/4π)(2 - δ_m0) p^m(mu, -mu0) e^{-t/mu0}
        # (DISORT; T&S ch. 6, with unit beam irradiance).
        if mu0 is not None and omega > 0.0:
            lam0 = _norm_assoc_legendre(m, lmax, np.array(mu0))
            self.src_coef = (
                fac * omega / (4.0 * math.pi) * eig.coef * eig.parity * lam0
            )  # · Λ(mu)
        else:
            self.src_coef = np.zeros(lmax + 1)
        q_plus = eig.lam.T @ self.src_coef  # Q^m(+mu_i)
        q_minus = eig.lam.T @ (self.src_coef * eig.parity)  # Q^m(-mu_i)
        if np.any(q_plus != 0.0) or np.any(q_minus != 0.0):
            s = np.concatenate([-q_plus / mu, q_minus / mu])
            assert mu0 is not None  # without a beam (mu0 None) the source coefficients, so q_plus and q_minus, are 0
            z = np.linalg.solve(eig.a_sys + np.eye(2 * n) / mu0, -s)
        else:
            z = np.zeros(2 * n)
        self.z = z
        beam_rate = 1.0 / mu0 if mu0 is not None else 0.0
        self.beam_rate = beam_rate

        # boundary data (m = 0 only): sky radiance at top, Lambertian floor.
        sky = 1.0 / math.pi if (mu0 is None and m == 0) else 0.0
        a = setup.floor_albedo if m == 0 else 0.0
        self.sky = sky
        self.floor = a

        k = eig.k
        x, yh = eig.x, eig.yhat
        columns: list[list[tuple[str, float, np.ndarray]]] = []
        for j in range(n):
            kj = float(k[j])
            xx = x[:, j]
            yy = yh[:, j]
            v_top = np.concatenate([(xx + kj * yy) / 2.0, (xx - kj * yy) / 2.0])
            v_bot = np.concatenate([(xx - kj * yy) / 2.0, (xx + kj * yy) / 2.0])
            if math.isinf(tau):
                columns.append([("top", kj, v_top)])
            elif kj * tau >= 1.0:
                columns.append([("top", kj, v_top)])
                columns.append([("bot", kj, v_bot)])
            else:
                # I± = d (X C ± k²/2 Ŷ D) + d' (X D/2 ± Ŷ C), C = (top + bot)/2
                sx = np.concatenate([xx, xx])
                sy = np.concatenate([yy, -yy])
                columns.append(
                    [
                        ("top", kj, sx / 2.0),
                        ("bot", kj, sx / 2.0),
                        ("D", kj, sy * (kj * kj / 2.0)),
                    ]
                )
                columns.append(
                    [("D", kj, sx / 2.0), ("top", kj, sy / 2.0), ("bot", kj, sy / 2.0)]
                )

        n_unknown = len(columns)
        finite = not math.isinf(tau)
        rows_top = np.zeros((n, n_unknown))
        rows_bot = np.zeros((n, n_unknown))
        floor_row = 2.0 * a * w * mu  # (a/π) · 2π Σ w mu I-(tau)
        for c, terms in enumerate(columns):
            v0 = np.zeros(2 * n)
            vt = np.zeros(2 * n)
            for kind, kk, vec in terms:
                v0 += self._scalar(kind, kk, 0.0) * vec
                if finite:
                    vt += self._scalar(kind, kk, tau) * vec
            rows_top[:, c] = v0[n:]
            if finite:
                rows_bot[:, c] = vt[:n] - floor_row @ vt[n:]
        rhs_top = sky - z[n:]
        if finite:
            e_beam = float(_decay(beam_rate, tau)) if mu0 is not None else 0.0
            floor_direct = (a / math.pi) * mu0 * e_beam if mu0 is not None else 0.0
            rhs_bot = floor_direct - (z[:n] - floor_row @ z[n:]) * e_beam
            mat = np.vstack([rows_top, rows_bot])
            rhs = np.concatenate([rhs_top, rhs_bot])
        else:
            mat = rows_top
            rhs = rhs_top
        # column equilibration (the D columns scale like tau)
        cscale = np.max(np.abs(mat), axis=0)
        cscale = np.where(cscale > 0.0, cscale, 1.0)
        coeff = np.linalg.solve(mat / cscale[None, :], rhs) / cscale

        groups: dict[str, tuple[list[float], list[np.ndarray]]] = {
            "top": ([], []),
            "bot": ([], []),
            "D": ([], []),
        }
        for c, terms in enumerate(columns):
            for kind, kk, vec in terms:
                groups[kind][0].append(kk)
                groups[kind][1].append(coeff[c] * vec)
        if mu0 is not None:
            groups["top"][0].append(beam_rate)
            groups["top"][1].append(z)
        self.terms = {
            kind: (
                np.array(rates, dtype=float),
                np.array(vecs, dtype=float).reshape(len(vecs), 2 * n),
            )
            for kind, (rates, vecs) in groups.items()
        }

    # -- scalar basis functions -------------------------------------------
    def _scalar(self, kind: str, k, t) -> np.ndarray:
        tau = self.setup.tau
        if kind == "top":
            return _decay(k, t)
        if kind == "bot":
            return _decay(k, np.asarray(tau - np.asarray(t, dtype=float)))
        # D_k(t) = -2 e^{-k tau/2} s shc(k s), s = t - tau/2 (only used with k tau < 1)
        s = np.asarray(t, dtype=float) - tau / 2.0
        k = np.asarray(k, dtype=float)
        return -2.0 * np.exp(-k * tau / 2.0) * s * _shc(k * s)

    # -- evaluation --------------------------------------------------------
    def nodal(self, t) -> np.ndarray:
        """Radiance at the 2N nodes (I+ then I-) at depths t: shape (len(t), 2N)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((t.size, 2 * self.setup.n))
        for kind, (rates, vecs) in self.terms.items():
            if rates.size:
                out += self._scalar(kind, rates[None, :], t[:, None]) @ vecs
        return out

    def integral(self) -> np.ndarray:
        """∫_0^tau I dt at the nodes, shape (2N,). Not for k = 0 with tau = inf."""
        tau = self.setup.tau
        out = np.zeros(2 * self.setup.n)
        for kind in ("top", "bot"):
            rates, vecs = self.terms[kind]
            if rates.size:
                if math.isinf(tau):
                    vals = (
                        1.0 / rates
                    )  # only "top" terms exist, all with k > 0 when omega < 1
                else:
                    vals = tau * _phi1(rates * tau)
                out += vals @ vecs
        # ∫ D_k dt = 0 (odd about tau/2)
        return out

    def floor_radiance(self) -> float:
        """Upward radiance leaving the Lambertian floor (m = 0; 0 otherwise)."""
        if self.floor == 0.0 or math.isinf(self.setup.tau):
            return 0.0
        tau = self.setup.tau
        n = self.setup.n
        i_minus = self.nodal([tau])[0, n:]
        f_down = 2.0 * math.pi * np.sum(self.setup.w * self.setup.mu * i_minus)
        if self.mu0 is not None:
            f_down += self.mu0 * float(_decay(self.beam_rate, tau))
        return self.floor / math.pi * f_down

    def user(self, t: np.ndarray, mu: np.ndarray) -> np.ndarray:
        """Radiance of this order at depths t (n_p,) in directions mu (n_p,), mu != 0.

        Formal solution along the line of sight (DISORT; T&S ch. 8):
        mu > 0: I(t, mu) = I(tau, mu) e^{-(tau-t)/mu} + ∫_t^tau S(t', mu) e^{-(t'-t)/mu} dt'/mu,
        mu < 0: I(t, mu) = I(0, mu) e^{-t/|mu|} + ∫_0^t S(t', mu) e^{-(t-t')/|mu|} dt'/|mu|,
        with S the discrete-ordinate source function (shinya2013 eq. (7) right-hand side).
        """
        setup = self.setup
        eig = self.eig
        n = setup.n
        tau = setup.tau
        omega = setup.omega
        lmax = 2 * n - 1
        t = np.asarray(t, dtype=float)
        mu = np.asarray(mu, dtype=float)
        lam_u = _norm_assoc_legendre(eig.m, lmax, mu)  # (L+1, n_p)
        p_same = lam_u.T @ (eig.coef[:, None] * eig.lam)  # p^m(mu_u, +mu_j)
        p_opp = lam_u.T @ (
            (eig.coef * eig.parity)[:, None] * eig.lam
        )  # p^m(mu_u, -mu_j)
        sigma = (
            0.5
            * omega
            * np.concatenate(
                [p_same * setup.w[None, :], p_opp * setup.w[None, :]], axis=1
            )
        )
        q_user = lam_u.T @ self.src_coef  # beam source amplitude at mu_u

        up = mu > 0.0
        amu = np.abs(mu)
        inv = 1.0 / amu
        length = np.where(
            up, tau - t, t
        )  # path length to the boundary the ray comes from
        out = np.zeros(mu.shape)

        def integ(kind, k):
            """∫ f(t') e^{-|t'-t|/|mu|} dt'/|mu| over the upstream part of the slab."""
            k = np.asarray(k, dtype=float)
            tt, ll, iv, am, upp = (
                t[:, None],
                length[:, None],
                inv[:, None],
                amu[:, None],
                up[:, None],
            )
            if kind in ("top", "bot"):
                top_up = _decay(k, tt) * _conv2(0.0, k + iv, ll) / am
                top_dn = _conv2(iv, k, ll) / am
                if kind == "top":
                    return np.where(upp, top_up, top_dn)
                bot_up = _conv2(k, iv, ll) / am
                bot_dn = _decay(k, tau - tt) * _conv2(0.0, k + iv, ll) / am
                return np.where(upp, bot_up, bot_dn)
            # D kind
            kpos = k > 0.0
            ks = np.where(kpos, k, 1.0)
            diff = (integ("top", ks) - integ("bot", ks)) / ks
            x = ll * iv
            e = np.exp(-x)
            lin = (tau - 2.0 * tt) * (-np.expm1(-x))
            ramp = 2.0 * am * (-np.expm1(-x) - x * e)
            lim = np.where(upp, lin - ramp, lin + ramp)
            return np.where(kpos, diff, lim)

        for kind, (rates, vecs) in self.terms.items():
            if rates.size:
                amp = sigma @ vecs.T  # (n_p, n_terms)
                out += np.sum(amp * integ(kind, rates[None, :]), axis=1)
        if self.mu0 is not None and np.any(q_user != 0.0):
            out += q_user * integ("top", np.array([self.beam_rate]))[:, 0]
        # boundary radiance entering the slab, attenuated along the path
        floor = self.floor_radiance()
        bc = np.where(up, floor, self.sky)
        if not (floor == 0.0 and self.sky == 0.0):
            out += bc * _decay(inv, length)
        return out


class _Combination:
    """Linear combination of mode solutions (resonance treatment)."""

    def __init__(self, parts: list[_ModeSolution], weights: list[float]):
        self.parts = parts
        self.weights = weights

    def nodal(self, t):
        return sum(wt * p.nodal(t) for p, wt in zip(self.parts, self.weights))

    def integral(self):
        return sum(wt * p.integral() for p, wt in zip(self.parts, self.weights))

    def user(self, t, mu):
        return sum(wt * p.user(t, mu) for p, wt in zip(self.parts, self.weights))


def resonance_offsets(mu0: float, k: np.ndarray) -> tuple[list[float], list[float]]:
    """Incidence cosines and weights standing for ``mu0`` given the eigenvalues ``k``.

    ``([mu0], [1.0])`` unless 1/mu0 is (nearly) an eigenvalue; at such a resonance the particular
    solution is singular, and two perturbed incidences combine to second order in the step h
    (±h about mu0, or one-sided 2(mu0 - h) - (mu0 - 2h) near mu0 = 1), the step grown until both
    are clear of every eigenvalue.
    """
    def resonant(x: float) -> bool:
        return bool(np.any(np.abs(k * x - 1.0) < RESONANCE_TOLERANCE))

    if not resonant(mu0):
        return [mu0], [1.0]
    h = RESONANCE_STEP
    for _ in range(20):
        if (
            mu0 * (1.0 + h) <= 1.0
            and not resonant(mu0 * (1 + h))
            and not resonant(mu0 * (1 - h))
        ):
            return [mu0 * (1.0 - h), mu0 * (1.0 + h)], [0.5, 0.5]
        if not resonant(mu0 * (1 - h)) and not resonant(mu0 * (1 - 2 * h)):
            return [mu0 * (1.0 - h), mu0 * (1.0 - 2.0 * h)], [2.0, -1.0]
        h *= 1.5
    raise RuntimeError("could not move mu0 off a resonance with the eigenvalues")  # pragma: no cover - needs clustered eigenvalues


def _solve_mode(setup: _Setup, eig: _Eigen):
    """Solve Fourier order m, treating a resonant mu0 by second-order perturbation."""
    mu0 = setup.mu0
    if mu0 is None or setup.omega == 0.0:
        return _ModeSolution(setup, eig, mu0)
    pts, wts = resonance_offsets(mu0, eig.k)
    if len(pts) == 1:
        return _ModeSolution(setup, eig, mu0)
    return _Combination([_ModeSolution(setup, eig, p) for p in pts], wts)


# --------------------------------------------------------------------------
# public result type
# --------------------------------------------------------------------------


class _Field:
    """Lazily computed Fourier orders of one slab problem (for user radiances)."""

    def __init__(self, setup: _Setup, mode0):
        self.setup = setup
        self.modes = {0: mode0}

    def mode(self, m: int):
        if m not in self.modes:
            self.modes[m] = _solve_mode(self.setup, _eigen(self.setup, m))
        return self.modes[m]

    def radiance(self, depth, mu, phi):
        setup = self.setup
        if setup.tau == 0.0:
            return self._radiance_tau0(depth, mu, phi)
        out = self.mode(0).user(depth, mu)
        if phi is None or setup.mu0 is None or setup.omega == 0.0 or setup.mu0 == 1.0:
            # azimuthal average, or azimuthally symmetric field
            return out
        for m in range(1, 2 * setup.n):
            out = out + self.mode(m).user(depth, mu) * np.cos(m * phi)
        return out

    def _radiance_tau0(self, depth, mu, phi):
        setup = self.setup
        if setup.mu0 is None:
            incident = 1.0
            sky = 1.0 / math.pi
        else:
            incident = setup.mu0
            sky = 0.0
        up = setup.floor_albedo / math.pi * incident
        return np.where(np.asarray(mu) > 0.0, up, sky) + 0.0 * np.asarray(
            depth, dtype=float
        )


@dataclass(frozen=True, eq=False)
class SlabSolution:
    """Solution of the slab problem. See the module docstring for normalisation.

    Attributes
    ----------
    tau, omega, mu0, n_streams, floor_albedo :
        The problem solved (``mu0`` is None for isotropic sky illumination).
    incident_flux : float
        Horizontal irradiance entering the top: ``mu0`` (beam) or 1 (sky).
    reflectance : float
        Plane albedo: upward diffuse flux leaving the top / ``incident_flux``.
    transmittance_direct : float
        Unscattered beam reaching the bottom / ``incident_flux`` = exp(-tau/mu0)
        (0 for sky illumination, whose uncollided part is counted as diffuse;
        0 for tau = inf).
    transmittance_diffuse : float
        Downward diffuse flux at the slab bottom (above the floor) /
        ``incident_flux`` (0 for tau = inf).
    absorptance : float
        Power absorbed in the slab / ``incident_flux``, computed independently
        of the boundary fluxes as (1 - omega) ∫_0^tau (actinic flux) dt.
    floor_absorptance : float
        Power absorbed by the floor / ``incident_flux``
        = (1 - floor_albedo) (downward flux at the bottom). With the above,
        reflectance + absorptance + floor_absorptance = 1.
    depths : ndarray (D,)
        The requested optical depths t (downward from the top).
    flux_direct : ndarray (D,)
        Horizontal irradiance of the unscattered beam, mu0 exp(-t/mu0)
        (per unit beam irradiance; zeros for sky illumination).
    flux_down_diffuse, flux_up : ndarray (D,)
        Downward and upward diffuse horizontal irradiance 2π ∫ |mu| I dmu.
    actinic_flux : ndarray (D,)
        Scalar irradiance 4π J = ∫ I dΩ including the direct beam
        (exp(-t/mu0) for the beam). The mean irradiance on one face of a
        randomly (uniformly) oriented flat leaf is actinic_flux / 4.
    actinic_flux_diffuse : ndarray (D,)
        Diffuse part of ``actinic_flux``. Mean intensity J = actinic_flux/(4π).
    mu, weights : ndarray (N,)
        Double-Gauss nodes (cosines, 0 < mu < 1) and weights (sum 1) of one
        hemisphere.
    radiance_up_top : ndarray (N,)
        Azimuthally averaged diffuse radiance leaving the top upward at the
        nodes ``mu`` (sr⁻¹ per unit incident irradiance).
    radiance_down_bottom : ndarray (N,)
        Azimuthally averaged diffuse radiance going downward at the bottom
        (t = tau) at cosines ``mu`` from the downward vertical; for tau = inf
        the limit t -> inf (zero unless omega = 1).
    """

    tau: float
    omega: float
    mu0: float | None
    n_streams: int
    floor_albedo: float
    incident_flux: float
    reflectance: float
    transmittance_direct: float
    transmittance_diffuse: float
    absorptance: float
    floor_absorptance: float
    depths: np.ndarray
    flux_direct: np.ndarray
    flux_down_diffuse: np.ndarray
    flux_up: np.ndarray
    actinic_flux: np.ndarray
    actinic_flux_diffuse: np.ndarray
    mu: np.ndarray
    weights: np.ndarray
    radiance_up_top: np.ndarray
    radiance_down_bottom: np.ndarray
    _field: _Field = field(repr=False, compare=False)

    @property
    def transmittance(self) -> float:
        """Total (direct + diffuse) transmittance."""
        return self.transmittance_direct + self.transmittance_diffuse

    def radiance(self, depth, mu, phi=None) -> np.ndarray:
        """Diffuse radiance at optical depth(s) ``depth`` in direction(s) (mu, phi).

        Parameters
        ----------
        depth : array_like
            Optical depth(s) t, 0 <= t <= tau (finite).
        mu : array_like
            Cosine of the direction from the *upward* vertical, -1 <= mu <= 1,
            mu != 0 (> 0: upward-going radiance, < 0: downward-going).
        phi : array_like or None
            Azimuth (radians) of the direction relative to the incident beam's
            propagation azimuth. None: azimuthal average (Fourier order 0 only).

        Returns
        -------
        numpy.ndarray
            Radiance (sr⁻¹ per unit incident irradiance as in the module
            docstring), broadcast shape of the inputs. The direct beam (a delta
            function) is not included.
        """
        if phi is None:
            depth_b, mu_b = np.broadcast_arrays(
                np.asarray(depth, dtype=float), np.asarray(mu, dtype=float)
            )
            phi_b = None
        else:
            depth_b, mu_b, phi_b = np.broadcast_arrays(
                np.asarray(depth, dtype=float),
                np.asarray(mu, dtype=float),
                np.asarray(phi, dtype=float),
            )
        if (
            not np.all(np.isfinite(depth_b))
            or np.any(depth_b < 0.0)
            or np.any(depth_b > self.tau)
        ):
            raise ValueError(f"depth must be finite and within [0, tau={self.tau}]")
        if (
            not np.all(np.isfinite(mu_b))
            or np.any(np.abs(mu_b) > 1.0)
            or np.any(mu_b == 0.0)
        ):
            raise ValueError(
                "mu must be in [-1, 1] and non-zero (> 0 upward, < 0 downward)"
            )
        if phi_b is not None and not np.all(np.isfinite(phi_b)):
            raise ValueError("phi must be finite")
        shape = mu_b.shape
        out = self._field.radiance(
            depth_b.ravel(), mu_b.ravel(), None if phi_b is None else phi_b.ravel()
        )
        return np.asarray(out, dtype=float).reshape(shape)

    def radiance_top(self, mu, phi=None) -> np.ndarray:
        """Diffuse radiance leaving the top upward; ``mu`` in (0, 1] from the upward vertical."""
        mu = np.asarray(mu, dtype=float)
        if np.any(mu <= 0.0):
            raise ValueError(
                "radiance_top needs mu in (0, 1] (cosine from the upward vertical)"
            )
        return self.radiance(0.0, mu, phi)

    def radiance_bottom(self, mu, phi=None) -> np.ndarray:
        """Diffuse radiance leaving the bottom downward; ``mu`` in (0, 1] from the downward vertical."""
        mu = np.asarray(mu, dtype=float)
        if np.any(mu <= 0.0):
            raise ValueError(
                "radiance_bottom needs mu in (0, 1] (cosine from the downward vertical)"
            )
        if math.isinf(self.tau):
            raise ValueError("a semi-infinite slab (tau = inf) has no bottom")
        return self.radiance(self.tau, -mu, phi)


# --------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------


_real = _as_real  # one checker for both modules (lighting.phase)


def _validate(tau, omega, phase, n_streams, depths, floor_albedo):
    tau = _real("tau (optical thickness)", tau)
    if tau < 0.0:
        raise ValueError(
            f"tau (optical thickness) must be >= 0 (inf for a semi-infinite slab), got {tau}"
        )
    omega = _real("omega (single-scattering albedo)", omega)
    if not 0.0 <= omega <= 1.0:
        raise ValueError(
            f"omega (single-scattering albedo) must be in [0, 1], got {omega}"
        )
    if not isinstance(phase, PhaseFunction):
        raise ValueError(  # noqa: TRY004 (project convention: bad inputs -> ValueError)
            "phase must be a PhaseFunction (e.g. hg_phase(g) or canopy_bilambertian_phase(...)), "
            f"got {type(phase).__name__}"
        )
    if isinstance(n_streams, bool) or not isinstance(n_streams, (int, np.integer)):
        raise ValueError(f"n_streams must be an integer, got {n_streams!r}")  # noqa: TRY004
    n = int(n_streams)
    if not 1 <= n <= MAX_STREAMS:
        raise ValueError(
            f"n_streams (per hemisphere) must be in [1, {MAX_STREAMS}], got {n}"
        )
    floor_albedo = _real("floor_albedo", floor_albedo)
    if not 0.0 <= floor_albedo <= 1.0:
        raise ValueError(f"floor_albedo must be in [0, 1], got {floor_albedo}")
    if math.isinf(tau) and floor_albedo != 0.0:
        raise ValueError(
            "floor_albedo has no effect under a semi-infinite slab (tau = inf); leave it 0"
        )
    if depths is None:
        d = np.zeros(0)
    else:
        try:
            d = np.asarray(depths, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("depths must be an array of optical depths") from None
        if d.ndim > 1:
            raise ValueError("depths must be a scalar or a 1-D array of optical depths")
        d = np.atleast_1d(d)
        if not np.all(np.isfinite(d)) or np.any(d < 0.0) or np.any(d > tau):
            raise ValueError(
                f"depths must be finite optical depths within [0, tau={tau}]"
            )
    chi = np.asarray(phase.legendre_moments(2 * n), dtype=float)
    if chi.shape != (2 * n,) or not np.all(np.isfinite(chi)):
        raise ValueError("phase.legendre_moments returned an invalid array")
    if abs(chi[0] - 1.0) > 1e-6:
        raise ValueError(
            f"phase function is not normalised: chi_0 = {chi[0]:.8g}, expected 1"
        )
    chi = chi.copy()
    chi[0] = 1.0
    return tau, omega, n, d, floor_albedo, chi


def solve_slab(
    *,
    tau: float,
    omega: float,
    mu0: float,
    phase: PhaseFunction,
    n_streams: int = 16,
    depths=None,
    floor_albedo: float = 0.0,
) -> SlabSolution:
    """Solve a homogeneous slab lit by a collimated beam (discrete ordinates).

    Parameters
    ----------
    tau : float
        Optical thickness (dimensionless), 0 <= tau <= inf (``math.inf``: a
        semi-infinite medium). For a spherical-leaf canopy, tau = 0.5 * LAI.
    omega : float
        Single-scattering albedo, 0 <= omega <= 1 (1: conservative, handled
        exactly).
    mu0 : float
        Cosine of the beam's zenith angle, 0 < mu0 <= 1. The beam has
        irradiance 1 on a plane perpendicular to it, so mu0 on the slab top.
    phase : PhaseFunction
        Rotationally symmetric phase function (1/4π normalisation), e.g.
        :func:`~foliage_tools.lighting.phase.hg_phase` or
        :func:`~foliage_tools.lighting.phase.canopy_bilambertian_phase`. Its
        Legendre expansion is truncated after 2 * n_streams terms (no delta-M
        scaling), so very forward-peaked functions need more streams.
    n_streams : int
        Quadrature directions per hemisphere N (2N streams in all), 1..256.
        Default 16: fluxes change by ~1e-8 (HG g = 0.5) to ~3e-7 (g = 0.8)
        from 16 to 32 streams. Without delta-M scaling, Henyey-Greenstein
        needs roughly n_streams >= 0.6/(1 - |g|) near omega = 1 (g = 0.95: 16,
        0.98: 32, 0.99: 64); otherwise a ValueError says so.
    depths : array_like, optional
        Optical depths (0 <= t <= tau, finite) where the flux profiles are
        reported. Default: none.
    floor_albedo : float
        Albedo of a Lambertian floor under the slab, 0..1 (0: black). Must be 0
        when tau = inf.

    Returns
    -------
    SlabSolution
        Fluxes, profiles, nodal radiances and a ``radiance`` method for any
        direction; see :class:`SlabSolution` for the normalisation.

    Raises
    ------
    ValueError
        If an input is out of range, or the phase function is too peaked for
        ``n_streams``.
    """
    tau, omega, n, d, floor_albedo, chi = _validate(
        tau, omega, phase, n_streams, depths, floor_albedo
    )
    mu0 = _real("mu0 (cosine of the beam zenith angle)", mu0)
    if not 0.0 < mu0 <= 1.0:
        raise ValueError(
            f"mu0 (cosine of the beam zenith angle) must be in (0, 1], got {mu0}"
        )
    return _solve(tau, omega, mu0, n, d, floor_albedo, chi)


def solve_slab_diffuse(
    *,
    tau: float,
    omega: float,
    phase: PhaseFunction,
    n_streams: int = 16,
    depths=None,
    floor_albedo: float = 0.0,
) -> SlabSolution:
    """Solve a homogeneous slab lit by a uniform isotropic sky.

    The sky radiance is 1/π (horizontal irradiance 1 on the top). Parameters
    and result as :func:`solve_slab` (``mu0`` is None in the result; all
    transmitted light, including the uncollided sky light, is counted as
    diffuse; the field is azimuthally symmetric). ``reflectance`` is the
    white-sky (bi-hemispherical) albedo. A beam + sky illumination is the sum
    of the two solutions' fluxes scaled by their incident irradiances.
    """
    tau, omega, n, d, floor_albedo, chi = _validate(
        tau, omega, phase, n_streams, depths, floor_albedo
    )
    return _solve(tau, omega, None, n, d, floor_albedo, chi)


def _solve(tau, omega, mu0, n, depths, floor_albedo, chi) -> SlabSolution:
    x, wgl = np.polynomial.legendre.leggauss(n)
    # double-Gauss: Gauss-Legendre on each hemisphere mu in (0, 1) (Sykes 1951)
    mu = 0.5 * (x + 1.0)
    w = 0.5 * wgl
    setup = _Setup(
        n=n,
        mu=mu,
        w=w,
        chi=chi,
        omega=omega,
        tau=tau,
        floor_albedo=floor_albedo,
        mu0=mu0,
    )
    beam = mu0 is not None
    f_inc = mu0 if beam else 1.0
    inf = math.isinf(tau)

    def direct_actinic(t):
        return _decay(1.0 / mu0, t) if beam else np.zeros(np.shape(t))

    if tau == 0.0:
        # exact: nothing in the slab; the floor reflects the incident light.
        up = floor_albedo / math.pi * f_inc
        sky = 0.0 if beam else 1.0 / math.pi
        zeros = np.zeros(depths.shape)
        fd = f_inc if not beam else 0.0
        return _make_solution(
            tau=tau,
            omega=omega,
            mu0=mu0,
            n_streams=n,
            floor_albedo=floor_albedo,
            incident_flux=f_inc,
            reflectance=floor_albedo,
            transmittance_direct=1.0 if beam else 0.0,
            transmittance_diffuse=0.0 if beam else 1.0,
            absorptance=0.0,
            floor_absorptance=1.0 - floor_albedo,
            depths=depths,
            flux_direct=zeros + (mu0 if beam else 0.0),
            flux_down_diffuse=zeros + fd,
            flux_up=zeros + floor_albedo * f_inc,
            actinic_flux=zeros + (1.0 if beam else 0.0) + 2.0 * math.pi * (up + sky),
            actinic_flux_diffuse=zeros + 2.0 * math.pi * (up + sky),
            mu=mu,
            weights=w,
            radiance_up_top=np.full(n, up),
            radiance_down_bottom=np.full(n, sky),
            _field=_Field(setup, None),
        )

    mode0 = _solve_mode(setup, _eigen(setup, 0))
    field_ = _Field(setup, mode0)

    def profile(t):
        t = np.asarray(t, dtype=float)
        if t.size == 0:
            e = np.zeros(0)
            return e, e, e, e, e
        nod = mode0.nodal(t)
        ip, im = nod[:, :n], nod[:, n:]
        f_up = 2.0 * math.pi * ip @ (w * mu)
        f_dn = 2.0 * math.pi * im @ (w * mu)
        act_diff = 2.0 * math.pi * (ip + im) @ w
        da = direct_actinic(t)
        f_dir = mu0 * da if beam else np.zeros(t.shape)
        return f_dir, f_dn, f_up, act_diff + da, act_diff

    f_dir, f_dn, f_up, act, act_diff = profile(depths)
    top = mode0.nodal([0.0])[0]
    bottom = mode0.nodal([tau])[0]
    reflectance = 2.0 * math.pi * float(top[:n] @ (w * mu)) / f_inc
    if inf:
        t_dir = 0.0
        t_diff = 0.0
    else:
        t_dir = float(_decay(1.0 / mu0, tau)) if beam else 0.0
        t_diff = 2.0 * math.pi * float(bottom[n:] @ (w * mu)) / f_inc
    if omega < 1.0:
        integ = mode0.integral()
        act_int = 2.0 * math.pi * float((integ[:n] + integ[n:]) @ w)
        if beam:
            act_int += mu0 if inf else mu0 * float(-np.expm1(-tau / mu0))
        absorptance = (1.0 - omega) * act_int / f_inc
    else:
        absorptance = 0.0
    floor_abs = 0.0 if inf else (1.0 - floor_albedo) * (t_dir + t_diff)
    return _make_solution(
        tau=tau,
        omega=omega,
        mu0=mu0,
        n_streams=n,
        floor_albedo=floor_albedo,
        incident_flux=f_inc,
        reflectance=reflectance,
        transmittance_direct=t_dir,
        transmittance_diffuse=t_diff,
        absorptance=absorptance,
        floor_absorptance=floor_abs,
        depths=depths,
        flux_direct=f_dir,
        flux_down_diffuse=f_dn,
        flux_up=f_up,
        actinic_flux=act,
        actinic_flux_diffuse=act_diff,
        mu=mu,
        weights=w,
        radiance_up_top=top[:n].copy(),
        radiance_down_bottom=bottom[n:].copy(),
        _field=field_,
    )


def _make_solution(**fields) -> SlabSolution:
    """Build a SlabSolution with float scalars and read-only array fields."""
    for name, value in fields.items():
        if isinstance(value, np.ndarray):
            arr = np.array(value, dtype=float)
            arr.setflags(write=False)
            fields[name] = arr
        elif isinstance(value, (float, np.floating)):
            fields[name] = float(value)
    return SlabSolution(**fields)

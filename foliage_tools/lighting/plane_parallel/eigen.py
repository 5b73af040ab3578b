"""Problem setup and the eigen-decomposition of one Fourier order.

:class:`_Setup` is the discretised problem (double-Gauss nodes and weights,
Legendre moments, omega, tau, floor, mu0); :func:`_eigen` reduces the 2N x 2N
homogeneous system of Fourier order m to an N x N symmetric eigenproblem for
k² (method in the package docstring, :mod:`foliage_tools.lighting.plane_parallel`), and
:func:`_refine_conservative` gives the smallest m = 0 eigenvalue to full
relative accuracy near omega = 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from foliage_tools.lighting.plane_parallel.constants import _PEAKED_MESSAGE, CONSERVATIVE_REFINE_BELOW
from foliage_tools.lighting.plane_parallel.special import _norm_assoc_legendre


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

"""One Fourier order: boundary-value solution and its evaluation at depths and directions.

:class:`_ModeSolution` adds the direct-beam particular solution to the
homogeneous modes of :func:`~foliage_tools.lighting.plane_parallel.eigen._eigen`, solves the
boundary conditions with scaled exponentials, and evaluates the radiance at the
nodes, its depth integral, and at any direction by the formal solution along
the line of sight. At a resonance (1/mu0 = k_j; package docstring,
:mod:`foliage_tools.lighting.plane_parallel`) :func:`resonance_offsets` picks two perturbed
incidences and :class:`_Combination` combines their solutions.
"""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.lighting.plane_parallel.constants import RESONANCE_STEP, RESONANCE_TOLERANCE
from foliage_tools.lighting.plane_parallel.eigen import _Eigen, _Setup
from foliage_tools.lighting.plane_parallel.special import _conv2, _decay, _norm_assoc_legendre, _phi1, _shc


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

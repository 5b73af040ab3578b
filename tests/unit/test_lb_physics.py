"""Physics of the LB lighting lattice against exact and asymptotic results (issue 4 "How we will know").

* Uniform slab: the paper's lattice vs its exact (two-stream) solution, the ordinates lattice vs the exact
  plane-parallel solver (``plane_parallel.solve_slab``).
* Decay length in a thick uniform absorbing medium vs the lattice's exact dispersion relation and the
  diffusion relation, geist2008 eq. (4), its small-absorption limit.
* Hard cases: sigma_a -> 0, sigma_a = 1, g = ±1, density 0 and 1, one occupied voxel, empty grids.

The horizontally periodic slab
------------------------------
``lb.solve`` has vacuum sides (light leaving the grid is gone, inflow slots
hold fixed boundary densities), so a finite grid is not an infinite slab:
horizontally moving light escapes through the sides. On a horizontally
periodic lattice every (x, y) column of an infinite uniform slab under a
uniform beam is the same, and the lattice reduces exactly to one column:
collision ``f + rho A f`` with A = ``collision.unit_moving_block`` (the same
matrix the fused kernel uses), then streaming that moves direction i by
c_iz in z only (its x/y step lands on an identical column). ``_column`` builds
that linear map T and solves ``(I - T) f = beta`` directly (sparse LU, float64). The
test ``test_periodic_column_is_the_wide_grid_limit_of_the_solver`` checks it
against ``lb.solve`` on a 48 x 48 grid (centre column agrees to 0.3 %; at
24 x 24 the side losses are 4-5 %, at 32 x 32 1.5-2 %: monotone in the width).

``_column`` takes the lattice (``collision``): ``geist2008``, the paper's,
whose slabs ``SLAB_CASES`` check against the lattice's own exact solution (its
column is a two-stream "pile of plates", ``_stokes_pile``; the comments on
``SLAB_CASES`` give its deviations from the exact slab, with the defect of
issue #15 in the oblique case), or the default ``ordinates``; the sun as a
first-collision source is tested the same way in test_lb_slab.py.

Mapping lattice density to optical thickness: one node of density rho
passes 1 - rho*sigma_t of an unscattered beam per step, and
``density_from_lad`` defines rho = 1 - exp(-G LAD dx), i.e. a node layer of
optical thickness -ln(1 - rho) (sigma_t = 1). A slab of H node layers
therefore has tau = -H ln(1 - rho) at normal incidence, single-scattering
albedo omega = sigma_s / sigma_t. Flux: the lattice's conserved quantity is
the density sum_i f_i, and the density crossing a horizontal plane per step
and column is sum over c_iz < 0 (c_iz > 0) of f_i, whatever |c_i|, so
T = sum_{c_iz<0} f_i below the slab, R = sum_{c_iz>0} f_i above it, per unit
incident density (a unit Kronecker beam, ``base_boundary``). These are the
T and R of solve_slab (fractions of the incident horizontal flux).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.linalg import spsolve

from foliage_tools.lighting.lb.collision import Medium, step_density, unit_moving_block
from foliage_tools.lighting.lb.lattice import DIRECTIONS, direction_index
from foliage_tools.lighting.lb import (
    LatticeStabilityError,
    LBParams,
    LBProblem,
    ambient_boundary,
    base_boundary,
    power_weights,
    solve,
    sun_boundary,
)
from foliage_tools.lighting.phase import hg_phase
from foliage_tools.lighting.plane_parallel import solve_slab

CZ = DIRECTIONS[1:, 2]
DOWN = direction_index((0, 0, -1))
OBLIQUE = direction_index((1, 0, -1))


def _column(H: int, rho: float, sigma_a: float, g: float, k: int, *, pad: int = 1, lattice: str = "geist2008") -> np.ndarray:
    """Steady state (nz, 18) of the horizontally periodic lattice: H slab layers, ``pad`` empty layers above and below.

    Lit from the top by the unit Kronecker beam along lattice direction k (c_kz < 0).
    """
    nz = H + 2 * pad
    A = unit_moving_block(Medium((sigma_a,), (1.0 - sigma_a,), (g,)), lattice)[0]
    rq = step_density(rho, lattice)  # per-direction step density (rho for every step on geist2008)
    dens = np.zeros(nz)
    dens[pad : pad + H] = 1.0
    n = 18 * nz
    rows, cols, vals = [], [], []
    for z in range(nz):
        M = np.eye(18) + dens[z] * A * rq[None, :]  # geist2008 eq. (2) collision, f_0 removed
        for q in range(18):
            zt = z + CZ[q]
            # horizontal light in the empty pad layers is never fed (nothing scatters there): drop it,
            # otherwise it would circulate for ever on the periodic lattice (a singular I - T)
            if 0 <= zt < nz and not (CZ[q] == 0 and dens[z] == 0):
                rows += [zt * 18 + q] * 18
                cols += range(z * 18, z * 18 + 18)
                vals += list(M[q])
    beta = np.zeros(n)
    beta[(nz - 1) * 18 + (k - 1)] = 1.0  # the beam enters the top layer along c_k
    T = sparse.csr_matrix((vals, (rows, cols)), shape=(n, n))
    return spsolve((sparse.identity(n, format="csr") - T).tocsc(), beta).reshape(nz, 18)


def _slab_fluxes(H, rho, sigma_a, g, k, lattice="geist2008"):
    """Transmitted and reflected power per unit incident power of the periodic slab (power_weights units)."""
    f = _column(H, rho, sigma_a, g, k, lattice=lattice)
    wq = power_weights(lattice)
    return (f[0, CZ < 0] * wq[CZ < 0]).sum() / wq[k - 1], (f[-1, CZ > 0] * wq[CZ > 0]).sum() / wq[k - 1]


@pytest.mark.slow  # 40-53 s each on 2 cores with a cold numba cache (a new CI venv); tests/unit/test_lb_slab.py covers the column in seconds
@pytest.mark.parametrize("lattice", ["geist2008", "ordinates"])
def test_periodic_column_is_the_wide_grid_limit_of_the_solver(lattice):
    H, rho, sa = 5, 0.3, 0.1
    W = 48
    d = np.zeros((W, W, H + 2))
    d[:, :, 1 : H + 1] = rho
    r = solve(LBProblem(d, Medium((sa,), (1 - sa,), (0.0,)), (base_boundary(DOWN),), lattice=lattice),
              LBParams(tolerance=1e-8, dtype="float64", keep_f=True, solver="iterate"))
    f = r.f[W // 2, W // 2, :, 1:, 0, 0]
    wq = power_weights(lattice)
    T, R = (f[0, CZ < 0] * wq[CZ < 0]).sum(), (f[-1, CZ > 0] * wq[CZ > 0]).sum()
    Tp, Rp = _slab_fluxes(H, rho, sa, 0.0, DOWN, lattice)
    # measured (geist2008): T 0.4211 vs 0.4220 (-0.22 %), R 0.3393 vs 0.3403 (-0.29 %); the finite grid
    # loses light through its sides, so it is below the periodic value and approaches it as W grows
    assert Tp * (1 - 0.01) < T < Tp and Rp * (1 - 0.01) < R < Rp
    # the periodic column conserves energy (power): T + R + absorbed = 1
    fc = _column(H, rho, sa, 0.0, DOWN, lattice=lattice)
    absorbed = sa * (fc[1 : H + 1] * step_density(rho, lattice) * wq).sum()
    assert Tp + Rp + absorbed == pytest.approx(1.0, abs=1e-12)


def _plate(rho: float, sigma_a: float) -> tuple[float, float, float]:
    """One node layer of the isotropic geist2008 column as a plate: transmittance t, reflectance r, and theta.

    geist2008 eqs. (2), (5)-(7) with sigma_t = 1, sigma_s = 1 - sigma_a, g = 0: a node maps each moving
    density f_i -> (1 - rho) f_i + rho sigma_s w_i S, S = sum_j f_j, and on this lattice every step, axial or
    diagonal, is attenuated by the same 1 - rho and moves one layer if c_iz = ±1. The periodic column therefore
    reduces exactly to three totals per node: U (c_z = +1, sum w_i = 1/4), D (c_z = -1, 1/4) and the horizontal
    total h (1/2), which stays in its layer, h = (1 - rho) h + rho sigma_s S / 2, so S = (U + D) / (1 - sigma_s/2).
    A layer sends U_out = t U + r D up and D_out = r U + t D down, r = rho w' / 2, t = 1 - rho + r, with the
    effective albedo w' = sigma_s / (2 - sigma_s). Its transfer matrix [U_z+1, D_z] <- [U_z, D_z-1] is
    [[t - r^2/t, r/t], [-r/t, 1/t]]: det 1, eigenvalues exp(±theta), cosh(theta) = (1 + t^2 - r^2) / (2t), i.e.
    cosh(theta) - 1 = (1 - t - r)(1 - t + r) / (2t) = rho (rho - 2r) / (2t) (used below without cancellation).
    """
    r = 0.5 * rho * (1.0 - sigma_a) / (1.0 + sigma_a)  # sigma_s / (2 - sigma_s) = (1 - sigma_a) / (1 + sigma_a)
    t = 1.0 - rho + r
    return t, r, 2.0 * math.asinh(math.sqrt(rho * (rho - 2.0 * r) / (4.0 * t)))


def _stokes_pile(H: int, rho: float, sigma_a: float) -> tuple[float, float]:
    """T, R of the isotropic geist2008 slab (H layers over vacuum, any beam with c_kz = -1), in closed form.

    H plates of ``_plate`` (Stokes 1862, "pile of plates"): with the transfer matrix P, [R, 1] = P^H [0, T]
    (nothing enters from below, unit density from above), and P^H = U_H-1 P - U_H-2 I (Cayley-Hamilton, U_n the
    Chebyshev polynomials, U_n(cosh theta) = sinh((n + 1) theta) / sinh theta) give
    T = t sinh(theta) / N, R = r sinh(H theta) / N, N = sinh(H theta) - t sinh((H - 1) theta).
    The beam is one of the D directions: the oblique (1, 0, -1) beam has the normal-incidence T and R.
    """
    t, r, th = _plate(rho, sigma_a)
    N = math.sinh(H * th) - t * math.sinh((H - 1) * th)
    return t * math.sinh(th) / N, r * math.sinh(H * th) / N


def _geist2008_adding(H: int, rho: float, sigma_a: float, g: float, k: int) -> tuple[float, float]:
    """T, R of the periodic geist2008 slab (any g) by adding H identical layers (van de Hulst 1980, "adding").

    Independent of ``collision``: the collision is written out from geist2008 eqs. (2), (8), (9) (multiplicity 2
    axial, 1 diagonal, sec. 2.2; sigma_t = 1, f_0 removed), the horizontal directions are eliminated per layer
    (they never leave it: h = M_hh h + M_hv v), and layers are added on top of the slab one at a time.
    """
    c = DIRECTIONS[1:]
    n = c / np.linalg.norm(c, axis=1, keepdims=True)
    m = np.where(np.abs(c).sum(axis=1) == 1, 2.0, 1.0)
    p = m[:, None] * (1.0 - g * g) / (1.0 + g * g - 2.0 * g * (n @ n.T)) ** 1.5  # eq. (9), times 24 w_i
    M = (1.0 - rho) * np.eye(18) + rho * (1.0 - sigma_a) * p / p.sum(axis=0)  # eq. (8): q_ij = w_i pn_ij
    u, d, h = (np.flatnonzero(c[:, 2] == s) for s in (1, -1, 0))
    v = np.concatenate([u, d])
    L = M[np.ix_(v, v)] + M[np.ix_(v, h)] @ np.linalg.solve(np.eye(len(h)) - M[np.ix_(h, h)], M[np.ix_(h, v)])
    tu, rud, rdu, td = L[:5, :5], L[:5, 5:], L[5:, :5], L[5:, 5:]  # (up, down) arriving -> (up, down) leaving
    R, T = np.zeros((5, 5)), np.eye(5)  # an empty slab over vacuum
    for _ in range(H):  # a new layer on top: X = what it sends down into the slab, per unit from above
        X = np.linalg.solve(np.eye(5) - rdu @ R, td)
        R, T = rud + tu @ R @ X, T @ X
    j = int(np.flatnonzero(d == k - 1)[0])
    return float(T[:, j].sum()), float(R[:, j].sum())


# (H, rho, sigma_a, g, lattice direction). The comments give the exact slab (solve_slab, same tau, omega, HG g, mu0)
# and the lattice's relative deviation from it, computed from the closed form / the adding solution: documentation
# of the paper's angular model (see the test's docstring), not bounds.
SLAB_CASES = [
    # normal incidence, isotropic: tau = 1.054, omega = 0.9 (exact T 0.5757, R 0.2752; lattice +0.04 %, -6.1 %)
    (10, 0.1, 0.1, 0.0, DOWN),
    # thicker: tau = 2.231 (exact T 0.3171, R 0.3729; lattice +7.9 %, -2.9 %)
    (10, 0.2, 0.1, 0.0, DOWN),
    # nearly conservative, omega = 0.99 (exact T 0.6382, R 0.3447; lattice +1.2 %, -2.9 %)
    (10, 0.1, 0.01, 0.0, DOWN),
    # forward scattering, lattice HG g = 0.5 vs continuous HG g = 0.5 (exact T 0.7261, R 0.1351; lattice +2.9 %,
    # -23 %; the lattice's HG column of an axial direction has mean cosine 0.585, and against the exact slab at
    # g = 0.585 the lattice is -1.3 %, -4.3 %, an isotropic-size error)
    (10, 0.1, 0.1, 0.5, DOWN),
    # oblique lattice direction (1, 0, -1), mu0 = 1/sqrt2 (exact T 0.4844, R 0.3388; lattice +19 %, -24 %: it
    # gives its normal-incidence answer, the first case, issue #15)
    (10, 0.1, 0.1, 0.0, OBLIQUE),
]


@pytest.mark.parametrize("H, rho, sa, g, k", SLAB_CASES)
def test_uniform_slab_on_the_geist2008_lattice_against_its_exact_solution(H, rho, sa, g, k):
    """The geist2008 slab is its two-stream closed form; how far that is from the exact slab is documented.

    Asserted: ``_slab_fluxes`` (the sparse solve of the lattice with the library's collision block) equals
    ``_geist2008_adding`` (the same lattice from the paper's equations, solved by adding layers) and, at g = 0,
    the closed form ``_stokes_pile``. Tolerance 1e-10: both sides are direct float64 solves of small
    well-conditioned systems (they agree to ~1e-15), so anything above round-off is a defect (a dropped or
    mis-weighted direction, a wrong sigma_a or g, a wrong step rule).

    Why not a bound against the exact slab (``solve_slab``): none follows from anything but the lattice model
    itself. By ``_plate`` the isotropic geist2008 column is a two-stream at mu = ±1 with albedo sigma_s / (2 -
    sigma_s) (the horizontal half of the scattered light re-collides in its layer); as rho -> 0 at fixed tau it
    tends to Schuster's two-stream, not to the transport equation. Refining the lattice moves the first case
    away from the exact slab (R -6.1 % at H = 10, -6.7 % at H = 20, -7.3 % in the limit; T +0.04 % -> -0.5 %),
    so its deviations (``SLAB_CASES`` comments) are the paper's angular model, not numerical error of the code,
    and a bound on them could only be a pin of today's value.
    """
    T, R = _slab_fluxes(H, rho, sa, g, k)
    Ta, Ra = _geist2008_adding(H, rho, sa, g, k)
    assert T == pytest.approx(Ta, rel=1e-10) and R == pytest.approx(Ra, rel=1e-10), (T, Ta, R, Ra)
    if g == 0.0:
        Ts, Rs = _stokes_pile(H, rho, sa)
        assert T == pytest.approx(Ts, rel=1e-10) and R == pytest.approx(Rs, rel=1e-10), (T, Ts, R, Rs)
    # the lattice's direct beam is exactly (1 - rho)^H = exp(-tau) along any lattice direction
    tau = -H * math.log1p(-rho)
    Tdir = _column(H, rho, 1.0, 0.0, k)[0, k - 1]  # sigma_s = 0: only the unscattered beam
    assert Tdir == pytest.approx(math.exp(-tau), rel=1e-12)


# The same slabs on the ordinates lattice (the default; collision docstring): (case, measured relative error of T,
# of R). The oblique beam now crosses the slab at its true slant, exp(-tau sqrt2): T +0.3 % / R -4.2 % instead of
# +19 % / -24 %, and g = 0.5 R -8.6 % instead of -23 % (the ordinate weights). The model is deterministic; the
# bound 0.01 around the measured value only absorbs harmless changes (e.g. summation order in spsolve).
ORDINATE_SLAB_CASES = [
    (SLAB_CASES[0][:5], -0.0011, -0.0368),
    (SLAB_CASES[1][:5], +0.0373, -0.0088),
    (SLAB_CASES[2][:5], +0.0063, -0.0162),
    (SLAB_CASES[3][:5], +0.0035, -0.0855),
    (SLAB_CASES[4][:5], +0.0027, -0.0424),
]


@pytest.mark.parametrize("case, err_t, err_r", ORDINATE_SLAB_CASES)
def test_uniform_slab_on_the_ordinates_lattice(case, err_t, err_r):
    H, rho, sa, g, k = case
    T, R = _slab_fluxes(H, rho, sa, g, k, "ordinates")
    tau = -H * math.log1p(-rho)
    mu0 = float(-DIRECTIONS[k, 2] / np.linalg.norm(DIRECTIONS[k]))
    ex = solve_slab(tau=tau, omega=1.0 - sa, mu0=mu0, phase=hg_phase(g))
    assert T / ex.transmittance - 1.0 == pytest.approx(err_t, abs=0.01)
    assert R / ex.reflectance - 1.0 == pytest.approx(err_r, abs=0.01)
    # the direct beam crosses H layers of |c_k| dx each: exp(-tau / mu0) exactly, also on the diagonal
    Tdir = _column(H, rho, 1.0, 0.0, k, lattice="ordinates")[0, k - 1]
    assert Tdir == pytest.approx(math.exp(-tau / mu0), rel=1e-12)


def test_oblique_lattice_beam_sees_the_normal_incidence_slab():
    # the documented diagonal-step convention, made visible: with isotropic scattering the lattice's
    # (1, 0, -1) beam gives exactly the T and R of its (0, 0, -1) beam
    a = _slab_fluxes(10, 0.1, 0.1, 0.0, DOWN)
    b = _slab_fluxes(10, 0.1, 0.1, 0.0, OBLIQUE)
    np.testing.assert_allclose(a, b, rtol=1e-10)


# --------------------------------------------------------------------------- diffusion, geist2008 eq. (4)


def _eq4_diffusion(rho: float, sigma_a: float, sigma_t: float = 1.0) -> float:
    """geist2008 eq. (4) with lambda = tau = 1 (one lattice step per update).

    Omega is multiplied by the node density (geist2008 sec. 2.2), so a node
    of density rho acts as sigma_t -> rho sigma_t, sigma_a -> rho sigma_a.
    """
    st, sa = rho * sigma_t, rho * sigma_a
    return ((2.0 / st) - 1.0) / (4.0 * (1.0 + sa))


@pytest.mark.parametrize("rho, sigma_a", [(0.5, 0.001), (0.5, 0.01), (0.9, 0.01), (0.5, 0.1), (0.9, 0.1)])
def test_decay_in_a_thick_absorbing_medium_follows_eq4_diffusion(rho, sigma_a):
    """In a uniform absorbing medium the field decays as exp(-kappa z); eq. (4) diffusion is its small-sigma_a limit.

    Diffusion: steady geist2008 eq. (3) with an absorption sink, D u'' = mu_a u, mu_a = rho sigma_a (the fraction
    of the density absorbed per step), D from eq. (4): kappa_d^2 = mu_a / D = 4 rho^2 sigma_a (1 + rho sigma_a) /
    (2 - rho).

    The lattice's exact kappa: inside the slab the isotropic column is the plate recursion of ``_plate``, whose
    solutions are exactly A exp(theta z) + B exp(-theta z) (the beam too: it is one of the D directions). So
    (u(z+1) + u(z-1)) / (2 u(z)) = cosh(theta) at every interior node, whatever A and B; the measured kappa must
    equal theta to 1e-9 (round-off: ~1e-15 in u over kappa^2 >= 5e-4 in the second difference; 1e-12 today).
    The slab is 12 diffusion lengths thick, the setting of eq. (4), though the three-point form does not need it.

    Eq. (4) against that: with sigma_t = 1, cosh(kappa) - 1 = C = 2 rho^2 sigma_a / (2 - rho + sigma_a (2 - 3 rho))
    (``_plate``'s t, r written out) and kappa^2 = 2C - C^2/3 + 4C^3/45 - ..., so
        rel = kappa / kappa_d - 1 = c1 sigma_a + c2 sigma_a^2 + ...,  c1 = -(2 - rho - 2 rho^2/3) / (2 (2 - rho))
    (-0.444 at rho = 0.5, -0.255 at rho = 0.9): eq. (4) is exact to leading order and the lattice decays slower.
    c2 = +0.20 (rho = 0.5), +0.29 (rho = 0.9), at most 0.41 for rho in (0, 1], and the sigma_a^3 term is negative,
    hence c1 sigma_a <= rel <= c1 sigma_a + sigma_a^2 / 2 (< 0) for sigma_a <= 0.1. (Case's dispersion relation of
    continuous isotropic transport, kappa^2 = 3 sigma_a (1 + 4 sigma_a / 5 + ...), is not the reference: the lattice
    column is a two-stream; transport decays faster than its diffusion limit, the lattice slower.)
    """
    D = _eq4_diffusion(rho, sigma_a)
    kappa_d = math.sqrt(rho * sigma_a / D)
    H = int(min(500, 12 / kappa_d))
    u = _column(H, rho, sigma_a, 0.0, DOWN).sum(axis=1)
    z0 = H // 2  # z index grows upward, toward the lit top; z0 - 1 .. z0 + 1 are slab layers
    kappa = 2.0 * math.asinh(math.sqrt((u[z0 + 1] + u[z0 - 1] - 2.0 * u[z0]) / (4.0 * u[z0])))  # arccosh, stable
    assert kappa == pytest.approx(_plate(rho, sigma_a)[2], rel=1e-9)
    rel = kappa / kappa_d - 1.0
    c1 = -(2.0 - rho - 2.0 * rho**2 / 3.0) / (2.0 * (2.0 - rho))
    assert c1 * sigma_a - 1e-9 <= rel <= c1 * sigma_a + sigma_a**2 / 2, (rel, c1 * sigma_a)


# --------------------------------------------------------------------------- hard cases


def _check(r, pb_inflow_conserved=False):
    assert r.converged, (r.residual, r.iterations)
    assert np.isfinite(r.energy_density).all() and (r.energy_density >= 0).all()
    np.testing.assert_allclose(r.inflow, r.outflow + r.absorbed, rtol=1e-6)
    if pb_inflow_conserved:
        assert np.abs(r.absorbed).max() == 0.0


@pytest.mark.parametrize(
    "sigma_a, sigma_s, g",
    [(0.0, 1.0, 0.0), (1e-12, 1.0 - 1e-12, 0.3), (0.0, 1.0, -1.0), (1.0, 0.0, 0.0), (0.5, 0.5, 1.0), (0.5, 0.5, -1.0), (0.0, 1.0, 1.0)],
)
def test_extreme_media_at_full_density_give_finite_balanced_fields(sigma_a, sigma_s, g):
    # density 1 everywhere with sigma_t = 1 is the stability limit rho sigma_t = 1 itself (allowed)
    pb = LBProblem(np.ones((7, 6, 5)), Medium((sigma_a,), (sigma_s,), (g,)), (sun_boundary((0.3, -0.2, 1.0)), ambient_boundary()))
    r = solve(pb, LBParams(dtype="float64", tolerance=1e-10, max_sweeps=50_000))
    _check(r, pb_inflow_conserved=sigma_a == 0.0)


def test_conservative_dense_cube_converges_with_the_default_solver():
    # sigma_a = 0: the only loss is leakage through the boundary (slowest case of DESIGN.md sec. 4)
    pb = LBProblem(np.ones((14, 14, 14)), Medium((0.0,), (1.0,), (0.0,)), (sun_boundary((0.0, 0.0, 1.0)),))
    r = solve(pb, LBParams(tolerance=1e-6))
    assert r.converged and np.isfinite(r.energy_density).all()
    np.testing.assert_allclose(r.outflow, r.inflow, rtol=1e-4)
    assert r.absorbed.max() == 0.0


def test_backscatter_delta_at_full_density_reflects_everything_at_the_first_layer():
    # g = -1, sigma_a = 0, rho = 1: every beam reverses at the first node it reaches (geist2008 "brown")
    pb = LBProblem(np.ones((4, 4, 5)), Medium((0.0,), (1.0,), (-1.0,)), (base_boundary(DOWN),))
    r = solve(pb, LBParams(dtype="float64", keep_f=True))
    u = r.energy_density[..., 0, 0]
    np.testing.assert_array_equal(u[:, :, -1], 1.0)  # the arriving beam; the reversed one has left
    np.testing.assert_array_equal(u[:, :, :-1], 0.0)
    np.testing.assert_allclose(r.outflow, r.inflow)


@pytest.mark.parametrize(
    "lattice, axial, diagonal",
    # geist2008: the shares of eqs. (6)-(7), 1/12 axial and 1/24 diagonal. ordinates: the ordinate weights
    # 1/30 and 1/15 of the scattered power, and a diagonal line stands for the cross-section 1/sqrt2 (in
    # lattice spacings), so its power share 1/15 is the irradiance sqrt2/15 (collision, "In-scattering")
    [("geist2008", 1 / 12, 1 / 24), ("ordinates", 1 / 30, math.sqrt(2) / 15)],
)
def test_single_occupied_voxel_closed_form(lattice, axial, diagonal):
    # a unit beam along -z hits one node of density 1 (sigma_t = 1: it all interacts); sigma_s is
    # shared isotropically, sigma_a is absorbed, and each share leaves along its own lattice line
    sa, ss = 0.3, 0.7
    rho = np.zeros((5, 5, 5))
    rho[2, 2, 2] = 1.0
    r = solve(LBProblem(rho, Medium((sa,), (ss,), (0.0,)), (base_boundary(DOWN),), lattice=lattice),
              LBParams(dtype="float64", keep_f=True))
    u = r.energy_density[..., 0, 0]
    assert r.absorbed[0, 0] == pytest.approx(sa, rel=1e-12)
    assert r.inflow[0, 0] == pytest.approx(25.0)  # 5 x 5 columns of unit beam enter the top
    assert u[2, 2, 1] == pytest.approx(ss * axial, rel=1e-12)  # directly below: only the scattered -z share
    assert u[2, 2, 0] == pytest.approx(ss * axial, rel=1e-12)
    assert u[3, 2, 2] == pytest.approx(1.0 + ss * axial, rel=1e-12)  # own beam + the +x share
    assert u[3, 3, 2] == pytest.approx(1.0 + ss * diagonal, rel=1e-12)  # own beam + the (1, 1, 0) share
    assert u[2, 2, 3] == pytest.approx(1.0 + ss * axial, rel=1e-12)  # above: incoming beam + the +z share


@pytest.mark.parametrize("lattice", ["geist2008", "ordinates"])
def test_one_node_grid_and_empty_grids(lattice):
    # 1 x 1 x 1: every slot is an inflow slot
    r = solve(LBProblem(np.ones((1, 1, 1)), Medium((0.2,), (0.8,), (0.0,)), (ambient_boundary(),), lattice=lattice),
              LBParams(dtype="float64"))
    _check(r)
    assert r.energy_density[0, 0, 0, 0, 0] == pytest.approx(18.0)  # arriving densities, all boundary
    # sigma_a of the arriving power (density 1: every step interacts); geist2008 counts density, so 0.2 * 18
    assert r.absorbed[0, 0] == pytest.approx(0.2 * power_weights(lattice).sum())
    for shape in ((0, 4, 4), (4, 0, 4), (4, 4)):
        with pytest.raises(ValueError, match="3D grid"):
            LBProblem(np.zeros(shape), Medium((0.1,), (0.9,), (0.0,)), (ambient_boundary(),))


def test_density_just_above_the_stability_limit_is_a_clear_error():
    with pytest.raises(LatticeStabilityError, match="rho \\* sigma_t"):
        LBProblem(np.full((3, 3, 3), 1.0 + 1e-6), Medium((0.5,), (0.5,), (0.0,)), (ambient_boundary(),))

"""Physics of the LB lighting lattice against exact and asymptotic results (issue 4 "How we will know").

* Uniform slab vs the exact plane-parallel solver (``plane_parallel.solve_slab``).
* Decay length in a thick uniform absorbing medium vs the diffusion relation, geist2008 eq. (4).
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
whose slab errors ``SLAB_CASES`` record (the defect of issue #15 in the oblique
case), or the default ``ordinates``; the sun as a first-collision source is
tested the same way in test_lb_slab.py.

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

from foliage_tools.lighting.collision import Medium, step_density, unit_moving_block
from foliage_tools.lighting.lattice import DIRECTIONS, direction_index
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


# (H, rho, sigma_a, g, lattice direction, measured relative error of T, of R). Measured with this
# test's helper; each bound is 1.5 x the measured error (+ 0.005 so a near-zero error is not a zero bound).
SLAB_CASES = [
    # normal incidence, isotropic: tau = 1.054, omega = 0.9 (exact T 0.5757, R 0.2752)
    (10, 0.1, 0.1, 0.0, DOWN, +0.0004, -0.061),
    # thicker: tau = 2.231 (exact T 0.3171, R 0.3729)
    (10, 0.2, 0.1, 0.0, DOWN, +0.079, -0.029),
    # nearly conservative, omega = 0.99 (exact T 0.6382, R 0.3447)
    (10, 0.1, 0.01, 0.0, DOWN, +0.012, -0.029),
    # forward scattering, lattice HG g = 0.5 vs continuous HG g = 0.5 (exact T 0.7261, R 0.1351)
    (10, 0.1, 0.1, 0.5, DOWN, +0.029, -0.230),
    # oblique lattice direction (1, 0, -1), mu0 = 1/sqrt2 (exact T 0.4844, R 0.3388)
    (10, 0.1, 0.1, 0.0, OBLIQUE, +0.189, -0.237),
]


@pytest.mark.parametrize("H, rho, sa, g, k, err_t, err_r", SLAB_CASES)
def test_uniform_slab_against_the_exact_plane_parallel_solver(H, rho, sa, g, k, err_t, err_r):
    """Lattice slab vs discrete ordinates with the same tau, omega, HG g and mu0 = |n_kz|.

    What the measured errors mean. At normal incidence the 18-direction angular
    discretisation and the step-wise attenuation give T within 8 % and R within
    6 % (isotropic). The lattice's HG weights on 18 directions are not a
    continuous HG (their mean cosine differs from g, see test_lb_solver), so
    g = 0.5 under-predicts R by 23 %. An oblique beam is the worst case: the
    lattice attenuates a diagonal step by the same 1 - rho as an axial one
    (the paper's convention, ``collision`` docstring), so its direct beam
    crosses H layers as if at normal incidence, exp(-tau) instead of
    exp(-tau/mu0): with isotropic scattering the lattice's oblique T and R are
    exactly its normal-incidence ones, +19 % and -24 % off the exact oblique slab.
    """
    T, R = _slab_fluxes(H, rho, sa, g, k)
    tau = -H * math.log1p(-rho)
    mu0 = float(-DIRECTIONS[k, 2] / np.linalg.norm(DIRECTIONS[k]))
    ex = solve_slab(tau=tau, omega=1.0 - sa, mu0=mu0, phase=hg_phase(g))
    rel_t = T / ex.transmittance - 1.0
    rel_r = R / ex.reflectance - 1.0
    assert abs(rel_t) <= 1.5 * abs(err_t) + 0.005, (rel_t, err_t)
    assert abs(rel_r) <= 1.5 * abs(err_r) + 0.005, (rel_r, err_r)
    # the lattice's direct beam is exactly (1 - rho)^H = exp(-tau) along any lattice direction
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


@pytest.mark.parametrize(
    "rho, sigma_a, measured",
    [
        # (measured relative error of the decay constant kappa)
        (0.5, 0.001, -0.0004),
        (0.5, 0.01, -0.0044),
        (0.9, 0.01, -0.0025),
        (0.5, 0.1, -0.0425),
        (0.9, 0.1, -0.0227),
    ],
)
def test_decay_in_a_thick_absorbing_medium_follows_eq4_diffusion(rho, sigma_a, measured):
    """Deep in a thick uniform slab the field decays as exp(-kappa z) with kappa = sqrt(mu_a / D).

    Steady state of geist2008 eq. (3) with an absorption sink: D u'' = mu_a u,
    mu_a = rho sigma_a (the fraction of the density absorbed per step), D from
    eq. (4). The lattice (periodic column, see module doc) is lit by a unit
    beam from the top of a slab 12 diffusion lengths thick; kappa is measured
    from u(z+1)/u(z) in its middle, where the beam (decaying as (1-rho)^z) and
    the bottom boundary are negligible. Diffusion is the small-absorption
    limit: measured agreement 0.04-0.44 % at sigma_a <= 0.01 and 2-4 % at
    sigma_a = 0.1 (the lattice decays a little slower than diffusion predicts
    when an absorption length is only a few mean free paths). Bound: 1.5 x
    measured + 0.002.
    """
    D = _eq4_diffusion(rho, sigma_a)
    kappa_d = math.sqrt(rho * sigma_a / D)
    H = int(min(500, 12 / kappa_d))
    u = _column(H, rho, sigma_a, 0.0, DOWN).sum(axis=1)
    z0 = H // 2
    kappa = math.log(u[z0 + 1] / u[z0])  # z index grows upward, toward the lit top
    rel = kappa / kappa_d - 1.0
    assert abs(rel) <= 1.5 * abs(measured) + 0.002, (rel, measured)


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

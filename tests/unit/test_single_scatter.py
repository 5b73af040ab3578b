"""The exact once-scattered light of lighting.single_scatter, and the lattice's first order it replaces."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, special

from foliage_tools.lighting import lb
from foliage_tools.lighting.lb import single_scatter as ss
from foliage_tools.lighting.lb.collision import Medium


def _slab(nz=10, ext=0.15, n=81, omega=0.2, elevation=60.0, g=0.0, phase="hg"):
    """A laterally wide uniform slab of nz node layers, ext optical depth per lattice spacing (sigma_t = 1)."""
    rho = np.full((n, n, nz), -math.expm1(-ext))  # 1 - rho sigma_t = exp(-ext)
    med = Medium(sigma_a=(1 - omega,), sigma_s=(omega,), g=(g,), phase=phase)
    e = math.radians(elevation)
    travel = np.array([-math.cos(e), 0.0, -math.sin(e)])
    return lb.LBProblem(density=rho, medium=med, boundaries=(lb.sun_source(-travel),)), travel


def _exact_slab_once_scattered(tau_node, tau0, mu0, omega):
    """Isotropic scattering, beam of irradiance 1: u_1(tau) = (omega/2) int_0^tau0 e^(-t/mu0) E1(|tau - t|) dt.

    (Chandrasekhar 1960 sec. 11 with the source of a collimated beam; u = 2 pi int I dmu and
    int_0^1 e^(-x/mu) dmu / mu = E1(x).)
    """
    f = lambda t: math.exp(-t / mu0) * special.exp1(abs(tau_node - t)) if t != tau_node else 0.0
    return 0.5 * omega * (integrate.quad(f, 0, tau_node, limit=200)[0] + integrate.quad(f, tau_node, tau0, limit=200)[0])


@pytest.mark.parametrize("elevation", [30.0, 60.0, 85.0])
def test_uniform_slab_against_the_closed_form(elevation):
    nz, ext, omega = 10, 0.15, 0.2
    prob, travel = _slab(nz, ext, omega=omega, elevation=elevation)
    beams = lb.beam_fields(prob)
    col = np.array([[40, 40, k] for k in range(nz)])
    u1 = ss.once_scattered_energy(np.full(prob.shape, ext), omega * beams.power[..., 0, :], np.zeros(prob.shape, np.intp),
                                  travel, [prob.medium], col)[:, 0]
    mu0 = math.sin(math.radians(elevation))
    want = np.array([_exact_slab_once_scattered(ext * (nz - k - 0.5), ext * nz, mu0, omega) for k in range(nz)])
    # The medium is exact per cell and the set's cosines integrate mu by the midpoint rule; what remains is
    # (a) the 40 cells to either side (optical half-width 6: e^-6 = 0.25 % of the horizontal paths leak) and
    # (b) each cell's beam power taken along the chord through its centre, its source then constant over the
    # cell: O((ext/mu0)^2 / 12) = 0.2 % at 60 degrees, 0.8 % at 30. 1.5 % covers both at every elevation.
    np.testing.assert_allclose(u1, want, rtol=0.015)


def test_phase_is_normalised_on_the_set_and_is_the_bilambertian_one():
    dirs = ss.fibonacci_directions(32)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-12)
    # the z cosines are the midpoints of 8 equal intervals of [-1, 1], four azimuths a quarter turn apart each
    np.testing.assert_allclose(np.sort(dirs[:, 2]), np.repeat(-1 + (2 * np.arange(8) + 1) / 8, 4), atol=1e-12)
    turned = dirs @ np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]])  # 90 degrees about z
    assert np.abs(turned[:, None, :] - dirs[None, :, :]).sum(axis=2).min(axis=1).max() < 1e-12
    d = np.array([0.0, 0.0, -1.0])
    p = ss._phase_on(dirs, d, 0.0, "bilambertian")
    assert p.mean() == pytest.approx(1.0)
    # r = t (g = 0): a two-sided Lambertian canopy scatters as much forward as backward, and most sideways
    # (Ross 1981 ch. 5: Gamma ~ sin(beta) - beta cos(beta) + sin(beta) + (pi - beta) cos(beta) = 2 sin + (pi - 2 beta) cos)
    mu = dirs @ d
    beta = np.arccos(mu)
    want = 2 * np.sin(beta) + (math.pi - 2 * beta) * np.cos(beta)
    np.testing.assert_allclose(p, want / want.mean(), rtol=1e-10)
    back = ss._phase_on(dirs, d, -1.0, "hg")  # HG at g = -1: everything straight back, on the nearest direction
    assert back.max() == pytest.approx(32.0) and np.argmax(back) == np.argmax(-mu)


def test_the_lattices_first_order_is_what_the_result_reports():
    # At a tiny albedo the scattered field is its first order up to O(omega^2): energy - beam = once_scattered
    prob, _ = _slab(nz=6, ext=0.3, n=12, omega=1e-4, elevation=50.0)
    res = lb.solve(prob, lb.LBParams(tolerance=1e-9, dtype="float64"))
    scattered = res.energy_density - res.beam_direct
    np.testing.assert_allclose(scattered, res.once_scattered, rtol=1e-3, atol=1e-12)
    assert res.once_scattered.max() > 0


def test_correction_on_a_slab_leaves_the_higher_orders_and_fills_only_next_to_computed_nodes():
    prob, _ = _slab(nz=8, ext=0.2, n=24, omega=0.9, elevation=45.0)
    res = lb.solve(prob, lb.LBParams(tolerance=1e-7))
    mask = np.zeros(prob.shape, bool)
    mask[8:16, 8:16, :] = True
    fill = np.zeros(prob.shape, bool)
    fill[7:17, 7:17, :] = True
    out = ss.corrected_energy(prob, res, mask=mask, fill=fill)
    e = np.asarray(res.energy_density, np.float64)
    far = ~fill
    np.testing.assert_array_equal(out[far], e[far])
    delta = (out - e)[..., 0, 0]
    assert np.all(delta[mask] != 0)
    # a filled node takes the mean correction of its computed 26-neighbours
    i, j, k = 7, 10, 3
    nb = delta[6:9, 9:12, 2:5][mask[6:9, 9:12, 2:5]]
    assert delta[i, j, k] == pytest.approx(nb.mean(), rel=1e-9)
    # the correction is the exact first order minus the lattice's, node by node
    u1 = ss.once_scattered_energy(-np.log(1 - prob.density), 0.9 * res.beam_power[..., 0, :], np.zeros(prob.shape, np.intp),
                                  np.asarray(prob.boundaries[0].beam), [prob.medium], np.argwhere(mask))
    np.testing.assert_allclose(delta[mask], u1[:, 0] - res.once_scattered[..., 0, 0][mask], rtol=1e-5, atol=1e-9)


def test_refuses_non_finite_media():
    ext = np.full((4, 4, 4), np.nan)
    with pytest.raises(ValueError, match="finite"):
        ss.once_scattered_energy(ext, np.zeros((4, 4, 4, 1)), np.zeros((4, 4, 4), np.intp), np.array([0, 0, -1.0]),
                                 [Medium((0.5,), (0.5,), (0.0,))], np.zeros((1, 3), int))

"""LB in the plane-parallel case against the exact slab solution (issue #15, lattice-Boltzmann).

The setting of the issue: a uniform layer of optical thickness tau = 1.5 (LAI 3, G = 0.5) of randomly
oriented two-sided leaves with r = t (0.1 and 0.45), under a sun at 30, 60 and 85 degrees. The exact
answer is ``plane_parallel.solve_slab`` with the bi-Lambertian canopy phase function: per leaf
E_scattered = actinic_flux_diffuse / 2 and E_direct = (actinic_flux - actinic_flux_diffuse) / 2
(tests/unit/test_reference.py::test_periodic_layer_matches_plane_parallel_solver). What ``foliage lb``
solves by default: the ``ordinates`` lattice (true step lengths, ordinate weights), the bi-Lambertian
phase function on the lattice, and the sun as a first-collision source (the exactly attenuated sun,
scattered once at every node; ``lb.beam_fields``), E = u / 2 at the node.

The error is split into parts measured separately, each with its own bound:

1. Implementation: ``lb.solve`` (fused kernels, march, source) on a wide finite grid against a
   horizontally periodic column of the same lattice built here from the same collision matrices
   (``_column``; test_lb_physics.py does the same for boundary inflow). The finite grid differs only by
   what its sides lose or gain: 1.8 % at 64 x 64 (measured, 0.24 % at 96 x 96); bound 2.5 %.
2. Spatial resolution: the column with 10 node layers (``foliage lb --resolution 64`` puts 9.6 in the
   1.5 m layer of examples/make_layer.py) against 80 layers (converged: 160 layers differ from 80 by
   < 0.8 % in every bin, 40 by < 2.4 %). Measured up to 12.5 % (the bottom bin at 30 degrees, r = t =
   0.1), mostly < 5 %.
3. Angular discretisation, the part no resolution removes: the 80-layer column against the exact
   solution. The 18 directions of D3Q19 put 40 % of the scattering weight (6 axial x 1/30 + 12
   diagonal x 1/15: the 4 axial and 4 diagonal directions of the horizontal plane) on directions that
   never move vertically in a slab aligned with the lattice; that light cannot escape through the top or
   the bottom, so the lattice overestimates E_scattered near both (+20 .. +42 % in the top bin, up to
   +16 % in the bottom one) and by 0 .. +13 % inside. geist2008's own weights (1/12, 1/24) put 50 % there
   and are worse (+33 .. +70 % in the top bin on this lattice at 10 layers); no cubic-symmetric
   weighting (6a + 12b = 1) puts less than 1/3 there (4a + 4b = 2/3 - 4b, b <= 1/12). Bound: the measured values +- 3 % (the column is deterministic; the tolerance
   absorbs harmless changes such as the interpolation between nodes).

So with default settings the lattice is *not* within 10 % of the exact E_scattered in the top and bottom
bins of the layer, at any resolution; parts 1-3 say by how much and why.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.linalg import spsolve

from foliage_tools.lighting.lb.collision import Medium, source_weights, step_density, unit_moving_block
from foliage_tools.lighting.lb.lattice import DIRECTIONS, STEP_LENGTHS
from foliage_tools.lighting.lb import LBParams, LBProblem, solve, sun_source
from foliage_tools.lighting.phase import canopy_bilambertian_phase
from foliage_tools.lighting.plane_parallel import solve_slab

CZ = DIRECTIONS[1:, 2]
TAU = 1.5
#: channel 0: r = t = 0.1 (albedo 0.2), channel 1: r = t = 0.45 (albedo 0.9); sigma_t = 1, g = 0
MEDIUM = Medium((0.8, 0.1), (0.2, 0.9), (0.0, 0.0), phase="bilambertian")
RT = (0.1, 0.45)


def _beam(elevation):
    e = math.radians(elevation)
    return np.array([-math.cos(e), 0.0, -math.sin(e)])  # the direction the sunlight travels


def _column(H: int, kappa: float, medium: Medium, beam, *, pad: int = 1):
    """Horizontally periodic ordinates lattice of H layers (node density 1 - exp(-kappa)) under a unit beam.

    Returns the steady arriving densities per channel (list of (nz, 18)), the exact unscattered beam at
    the node centres (nz,; sigma_t = 1 in every channel) and the depth of each node centre below the slab
    top in lattice spacings (nz,; negative above). Layer z counts from the bottom. The source is that of
    ``lb.beam_fields`` written out for a horizontally uniform slab: the ray from a node centre to the
    sun crosses depth / mu0 of medium, tau_up = tau_c - ext l_d / 2 with l_d = 1 / max_k |d_k| the
    chord through the cell, cell loss exp(-tau_up) (1 - exp(-ext l_d)) / l_d, handed to direction i as
    (sigma_s / sigma_t) q_i(d) |c_i| times that.
    """
    nz = H + 2 * pad
    rho = -math.expm1(-kappa)
    rq = step_density(rho, "ordinates")
    A = unit_moving_block(medium, "ordinates")
    dens = np.zeros(nz)
    dens[pad : pad + H] = 1.0
    depth = pad + H - np.arange(nz) - 0.5
    d = np.asarray(beam, dtype=float) / np.linalg.norm(beam)
    mu0, chord = -d[2], 1.0 / np.abs(d).max()
    out = []
    for c in range(medium.channels):
        n = 18 * nz
        rows, cols, vals = [], [], []
        for z in range(nz):
            M = np.eye(18) + dens[z] * A[c] * rq[None, :]
            for q in range(18):
                zt = z + CZ[q]
                # horizontal light in the empty pad layers is never fed: drop it (a singular I - T otherwise)
                if 0 <= zt < nz and not (CZ[q] == 0 and dens[z] == 0):
                    rows += [zt * 18 + q] * 18
                    cols += range(z * 18, z * 18 + 18)
                    vals += list(M[q])
        T = sparse.csr_matrix((vals, (rows, cols)), shape=(n, n))
        ext = -math.log1p(-rho * medium.sigma_t[c])
        tau_c = ext * np.clip(depth, 0.0, H) / mu0
        power = dens * np.exp(-(tau_c - 0.5 * chord * ext)) * -math.expm1(-chord * ext) / chord
        s = (medium.sigma_s[c] / medium.sigma_t[c]) * source_weights(d, medium.g[c], medium.phase) * STEP_LENGTHS[1:]
        beta = np.zeros(n)
        for z in range(nz):
            for q in range(18):
                zt = z + CZ[q]
                if 0 <= zt < nz:
                    beta[zt * 18 + q] += s[q] * power[z]
        out.append(spsolve((sparse.identity(n, format="csr") - T).tocsc(), beta).reshape(nz, 18))
    direct = np.exp(-kappa * np.clip(depth, 0.0, H) / mu0)
    return out, direct, depth


def _exact(rt, mu0, depths):
    return solve_slab(tau=TAU, omega=2 * rt, mu0=mu0, phase=canopy_bilambertian_phase(reflectance=rt, transmittance=rt),
                      depths=depths)


def _bin_errors(depth, e_nodes, rt, mu0, nbins=5, fine=1000):
    """Relative error of the depth-bin means of E (nodes linearly interpolated in depth, as leaves at every
    depth would sample them) against the exact E_scattered."""
    t = (np.arange(fine) + 0.5) / fine * TAU
    order = np.argsort(depth)
    lat = np.interp(t, depth[order], e_nodes[order])
    ex = _exact(rt, mu0, t).actinic_flux_diffuse / 2
    b = np.minimum((t / TAU * nbins).astype(int), nbins - 1)
    return np.array([lat[b == k].mean() / ex[b == k].mean() - 1 for k in range(nbins)])


def _lattice_errors(elevation, H):
    fs, _, depth = _column(H, TAU / H, MEDIUM, _beam(elevation))
    inside = (depth > 0) & (depth < H)
    mu0 = math.sin(math.radians(elevation))
    return [_bin_errors(depth[inside] * TAU / H, f.sum(axis=1)[inside] / 2, rt, mu0) for f, rt in zip(fs, RT)]


@pytest.mark.parametrize("elevation", [30.0, 85.0])
def test_wide_grid_centre_is_the_periodic_column(elevation):
    """Part 1: the solver with the first-collision sun on a 64 x 64 x 12 grid (a 10-layer slab), centre column
    against the periodic column: within 2.5 % at every node (measured 1.8 %: light lost or gained through
    the finite grid's sides; 0.24 % at 96 x 96). Also E = u / 2 normalisation: the unscattered part of u
    is the exact beam, 1 above the slab and exp(-tau / mu0) inside (the exact solver's direct actinic
    flux), to round-off."""
    H, W = 10, 64
    kappa = TAU / H
    rho = np.zeros((W, W, H + 2))
    rho[:, :, 1 : H + 1] = -math.expm1(-kappa)
    d = _beam(elevation)
    r = solve(LBProblem(rho, MEDIUM, (sun_source(-d),)), LBParams(tolerance=1e-7, dtype="float64"))
    assert r.converged
    np.testing.assert_allclose(r.inflow, r.outflow + r.absorbed, rtol=1e-6)
    fs, direct, depth = _column(H, kappa, MEDIUM, d)
    u = r.energy_density[W // 2, W // 2, :, 0, :]
    for c in range(2):
        col = fs[c].sum(axis=1) + direct
        rel = u[1 : H + 1, c] / col[1 : H + 1] - 1
        assert np.abs(rel).max() < 0.025, (c, rel)
    mu0 = math.sin(math.radians(elevation))
    ex = _exact(0.1, mu0, np.clip(depth, 0, H) * kappa)
    np.testing.assert_allclose(direct, ex.actinic_flux - ex.actinic_flux_diffuse, rtol=1e-12)
    from foliage_tools.lighting.lb import unscattered_energy

    un = unscattered_energy(LBProblem(rho, MEDIUM, (sun_source(-d),)), "float64")[W // 2, W // 2, :, 0, 0]
    np.testing.assert_allclose(un, direct, rtol=1e-12)


# (elevation, r = t): measured bin errors of E_scattered, top bin first, for 10 node layers (what the layer gets at
# --resolution 64) and for 80 (the angular floor); module docstring, parts 2 and 3
MEASURED = {
    (30, 0.1): ([+0.304, +0.079, +0.045, +0.061, +0.136], [+0.308, +0.032, -0.027, -0.032, +0.011]),
    (30, 0.45): ([+0.355, +0.114, +0.067, +0.075, +0.168], [+0.418, +0.130, +0.062, +0.058, +0.129]),
    (60, 0.1): ([+0.234, +0.079, +0.059, +0.073, +0.152], [+0.226, +0.038, +0.000, +0.001, +0.059]),
    (60, 0.45): ([+0.277, +0.102, +0.070, +0.081, +0.178], [+0.325, +0.122, +0.075, +0.077, +0.158]),
    (85, 0.1): ([+0.214, +0.074, +0.059, +0.073, +0.152], [+0.205, +0.036, +0.003, +0.005, +0.066]),
    (85, 0.45): ([+0.257, +0.096, +0.068, +0.079, +0.178], [+0.303, +0.117, +0.075, +0.079, +0.163]),
}


@pytest.mark.parametrize("elevation", [30, 60, 85])
def test_slab_error_is_the_lattices_angular_floor_plus_resolution(elevation):
    """Parts 2 and 3: the periodic ordinates lattice with the first-collision sun against the exact slab, per
    depth bin, at 10 node layers and refined to 80. Bounds: measured +- 3 % (deterministic model); the
    refined lattice's error is the angular discretisation (module docstring), and refining changes a bin by
    at most 12.5 %."""
    coarse = _lattice_errors(elevation, 10)
    fine = _lattice_errors(elevation, 80)
    for c, rt in enumerate(RT):
        want10, want80 = (np.array(v) for v in MEASURED[(elevation, rt)])
        np.testing.assert_allclose(coarse[c], want10, atol=0.03, err_msg=f"10 layers, r = t = {rt}")
        np.testing.assert_allclose(fine[c], want80, atol=0.03, err_msg=f"80 layers, r = t = {rt}")
        assert np.abs(coarse[c] - fine[c]).max() < 0.13
        # the floor: inner bins within 13 %, the boundary bins above the exact value (trapped horizontal light)
        assert np.abs(fine[c][1:4]).max() < 0.13 and fine[c][0] > 0.15 and fine[c][4] > 0.0

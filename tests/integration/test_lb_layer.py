"""``foliage lb`` with its defaults on the issue's uniform layer against the exact plane-parallel solution (issue #15).

The layer of examples/make_layer.py (10 x 10 x 1.5 m, 30 000 cards of 0.1 m, LAI 3, tau = 1.5), read back
from USD, baked per prototype at --resolution 64 for r = t = 0.1 and 0.45 (two channels of one bake) under
suns at 30, 60 and 85 degrees; per-leaf E_scattered in five depth bins of the inner region |x|, |y| < 3 m
against ``plane_parallel.solve_slab`` with the bi-Lambertian phase function.

What ``foliage lb`` does by default: the ordinates lattice, the bi-Lambertian phase, the sun as a
first-collision source, and the once-scattered light replaced by the exact one (lighting.single_scatter;
the lattice keeps the higher orders). Bound: the issue's own, within 10 % of the exact E_scattered in every
bin. Measured, top bin first, %:

    30 deg  r=t=0.1    +0.8  -1.7  -0.6  +1.9  +7.5   (lattice's own first order: +23.5  +8.7  +8.3 +13.7 +26.5)
            r=t=0.45   +9.6  +0.1  -2.2  -0.6  +6.9                               +21.3  +4.7  +1.2  +3.4 +13.0
    60 deg  r=t=0.1    -0.5  -3.5  -3.0  -1.9  +1.4                               +17.1  +6.3  +6.2  +8.9 +17.0
            r=t=0.45   +4.7  -3.4  -5.3  -4.4  +1.6                               +13.3  +0.9  -1.6  -0.4  +7.2
    85 deg  r=t=0.1    -0.3  -3.2  -3.0  -1.6  +2.1                               +16.0  +6.3  +6.1  +9.0 +17.0
            r=t=0.45   +4.2  -3.6  -5.4  -4.4  +1.8                               +11.9  +0.5  -1.8  -0.3  +7.4

The finite layer itself reads 2-5 % below the infinite slab in this region (its sides leak; the Monte
Carlo reference on the same layer), which is most of the inner bins' deficit. What is left in the top
and bottom bins is the lattice's angular error on the higher orders (tests/unit/test_lb_slab.py). The
paper's setting (geist2008 lattice, sun boundary, HG phase) is the second check: its RMS over the 30 bins
(measured 0.207) must be at least twice the default's (0.038): the correction must be what makes the
difference, not a cancellation in one bin.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.phase import canopy_bilambertian_phase
from foliage_tools.lighting.plane_parallel import solve_slab
from foliage_tools.pipeline.density import compute_density
from foliage_tools.pipeline.lb import LBBakeParams, bake_prototype
from foliage_tools.params import DensityParams
from foliage_tools.scene.read import read_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))

ELEVATIONS = (30, 60, 85)


def _bin_errors(values, expected, depth, mask):
    b = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    return np.array([values[mask & (b == k)].mean() / expected[mask & (b == k)].mean() - 1 for k in range(5)])


OPTICS = LeafOptics((0.1, 0.45, 0.3), (0.1, 0.45, 0.3))  # r = t = 0.1 and 0.45 in two channels of one bake


def _layer(tmp_path):
    """The issue's layer read back from USD, its 64-voxel density, and each leaf's optical depth and inner mask."""
    from make_layer import build_layer, write_layer_stage

    path = write_layer_stage(tmp_path / "layer.usdc", build_layer(seed=1), sun=(0.0, 60.0))
    proto = read_scene(path)[0].prototypes[0]
    dens = compute_density(proto, DensityParams(resolution=64, method="area"))
    c = proto.leaves.centers
    depth = np.clip(0.5 * 3.0 * (1.5 - c[:, 2]) / 1.5, 0.0, 1.5)
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    return proto, dens, depth, inner


def _sun(elevation: float) -> np.ndarray:
    e = math.radians(elevation)
    return np.array([math.cos(e), 0.0, math.sin(e)])


def _exact(sun: np.ndarray, depth: np.ndarray, rt: float) -> np.ndarray:
    """Per leaf, the exact slab's E_scattered (half the diffuse actinic flux) at its optical depth."""
    sol = solve_slab(tau=1.5, omega=2 * rt, mu0=sun[2], phase=canopy_bilambertian_phase(reflectance=rt, transmittance=rt),
                     depths=depth)
    return sol.actinic_flux_diffuse / 2


@pytest.mark.slow
def test_default_lb_on_the_uniform_layer_against_the_exact_slab(tmp_path):
    proto, dens, depth, inner = _layer(tmp_path)
    new_sq, old_sq = [], []
    for elevation in ELEVATIONS:
        sun = _sun(elevation)
        new = bake_prototype(proto, 0, sun, LBBakeParams(optics=OPTICS), dens)
        old = bake_prototype(proto, 0, sun, LBBakeParams(optics=OPTICS, lattice="geist2008", sun_source="boundary", phase="hg"),
                             dens)
        for ch, rt in ((0, 0.1), (1, 0.45)):
            exact = _exact(sun, depth, rt)
            err = _bin_errors(new.e_scattered[:, ch], exact, depth, inner)
            assert np.all(np.abs(err) <= 0.10), (elevation, rt, err)
            new_sq.append(err**2)
            old_sq.append(_bin_errors(old.e_scattered[:, ch], exact, depth, inner) ** 2)
    rms_new, rms_old = math.sqrt(np.mean(new_sq)), math.sqrt(np.mean(old_sq))
    assert rms_new < 0.5 * rms_old, (rms_new, rms_old)  # measured 0.038 against 0.207


def test_default_lb_at_a_low_sun_on_the_uniform_layer(tmp_path):
    """The default suite's share of the test above: the hardest elevation (30 degrees), the default bake only."""
    proto, dens, depth, inner = _layer(tmp_path)
    sun = _sun(30.0)
    bake = bake_prototype(proto, 0, sun, LBBakeParams(optics=OPTICS), dens)
    for ch, rt in ((0, 0.1), (1, 0.45)):
        err = _bin_errors(bake.e_scattered[:, ch], _exact(sun, depth, rt), depth, inner)
        assert np.all(np.abs(err) <= 0.10), (rt, err)  # the bound; measured at most +9.6 % (top bin, 0.45)


def test_marched_lb_on_the_uniform_layer(tmp_path):
    """``foliage lb --first-order march`` (the first order marched from the leaves' exact direct light, the
    lattice's later orders on top) at 60 degrees. Bound: the issue's, 10 % of the exact E_scattered in every
    bin. Measured, top bin first: r=t=0.1 +1.7 -1.0 -1.4 -0.6 +3.0 %, r=t=0.45 +5.8 -2.3 -4.6 -3.9 +2.1 %
    (the field, ``--first-order field``: -0.4 ... +1.4 % and -5.2 ... +4.8 %). At 30 degrees it reads +1.7 ...
    +8.8 % for r=t=0.1 and -1.2 ... +10.1 % for r=t=0.45 (the top bin; the field +9.7 %), which is why it is
    not ``foliage lb``'s default (README "SPPG's first order")."""
    from make_layer import build_layer, write_layer_stage

    from foliage_tools.pipeline.direct import DirectChoice, bake_direct
    from foliage_tools.pipeline.first_order import march_lb
    from foliage_tools.pipeline.lb import bake_lb, later_orders
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake

    path = write_layer_stage(tmp_path / "layer.usdc", build_layer(seed=1), sun=(0.0, 60.0))
    _, scene, sun = begin_bake("lb", path, None, (0.0, 60.0), Silent())
    bakes = bake_lb(scene, sun, LBBakeParams(optics=OPTICS, sun=(0.0, 60.0), first_order="march"), [], Silent())
    later = {0: later_orders(bakes[0], scene.prototypes[0].leaves.centers)}
    marched = march_lb(scene, sun, OPTICS, bakes, later, bake_direct(scene, sun, DirectChoice(), Silent()), Silent())[0]
    c = scene.prototypes[0].leaves.centers
    depth = np.clip(0.5 * 3.0 * (1.5 - c[:, 2]) / 1.5, 0.0, 1.5)
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    for ch, rt in ((0, 0.1), (1, 0.45)):
        err = _bin_errors(marched.e_scattered[:, ch], _exact(sun.direction, depth, rt), depth, inner)
        assert np.all(np.abs(err) <= 0.10), (rt, err)
        assert not np.allclose(marched.e_scattered[:, ch], bakes[0].e_scattered[:, ch], rtol=0.02)  # it did march

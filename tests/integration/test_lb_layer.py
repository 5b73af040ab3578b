"""``foliage lb`` with its defaults on the issue's uniform layer against the exact plane-parallel solution (issue #15).

The layer of examples/make_layer.py (10 x 10 x 1.5 m, 30 000 cards of 0.1 m, LAI 3, tau = 1.5), read back
from USD, baked per prototype at --resolution 64 for r = t = 0.1 and 0.45 (two channels of one bake) under
suns at 30, 60 and 85 degrees; per-leaf E_scattered in five depth bins of the inner region |x|, |y| < 3 m
against ``plane_parallel.solve_slab`` with the bi-Lambertian phase function.

What ``foliage lb`` does by default: the ordinates lattice, the bi-Lambertian phase, the sun as a
first-collision source, the lattice's once-scattered light replaced by the exact one (lighting.single_scatter;
the lattice keeps the higher orders), and per leaf the first order marched from the leaves' exact direct light
(``--first-order march``, lighting.first_order) with the lattice's later orders on top. Bound: the issue's
own, within 10 % of the exact E_scattered in every bin. Measured, top bin first, %:

                       default (march)                   --first-order field
    30 deg  r=t=0.1    +0.5  +0.4  +1.9  +3.5  +8.6      +1.0  -1.7  -0.6  +1.8  +7.4
            r=t=0.45   +9.5  +1.0  -1.2  -0.1  +7.3      +9.7  +0.1  -2.2  -0.6  +6.9
    60 deg  r=t=0.1    +0.8  -1.0  -1.4  -0.6  +2.7      -0.4  -3.4  -3.0  -1.8  +1.4
            r=t=0.45   +5.4  -2.3  -4.6  -3.9  +2.0      +4.8  -3.3  -5.2  -4.4  +1.5
    85 deg  r=t=0.1    +0.8  -1.1  -1.5  -0.8  +2.4      -0.1  -3.1  -2.9  -1.6  +2.1
            r=t=0.45   +4.7  -2.7  -4.8  -4.0  +1.9      +4.3  -3.5  -5.4  -4.3  +1.8

(the lattice's own first order instead, 30 deg: +23.5 +8.7 +8.3 +13.7 +26.5 and +21.3 +4.7 +1.2 +3.4 +13.0.)
The finite layer itself reads 2-5 % below the infinite slab in this region (its sides leak; the Monte Carlo
reference on the same layer), which is most of the inner bins' deficit; and at 30 degrees its sides let the
sun reach the deepest leaves near them more than an infinite slab would, which raises the march's bottom bin
(+6.7 % with the cards' exact direct light against +2.1 % with the slab's mean one, tests/unit/
test_first_order.py). What is left in the top and bottom bins is the lattice's angular error on the higher
orders (+20 % in the top bin at 30 degrees, r = t = 0.45, README "LB with the marched first order"). The
paper's setting (geist2008 lattice, sun boundary, HG phase) is the second check: its RMS over the 30 bins
(measured 0.207) must be at least twice the default's: the correction must be what makes the difference, not a
cancellation in one bin.
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


def _default_lb(path: Path, elevation: float, **options):
    """Per-leaf E_scattered of ``foliage lb``'s bake (``pipeline.lb.run_lb``'s stages, without the gather) of the
    layer at ``path`` under a sun at ``elevation``, with ``options`` over the defaults; and the leaf centres."""
    from foliage_tools.pipeline.direct import DirectChoice, bake_direct
    from foliage_tools.pipeline.first_order import march_lb
    from foliage_tools.pipeline.lb import bake_lb, later_orders, marches
    from foliage_tools.pipeline.report import Silent
    from foliage_tools.pipeline.stage import begin_bake

    _, scene, sun = begin_bake("lb", path, None, (0.0, elevation), Silent())
    params = LBBakeParams(optics=OPTICS, sun=(0.0, elevation), **options)
    bakes = bake_lb(scene, sun, params, [], Silent())
    if marches(params):
        later = {0: later_orders(bakes[0], scene.prototypes[0].leaves.centers)}
        bakes = march_lb(scene, sun, OPTICS, bakes, later, bake_direct(scene, sun, DirectChoice(), Silent()), Silent())
    return bakes[0].e_scattered, scene.prototypes[0].leaves.centers


def _layer_file(tmp_path) -> Path:
    from make_layer import build_layer, write_layer_stage

    return write_layer_stage(tmp_path / "layer.usdc", build_layer(seed=1), sun=(0.0, 60.0))


def _depth_inner(c):
    return np.clip(0.5 * 3.0 * (1.5 - c[:, 2]) / 1.5, 0.0, 1.5), (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)


@pytest.mark.slow
def test_default_lb_on_the_uniform_layer_against_the_exact_slab(tmp_path):
    path = _layer_file(tmp_path)
    proto, dens, depth, inner = _layer(tmp_path)
    new_sq, old_sq = [], []
    for elevation in ELEVATIONS:
        sun = _sun(elevation)
        new, c = _default_lb(path, elevation)
        d, i = _depth_inner(c)
        old = bake_prototype(proto, 0, sun, LBBakeParams(optics=OPTICS, lattice="geist2008", sun_source="boundary", phase="hg"),
                             dens)
        for ch, rt in ((0, 0.1), (1, 0.45)):
            err = _bin_errors(new[:, ch], _exact(sun, d, rt), d, i)
            assert np.all(np.abs(err) <= 0.10), (elevation, rt, err)
            new_sq.append(err**2)
            old_sq.append(_bin_errors(old.e_scattered[:, ch], _exact(sun, depth, rt), depth, inner) ** 2)
    rms_new, rms_old = math.sqrt(np.mean(new_sq)), math.sqrt(np.mean(old_sq))
    assert rms_new < 0.5 * rms_old, (rms_new, rms_old)  # measured 0.037 against 0.207


def test_default_lb_at_a_low_sun_on_the_uniform_layer(tmp_path):
    """The default suite's share of the test above: the hardest elevation (30 degrees), the default bake and
    ``--first-order field``. Bound: the issue's; measured at most +9.5 % (march) and +9.7 % (field), the top bin
    at r = t = 0.45."""
    path = _layer_file(tmp_path)
    sun = _sun(30.0)
    marched, c = _default_lb(path, 30.0)
    field, _ = _default_lb(path, 30.0, first_order="field")
    depth, inner = _depth_inner(c)
    for ch, rt in ((0, 0.1), (1, 0.45)):
        exact = _exact(sun, depth, rt)
        for name, got in (("march", marched), ("field", field)):
            err = _bin_errors(got[:, ch], exact, depth, inner)
            assert np.all(np.abs(err) <= 0.10), (name, rt, err)
        assert not np.allclose(marched[:, ch], field[:, ch], rtol=0.02)  # the default did march

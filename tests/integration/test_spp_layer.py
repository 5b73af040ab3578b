"""``foliage spp`` with its defaults on the issue's uniform layer against the exact plane-parallel solution (issue #15).

The layer of examples/make_layer.py (10 x 10 x 1.5 m, 30 000 cards of 0.1 m, LAI 3, tau = 1.5), read back from
USD; per-leaf SPPG E_scattered (the exact slab per leaf with the G-factor, with the slab's first order times G
(``--first-order slab``) and with ``foliage spp``'s default, the first order marched from the exact direct light) in five
depth bins of the inner region |x|, |y| < 3 m against ``plane_parallel.solve_slab`` with the bi-Lambertian phase
function, as tests/integration/test_lb_layer.py does for LB. Bound: the issue's own, 10 % in every bin. The
finite layer itself reads 2-5 % below the infinite slab there (its sides leak; the Monte Carlo reference on the
same layer), so that is part of every bin's deficit. Measured at 60 degrees, top bin first, %:

    r=t=0.1    auto (32 voxels)  -1.9  -4.0  -3.6  -3.3  -1.6    64 voxels  -6.7  -6.6  -5.4  -4.1  -5.0
    r=t=0.45                     -3.7  -6.2  -5.9  -6.9  -5.6               -8.5  -9.7  -8.8  -9.3 -10.8
    march (default)   r=t=0.1    -1.2  -2.1  -2.1  -1.6  +3.1  (32 voxels, against the infinite slab)
                      r=t=0.45   -2.9  -4.0  -3.9  -4.3  +0.2

The second check is the depth grid (``SppParams.depth_resolution``). The layer's 64-voxel grid holds 1.4 leaves
per leaf-holding voxel: each leaf's depths are then a noisy sample of the layer's, and the slab solution is
concave in depth, so the noise alone darkens the mean (Jensen). ``auto`` coarsens to 4 leaves a voxel (32 voxels
here). If the default did not coarsen, or coarsening did not remove that darkening, its RMS error over the bins
would not be below the 64-voxel grid's.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.phase import canopy_bilambertian_phase
from foliage_tools.lighting.plane_parallel import solve_slab
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_sppg
from foliage_tools.pipeline.spp import SppParams, bake_spp, depth_resolution
from foliage_tools.pipeline.stage import begin_bake

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))

OPTICS = LeafOptics((0.1, 0.45, 0.3), (0.1, 0.45, 0.3))  # r = t = 0.1 and 0.45 in two channels of one bake


def _bin_errors(values, expected, depth, mask):
    b = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    return np.array([values[mask & (b == k)].mean() / expected[mask & (b == k)].mean() - 1 for k in range(5)])


def test_default_spp_on_the_uniform_layer_against_the_exact_slab(tmp_path):
    from make_layer import build_layer, write_layer_stage

    elevation = 60.0
    path = write_layer_stage(tmp_path / "layer.usdc", build_layer(seed=1), sun=(0.0, elevation))
    _, scene, sun = begin_bake("spp", path, None, (0.0, elevation), Silent())
    proto = scene.prototypes[0]
    c = proto.leaves.centers
    depth = np.clip(0.5 * 3.0 * (1.5 - c[:, 2]) / 1.5, 0.0, 1.5)  # G = 0.5, LAD 2: tau = 1.5 over 1.5 m
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    mu0 = math.sin(math.radians(elevation))
    assert depth_resolution(proto, SppParams(optics=OPTICS)) == 32  # 5.1 leaves a leaf-holding voxel; 48: 2.1

    auto = bake_spp(scene, sun, SppParams(optics=OPTICS, sun=(0.0, elevation), first_order="slab"), [], Silent())[0]
    march = march_sppg(scene, sun, OPTICS, [replace(auto)], bake_direct(scene, sun, DirectChoice(), Silent()), Silent())[0]
    fine = bake_spp(scene, sun, SppParams(optics=OPTICS, sun=(0.0, elevation), depth_resolution=64), [], Silent())[0]
    assert auto.depth_resolution == 32 and fine.depth_resolution == 64
    sq_auto, sq_fine = [], []
    for ch, rt in ((0, 0.1), (1, 0.45)):
        sol = solve_slab(tau=1.5, omega=2 * rt, mu0=mu0, phase=canopy_bilambertian_phase(reflectance=rt, transmittance=rt),
                         depths=depth)
        exact = sol.actinic_flux_diffuse / 2
        err = _bin_errors(auto.result.sppg.scattered[:, ch], exact, depth, inner)
        assert np.all(np.abs(err) <= 0.10), (rt, err)
        err_march = _bin_errors(march.result.sppg.scattered[:, ch], exact, depth, inner)
        assert np.all(np.abs(err_march) <= 0.10), (rt, err_march)
        sq_auto.append(err**2)
        f = _bin_errors(fine.result.sppg.scattered[:, ch], exact, depth, inner)
        sq_fine.append(f**2)
    rms_auto, rms_fine = math.sqrt(np.mean(sq_auto)), math.sqrt(np.mean(sq_fine))
    assert rms_auto < rms_fine, (rms_auto, rms_fine)  # measured 0.046 against 0.078

"""``foliage lb`` with its defaults on the issue's uniform layer against the exact plane-parallel solution (issue #15).

The layer of examples/make_layer.py (10 x 10 x 1.5 m, 30 000 cards of 0.1 m, LAI 3, tau = 1.5), read back
from USD, baked per prototype at --resolution 64 for r = t = 0.1 and 0.45 (two channels of one bake) under
suns at 30, 60 and 85 degrees; per-leaf E_scattered in five depth bins of the inner region |x|, |y| < 3 m
against ``plane_parallel.solve_slab`` with the bi-Lambertian phase function.

Measured (new defaults: ordinates lattice, first-collision sun, bi-Lambertian phase), top bin first, %:

    30 deg  r=t=0.1   +23.5  +8.7  +8.3 +13.7 +26.5     old defaults  -11.7  -9.8  +7.0 +34.7 +83.8
            r=t=0.45  +21.3  +4.7  +1.2  +3.4 +13.0                    -7.3 -11.4  -4.4  +9.5 +36.0
    60 deg  r=t=0.1   +17.1  +6.3  +6.2  +8.9 +17.0                    -0.7 -13.0 -14.3 -10.2  +2.1
            r=t=0.45  +13.3  +0.9  -1.6  -0.4  +7.2                    -4.2 -18.1 -21.7 -19.7 -10.0
    85 deg  r=t=0.1   +16.0  +6.3  +6.1  +9.0 +17.0                   +20.4  +3.2  -1.8  -0.5  +7.9
            r=t=0.45  +11.9  +0.5  -1.8  -0.3  +7.4                   +14.1  -4.1 -10.5 -10.1  -2.0

(old defaults: geist2008 lattice, geist2008 sun boundary, Henyey-Greenstein phase). The remaining error is
the lattice's angular discretisation (tests/unit/test_lb_slab.py: +20 .. +42 % in the top bin and up to
+16 % in the bottom one for the periodic lattice at any resolution), less the finite layer's side losses
(the Monte Carlo reference on this finite layer reads 2-5 % below the exact infinite-slab values in this
region). Bounds: the measured values +- 3 % (the bake is deterministic; the tolerance absorbs harmless
changes of voxelization or interpolation), and the RMS over all 30 bins must stay below 0.7 x the old one
(measured 0.117 against 0.207: the old defaults are better in a few bins, e.g. 60 deg r = t = 0.1, by cancellation
of a missing sun flux against the same trapped light).
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

MEASURED = {
    30: ([+0.235, +0.087, +0.083, +0.137, +0.265], [+0.213, +0.047, +0.012, +0.034, +0.130]),
    60: ([+0.171, +0.063, +0.062, +0.089, +0.170], [+0.133, +0.009, -0.016, -0.004, +0.072]),
    85: ([+0.160, +0.063, +0.061, +0.090, +0.170], [+0.119, +0.005, -0.018, -0.003, +0.074]),
}


def _bin_errors(values, expected, depth, mask):
    b = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    return np.array([values[mask & (b == k)].mean() / expected[mask & (b == k)].mean() - 1 for k in range(5)])


@pytest.mark.slow
def test_default_lb_on_the_uniform_layer_against_the_exact_slab(tmp_path):
    from make_layer import build_layer, write_layer_stage

    path = write_layer_stage(tmp_path / "layer.usdc", build_layer(seed=1), sun=(0.0, 60.0))
    proto = read_scene(path)[0].prototypes[0]
    optics = LeafOptics((0.1, 0.45, 0.3), (0.1, 0.45, 0.3))
    dens = compute_density(proto, DensityParams(resolution=64, method="area"))
    c = proto.leaves.centers
    depth = np.clip(0.5 * 3.0 * (1.5 - c[:, 2]) / 1.5, 0.0, 1.5)
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    new_sq, old_sq = [], []
    for elevation, want in MEASURED.items():
        e = math.radians(elevation)
        sun = np.array([math.cos(e), 0.0, math.sin(e)])
        new = bake_prototype(proto, 0, sun, LBBakeParams(optics=optics), dens)
        old = bake_prototype(proto, 0, sun, LBBakeParams(optics=optics, lattice="geist2008", sun_source="boundary", phase="hg"),
                             dens)
        for ch, rt in ((0, 0.1), (1, 0.45)):
            sol = solve_slab(tau=1.5, omega=2 * rt, mu0=sun[2], phase=canopy_bilambertian_phase(reflectance=rt, transmittance=rt),
                             depths=depth)
            exact = sol.actinic_flux_diffuse / 2
            err = _bin_errors(new.e_scattered[:, ch], exact, depth, inner)
            np.testing.assert_allclose(err, want[ch], atol=0.03, err_msg=f"elevation {elevation}, r = t = {rt}")
            new_sq.append(err**2)
            old_sq.append(_bin_errors(old.e_scattered[:, ch], exact, depth, inner) ** 2)
    rms_new, rms_old = math.sqrt(np.mean(new_sq)), math.sqrt(np.mean(old_sq))
    assert rms_new < 0.7 * rms_old, (rms_new, rms_old)  # measured 0.117 against 0.207

"""``foliage lb``: a rotated tree under the same-rotated sun is lit as the unrotated one (issue 4).

Two ways a tree can be rotated, two different things tested:

* the tree's root prim carries the rotation (an instance transform): the
  prototype geometry and its lattice are unchanged, and ``bake_lb`` must
  rotate the sun into prototype space (DESIGN.md sec. 4, "instances are lit
  with the sun rotated into prototype space"). The per-leaf results must
  agree to float32 round-off.
* the leaf geometry itself is rotated by 90 deg about Z: the density grid is
  rebuilt in the rotated frame, and the result must agree because D3Q19 (its
  directions, weights and HG kernel) is invariant under 90 deg rotations
  about the axes and the voxelization commutes with them (the rotation
  (x, y) -> (-y, x) is exact in floating point and maps the cropped grid
  onto itself with x and y swapped).
"""

from __future__ import annotations

import numpy as np

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.lb import LBBakeParams, run_lb
from tests.conftest import cards_mesh, write_mesh_stage

SUN = (30.0, 50.0)  # azimuth, elevation in degrees: not a lattice direction
RES = 14


def _leaf_cards(seed=7, n=40):
    """An asymmetric crown: cards at random points in a lopsided ellipsoid, normals along z and x."""
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(n, 3)) * (0.5, 0.3, 0.4) + (0.2, 0.0, 1.5)
    zc = cards_mesh(c[: n // 2], size=0.15, normal_axis=2)
    xc = cards_mesh(c[n // 2 :], size=0.15, normal_axis=0)
    k = len(zc["points"])
    return {
        "points": np.concatenate([zc["points"], xc["points"]]),
        "counts": zc["counts"] + xc["counts"],
        "indices": list(zc["indices"]) + [i + k for i in xc["indices"]],
        "isLeaf": True,
    }


def _rot_z90(p):
    p = np.asarray(p, dtype=np.float64)
    return np.stack([-p[:, 1], p[:, 0], p[:, 2]], axis=1)


def _bake(path, out, sun):
    from pxr import Usd, UsdGeom

    # the lattice's per-leaf light (no gather: its rays are seeded in world space, so a rotated copy is equal
    # only within the gather's sampling noise)
    report = run_lb(path, out, LBBakeParams(optics=parse_leaf_optics(None), resolution=RES, sun=sun, gather=0))
    stage = Usd.Stage.Open(str(out))
    pv = UsdGeom.PrimvarsAPI(UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves")))

    def get(name):
        return np.asarray(pv.GetPrimvar(name).Get(), dtype=np.float64)

    return report, get("foliage:lb:scattered"), get("foliage:lb:direct")


def test_rotated_instance_under_rotated_sun_equals_unrotated(tmp_path):
    from pxr import Usd, UsdGeom

    leaves = _leaf_cards()
    plain = write_mesh_stage(tmp_path / "plain.usda", {"Leaves": leaves})
    rotated = write_mesh_stage(tmp_path / "rotated.usda", {"Leaves": leaves})
    stage = Usd.Stage.Open(str(rotated))
    UsdGeom.Xform(stage.GetPrimAtPath("/Tree")).AddRotateZOp().Set(90.0)
    stage.GetRootLayer().Save()

    rep0, s0, d0 = _bake(plain, tmp_path / "p_lb.usda", SUN)
    rep1, s1, d1 = _bake(rotated, tmp_path / "r_lb.usda", (SUN[0] + 90.0, SUN[1]))
    assert rep0.stats["prototypes"][0]["converged"] and rep1.stats["prototypes"][0]["converged"]
    assert s0.shape == (40, 3) and s0.min() >= 0 and s0.max() > 0
    # same prototype grid, same sun in prototype space (to ~1e-16): measured bit-identical; allow
    # float32 round-off in case the rotated sun's last bits differ
    np.testing.assert_allclose(s1, s0, rtol=1e-5, atol=1e-6 * s0.max())
    np.testing.assert_allclose(d1, d0, rtol=1e-5, atol=1e-6 * d0.max())
    # control: without rotating the sun the answer differs by ~5% (scattered) / ~33% (direct) of
    # the maximum, so the comparison above can fail
    _, s2, _ = _bake(rotated, tmp_path / "r2_lb.usda", SUN)
    assert np.abs(s2 - s0).max() > 0.01 * s0.max()


def test_rotated_geometry_under_rotated_sun_equals_unrotated(tmp_path):
    leaves = _leaf_cards()
    turned = {**leaves, "points": _rot_z90(leaves["points"])}
    plain = write_mesh_stage(tmp_path / "plain.usda", {"Leaves": leaves})
    rotated = write_mesh_stage(tmp_path / "rotgeom.usda", {"Leaves": turned})

    _, s0, d0 = _bake(plain, tmp_path / "p_lb.usda", SUN)
    _, s1, d1 = _bake(rotated, tmp_path / "g_lb.usda", (SUN[0] + 90.0, SUN[1]))
    # A different grid (16x13x16 vs 13x16x16 here) solved independently: the two solutions are exact
    # lattice rotations of each other up to float32 summation order (the rotated problem visits the
    # directions in another order) and the steady-state stopping point (1e-5 relative residual; both
    # stop after the same 32 sweeps). Measured: max |s1 - s0| = 1.7e-6 x max s0 (scattered),
    # 7.9e-8 x max d0 (direct). Bound: 2e-5 x max, about the bake's residual tolerance.
    assert np.abs(s1 - s0).max() <= 2e-5 * s0.max()
    assert np.abs(d1 - d0).max() <= 2e-5 * d0.max()
    # control: without rotating the sun the scattered light differs by ~5% of its maximum
    _, s2, _ = _bake(rotated, tmp_path / "g2_lb.usda", SUN)
    assert np.abs(s2 - s0).max() > 0.01 * s0.max()

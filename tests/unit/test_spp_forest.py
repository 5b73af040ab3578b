"""Forest placements for shinya2013 eq. (31): which instance transforms keep optical depth invariant.

Optical depth is invariant under a rotation times a uniform scale s (lengths
× s, leaf-area density / s). PointInstancer orientations are often
half-precision quaternions (``quath``): M^T M then departs from s² I by
~1e-4 relative (measured on ``examples/forest_small.usda``: 0.683491 vs
0.683372), which must be accepted; a real non-uniform scale must not.
"""

from __future__ import annotations

import numpy as np
import pytest

from foliage_tools.geometry.voxelize import GridSpec
from foliage_tools.lighting import depth as dp
from foliage_tools.pipeline.spp_neighbours import is_similarity as _is_similarity


def quat_matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z) *without* normalising it, as USD composes an unnormalised quath."""
    w, x, y, z = q
    return np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ])


def placement(lin, t=(3.0, 0.0, 0.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = lin
    m[:3, 3] = t
    return m


def test_half_precision_quaternions_pass_and_squashed_trees_do_not():
    q = np.array([0.666992, 0.0, 0.0, 0.745117], dtype=np.float16).astype(np.float64)  # forest_small Grove[0]
    half = placement(0.83 * quat_matrix(q))
    assert abs(np.linalg.norm(q) - 1.0) > 1e-5  # really not unit
    assert _is_similarity(half)
    assert _is_similarity(placement(2.0 * np.eye(3)))
    assert not _is_similarity(placement(np.diag([1.0, 1.0, 0.9])))
    shear = np.eye(3)
    shear[0, 1] = 0.05
    assert not _is_similarity(placement(shear))


def test_neighbour_depth_through_a_half_precision_placement_is_within_its_rounding():
    """The neighbour's depth through the quath placement differs from the exact rotation by ~|q|² - 1."""
    grid = GridSpec(origin=(-1.0, -1.0, -1.0), voxel_size=0.25, shape=(8, 8, 8))
    rho = np.random.default_rng(0).uniform(0.0, 2.0, size=grid.shape)
    q = np.array([0.666992, 0.0, 0.0, 0.745117], dtype=np.float16).astype(np.float64)
    exact = q / np.linalg.norm(q)
    pts = np.array([[-3.0, 0.1, 0.05], [-2.5, -0.2, 0.3]])
    dirs = np.array([[1.0, 0.0, 0.0], [1.0, 0.1, 0.05]])
    got = []
    for qq in (q, exact):
        world_from_proto = placement(quat_matrix(qq), t=(0.0, 0.0, 0.0))
        got.append(dp.instance_depth_samples(
            rho, grid, points=pts, sun_direction=[1.0, 0.0, 0.0], directions=dirs,
            prototype_from_world=np.linalg.inv(world_from_proto),
        ).sample_depth)
    assert np.all(got[1] > 0.5)  # the rays cross the neighbour
    np.testing.assert_allclose(got[0], got[1], rtol=1e-3)  # |q|² - 1 = 8e-5 for this quaternion
    with pytest.raises(ValueError, match="uniform scale"):
        dp.instance_depth_samples(
            rho, grid, points=pts, sun_direction=[1.0, 0.0, 0.0], directions=dirs,
            prototype_from_world=placement(np.diag([1.0, 1.0, 0.9]), t=(0.0, 0.0, 0.0)),
        )

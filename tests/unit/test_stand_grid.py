"""lighting.stand: the placed leaves of many instances on a coarse grid, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from foliage_tools.geometry.voxelize import GridSpec
from foliage_tools.lighting import stand

GRID = GridSpec(origin=(-5.0, -5.0, -2.0), voxel_size=0.5, shape=(20, 20, 10))


def _placements(rng, n, scale=1.0):
    m = np.zeros((n, 4, 4))
    for k in range(n):
        a = rng.uniform(0, 2 * np.pi)
        m[k, :3, :3] = scale * np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        m[k, :3, 3] = (rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0, 1))
        m[k, 3, 3] = 1
    return m


def test_deposit_puts_each_scaled_leaf_area_in_the_cell_of_its_placed_centre():
    rng = np.random.default_rng(0)
    m = _placements(rng, 7, scale=1.5)
    centres = rng.uniform(-0.8, 0.8, (50, 3))
    areas = rng.uniform(0.01, 0.02, 50)
    lad = stand.deposit(GRID, m, centres, areas)
    # the same by hand: place every leaf, bin its area (scaled by 1.5^2) into its cell, over the cell volume
    placed = np.einsum("kij,lj->kli", m[:, :3, :3], centres) + m[:, None, :3, 3]
    idx = np.floor((placed.reshape(-1, 3) - np.asarray(GRID.origin)) / GRID.voxel_size).astype(int)
    expect = np.zeros(GRID.shape)
    np.add.at(expect, tuple(idx.T), np.tile(areas * 1.5**2, 7) / GRID.voxel_size**3)
    np.testing.assert_allclose(lad, expect, rtol=1e-12, atol=1e-12)
    assert lad.sum() * GRID.voxel_size**3 == pytest.approx(7 * 1.5**2 * areas.sum())


def test_instance_means_of_a_linear_field_are_the_field_at_the_area_weighted_placed_centroid():
    # trilinear interpolation reproduces a linear field exactly between node centres, so the area-weighted
    # mean over an instance's leaves is the field at its placed area-weighted centroid
    rng = np.random.default_rng(1)
    m = _placements(rng, 5)
    centres = rng.uniform(-0.8, 0.8, (40, 3))
    areas = rng.uniform(0.5, 1.5, 40)
    nodes = np.stack(np.meshgrid(*[GRID.origin[a] + (np.arange(GRID.shape[a]) + 0.5) * GRID.voxel_size for a in range(3)],
                                 indexing="ij"), axis=-1)
    coef = np.array([[0.3, -0.2, 0.5], [1.0, 0.1, -0.4]])  # two channels
    field = nodes @ coef.T + np.array([2.0, 3.0])
    got = stand.instance_means(field, GRID, m, centres, areas)
    centroid = areas @ centres / areas.sum()
    placed = np.einsum("kij,j->ki", m[:, :3, :3], centroid) + m[:, :3, 3]
    np.testing.assert_allclose(got, placed @ coef.T + np.array([2.0, 3.0]), rtol=1e-10)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="areas"):
        stand.deposit(GRID, np.eye(4), np.zeros((3, 3)), np.ones(2))
    with pytest.raises(ValueError, match="finite"):
        stand.deposit(GRID, np.eye(4), np.full((1, 3), np.nan), np.ones(1))
    with pytest.raises(ValueError, match="field"):
        stand.instance_means(np.zeros((2, 2, 2, 1)), GRID, np.eye(4), np.zeros((1, 3)), np.ones(1))

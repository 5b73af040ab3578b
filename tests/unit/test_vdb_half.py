"""``Grid.half`` (issue #21): grids stored as half floats through OpenVDB's own ``saveFloatAsHalf``.

Bound: IEEE binary16 has an 11-bit significand (10 stored + the implicit bit), so rounding a normal
value (|x| >= 2^-14) to the nearest half is off by at most 2^-11 of it; below, the subnormals are
spaced 2^-24 apart (error <= 2^-25). OpenVDB rounds to nearest (asserted by the bound itself: a
truncating conversion would be off by up to 2^-10). Read back, the values are float32 again.
"""

import numpy as np
import pytest

from foliage_tools.scene.vdb import HALF_MAX, Grid, read_grid, write_vdb

HALF_ULP = 2.0**-11  # binary16: 11-bit significand, round to nearest
HALF_MIN_NORMAL = 2.0**-14
SUBNORMAL_HALF_STEP = 2.0**-25


def within_half(back: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.abs(back - x) <= np.maximum(HALF_ULP * np.abs(x), SUBNORMAL_HALF_STEP)


def values(rng, shape) -> np.ndarray:
    """Magnitudes over 10^-8 .. 10^3 (normal and subnormal halves) with zeros and some negatives."""
    x = 10.0 ** rng.uniform(-8, 3, shape)
    x[rng.random(shape) < 0.1] = 0.0
    x[rng.random(shape) < 0.1] *= -1
    return x.astype(np.float32)


@pytest.mark.parametrize("channels", [None, 3], ids=["scalar", "vec3"])
def test_half_grid_reads_back_within_half_precision_and_is_smaller(tmp_path, rng, channels):
    shape = (24, 20, 16) + ((channels,) if channels else ())
    x = values(rng, shape)
    meta = {"units": "test"}
    write_vdb(tmp_path / "f.vdb", [Grid("g", x, (0.0, 0.0, 0.0), 0.1, meta)])
    write_vdb(tmp_path / "h.vdb", [Grid("g", x, (0.0, 0.0, 0.0), 0.1, meta, half=True)])
    f, h = read_grid(tmp_path / "f.vdb", "g"), read_grid(tmp_path / "h.vdb", "g")
    assert not f.half and h.half
    assert h.values.dtype == np.float32 and h.values.shape == x.shape
    np.testing.assert_array_equal(f.values, x)  # float stays exact
    assert np.all(within_half(h.values, x))
    normal = np.abs(x) >= HALF_MIN_NORMAL
    assert np.any(h.values[normal] != x[normal])  # it was quantised (else the test proves nothing)
    assert h.metadata == f.metadata  # OpenVDB's own is_saved_as_half_float is Grid.half, not metadata
    assert (tmp_path / "h.vdb").stat().st_size < (tmp_path / "f.vdb").stat().st_size


def test_half_grid_written_again_stays_half_and_unchanged(tmp_path, rng):
    """Read back and rewritten (as a later stage carries it), a half grid is already on the half lattice."""
    x = values(rng, (8, 8, 8))
    write_vdb(tmp_path / "a.vdb", [Grid("g", x, (0.0, 0.0, 0.0), 0.1, half=True)])
    once = read_grid(tmp_path / "a.vdb", "g")
    write_vdb(tmp_path / "b.vdb", [once])
    write_vdb(tmp_path / "c.vdb", [Grid("other", x, (0.0, 0.0, 0.0), 0.1)], carried=[(tmp_path / "a.vdb", "g")])
    for name in ("b.vdb", "c.vdb"):
        twice = read_grid(tmp_path / name, "g")
        assert twice.half, name
        np.testing.assert_array_equal(twice.values, once.values)


def test_float_grid_file_has_no_half_flag(tmp_path, rng):
    """The default writes what it wrote before: not even is_saved_as_half_float = False in the grid's metadata."""
    import pyopenvdb

    write_vdb(tmp_path / "f.vdb", [Grid("g", values(rng, (4, 4, 4)), (0.0, 0.0, 0.0), 0.1)])
    (meta,) = pyopenvdb.readAllGridMetadata(str(tmp_path / "f.vdb"))
    assert "is_saved_as_half_float" not in dict(meta.metadata)


def test_half_refuses_values_beyond_the_largest_half(tmp_path):
    x = np.full((2, 2, 2), 2 * HALF_MAX, np.float32)
    with pytest.raises(ValueError, match="largest half float"):
        write_vdb(tmp_path / "h.vdb", [Grid("g", x, (0.0, 0.0, 0.0), 0.1, half=True)])


def test_a_sparse_grid_reads_back_over_its_active_voxels_and_on_lattice_puts_it_back(tmp_path, rng):
    """``lb --base-extent leaves`` writes zeros away from the leaves: OpenVDB stores only the rest (its active voxels),
    read_grid returns their bounding box, and on_lattice restores the baked lattice from the grid's metadata, equal to
    the array written (half: to its precision); a grid without that metadata is returned as it is."""
    from foliage_tools.scene.vdb import on_lattice

    shape, origin, h = (20, 16, 12), (-2.0, 1.0, 0.5), 0.1
    values = np.zeros(shape + (3,), np.float32)
    values[5:9, 3:12, 2:7] = rng.uniform(0.1, 1.0, size=(4, 9, 5, 3))
    meta = {"foliage:latticeShape": shape, "foliage:latticeOrigin": origin}
    for half in (False, True):
        path = tmp_path / f"sparse{half}.vdb"
        write_vdb(path, [Grid("lbBase01", values, origin, h, meta, half=half)])
        got = read_grid(path, "lbBase01")
        assert got.values.shape == (4, 9, 5, 3)  # only the stored block
        full = on_lattice(got)
        assert full.values.shape == values.shape and np.allclose(full.origin, origin, atol=1e-12)
        np.testing.assert_allclose(full.values, values, rtol=2.0 ** -11 if half else 0, atol=0)
    plain = Grid("density", values[..., 0], origin, h)
    write_vdb(tmp_path / "plain.vdb", [plain])
    back = read_grid(tmp_path / "plain.vdb", "density")
    assert on_lattice(back) is back
    with pytest.raises(ValueError, match="outside the lattice"):
        on_lattice(Grid("lbBase01", values, (origin[0] + 5 * h, *origin[1:]), h, meta))

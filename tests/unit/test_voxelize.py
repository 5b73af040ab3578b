"""Voxelization kernels: exact area per voxel, geist2008 sec. 4.2 subgrid coverage, grids.

Expected values are computed by hand (stated next to each case), or by slow
pure-Python clipping references defined here, which share no code with the
numba kernels.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from foliage_tools.geometry.voxelize import (
    GridSpec,
    _tri_box_overlap,
    area_per_voxel,
    grid_for_bounds,
    mark_wood_fraction,
    subgrid_coverage,
)

UNIT = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(1, 1, 1))


def tri_areas(tris) -> np.ndarray:
    t = np.asarray(tris, dtype=float)
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def quad(p0, u, v) -> np.ndarray:
    """Two triangles of the parallelogram p0, p0+u, p0+u+v, p0+v."""
    p0, u, v = (np.asarray(x, dtype=float) for x in (p0, u, v))
    return np.array([[p0, p0 + u, p0 + u + v], [p0, p0 + u + v, p0 + v]])


def to_world(grid: GridSpec, index_coords) -> np.ndarray:
    return np.asarray(grid.origin) + np.asarray(index_coords, dtype=float) * grid.voxel_size


def only_nonzero(arr: np.ndarray) -> dict:
    return {tuple(int(i) for i in ijk): float(arr[tuple(ijk)]) for ijk in np.argwhere(arr != 0)}


# --------------------------------------------------------------------------
# Pure-Python references (world coordinates, no index-space transform)
# --------------------------------------------------------------------------


def _ref_clip(poly, axis, c, keep_above):
    sign = 1.0 if keep_above else -1.0
    out = []
    for k in range(len(poly)):
        p, q = poly[k - 1], poly[k]
        dp, dq = sign * (p[axis] - c), sign * (q[axis] - c)
        if dq >= 0:
            if dp < 0:
                out.append(p + (c - p[axis]) / (q[axis] - p[axis]) * (q - p))
            out.append(q)
        elif dp >= 0:
            out.append(p + (c - p[axis]) / (q[axis] - p[axis]) * (q - p))
    return out


def _ref_clip_box(tri, lo, hi):
    poly = [np.asarray(v, dtype=float) for v in tri]
    for axis in range(3):
        poly = _ref_clip(poly, axis, lo[axis], True)
        poly = _ref_clip(poly, axis, hi[axis], False)
        if not poly:
            break
    return poly


def _ref_area(poly) -> float:
    if len(poly) < 3:
        return 0.0
    s = np.zeros(3)
    for k in range(1, len(poly) - 1):
        s += np.cross(poly[k] - poly[0], poly[k + 1] - poly[0])
    return 0.5 * float(np.linalg.norm(s))


def ref_area_per_voxel(tris, grid: GridSpec) -> np.ndarray:
    out = np.zeros(grid.shape)
    o, h = np.asarray(grid.origin), grid.voxel_size
    for ijk in np.ndindex(*grid.shape):
        lo = o + np.asarray(ijk) * h
        out[ijk] = sum(_ref_area(_ref_clip_box(t, lo, lo + h)) for t in tris)
    return out


def ref_subgrid_coverage(tris, grid: GridSpec) -> np.ndarray:
    """A sub-cube is intersected iff clipping the triangle by its 6 closed half-spaces leaves something."""
    o, s = np.asarray(grid.origin), grid.voxel_size / 3
    hit = np.zeros(tuple(3 * n for n in grid.shape), dtype=bool)
    for abc in np.ndindex(*hit.shape):
        lo = o + np.asarray(abc) * s
        hit[abc] = any(_ref_clip_box(t, lo, lo + s) for t in tris)
    nx, ny, nz = grid.shape
    return hit.reshape(nx, 3, ny, 3, nz, 3).sum(axis=(1, 3, 5)) / 27.0


# --------------------------------------------------------------------------
# GridSpec
# --------------------------------------------------------------------------


def test_gridspec_helpers():
    g = GridSpec(origin=(1.0, -2.0, 0.5), voxel_size=0.5, shape=(4, 2, 3))
    assert g.voxel_volume == 0.125
    lo, hi = g.bounds
    np.testing.assert_array_equal(lo, [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(hi, [3.0, -1.0, 2.0])
    np.testing.assert_array_equal(g.index_to_world((0, 0, 0)), [1.25, -1.75, 0.75])
    np.testing.assert_array_equal(g.index_to_world([[3, 1, 2], [1, 0, 0]]), [[2.75, -1.25, 1.75], [1.75, -1.75, 0.75]])
    # numpy inputs are normalised to hashable Python tuples
    g2 = GridSpec(origin=np.array([1.0, -2.0, 0.5]), voxel_size=np.float64(0.5), shape=np.array([4, 2, 3]))
    assert g2 == g and hash(g2) == hash(g)
    assert isinstance(g2.shape[0], int) and isinstance(g2.origin[0], float)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"origin": (0, float("nan"), 0)}, "origin"),
        ({"origin": (0, 0)}, "origin"),
        ({"voxel_size": 0.0}, "voxel_size"),
        ({"voxel_size": -1.0}, "voxel_size"),
        ({"voxel_size": float("inf")}, "voxel_size"),
        ({"shape": (4, 0, 4)}, "shape"),
        ({"shape": (4, 4)}, "shape"),
        ({"shape": (4, 4.0, 4)}, "shape"),
    ],
)
def test_gridspec_rejects_bad_fields(kwargs, words):
    fields = {"origin": (0.0, 0.0, 0.0), "voxel_size": 1.0, "shape": (4, 4, 4)} | kwargs
    with pytest.raises(ValueError, match=words):
        GridSpec(**fields)


# --------------------------------------------------------------------------
# grid_for_bounds
# --------------------------------------------------------------------------


def test_grid_for_bounds_resolution_is_along_longest_edge():
    g = grid_for_bounds((0, 0, 0), (4.0, 2.0, 1.0), resolution=8, margin_voxels=1)
    assert g.voxel_size == 0.5
    assert g.shape == (10, 6, 4)  # (8, 4, 2) voxels on [lo, hi] + one margin voxel per side
    np.testing.assert_allclose(g.origin, (-0.5, -0.5, -0.5), atol=1e-15)


def test_grid_for_bounds_voxel_size_margins_and_rounding_up():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.3, 0.0])
    g = grid_for_bounds(lo, hi, voxel_size=0.25, margin_voxels=2)
    # x: exactly 4 voxels; y: 0.3 / 0.25 -> 2 voxels; z: flat -> 1 voxel; + 2 * 2 margin voxels
    assert g.shape == (8, 6, 5)
    assert g.voxel_size == 0.25
    glo, ghi = g.bounds
    assert np.all(glo + 2 * 0.25 <= lo + 1e-12) and np.all(ghi - 2 * 0.25 >= hi - 1e-12)
    # the core voxels are centred on the bounds: the flat z plane is at a voxel centre, not on a face
    np.testing.assert_allclose((glo + ghi) / 2, (lo + hi) / 2, atol=1e-15)
    assert (0.0 - glo[2]) / 0.25 == pytest.approx(2.5)


def test_grid_for_bounds_degenerate_bounds():
    g = grid_for_bounds((1, 2, 3), (1, 2, 3), voxel_size=0.1, margin_voxels=0)
    assert g.shape == (1, 1, 1)
    np.testing.assert_allclose(g.index_to_world((0, 0, 0)), (1, 2, 3))
    g = grid_for_bounds((0, 0, 5), (2, 1, 5), resolution=4, margin_voxels=3)
    assert g.shape == (4 + 6, 2 + 6, 1 + 6)
    with pytest.raises(ValueError, match="single point"):
        grid_for_bounds((1, 2, 3), (1, 2, 3), resolution=4)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"voxel_size": 0.1, "resolution": 10},
        {"voxel_size": 0.0},
        {"voxel_size": -0.5},
        {"voxel_size": float("nan")},
        {"resolution": 0},
        {"resolution": -3},
        {"resolution": 2.5},
        {"resolution": True},
    ],
)
def test_grid_for_bounds_bad_options(kwargs):
    with pytest.raises(ValueError, match=r"voxel_size.*resolution|resolution.*voxel_size"):
        grid_for_bounds((0, 0, 0), (1, 1, 1), **kwargs)


def test_grid_for_bounds_bad_bounds_and_margin():
    with pytest.raises(ValueError, match="lo must be <= hi"):
        grid_for_bounds((0, 0, 2), (1, 1, 1), resolution=4)
    with pytest.raises(ValueError, match="finite"):
        grid_for_bounds((0, 0, 0), (1, np.inf, 1), resolution=4)
    with pytest.raises(ValueError, match="margin_voxels"):
        grid_for_bounds((0, 0, 0), (1, 1, 1), resolution=4, margin_voxels=-1)


def test_grid_for_bounds_holds_all_area(rng):
    tris = rng.normal(size=(300, 3, 3)) * [3.0, 1.0, 0.5] + [10.0, -4.0, 2.0]
    pts = tris.reshape(-1, 3)
    for margin in (0, 1):
        grid = grid_for_bounds(pts.min(0), pts.max(0), resolution=17, margin_voxels=margin)
        total = tri_areas(tris).sum()
        assert area_per_voxel(tris, grid).sum() == pytest.approx(total, rel=1e-12)


# --------------------------------------------------------------------------
# area_per_voxel
# --------------------------------------------------------------------------


def test_area_quad_inside_one_voxel():
    grid = GridSpec(origin=(-1.0, 0.0, 2.0), voxel_size=0.5, shape=(3, 4, 2))
    # tilted rectangle inside voxel (1, 2, 0), given in index coordinates: u x v = (-0.15, 0, 0.3)
    tris = to_world(grid, quad((1.1, 2.1, 0.1), (0.6, 0.0, 0.3), (0.0, 0.5, 0.0)))
    expected = math.sqrt(0.15**2 + 0.3**2) * 0.5**2  # index-space area times voxel_size^2
    area = area_per_voxel(tris, grid)
    assert area.dtype == np.float64 and area.shape == grid.shape
    assert list(only_nonzero(area)) == [(1, 2, 0)]
    assert area[1, 2, 0] == pytest.approx(expected, rel=1e-14)


def test_area_square_split_30_70_across_a_face():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(2, 1, 1))
    # square x in [0.7, 1.7], y in [0.2, 0.8] at z = 0.5: 0.3 x 0.6 in voxel 0, 0.7 x 0.6 in voxel 1
    area = area_per_voxel(quad((0.7, 0.2, 0.5), (1.0, 0.0, 0.0), (0.0, 0.6, 0.0)), grid)
    assert area[0, 0, 0] == pytest.approx(0.18, abs=1e-12)
    assert area[1, 0, 0] == pytest.approx(0.42, abs=1e-12)


def test_area_diagonal_split():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(2, 2, 1))
    # right triangle (0,0)-(2,0)-(0,2): the unit square (0,0), two half squares, and only a point of voxel (1,1)
    area = area_per_voxel(np.array([[[0, 0, 0.5], [2, 0, 0.5], [0, 2, 0.5]]]), grid)
    np.testing.assert_allclose(area[:, :, 0], [[1.0, 0.5], [0.5, 0.0]], rtol=0, atol=1e-12)


def test_area_triangle_in_a_face_plane_counted_once():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(2, 2, 2))
    # In the face plane x = 1 shared by voxels i = 0 and i = 1: it goes to the + side, i = 1, only.
    in_face = np.array([[[1.0, 0.2, 0.2], [1.0, 0.8, 0.2], [1.0, 0.5, 0.8]]])
    area = area_per_voxel(in_face, grid)
    assert only_nonzero(area) == {(1, 0, 0): pytest.approx(0.18, abs=1e-15)}
    # In the grid's upper face x = 2: the last voxel owns that face, i = 1.
    area = area_per_voxel(in_face + [1.0, 0, 0], grid)
    assert only_nonzero(area) == {(1, 0, 0): pytest.approx(0.18, abs=1e-15)}
    # In the lower face x = 0 of the grid: voxel 0.
    area = area_per_voxel(in_face - [1.0, 0, 0], grid)
    assert only_nonzero(area) == {(0, 0, 0): pytest.approx(0.18, abs=1e-15)}
    # In the face plane x = 1 and straddling the faces y = 1 and z = 1: split 4 ways between the i = 1 voxels.
    # Base y in [0.5, 1.5] at z = 0.5, apex (y=1, z=1.5): area 0.5, 0.375 below z = 1, halves on either side of y = 1.
    area = area_per_voxel(np.array([[[1.0, 0.5, 0.5], [1.0, 1.5, 0.5], [1.0, 1.0, 1.5]]]), grid)
    assert only_nonzero(area) == {
        (1, 0, 0): pytest.approx(0.1875, abs=1e-15),
        (1, 1, 0): pytest.approx(0.1875, abs=1e-15),
        (1, 0, 1): pytest.approx(0.0625, abs=1e-15),
        (1, 1, 1): pytest.approx(0.0625, abs=1e-15),
    }


def test_area_triangle_along_a_voxel_edge():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(1, 2, 2))
    # In the face plane z = 1 with an edge on the line y = 1, z = 1 (a voxel edge shared by 4 voxels).
    # z: the + side (k = 1); y: the triangle spans y in [1, 1.6], only voxel j = 1 has area.
    above = np.array([[[0.2, 1.0, 1.0], [0.8, 1.0, 1.0], [0.5, 1.6, 1.0]]])
    assert only_nonzero(area_per_voxel(above, grid)) == {(0, 1, 1): pytest.approx(0.18, abs=1e-15)}
    # mirrored to y in [0.4, 1]: voxel j = 0
    below = np.array([[[0.2, 1.0, 1.0], [0.8, 1.0, 1.0], [0.5, 0.4, 1.0]]])
    assert only_nonzero(area_per_voxel(below, grid)) == {(0, 0, 1): pytest.approx(0.18, abs=1e-15)}
    # the two together (a card whose diagonal lies on the edge): no loss, no double counting
    area = area_per_voxel(np.concatenate([above, below]), grid)
    assert area.sum() == pytest.approx(0.36, abs=1e-15)


def test_area_partly_outside_grid():
    # plane z = 0.5 triangle (-1,0)-(1,0)-(-1,2) (area 2); hypotenuse x + y = 1: inside [0,1]^2 the half square, 0.5
    tri = np.array([[[-1.0, 0.0, 0.5], [1.0, 0.0, 0.5], [-1.0, 2.0, 0.5]]])
    assert area_per_voxel(tri, UNIT)[0, 0, 0] == pytest.approx(0.5, abs=1e-15)
    # tilted through the grid and out of both z faces: plane z = 0.5 + 2 (x - 0.5) cuts [0,1]^3 in the
    # strip x in [0.25, 0.75], whose area is 0.5 (width) * 1 (y) * sqrt(1 + 2^2)
    big = quad((-1.0, -1.0, -2.5), (3.0, 0.0, 6.0), (0.0, 3.0, 0.0))
    assert area_per_voxel(big, UNIT)[0, 0, 0] == pytest.approx(0.5 * math.sqrt(5.0), rel=1e-14)
    # a plane covering a 3x3x1 grid and extending past it: each voxel holds exactly 1
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(3, 3, 1))
    area = area_per_voxel(quad((-5.0, -5.0, 0.25), (13.0, 0.0, 0.0), (0.0, 13.0, 0.0)), grid)
    np.testing.assert_allclose(area, np.ones((3, 3, 1)), rtol=0, atol=1e-13)
    # entirely outside: nothing
    assert not area_per_voxel(tri + [0.0, 0.0, 3.0], UNIT).any()


def test_area_degenerate_triangles_contribute_zero():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(2, 2, 2))
    degenerate = np.array(
        [
            [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]],  # a point
            [[0.1, 0.2, 0.3], [1.1, 1.2, 1.3], [1.6, 1.7, 1.8]],  # collinear, crossing faces
            [[1.0, 1.0, 0.0], [1.0, 1.0, 2.0], [1.0, 1.0, 1.0]],  # on a voxel edge line
        ]
    )
    area = area_per_voxel(degenerate, grid)
    assert np.all(np.isfinite(area)) and np.all(area >= 0)
    assert area.sum() <= 1e-15
    assert not subgrid_coverage(degenerate, grid).any()


def test_area_random_triangles_conserve_total(rng):
    grid = GridSpec(origin=(-0.3, 1.7, 2.2), voxel_size=0.37, shape=(5, 4, 3))
    lo, hi = grid.bounds
    tris = rng.uniform(lo, hi, size=(2000, 3, 3))
    area = area_per_voxel(tris, grid)
    assert np.all(np.isfinite(area)) and np.all(area >= 0.0)
    total = tri_areas(tris).sum()
    assert abs(area.sum() - total) <= 1e-12 * total
    # small triangles (leaf-like) too
    small = np.clip(rng.uniform(lo, hi, size=(3000, 1, 3)) + rng.normal(scale=0.05, size=(3000, 3, 3)), lo, hi)
    area = area_per_voxel(small, grid)
    assert abs(area.sum() - tri_areas(small).sum()) <= 1e-12 * tri_areas(small).sum()


# Vertices on a quarter-voxel lattice: many triangles lie in face planes, have edges on voxel
# edge lines or vertices on corners, or are degenerate -- the cases where conventions matter.
lattice_triangles = st.lists(
    st.lists(st.tuples(*[st.integers(0, 12)] * 3), min_size=3, max_size=3), min_size=1, max_size=12
)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lattice_triangles)
def test_area_conserved_on_lattice_aligned_triangles(points):
    grid = GridSpec(origin=(-1.0, 0.0, 0.5), voxel_size=0.5, shape=(6, 6, 6))  # index coords 0..6
    tris = to_world(grid, np.asarray(points, dtype=float) / 2.0)  # index coords k / 2, k in 0..12
    area = area_per_voxel(tris, grid)
    assert np.all(np.isfinite(area)) and np.all(area >= 0.0)
    total = tri_areas(tris).sum()
    assert abs(area.sum() - total) <= 1e-12 * max(total, 1.0)


def test_area_matches_python_reference(rng):
    grid = GridSpec(origin=(0.25, -0.5, 1.0), voxel_size=0.4, shape=(3, 3, 2))
    lo, hi = grid.bounds
    centres = rng.uniform(lo - 0.2, hi + 0.2, size=(12, 1, 3))  # some partly outside the grid
    tris = centres + rng.normal(scale=0.35, size=(12, 3, 3))
    got = area_per_voxel(tris, grid)
    want = ref_area_per_voxel(tris, grid)
    assert want.sum() > 0.1 and np.count_nonzero(want) > 6
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_area_same_result_for_any_thread_count(rng):
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=0.1, shape=(16, 8, 8))
    tris = rng.uniform(0.0, 0.8, size=(4000, 1, 3)) * [2, 1, 1] + rng.normal(scale=0.1, size=(4000, 3, 3))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = area_per_voxel(tris, grid)
        cov_one = subgrid_coverage(tris, grid)
    finally:
        numba.set_num_threads(before)
    # each voxel receives its pieces in triangle order whatever the thread count: bitwise equal
    np.testing.assert_array_equal(area_per_voxel(tris, grid), one)
    np.testing.assert_array_equal(subgrid_coverage(tris, grid), cov_one)


@pytest.mark.parametrize("fn", [area_per_voxel, subgrid_coverage])
def test_input_checks(fn):
    with pytest.raises(ValueError, match=r"\(T, 3, 3\)"):
        fn(np.zeros((4, 3)), UNIT)
    with pytest.raises(ValueError, match=r"\(T, 3, 3\)"):
        fn(np.zeros((4, 3, 2)), UNIT)
    bad = np.zeros((5, 3, 3))
    bad[3, 1, 2] = np.nan
    with pytest.raises(ValueError, match="finite.*index 3"):
        fn(bad, UNIT)
    with pytest.raises(TypeError, match="GridSpec"):
        fn(np.zeros((1, 3, 3)), (0, 0, 0))
    empty = fn(np.zeros((0, 3, 3)), UNIT)
    assert empty.shape == (1, 1, 1) and not empty.any()
    # float32 and nested lists are accepted
    tri32 = np.array([[[0.1, 0.1, 0.5], [0.9, 0.1, 0.5], [0.1, 0.9, 0.5]]], dtype=np.float32)
    assert fn(tri32, UNIT)[0, 0, 0] > 0
    assert fn(tri32.tolist(), UNIT)[0, 0, 0] > 0


# --------------------------------------------------------------------------
# subgrid_coverage (geist2008 sec. 4.2)
# --------------------------------------------------------------------------


def test_subgrid_tiny_triangle_in_one_subcube():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(2, 2, 2))
    # sub-cube (sa, sb, sc) = (1, 2, 0) of voxel (1, 0, 1): [4/3, 5/3] x [2/3, 1] x [1, 4/3], centre below
    c = np.array([1.5, 5 / 6, 7 / 6])
    tri = np.array([[c + [-0.05, -0.04, 0.0], c + [0.05, -0.03, 0.02], c + [0.0, 0.05, -0.05]]])
    cov = subgrid_coverage(tri, grid)
    assert only_nonzero(cov) == {(1, 0, 1): pytest.approx(1 / 27, abs=1e-15)}


def test_subgrid_plane_through_voxel_middle():
    # z = 0.5 is inside the middle layer of sub-cubes: 9 of 27
    cov = subgrid_coverage(quad((-1.0, -1.0, 0.5), (3.0, 0.0, 0.0), (0.0, 3.0, 0.0)), UNIT)
    assert cov[0, 0, 0] == pytest.approx(9 / 27, abs=1e-15)
    # tilted plane through the centre and the whole voxel, z = 0.5 + 0.1 (x - 0.5): rises 0.1 over the
    # voxel, staying inside the middle layer [1/3, 2/3]: still 9 of 27
    cov = subgrid_coverage(quad((-1.0, -1.0, 0.35), (3.0, 0.0, 0.3), (0.0, 3.0, 0.0)), UNIT)
    assert cov[0, 0, 0] == pytest.approx(9 / 27, abs=1e-15)


def test_subgrid_closed_boxes_touching_counts():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(3, 3, 3))
    # the square [1,2]^2 at z = 1.5 covers the centre voxel's middle layer (9/27); its edges lie in the
    # faces of the 4 side neighbours (touching a row of 3 sub-cubes each) and its corners touch one
    # sub-cube of the 4 diagonal neighbours
    cov = subgrid_coverage(quad((1.0, 1.0, 1.5), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)), grid) * 27
    expected = np.zeros((3, 3, 3))
    expected[:, :, 1] = [[1, 3, 1], [3, 9, 3], [1, 3, 1]]
    np.testing.assert_allclose(cov, expected, atol=1e-12)
    # a triangle lying exactly in the voxel face x = 1 marks the sub-cubes on both sides: in sub-cube
    # units (y, z) its vertices are (0.6,0.6), (2.4,0.6), (1.5,2.4): 3 + 3 + 1 = 7 squares touched
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(2, 1, 1))
    cov = subgrid_coverage(np.array([[[1.0, 0.2, 0.2], [1.0, 0.8, 0.2], [1.0, 0.5, 0.8]]]), grid) * 27
    np.testing.assert_allclose(cov.ravel(), [7, 7], atol=1e-12)


def test_subgrid_rejects_boxes_inside_the_bounding_box_only():
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=1.0, shape=(3, 3, 1))
    # triangle (0,0)-(2.9,0)-(0,2.9) at z = 0.5: its bounding box covers all 9 voxels, but voxels with
    # i + j >= 3 lie beyond the hypotenuse x + y = 2.9. A sub-cube with lower corner (x0, y0) is hit iff
    # x0 + y0 <= 2.9 (middle z layer only): 9, 9, 6 sub-cubes along the first row, etc.
    tri = np.array([[[0.0, 0.0, 0.5], [2.9, 0.0, 0.5], [0.0, 2.9, 0.5]]])
    cov = subgrid_coverage(tri, grid)[:, :, 0] * 27
    np.testing.assert_allclose(cov, [[9, 9, 6], [9, 6, 0], [6, 0, 0]], atol=1e-12)


def test_sat_rejects_bounding_box_overlap():
    tri = np.zeros((3, 3))
    # box [0,1]^3; the triangle's bounding box [0.9, 2]^2 overlaps it but the triangle is x + y >= 2.9
    tri[:] = [[0.9, 2.0, 0.5], [2.0, 0.9, 0.5], [2.0, 2.0, 0.5]]
    assert not _tri_box_overlap(tri, 0.5, 0.5, 0.5, 0.5)
    # the same triangle moved so that its long edge crosses the box corner region
    tri[:] = [[0.4, 1.5, 0.5], [1.5, 0.4, 0.5], [2.0, 2.0, 0.5]]
    assert _tri_box_overlap(tri, 0.5, 0.5, 0.5, 0.5)
    # a tilted triangle beside a box edge: its bounding box [0.9, 2] x [0.9, 2] x [0.2, 0.8] overlaps the
    # box, and its plane passes through the box centre (normal (-0.33, 0.33, 1.21)), but x + y >= 2.9
    tri[:] = [[0.9, 2.0, 0.2], [2.0, 0.9, 0.8], [2.0, 2.0, 0.5]]
    assert not _tri_box_overlap(tri, 0.5, 0.5, 0.5, 0.5)
    # touching counts: a triangle in the plane z = 1 over the box
    tri[:] = [[0.2, 0.2, 1.0], [0.8, 0.2, 1.0], [0.5, 0.8, 1.0]]
    assert _tri_box_overlap(tri, 0.5, 0.5, 0.5, 0.5)
    tri[:, 2] = 1.0 + 1e-12
    assert not _tri_box_overlap(tri, 0.5, 0.5, 0.5, 0.5)


def test_sat_matches_clipping_on_random_triangles(rng):
    # near-miss triangles around the box [0,1]^3: the SAT agrees with clipping, including on the many
    # whose bounding box overlaps the box while the triangle misses it
    tris = rng.uniform(-0.6, 1.6, size=(1500, 1, 3)) + rng.normal(scale=0.5, size=(1500, 3, 3))
    lo, hi = np.zeros(3), np.ones(3)
    bbox_only = 0
    for t in tris:
        want = bool(_ref_clip_box(t, lo, hi))
        assert _tri_box_overlap(t, 0.5, 0.5, 0.5, 0.5) == want
        bbox_only += (not want) and bool(np.all(t.min(0) <= hi) and np.all(t.max(0) >= lo))
    assert bbox_only > 100


def test_subgrid_matches_python_reference(rng):
    grid = GridSpec(origin=(-0.2, 0.1, 0.3), voxel_size=0.5, shape=(3, 2, 2))
    lo, hi = grid.bounds
    centres = rng.uniform(lo - 0.1, hi + 0.1, size=(8, 1, 3))
    tris = centres + rng.normal(scale=0.25, size=(8, 3, 3))
    got = subgrid_coverage(tris, grid)
    want = ref_subgrid_coverage(tris, grid)
    assert 0 < np.count_nonzero(want) < want.size and np.any((want > 0) & (want < 1))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)


def test_subgrid_values_are_multiples_of_one_27th(rng):
    grid = GridSpec(origin=(0.0, 0.0, 0.0), voxel_size=0.25, shape=(6, 6, 6))
    tris = rng.uniform(0.2, 1.3, size=(400, 1, 3)) + rng.normal(scale=0.08, size=(400, 3, 3))
    cov = subgrid_coverage(tris, grid)
    assert cov.shape == grid.shape and np.all((cov >= 0) & (cov <= 1))
    np.testing.assert_allclose(cov * 27, np.round(cov * 27), atol=1e-12)
    # every voxel holding area is covered, and covered voxels hold area or touch the triangles
    area = area_per_voxel(tris, grid)
    assert np.all(cov[area > 0] > 0)


# --------------------------------------------------------------------------
# mark_wood_fraction
# --------------------------------------------------------------------------


def test_mark_wood_fraction():
    leaf = np.array([[0.0, 1.0], [3.0, 0.0]])
    wood = np.array([[0.0, 1.0], [1.0, 2.0]])
    frac = mark_wood_fraction(leaf, wood)
    np.testing.assert_array_equal(frac, [[0.0, 0.5], [0.25, 1.0]])
    assert frac.dtype == np.float64
    tiny = mark_wood_fraction(np.array([0.0, 1e-320]), np.array([1e-320, 0.0]))
    assert np.all(np.isfinite(tiny)) and tiny.tolist() == [1.0, 0.0]
    with pytest.raises(ValueError, match="same shape"):
        mark_wood_fraction(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        mark_wood_fraction(np.array([np.nan]), np.array([1.0]))
    with pytest.raises(ValueError, match=">= 0"):
        mark_wood_fraction(np.array([1.0]), np.array([-1.0]))


# --------------------------------------------------------------------------
# the nodes trilinear interpolation reads (lb --base-extent leaves)
# --------------------------------------------------------------------------


def test_stencil_mask_holds_every_node_trilinear_interpolation_reads(rng):
    """Interpolating a field zeroed outside the mask gives the same values to the bit at the points, inside the
    lattice, on its faces and outside it (clamped); and the mask is no larger than 8 nodes a point."""
    from foliage_tools.geometry.voxelize import stencil_mask
    from foliage_tools.pipeline.lb import sample_trilinear

    grid = GridSpec(origin=(-1.0, 0.5, 2.0), voxel_size=0.25, shape=(12, 9, 7))
    field = rng.uniform(0.5, 2.0, size=grid.shape + (3,))
    lo, hi = np.asarray(grid.origin), np.asarray(grid.origin) + 0.25 * np.asarray(grid.shape)
    inside = rng.uniform(lo, hi, size=(40, 3))
    faces = np.array([lo, hi, lo + 0.125, hi - 0.125, [lo[0], hi[1], lo[2]]])  # boundary nodes' centres and corners
    outside = np.array([lo - 1.0, hi + 3.0, [lo[0] - 0.5, (lo[1] + hi[1]) / 2, hi[2] + 0.3]])
    for pts in (inside, faces, outside, inside[:1]):
        mask = stencil_mask(grid.shape, grid, pts)
        assert mask.shape == grid.shape and 1 <= mask.sum() <= 8 * len(pts)
        kept = np.where(mask[..., None], field, 0.0)
        assert np.array_equal(sample_trilinear(kept, grid, pts), sample_trilinear(field, grid, pts))
    # a point at a node's centre away from the faces still has a full 2 x 2 x 2 stencil (weight 0 on the upper nodes)
    assert stencil_mask(grid.shape, grid, grid.index_to_world(np.array([[3, 4, 2]]))).sum() == 8

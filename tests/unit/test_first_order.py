"""The first-order march (lighting.first_order) against the exact slab's once-scattered light, and its guards.

The case where the march's model is exact in expectation: the issue's uniform layer (examples/make_layer.py,
10 x 10 x 1.5 m, 30 000 random cards of 0.1 m, LAI 3) with each card's direct light given as the layer's mean
one, |n . s| exp(-tau(z) / mu0) (G = 0.5 for normals uniform on the sphere: Beer's law in a Poisson medium, which
the voxel medium reproduces in expectation). The once-scattered irradiance of a homogeneous slab is then the exact
discrete-ordinate solution at a vanishing albedo scaled to the real one (plane_parallel.solve_slab; its first
order is linear in the albedo), per depth bin of the inner region |x|, |y| < 3 m.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.lighting import first_order as fo
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.phase import canopy_bilambertian_phase
from foliage_tools.lighting.plane_parallel import solve_slab

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))

EPS = 1e-4


def _layer_inputs(r, t, elevation, seed=1):
    from make_layer import build_layer

    layer = build_layer(seed=seed)
    n = layer.leaf_count
    quads = layer.points.reshape(n, 4, 3)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    ids = np.concatenate([np.arange(n), np.arange(n)])
    el = math.radians(elevation)
    sun = np.array([math.cos(el), 0.0, math.sin(el)])
    depth = 0.5 * 2.0 * (1.5 - layer.centres[:, 2])  # G 0.5 x LAD 2 per metre below the top
    e_dir = np.abs(layer.normals @ sun) * np.exp(-depth / sun[2])
    optics = LeafOptics((r,) * 3, (t,) * 3)
    return fo.FirstOrderInputs(tris, ids, layer.centres, np.full(n, 0.01), e_dir, optics, sun), depth, sun[2]


def _exact_once(r, t, mu0, depth):
    """The slab's once-scattered irradiance, both faces summed (actinic flux / 2 of a unit beam)."""
    phase = canopy_bilambertian_phase(reflectance=EPS * r / (r + t), transmittance=EPS * t / (r + t))
    sol = solve_slab(tau=1.5, omega=EPS, mu0=mu0, phase=phase, depths=depth)
    return sol.actinic_flux_diffuse / 2 * (r + t) / EPS


@pytest.mark.parametrize("r, t, elevation", [(0.45, 0.45, 60.0), (0.4, 0.05, 30.0), (0.05, 0.4, 30.0)])
def test_uniform_layer_against_the_exact_slabs_first_order(r, t, elevation):
    # Bound 8 % per bin: the issue asks the whole E_scattered of `foliage spp` within 10 % of the exact solution
    # in every bin, and the later orders SPPG adds carry errors of their own (-1 ... -5 % in the slab's rows of
    # README's layer table), so the first order must leave them room. Measured at the default 32 voxels, top bin
    # first, with the default 2 averaged grids: -0.7 -1.5 -1.3 -0.9 +1.1 / -2.3 -0.6 +0.4 +1.2 +3.4 /
    # -2.2 -1.4 -0.7 -0.3 +1.3 %; the bottom bin is the highest in each (with cubic cells, the layer's bottom in a
    # 79 %-full cell, +3.5 / +6.3 / +3.7 %: the test below). Swapping r and t (the second and third cases) moves the light between the sunlit and the
    # shaded side: with the side of reflection flipped the two read -12 ... +69 % and +11 ... -35 % (measured).
    inputs, depth, mu0 = _layer_inputs(r, t, elevation)
    got = fo.solve(inputs).e_once[:, 0]
    want = _exact_once(r, t, mu0, depth)
    c = inputs.leaf_centers
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    bins = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    err = np.array([got[inner & (bins == k)].mean() / want[inner & (bins == k)].mean() - 1 for k in range(5)])
    assert np.all(np.abs(err) < 0.08), err


def test_reflection_and_transmission_sides_differ_as_the_slab_says():
    # The two swapped cases above against each other: the exact slab's first order of r = 0.4, t = 0.05 over
    # r = 0.05, t = 0.4 per depth bin (1.12 at the top to 0.61 at the bottom), and the march's, agree within 5 %
    # of the ratio: the grid's error largely cancels in it (same cards, same direct light; measured 0.6-2.5 %),
    # while a flipped side of reflection puts it at 0.79-2.6 of the slab's (measured).
    ratios = []
    for r, t in ((0.4, 0.05), (0.05, 0.4)):
        inputs, depth, mu0 = _layer_inputs(r, t, 30.0)
        ratios.append((fo.solve(inputs).e_once[:, 0], _exact_once(r, t, mu0, depth)))
    c = inputs.leaf_centers
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    bins = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    for k in range(5):
        m = inner & (bins == k)
        got = ratios[0][0][m].mean() / ratios[1][0][m].mean()
        want = ratios[0][1][m].mean() / ratios[1][1][m].mean()
        assert abs(got / want - 1) < 0.05, (k, got, want)


def test_the_grid_puts_the_layers_faces_on_cell_boundaries():
    # The layer's leaf-area density is uniform in z (card centres uniform in [0, 1.5 m]), so every z-band of the
    # march's grid must hold the same area, up to Poisson noise (about 6 000 cards a band: 1.3 %) and the cards'
    # own reach past the faces (a card's two centroids lie within a third of its 0.1 m side of its centre, 2 % of
    # a 0.3 m band). Bound 5 %. Cubic cells put the bottom face inside a cell 79 % full (5.2 cells of 0.317 m).
    inputs, _, _ = _layer_inputs(0.45, 0.45, 60.0)
    centroids = inputs.triangles.mean(axis=1)
    lo, h, shape = fo._fit_grid(np.concatenate([centroids, inputs.leaf_centers]), fo.DEFAULT_RESOLUTION)
    assert shape[0] == shape[1] == fo.DEFAULT_RESOLUTION and shape[2] == 5, shape
    band = np.floor((centroids[:, 2] - lo[2]) / h[2]).astype(int)
    assert band.min() == 0 and band.max() == shape[2] - 1
    counts = np.bincount(band, minlength=shape[2])
    assert np.all(np.abs(counts / counts.mean() - 1) < 0.05), counts


def test_a_thin_medium_keeps_one_cell_as_wide_as_the_long_axis_cells():
    # two cards above each other: 0.3 m tall, their centroids 0.033 m wide; one cell of 0.3 / 2 m across keeps the
    # 0.1 m cards inside it (a cell of the centroids' width would let every slanted march leave at once)
    kw = _two_cards()
    tri = kw["triangles"]
    lo, h, shape = fo._fit_grid(np.concatenate([tri.mean(axis=1), kw["leaf_centers"]]), 2)
    assert tuple(shape) == (1, 1, 2) and np.allclose(h, 0.15)
    assert np.all(lo[:2] < tri[..., :2].min(axis=(0, 1))) and np.all(lo[:2] + h[:2] > tri[..., :2].max(axis=(0, 1)))


def _two_cards(e_direct=(1.0, 0.0)):
    quad = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
    cards = [quad, quad + [0.0, 0.0, -0.3]]
    tris = np.array([q[list(idx)] for q in cards for idx in ((0, 1, 2), (0, 2, 3))])
    ids = np.array([0, 0, 1, 1])
    centers = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -0.3]])
    return dict(triangles=tris, leaf_of_triangle=ids, leaf_centers=centers, leaf_area=np.full(2, 0.01),
                e_direct=np.asarray(e_direct), optics=LeafOptics(0.3, 0.2), sun_direction=np.array([0.0, 0.0, 1.0]))


def test_a_lit_card_lights_the_card_below_it_and_not_itself():
    res = fo.solve(fo.FirstOrderInputs(**_two_cards()), resolution=2)
    assert res.e_once.shape == (2, 3) and np.all(np.isfinite(res.e_once))
    assert res.e_once[0].max() == 0.0  # the only lit card, taken out of its own voxel
    assert np.all(res.e_once[1] > 0.0)


def test_no_direct_light_no_first_order_and_wood_only_blocks():
    kw = _two_cards(e_direct=(0.0, 0.0))
    assert np.all(fo.solve(fo.FirstOrderInputs(**kw)).e_once == 0.0)
    kw = _two_cards()
    kw["leaf_of_triangle"] = np.array([0, 0, -1, -1])  # the lower card is wood: no leaf receives anything but card 0
    kw["leaf_centers"], kw["leaf_area"], kw["e_direct"] = kw["leaf_centers"][:1], kw["leaf_area"][:1], kw["e_direct"][:1]
    assert np.all(fo.solve(fo.FirstOrderInputs(**kw), resolution=2).e_once == 0.0)


@pytest.mark.parametrize("field, value", [
    ("triangles", np.full((4, 3, 3), np.nan)), ("leaf_of_triangle", np.array([0, 0, 2, 2])),
    ("leaf_area", np.array([0.01, 0.0])), ("e_direct", np.array([1.0, -1.0])), ("sun_direction", np.zeros(3)),
])
def test_bad_inputs_are_value_errors(field, value):
    kw = _two_cards()
    kw[field] = value
    with pytest.raises(ValueError):
        fo.FirstOrderInputs(**kw)


def test_bad_resolution_is_a_value_error():
    with pytest.raises(ValueError, match="resolution"):
        fo.solve(fo.FirstOrderInputs(**_two_cards()), resolution=0)


def test_lit_wood_reflects_to_its_lit_side_only():
    # an opaque Lambertian wood card lit from above (sun at the zenith) sends light up, none down: the leaf above it
    # receives, the same leaf placed below receives nothing (t = 0 for wood); and without wood_direct none either
    for leaf_z, wood_z, lit in ((0.0, -0.3, True), (-0.3, 0.0, False)):
        kw = _two_cards()
        quad = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
        kw["triangles"] = np.array([(quad + [0, 0, z])[list(i)] for z in (leaf_z, wood_z) for i in ((0, 1, 2), (0, 2, 3))])
        kw["leaf_of_triangle"] = np.array([0, 0, -1, -1])
        kw["leaf_centers"], kw["leaf_area"], kw["e_direct"] = np.array([[0.0, 0.0, leaf_z]]), np.full(1, 0.01), np.zeros(1)
        got = fo.solve(fo.FirstOrderInputs(**kw, wood_direct=np.ones(2)), resolution=2).e_once
        assert np.all(got > 0) if lit else np.all(got == 0), (leaf_z, got)
        assert np.all(fo.solve(fo.FirstOrderInputs(**kw), resolution=2).e_once == 0)


def test_wood_direct_needs_one_value_per_wood_triangle():
    kw = _two_cards()
    kw["leaf_of_triangle"] = np.array([0, 0, -1, -1])
    kw["leaf_centers"], kw["leaf_area"], kw["e_direct"] = kw["leaf_centers"][:1], kw["leaf_area"][:1], kw["e_direct"][:1]
    with pytest.raises(ValueError, match="wood_direct"):
        fo.FirstOrderInputs(**kw, wood_direct=np.ones(3))


@pytest.mark.parametrize("shift", [0.0, 0.25, 0.5])
def test_shifted_grids_keep_the_boxs_faces_and_cover_it(shift):
    # the averaged shifted grids (module docstring): a shifted axis of n cells has n + 1, its inner boundaries moved
    # by shift x h, its outer ones the box's faces (so a layer's faces stay on cell boundaries); one cell is not
    # shifted; the cells tile the box exactly
    lo, h, shape = np.zeros(3), np.array([0.3, 0.2, 0.5]), np.array([4, 1, 3])
    edges = fo._shifted_edges(lo, h, shape, (shift, shift, shift))
    for k in range(3):
        e = edges[k]
        assert e[0] == lo[k] and e[-1] == pytest.approx(lo[k] + shape[k] * h[k]) and np.all(np.diff(e) > 0)
        moved = shift > 0 and shape[k] > 1
        assert len(e) - 1 == shape[k] + moved
        if moved:
            assert np.diff(e)[0] == pytest.approx((1 - shift) * h[k]) and np.diff(e)[-1] == pytest.approx(shift * h[k])
            assert np.allclose(np.diff(e)[1:-1], h[k])


def test_every_shift_count_gives_the_layers_first_order():
    # each grid of the average is a voxel medium of the same layer: the mean over 1, 2 or 8 of them is within the
    # same 8 % of the exact slab's first order (the bound of the layer test above); measured at 60 deg, top bin
    # first, 1: +0.3 ... +1.6 %, 2: -0.7 ... +1.1 %, 8: -0.7 ... +1.2 %
    inputs, depth, mu0 = _layer_inputs(0.45, 0.45, 60.0)
    want = _exact_once(0.45, 0.45, mu0, depth)
    c = inputs.leaf_centers
    inner = (np.abs(c[:, 0]) < 3.0) & (np.abs(c[:, 1]) < 3.0)
    bins = np.clip(np.digitize(depth, np.linspace(0, 1.5, 6)) - 1, 0, 4)
    for shifts in sorted(fo.SHIFTS):
        got = fo.solve(inputs, shifts=shifts).e_once[:, 0]
        err = np.array([got[inner & (bins == k)].mean() / want[inner & (bins == k)].mean() - 1 for k in range(5)])
        assert np.all(np.abs(err) < 0.08), (shifts, err)
    with pytest.raises(ValueError, match="shifts"):
        fo.solve(inputs, shifts=3)

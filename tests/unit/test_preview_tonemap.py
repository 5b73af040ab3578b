"""Reinhard tone mapping, sRGB encoding and the comparison helpers, against their closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from foliage_tools.preview.compare import false_colour, rel_rms, relative_error, side_by_side
from foliage_tools.preview.tonemap import Exposure, luminance, measure_exposure, photographic_exposure, reinhard, srgb_decode, srgb_encode


def grey(values) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    return np.repeat(v[..., None], 3, axis=-1)


def test_log_average_is_reinhard_eq_1():
    img = grey([[0.01, 0.1], [10.0, 100.0]])
    e = measure_exposure(img, delta=0.0 + 1e-12)
    assert e.log_average == pytest.approx(1.0, rel=1e-9)  # geometric mean of 0.01, 0.1, 10, 100


def test_key_maps_the_log_average_to_middle_grey():
    # without burn-out (L_white = inf, eq. 3) a pixel at the log-average maps to a / (1 + a)
    e = Exposure(log_average=0.37, white=math.inf, key=0.18)
    out = reinhard(grey([[0.37]]), e)
    assert out[0, 0, 0] == pytest.approx(0.18 / 1.18, rel=1e-6)


def test_white_point_maps_to_one():
    # eq. (4): a scaled luminance equal to L_white maps to exactly 1
    e = Exposure(log_average=1.0, white=4.0, key=0.5)
    out = reinhard(grey([[8.0]]), e)  # scaled L = 0.5 * 8 = 4
    assert out[0, 0, 0] == pytest.approx(1.0, rel=1e-6)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0, 1e4), min_size=2, max_size=20))
def test_displayed_luminance_is_monotonic_and_bounded(values):
    lum = np.sort(np.asarray(values))
    e = Exposure(log_average=0.2, white=3.0)
    out = luminance(reinhard(grey(lum)[None], e))[0]
    assert np.all(np.diff(out) >= -1e-6)
    assert np.all((out >= 0) & (out <= 1.0 + 1e-6))


def test_black_and_empty_images_stay_black():
    e = measure_exposure(np.zeros((4, 4, 3)))
    assert np.all(reinhard(np.zeros((4, 4, 3)), e) == 0)
    e = measure_exposure(np.ones((4, 4, 3)), np.zeros((4, 4)))  # nothing masked in
    assert e.white == 1.0


def test_white_from_the_surroundings_keeps_them_from_burning_out():
    tree = grey(np.full((10, 10), 0.02))
    scene = tree.copy()
    scene[:5] = 0.2  # a ground ten times brighter than the tree
    mask = np.zeros((10, 10))
    mask[5:] = 1
    e = measure_exposure(scene, mask, white_rgb=scene, white_percentile=100)
    out = reinhard(scene, e)
    assert out[0, 0, 0] == pytest.approx(1.0, rel=1e-5)  # the brightest pixel maps to white, not beyond
    assert out[9, 0, 0] < 0.5


def test_photographic_exposure_maps_an_18_percent_grey_surface_to_the_key_whatever_the_picture():
    # a horizontal Lambertian surface of reflectance 0.18 under illuminance E has radiance 0.18 E / pi;
    # Reinhard eq. (2) must scale it to the key, and white paper (reflectance 1) to scaled luminance 1
    e_h = 0.93
    card = grey([[0.18 * e_h / math.pi]])
    dark = grey(np.full((8, 8), 1e-3))
    bright = grey(np.full((8, 8), 0.05))
    for picture in (dark, bright):
        exp = photographic_exposure(e_h, white_rgb=picture)
        assert exp.key / exp.log_average * float(luminance(card)[0, 0]) == pytest.approx(0.18, rel=1e-9)
        assert exp.white == pytest.approx(1.0)  # nothing in these pictures is brighter than white paper
        out = reinhard(grey([[e_h / math.pi]]), exp)
        assert out[0, 0, 0] == pytest.approx(1.0, rel=1e-6)  # white paper maps to display white
    # a highlight brighter than white paper raises L_white so it does not burn out
    glossy = bright.copy()
    glossy[0, 0] = 3.0 * e_h / math.pi
    assert photographic_exposure(e_h, white_rgb=glossy, white_percentile=100).white == pytest.approx(3.0, rel=1e-9)
    assert photographic_exposure(0.0) is None and photographic_exposure(float("nan")) is None


def test_srgb_round_trip_and_known_points():
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-6)
    assert srgb_encode(np.array([0.18]))[0] == pytest.approx(0.4614, abs=1e-3)  # middle grey


def test_relative_error_and_rel_rms():
    ref = grey([[1.0, 2.0], [4.0, 0.0]])
    test = grey([[1.1, 2.0], [3.0, 5.0]])
    mask = np.array([[1, 1], [1, 0]])
    err = relative_error(test, ref, mask)
    np.testing.assert_allclose(err[0], [0.1, 0.0], atol=1e-12)
    assert err[1, 0] == pytest.approx(-0.25) and np.isnan(err[1, 1])
    # DESIGN.md: sqrt(sum (x - r)^2 / sum r^2) over the masked pixels
    assert rel_rms(test, ref, mask) == pytest.approx(math.sqrt((0.01 + 0 + 1) / (1 + 4 + 16)))


def test_false_colour_signs_and_no_data():
    img = false_colour(np.array([[-0.5, 0.0, 0.5, np.nan]]), scale=0.5)
    blue, white, red, nodata = img[0]
    assert blue[2] > blue[0] and red[0] > red[2]
    assert np.all(white > 0.9) and np.all(nodata < 0.1)


def test_side_by_side_layout_and_labels():
    a = np.zeros((40, 30, 3), np.float32)
    out = side_by_side([[a, a, a], [a]], [["direct", "lb", "reference"], ["err"]])
    from foliage_tools.preview.compare import SEPARATOR, header_height

    hh = header_height(40)
    assert out.shape == (2 * (40 + hh) + SEPARATOR, 3 * 30 + 2 * SEPARATOR, 3)
    # the label strip holds bright text pixels; the panels stay untouched
    assert out[:hh, :30].max() > 0.5
    assert out[hh : hh + 40, :30].max() == 0.0

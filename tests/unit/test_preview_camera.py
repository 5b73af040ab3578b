"""Preview cameras: angle conventions, look-at/projection matrices, framing, USD camera parameters.

All checks are closed forms of the pinhole camera; tolerances are float64
round-off unless stated.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from foliage_tools.errors import UsageError
from foliage_tools.preview.camera import (
    angles_from_direction,
    bounds_corners,
    camera_from_usd,
    direction_from_angles,
    look_at,
    orbit_camera,
    perspective,
    usd_camera_size,
)

TALL_BOX = np.array([[-1.0, -2.0, 0.0], [1.5, 1.0, 5.0]])


@pytest.mark.parametrize(
    "up, az, el, expected",
    [
        ("Z", 0, 0, (1, 0, 0)),
        ("Z", 90, 0, (0, 1, 0)),  # DESIGN.md: counter-clockwise toward +Y in a Z-up stage
        ("Z", 0, 90, (0, 0, 1)),
        ("Y", 0, 0, (1, 0, 0)),
        ("Y", 90, 0, (0, 0, -1)),  # ... and toward -Z in a Y-up stage
        ("Y", 0, 90, (0, 1, 0)),
        ("Z", 45, 60, (0.5 * math.sqrt(0.5), 0.5 * math.sqrt(0.5), math.sqrt(3) / 2)),
    ],
)
def test_direction_from_angles_follows_the_design_convention(up, az, el, expected):
    np.testing.assert_allclose(direction_from_angles(az, el, up), expected, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(az=st.floats(0, 359.999), el=st.floats(-89.9, 89.9), up=st.sampled_from(["Y", "Z"]))
def test_angles_round_trip(az, el, up):
    d = direction_from_angles(az, el, up)
    assert abs(np.linalg.norm(d) - 1) < 1e-12
    az2, el2 = angles_from_direction(d, up)
    assert abs(el2 - el) < 1e-7
    assert min(abs(az2 - az), 360 - abs(az2 - az)) < 1e-6


def test_look_at_puts_the_eye_at_the_origin_and_the_target_down_minus_z():
    eye, target = np.array([3.0, -2.0, 5.0]), np.array([0.5, 1.0, 1.0])
    v = look_at(eye, target, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(v[:3, :3] @ v[:3, :3].T, np.eye(3), atol=1e-12)  # a rotation
    assert np.linalg.det(v[:3, :3]) > 0
    np.testing.assert_allclose(v @ np.r_[eye, 1], [0, 0, 0, 1], atol=1e-12)
    t = v @ np.r_[target, 1]
    np.testing.assert_allclose(t[:2], 0, atol=1e-12)
    assert t[2] == pytest.approx(-np.linalg.norm(eye - target))
    # world up stays up in the image: its camera-space y is positive
    assert (v[:3, :3] @ [0, 0, 1])[1] > 0
    with pytest.raises(ValueError):
        look_at(eye, eye, np.array([0.0, 0.0, 1.0]))


def test_perspective_maps_near_and_far_planes_to_ndc_minus_one_and_one():
    p = perspective(40.0, 1.5, 0.5, 80.0)
    for z, ndc in ((-0.5, -1.0), (-80.0, 1.0)):
        c = p @ [0, 0, z, 1]
        assert c[2] / c[3] == pytest.approx(ndc)
    # a point on the top edge of the field of view lands on ndc y = 1
    y = 10 * math.tan(math.radians(20))
    c = p @ [y * 1.5, y, -10, 1]
    assert c[0] / c[3] == pytest.approx(1.0) and c[1] / c[3] == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(
    az=st.floats(0, 360),
    el=st.floats(-90, 90),
    width=st.integers(16, 2048),
    height=st.integers(16, 2048),
    up=st.sampled_from(["Y", "Z"]),
)
def test_orbit_camera_frames_the_bounds_tightly(az, el, width, height, up):
    cam = orbit_camera(TALL_BOX, width=width, height=height, up_axis=up, azimuth=az, elevation=el, margin=1.05)
    px, w = cam.project(bounds_corners(TALL_BOX))
    assert np.all(w > 0), "every corner is in front of the camera"
    ndc = np.c_[px[:, 0] / width * 2 - 1, 1 - px[:, 1] / height * 2]
    # inside the image with the margin, and touching it on at least one side (the fit is exact)
    assert np.abs(ndc).max() == pytest.approx(1 / 1.05, rel=1e-9)
    # the camera sits at the requested angles as seen from the centre of the box
    az2, el2 = angles_from_direction(cam.position - TALL_BOX.mean(axis=0), up)
    assert el2 == pytest.approx(el, abs=1e-6)
    if abs(el) < 89.9:
        assert min(abs(az2 - az % 360), 360 - abs(az2 - az % 360)) < 1e-6
    # near and far enclose the bounds
    depth = -(np.c_[bounds_corners(TALL_BOX), np.ones(8)] @ cam.view.T)[:, 2]
    assert cam.near <= depth.min() and depth.max() <= cam.far


def test_orbit_camera_keeps_the_up_axis_up_in_the_image():
    for up, top in (("Z", [0, 0, 5.0]), ("Y", [0, 5.0, 0])):
        cam = orbit_camera(np.array([[-1.0, -1, -1], [1, 1, 1]]) * 5, width=100, height=100, up_axis=up, azimuth=30, elevation=10)
        (p_top, p_bottom), _ = cam.project(np.array([top, [0, 0, 0]]))
        assert p_top[1] < p_bottom[1], f"{up}-up: a point above the centre must be higher in the image (smaller row)"


def test_orbit_camera_distance_is_from_the_centre():
    cam = orbit_camera(TALL_BOX, width=64, height=64, up_axis="Z", azimuth=90, elevation=0, distance=20.0)
    np.testing.assert_allclose(cam.position, TALL_BOX.mean(axis=0) + [0, 20, 0], atol=1e-9)


@pytest.mark.parametrize("kwargs", [{"elevation": 91}, {"distance": -1.0}, {"distance": float("nan")}, {"fovy": 0.0}, {"width": 0}])
def test_orbit_camera_rejects_bad_options(kwargs):
    args = {"width": 64, "height": 64, "up_axis": "Z", **kwargs}
    with pytest.raises(UsageError):
        orbit_camera(TALL_BOX, **args)


def _usd(transform=None, **kw):
    args = {
        "transform": np.eye(4) if transform is None else transform,
        "projection": "perspective",
        "focal_length": 50.0,
        "horizontal_aperture": 36.0,
        "vertical_aperture": 24.0,
        "clipping_range": (0.1, 1000.0),
        "width": 360,
        "height": 240,
    }
    args.update(kw)
    return camera_from_usd(**args)


def test_usd_camera_field_of_view_from_focal_length_and_aperture():
    cam = _usd()
    # at depth 10 the window is 10 * 36/50 wide: its right edge is at x = 3.6
    (p,), w = cam.project(np.array([[3.6, 2.4, -10.0]]))
    np.testing.assert_allclose(p, [360, 0], atol=1e-9)
    assert w[0] == pytest.approx(10.0)


def test_usd_camera_transform_places_and_orients_the_camera():
    # camera at (0, -10, 2) looking along +Y (rotate -Z onto +Y: +90° about X), scaled by 3 (ignored)
    m = np.eye(4)
    m[:3, :3] = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]) * 3.0
    m[:3, 3] = [0, -10, 2]
    cam = _usd(transform=m)
    np.testing.assert_allclose(cam.position, [0, -10, 2], atol=1e-12)
    np.testing.assert_allclose(cam.forward, [0, 1, 0], atol=1e-12)
    (centre, above), _ = cam.project(np.array([[0, 5, 2.0], [0, 5, 3.0]]))
    np.testing.assert_allclose(centre, [180, 120], atol=1e-9)
    assert above[1] < centre[1]


def test_usd_camera_aperture_offset_shifts_the_window():
    cam = _usd(horizontal_aperture_offset=3.6)  # a tenth of the aperture: 10 % of the width
    (p,), _ = cam.project(np.array([[0, 0, -10.0]]))
    assert p[0] == pytest.approx(180 - 36)


def test_usd_camera_fits_the_whole_aperture_into_another_aspect():
    # a square image of a 3:2 aperture: the horizontal aperture fits, the vertical window grows
    cam = _usd(width=200, height=200)
    (right, top), _ = cam.project(np.array([[3.6, 0, -10.0], [0, 2.4, -10.0]]))
    assert right[0] == pytest.approx(200)
    assert top[1] == pytest.approx(100 - 100 * 24 / 36)


def test_usd_orthographic_camera_uses_tenths_of_a_unit():
    cam = _usd(projection="orthographic", horizontal_aperture=40.0, vertical_aperture=40.0, width=100, height=100)
    assert cam.orthographic
    (p,), _ = cam.project(np.array([[2.0, -2.0, -50.0]]))  # 40 tenths = 4 units wide
    np.testing.assert_allclose(p, [100, 100], atol=1e-9)


@pytest.mark.parametrize(
    "kw", [{"focal_length": 0.0}, {"clipping_range": (5.0, 1.0)}, {"projection": "fisheye"}, {"vertical_aperture": -1.0}]
)
def test_usd_camera_rejects_unusable_parameters(kw):
    with pytest.raises(UsageError):
        _usd(**kw)


def test_usd_camera_size_keeps_the_aperture_aspect():
    assert usd_camera_size(36.0, 24.0, 1024) == (1024, 683)


@pytest.mark.parametrize("up", [np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])])
def test_sky_directions_cover_the_upper_hemisphere_evenly(up):
    from foliage_tools.preview.renderer import sky_directions

    d = sky_directions(16, up)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    cos_t = d @ up
    assert np.all(cos_t > 0)
    # uniform in solid angle: cos(zenith) is uniform on (0, 1), mean 1/2; the cosine-weighted
    # mean of cos is 2/3 (the irradiance-weighted integral over the hemisphere)
    assert cos_t.mean() == pytest.approx(0.5, abs=1e-12)
    assert (cos_t**2).sum() / cos_t.sum() == pytest.approx(2 / 3, abs=0.01)
    # azimuths spread around: the horizontal components nearly cancel
    assert np.linalg.norm((d - np.outer(cos_t, up)).sum(axis=0)) < 0.5

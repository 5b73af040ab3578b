"""The ``smax`` method's vertex shader against Boulanger's model in Python (float64).

boulanger2008 ch. 5, Algorithms 11-13: the previewer evaluates the sky, direct-sun and
one-bounce terms per vertex from s_max and τ (shaders/boulanger.glsl). These tests read
the shader's per-vertex irradiance back by transform feedback
(:meth:`Renderer.smax_irradiance`) and hold it to
:mod:`foliage_tools.lighting.envelope.boulanger` evaluated in float64, for instances that rotate
and scale the tree and for suns exactly on, midway between, and away from the ω_j.

Tolerance: float32 evaluation of sums of 8 non-negative terms of O(1) magnitude with
exp/acos: 2e-5 relative to the largest value of each term over the leaves (absolute),
plus 2e-4 relative, ~100 float32 ulps. A wrong index, a swapped face, a sun left in
world space or a missing factor 2 fails by orders of magnitude more.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from foliage_tools.geometry.sun import to_prototype_space
from foliage_tools.lighting.envelope import boulanger
from foliage_tools.lighting.envelope import EnvelopeParams, sample_directions
from foliage_tools.lighting.envelope import solve as envelope_solve
from foliage_tools.preview.camera import direction_from_angles, orbit_camera
from foliage_tools.preview.renderer import DrawMesh, DrawPrototype, DrawScene, Ground, Lighting, Renderer
from foliage_tools.preview.tonemap import luminance
from tests.helpers.crowns import OPTICS, crown

Z = np.array([0.0, 0.0, 1.0])
SKY = (0.3, 0.4, 0.5)


def transforms():
    """Identity; rotated 70° about up, scaled 1.3, moved; tilted 25° about x with non-uniform scale."""
    rot = np.eye(4)
    a = math.radians(70)
    rot[:3, :3] = 1.3 * np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    rot[:3, 3] = [5.0, -2.0, 0.0]
    tilt = np.eye(4)
    b = math.radians(25)
    tilt[:3, :3] = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]]) @ np.diag([1.0, 0.8, 1.1])
    tilt[:3, 3] = [-4.0, 3.0, 0.0]
    return np.stack([np.eye(4), rot, tilt])


@pytest.fixture(scope="module")
def baked():
    corners, centres, normals, areas = crown()
    env = envelope_solve(centres, normals, areas, up=Z, params=EnvelopeParams(path="reference"))
    smax = np.repeat(env.smax.astype(np.float32), 6, axis=0)  # every corner of a leaf carries its s_max
    mesh = DrawMesh(corners=corners, leaf=True, smax=smax)
    scene = DrawScene((DrawPrototype((mesh,), transforms(), tau=env.tau),), Z)
    return scene, normals, env


def python_model(normals, env, sun_local, up_local):
    """Per-leaf float64 terms of boulanger.py, unit sun, for a sun already in the prototype's frame."""
    dirs = sample_directions(up_local)
    s = env.smax.astype(np.float64)
    optics = np.array([OPTICS.leaf.reflectance_front, OPTICS.leaf.transmittance_front,
                       OPTICS.leaf.reflectance_back, OPTICS.leaf.transmittance_back])
    d_front, d_back = boulanger.sun_direct_irradiance(normals, s, env.tau, sun_local, dirs)
    s_front, s_back = boulanger.sun_indirect_irradiance(normals, s, env.tau, sun_local, optics, dirs)
    sky = boulanger.sky_radiance_per_direction(SKY, OPTICS.ground_reflectance, dirs, up_local)
    k_front, k_back = boulanger.sky_irradiance(normals, np.exp(-env.tau * s), sky, dirs)
    return {"direct_front": d_front, "direct_back": d_back, "scattered_front": s_front, "scattered_back": s_back,
            "sky_front": k_front, "sky_back": k_back}


def suns():
    """World suns: exactly on ω_5 and ω_7 (above the horizon), midway between ω_4 and ω_5, and a generic one."""
    dirs = sample_directions(Z)
    mid = dirs[4] + dirs[5]
    return [dirs[5], dirs[7], mid / np.linalg.norm(mid), direction_from_angles(33.0, 41.0, "Z")]


@pytest.mark.parametrize("sun_index", range(4))
def test_vertex_shader_equals_the_python_model(baked, sun_index):
    scene, normals, env = baked
    sun = suns()[sun_index]
    with Renderer(scene, sky_samples=0) as r:
        (got,) = r.smax_irradiance(Lighting(sun, sky_radiance=SKY), OPTICS)
    n_leaves = len(normals)
    for k, t in enumerate(scene.prototypes[0].transforms):
        sun_local = to_prototype_space(sun, t)
        up_local = to_prototype_space(Z, scene.prototypes[0].transforms[0])  # the ω_j the bake used
        want = python_model(normals, env, sun_local, up_local)
        for name, expected in want.items():
            shader = got[name].reshape(len(scene.prototypes[0].transforms), n_leaves, 6, -1)[k]
            scale = float(np.abs(expected).max())
            assert scale > 0, f"{name} is zero everywhere: the test would not test it"
            # every corner of a leaf evaluates the same leaf (its two triangles' float32 normals
            # differ by round-off only)
            for corner in range(6):
                np.testing.assert_allclose(shader[:, corner].reshape(expected.shape), expected, rtol=2e-4, atol=2e-5 * scale,
                                           err_msg=f"{name}, instance {k}, corner {corner}")


def test_instances_see_the_sun_in_their_own_frame(baked):
    # the rotated instance's leaves get a different direct term than the identity's (same leaves,
    # same world sun): evaluating the model with the world sun for every instance would fail here
    scene, _, _ = baked
    with Renderer(scene, sky_samples=0) as r:
        (got,) = r.smax_irradiance(Lighting(suns()[3]), OPTICS)
    per_instance = got["direct_front"].reshape(3, -1)
    assert np.abs(per_instance[1] - per_instance[0]).max() > 0.1


def test_the_sun_on_a_sample_direction_is_continuous(baked):
    # eq. (5.7) exists to make s~_max continuous in the sun direction: a sun 1e-3 rad off ω_5
    # changes the per-leaf terms by O(1e-3), not by a jump
    scene, _, _ = baked
    dirs = sample_directions(Z)
    off = dirs[5] + 1e-3 * np.cross(dirs[5], Z) / np.linalg.norm(np.cross(dirs[5], Z))
    with Renderer(scene, sky_samples=0) as r:
        (a,) = r.smax_irradiance(Lighting(dirs[5]), OPTICS)
        (b,) = r.smax_irradiance(Lighting(off / np.linalg.norm(off)), OPTICS)
    for name in ("direct_front", "scattered_front"):
        assert np.abs(a[name] - b[name]).max() < 1e-2 * np.abs(a[name]).max()


def test_smax_scattered_light_raises_the_crown_and_never_lowers_a_pixel(baked):
    scene, _, _ = baked
    one = DrawScene((DrawPrototype(scene.prototypes[0].meshes, scene.prototypes[0].transforms[:1], tau=scene.prototypes[0].tau),), Z)
    bounds = one.bounds()
    cam = orbit_camera(bounds, width=96, height=96, up_axis="Z", azimuth=200, elevation=10, fovy=30.0)
    lighting = Lighting(direction_from_angles(45, 60, "Z"), sky_radiance=(0.02, 0.03, 0.04))
    ground = Ground.under(bounds, Z)
    with Renderer(one) as r:
        direct = r.render(cam, lighting, OPTICS, ground=ground)
        smax = r.render(cam, lighting, OPTICS, method="smax", ground=ground)
    tree = direct.tree > 0.5
    assert tree.sum() > 500
    # a sparse crown (300 cards, τ small): one bounce adds a few per cent (measured 3.5 %)
    assert luminance(smax.radiance)[tree].mean() > 1.02 * luminance(direct.radiance)[tree].mean()
    assert np.all(smax.radiance >= direct.radiance), "a non-negative term cannot darken any pixel"
    off_tree = direct.tree == 0
    np.testing.assert_array_equal(smax.radiance[off_tree], direct.radiance[off_tree])


def test_smax_light_on_one_card_is_eq_5_4_of_the_shader_irradiance():
    # one card facing the camera, the sun behind it: the smax method adds eq. (5.4) of the
    # shader's per-face scattered irradiance to the direct render,
    # (rho_rf E_front + rho_tb E_back) / pi -- not half of their sum on each face
    corners = np.array([[0, -0.5, -0.5], [0, 0.5, -0.5], [0, 0.5, 0.5], [0, -0.5, -0.5], [0, 0.5, 0.5], [0, -0.5, 0.5]], np.float32)
    corners[:, 2] += 2.0
    smax = np.tile(np.array([0.5, 1.0, 0.2, 0.0, 0.7, 0.3, 0.9, 0.4], np.float32), (6, 1))
    scene = DrawScene((DrawPrototype((DrawMesh(corners=corners, leaf=True, smax=smax),), np.eye(4)[None], tau=1.5),), Z)
    sun = direction_from_angles(150.0, 40.0, "Z")  # behind the card: the seen face gets no direct sun
    cam = orbit_camera(scene.bounds(), width=32, height=32, up_axis="Z", azimuth=0.0, elevation=0.0, fovy=30.0, distance=4.0)
    with Renderer(scene, sky_samples=0) as r:
        (terms,) = r.smax_irradiance(Lighting(sun), OPTICS)
        direct = r.render(cam, Lighting(sun), OPTICS)
        f = r.render(cam, Lighting(sun), OPTICS, method="smax")
    leaf = OPTICS.leaf
    added = (np.array(leaf.reflectance_front) * terms["scattered_front"][0] + np.array(leaf.transmittance_back) * terms["scattered_back"][0]) / math.pi
    assert np.all(added > 1e-4)
    np.testing.assert_allclose(f.radiance[16, 16] - direct.radiance[16, 16], added, rtol=1e-4)

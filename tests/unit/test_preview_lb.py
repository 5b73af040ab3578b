"""``--method lb`` relit per instance from the 18 LB bases (steele2010 sec. 3.1) in the vertex shader.

The shader reads E_scattered of every base per vertex from a texture and blends the three
bases whose hull face the sun falls in, in each instance's own frame. Checked against the
same blend done in numpy and drawn through the plain per-vertex path, which the other
preview tests already pin down.
"""

import math

import numpy as np
import pytest

from foliage_tools.geometry.sun import to_prototype_space
from foliage_tools.lighting.lb.lattice import barycentric_weights
from foliage_tools.preview.camera import direction_from_angles, orbit_camera
from foliage_tools.preview.renderer import DrawMesh, DrawPrototype, DrawScene, Lighting, Renderer
from tests.helpers.crowns import OPTICS, crown

Z = np.array([0.0, 0.0, 1.0])


def _rotated(deg: float, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    t = np.eye(4)
    a = math.radians(deg)
    t[:3, :3] = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    t[:3, 3] = shift
    return t


@pytest.fixture(scope="module")
def bases():
    corners, centres, _, _ = crown(n=120, seed=3)
    rng = np.random.default_rng(0)
    # distinct, smooth-ish fields per base and channel so a wrong index or weight shows
    k = np.arange(18)[:, None, None]
    b = (0.05 + 0.02 * k) * (1.0 + 0.3 * np.sin(corners[None, :, :] * (1 + k % 5))) * rng.uniform(0.8, 1.2, (18, 1, 3))
    return corners, b.astype(np.float32)


@pytest.mark.parametrize("deg", [0.0, 70.0])
@pytest.mark.parametrize("sun_angles", [(33.0, 41.0), (45.0, 35.26438968275466)])  # generic; along lattice direction (1,1,1)
def test_relit_lb_equals_the_numpy_blend_for_the_instance_frame(bases, deg, sun_angles):
    corners, b = bases
    t = _rotated(deg, (1.0, -0.5, 0.0))
    sun = direction_from_angles(*sun_angles, "Z")
    idx, w = barycentric_weights(-to_prototype_space(sun, t))
    expect = sum(w[j] * b[idx[j] - 1] for j in range(3)).astype(np.float32)
    relit = DrawScene((DrawPrototype((DrawMesh(corners=corners, leaf=True, lb_bases=b),), t[None]),), Z)
    plain = DrawScene((DrawPrototype((DrawMesh(corners=corners, leaf=True, indirect={"lb": expect}),), t[None]),), Z)
    cam = orbit_camera(relit.bounds(), width=80, height=80, up_axis="Z", azimuth=200, elevation=10, fovy=30.0)
    light = Lighting(sun, sky_radiance=(0.02, 0.03, 0.04))
    with Renderer(relit, sky_samples=0) as r:
        got = r.render(cam, light, OPTICS, method="lb")
        direct = r.render(cam, light, OPTICS)
    with Renderer(plain, sky_samples=0) as r:
        want = r.render(cam, light, OPTICS, method="lb")
    tree = direct.tree > 0.5
    assert tree.sum() > 200
    assert np.all(got.radiance >= direct.radiance - 1e-7)  # the term only adds light
    assert (got.radiance[tree] - direct.radiance[tree]).mean() > 1e-3  # and it is there
    np.testing.assert_allclose(got.radiance, want.radiance, rtol=1e-5, atol=1e-6)


def test_instances_are_relit_in_their_own_frames(bases):
    # two copies, one turned 120 degrees: the same world sun hits different hull faces in their frames
    corners, b = bases
    sun = direction_from_angles(10.0, 50.0, "Z")
    ts = np.stack([_rotated(0.0), _rotated(120.0, (0.0, 4.0, 0.0))])  # side by side as the camera sees them
    faces = [tuple(barycentric_weights(-to_prototype_space(sun, t))[0]) for t in ts]
    assert faces[0] != faces[1]  # the case this test is about
    scene = DrawScene((DrawPrototype((DrawMesh(corners=corners, leaf=True, lb_bases=b),), ts),), Z)
    cam = orbit_camera(scene.bounds(), width=96, height=64, up_axis="Z", azimuth=0, elevation=5, fovy=40.0)
    with Renderer(scene, sky_samples=0) as r:
        # the lb term alone (the direct light differs where one tree shadows the other)
        img = r.render(cam, Lighting(sun), OPTICS, method="lb").radiance - r.render(cam, Lighting(sun), OPTICS).radiance
    for k, t in enumerate(ts):  # each instance alone, through the plain path with its own blend
        idx, w = barycentric_weights(-to_prototype_space(sun, t))
        expect = sum(w[j] * b[idx[j] - 1] for j in range(3)).astype(np.float32)
        one = DrawScene((DrawPrototype((DrawMesh(corners=corners, leaf=True, indirect={"lb": expect}),), ts[k : k + 1]),), Z)
        with Renderer(one, sky_samples=0) as r:
            alone = r.render(cam, Lighting(sun), OPTICS, method="lb")
            term = alone.radiance - r.render(cam, Lighting(sun), OPTICS).radiance
        mask = alone.tree > 0.5
        assert mask.sum() > 100 and term[mask].mean() > 1e-3
        np.testing.assert_allclose(img[mask], term[mask], rtol=1e-4, atol=1e-5)

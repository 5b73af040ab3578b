"""``foliage preview`` on llvmpipe: geometry, shading closed forms, shadows, indirect light, images, CLI.

Shading tests use scenes whose radiance has a closed form (a single card, a
ground plane, a uniform sky); tolerances are float32 round-off unless a
comment says otherwise. Rasterisation is deterministic on one driver but
pixel edges may differ on another, so coverage checks allow a few per cent.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from foliage_tools.errors import InputError, UsageError
from foliage_tools.pipeline.baked_light import load_method_data
from foliage_tools.pipeline.preview import PreviewParams, choose_lighting, parse_size, parse_sun, run_preview
from foliage_tools.preview.camera import bounds_corners, direction_from_angles, orbit_camera
from foliage_tools.preview.compare import false_colour, relative_error
from foliage_tools.preview.optics import LeafOptics, SurfaceOptics
from foliage_tools.preview.renderer import DrawMesh, DrawPrototype, DrawScene, Ground, Lighting, Renderer
from foliage_tools.preview.tonemap import luminance, measure_exposure, reinhard, srgb_encode
from foliage_tools.scene.image import read_image, write_image
from foliage_tools.scene.read import read_scene
from tests.conftest import ASSETS, REPO, cards_mesh, sha256, write_mesh_stage
from tests.helpers.crowns import LEAF

GOLDEN = REPO / "tests" / "golden" / "preview"
Z = np.array([0.0, 0.0, 1.0])
NO_SKY = (0.0, 0.0, 0.0)
# the helpers' leaf (distinct values per face and channel) over a grey ground (the goldens were drawn with it)
OPTICS = SurfaceOptics(leaf=LEAF, ground_reflectance=(0.2, 0.2, 0.2))


# -- scenes ------------------------------------------------------------------------------


def card(side=1.0, *, normal="x", height=0.0, flip=False) -> np.ndarray:
    """(6, 3) corners of a square card centred on the up axis; right-handed normal +X or +Z."""
    h = side / 2
    if normal == "x":
        p = np.array([[0, -h, -h], [0, h, -h], [0, h, h], [0, -h, h]], float)
    else:
        p = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    p[:, 2] += height
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    if flip:
        tris = tris[:, ::-1]
    return p[tris].reshape(-1, 3).astype(np.float32)


def one_mesh_scene(corners, *, leaf=True, indirect=None, transforms=None) -> DrawScene:
    mesh = DrawMesh(corners=corners, leaf=leaf, indirect=indirect or {})
    t = np.eye(4)[None] if transforms is None else transforms
    return DrawScene((DrawPrototype((mesh,), t),), Z)


def crown_cards(n=400, radius=1.0, centre=(0.0, 0.0, 2.5), side=0.18, seed=7):
    """Cards with centres uniform in a ball and random orientations (seeded)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = np.asarray(centre) + d * radius * rng.uniform(size=(n, 1)) ** (1 / 3)
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u, v = q[:, :, 0] * side / 2, q[:, :, 1] * side / 2
    pts = np.stack([c - u - v, c + u - v, c + u + v, c - u + v], axis=1)  # (n, 4, 3)
    return pts


def trunk(height=1.7, half=0.06):
    """A closed square prism from the ground into the crown: 8 points, 6 quads (outward)."""
    h = half
    pts = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0], [-h, -h, height], [h, -h, height], [h, h, height], [-h, h, height]], float)
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    return {"points": pts, "counts": [4] * 6, "indices": [i for q in quads for i in q], "isLeaf": False}


def crown_stage(path: Path, *, n=400, seed=7, up_axis="Z") -> Path:
    pts = crown_cards(n=n, seed=seed)
    leaves = {"points": pts.reshape(-1, 3), "counts": [4] * n, "indices": list(range(4 * n)), "isLeaf": True}
    return write_mesh_stage(path, {"Leaves": leaves, "Trunk": trunk()}, up_axis=up_axis)


def add_primvar(path: Path, mesh: str, name: str, values: np.ndarray, interpolation: str) -> None:
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.Open(str(path))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(mesh)).CreatePrimvar(name, Sdf.ValueTypeNames.Color3fArray, interpolation)
    pv.Set(Vt.Vec3fArray.FromNumpy(np.asarray(values, dtype=np.float32)))
    stage.GetRootLayer().Save()


def side_camera(bounds, size=64, **kw):
    args = {"width": size, "height": size, "up_axis": "Z", "azimuth": 0.0, "elevation": 0.0, "fovy": 30.0}
    args.update(kw)
    return orbit_camera(np.asarray(bounds, float), **args)


# -- geometry ----------------------------------------------------------------------------


def test_a_card_facing_the_camera_covers_its_predicted_pixel_count():
    side, distance, fovy, size = 1.3, 5.0, 30.0, 96
    scene = one_mesh_scene(card(side))
    with Renderer(scene) as r:
        cam = side_camera(scene.bounds(), size=size, distance=distance, fovy=fovy)
        f = r.render(cam, Lighting(direction_from_angles(0, 30, "Z")), OPTICS)
    # pinhole: a length s at distance d spans s / (2 d tan(fovy/2)) of the image height
    predicted = (side / (2 * distance * math.tan(math.radians(fovy / 2))) * size) ** 2
    # 4x MSAA resolves coverage to quarter pixels along the 4 edges: well under 2 %
    assert f.tree.sum() == pytest.approx(predicted, rel=0.02)
    assert np.array_equal(f.tree > 0, f.alpha > 0), "no ground here: the tree is all the geometry"


def test_tree_pixels_lie_inside_its_projected_bounds(tmp_path):
    scene, _ = read_scene(crown_stage(tmp_path / "crown.usda"))
    draw = DrawScene.from_scene(scene)
    bounds = draw.bounds()
    cam = side_camera(bounds, size=96, azimuth=30, elevation=20)
    with Renderer(draw) as r:
        f = r.render(cam, Lighting(direction_from_angles(45, 60, "Z")), ground=Ground.under(bounds, Z))
    px, _ = cam.project(bounds_corners(bounds))
    (x0, y0), (x1, y1) = np.floor(px.min(axis=0)), np.ceil(px.max(axis=0))
    rows, cols = np.nonzero(f.tree > 0)
    assert len(rows) > 0.05 * 96 * 96
    assert cols.min() >= x0 and cols.max() <= x1 and rows.min() >= y0 and rows.max() <= y1
    # a ball in its box, seen obliquely: the covered extent is most of the projected box's
    assert np.ptp(cols) > 0.6 * (x1 - x0) and np.ptp(rows) > 0.6 * (y1 - y0)


def test_instances_are_drawn_where_their_matrices_put_them():
    # two instances of one card, the second mirrored and moved: both visible, the mirror flips the seen face
    t = np.stack([np.eye(4), np.diag([1.0, -1.0, 1.0, 1.0])])
    t[1, 1, 3] = 2.0
    scene = one_mesh_scene(card(1.0), transforms=t)
    with Renderer(scene) as r:
        cam = side_camera(scene.bounds(), size=64, fovy=40)
        f = r.render(cam, Lighting(direction_from_angles(0, 30, "Z"), sky_radiance=NO_SKY), OPTICS)
    (left, right), _ = cam.project(np.array([[0, 0, 0], [0, 2.0, 0]]))
    a = f.radiance[int(left[1]), int(left[0])]
    b = f.radiance[int(right[1]), int(right[0])]
    cos30 = math.cos(math.radians(30))
    np.testing.assert_allclose(a, np.array(OPTICS.leaf.reflectance_front) / math.pi * cos30, rtol=1e-5)
    # mirrored in Y: the geometric front still faces +X, so the front reflectance is seen again
    np.testing.assert_allclose(b, np.array(OPTICS.leaf.reflectance_front) / math.pi * cos30, rtol=1e-5)


# -- shading closed forms -----------------------------------------------------------------


@pytest.mark.parametrize(
    "flip, sun_az, face",
    [
        (False, 0, "reflectance_front"),  # front faces camera and sun: boulanger eq. 5.4, rho_rf
        (False, 180, "transmittance_back"),  # sun behind: light enters the back face, rho_tb
        (True, 0, "reflectance_back"),  # back faces camera and sun: rho_rb
        (True, 180, "transmittance_front"),  # seen from the back, light entering the front: rho_tf
    ],
)
def test_leaf_radiance_matches_the_two_sided_lambertian_closed_form(flip, sun_az, face):
    scene = one_mesh_scene(card(1.0, flip=flip))
    with Renderer(scene) as r:
        cam = side_camera(scene.bounds(), size=32, distance=4.0)
        f = r.render(cam, Lighting(direction_from_angles(sun_az, 30, "Z"), sky_radiance=NO_SKY), OPTICS)
    expected = np.array(getattr(OPTICS.leaf, face)) / math.pi * math.cos(math.radians(30))
    np.testing.assert_allclose(f.radiance[16, 16], expected, rtol=1e-5)


def test_a_leaf_seen_against_the_sun_is_lit_by_transmission_and_black_without_it():
    scene = one_mesh_scene(card(1.0))
    opaque = SurfaceOptics(leaf=LeafOptics.lambertian((0.1, 0.1, 0.1), (0.0, 0.0, 0.0)))
    sun_behind = Lighting(direction_from_angles(180, 20, "Z"), sky_radiance=NO_SKY)
    with Renderer(scene) as r:
        cam = side_camera(scene.bounds(), size=32, distance=4.0)
        lit = r.render(cam, sun_behind, OPTICS)
        dark = r.render(cam, sun_behind, opaque)
    inside = lit.tree > 0.99
    assert luminance(lit.radiance)[inside].min() > 0.02
    assert np.all(dark.radiance[inside] == 0.0)


def test_uniform_sky_lights_both_faces_of_a_vertical_leaf():
    # a vertical card sees half the sky on each face: E = pi L / 2 per face, so
    # L_out = (rho_r + rho_t) / pi * pi L / 2 = (rho_r + rho_t) L / 2
    sky = (0.3, 0.5, 0.7)
    scene = one_mesh_scene(card(1.0))
    with Renderer(scene) as r:
        cam = side_camera(scene.bounds(), size=32, distance=4.0)
        f = r.render(cam, Lighting(direction_from_angles(0, 30, "Z"), sun_irradiance=(0, 0, 0), sky_radiance=sky), OPTICS)
    leaf = OPTICS.leaf
    expected = (np.array(leaf.reflectance_front) + np.array(leaf.transmittance_back)) / 2 * np.array(sky)
    np.testing.assert_allclose(f.radiance[16, 16], expected, rtol=1e-5)


def test_glossy_lobe_only_adds_light_and_peaks_at_the_mirror_direction():
    glossy = SurfaceOptics(leaf=LeafOptics(specular=0.05, roughness=0.3))
    matte = SurfaceOptics(leaf=LeafOptics(specular=0.0))
    scene = one_mesh_scene(card(1.0))
    with Renderer(scene) as r:
        cam = side_camera(scene.bounds(), size=32, distance=4.0, fovy=10)
        mirror = Lighting(direction_from_angles(0, 0, "Z"), sky_radiance=NO_SKY)  # sun behind the camera: H = N
        off = Lighting(direction_from_angles(60, 0, "Z"), sky_radiance=NO_SKY)
        g_m, m_m = r.render(cam, mirror, glossy), r.render(cam, mirror, matte)
        g_o, m_o = r.render(cam, off, glossy), r.render(cam, off, matte)
    peak = luminance(g_m.radiance)[16, 16] - luminance(m_m.radiance)[16, 16]
    side = luminance(g_o.radiance)[16, 16] - luminance(m_o.radiance)[16, 16]
    # wang2005 eq. (7) at alpha = 0: rho_s / (4 pi m^2 cos_r); cos_r ~ 1 on the axis
    assert peak == pytest.approx(0.05 / (4 * math.pi * 0.09), rel=0.01)
    assert 0 <= side < 0.1 * peak


# -- shadows -----------------------------------------------------------------------------


@pytest.mark.parametrize("elevation", [60.0, 25.0, 8.0])
def test_shadows_darken_the_ground_and_lit_surfaces_show_no_acne(elevation):
    # a horizontal 1x1 leaf at height 1 over a ground plane, sun at azimuth 0
    scene = one_mesh_scene(card(1.0, normal="z", height=1.0))
    ground = Ground(point=np.zeros(3), radius=8.0)
    lighting = Lighting(direction_from_angles(0, elevation, "Z"), sky_radiance=NO_SKY)
    t = math.tan(math.radians(elevation))
    shadow_centre = np.array([-1.0 / t, 0.0, 0.0])  # the card's centre projected along the sun
    box = np.array([[-1.0 / t - 1, -2, 0], [1, 2, 1]])
    with Renderer(scene, samples=1) as r:
        cam = orbit_camera(box, width=128, height=128, up_axis="Z", azimuth=-90, elevation=50, fovy=45)
        f = r.render(cam, lighting, OPTICS, ground=ground)
    rho_g = 0.2
    lit_expected = rho_g / math.pi * math.sin(math.radians(elevation))
    lum = luminance(f.radiance)
    ground_px = (f.alpha > 0.999) & (f.tree < 1e-3)
    px, _ = cam.project(shadow_centre[None])
    sx, sy = int(px[0, 0]), int(px[0, 1])
    assert ground_px[sy, sx], "the shadow centre must be visible ground in this view"
    # closed forms: lit ground rho_g/pi E sin(el); in the umbra only the (zero) sky: 0
    lit = lum[ground_px & (np.abs(np.arange(128)[None, :] - sx) > 40)]
    assert np.median(lit) == pytest.approx(lit_expected, rel=1e-4)
    assert lum[sy - 1 : sy + 2, sx - 1 : sx + 2].max() < 0.02 * lit_expected
    # the card's top face is fully lit (normal-offset bias: no self-shadowing, even at 8 degrees)
    top = f.radiance[f.tree > 0.999]
    rho_top = np.array(OPTICS.leaf.reflectance_front) / math.pi * math.sin(math.radians(elevation))
    # plus the ground bounce transmitted through the card: rho_tb/pi * pi L_g, L_g = rho_g E sin(el) / pi
    rho_top = rho_top + np.array(OPTICS.leaf.transmittance_back) / math.pi * rho_g * math.sin(math.radians(elevation))
    np.testing.assert_allclose(top.min(axis=0), rho_top, rtol=1e-4)


def test_the_tree_shadows_the_ground_under_it(tmp_path):
    scene, _ = read_scene(crown_stage(tmp_path / "crown.usda"))
    draw = DrawScene.from_scene(scene)
    bounds = draw.bounds()
    ground = Ground.under(bounds, Z)
    el = 50.0
    lighting = Lighting(direction_from_angles(0, el, "Z"), sky_radiance=(0.02, 0.02, 0.02))
    crown_centre = np.array([0.0, 0.0, 2.5])
    shadow_centre = crown_centre - direction_from_angles(0, el, "Z") * (2.5 / math.sin(math.radians(el)))
    cam = orbit_camera(np.array([[-3.5, -2, 0], [2, 2, 3.5]]), width=128, height=128, up_axis="Z", azimuth=-90, elevation=55)
    with Renderer(draw) as r:
        f = r.render(cam, lighting, ground=ground)
    lum = luminance(f.radiance)
    ground_px = (f.alpha > 0.999) & (f.tree < 1e-3)
    px, _ = cam.project(shadow_centre[None])
    sx, sy = px[0]
    yy, xx = np.mgrid[:128, :128]
    near = ground_px & (np.hypot(xx - sx, yy - sy) < 6)
    far = ground_px & (np.hypot(xx - sx, yy - sy) > 45)
    assert near.sum() > 20 and far.sum() > 200
    assert lum[near].mean() < 0.5 * np.median(lum[far])


def test_the_sunlit_side_of_the_crown_is_brighter(tmp_path):
    scene, _ = read_scene(crown_stage(tmp_path / "crown.usda"))
    draw = DrawScene.from_scene(scene)
    cam = side_camera(draw.bounds(), size=96, azimuth=90, elevation=0)  # look along -Y: the sun (+X) is to one side
    with Renderer(draw) as r:
        f = r.render(cam, Lighting(direction_from_angles(0, 15, "Z"), sky_radiance=(0.01, 0.01, 0.01)))
    (sunny, shady), _ = cam.project(np.array([[1.0, 0, 2.5], [-1.0, 0, 2.5]]))
    cols = np.arange(96)[None, :].repeat(96, axis=0)
    mid = (sunny[0] + shady[0]) / 2
    tree = f.tree > 0.99
    lum = luminance(f.radiance)
    sunny_side = tree & ((cols - mid) * np.sign(sunny[0] - mid) > 0)
    shady_side = tree & ((cols - mid) * np.sign(shady[0] - mid) > 0)
    assert lum[sunny_side].mean() > 2.0 * lum[shady_side].mean()


def test_sky_occlusion_darkens_the_crown_inside_and_the_ground_below(tmp_path):
    # sun off, uniform sky: without occlusion every horizontal ground point receives pi L;
    # with it, the ground under the crown sees less sky, far ground sees all of it
    scene, _ = read_scene(crown_stage(tmp_path / "crown.usda"))
    draw = DrawScene.from_scene(scene)
    bounds = draw.bounds()
    sky_only = Lighting(direction_from_angles(0, 60, "Z"), sun_irradiance=(0, 0, 0), sky_radiance=(1.0, 1.0, 1.0))
    cam = orbit_camera(np.array([[-3, -3, 0], [3, 3, 3.5]]), width=96, height=96, up_axis="Z", azimuth=-90, elevation=60)
    ground = Ground.under(bounds, Z)
    frames = {}
    for k in (0, 16):
        with Renderer(draw, sky_samples=k) as r:
            frames[k] = r.render(cam, sky_only, OPTICS, ground=ground)
    lum = {k: luminance(f.radiance) for k, f in frames.items()}
    ground_px = (frames[0].alpha > 0.999) & (frames[0].tree < 1e-3)
    unoccluded = 0.2 * 1.0  # rho_g / pi * pi L
    np.testing.assert_allclose(lum[0][ground_px], unoccluded, rtol=1e-5)
    assert np.all(lum[16][ground_px] <= unoccluded * (1 + 1e-5)), "occlusion only removes light"
    px, _ = cam.project(np.array([[0.2, 0.2, 0.0], [2.9, -2.9, 0.0]]))
    (ux, uy), (fx, fy) = px.astype(int)
    assert lum[16][uy - 1 : uy + 2, ux - 1 : ux + 2].mean() < 0.8 * unoccluded  # next to the trunk, under the crown
    assert lum[16][fy, fx] > 0.9 * unoccluded  # far from the tree most of the sky is open
    tree = frames[0].tree > 0.99
    assert lum[16][tree].mean() < 0.85 * lum[0][tree].mean()


# -- indirect light from baked primvars -----------------------------------------------------


def test_indirect_term_raises_the_crown_and_never_lowers_a_pixel(tmp_path):
    path = crown_stage(tmp_path / "crown.usda")
    scene, _ = read_scene(path)
    leaves = next(m for m in scene.prototypes[0].meshes if m.is_leaf)
    rng = np.random.default_rng(3)
    add_primvar(path, leaves.path, "foliage:lbIndirect", rng.uniform(0.0, 0.3, size=(len(leaves.points), 3)), "vertex")
    data = load_method_data(path, scene, ("direct", "lb"), [])
    draw = DrawScene.from_scene(scene, data)
    cam = side_camera(draw.bounds(), size=96, azimuth=200, elevation=10)
    lighting = Lighting(direction_from_angles(45, 60, "Z"), sky_radiance=(0.02, 0.03, 0.04))
    with Renderer(draw) as r:
        direct = r.render(cam, lighting, ground=Ground.under(draw.bounds(), Z))
        lb = r.render(cam, lighting, method="lb", ground=Ground.under(draw.bounds(), Z))
    tree = direct.tree > 0.5
    assert luminance(lb.radiance)[tree].mean() > 1.2 * luminance(direct.radiance)[tree].mean()
    assert np.all(lb.radiance >= direct.radiance), "a non-negative term cannot darken any pixel"
    off_tree = direct.tree == 0
    np.testing.assert_array_equal(lb.radiance[off_tree], direct.radiance[off_tree])


def test_per_face_reference_scattered_light_adds_its_closed_form(tmp_path):
    # one card, no sun, no sky: the only light is E_scattered, split evenly over the faces:
    # L = (rho_r + rho_t) / (2 pi) * E
    mesh = {**cards_mesh([(0.0, 0.0, 0.0)], size=1.0, normal_axis=0), "isLeaf": True}
    path = write_mesh_stage(tmp_path / "card.usda", {"Leaf": mesh})
    e = np.array([[0.6, 0.9, 1.2]])
    add_primvar(path, "/Tree/Leaf", "foliage:ref:scattered", e, "uniform")
    scene, _ = read_scene(path)
    draw = DrawScene.from_scene(scene, load_method_data(path, scene, ("reference",), []))
    with Renderer(draw) as r:
        cam = side_camera(draw.bounds(), size=32, distance=4.0)
        f = r.render(cam, Lighting(direction_from_angles(0, 30, "Z"), sun_irradiance=(0, 0, 0), sky_radiance=NO_SKY), OPTICS,
                     method="reference")
    # cards_mesh winds the quad so its right-handed normal is +X, toward the camera
    leaf = OPTICS.leaf
    expected = (np.array(leaf.reflectance_front) + np.array(leaf.transmittance_back)) / (2 * math.pi) * e[0]
    np.testing.assert_allclose(f.radiance[16, 16], expected, rtol=1e-5)


def test_smax_method_evaluates_the_baked_envelope_like_the_bake(tmp_path):
    # `foliage smax` stores s_max, tau and its own per-leaf E_direct / E_scattered for its sun;
    # the previewer's vertex shader, given the same s_max, tau, sun and leaf optics, must
    # reproduce those per-leaf values (float32 GPU vs float64 bake) -- and follows any other sun
    from pxr import Usd, UsdGeom

    from foliage_tools.lighting.optics import parse_leaf_optics
    from foliage_tools.pipeline.direct import DirectChoice
    from foliage_tools.pipeline.baked_light import load_smax_data
    from foliage_tools.pipeline.smax import SmaxParams, run_smax

    src = crown_stage(tmp_path / "crown.usda", n=200)
    baked = tmp_path / "baked.usda"
    bake_optics = parse_leaf_optics(None)
    # --direct volume and --scatter paper: the bake's own eq. 5.7 direct term and the thesis' eq. 5.24, which the
    # shader evaluates for any sun (the default --scatter leaves needs the shadow rays of the bake's sun)
    run_smax(src, baked, SmaxParams(optics=bake_optics, sun=(45.0, 60.0), direct=DirectChoice(mode="volume"),
                                    scatter="paper"))
    scene, _ = read_scene(baked)
    draw = DrawScene.from_scene(scene, None, load_smax_data(baked, scene))
    assert draw.methods == {"smax"}
    r_, t_ = tuple(bake_optics.reflectance), tuple(bake_optics.transmittance)
    optics = SurfaceOptics(leaf=LeafOptics(reflectance_front=r_, reflectance_back=r_, transmittance_front=t_, transmittance_back=t_))
    with Renderer(draw, sky_samples=0) as r:
        (terms,) = r.smax_irradiance(Lighting(direction_from_angles(45.0, 60.0, "Z")), optics)
        (other,) = r.smax_irradiance(Lighting(direction_from_angles(200.0, 30.0, "Z")), optics)
    leaves = next(m for m in scene.prototypes[0].meshes if m.is_leaf)
    stage = Usd.Stage.Open(str(baked))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(leaves.path))
    want_scattered = np.asarray(pv.GetPrimvar("foliage:smax:scattered").Get())[leaves.face_of_triangle]
    want_direct = np.asarray(pv.GetPrimvar("foliage:smax:direct").Get())[leaves.face_of_triangle][:, 0]
    got_scattered = (terms["scattered_front"] + terms["scattered_back"])[::3]  # first corner of each triangle
    got_direct = (terms["direct_front"] + terms["direct_back"])[::3]
    assert want_scattered.max() > 0 and want_direct.max() > 0
    np.testing.assert_allclose(got_scattered, want_scattered, rtol=1e-3, atol=1e-5 * want_scattered.max())
    np.testing.assert_allclose(got_direct, want_direct, rtol=1e-3, atol=1e-5)
    assert np.abs((other["scattered_front"] + other["scattered_back"])[::3] - got_scattered).max() > 0.05 * want_scattered.max()
    # and the command renders it
    report = run_preview(baked, tmp_path / "smax.png", PreviewParams(method="smax", size=(48, 48), samples=1, sky_samples=0))
    assert (tmp_path / "smax.png").exists() and report.stats["per_method"]["smax"]["mean_tree_luminance"] > 0


@pytest.mark.parametrize("method, command", [("lb", "foliage lb"), ("spp", "foliage spp"), ("smax", "foliage smax"), ("reference", "foliage reference")])
def test_missing_bake_data_names_the_command_that_makes_it(tmp_path, method, command):
    path = crown_stage(tmp_path / "crown.usda", n=20)
    with pytest.raises(InputError) as exc:
        run_preview(path, tmp_path / "out.png", PreviewParams(method=method, size=(32, 32)))
    assert f"`{command} " in str(exc.value) and "crown.usda" in str(exc.value)
    assert not (tmp_path / "out.png").exists()


def test_wrong_primvar_length_is_an_input_error_naming_the_mesh(tmp_path):
    path = crown_stage(tmp_path / "crown.usda", n=20)
    add_primvar(path, "/Tree/Leaves", "foliage:lbIndirect", np.zeros((7, 3)), "vertex")
    scene, _ = read_scene(path)
    with pytest.raises(InputError, match=r"</Tree/Leaves> primvars:foliage:lbIndirect: 7 values"):
        load_method_data(path, scene, ("lb",), [])


# -- golden image --------------------------------------------------------------------------


def _blocks(lum: np.ndarray, n: int = 8) -> np.ndarray:
    h, w = lum.shape
    return lum.reshape(n, h // n, n, w // n).mean(axis=(1, 3))


def test_render_matches_the_stored_reference_statistically(tmp_path):
    """A 128² render of a seeded crown against ``tests/golden/preview/crown_direct.exr`` (RGB radiance, A = tree mask).

    Regenerate after an intended change with ``FOLIAGE_UPDATE_GOLDEN=1 pytest -k stored_reference``
    and look at the image. Three statistics, tolerant to rasterisation-rule
    differences at leaf edges (even dropping antialiasing, 1 instead of 4
    samples, moves them by only 0.6 %, 0.2 % and 0.1 %) but not to shading
    changes (measured: +5 % leaf reflectance moves the tree mean by 2.8 %, +5 %
    transmittance by 1.3 %, +5 % ground albedo the block means by 4.8 %,
    dropping the glossy lobe the tree mean by 8 %):

    * relative RMS of 16×16-pixel block means of luminance < 2 %,
    * mean luminance of the fully covered tree pixels within 1 %,
    * tree coverage within 2 %.
    """
    path = crown_stage(tmp_path / "crown.usda")
    scene, warnings = read_scene(path)
    draw = DrawScene.from_scene(scene)
    bounds = draw.bounds()
    light = choose_lighting(scene, None, warnings)
    cam = orbit_camera(bounds, width=128, height=128, up_axis="Z", azimuth=20, elevation=15,
                       clip_bounds=Ground.under(bounds, Z).bounds(Z))
    with Renderer(draw) as r:
        f = r.render(cam, light.lighting, SurfaceOptics(), ground=Ground.under(bounds, Z))
    actual = np.concatenate([f.radiance, f.tree[..., None]], axis=2)
    golden = GOLDEN / "crown_direct.exr"
    if os.environ.get("FOLIAGE_UPDATE_GOLDEN"):
        write_image(golden, actual)
        pytest.skip(f"wrote {golden}")
    ref = read_image(golden)
    lum_a, lum_r = luminance(actual[..., :3]), luminance(ref[..., :3])
    ba, br = _blocks(lum_a), _blocks(lum_r)
    block_err = float(np.sqrt(np.sum((ba - br) ** 2) / np.sum(br**2)))
    # fully covered tree pixels only: edge pixels mix in the ground and depend on antialiasing
    tree_a = float(lum_a[actual[..., 3] > 0.999].mean())
    tree_r = float(lum_r[ref[..., 3] > 0.999].mean())
    tree_err = abs(tree_a / tree_r - 1)
    cov_err = float(abs(actual[..., 3].sum() - ref[..., 3].sum()) / ref[..., 3].sum())
    if block_err > 0.02 or tree_err > 0.01 or cov_err > 0.02:
        e = measure_exposure(ref[..., :3], ref[..., 3], white_rgb=ref[..., :3])
        write_image(tmp_path / "actual.png", srgb_encode(reinhard(actual[..., :3], e)))
        write_image(tmp_path / "golden.png", srgb_encode(reinhard(ref[..., :3], e)))
        write_image(tmp_path / "diff.png", srgb_encode(false_colour(relative_error(actual[..., :3], ref[..., :3], np.ones((128, 128))))))
        pytest.fail(f"render differs from {golden}: block rel. RMS {block_err:.4f} (limit 0.02), tree mean luminance "
                    f"{tree_err:.4f} (limit 0.01), coverage {cov_err:.4f} (limit 0.02); images in {tmp_path} "
                    "(actual.png, golden.png, diff.png: blue darker, red brighter than the golden image)")


# -- the command and its files --------------------------------------------------------------


def cli(*args):
    from foliage_tools.cli.preview import preview

    return CliRunner().invoke(preview, [str(a) for a in args], catch_exceptions=False)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--size", "256"], "--size must be WIDTHxHEIGHT"),
        (["--size", "0x10"], "--size must be between"),
        (["--sun", "45"], "--sun must be AZIMUTH,ELEVATION"),
        (["--sun", "10,95"], "elevation must be between -90 and 90"),
        (["--sun", "a,b"], "--sun must be AZIMUTH,ELEVATION"),
        (["--frames", "3"], "--frames needs --orbit"),
        (["--compare", "direct,foo"], "unknown method(s) foo"),
        (["--camera", "/Cam", "--azimuth", "10"], "--camera cannot be combined with --azimuth"),
        (["--lod", "0"], "--lod must be a fraction in (0, 1]"),
        (["--lod", "2"], "--lod must be a fraction in (0, 1]"),
    ],
)
def test_bad_options_exit_2_with_a_message(tmp_path, args, message):
    path = crown_stage(tmp_path / "crown.usda", n=10)
    r = cli(path, "-o", tmp_path / "out.png", *args)
    assert r.exit_code == 2, r.output
    assert message in r.output
    assert not (tmp_path / "out.png").exists()


def test_missing_method_via_cli_exits_2_naming_the_command(tmp_path):
    path = crown_stage(tmp_path / "crown.usda", n=10)
    r = cli(path, "-o", tmp_path / "out.png", "--method", "spp")
    assert r.exit_code == 2 and "foliage spp" in r.output


def test_bad_output_paths_exit_2_and_write_nothing(tmp_path):
    path = crown_stage(tmp_path / "crown.usda", n=10)
    r = cli(path, "-o", tmp_path / "out.jpg", "--size", "16x16")
    assert r.exit_code == 2 and ".png" in r.output
    # a missing folder is made before the work, and removed again when the run fails
    r = cli(path, "-o", tmp_path / "nodir" / "out.jpg", "--size", "16x16")
    assert r.exit_code == 2 and ".png" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crown.usda"]


def test_png_exposure_leaves_ground_and_sky_in_the_midtones(tmp_path):
    # the exposure is metered from the sun and sky, not keyed on the (dark) crown: the ground in
    # front of the tree and the sky above it stay mid-tones instead of burning out to near white
    # (keying on the tree gave them 0.84 and 0.86 in sRGB), and the crown is darker than the ground
    path = crown_stage(tmp_path / "crown.usda")
    report = run_preview(path, tmp_path / "a.png", PreviewParams(size=(128, 128), samples=1))
    img = read_image(tmp_path / "a.png")
    ground, sky, crown = img[-12:].mean(), img[:8].mean(), img[40:90, 54:74].mean()
    assert report.stats["exposure"]["mode"] == "photographic"
    assert 0.25 < ground < 0.6 and 0.25 < sky < 0.6, (ground, sky)
    assert 0.1 < crown < ground


def test_lod_via_cli_draws_fewer_triangles_and_help_teaches_it(tmp_path):
    import json

    help_text = cli("--help").output
    assert "--lod FRACTION" in help_text and "leaf area" in " ".join(help_text.split())
    path = REPO / "examples" / "forest_small.usda"  # 16 instances of examples/tree_small.usda
    out = {}
    for args in ((), ("--lod", "0.25")):
        r = cli(path, "-o", tmp_path / f"f{len(args)}.exr", "--size", "48x48", "--samples", "1", "--sky-samples", "0", "--json", *args)
        assert r.exit_code == 0, r.output
        out[len(args)] = json.loads(r.output)["stats"]
    assert out[2]["lod"] == {"fraction": 0.25, "triangles_full_detail": out[0]["triangles"]}
    assert out[2]["triangles"] < out[0]["triangles"]


def test_png_and_exr_outputs(tmp_path):
    path = crown_stage(tmp_path / "crown.usda", n=100)
    before = sha256(path)
    r = cli(path, "-o", tmp_path / "tree.png", "--size", "80x60", "--sun", "120,30", "--json")
    assert r.exit_code == 0, r.output
    png = read_image(tmp_path / "tree.png")
    assert png.shape == (60, 80, 3) and 0.0 <= png.min() and png.max() <= 1.0
    r = cli(path, "-o", tmp_path / "tree.exr", "--size", "80x60", "--no-ground", "-q")
    assert r.exit_code == 0, r.output
    exr = read_image(tmp_path / "tree.exr")
    assert exr.shape == (60, 80, 4)
    alpha = exr[..., 3]
    assert 0.02 < alpha.mean() < 0.9 and alpha.min() == 0.0, "no ground: sky pixels are transparent"
    assert np.all(exr[..., :3][alpha == 0] == 0), "premultiplied: nothing where there is no geometry"
    assert sha256(path) == before, "the input must never change"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crown.usda", "tree.exr", "tree.png"], "no temporary files left"


def test_json_report(tmp_path):
    import json

    path = crown_stage(tmp_path / "crown.usda", n=50)
    r = cli(path, "-o", tmp_path / "t.png", "--size", "32x32", "--sun", "90,45", "--json")
    rep = json.loads(r.output)
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.validate(rep, json.loads((REPO / "schemas" / "json" / "report.schema.json").read_text()))
    assert rep["command"] == "preview" and rep["outputs"] == [str(tmp_path / "t.png")]
    from tests.helpers.typed_json import assert_typed_stats

    assert_typed_stats(rep)
    s = rep["stats"]
    assert s["sun"]["source"] == "--sun" and s["sun"]["azimuth"] == 90 and s["sun"]["elevation"] == 45
    np.testing.assert_allclose(s["sun"]["direction"], direction_from_angles(90, 45, "Z"), atol=1e-12)
    assert s["triangles"] == 50 * 2 + 12 and s["instances"] == 1 and s["size"] == [32, 32]


def test_sequences_write_numbered_frames_all_or_nothing(tmp_path):
    path = crown_stage(tmp_path / "crown.usda", n=60)
    r = cli(path, "-o", tmp_path / "turn.png", "--size", "40x40", "--orbit", "--frames", "3", "-q")
    assert r.exit_code == 0, r.output
    frames = [read_image(tmp_path / f"turn.{i:04d}.png") for i in (1, 2, 3)]
    assert not (tmp_path / "turn.png").exists()
    assert np.abs(frames[0] - frames[1]).mean() > 0.01, "the camera moved"
    r = cli(path, "-o", tmp_path / "sweep.exr", "--size", "40x40", "--sun-sweep", "--frames", "2", "-q")
    assert r.exit_code == 0, r.output
    a, b = (read_image(tmp_path / f"sweep.{i:04d}.exr") for i in (1, 2))
    np.testing.assert_array_equal(a[..., 3], b[..., 3])  # same camera
    assert np.abs(a - b).max() > 0.001  # the sun moved half a turn


def test_comparison_with_error_row(tmp_path):
    path = crown_stage(tmp_path / "crown.usda", n=80)
    scene, _ = read_scene(path)
    leaves = next(m for m in scene.prototypes[0].meshes if m.is_leaf)
    add_primvar(path, leaves.path, "foliage:lbIndirect", np.full((len(leaves.points), 3), 0.1), "vertex")
    add_primvar(path, leaves.path, "foliage:ref:scattered", np.full((leaves.face_count, 3), 0.12), "uniform")
    r = cli(path, "-o", tmp_path / "cmp.png", "--size", "64x64", "--compare", "direct,lb", "--error-image", "--json")
    assert r.exit_code == 0, r.output
    import json

    from foliage_tools.preview.compare import SEPARATOR, header_height

    stats = json.loads(r.output)["stats"]
    assert stats["methods"] == ["direct", "lb", "reference"]
    per = stats["per_method"]
    # lb (0.1) is closer to the reference (0.12) than direct (0)
    assert per["lb"]["rel_rms_vs_reference"] < per["direct"]["rel_rms_vs_reference"]
    img = read_image(tmp_path / "cmp.png")
    hh = header_height(64)
    assert img.shape == (2 * (64 + hh) + SEPARATOR, 3 * 64 + 2 * SEPARATOR, 3)


def test_usd_camera_sees_what_it_points_at(tmp_path):
    from pxr import Gf, Usd, UsdGeom

    mesh = {**cards_mesh([(0.0, 0.0, 1.0)], size=0.5, normal_axis=1), "isLeaf": True}
    path = write_mesh_stage(tmp_path / "cam.usda", {"Leaf": mesh})
    stage = Usd.Stage.Open(str(path))
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    # from (0, -10, 1) looking along +Y at the card: rotate the camera's -Z onto +Y
    cam.AddTranslateOp().Set(Gf.Vec3d(0, -10, 1))
    cam.AddRotateXOp().Set(90.0)
    cam.CreateFocalLengthAttr(50.0)
    cam.CreateHorizontalApertureAttr(20.0)
    cam.CreateVerticalApertureAttr(20.0)
    stage.GetRootLayer().Save()
    report = run_preview(path, tmp_path / "c.exr", PreviewParams(camera="/Cam", size=(64, 64), ground=False))
    img = read_image(tmp_path / "c.exr")
    ys, xs = np.nonzero(img[..., 3] > 0.5)
    # pinhole: the card (0.5 wide at distance 10, window 10 * 20/50 = 4 wide) spans 64 * 0.5/4 = 8 px, centred
    assert xs.mean() == pytest.approx(31.5, abs=0.6) and ys.mean() == pytest.approx(31.5, abs=0.6)
    assert (img[..., 3] > 0.5).sum() == pytest.approx(64, rel=0.15)
    assert report.stats["camera"]["source"] == "/Cam"
    with pytest.raises(InputError, match=r"cameras in the stage: </Cam>"):
        run_preview(path, tmp_path / "d.png", PreviewParams(camera="/Nope", size=(16, 16)))


# -- real assets -----------------------------------------------------------------------------

ASSET_FILES = {
    "oak": ASSETS / "webots_oak" / "oak.usda",
    "blender_tree": ASSETS / "sapling_blendertree" / "blender_tree.usda",
    "big_sassafras": ASSETS / "webots_bigsassafras" / "big_sassafras.usda",
}


@pytest.mark.parametrize("name", sorted(ASSET_FILES))
def test_third_party_trees_render_upright(tmp_path, name):
    path = ASSET_FILES[name]
    if not path.exists():
        pytest.skip(f"third-party assets not present at {ASSETS}")
    report = run_preview(path, tmp_path / f"{name}.png", PreviewParams(size=(256, 256)))
    assert read_image(tmp_path / f"{name}.png").shape == (256, 256, 3)
    assert report.stats["per_method"]["direct"]["tree_coverage"] > 0.03
    scene, _ = read_scene(path)
    draw = DrawScene.from_scene(scene)
    with Renderer(draw, samples=1) as r:
        cam = orbit_camera(draw.bounds(), width=128, height=128, up_axis=scene.up_axis, azimuth=0, elevation=0)
        f = r.render(cam, choose_lighting(scene, None, []).lighting)
    rows, cols = np.nonzero(f.tree > 0.5)
    # all three trees are taller than wide: lying on its side would mean the up axis was ignored
    assert np.ptp(rows) > 1.2 * np.ptp(cols)
    # the trunk (bottom rows) is narrower than the crown
    bottom = cols[rows > rows.max() - 5]
    assert np.ptp(bottom) < 0.5 * np.ptp(cols)


def test_forest_instances_are_all_drawn(tmp_path):
    forest = REPO / "examples" / "forest_small.usda"
    if not forest.exists():
        pytest.skip("examples/forest_small.usda not generated yet")
    report = run_preview(forest, tmp_path / "forest.png", PreviewParams(size=(128, 128), elevation=60))
    scene, _ = read_scene(forest)
    per_instance = {i.prototype: sum(len(m.triangles) for m in scene.prototypes[i.prototype].meshes) for i in scene.instances}
    assert report.stats["instances"] == len(scene.instances) == 16
    assert report.stats["triangles"] == sum(per_instance[i.prototype] for i in scene.instances)
    assert report.stats["sun"]["source"] == "</Lights/Sun>"
    assert report.stats["sky"]["source"] == "</Lights/Sky>"


def test_parsers():
    assert parse_size("640x480") == (640, 480) and parse_size(" 8 X 9 ") == (8, 9)
    assert parse_sun("-30,12.5") == (330.0, 12.5)
    with pytest.raises(UsageError):
        parse_size("640x")
    with pytest.raises(UsageError):
        parse_sun("1,2,3")

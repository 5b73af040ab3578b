"""The example generators (examples/make_tree.py, examples/make_forest.py) and the scenes committed beside them."""

from __future__ import annotations

import importlib.util
import itertools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdLux, UsdShade

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _load(name: str):
    """Import a sibling script of examples/ by path (examples/ is not a package)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is created
    spec.loader.exec_module(module)
    return module


mt = _load("make_tree")
mf = _load("make_forest")

H, R = 4.0, 1.2  # tree height and crown radius used throughout


def _tree(crown="ellipsoid", leaves=2000, leaf_size=0.1, seed=3):
    return mt.build_tree(leaves=leaves, leaf_size=leaf_size, crown=crown, height=H, crown_radius=R, seed=seed)


def _cards(g) -> np.ndarray:
    return g.leaf_points.reshape(-1, 4, 3)


def _card_normals(cards: np.ndarray) -> np.ndarray:
    n = np.cross(cards[:, 1] - cards[:, 0], cards[:, 2] - cards[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# -- leaf cards ---------------------------------------------------------------


@pytest.mark.parametrize("crown", ["ellipsoid", "cone", "lobes"])
def test_every_leaf_is_a_square_card_of_its_own_with_the_requested_size(crown):
    size = 0.07
    g = _tree(crown, leaves=1500, leaf_size=size)
    assert g.leaf_count == 1500
    assert g.leaf_points.shape == (6000, 3)
    assert g.leaf_face_vertex_counts.tolist() == [4] * 1500
    # each card indexes its own 4 points: no point is shared between cards
    assert np.array_equal(g.leaf_face_vertex_indices, np.arange(6000))
    c = _cards(g)
    d = np.linalg.norm(c[:, :, None, :] - c[:, None, :, :], axis=-1)  # (L, 4, 4) corner distances
    sides = d[:, [0, 1, 2, 3], [1, 2, 3, 0]]
    diagonals = d[:, [0, 1], [2, 3]]
    # float64 arithmetic on O(1) coordinates: 1e-9 leaves ~6 orders of magnitude of headroom
    np.testing.assert_allclose(sides, size, atol=1e-9, rtol=0)
    np.testing.assert_allclose(diagonals, size * np.sqrt(2.0), atol=1e-9, rtol=0)
    area = 0.5 * np.linalg.norm(np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1]), axis=1)
    np.testing.assert_allclose(area, size**2, atol=1e-9, rtol=0)
    planar = np.einsum("ij,ij->i", _card_normals(c), c[:, 3] - c[:, 0])
    np.testing.assert_allclose(planar, 0.0, atol=1e-9, rtol=0)


def _independent_containment(crown: str, p: np.ndarray, g) -> np.ndarray:
    """The crown of the module docstring, rewritten here rather than calling Crown.contains."""
    zb = mt.CROWN_BASE_FRACTION * H
    x, y, z = p.T
    if crown == "ellipsoid":
        c, a = (zb + H) / 2, (H - zb) / 2
        return (x / R) ** 2 + (y / R) ** 2 + ((z - c) / a) ** 2 <= 1 + 1e-12
    if crown == "cone":
        return (z >= zb) & (z <= H) & (np.hypot(x, y) <= R * (H - z) / (H - zb) + 1e-12)
    inside = np.zeros(len(p), dtype=bool)
    for centre, axes in g.crown.ellipsoids:
        inside |= (((p - centre) / axes) ** 2).sum(axis=1) <= 1 + 1e-12
    return inside


@pytest.mark.parametrize("crown", ["ellipsoid", "cone", "lobes"])
def test_leaf_centres_lie_inside_the_requested_crown(crown):
    g = _tree(crown, leaves=5000)
    centres = _cards(g).mean(axis=1)
    assert _independent_containment(crown, centres, g).all()
    # and they reach out to the crown's edge rather than bunching on the axis
    assert np.hypot(centres[:, 0], centres[:, 1]).max() > 0.85 * R
    assert centres[:, 2].min() < mt.CROWN_BASE_FRACTION * H + 0.15 * H and centres[:, 2].max() > 0.85 * H


def test_lobes_stay_in_the_bounding_cylinder_and_hold_leaves_of_their_own():
    g = _tree("lobes", leaves=5000)
    zb = mt.CROWN_BASE_FRACTION * H
    lobes = g.crown.ellipsoids
    assert len(lobes) == 1 + mt.SIDE_LOBES
    for (cx, cy, cz), (ax, ay, az) in lobes:
        assert ax == ay
        assert np.hypot(cx, cy) + ax <= R + 1e-12
        assert zb - 1e-12 <= cz - az and cz + az <= H + 1e-12
    (c0, a0) = lobes[0]
    centres = _cards(g).mean(axis=1)
    outside_central = (((centres - c0) / a0) ** 2).sum(axis=1) > 1
    assert outside_central.mean() > 0.2  # the side lobes are not swallowed by the central one


def test_leaves_fill_the_crown_volume_uniformly():
    # A uniform density puts (1/2)^3 = 1/8 of the leaves in the crown scaled by 1/2 about
    # its centre (ellipsoid) or its apex (cone). Binomial sd at n = 20000 is 0.0023;
    # 0.01 is > 4 sd, and sampling the radius linearly (a classic bug) gives 0.5.
    n = 20000
    zb = mt.CROWN_BASE_FRACTION * H
    g = _tree("ellipsoid", leaves=n)
    c = _cards(g).mean(axis=1)
    mid = (zb + H) / 2
    inner = (c[:, 0] / (R / 2)) ** 2 + (c[:, 1] / (R / 2)) ** 2 + ((c[:, 2] - mid) / ((H - zb) / 4)) ** 2 <= 1
    assert abs(inner.mean() - 1 / 8) < 0.01
    g = _tree("cone", leaves=n)
    c = _cards(g).mean(axis=1)
    assert abs((c[:, 2] > mid).mean() - 1 / 8) < 0.01


def test_leaf_normals_are_uniform_on_the_sphere():
    # For uniform directions E[n] = 0 and E[n_i^2] = 1/3; with 20000 samples the sd of each
    # mean component is ~0.004 and of mean(n_i^2) ~0.002, so 0.05 and 0.02 are loose bounds
    # that still catch a bias toward an axis or a hemisphere.
    n = _card_normals(_cards(_tree(leaves=20000)))
    assert np.linalg.norm(n.mean(axis=0)) < 0.05
    np.testing.assert_allclose((n**2).mean(axis=0), 1 / 3, atol=0.02)
    # Archimedes: each component of a uniform direction is uniform on [-1, 1]. Chi-square over
    # 10 bins (9 dof) stays below 30 with probability 1 - 4e-4; normalising points of a cube
    # instead of a Gaussian (right moments above, wrong distribution) scores > 1000.
    for axis in range(3):
        counts = np.histogram(n[:, axis], bins=10, range=(-1, 1))[0]
        expected = len(n) / 10
        assert ((counts - expected) ** 2 / expected).sum() < 30


# -- seeds ----------------------------------------------------------------------


def _arrays(g):
    return [g.wood_points, g.wood_face_vertex_counts, g.wood_face_vertex_indices, g.leaf_points,
            g.leaf_face_vertex_counts, g.leaf_face_vertex_indices]


@pytest.mark.parametrize("crown", ["ellipsoid", "lobes"])
def test_same_seed_gives_identical_arrays_and_a_different_seed_does_not(crown):
    a, b, c = _tree(crown, seed=11), _tree(crown, seed=11), _tree(crown, seed=12)
    for x, y in zip(_arrays(a), _arrays(b)):
        assert np.array_equal(x, y)
    assert a.crown == b.crown
    assert not np.array_equal(a.leaf_points, c.leaf_points)
    assert a.wood_points.shape != c.wood_points.shape or not np.array_equal(a.wood_points, c.wood_points)


def test_leaf_count_does_not_change_the_wood():
    a, b = _tree("lobes", leaves=1000), _tree("lobes", leaves=3000)
    assert np.array_equal(a.wood_points, b.wood_points)
    assert a.crown == b.crown


@pytest.mark.parametrize("crown", ["ellipsoid", "cone", "lobes"])
def test_branch_tips_end_in_the_crown(crown):
    g = _tree(crown, leaves=10)
    s = mt.TUBE_SIDES
    tips = g.wood_points.reshape(g.branch_count, 2 * s, 3)[1:, s:].mean(axis=1)  # top ring centres, trunk excluded
    assert g.crown.contains(tips).all()
    assert g.wood_face_vertex_counts.shape[0] == g.branch_count * (s + 2)


def test_wood_tubes_are_closed_and_face_outward():
    # each tube is a convex capped frustum: every face's (Newell) normal points away from the tube's centroid
    g = _tree("lobes", leaves=10)
    p, counts, idx = g.wood_points, g.wood_face_vertex_counts, g.wood_face_vertex_indices
    per_tube = 2 * mt.TUBE_SIDES
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    outward = []
    for off, n in zip(offsets, counts):
        v = p[idx[off:off + n]]
        newell = np.cross(v, np.roll(v, -1, axis=0)).sum(axis=0)
        tube = idx[off] // per_tube
        centre = p[tube * per_tube:(tube + 1) * per_tube].mean(axis=0)
        outward.append(np.dot(newell, v.mean(axis=0) - centre))
    assert np.all(np.array(outward) > 0)
    # closed: every edge is used exactly twice, once in each direction
    edges = np.concatenate([np.stack([idx[o:o + n], np.roll(idx[o:o + n], -1)], axis=1) for o, n in zip(offsets, counts)])
    assert len({tuple(e) for e in edges.tolist()}) == len(edges)
    assert {tuple(e) for e in edges.tolist()} == {tuple(e) for e in edges[:, ::-1].tolist()}


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"leaves": 0}, "leaves"),
        ({"leaf_size": -0.1}, "leaf_size"),
        ({"height": float("nan")}, "height"),
        ({"crown_radius": 0.0}, "crown_radius"),
        ({"crown": "sphere"}, "crown"),
        ({"seed": -1}, "seed"),
    ],
)
def test_build_tree_rejects_bad_arguments(kwargs, message):
    args = dict(leaves=10, leaf_size=0.1, crown="cone", height=H, crown_radius=R, seed=0) | kwargs
    with pytest.raises(ValueError, match=message):
        mt.build_tree(**args)


# -- USD ------------------------------------------------------------------------


def _open(path) -> Usd.Stage:
    stage = Usd.Stage.Open(str(path))
    assert stage is not None
    return stage


def test_written_tree_stage(tmp_path):
    g = _tree("cone", leaves=300)
    path = mt.write_tree(tmp_path / "tree.usda", g)
    stage = _open(path)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    root = stage.GetDefaultPrim()
    assert root.GetPath() == Sdf.Path("/Tree") and Usd.ModelAPI(root).GetKind() == "component"

    leaves, wood = UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves")), UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Wood"))
    assert UsdGeom.PrimvarsAPI(leaves).GetPrimvar("foliage:isLeaf").Get() is True
    assert UsdGeom.PrimvarsAPI(leaves).GetPrimvar("foliage:isLeaf").GetInterpolation() == UsdGeom.Tokens.constant
    assert UsdGeom.PrimvarsAPI(wood).GetPrimvar("foliage:isLeaf").Get() is False
    pts = np.asarray(leaves.GetPointsAttr().Get())
    assert pts.shape == (4 * 300, 3)
    np.testing.assert_allclose(pts, g.leaf_points, atol=1e-6)  # float32 on disk
    assert list(leaves.GetFaceVertexCountsAttr().Get()) == [4] * 300
    for mesh, points, material, color in ((leaves, g.leaf_points, "Leaf", mt.LEAF_COLOR), (wood, g.wood_points, "Bark", mt.BARK_COLOR)):
        assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
        assert mesh.GetDoubleSidedAttr().Get() is True
        extent = np.asarray(mesh.GetExtentAttr().Get())
        np.testing.assert_allclose(extent, [points.min(axis=0), points.max(axis=0)], atol=1e-6)
        np.testing.assert_allclose(mesh.GetDisplayColorPrimvar().Get()[0], color, atol=1e-6)
        bound, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
        assert bound.GetPath() == Sdf.Path(f"/Tree/Materials/{material}")
        shader = UsdShade.Shader(stage.GetPrimAtPath(f"/Tree/Materials/{material}/PreviewSurface"))
        assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
        np.testing.assert_allclose(shader.GetInput("diffuseColor").Get(), color, atol=1e-6)
    assert len(wood.GetPointsAttr().Get()) == g.wood_points.shape[0]

    sun, sky = stage.GetPrimAtPath("/Lights/Sun"), stage.GetPrimAtPath("/Lights/Sky")
    assert sun.IsA(UsdLux.DistantLight) and sky.IsA(UsdLux.DomeLight)
    assert UsdLux.DistantLight(sun).GetAngleAttr().Get() == pytest.approx(0.53)
    assert UsdLux.DistantLight(sun).GetIntensityAttr().Get() == pytest.approx(1.0)
    # the light travels along its -Z, so its +Z axis must point at the sun: azimuth 45, elevation 60
    m = np.array(UsdGeom.Xformable(sun).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    el, az = np.radians(60.0), np.radians(45.0)
    np.testing.assert_allclose(m[2, :3], [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], atol=1e-6)

    path2 = mt.write_tree(tmp_path / "bare.usda", g, with_lights=False)
    assert not _open(path2).GetPrimAtPath("/Lights")


def test_same_arguments_write_byte_identical_files(tmp_path):
    for ext in ("usda", "usdc"):
        a = mt.write_tree(tmp_path / f"a.{ext}", _tree("lobes", leaves=200, seed=5))
        b = mt.write_tree(tmp_path / f"b.{ext}", _tree("lobes", leaves=200, seed=5))
        c = mt.write_tree(tmp_path / f"c.{ext}", _tree("lobes", leaves=200, seed=6))
        assert a.read_bytes() == b.read_bytes()
        assert a.read_bytes() != c.read_bytes()


def test_file_format_follows_extension_and_flag(tmp_path):
    g = _tree(leaves=20)
    assert mt.write_tree(tmp_path / "t.usdc", g).read_bytes().startswith(b"PXR-USDC")
    assert mt.write_tree(tmp_path / "t.usda", g).read_bytes().startswith(b"#usda")
    assert mt.write_tree(tmp_path / "t1.usd", g, file_format="usda").read_bytes().startswith(b"#usda")
    assert mt.write_tree(tmp_path / "t2.usd", g).read_bytes().startswith(b"PXR-USDC")
    with pytest.raises(ValueError, match="contradicts"):
        mt.write_tree(tmp_path / "t.usda", g, file_format="usdc")
    with pytest.raises(ValueError, match="extension"):
        mt.write_tree(tmp_path / "t.obj", g)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.usda", "t.usdc", "t1.usd", "t2.usd"]  # no temp files left


def test_tree_command_line(tmp_path, capsys):
    out = tmp_path / "cli.usda"
    assert mt.main(["--leaves", "120", "--crown", "lobes", "--leaf-size", "0.05", "--seed", "9", "--out", str(out)]) == 0
    assert "120 leaves" in capsys.readouterr().out
    stage = _open(out)
    assert len(UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves")).GetPointsAttr().Get()) == 480
    assert dict(stage.GetRootLayer().customLayerData["foliage:parameters"])["crown"] == "lobes"
    for bad in (["--leaves", "0"], ["--crown", "box"], ["--out", str(tmp_path / "x.usda"), "--format", "usdc"]):
        with pytest.raises(SystemExit) as exc:
            mt.main(bad)
        assert exc.value.code == 2
    capsys.readouterr()


def test_scripts_run_from_a_shell():
    for script in ("make_tree.py", "make_forest.py"):
        run = subprocess.run([sys.executable, str(EXAMPLES / script), "--help"], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        assert "--out" in run.stdout and "--seed" in run.stdout


# -- forest ---------------------------------------------------------------------


def test_forest_layout_keeps_crowns_apart():
    r = 1.3
    lay = mf.plan_forest(trees=4, grove=12, tree_radius=r, seed=2)
    pos = np.concatenate([lay.tree_positions, lay.grove_positions])
    scale = np.concatenate([lay.tree_scales, lay.grove_scales])
    assert pos.shape == (16, 3) and np.all(pos[:, 2] == 0)
    for i, j in itertools.combinations(range(16), 2):
        assert np.linalg.norm(pos[i] - pos[j]) >= r * (scale[i] + scale[j])
    again = mf.plan_forest(trees=4, grove=12, tree_radius=r, seed=2)
    assert np.array_equal(again.grove_positions, lay.grove_positions) and np.array_equal(again.tree_angles, lay.tree_angles)


def test_forest_references_the_tree_relatively(tmp_path):
    (tmp_path / "assets").mkdir()
    g = _tree(leaves=50)
    tree = mt.write_tree(tmp_path / "assets" / "t.usda", g)
    layout = mf.plan_forest(trees=2, grove=3, tree_radius=mf.tree_radius_of(tree), seed=1)
    forest = mf.write_forest(tmp_path / "forest.usda", tree, layout)
    stage = _open(forest)
    refs = stage.GetPrimAtPath("/World/Trees/Tree_01").GetMetadata("references").GetAddedOrExplicitItems()
    assert [r.assetPath for r in refs] == ["./assets/t.usda"]
    assert stage.GetPrimAtPath("/World/Grove/Prototypes/TreeProto/Leaves").IsA(UsdGeom.Mesh)
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove"))
    xf = pi.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default())
    np.testing.assert_allclose([np.array(m)[3, :3] for m in xf], layout.grove_positions, atol=1e-5)
    # rotation about +Z by the layout angle, scaled (quath on disk: ~1e-3 precision)
    m0 = np.array(xf[0])[:3, :3] / layout.grove_scales[0]
    a = np.radians(layout.grove_angles[0])
    np.testing.assert_allclose(m0, [[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]], atol=3e-3)
    # the authored extent covers the instanced trees, whatever the working directory was
    lo, hi = np.asarray(pi.GetExtentAttr().Get())
    assert np.all(lo[:2] <= layout.grove_positions[:, :2].min(axis=0)) and np.all(hi[:2] >= layout.grove_positions[:, :2].max(axis=0))
    top = max(g.leaf_points[:, 2].max(), g.wood_points[:, 2].max())
    assert hi[2] == pytest.approx(top * layout.grove_scales.max(), rel=1e-5)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left


# -- the committed example scenes -------------------------------------------------


def _leaf_mesh(stage: Usd.Stage) -> UsdGeom.Mesh:
    return UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves"))


def test_committed_tree_small_opens_and_matches_its_generator():
    path = EXAMPLES / "tree_small.usda"
    data = path.read_bytes()
    assert len(data) < 2_000_000
    assert data.startswith(b"#usda") and data.isascii()
    stage = _open(path)
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Tree")
    counts = np.asarray(_leaf_mesh(stage).GetFaceVertexCountsAttr().Get())
    assert counts.shape == (1500,) and np.all(counts == 4)
    # stale-file check: rebuild from the parameters recorded in the file
    params = dict(stage.GetRootLayer().customLayerData["foliage:parameters"])
    g = mt.build_tree(**params)
    np.testing.assert_allclose(np.asarray(_leaf_mesh(stage).GetPointsAttr().Get()), g.leaf_points, atol=1e-6)
    wood = UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Wood"))
    np.testing.assert_allclose(np.asarray(wood.GetPointsAttr().Get()), g.wood_points, atol=1e-6)


def test_committed_forest_small_has_four_instances_and_a_point_instancer_of_twelve():
    path = EXAMPLES / "forest_small.usda"
    assert path.stat().st_size + (EXAMPLES / "tree_small.usda").stat().st_size < 4_000_000
    stage = _open(path)
    assert not stage.GetCompositionErrors()
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    trees = [p for p in stage.GetPrimAtPath("/World/Trees").GetChildren()]
    assert [p.GetName() for p in trees] == ["Tree_00", "Tree_01", "Tree_02", "Tree_03"]
    assert all(p.IsInstanceable() and p.IsInstance() for p in trees)
    assert len({p.GetPrototype().GetPath() for p in trees}) == 1  # one shared prototype
    for p in trees:
        refs = p.GetMetadata("references").GetAddedOrExplicitItems()
        assert [r.assetPath for r in refs] == ["./tree_small.usda"]
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove"))
    assert pi
    assert [str(t) for t in pi.GetPrototypesRel().GetTargets()] == ["/World/Grove/Prototypes/TreeProto"]
    assert list(pi.GetProtoIndicesAttr().Get()) == [0] * 12
    assert len(pi.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default())) == 12
    leaves = stage.GetPrimAtPath("/World/Grove/Prototypes/TreeProto/Leaves")
    assert len(UsdGeom.Mesh(leaves).GetFaceVertexCountsAttr().Get()) == 1500
    assert stage.GetPrimAtPath("/Lights/Sun").IsA(UsdLux.DistantLight)
    assert stage.GetPrimAtPath("/Lights/Sky").IsA(UsdLux.DomeLight)


def test_committed_forest_small_matches_its_generator():
    stage = _open(EXAMPLES / "forest_small.usda")
    params = dict(stage.GetRootLayer().customLayerData["foliage:parameters"])
    assert params["tree"] == "./tree_small.usda"
    radius = mf.tree_radius_of(EXAMPLES / "tree_small.usda")
    layout = mf.plan_forest(trees=params["trees"], grove=params["grove"], tree_radius=radius, seed=params["seed"])
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Grove"))
    np.testing.assert_allclose(np.asarray(pi.GetPositionsAttr().Get()), layout.grove_positions, atol=1e-5)
    for i, pos in enumerate(layout.tree_positions):
        xf = UsdGeom.Xformable(stage.GetPrimAtPath(f"/World/Trees/Tree_{i:02d}"))
        m = np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        np.testing.assert_allclose(m[3, :3], pos, atol=1e-9)

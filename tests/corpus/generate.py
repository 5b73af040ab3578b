"""Write the corpus of small tree assets: ``clean/`` (what a good asset looks like) and ``bad/`` (one problem each).

Usage (from the repository root)::

    .venv/bin/python tests/corpus/generate.py            # rewrites tests/corpus/clean and tests/corpus/bad
    .venv/bin/python tests/corpus/generate.py OUT_DIR    # writes OUT_DIR/clean and OUT_DIR/bad

Deterministic: the leaves come from a seeded generator and every coordinate is rounded, so the same usd-core
writes the same bytes (``tests/integration/test_corpus.py`` checks that the committed files are this script's
output, and that the CLI's text on each of them equals ``tests/corpus/baseline/``). After changing this script:
run it, then ``FOLIAGE_UPDATE_GOLDEN=1 pytest tests/integration/test_corpus.py`` and review the diff.

Each asset is built in memory and exported (``Sdf.Layer.Export``), so nothing is composed against the files on
disk while writing: a missing sublayer or reference is written without USD complaining here.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Callable

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE.parents[1]) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(HERE.parents[1]))

from foliage_tools.scene.schemas import register  # noqa: E402

register()  # FoliageLeafAPI

from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdVol, Vt  # noqa: E402

SEED = 20261204
LEAVES = 24
LEAF_SIZE = 0.2
#: decimals kept in every coordinate, so the text (and its bytes) do not depend on float noise
DECIMALS = 4


# -- geometry (numpy) -----------------------------------------------------------


def leaf_cards(n: int = LEAVES, *, seed: int = SEED, centre=(0.0, 0.0, 2.0), radius=(0.8, 0.8, 0.6),
               size: float = LEAF_SIZE) -> tuple[np.ndarray, list[int], list[int]]:
    """n square leaf cards (4 own points, one quad each) at random places in an ellipsoid, random orientations."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = d * np.asarray(radius) * rng.uniform(size=(n, 1)) ** (1 / 3) + np.asarray(centre)
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u, v = q[:, :, 0] * size / 2, q[:, :, 1] * size / 2
    pts = np.stack([c - u - v, c + u - v, c + u + v, c - u + v], axis=1).reshape(-1, 3)
    return np.round(pts, DECIMALS), [4] * n, list(range(4 * n))


def trunk_box(height: float = 1.6, half: float = 0.06) -> tuple[np.ndarray, list[int], list[int]]:
    """A closed box from z = 0 to ``height``: 8 points, 6 quads."""
    pts = np.array([(x, y, z) for z in (0.0, height) for y in (-half, half) for x in (-half, half)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return pts, [4] * 6, [i for q in quads for i in q]


def z_up_to_y_up(pts: np.ndarray) -> np.ndarray:
    """(x, y, z) Z-up -> (x, z, -y) Y-up: the same tree standing on the other axis."""
    return np.stack([pts[:, 0], pts[:, 2], -pts[:, 1]], axis=1)


# -- authoring (pxr) -------------------------------------------------------------


def new_stage(*, up: str | None = "Z", mpu: float | None = 1.0, doc: str = "") -> Usd.Stage:
    stage = Usd.Stage.CreateInMemory()
    if up is not None:
        UsdGeom.SetStageUpAxis(stage, up)
    if mpu is not None:
        UsdGeom.SetStageMetersPerUnit(stage, mpu)
    layer = stage.GetRootLayer()
    layer.customLayerData = {"foliage:generator": "tests/corpus/generate.py"}
    if doc:
        layer.documentation = doc
    return stage


def mesh(stage: Usd.Stage, path: str, pts, counts, indices) -> UsdGeom.Mesh:
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(pts, dtype=np.float32)))
    m.CreateFaceVertexCountsAttr(Vt.IntArray(list(map(int, counts))))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray(list(map(int, indices))))
    m.CreateDoubleSidedAttr(True)
    return m


def tree(stage: Usd.Stage, root: str = "/Tree", *, leaves=None, trunk=None, default: bool = True) -> Usd.Prim:
    """A component Xform with a ``Trunk`` box (wood) and a ``Leaves`` mesh (a leaf mesh by its name)."""
    prim = UsdGeom.Xform.Define(stage, root).GetPrim()
    Usd.ModelAPI(prim).SetKind(Kind.Tokens.component)
    mesh(stage, f"{root}/Trunk", *(trunk or trunk_box()))
    mesh(stage, f"{root}/Leaves", *(leaves or leaf_cards()))
    if default and prim.GetParent().IsPseudoRoot():
        stage.SetDefaultPrim(prim)
    return prim


def sun(stage: Usd.Stage, path: str = "/Lights/Sun", *, up: str = "Z", azimuth: float = 45.0, elevation: float = 60.0) -> UsdLux.DistantLight:
    """A DistantLight whose +Z axis points toward the sun (azimuth from +X toward +Y, elevation above the horizon)."""
    if not stage.GetPrimAtPath(str(Sdf.Path(path).GetParentPath())):
        UsdGeom.Scope.Define(stage, Sdf.Path(path).GetParentPath())
    light = UsdLux.DistantLight.Define(stage, path)
    light.CreateIntensityAttr(1.0)
    light.CreateAngleAttr(0.53)
    rot = (0.0, 90.0 - elevation, azimuth) if up == "Z" else (-elevation, azimuth, 0.0)
    light.AddRotateXYZOp().Set(Gf.Vec3f(*rot))
    return light


def export(stage_or_layer, path: Path) -> None:
    layer = stage_or_layer.GetRootLayer() if isinstance(stage_or_layer, Usd.Stage) else stage_or_layer
    path.parent.mkdir(parents=True, exist_ok=True)
    if not layer.Export(str(path)):
        raise RuntimeError(f"could not write {path}")


def edit(path: Path, fn: Callable[[Sdf.Layer], object]) -> None:
    """Edit the written file ``path`` as a lone layer (nothing composed: a missing sublayer is not looked for here)."""
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    fn(layer)
    export(layer, path)


def minimal(doc: str, *, light: bool = True, **kw) -> Usd.Stage:
    stage = new_stage(doc=doc)
    tree(stage, **kw)
    if light:
        sun(stage)
    return stage


def instancer(stage: Usd.Stage, path: str, protos: list[str], indices: list[int]) -> UsdGeom.PointInstancer:
    pi = UsdGeom.PointInstancer.Define(stage, path)
    pi.CreatePrototypesRel().SetTargets([Sdf.Path(p) for p in protos])
    pi.CreateProtoIndicesAttr(Vt.IntArray(indices))
    pi.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(4.0 * (i % 3), 4.0 * (i // 3), 0.0) for i in range(len(indices))]))
    return pi


# -- clean/ -----------------------------------------------------------------------


def clean_minimal_tree(d: Path) -> None:
    export(minimal("The smallest tree: a trunk box and 24 leaf cards (a leaf mesh by its name), Z up, metres, a sun."),
           d / "minimal_tree.usda")


def clean_y_up_centimetres(d: Path) -> None:
    stage = new_stage(up="Y", mpu=0.01, doc="The minimal tree in centimetres standing on +Y; leaves marked by "
                                          "primvars:foliage:isLeaf on a mesh named Canopy.")
    prim = UsdGeom.Xform.Define(stage, "/Tree").GetPrim()
    Usd.ModelAPI(prim).SetKind(Kind.Tokens.component)
    stage.SetDefaultPrim(prim)
    pts, counts, idx = trunk_box()
    mesh(stage, "/Tree/Trunk", np.round(z_up_to_y_up(pts) * 100.0, 2), counts, idx)
    pts, counts, idx = leaf_cards()
    canopy = mesh(stage, "/Tree/Canopy", np.round(z_up_to_y_up(pts) * 100.0, 2), counts, idx)
    UsdGeom.PrimvarsAPI(canopy).CreatePrimvar("foliage:isLeaf", Sdf.ValueTypeNames.Bool, UsdGeom.Tokens.constant).Set(True)
    sun(stage, up="Y")
    export(stage, d / "y_up_centimetres.usda")


def _forest_prototype(stage: Usd.Stage, root: str, seed: int, *, material: str | None) -> None:
    UsdGeom.Xform.Define(stage, root)
    mesh(stage, f"{root}/Trunk", *trunk_box(height=1.6 if material else 1.2))
    pts, counts, idx = leaf_cards(16, seed=seed, centre=(0.0, 0.0, 1.8 if material else 1.5), radius=(0.6, 0.6, 0.7))
    crown = mesh(stage, f"{root}/Crown", pts, counts, idx)  # "Crown" is not a leaf name: API or material says so
    if material is None:
        crown.GetPrim().ApplyAPI("FoliageLeafAPI")
    else:
        mat = UsdShade.Material.Define(stage, f"{root}/Materials/{material}")
        UsdShade.MaterialBindingAPI.Apply(crown.GetPrim()).Bind(mat)


def clean_forest_instancer(d: Path) -> None:
    stage = new_stage(doc="A stand of 6 trees: a PointInstancer of two prototypes (Oak: FoliageLeafAPI; Birch: a "
                          "material named BirchLeaf), no light (bakes use the default sun).")
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    Usd.ModelAPI(world.GetPrim()).SetKind(Kind.Tokens.assembly)
    protos = ["/World/Forest/Prototypes/Oak", "/World/Forest/Prototypes/Birch"]
    pi = instancer(stage, "/World/Forest", protos, [0, 1, 0, 1, 0, 1])
    pi.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(math.cos(a / 2), 0.0, 0.0, math.sin(a / 2))
                                             for a in np.radians([0, 30, 60, 90, 120, 150])]))
    pi.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(s, s, s) for s in (1.0, 0.9, 1.1, 1.0, 0.8, 1.2)]))
    UsdGeom.Scope.Define(stage, "/World/Forest/Prototypes")
    _forest_prototype(stage, protos[0], SEED + 1, material=None)
    _forest_prototype(stage, protos[1], SEED + 2, material="BirchLeaf")
    export(stage, d / "forest_instancer.usda")


def clean_layered_tree(d: Path) -> None:
    base = new_stage(doc="The sublayer of layered_tree.usda: the tree with two leaf meshes (on its own it is a "
                         "valid tree too).")
    tree(base)
    mesh(base, "/Tree/LeavesUpper", *leaf_cards(12, seed=SEED + 3, centre=(0.0, 0.0, 2.6), radius=(0.5, 0.5, 0.3)))
    export(base, d / "layers" / "layered_tree_base.usda")

    stage = new_stage(doc="A tree in two layers: the geometry comes from layers/layered_tree_base.usda; this "
                          "stronger layer hides LeavesUpper and adds the sun, so only the layer stack gives the tree.")
    stage.GetRootLayer().defaultPrim = "Tree"
    over = stage.OverridePrim("/Tree/LeavesUpper")
    over.CreateAttribute("visibility", Sdf.ValueTypeNames.Token, custom=False).Set(UsdGeom.Tokens.invisible)
    sun(stage)
    export(stage, d / "layered_tree.usda")
    edit(d / "layered_tree.usda", lambda layer: layer.subLayerPaths.append("./layers/layered_tree_base.usda"))


# -- bad/ -------------------------------------------------------------------------


def bad_empty_file(d: Path) -> None:
    (d / "empty_file.usda").write_bytes(b"")


def bad_not_usd_text(d: Path) -> None:
    (d / "not_usd_text.usda").write_text("# an OBJ file saved with a .usda name\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")


def bad_syntax_error(d: Path) -> None:
    stage = minimal("A .usda whose faceVertexCounts array lacks its closing bracket.")
    text = stage.GetRootLayer().ExportToString()  # (the stage held: its layer dies with it)
    broken = text.replace("int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]", "int[] faceVertexCounts = [4, 4, 4, 4, 4, 4", 1)
    assert broken != text
    (d / "syntax_error.usda").write_text(broken)


def bad_empty_stage(d: Path) -> None:
    export(new_stage(doc="Stage metadata and no prims at all."), d / "empty_stage.usda")


def bad_no_meshes(d: Path) -> None:
    stage = new_stage(doc="A tree Xform and a sun, but no mesh.")
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Tree").GetPrim())
    sun(stage)
    export(stage, d / "no_meshes.usda")


def bad_no_leaf_meshes(d: Path) -> None:
    stage = new_stage(doc="Meshes, but none is a leaf mesh (the leaves are named Cards: no name, primvar, API or material says leaf).")
    prim = UsdGeom.Xform.Define(stage, "/Tree").GetPrim()
    stage.SetDefaultPrim(prim)
    mesh(stage, "/Tree/Trunk", *trunk_box())
    mesh(stage, "/Tree/Cards", *leaf_cards())
    sun(stage)
    export(stage, d / "no_leaf_meshes.usda")


def bad_leaves_invisible(d: Path) -> None:
    stage = minimal("The leaf mesh is invisible: bakes leave it out, so they find no leaf.")
    UsdGeom.Imageable(stage.GetPrimAtPath("/Tree/Leaves")).CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    export(stage, d / "leaves_invisible.usda")


def bad_nan_inf_points(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    pts = pts.copy()
    pts[0] = (math.nan, 0.0, 2.0)
    pts[5] = (0.0, math.inf, 2.0)
    export(minimal("Two leaf points are NaN and infinite.", leaves=(pts, counts, idx)), d / "nan_inf_points.usda")


def bad_face_index_out_of_range(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    idx = list(idx)
    idx[-1] = len(pts) + 10
    export(minimal("The last leaf quad names a point past the end of points.", leaves=(pts, counts, idx)),
           d / "face_index_out_of_range.usda")


def bad_face_with_two_vertices(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    counts = list(counts[:-1]) + [2, 2]  # still summing to the indices: only the face sizes are wrong
    export(minimal("The last leaf quad is split into two 2-vertex faces.", leaves=(pts, counts, idx)),
           d / "face_with_two_vertices.usda")


def bad_face_counts_mismatch(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    export(minimal("faceVertexCounts sum to more than there are faceVertexIndices.", leaves=(pts, list(counts) + [4], idx)),
           d / "face_counts_mismatch.usda")


def bad_degenerate_leaf_triangles(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    pts = pts.copy()
    for k in (0, 7, 13):  # three cards collapsed onto a point: their 6 triangles have zero area
        pts[4 * k: 4 * k + 4] = pts[4 * k]
    export(minimal("Three of the 24 leaf cards are collapsed to a point (zero-area triangles; a warning).",
                   leaves=(pts, counts, idx)), d / "degenerate_leaf_triangles.usda")


def bad_zero_area_leaves(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    pts = pts.copy()
    pts[:, 2] = 2.0
    pts[:, 1] = pts[:, 0]  # every point on the line x = y, z = 2: no triangle has area
    export(minimal("Every leaf triangle has zero area (all points on one line).", leaves=(pts, counts, idx)),
           d / "zero_area_leaves.usda")


def bad_leaf_mesh_without_points(d: Path) -> None:
    stage = minimal("The leaf mesh has faces but no points authored.")
    stage.GetPrimAtPath("/Tree/Leaves").GetAttribute("points").Clear()
    export(stage, d / "leaf_mesh_without_points.usda")


def bad_meters_per_unit_zero(d: Path) -> None:
    stage = minimal("metersPerUnit = 0.")
    UsdGeom.SetStageMetersPerUnit(stage, 0.0)
    export(stage, d / "meters_per_unit_zero.usda")


def bad_no_stage_metadata(d: Path) -> None:
    stage = new_stage(up=None, mpu=None, doc="No upAxis, no metersPerUnit (USD's fallbacks: Y up, centimetres).")
    tree(stage)
    sun(stage)
    export(stage, d / "no_stage_metadata.usda")


def bad_zero_scale_transform(d: Path) -> None:
    stage = minimal("The tree's Xform scales by 0.")
    UsdGeom.Xformable(stage.GetPrimAtPath("/Tree")).AddScaleOp().Set(Gf.Vec3f(0.0, 0.0, 0.0))
    export(stage, d / "zero_scale_transform.usda")


def bad_sun_zero_scale(d: Path) -> None:
    stage = minimal("The sun (DistantLight) is scaled by 0, so it points nowhere.")
    UsdGeom.Xformable(stage.GetPrimAtPath("/Lights/Sun")).AddScaleOp().Set(Gf.Vec3f(0.0, 0.0, 0.0))
    export(stage, d / "sun_zero_scale.usda")


def bad_missing_sublayer(d: Path) -> None:
    export(minimal("Sublayers a file that does not exist."), d / "missing_sublayer.usda")
    edit(d / "missing_sublayer.usda", lambda layer: layer.subLayerPaths.append("./missing_layer.usda"))


def bad_missing_reference(d: Path) -> None:
    stage = minimal("/Tree/Branch references a file that does not exist.")
    UsdGeom.Xform.Define(stage, "/Tree/Branch")
    export(stage, d / "missing_reference.usda")
    edit(d / "missing_reference.usda",
         lambda layer: layer.GetPrimAtPath("/Tree/Branch").referenceList.Prepend(Sdf.Reference("./missing_branch.usda")))


def bad_sublayer_cycle(d: Path) -> None:
    export(minimal("Sublayers layers/sublayer_cycle_back.usda, which sublayers this file again."), d / "sublayer_cycle.usda")
    edit(d / "sublayer_cycle.usda", lambda layer: layer.subLayerPaths.append("./layers/sublayer_cycle_back.usda"))
    back = Sdf.Layer.CreateAnonymous(".usda")
    back.subLayerPaths.append("../sublayer_cycle.usda")
    export(back, d / "layers" / "sublayer_cycle_back.usda")


def _forest(doc: str, protos: list[str], indices: list[int]) -> tuple[Usd.Stage, UsdGeom.PointInstancer]:
    """/World/Forest: a PointInstancer of ``protos`` with its prototype tree at /World/Forest/Prototypes/Tree."""
    stage = new_stage(doc=doc)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    pi = instancer(stage, "/World/Forest", protos, indices)
    UsdGeom.Scope.Define(stage, "/World/Forest/Prototypes")
    tree(stage, "/World/Forest/Prototypes/Tree")
    sun(stage)
    return stage, pi


TREE_PROTO = "/World/Forest/Prototypes/Tree"


def bad_instancer_proto_index_out_of_range(d: Path) -> None:
    stage, _ = _forest("A PointInstancer with one prototype whose protoIndices also name prototypes 1 and 3.",
                       [TREE_PROTO], [0, 1, 0, 3])
    export(stage, d / "instancer_proto_index_out_of_range.usda")


def bad_instancer_missing_prototype(d: Path) -> None:
    stage, _ = _forest("A PointInstancer whose second prototype target does not exist.",
                       [TREE_PROTO, "/World/Forest/Prototypes/Gone"], [0, 1, 0, 1])
    export(stage, d / "instancer_missing_prototype.usda")


def bad_instancer_zero_scale(d: Path) -> None:
    stage, pi = _forest("A PointInstancer whose third instance is scaled by 0.", [TREE_PROTO], [0, 0, 0, 0])
    pi.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(1, 1, 1), Gf.Vec3f(1, 1, 1), Gf.Vec3f(0, 0, 0), Gf.Vec3f(1, 1, 1)]))
    export(stage, d / "instancer_zero_scale.usda")


def bad_instancer_nested(d: Path) -> None:
    grove = "/World/Forest/Prototypes/Grove"
    stage, _ = _forest("The PointInstancer's prototype Grove holds another PointInstancer (nested instancing is not "
                       "read): only the Tree instances are baked.", [TREE_PROTO, grove], [0, 1])
    inner = instancer(stage, f"{grove}/Inner", [f"{grove}/Inner/Prototypes/Tree"], [0, 0, 0])
    inner.GetPositionsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0.0, 3.0 * i, 0.0) for i in range(3)]))
    tree(stage, f"{grove}/Inner/Prototypes/Tree")
    export(stage, d / "instancer_nested.usda")


def bad_instancer_prototype_is_instancer(d: Path) -> None:
    grove = "/World/Forest/Prototypes/Grove"
    stage, _ = _forest("The PointInstancer's prototype Grove is itself a PointInstancer (nested instancing is not "
                       "read): only the Tree instances are baked.", [TREE_PROTO, grove], [0, 1])
    inner = instancer(stage, grove, [f"{grove}/Prototypes/Tree"], [0, 0, 0])
    inner.GetPositionsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0.0, 3.0 * i, 0.0) for i in range(3)]))
    tree(stage, f"{grove}/Prototypes/Tree")
    export(stage, d / "instancer_prototype_is_instancer.usda")


def bad_primvar_length_mismatch(d: Path) -> None:
    stage = minimal("primvars:displayColor is uniform (one per face) but has 3 values for 24 faces.")
    UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves")).CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(
        Vt.Vec3fArray([Gf.Vec3f(0.2, 0.45, 0.1)] * 3))
    export(stage, d / "primvar_length_mismatch.usda")


def bad_primvar_indices_out_of_range(d: Path) -> None:
    stage = minimal("An indexed primvars:displayColor whose indices reach past its 2 values.")
    pv = UsdGeom.Mesh(stage.GetPrimAtPath("/Tree/Leaves")).CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform)
    pv.Set(Vt.Vec3fArray([Gf.Vec3f(0.2, 0.45, 0.1), Gf.Vec3f(0.3, 0.5, 0.1)]))
    pv.SetIndices(Vt.IntArray([i % 2 for i in range(LEAVES - 1)] + [5]))
    export(stage, d / "primvar_indices_out_of_range.usda")


def bad_missing_vdb(d: Path) -> None:
    stage = minimal("A Volume whose OpenVDBAsset field names a .vdb file that does not exist.")
    vol = UsdVol.Volume.Define(stage, "/Tree/FoliageLighting")
    field = UsdVol.OpenVDBAsset.Define(stage, "/Tree/FoliageLighting/density")
    field.CreateFilePathAttr(Sdf.AssetPath("./missing_density.vdb"))
    field.CreateFieldNameAttr("density")
    vol.CreateFieldRelationship("density", field.GetPath())
    export(stage, d / "missing_vdb.usda")


def bad_leaf_optics_attributes(d: Path) -> None:
    stage = minimal("The leaf mesh authors foliage:leaf:reflectance, which is reserved and not read yet (a warning).")
    stage.GetPrimAtPath("/Tree/Leaves").CreateAttribute("foliage:leaf:reflectance", Sdf.ValueTypeNames.Color3f).Set(
        Gf.Vec3f(0.1, 0.2, 0.05))
    export(stage, d / "leaf_optics_attributes.usda")


def _garbage(n: int, seed: int) -> bytes:
    """``n`` seeded random bytes: the same garbage on every run."""
    return np.random.default_rng(seed).bytes(n)


def bad_garbage_vdb(d: Path) -> None:
    stage = minimal("A Volume field names a .vdb file of random bytes (not an OpenVDB file).")
    vol = UsdVol.Volume.Define(stage, "/Tree/FoliageLighting")
    field = UsdVol.OpenVDBAsset.Define(stage, "/Tree/FoliageLighting/density")
    field.CreateFilePathAttr(Sdf.AssetPath("./layers/garbage.vdb"))
    field.CreateFieldNameAttr("density")
    vol.CreateFieldRelationship("density", field.GetPath())
    export(stage, d / "garbage_vdb.usda")
    (d / "layers").mkdir(exist_ok=True)
    (d / "layers" / "garbage.vdb").write_bytes(_garbage(2000, SEED + 10))


def bad_meters_per_unit_huge(d: Path) -> None:
    stage = minimal("metersPerUnit = 1e300: finite, but beyond the float32 the bakes record it in (it became inf).")
    UsdGeom.SetStageMetersPerUnit(stage, 1e300)
    export(stage, d / "meters_per_unit_huge.usda")


def bad_up_axis_x(d: Path) -> None:
    stage = minimal("upAxis = X, which USD does not allow (only Y or Z).")
    stage.GetRootLayer().pseudoRoot.SetInfo("upAxis", "X")
    export(stage, d / "up_axis_x.usda")


def bad_sun_below_horizon(d: Path) -> None:
    stage = new_stage(doc="The stage's sun (its DistantLight) is 30 degrees below the horizon.")
    tree(stage)
    sun(stage, elevation=-30.0)
    export(stage, d / "sun_below_horizon.usda")


def bad_projective_transform(d: Path) -> None:
    stage = minimal("The tree's Xform is a matrix whose w is 0 (projective, no inverse).")
    UsdGeom.Xformable(stage.GetPrimAtPath("/Tree")).AddTransformOp().Set(
        Gf.Matrix4d(1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0))
    export(stage, d / "projective_transform.usda")


def bad_tiny_coordinates(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    trunk, tc, ti = trunk_box()
    export(minimal("Every coordinate scaled by 1e-30: the foliage is too small for any grid OpenVDB stores.",
                   leaves=(pts * 1e-30, counts, idx), trunk=(trunk * 1e-30, tc, ti)), d / "tiny_coordinates.usda")


def bad_denormal_coordinates(d: Path) -> None:
    pts, counts, idx = leaf_cards()
    trunk, tc, ti = trunk_box()
    export(minimal("Every coordinate scaled by 1e-40: float32 denormals.", leaves=(pts * 1e-40, counts, idx),
                   trunk=(trunk * 1e-40, tc, ti)), d / "denormal_coordinates.usda")


def bad_tiny_single_leaf(d: Path) -> None:
    stage = new_stage(doc="A single leaf triangle of area 5e-31.")
    tree(stage, leaves=(np.array([(0.0, 0.0, 1.0), (1e-15, 0.0, 1.0), (0.0, 1e-15, 1.0)]), [3], [0, 1, 2]))
    sun(stage)
    export(stage, d / "tiny_single_leaf.usda")


def bad_sun_colour_nan(d: Path) -> None:
    stage = minimal("The sun's inputs:color is (nan, 1, 1).")
    UsdLux.DistantLight(stage.GetPrimAtPath("/Lights/Sun")).CreateColorAttr(Gf.Vec3f(math.nan, 1.0, 1.0))
    export(stage, d / "sun_colour_nan.usda")


def bad_sun_colour_negative(d: Path) -> None:
    stage = minimal("The sun's inputs:color is (-1, 1, 1).")
    UsdLux.DistantLight(stage.GetPrimAtPath("/Lights/Sun")).CreateColorAttr(Gf.Vec3f(-1.0, 1.0, 1.0))
    export(stage, d / "sun_colour_negative.usda")


def bad_dome_intensity_nan(d: Path) -> None:
    stage = minimal("A DomeLight (the sky) of inputs:intensity nan.")
    UsdLux.DomeLight.Define(stage, "/Lights/Sky").CreateIntensityAttr(math.nan)
    export(stage, d / "dome_intensity_nan.usda")


def bad_non_utf8_layer(d: Path) -> None:
    stage = minimal("The doc string holds bytes that are not UTF-8: ")
    text = stage.GetRootLayer().ExportToString()  # (the stage held: its layer dies with it)
    raw = text.encode("utf-8").replace(b"not UTF-8: ", b"not UTF-8: \xff\xfe", 1)
    (d / "non_utf8_layer.usda").write_bytes(raw)


def bad_unknown_attribute_type(d: Path) -> None:
    stage = minimal("The leaf mesh's points are authored as point9f[], a type USD does not know.")
    text = stage.GetRootLayer().ExportToString()  # (the stage held: its layer dies with it)
    at = text.index('def Mesh "Leaves"')
    broken = text[:at] + text[at:].replace("point3f[] points", "point9f[] points", 1)
    (d / "unknown_attribute_type.usda").write_text(broken)


def bad_unknown_xform_op(d: Path) -> None:
    stage = minimal("The sun's xformOp is xformOp:frobnicate, an op USD does not know.")
    text = stage.GetRootLayer().ExportToString()  # (the stage held: its layer dies with it)
    broken = text.replace("xformOp:rotateXYZ", "xformOp:frobnicate")
    (d / "unknown_xform_op.usda").write_text(broken)


def bad_payload_garbage(d: Path) -> None:
    stage = minimal("/Tree/Branch has a payload of layers/garbage.usda, random bytes under a .usda name.")
    UsdGeom.Xform.Define(stage, "/Tree/Branch")
    export(stage, d / "payload_garbage.usda")
    edit(d / "payload_garbage.usda",
         lambda layer: layer.GetPrimAtPath("/Tree/Branch").payloadList.Prepend(Sdf.Payload("./layers/garbage.usda")))
    (d / "layers").mkdir(exist_ok=True)
    (d / "layers" / "garbage.usda").write_bytes(_garbage(3000, SEED + 11))


def bad_reference_garbage_usdc(d: Path) -> None:
    stage = minimal("/Tree/Branch references layers/garbage.usdc: a crate header and random bytes.")
    UsdGeom.Xform.Define(stage, "/Tree/Branch")
    export(stage, d / "reference_garbage_usdc.usda")
    edit(d / "reference_garbage_usdc.usda",
         lambda layer: layer.GetPrimAtPath("/Tree/Branch").referenceList.Prepend(Sdf.Reference("./layers/garbage.usdc")))
    (d / "layers").mkdir(exist_ok=True)
    (d / "layers" / "garbage.usdc").write_bytes(b"PXR-USDC" + _garbage(3000, SEED + 12))


CLEAN: list[Callable[[Path], None]] = [clean_minimal_tree, clean_y_up_centimetres, clean_forest_instancer, clean_layered_tree]
BAD: list[Callable[[Path], None]] = [
    bad_empty_file, bad_not_usd_text, bad_syntax_error, bad_empty_stage, bad_no_meshes, bad_no_leaf_meshes,
    bad_leaves_invisible, bad_nan_inf_points, bad_face_index_out_of_range, bad_face_with_two_vertices,
    bad_face_counts_mismatch, bad_degenerate_leaf_triangles, bad_zero_area_leaves, bad_leaf_mesh_without_points,
    bad_meters_per_unit_zero, bad_no_stage_metadata, bad_zero_scale_transform, bad_sun_zero_scale,
    bad_missing_sublayer, bad_missing_reference, bad_sublayer_cycle, bad_instancer_proto_index_out_of_range,
    bad_instancer_missing_prototype, bad_instancer_zero_scale, bad_instancer_nested, bad_instancer_prototype_is_instancer,
    bad_primvar_length_mismatch, bad_primvar_indices_out_of_range, bad_missing_vdb, bad_leaf_optics_attributes,
    bad_garbage_vdb, bad_meters_per_unit_huge, bad_up_axis_x, bad_sun_below_horizon, bad_projective_transform,
    bad_tiny_coordinates, bad_denormal_coordinates, bad_tiny_single_leaf, bad_sun_colour_nan, bad_sun_colour_negative,
    bad_dome_intensity_nan, bad_non_utf8_layer, bad_unknown_attribute_type, bad_unknown_xform_op, bad_payload_garbage,
    bad_reference_garbage_usdc,
]


def generate(out: Path) -> list[Path]:
    """Write ``out/clean`` and ``out/bad``; return the files written (sorted, relative to ``out``)."""
    for sub, makers in (("clean", CLEAN), ("bad", BAD)):
        d = out / sub
        d.mkdir(parents=True, exist_ok=True)
        for make in makers:
            make(d)
    return sorted(p.relative_to(out) for p in out.glob("*/**/*.usda"))


def main(argv: list[str]) -> int:
    out = Path(argv[1]) if len(argv) > 1 else HERE
    for p in generate(out):
        print(f"{p}  ({(out / p).stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

"""Odd assets (issue 18, cases 3 and 6): what a bake cannot handle, ``validate`` reports as an error and every command refuses.

Each asset is a small stage written with pxr by the ``odd_asset`` fixture:
the smallest valid tree (two leaf cards and a wood triangle) with one thing
broken. Before the fix these crashed the commands (exit 3: "Singular matrix",
"UFuncTypeError", "sun_dir ... (nan, nan, nan)") or were baked silently
(exit 0) while ``validate`` said "passed" or itself crashed.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from foliage_tools.errors import InputError
from foliage_tools.scene.read import read_scene
from foliage_tools.scene.validate import ERROR, validate
from tests.conftest import cards_mesh, write_mesh_stage
from tests.helpers.cli import foliage

WOOD = {"points": [(0, 0, 0), (0.05, 0, 0), (0, 0, 1.0)], "counts": [3], "indices": [0, 1, 2], "isLeaf": False}


def _tree(path: Path, *, leaves: dict | None = None, **kw) -> Path:
    if leaves is None:
        leaves = cards_mesh([(0.0, 0.0, 1.0), (0.5, 0.0, 1.2)])
    leaves = dict(leaves, isLeaf=True)
    return write_mesh_stage(path, {"Leaves": leaves, "Trunk": WOOD}, **kw)


def _edit(path: Path, fn) -> Path:
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    fn(stage)
    stage.GetRootLayer().Save()
    return path


def _scale(prim_path: str, s: float, *, double: bool = False):
    from pxr import Gf, UsdGeom

    def fn(stage):
        xf = UsdGeom.Xformable(stage.GetPrimAtPath(prim_path))
        if double:
            xf.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(s, s, s))
        else:
            xf.AddScaleOp().Set(Gf.Vec3f(s, s, s))

    return fn


def _scaled_light(stage):
    from pxr import Gf, UsdGeom, UsdLux

    UsdGeom.Xformable(UsdLux.DistantLight.Define(stage, "/Sun")).AddScaleOp().Set(Gf.Vec3f(0, 0, 0))


def _point_instancer_with_a_flat_instance(stage):
    from pxr import Gf, UsdGeom, Vt

    pi = UsdGeom.PointInstancer.Define(stage, "/Forest")
    pi.CreatePrototypesRel().SetTargets(["/Tree"])
    pi.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, 0), Gf.Vec3f(5, 0, 0)]))
    pi.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(1, 1, 1), Gf.Vec3f(0, 0, 0)]))
    pi.CreateProtoIndicesAttr([0, 0])
    stage.SetDefaultPrim(pi.GetPrim())


def _with_faces(counts):
    m = cards_mesh([(0.0, 0.0, 1.0), (0.5, 0.0, 1.2)])
    m["counts"] = counts  # still summing to the 8 indices, so only the face sizes are wrong
    return m


def _build(name: str, d: Path) -> Path:
    """The asset ``name`` in directory ``d``; returns the file to open."""
    from pxr import Sdf

    p = d / f"{name}.usda"
    if name == "leaf-mesh-scaled-to-0":
        return _edit(_tree(p), _scale("/Tree/Leaves", 0.0))
    if name == "tree-root-scaled-to-0":
        return _edit(_tree(p), _scale("/Tree", 0.0))
    if name == "tree-root-scaled-1e200":
        return _edit(_tree(p), _scale("/Tree", 1e200, double=True))
    if name == "zero-area-leaves":
        return _tree(p, leaves={"points": [(0, 0, 1)] * 4, "counts": [4], "indices": [0, 1, 2, 3]})
    if name == "point-instance-scaled-to-0":
        return _edit(_tree(p), _point_instancer_with_a_flat_instance)
    if name == "distant-light-scaled-to-0":
        return _edit(_tree(p), _scaled_light)
    if name == "negative-face-vertex-count":
        return _tree(p, leaves=_with_faces([4, 6, -2]))
    if name == "two-vertex-faces":
        return _tree(p, leaves=_with_faces([4, 2, 2]))
    if name == "meters-per-unit-0":
        return _tree(p, meters_per_unit=0.0)
    _tree(d / "base.usda")
    if name == "missing-sublayer":
        layer = Sdf.Layer.CreateNew(str(p))
        layer.subLayerPaths = ["base.usda", "gone.usda"]
        layer.Save()
        return p
    if name == "missing-reference":
        return _edit(_tree(p), lambda stage: stage.DefinePrim("/Other").GetReferences().AddReference("gone.usda"))
    if name == "sublayer-cycle":
        a, b = Sdf.Layer.CreateNew(str(p)), Sdf.Layer.CreateNew(str(d / "other.usda"))
        a.subLayerPaths = ["other.usda", "base.usda"]
        b.subLayerPaths.append(p.name)
        a.Save()
        b.Save()
        return p
    raise ValueError(name)


#: asset -> (validate rule, text both validate and the commands must print)
BAKEABLE = {  # issue 18 case 3: validate passed them, the commands crashed
    "leaf-mesh-scaled-to-0": ("transforms", "</Tree/Leaves> has a transform that scales by 0"),
    "tree-root-scaled-to-0": ("transforms", "</Tree> has a transform that scales by 0"),
    "tree-root-scaled-1e200": ("transforms", "</Tree> has a transform that scales by 1e+200"),
    "zero-area-leaves": ("leaf-area", "leaf mesh </Tree/Leaves> has zero area"),
    "point-instance-scaled-to-0": ("transforms", "1 instance(s) of point instancer </Forest> (first: index 1)"),
    "distant-light-scaled-to-0": ("transforms", "DistantLight </Sun> has a transform that scales by 0"),
    # issue 18 case 6: validate rejected (or crashed on) them, the commands baked them
    "negative-face-vertex-count": ("finite-geometry", "</Tree/Leaves> has 1 face(s) with fewer than 3 vertices"),
    "two-vertex-faces": ("finite-geometry", "</Tree/Leaves> has 2 face(s) with fewer than 3 vertices"),
    "meters-per-unit-0": ("stage-units", "metersPerUnit is 0"),
}
COMPOSITION = {  # issue 18 case 6: baked with only USD's raw warnings on stderr
    "missing-sublayer": "Could not load sublayer @gone.usda@",
    "missing-reference": "Could not open asset @gone.usda@ for reference",
    "sublayer-cycle": "has cycles",
}


@pytest.fixture
def odd_asset(request, tmp_path) -> Path:
    return _build(request.param, tmp_path)


@pytest.mark.parametrize("odd_asset", list(BAKEABLE), indirect=True)
def test_validate_and_the_scene_reader_refuse_the_same_asset_with_the_same_message(odd_asset):
    rule, text = BAKEABLE[odd_asset.stem]
    errors = [f for f in validate(odd_asset) if f.severity == ERROR and f.rule == rule]
    assert len(errors) == 1 and text in errors[0].message, [f.message for f in validate(odd_asset)]
    with pytest.raises(InputError) as exc:
        read_scene(odd_asset)
    assert text in str(exc.value) and errors[0].message in str(exc.value)


@pytest.mark.parametrize("odd_asset", list(COMPOSITION), indirect=True)
def test_an_asset_usd_cannot_compose_in_full_is_refused_naming_the_layer(odd_asset):
    text = COMPOSITION[odd_asset.stem]
    assert any(text in f.message for f in validate(odd_asset) if f.severity == ERROR)
    with pytest.raises(InputError) as exc:
        read_scene(odd_asset)
    assert text in str(exc.value) and odd_asset.name in str(exc.value) and "fix or remove the path" in str(exc.value)


@pytest.mark.parametrize("odd_asset", ["tree-root-scaled-to-0", "distant-light-scaled-to-0", "missing-sublayer"], indirect=True)
@pytest.mark.parametrize("command", ["inspect", "plan", "lb"])
def test_commands_exit_2_with_the_validate_message(odd_asset, command, tmp_path):
    out = ["-o", tmp_path / "out.usda"] if command == "lb" else []
    r = foliage(command, odd_asset, *out, "--json")
    assert r.returncode == 2, r.stderr
    error = json.loads(r.stdout)["error"]
    text = BAKEABLE.get(odd_asset.stem, (None, COMPOSITION.get(odd_asset.stem)))[1]
    assert text in error["message"] and str(odd_asset) in error["message"], error
    assert not (tmp_path / "out.usda").exists()


def _density_layer(tmp_path: Path) -> tuple[Path, Path]:
    """A ``foliage density`` output on the small tree: (layer, its .vdb), with the layer's file-hash record removed,
    as an upstream layer written by hand or by another tool would be (the record alone would otherwise report a
    changed .vdb as stale, before its values are read)."""
    from pxr import Sdf

    tree = _tree(tmp_path / "tree.usda")
    layer = tmp_path / "tree.density.usda"
    r = foliage("density", tree, "-o", layer, "--resolution", "8")
    assert r.returncode == 0, r.stderr
    sdf = Sdf.Layer.FindOrOpen(str(layer))
    sdf.customLayerData = {}
    sdf.Save()
    return layer, tmp_path / "tree.density.vdb"


def test_a_nan_voxel_in_an_upstream_vdb_is_exit_2_naming_the_file(tmp_path):
    import pyopenvdb as vdb

    layer, grid_file = _density_layer(tmp_path)
    grids = vdb.readAll(str(grid_file))[0]
    density = next(g for g in grids if g.name == "density")
    density.getAccessor().setValueOn(density.evalActiveVoxelBoundingBox()[0], float("nan"))
    vdb.write(str(grid_file), grids=grids)
    message = f"@{grid_file}@: grid 'density' holds 1 NaN or infinite voxel(s)"
    assert any(message in f.message for f in validate(layer) if f.rule == "volume-grids")
    r = foliage("lb", layer, "-o", tmp_path / "tree.lb.usda", "--resolution", "8")  # was exit 3, "must be finite"
    assert r.returncode == 2 and message in r.stderr and "internal error" not in r.stderr, r.stderr
    assert not (tmp_path / "tree.lb.usda").exists()


def test_a_missing_upstream_vdb_is_refused_with_validates_message(tmp_path):
    # the bake's layer sublayers the input, so a Volume field naming a missing .vdb would make its own output fail
    # validate: what validate fails, every bake refuses, in the same words (it was voxelized anew with a warning)
    layer, grid_file = _density_layer(tmp_path)
    grid_file.unlink()
    r = foliage("lb", layer, "-o", tmp_path / "tree.lb.usda", "--resolution", "8", "--json")
    assert r.returncode == 2, r.stderr
    message = json.loads(r.stdout)["error"]["message"]
    assert "@./tree.density.vdb@" in message and "does not exist" in message, message
    # one finding per field naming the file (density, woodFraction); the bake names the first and counts the rest
    found = [f for f in validate(layer) if f.severity == ERROR and "@./tree.density.vdb@" in f.message]
    assert len(found) == 2 and found[0].message.split("@./tree.density.vdb@")[-1] in message, (found, message)
    assert not (tmp_path / "tree.lb.usda").exists()


def test_invisible_leaves_are_a_validate_error_as_every_bake_refuses_them(tmp_path):
    # a leaf mesh that is invisible is left out by the reader (as renderers leave it out), so no bake finds a leaf;
    # validate said "passed" (a new user's trial)
    from pxr import UsdGeom

    tree = _edit(_tree(tmp_path / "tree.usda"), lambda stage: UsdGeom.Imageable(stage.GetPrimAtPath("/Tree/Leaves")).MakeInvisible())
    errors = [f for f in validate(tree) if f.severity == ERROR and f.rule == "leaf-meshes-found"]
    assert len(errors) == 1 and "</Tree/Leaves>" in errors[0].message and "invisible" in errors[0].message
    r = foliage("spp", tree, "-o", tmp_path / "o.usda")
    assert r.returncode == 2 and "invisible meshes" in r.stderr, r.stderr
    assert foliage("validate", tree).returncode != 0

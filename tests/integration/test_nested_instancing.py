"""validate's ``nested-instancing`` warning against what the reader places: a point instancer's prototype whose root
is itself a point instancer, or an instanceable prim whose prototype holds one, is a second level of instancing
that the bakes leave out, so validate warns; an instanceable prim as the prototype's root is one level, read
through, so validate says nothing."""

from __future__ import annotations

import json

import pytest

from tests.conftest import cards_mesh
from tests.helpers.cli import foliage

#: leaf cards per tree: each tree is one leaf mesh of this many cards (a card is one leaf)
CARDS = 2
GROVE = "/World/Forest/Prototypes/Grove"


def _tree(stage, root: str) -> None:
    from pxr import UsdGeom, Vt

    UsdGeom.Xform.Define(stage, root)
    m = cards_mesh([(0.3 * i, 0.0, 1.0) for i in range(CARDS)])
    mesh = UsdGeom.Mesh.Define(stage, f"{root}/Leaves")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(m["points"].astype("float32")))
    mesh.CreateFaceVertexCountsAttr(m["counts"])
    mesh.CreateFaceVertexIndicesAttr(m["indices"])


def _instancer(stage, path: str, proto: str, n: int) -> None:
    from pxr import Sdf, UsdGeom

    pi = UsdGeom.PointInstancer.Define(stage, path)
    pi.CreatePrototypesRel().SetTargets([Sdf.Path(proto)])
    pi.CreateProtoIndicesAttr([0] * n)
    pi.CreatePositionsAttr([(3.0 * i, 0.0, 0.0) for i in range(n)])
    _tree(stage, proto)


def _forest(path, grove: str):
    """/World/Forest places one Tree and one Grove; ``grove`` says what the Grove prototype is. Returns the path
    and the number of leaves the composed asset holds (what a flattened copy of it would place)."""
    from pxr import Sdf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Forest")
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Forest/Prototypes/Tree"), Sdf.Path(GROVE)])
    pi.CreateProtoIndicesAttr([0, 1])
    pi.CreatePositionsAttr([(0.0, 0.0, 0.0), (0.0, 10.0, 0.0)])
    _tree(stage, "/World/Forest/Prototypes/Tree")
    if grove == "instancer":  # the prototype's root is a point instancer of 3 trees
        _instancer(stage, GROVE, f"{GROVE}/Prototypes/Tree", 3)
        held = 1 + 3
    elif grove == "instance of an instancer":  # an instanceable reference to a prim holding a point instancer
        stage.CreateClassPrim("/Library")  # a class: referenced, not placed itself
        _instancer(stage, "/Library/Grove/Inner", "/Library/Grove/Inner/Prototypes/Tree", 3)
        prim = stage.DefinePrim(GROVE, "Xform")
        prim.GetReferences().AddInternalReference("/Library/Grove")
        prim.SetInstanceable(True)
        held = 1 + 3
    else:  # "instance": an instanceable reference to a plain tree
        stage.CreateClassPrim("/Library")
        _tree(stage, "/Library/Tree")
        prim = stage.DefinePrim(GROVE, "Xform")
        prim.GetReferences().AddInternalReference("/Library/Tree")
        prim.SetInstanceable(True)
        held = 1 + 1
    stage.GetRootLayer().Save()
    return path, held * CARDS


def _placed_leaves(path) -> int:
    r = foliage("inspect", path, "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)["stats"]["leaves_total"]


@pytest.mark.parametrize("grove", ["instancer", "instance of an instancer"])
def test_a_second_level_of_instancing_at_or_under_a_prototype_root_is_warned_about(tmp_path, grove):
    """The independent fact: the reader places fewer leaves than the composed asset holds (it reads one level of
    instancing), so geometry is left out and validate must warn, naming the file and the prim holding the second
    level (the Grove's root, or its instancer seen through the instance). Before the fix validate skipped the
    prototype's root and did not look inside an instanceable root: both passed without a word."""
    path, held = _forest(tmp_path / "forest.usda", grove)
    assert _placed_leaves(path) < held  # Grove's 3 trees are not placed
    r = foliage("validate", path.name, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    warned = [line for line in r.stdout.splitlines() if "[nested-instancing]" in line]
    assert len(warned) == 1, r.stdout
    inner = GROVE if grove == "instancer" else f"{GROVE}/Inner"
    assert f"<{inner}>" in warned[0] and "@forest.usda@" in warned[0], warned[0]
    assert foliage("validate", path, "--strict").returncode == 1


def test_an_instanceable_prototype_root_is_read_so_not_warned_about(tmp_path):
    """The independent fact: the reader places every leaf the composed asset holds when the prototype's root is an
    instanceable reference (it reads through it: one level), so validate has nothing to warn about."""
    path, held = _forest(tmp_path / "forest.usda", "instance")
    assert _placed_leaves(path) == held
    r = foliage("validate", path)
    assert r.returncode == 0 and "[nested-instancing]" not in r.stdout, r.stdout + r.stderr

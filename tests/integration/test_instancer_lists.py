"""Point instancers whose per-instance lists do not line up: validate names them (rule ``instancers``, exit 1) and
the commands that read them refuse them with the same message (exit 2); none crashes (a new user's trial found
exit 3 for each of these before session 19's checks)."""

import pytest

from tests.helpers.cli import foliage


def _instancer(path, edit):
    """A PointInstancer of 3 instances of one 20-leaf prototype, changed by ``edit(instancer)``."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    inst = UsdGeom.PointInstancer.Define(stage, "/World/Forest")
    tree = UsdGeom.Xform.Define(stage, "/World/Forest/Prototypes/Tree")
    mesh = UsdGeom.Mesh.Define(stage, "/World/Forest/Prototypes/Tree/Leaves")
    pts = [(0.2 * i, 0.1 * (i % 3), 1.0 + dz) for i in range(20) for dz in (0.0, 0.05, 0.1)]
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr([3] * 20)
    mesh.CreateFaceVertexIndicesAttr(list(range(60)))
    inst.CreatePrototypesRel().SetTargets([tree.GetPath()])
    inst.CreatePositionsAttr([(0, 0, 0), (5, 0, 0), (0, 5, 0)])
    inst.CreateProtoIndicesAttr([0, 0, 0])
    edit(inst)
    stage.Save()
    return path


def _quats(n):
    from pxr import Gf, Vt

    return Vt.QuathArray([Gf.Quath(1.0, 0.0, 0.0, 0.0)] * n)


CASES = {
    "short_positions": (lambda i: i.GetPositionsAttr().Set([(0, 0, 0)]), "has 1 positions for its 3 protoIndices"),
    "long_positions": (lambda i: i.GetPositionsAttr().Set([(0, 0, 0)] * 4), "has 4 positions for its 3 protoIndices"),
    "short_orientations": (lambda i: i.CreateOrientationsAttr(_quats(1)), "has 1 orientations for its 3"),
    "short_scales": (lambda i: i.CreateScalesAttr([(1, 1, 1)]), "has 1 scales for its 3"),
    "itself_as_prototype": (lambda i: i.GetPrototypesRel().SetTargets([i.GetPath()]), "itself or a prim above it"),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_misaligned_instancer_is_named_by_validate_and_refused_by_inspect(tmp_path, name):
    edit, says = CASES[name]
    path = _instancer(tmp_path / f"{name}.usda", edit)
    v = foliage("validate", path)
    assert v.returncode == 1 and "[instancers]" in v.stdout and says in v.stdout, v.stdout + v.stderr
    i = foliage("inspect", path)
    assert i.returncode == 2 and says in i.stderr and f"{name}.usda" in i.stderr, i.stdout + i.stderr


def test_an_instancer_with_no_instances_is_not_an_error(tmp_path):
    """protoIndices and positions both empty: a legal instancer placing nothing (it crashed validate, exit 3)."""
    def empty(i):
        i.GetProtoIndicesAttr().Set([])
        i.GetPositionsAttr().Set([])

    path = _instancer(tmp_path / "empty.usda", empty)
    v = foliage("validate", path)
    assert v.returncode in (0, 1) and "internal error" not in v.stderr, v.stdout + v.stderr
    assert "[instancers]" not in v.stdout


def test_list_rules_needs_no_scene_and_names_the_new_rules():
    r = foliage("validate", "--list-rules")
    assert r.returncode == 0, r.stderr
    names = {line.split(":")[0] for line in r.stdout.splitlines() if ":" in line}
    assert {"instancers", "nested-instancing", "empty-meshes", "transforms"} <= names, names
    missing = foliage("validate")
    assert missing.returncode == 2 and "Missing argument 'SCENE'" in missing.stderr

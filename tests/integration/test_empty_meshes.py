"""A mesh without points or faces, said the same way by validate and by the reader: unauthored or an empty array,
the reader skips it with a warning, so validate warns (``empty-meshes``, naming the file, the prim and what is
missing) and raises no error about it; when it is the only leaf mesh, every bake refuses the asset, so validate
errs (``leaf-meshes-found``)."""

from __future__ import annotations

import json

import pytest

from tests.conftest import cards_mesh, write_mesh_stage
from tests.helpers.cli import foliage

#: how the "Twig" mesh of 2 faces is emptied, and what the message must say it lacks
CASES: dict[str, tuple[str, list | None, str]] = {
    "points unauthored": ("points", None, "2 face(s) but no points (points is not authored)"),
    "points empty": ("points", [], "2 face(s) but no points (points is empty)"),
    "indices empty": ("faceVertexIndices", [], "8 point(s) and 2 face(s) but no face vertex indices (faceVertexIndices is empty)"),
    "no faces": ("faceVertexCounts", [], "8 point(s) but no faces (faceVertexCounts is empty)"),
}


def _tree(path, attribute: str | None, value, *, leaf: bool = False):
    """A tree of one good leaf mesh (3 cards) and a "Twig" mesh of 2 cards (a leaf mesh when ``leaf``), whose
    ``attribute`` is then cleared (``value`` None) or set to ``value``."""
    from pxr import Usd

    leaves = cards_mesh([(0.0, 0.0, 1.0), (0.3, 0.0, 1.1), (0.6, 0.0, 1.2)])
    leaves["isLeaf"] = True
    twig = cards_mesh([(0.0, 0.5, 0.5), (0.3, 0.5, 0.6)])
    twig["isLeaf"] = leaf
    meshes = {"Twig": twig} if leaf else {"Leaves": leaves, "Twig": twig}
    write_mesh_stage(path, meshes)
    if attribute is not None:
        stage = Usd.Stage.Open(str(path))
        attr = stage.GetPrimAtPath("/Tree/Twig").GetAttribute(attribute)
        attr.Clear() if value is None else attr.Set(value)
        stage.GetRootLayer().Save()
    return path


def _inspect(path) -> dict:
    r = foliage("inspect", path, "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_empty_mesh_is_one_warning_as_the_reader_skips_it(tmp_path, case):
    """The independent fact: the reader (inspect) skips the emptied mesh with a warning and reads the rest (exit 0;
    the Twig among no prototype's meshes), so validate's one finding about it is a warning that names the file and
    what the mesh lacks. Before: an empty ``points`` array was an error (finite-geometry) while unauthored points
    were a warning, and the warning said "no points or faces" whatever was missing."""
    attribute, value, lacks = CASES[case]
    path = _tree(tmp_path / "tree.usda", attribute, value)
    report = _inspect(path)
    read = [m for p in report["stats"]["prototypes"] for m in p["leaf_meshes"] + p["wood_meshes"]]
    assert "/Tree/Twig" not in read and "/Tree/Leaves" in read, read
    assert any("</Tree/Twig>" in w and "skipped" in w for w in report["warnings"]), report["warnings"]
    r = foliage("validate", path.name, "--json", cwd=tmp_path)
    findings = json.loads(r.stdout)["stats"]["findings"]
    about = [f for f in findings if f["prim"] == "/Tree/Twig"]
    assert [(f["severity"], f["rule"]) for f in about] == [("warning", "empty-meshes")], findings
    assert about[0]["message"].startswith("@tree.usda@: mesh </Tree/Twig> has " + lacks + ";"), about[0]["message"]
    assert r.returncode == 0, r.stdout


def test_a_lone_empty_leaf_mesh_is_an_error_as_every_bake_refuses_the_asset(tmp_path):
    """The independent fact: with its only leaf mesh empty the asset holds no leaf, and a bake (density) refuses it
    (exit 2), so validate must fail it (exit 1) rather than pass it with a warning."""
    path = _tree(tmp_path / "tree.usda", "points", None, leaf=True)
    bake = foliage("density", path, "-o", tmp_path / "d.usda")
    assert bake.returncode == 2, bake.stderr
    # and the refusal names the skipped mesh and what it lacks, not "mark your leaf meshes" (it is marked)
    assert "</Tree/Twig>" in bake.stderr and "no points" in bake.stderr, bake.stderr
    assert "FoliageLeafAPI" not in bake.stderr, bake.stderr
    r = foliage("validate", path.name, "--json", cwd=tmp_path)
    assert r.returncode == 1, r.stdout
    rules = {(f["severity"], f["rule"]) for f in json.loads(r.stdout)["stats"]["findings"]}
    assert ("error", "leaf-meshes-found") in rules and ("warning", "empty-meshes") in rules, rules

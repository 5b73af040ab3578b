"""An asset whose sublayer or reference is missing: validate, inspect and bake say so once, in their own words,
naming the missing file as the asset names it (relative to the asset's folder); USD's own warnings about it (with
absolute paths and the C++ source line of the diagnostic) are logged for ``-vv`` instead of printed."""

from __future__ import annotations

import pytest

from tests.conftest import cards_mesh, write_mesh_stage
from tests.helpers.cli import foliage

MISSING = {"sublayer": "./missing_layer.usda", "reference": "./missing_branch.usda",
           # a reference into a folder that is missing too (its path was once left absolute)
           "reference-elsewhere": "../elsewhere/missing_branch.usda"}


def _asset(folder, kind: str):
    """``folder/assets/tree.usda``: a small tree whose root layer sublayers, or whose </Tree/Branch> references,
    ``MISSING[kind]`` (authored on the layer alone, so nothing is composed while writing it)."""
    from pxr import Sdf

    leaves = cards_mesh([(0.0, 0.0, 1.0), (0.3, 0.0, 1.1)])
    leaves["isLeaf"] = True
    (folder / "assets").mkdir()
    path = write_mesh_stage(folder / "assets" / "tree.usda", {"Leaves": leaves})
    layer = Sdf.Layer.FindOrOpen(str(path))
    if kind == "sublayer":
        layer.subLayerPaths.append(MISSING[kind])
    else:
        branch = Sdf.CreatePrimInLayer(layer, "/Tree/Branch")
        branch.specifier = Sdf.SpecifierDef
        branch.referenceList.Prepend(Sdf.Reference(MISSING[kind]))
    layer.Save()
    return path


@pytest.mark.parametrize("kind", sorted(MISSING))
@pytest.mark.parametrize("command", ["validate", "inspect", "bake"])
def test_a_missing_dependency_is_reported_once_relative_to_the_asset(tmp_path, kind, command):
    """The independent fact: the asset names the missing file ``./missing_....usda`` (written so above) and it is
    not on disk; the command, run from the folder above the asset's, must report that path as the asset names it
    (not as the current folder or USD's resolver sees it), once, and print nothing of USD's own. Before: USD's
    warnings (``Warning: in _ReportErrors at line ... of .../stage.cpp -- ... @/abs/path@``) came first on stderr,
    and every message held the absolute path."""
    path = _asset(tmp_path, kind)
    assert not (path.parent / MISSING[kind]).exists()
    args = {"validate": (), "inspect": (), "bake": ("-o", "out")}[command]
    r = foliage(command, "assets/tree.usda", *args, cwd=tmp_path)
    assert r.returncode == (1 if command == "validate" else 2), r.stdout + r.stderr
    text = r.stdout + r.stderr
    assert f"@{MISSING[kind]}@" in text, text
    for leak in (str(tmp_path), "Warning: in", ".cpp", "assets/missing"):
        assert leak not in text, text
    if command == "validate":
        assert r.stderr == "" and "[usdValidation:CompositionErrorTest]" in r.stdout, r.stdout + r.stderr
    else:  # the one error, naming the asset (without USD's "; skipping.": the asset is refused)
        assert "skipping" not in r.stderr, r.stderr
        assert r.stderr.startswith("error: @assets/tree.usda@: ") and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_usds_own_warning_is_there_with_vv(tmp_path):
    """Captured, not lost: ``-vv`` (debug logging) shows what USD said."""
    _asset(tmp_path, "sublayer")
    r = foliage("inspect", "assets/tree.usda", "-vv", cwd=tmp_path)
    assert r.returncode == 2 and "USD: Could not load sublayer" in r.stderr, r.stderr

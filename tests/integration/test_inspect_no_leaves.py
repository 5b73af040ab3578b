"""``foliage inspect`` warns when the asset holds no leaf the bakes would find, saying what a leaf is for this tool
and how to mark one; a tree with leaves gets no such warning."""

from __future__ import annotations

import json

from tests.conftest import cards_mesh, write_mesh_stage
from tests.helpers.cli import foliage


def _tree(path, *, leaves: bool):
    """A trunk triangle and a mesh of 2 cards named "Cards", marked a leaf mesh (primvars:foliage:isLeaf) or not:
    nothing else (name, material, FoliageLeafAPI) says leaf."""
    cards = cards_mesh([(0.0, 0.0, 1.0), (0.3, 0.0, 1.1)])
    if leaves:
        cards["isLeaf"] = True
    trunk = {"points": [(0, 0, 0), (0.05, 0, 0), (0, 0, 1.0)], "counts": [3], "indices": [0, 1, 2]}
    return write_mesh_stage(path, {"Trunk": trunk, "Cards": cards})


def test_inspect_warns_on_a_tree_without_leaves_that_every_bake_refuses(tmp_path):
    """The independent fact: a bake (density) refuses the asset for want of leaves (exit 2), so inspect, which shows
    what the bakes will see, must not print "0 leaves" silently: it warns, naming the file and saying what makes a
    leaf mesh. Before, it exited 0 with no warning."""
    path = _tree(tmp_path / "tree.usda", leaves=False)
    bake = foliage("density", path, "-o", tmp_path / "d.usda")
    assert bake.returncode == 2 and "no leaves found" in bake.stderr, bake.stderr
    r = foliage("inspect", "tree.usda", cwd=tmp_path)
    assert r.returncode == 0 and "0 leaves placed" in r.stdout, r.stdout + r.stderr
    warned = [line for line in r.stderr.splitlines() if line.startswith("warning:") and "leaf" in line]
    assert len(warned) == 1, r.stderr
    for says in ("@tree.usda@", "none of the 2 mesh(es) read is a leaf mesh", "FoliageLeafAPI",
                 "primvars:foliage:isLeaf = true", "needle"):
        assert says in warned[0], warned[0]
    report = json.loads(foliage("inspect", path, "--json").stdout)
    assert any("is a leaf mesh" in w for w in report["warnings"]), report["warnings"]


def test_inspect_says_nothing_about_leaves_on_a_tree_with_leaves(tmp_path):
    """The independent fact: the same tree with its cards marked (isLeaf) bakes (density exit 0), so no warning."""
    path = _tree(tmp_path / "tree.usda", leaves=True)
    assert foliage("density", path, "-o", tmp_path / "d.usda").returncode == 0
    report = json.loads(foliage("inspect", path, "--json").stdout)
    assert report["stats"]["leaves_total"] == 2 and report["warnings"] == [], report

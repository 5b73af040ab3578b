"""A stage whose upAxis would lay its tree on its side (a Z-up tree written Y-up): inspect, validate and the bakes
warn, naming the axis the trunk shows; a tree standing along its upAxis gets no such warning."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers.cli import foliage

CORPUS = Path(__file__).resolve().parents[1] / "corpus" / "clean"


def test_a_z_up_tree_written_y_up_is_warned_about_everywhere(tmp_path):
    tree = tmp_path / "sideways.usda"
    # the minimal tree's trunk runs 0-1.6 along Z under leaves from 1.58 to 2.66: it stands along +Z
    tree.write_text((CORPUS / "minimal_tree.usda").read_text().replace('upAxis = "Z"', 'upAxis = "Y"'))
    r = foliage("inspect", tree)
    assert r.returncode == 0 and "lies on its side" in r.stderr and "stands along +Z" in r.stderr, r.stderr
    r = foliage("validate", tree, "--strict", "--json")
    found = [f for f in json.loads(r.stdout)["stats"]["findings"] if f["rule"] == "upright"]
    assert r.returncode == 1 and len(found) == 1 and found[0]["severity"] == "warning", r.stdout
    assert "upAxis to Z" in found[0]["message"]
    assert foliage("validate", tree).returncode == 0  # a warning: fails only --strict


def test_trees_standing_along_their_up_axis_are_not_warned_about():
    for name in ("minimal_tree.usda", "y_up_centimetres.usda", "forest_instancer.usda", "layered_tree.usda"):
        r = foliage("validate", CORPUS / name, "--strict")
        assert r.returncode == 0 and "upright" not in r.stdout, (name, r.stdout)

"""An instance placed so far from the origin that single-precision coordinates (the ray tracer's) cannot hold its
leaves is refused by validate and every bake with one message; a stand kilometres out is still baked."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers.cli import foliage

TREE = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
FOREST = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Z"
)
def Xform "World"
{{
    def PointInstancer "Forest"
    {{
        rel prototypes = [</World/Forest/Protos/Tree>]
        int[] protoIndices = [0, 0]
        point3f[] positions = [(0, 0, 0), ({far}, 0, 0)]
        def Scope "Protos"
        {{
            def Xform "Tree" (references = @{tree}@</Tree>)
            {{
            }}
        }}
    }}
}}
"""


def test_an_instance_where_float32_cannot_hold_its_leaves_is_refused_in_one_message(tmp_path):
    # at 1e25 the float32 step is 1.2e18 units; the minimal tree's leaves are 0.2 wide (it baked with exit 0, its
    # second instance's light computed from triangles collapsed to a point)
    stand = tmp_path / "far.usda"
    stand.write_text(FOREST.format(far="1e25", tree=TREE))
    v = foliage("validate", stand, "--json")
    found = [f for f in json.loads(v.stdout)["stats"]["findings"] if f["rule"] == "geometry-scale"]
    assert v.returncode == 1 and len(found) == 1 and "</World/Forest[1]>" in found[0]["message"], v.stdout
    r = foliage("lb", stand, "-o", tmp_path / "o.usda", "--resolution", "8", "--json")
    assert r.returncode == 2 and json.loads(r.stdout)["error"]["message"] == found[0]["message"], r.stdout
    assert not (tmp_path / "o.usda").exists()


def test_a_stand_kilometres_from_the_origin_is_still_accepted(tmp_path):
    # at 1e4 the float32 step is 1.2e-3 units, a 170th of a 0.2 leaf
    stand = tmp_path / "near.usda"
    stand.write_text(FOREST.format(far="1e4", tree=TREE))
    assert foliage("validate", stand).returncode == 0

"""A reference in which no sun path can reach a second leaf has E_scattered = 0 exactly: it is reported as a result
with its bound (no hit in N paths, the rule of three), not as a failed accuracy check; a zero from too few paths is
still refused, with advice above what already ran."""

from __future__ import annotations

import json
import re

from pxr import Usd

from tests.helpers.cli import foliage

# one flat square leaf, 0.2 x 0.2 m, 2 m up, no wood: a light path leaving it can never come back to a leaf
ONE_LEAF = """#usda 1.0
(
    defaultPrim = "Tree"
    metersPerUnit = 1
    upAxis = "Z"
)

def Xform "Tree" (
    kind = "component"
)
{
    def Mesh "Leaves"
    {
        uniform bool doubleSided = 1
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-0.1, -0.1, 2), (0.1, -0.1, 2), (0.1, 0.1, 2.05), (-0.1, 0.1, 2.05)]
    }
}
"""


def test_a_single_flat_leaf_has_zero_scattered_light_reported_with_its_bound(tmp_path):
    tree = tmp_path / "leaf.usda"
    tree.write_text(ONE_LEAF)
    out = tmp_path / "leaf.ref.usda"
    r = foliage("reference", tree, "-o", out, "--paths", "200000", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    note = next(w for w in report["warnings"] if "written as 0" in w)
    # the bound is 3 / (photons that reached the leaf directly, each path split at its first hit): positive, and
    # below the 1 % at which a zero is resolved
    bound = float(re.search(r"below ([0-9.e+-]+) of the direct light", note).group(1))
    assert 0 < bound <= 0.01, note
    stage = Usd.Stage.Open(str(out))
    leaves = stage.GetPrimAtPath("/Tree/Leaves")
    scattered = leaves.GetAttribute("primvars:foliage:ref:scattered").Get()
    direct = leaves.GetAttribute("primvars:foliage:ref:direct").Get()
    assert list(scattered[0]) == [0.0, 0.0, 0.0]
    assert min(direct[0]) > 0.1  # the sun reaches it: the zero is of scattered light, not of samples


def test_a_zero_from_too_few_paths_is_refused_with_advice_above_what_ran(tmp_path):
    tree = tmp_path / "leaf.usda"
    tree.write_text(ONE_LEAF)
    # 100 paths: at most 100 direct hits bound the scattered light only below 3/100 > 1 %
    r = foliage("reference", tree, "-o", tmp_path / "r.usda", "--paths", "100", "--json")
    assert r.returncode == 1, r.stderr
    message = json.loads(r.stdout)["error"]["message"]
    need = int(re.search(r"Raise --paths to at least ([0-9,]+)", message).group(1).replace(",", ""))
    assert need >= 200, message
    assert list(tmp_path.iterdir()) == [tree]

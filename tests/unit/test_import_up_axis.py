"""``foliage import --up-axis auto``: the axis a tree stands along, from its geometry (the trunk's base is its lowest
point, the crown its highest), and a warning whenever the authored upAxis would lay it on its side."""

from __future__ import annotations


import numpy as np
import pytest

from foliage_tools.pipeline.import_model import ImportParams, run_import, stands_along
from foliage_tools.scene.meshfile import Part

from tests.conftest import ASSETS  # the third-party trees (../shared/assets or FOLIAGE_TEST_ASSETS)


def _tree(up: int = 2, sign: float = 1.0) -> list[Part]:
    """A 0.2 m square trunk 0-3 m and a 2 m crown of leaf points 2-4 m, standing along axis ``up`` (``sign`` < 0:
    on its head)."""
    rng = np.random.default_rng(1)
    trunk = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (0.0, 3.0)])
    crown = rng.uniform([-1.0, -1.0, 2.0], [1.0, 1.0, 4.0], size=(400, 3))

    def turned(p: np.ndarray) -> np.ndarray:
        p = p.copy()
        p[:, 2] *= sign
        return p[:, np.roll(np.arange(3), up - 2)] if up != 2 else p

    tris = np.zeros((1, 3), dtype=np.int32)
    return [Part("trunk", "", turned(trunk), tris, 1, False), Part("leaves", "", turned(crown), tris, 1, True)]


@pytest.mark.parametrize("up,sign,expect", [(2, 1.0, "+Z"), (1, 1.0, "+Y"), (0, 1.0, "+X"), (2, -1.0, "-Z"),
                                            (1, -1.0, "-Y")])
def test_a_tree_stands_along_the_axis_its_trunk_is_at_the_bottom_of(up, sign, expect):
    axis, why = stands_along(_tree(up, sign))
    # the leaves begin 2 m above the trunk's base in a 4 m tall tree: 50 % of the extent
    assert axis == expect and "50 %" in why, (axis, why)


def test_without_wood_the_clearly_tallest_extent_decides_and_a_cube_is_undecided():
    leaves = _tree(1)[1]
    tall = Part("leaves", "", leaves.points * np.array([1.0, 3.0, 1.0]), leaves.triangles, 1, True)
    assert stands_along([tall])[0] == "+Y"
    cube = Part("leaves", "", np.random.default_rng(2).uniform(-1, 1, (300, 3)), leaves.triangles, 1, True)
    axis, why = stands_along([cube])
    assert axis is None and "which way is up" in why


@pytest.mark.parametrize("asset,up", [("webots_oak/oak.obj", "Z"), ("webots_bigsassafras/big_sassafras.obj", "Z"),
                                      ("sapling_blendertree/blender_tree.obj", "Y")])
def test_the_real_trees_are_imported_upright_and_a_wrong_axis_is_warned_about(tmp_path, asset, up):
    source = ASSETS / asset
    if not source.is_file():
        pytest.skip(f"{source} is not there (../shared/assets is optional)")
    # the assets' README gives each tree's up axis, measured by whoever converted it, not by this code
    report = run_import(source, tmp_path / "t.usda", ImportParams())
    assert report.stats["up_axis"] == up and not [w for w in report.warnings if "upAxis" in w], report.warnings
    other = "Y" if up == "Z" else "Z"
    report = run_import(source, tmp_path / "u.usda", ImportParams(up_axis=other))
    assert report.stats["up_axis"] == other
    said = [w for w in report.warnings if "lie on its side" in w]
    assert len(said) == 1 and f"--up-axis {up}" in said[0], report.warnings

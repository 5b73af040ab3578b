"""The forest lattice where MAX_NODES leaves its grid coarse: the factors are divided by the grid's own bias.

The independent answer is the same stand's lattice at CELLS_PER_CROWN, uncapped: on the 5 x 5 stand of
test_stand.py its factors were within 1.4 % RMS of the Monte Carlo reference's (README), while at 8 cells per
crown they read +6.2 % (the coarse grid homogenises the gaps between crowns).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline import forest
from foliage_tools.pipeline.report import Silent
from foliage_tools.pipeline.stage import begin_bake

REPO = Path(__file__).resolve().parents[2]
SIDE = 6  # 36 instances: more than the 25 the calibration solves apart
CALIBRATION_INSTANCES = forest.CALIBRATION_INSTANCES


def _factors(scene, sun, max_nodes, monkeypatch, calibrate=True):
    monkeypatch.setattr(forest, "MAX_NODES", max_nodes)
    monkeypatch.setattr(forest, "CALIBRATION_INSTANCES", CALIBRATION_INSTANCES if calibrate else 10**9)
    forest._LAST.clear()
    fl = forest.forest_light(scene, sun, parse_leaf_optics(None))
    crown = float(np.ptp(scene.prototypes[0].leaves.centers, axis=0).max())
    return fl.factors[:, 1], crown / fl.grid.voxel_size


def test_a_capped_grid_is_calibrated_to_the_fine_one(tmp_path, monkeypatch):
    sys.path.insert(0, str(REPO / "examples"))
    from make_forest import plan_stand, tree_radius_of, write_forest

    tree = tmp_path / "tree_small.usda"
    shutil.copy(REPO / "examples" / "tree_small.usda", tree)
    path = write_forest(tmp_path / "stand.usda", tree, plan_stand(side=SIDE, tree_radius=tree_radius_of(tree), seed=3))
    _, scene, sun = begin_bake("bench", path, None, (30.0, 45.0), Silent())
    fine, cells = _factors(scene, sun, 10**8, monkeypatch)
    assert cells > 0.99 * forest.CELLS_PER_CROWN  # uncapped: no calibration
    coarse, cells = _factors(scene, sun, 30_000, monkeypatch, calibrate=False)
    assert cells < 10  # capped to the coarse regime where the bias is several per cent
    calibrated, _ = _factors(scene, sun, 30_000, monkeypatch)
    raw, cal = coarse / fine, calibrated / fine
    # the precondition: the capped grid is off (measured +6 % at 8 cells on the 5 x 5 stand)
    assert abs(raw.mean() - 1) > 0.03, raw.mean()
    # The calibration divides every factor by the bias of the 25 instances nearest the centre, of the 36 here: it
    # removes the stand's mean bias up to how much the window's differs from the whole stand's (centre against
    # edges), allowed up to 30 % of the bias itself; no instance ends farther off than the worst raw one, and
    # the spread over instances falls with the mean. (Measured at 6.2 / 8.2 / 10.3 cells: mean +0.6-0.8 %
    # against the raw +6.0-8.5 %, RMS 0.018-0.021 against 0.062-0.087.)
    assert abs(cal.mean() - 1) < 0.3 * abs(raw.mean() - 1), (cal.mean(), raw.mean())
    assert np.abs(cal - 1).max() < np.abs(raw - 1).max()
    # and within 5 % for every instance: the uncapped lattice is within ~2.7 % of the reference per instance on
    # the 5 x 5 stand (README), so every instance stays inside the 10 % of the reference
    assert np.abs(cal - 1).max() < 0.05, np.abs(cal - 1).max()
    assert np.sqrt(np.mean((cal - 1) ** 2)) < 0.6 * np.sqrt(np.mean((raw - 1) ** 2))


def test_a_stand_of_one_leaf_cards_gets_cells_a_leaf_wide(tmp_path):
    """A prototype of one 0.1 m leaf card has a leaf box of no extent: the stand's cells are then CELLS_PER_CROWN
    across the leaf (sqrt of its area), so two cards 3 m apart make a lattice of ~3 m / (0.1 m / 24) = 720 cells
    along x and a few across (it was 944215 x 2 x 2 cells of 3e-6 m: 19 s and 2.5 GB)."""
    card = tmp_path / "cards.usda"
    card.write_text("""#usda 1.0
(
    defaultPrim = "Forest"
    metersPerUnit = 1
    upAxis = "Z"
)
def Xform "Forest"
{
    def PointInstancer "Stand"
    {
        rel prototypes = [</Forest/Stand/Protos/Card>]
        int[] protoIndices = [0, 0]
        point3f[] positions = [(0, 0, 0), (3, 0, 0)]
        def Scope "Protos"
        {
            def Xform "Card" (kind = "component")
            {
                def Mesh "leaves"
                {
                    point3f[] points = [(0, 0, 1), (0.1, 0, 1), (0.1, 0.1, 1), (0, 0.1, 1)]
                    int[] faceVertexCounts = [4]
                    int[] faceVertexIndices = [0, 1, 2, 3]
                }
            }
        }
    }
}
""")
    _, scene, _ = begin_bake("bench", card, None, (30.0, 45.0), Silent())
    grid = forest.stand_grid(scene)
    assert abs(grid.voxel_size - 0.1 / forest.CELLS_PER_CROWN) < 1e-6
    assert 700 <= grid.shape[0] <= 760 and max(grid.shape[1:]) <= 8

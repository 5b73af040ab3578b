"""``scene.write.VolumeEdit``: a placed volume's class must hold it, and placements need a class to reference."""

from pathlib import Path

import numpy as np
import pytest

from foliage_tools.scene.write import VolumeEdit, VolumePlacement

PLACED = (VolumePlacement(path="/W/FoliageBakes/Instances/T", transform=np.eye(4), instance="/W/T"),)


def test_placements_without_a_class_are_refused():
    with pytest.raises(ValueError, match="no class_prim"):
        VolumeEdit(path="/W/FoliageBakes/Prototypes/T/FoliageLighting", vdb_file=Path("x.vdb"), grids=(), placements=PLACED)


@pytest.mark.parametrize("class_prim", ["/W/Other", "/W/FoliageBakes/Prototypes/T/FoliageLighting"])
def test_the_class_must_be_an_ancestor_of_the_volume(class_prim):
    with pytest.raises(ValueError, match="must be an ancestor"):
        VolumeEdit(path="/W/FoliageBakes/Prototypes/T/FoliageLighting", vdb_file=Path("x.vdb"), grids=(),
                   class_prim=class_prim, placements=PLACED)


def test_a_class_held_volume_is_accepted():
    edit = VolumeEdit(path="/W/FoliageBakes/Prototypes/T/FoliageLighting", vdb_file=Path("x.vdb"), grids=(),
                      class_prim="/W/FoliageBakes/Prototypes/T", placements=PLACED)
    assert edit.placements == PLACED

"""``--resolution`` has one default and one range (``params.DEFAULT_RESOLUTION``, ``RESOLUTION_RANGE``), which every
bake command's option and every stage's parameters use (issue #20: "resolution=64 in 14 places", the CLI allowing
4-512 where the density parameters allowed 1-2048). A command or stage given its own literal would fail here when
the two disagree."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from foliage_tools.cli.main import cli
from foliage_tools.errors import UsageError
from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.params import DEFAULT_RESOLUTION, RESOLUTION_RANGE
from foliage_tools.pipeline.bake import BakeParams
from foliage_tools.pipeline.lb import LBBakeParams
from foliage_tools.pipeline.plan import PlanParams
from foliage_tools.pipeline.spp import SppParams

COMMANDS = ("density", "lb", "spp", "bake", "plan")


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_s_resolution_option_has_the_one_default_and_range(name):
    option = next(p for p in cli.commands[name].params if p.name == "resolution")
    assert option.default == DEFAULT_RESOLUTION  # density's gives way to --voxel-size (tests/integration/test_density.py)
    assert (option.type.min, option.type.max) == RESOLUTION_RANGE


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_s_help_gives_the_resolution_default_and_range_once(name):
    """A new user's trial: `foliage density --help` printed the range twice ("[default: 64; 4-512].  [4<=x<=512]")."""
    text = CliRunner().invoke(cli, [name, "--help"], terminal_width=100).output
    block = text[text.index("--resolution INTEGER RANGE"):]
    block = " ".join(block[:block.index("\n  -", 1)].split())  # the option's lines, up to the next option
    lo, hi = RESOLUTION_RANGE
    assert f"[default: {DEFAULT_RESOLUTION}; {lo}<=x<={hi}]" in block, block
    assert block.count(str(hi)) == 1 and block.count("default") == 1, block


def test_every_stage_refuses_the_same_resolutions_with_the_same_message():
    lo, hi = RESOLUTION_RANGE
    optics = parse_leaf_optics(None)
    stages = (lambda r: LBBakeParams(optics=optics, resolution=r), lambda r: SppParams(optics=optics, resolution=r),
              lambda r: PlanParams(resolution=r))
    for make in stages:
        make(lo), make(hi)  # the ends are allowed
        for bad in (lo - 1, hi + 1):
            with pytest.raises(UsageError, match=f"--resolution must be between {lo} and {hi}, got {bad}"):
                make(bad)
    assert {LBBakeParams(optics=optics).resolution, SppParams(optics=optics).resolution, PlanParams().resolution,
            BakeParams(optics=optics).resolution} == {DEFAULT_RESOLUTION}

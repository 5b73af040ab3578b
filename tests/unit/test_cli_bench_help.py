"""``foliage bench --help`` lists the bench registry's methods and families, generated from the registry."""

from __future__ import annotations

import re

from click.testing import CliRunner

from foliage_tools.bench import registry
from foliage_tools.cli.main import cli


def _help() -> str:
    result = CliRunner().invoke(cli, ["bench", "--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    return result.output


def test_help_lists_every_method_and_family():
    out = _help()
    names = [m.name for m in registry.methods()]
    listed = out[out.index("Methods:"):]
    for name in names:
        assert re.search(rf"^\s+{re.escape(name)}\s", listed, re.M), f"{name} is not listed in\n{listed}"
    fams = registry.families(names)
    # the registry lists methods sorted by name, and a family keeps that order; lb+gather is not an lb variant
    assert fams["lb"] == ["lb-32", "lb-32-march", "lb-64", "lb-64-lattice1", "lb-64-march"]
    for head, members in fams.items():
        assert re.search(rf"^\s+{re.escape(head)}\s+{re.escape(', '.join(members))}$", listed, re.M), listed


def test_a_method_that_lands_appears_in_the_help_without_editing_it():
    registry.methods()  # import the method modules first
    registry.register("zz-landed", "a method registered by this test")(lambda ctx: None)
    try:
        out = _help()
    finally:
        del registry._REGISTRY["zz-landed"]
    assert "zz-landed" in out and "a method registered by this test" in out
    assert re.search(r"^\s+zz\s+zz-landed$", out, re.M), out

"""A malformed .usda: every command says where USD's parser stopped (line and column), names the file, says what to
do, and exits 2 (bad input, DESIGN.md section 3)."""

from __future__ import annotations

import json

import pytest

from foliage_tools.errors import EXIT_BAD_INPUT, InputError
from foliage_tools.scene.read import open_stage
from tests.helpers.cli import foliage

BROKEN = """#usda 1.0
(
    defaultPrim = "Tree"
)

def Xform "Tree"
{
    def Mesh "Leaves" {{ oops
}
"""
# where the parser stops: the second brace of line 8 (1-based, as USD and editors count)
LINE, COLUMN = 8, BROKEN.splitlines()[7].index("{ oops") + 1


def test_open_stage_names_line_and_column(tmp_path):
    bad = tmp_path / "broken.usda"
    bad.write_text(BROKEN)
    with pytest.raises(InputError) as info:
        open_stage(bad)
    message = str(info.value)
    assert message.startswith(f"@{bad}@, line {LINE}, column {COLUMN}: "), message
    assert "Expected" in message and "Fix the file at that place" in message
    assert "pxrInternal" not in message  # USD's C++ source positions are not the user's


@pytest.mark.parametrize("args", [("inspect",), ("validate",), ("smax", "-o", "out.usda")])
def test_commands_exit_2_with_the_position(tmp_path, args):
    bad = tmp_path / "broken.usda"
    bad.write_text(BROKEN)
    r = foliage(args[0], bad, *args[1:], "--json", cwd=tmp_path)
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    error = json.loads(r.stdout)["error"]
    assert error["code"] == EXIT_BAD_INPUT and f"broken.usda@, line {LINE}, column {COLUMN}" in error["message"], error
    assert not (tmp_path / "out.usda").exists()

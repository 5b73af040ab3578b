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


UNCLOSED = """#usda 1.0

def Mesh "Leaf"
{
    int[] faceVertexCounts = [3, 3

    # the next statement: where USD's parser finds out that the list above never closed
    int[] faceVertexIndices = [0, 1, 2, 0, 2, 3]
}
"""


def test_an_unclosed_list_is_placed_where_its_bracket_is_missing(tmp_path):
    """The independent fact: the text itself, whose only fault is the ']' missing at the end of the
    faceVertexCounts line (line and column counted here from the string, 1-based as editors count). USD's parser
    notices it only at the next statement, three lines on; the message gives the place to fix, and what USD saw."""
    bad = tmp_path / "unclosed.usda"
    bad.write_text(UNCLOSED)
    lines = UNCLOSED.splitlines()
    line = next(k for k, text in enumerate(lines, 1) if "faceVertexCounts" in text)
    column = len(lines[line - 1].rstrip()) + 1  # just after "[3, 3"
    with pytest.raises(InputError) as info:
        open_stage(bad)
    message = str(info.value)
    assert message.startswith(f"@{bad}@, line {line}, column {column}: not valid USD text: "), message
    assert "']'" in message and "</Leaf.faceVertexCounts>" in message and "faceVertexIndices" in message, message
    assert "pxrInternal" not in message and "Sdf_TextFileFormatParser" not in message, message


def test_a_file_that_is_not_usd_text_is_named_without_usds_source_positions(tmp_path):
    """The independent fact: the file is OBJ text, not USD; what USD says about it (not a valid usda layer) is the
    useful part, while the C++ function, source file and line of USD's own diagnostics say nothing about the file."""
    bad = tmp_path / "mesh.usda"
    bad.write_text("# an OBJ file\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = foliage("inspect", "mesh.usda", cwd=tmp_path)
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    assert r.stderr.startswith("error: @mesh.usda@: cannot be opened as USD") and "not a valid usda layer" in r.stderr, r.stderr
    for internal in (".cpp", "at line", "pxrInternal", "Error in", str(tmp_path)):
        assert internal not in r.stderr, r.stderr

"""Tables on stdout in a pipe (a CI log, ``| cat``, ``| grep``): one line per row, nothing folded.

A new user's trial piped ``foliage plan`` and ``foliage inspect`` and got prim paths and headings broken across
lines ("prototyp / e"): rich fits a table to 80 columns (or ``$COLUMNS``) when stdout is not a terminal. The
commands run for real here, in a subprocess whose stdout is a pipe, at 60 columns.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.cli import foliage

FOREST = Path(__file__).resolve().parents[2] / "examples" / "forest_small.usda"


@pytest.fixture(autouse=True)
def narrow(monkeypatch):
    monkeypatch.setenv("COLUMNS", "60")


def _line_with(text: str, *words: str) -> str:
    lines = [line for line in text.splitlines() if all(w in line for w in words)]
    assert lines, f"no line holds all of {words} in\n{text}"
    return lines[0]


def test_inspect_in_a_pipe_prints_each_prototype_on_one_line():
    r = foliage("inspect", FOREST)
    assert r.returncode == 0, r.stderr
    _line_with(r.stdout, "prototype", "kind", "inst.", "leaves", "leaf tris", "wood tris", "leaf area", "size")
    _line_with(r.stdout, "/World/Trees/Tree_00", "instance", "16", "1500", "3000", "2268", "2.38×2.42×4.01")


def test_plan_in_a_pipe_prints_rows_and_sentences_whole():
    r = foliage("plan", FOREST, "--resolution", "16")
    assert r.returncode == 0, r.stderr
    _line_with(r.stdout, "/World/Trees/Tree_00", "16", "1500", "GB", "reference")
    _line_with(r.stdout, "density", "smax", "direct (rays; once per bake)", "peak memory")
    _line_with(r.stdout, "forest: 16 instances", "the reference would hold")

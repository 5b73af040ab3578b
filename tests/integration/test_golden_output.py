"""Golden text of ``foliage inspect`` and ``foliage validate`` on the oak asset (after usdchecker's baseline tests).

To update after an intended change: run with FOLIAGE_UPDATE_GOLDEN=1 and review the diff.
"""

import os
from pathlib import Path

import pytest

from tests.helpers.cli import foliage

GOLDEN = Path(__file__).resolve().parents[1] / "golden"


@pytest.mark.parametrize("command", ["inspect", "validate"])
def test_text_output_matches_golden(command, oak, monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    # a relative path, so the text does not depend on where the assets live
    r = foliage(command, oak.name, cwd=oak.parent)
    assert r.returncode == 0, r.stderr
    text = r.stdout
    golden = GOLDEN / f"{command}_oak.txt"
    if os.environ.get("FOLIAGE_UPDATE_GOLDEN"):
        golden.write_text(text)
    assert text == golden.read_text()

"""Inputs that try to make a command read, copy or report files it was not asked to, and values read as the wrong thing."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from tests.helpers.cli import foliage

CORPUS = Path(__file__).resolve().parents[1] / "corpus"
TREE = CORPUS / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")


def _tree_with(tmp_path: Path, layer_data: str = "", name: str = "tree.usda", text: str | None = None) -> Path:
    """The minimal tree with ``layer_data`` added to its customLayerData."""
    text = TREE.read_text() if text is None else text
    if layer_data:
        text = text.replace('string "foliage:generator" = "tests/corpus/generate.py"',
                            'string "foliage:generator" = "tests/corpus/generate.py"\n        ' + layer_data, 1)
    out = tmp_path / name
    out.write_text(text)
    return out


# -- a forged bake record (customLayerData foliage.files) --------------------------------------------------------------

@pytest.fixture
def secret(tmp_path: Path) -> Path:
    victim = tmp_path / "outside" / "secret.txt"
    victim.parent.mkdir()
    victim.write_text("not for foliage to read\n")
    return victim


def _forged(tmp_path: Path, entry: str) -> Path:
    folder = tmp_path / "in"
    folder.mkdir()
    return _tree_with(folder, f'dictionary foliage = {{ dictionary files = {{ string "{entry}" = "sha256:00" }} }}')


@pytest.mark.parametrize("entry", ["../outside/secret.txt", "SECRET_ABS", "./../outside/secret.txt"])
def test_forged_record_is_refused_without_reading_the_file(tmp_path: Path, secret: Path, entry: str) -> None:
    entry = str(secret) if entry == "SECRET_ABS" else entry
    tree = _forged(tmp_path, entry)
    leaked = hashlib.sha256(secret.read_bytes()).hexdigest()[:12]
    v = foliage("validate", tree, "--json")
    assert v.returncode == 1, v.stderr
    messages = [f["message"] for f in json.loads(v.stdout)["stats"]["findings"] if f["rule"] == "bake-files-match"]
    assert len(messages) == 1 and "not one foliage wrote" in messages[0] and f"@{tree}@" in messages[0], messages
    assert leaked not in v.stdout + v.stderr
    b = foliage("bake", tree, "-o", tmp_path / "out", *FAST, "-q")
    assert b.returncode == 2, b.stderr
    assert messages[0] in b.stderr and leaked not in b.stdout + b.stderr


# -- a forged batch.json -----------------------------------------------------------------------------------------------

def test_batch_cache_hit_needs_the_assets_own_outputs_under_outroot(tmp_path: Path) -> None:
    outputs = ["../victim.txt", "/etc/hostname", "tree/../../victim.txt"]
    tree = _tree_with(tmp_path)
    root = tmp_path / "root"
    first = foliage("batch", tree, "-o", root, *FAST, "--json")
    assert first.returncode == 0, first.stderr
    (tmp_path / "victim.txt").write_text("victim\n")
    record = json.loads((root / "batch.json").read_text())
    record["assets"]["tree"]["outputs"] = outputs
    (root / "batch.json").write_text(json.dumps(record))
    (root / "tree").rename(tmp_path / "moved")
    dry = foliage("batch", tree, "-o", root, *FAST, "--dry-run", "--json")
    assert dry.returncode == 0, dry.stderr
    entry = json.loads(dry.stdout)["stats"]["assets"]["tree"]
    assert entry["action"] == "bake" and "not one foliage wrote" in entry["reason"], entry
    again = foliage("batch", tree, "-o", root, *FAST, "--json")
    assert again.returncode == 0, again.stderr
    report = json.loads(again.stdout)
    assert report["stats"]["assets"]["tree"]["status"] == "baked"
    for out in report["outputs"]:
        assert Path(out).resolve().is_relative_to(root.resolve()), report["outputs"]
    assert (root / "tree" / "tree.lb.usda").is_file()

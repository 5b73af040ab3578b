"""Every command makes the folder its ``-o`` file goes into (as ``bake`` makes OUTDIR), before the work; a run that
fails removes again the folders it made, and never one that was there before."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.cli import foliage

CORPUS = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
OBJ = "o leaves\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nf 1 2 3 4\n"


@pytest.mark.parametrize("command", [
    ("density", CORPUS, "--resolution", "8"),
    ("preview", CORPUS, "--size", "32x32", "--samples", "1"),
    ("import", "leaf.obj", "--all-leaves"),
])
def test_the_output_folder_is_made_when_missing(tmp_path, command):
    (tmp_path / "leaf.obj").write_text(OBJ)
    name, scene, *rest = command
    out = tmp_path / "new" / "deeper" / ("x.png" if name == "preview" else "x.usda")
    r = foliage(name, scene, "-o", out, *rest, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert out.is_file()


def test_a_failed_run_removes_the_folders_it_made_and_only_those(tmp_path):
    missing = tmp_path / "no_such_tree.usda"
    r = foliage("density", missing, "-o", tmp_path / "made" / "here" / "x.usda")
    assert r.returncode == 2 and "no_such_tree.usda" in r.stderr, r.stderr
    assert not (tmp_path / "made").exists()
    (tmp_path / "kept").mkdir()
    r = foliage("density", missing, "-o", tmp_path / "kept" / "sub" / "x.usda")
    assert r.returncode == 2
    assert (tmp_path / "kept").is_dir() and not (tmp_path / "kept" / "sub").exists()

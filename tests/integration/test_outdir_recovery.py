"""What a run finds in its output directory and follows: only the staging folders a foliage run leaves.

A planted commit journal or a staging folder that is a symbolic link must not
make the next run move, remove or overwrite anything outside the output
directory, nor anything its run did not stage: it is refused (exit 2, naming
the folder), and nothing moves.
"""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest

from foliage_tools.errors import OutputError
from foliage_tools.scene import atomic
from tests.helpers.cli import foliage
from tests.helpers.staging import dead_pid, plant_staging

MINIMAL = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"


def _tree(where: Path) -> Path:
    tree = where / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    return tree


def test_a_journal_naming_a_file_outside_outdir_is_refused_and_moves_nothing(tmp_path):
    work = tmp_path / "w"
    out = work / "out"
    out.mkdir(parents=True)
    tree = _tree(work)
    precious = work / "precious.txt"
    precious.write_text("precious\n")
    staging = plant_staging(out, "x.usda", ["../../precious.txt"])
    r = foliage("density", tree, "-o", out / "x.usda", "--resolution", "8", "--json")
    assert r.returncode == 2, r.stderr
    assert str(staging) in r.stderr and "rm -r" in r.stderr and "nothing was moved" in r.stderr, r.stderr
    assert json.loads(r.stdout)["error"]["code"] == 2
    assert precious.read_text() == "precious\n" and not (tmp_path / "precious.txt").exists()
    assert sorted(p.name for p in out.iterdir()) == [staging.name]  # nothing written, nothing removed


def test_a_staging_folder_that_is_a_symlink_is_refused_and_its_target_is_untouched(tmp_path):
    work = tmp_path / "w"
    out = work / "out"
    out.mkdir(parents=True)
    tree = _tree(work)
    victim = work / "victim"
    victim.mkdir()
    (victim / "a.txt").write_text("a\n")
    (victim / atomic.JOURNAL).write_text("a.txt\n")
    (victim / atomic.OWNER).write_text(f"{socket.gethostname()} {dead_pid()}\n")
    link = out / f".x.usda.tmp-{dead_pid()}-ab"
    link.symlink_to("../victim")
    r = foliage("density", tree, "-o", out / "x.usda", "--resolution", "8")
    assert r.returncode == 2, r.stderr
    assert str(link) in r.stderr and "symbolic link" in r.stderr, r.stderr
    assert sorted(p.name for p in victim.iterdir()) == sorted(["a.txt", atomic.JOURNAL, atomic.OWNER])
    assert (victim / "a.txt").read_text() == "a\n"
    assert sorted(p.name for p in out.iterdir()) == [link.name] and link.is_symlink()


@pytest.mark.parametrize("name", ["../a.txt", "/etc/hostname", "sub/a.txt", "..", ".", "a\0b", atomic.OWNER,
                                  atomic.JOURNAL, ".x.usda.tmp-1-ab", ".x.bake.lock"])
def test_a_journal_name_that_is_not_a_plain_file_name_is_refused(tmp_path, name):
    staging = plant_staging(tmp_path, "x.usda", [name])
    with pytest.raises(OutputError, match="not a file name inside"):
        atomic.recover(tmp_path, ["x.usda"], [])
    assert staging.is_dir() and atomic.pending_commits(tmp_path) == []


def test_a_staged_entry_that_is_a_symlink_is_refused(tmp_path):
    (tmp_path / "target.txt").write_text("t\n")
    staging = plant_staging(tmp_path, "x.usda", ["x.usda"], files={})
    (staging / "x.usda").symlink_to(tmp_path / "target.txt")
    with pytest.raises(OutputError, match="symbolic link or not a regular file"):
        atomic.recover(tmp_path, ["x.usda"], [])
    assert (tmp_path / "target.txt").read_text() == "t\n" and not (tmp_path / "x.usda").exists()


def test_a_well_formed_journal_is_still_finished(tmp_path):
    staging = plant_staging(tmp_path, "x.usda", ["x.vdb", "x.usda"])
    warnings: list[str] = []
    atomic.recover(tmp_path, ["x.usda"], warnings)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.usda", "x.vdb"] and not staging.exists()
    hidden_output = plant_staging(tmp_path, ".y.usda", [".y.usda"], files={".y.usda": "y\n"})  # -o .y.usda
    atomic.recover(tmp_path, [".y.usda"], warnings)
    assert (tmp_path / ".y.usda").read_text() == "y\n" and not hidden_output.exists()
    assert any("finished the write of an interrupted run" in w for w in warnings), warnings


def test_a_staging_folder_of_another_host_is_left_with_a_warning_naming_the_host(tmp_path):
    staging = plant_staging(tmp_path, "x.usda", ["x.usda"], host="render-node-7")
    warnings: list[str] = []
    atomic.recover(tmp_path, ["x.usda"], warnings)
    assert staging.is_dir() and not (tmp_path / "x.usda").exists()
    assert any("render-node-7" in w and str(staging) in w and "rm -r" in w for w in warnings), warnings


def test_a_layer_of_another_host_is_reported_by_the_command(tmp_path):
    work = tmp_path / "w"
    out = work / "out"
    out.mkdir(parents=True)
    tree = _tree(work)
    staging = plant_staging(out, "x.usda", [], host="render-node-7")
    r = foliage("density", tree, "-o", out / "x.usda", "--resolution", "8", "--json")
    assert r.returncode == 0, r.stderr
    assert any("render-node-7" in w for w in json.loads(r.stdout)["warnings"])
    assert staging.is_dir()

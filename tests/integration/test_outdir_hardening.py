"""What a command finds at its output names, its lock and its option file is checked before it is followed.

A staging folder's journal is followed only for the command's own planned outputs; a lock file is written only
when this run made it or it is a lone regular file; a staging folder with a pid no process can have, a symbolic
link that loops at an output name or at ``--config``, and an option file that is a FIFO are refused or skipped
(exit 2 at most, never exit 3 or a hang).
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

from tests.helpers.cli import foliage
from tests.helpers.staging import plant_staging

MINIMAL = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")


def _tree(where: Path) -> Path:
    where.mkdir(parents=True, exist_ok=True)
    tree = where / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    return tree


def _error(r) -> dict:
    doc = json.loads(r.stdout)
    assert isinstance(doc, dict), r.stdout
    return doc["error"]


def test_a_bake_journal_naming_the_input_is_refused_and_the_input_is_kept(tmp_path):
    out = tmp_path / "out"
    tree = _tree(out)  # the input inside OUTDIR, as in a pipeline that bakes beside its asset
    before = tree.read_bytes()
    staging = plant_staging(out, "tree.bake", ["tree.usda"], files={"tree.usda": "#usda 1.0\n(doc = \"planted\")\n"})
    r = foliage("bake", tree, "-o", out, *FAST, "--json")
    assert r.returncode == 2, r.stderr
    assert tree.read_bytes() == before
    assert staging.is_dir() and (staging / "tree.usda").exists()  # nothing moved
    assert str(staging) in _error(r)["message"]


def test_a_density_journal_naming_another_results_file_is_refused(tmp_path):
    work = tmp_path / "w"
    tree = _tree(work)
    results = work / "results"
    results.mkdir()
    other = results / "oak.lb.usda"
    other.write_text("oak's own result\n")
    staging = plant_staging(results, "tree.density.usda", ["oak.lb.usda"])
    r = foliage("density", tree, "-o", results / "tree.density.usda", "--resolution", "8", "--json")
    assert r.returncode == 2, r.stderr
    assert other.read_text() == "oak's own result\n"
    assert (staging / "oak.lb.usda").exists()
    assert "oak.lb.usda" in _error(r)["message"]


def test_a_density_journal_of_its_own_layer_and_grid_is_still_finished(tmp_path):
    work = tmp_path / "w"
    tree = _tree(work)
    results = work / "results"
    results.mkdir()
    plant_staging(results, "tree.density.usda", ["tree.density.vdb", "tree.density.usda"])
    # the killed run's commit is finished first (its layer is then replaced by this run's result)
    r = foliage("density", tree, "-o", results / "tree.density.usda", "--resolution", "8", "--json")
    assert r.returncode == 0, r.stderr
    assert any("finished the write of an interrupted run" in w for w in json.loads(r.stdout)["warnings"])


def test_a_hard_linked_lock_file_is_refused_and_its_other_name_is_not_written(tmp_path):
    out = tmp_path / "out"
    tree = _tree(tmp_path)
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("victim content\n")
    os.link(victim, out / ".tree.bake.lock")
    r = foliage("bake", tree, "-o", out, *FAST, "--json")
    assert r.returncode == 2, r.stderr
    assert victim.read_text() == "victim content\n"
    assert ".tree.bake.lock" in _error(r)["message"] and "hard links" in _error(r)["message"]


def test_a_fifo_at_the_lock_name_is_refused(tmp_path):
    out = tmp_path / "out"
    tree = _tree(tmp_path)
    out.mkdir()
    os.mkfifo(out / ".tree.bake.lock")
    r = foliage("bake", tree, "-o", out, *FAST, "--json")
    assert r.returncode == 2, r.stderr
    assert "not a regular file" in _error(r)["message"]


def test_a_staging_folder_with_a_pid_no_process_can_have_is_not_a_crash(tmp_path):
    work = tmp_path / "w"
    tree = _tree(work)
    out = work / "out"
    out.mkdir()
    staging = out / ".tree.density.usda.tmp-99999999999999999999999-ab"
    staging.mkdir()
    (staging / ".owner").write_text(f"{socket.gethostname()} 99999999999999999999999\n")
    r = foliage("density", tree, "-o", out / "tree.density.usda", "--resolution", "8", "--json")
    assert r.returncode == 0, r.stderr
    assert not staging.exists()  # no live process of this host: a dead run's unfinished work, removed


def _loop(at: Path) -> Path:
    at.symlink_to(at.name)  # a link to itself
    return at


def test_a_symbolic_link_loop_at_a_bake_output_is_exit_2_naming_it(tmp_path):
    tree = _tree(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    loop = _loop(out / "tree.lb.usda")
    r = foliage("bake", tree, "-o", out, *FAST, "--json")
    assert r.returncode == 2, r.stderr
    err = _error(r)["message"]
    assert str(loop) in err and "symbolic link that loops" in err


def test_a_symbolic_link_loop_at_density_and_preview_outputs_is_exit_2(tmp_path):
    tree = _tree(tmp_path)
    loop = _loop(tmp_path / "loop.usda")
    r = foliage("density", tree, "-o", loop, "--resolution", "8", "--json")
    assert r.returncode == 2, r.stderr
    assert "symbolic link that loops" in _error(r)["message"]
    png = _loop(tmp_path / "loop.png")
    r = foliage("preview", tree, "-o", png, "--json")
    assert r.returncode == 2, r.stderr
    assert "symbolic link that loops" in _error(r)["message"]


def test_a_config_that_is_a_symbolic_link_loop_is_exit_2_with_one_json_error(tmp_path):
    tree = _tree(tmp_path)
    loop = _loop(tmp_path / "loop1")
    r = foliage("density", tree, "-o", tmp_path / "d.usda", "--config", loop, "--json")
    assert r.returncode == 2, r.stderr
    assert "symbolic link that loops" in _error(r)["message"]


def test_a_config_that_is_a_fifo_is_refused_without_reading_it(tmp_path):
    tree = _tree(tmp_path)
    fifo = tmp_path / "opts.toml"
    os.mkfifo(fifo)
    r = foliage("density", tree, "-o", tmp_path / "d.usda", "--config", fifo, "--json")  # the old code blocked here
    assert r.returncode == 2, r.stderr
    assert "FIFO" in _error(r)["message"]


def test_own_names_are_the_planned_names_their_layers_grids_and_what_allow_accepts():
    from foliage_tools.scene import atomic

    own = atomic.own_names(["tree.lb.usda", "tree.png"], allow=lambda n: n.startswith("tree.input."))
    for name in ("tree.lb.usda", "tree.png", "tree.lb.vdb", "tree.lb.03_oak.vdb", "tree.lb.forest.vdb", "tree.input.bark.png"):
        assert own(name), name
    for name in ("tree.usda", "oak.lb.usda", "tree.vdb", "tree.lb.x.vdb", "tree.density.usda", "victim.txt"):
        assert not own(name), name

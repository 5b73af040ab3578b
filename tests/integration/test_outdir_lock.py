"""One run at a time writes a result into an output directory; an interrupted batch leaves nothing behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from foliage_tools.errors import OutputError
from foliage_tools.scene import atomic
from tests.helpers.cli import foliage
from tests.helpers.staging import visible

REPO = Path(__file__).resolve().parents[2]
MINIMAL = REPO / "tests" / "corpus" / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")


def test_a_second_run_on_the_same_result_is_refused_naming_the_first(tmp_path):
    with atomic.run_lock(tmp_path, "tree.bake"):
        with pytest.raises(OutputError, match=f"process {os.getpid()} on "):
            with atomic.run_lock(tmp_path, "tree.bake"):
                pass
        with atomic.run_lock(tmp_path, "other.bake"):  # another result in the same directory: no wait
            pass
    assert list(tmp_path.iterdir()) == []  # the lock file goes with the run
    with atomic.run_lock(tmp_path, "tree.bake"):  # and the result is free again
        pass


def test_a_lock_left_by_a_killed_run_is_taken_and_removed(tmp_path):
    (tmp_path / ".tree.bake.lock").write_text("elsewhere 1\n")  # no process holds it: the kernel dropped the lock
    with atomic.run_lock(tmp_path, "tree.bake"):
        assert (tmp_path / ".tree.bake.lock").read_text().split()[1] == str(os.getpid())
    assert list(tmp_path.iterdir()) == []
    (tmp_path / ".tree.bake.lock").write_text("")
    atomic.recover(tmp_path, ["tree.bake"], [])
    assert list(tmp_path.iterdir()) == []


def test_a_bake_into_an_outdir_another_bake_of_the_asset_holds_is_exit_2_and_writes_nothing(tmp_path):
    tree = tmp_path / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    out = tmp_path / "out"
    assert foliage("bake", tree, "-o", out, *FAST, "--sun", "30,50").returncode == 0
    before = visible(out)
    with atomic.run_lock(out, "tree.bake"):  # this test process stands for the other bake
        r = foliage("bake", tree, "-o", out, *FAST, "--sun", "200,40")
    assert r.returncode == 2, r.stderr
    assert f"process {os.getpid()}" in r.stderr and "another foliage run" in r.stderr, r.stderr
    assert visible(out) == before and sorted(p.name for p in out.iterdir()) == sorted(before)


def test_sigterm_to_a_batchs_process_group_leaves_no_staging_folder(tmp_path):
    tree = tmp_path / "in" / "tree.usda"
    tree.parent.mkdir()
    tree.write_bytes(MINIMAL.read_bytes())
    out = tmp_path / "out"
    env = dict(os.environ, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"))
    proc = subprocess.Popen([sys.executable, "-m", "foliage_tools", "batch", str(tree), "-o", str(out), "--workers", "1",
                             *FAST], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while not any(p.name.startswith(".tree.bake.tmp-") for p in (out / "tree").glob(".*")):
            assert proc.poll() is None and time.monotonic() < deadline, "the batch ended before its bake started"
            time.sleep(0.02)  # polling another process's progress, with a deadline
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    left = [p for p in out.rglob(".*")]
    assert left == [], left

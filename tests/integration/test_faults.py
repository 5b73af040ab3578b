"""Fault injection (issue 18): kills between renames, signals, full disks, read-only and mounted output directories.

Each test runs the real command or stage on real files. A process killed
outright is simulated by the commit's own test hook (scene.atomic: the
process sends itself SIGKILL just before rename N), so no test waits for
time to pass. Tests that need a tmpfs mount (root with CAP_SYS_ADMIN) skip,
saying so, where the machine does not allow it.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bake import BakeParams, run_bake
from foliage_tools.scene import atomic
from foliage_tools.scene.integrity import check_layers, digest
from tests.helpers.cli import foliage, signal_after_line
from tests.helpers.staging import as_if_dead, dead_pid, hidden, visible

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
BAKE_FILES = [f"tree_small.{n}" for n in
              ("density.usda", "density.vdb", "smax.usda", "spp.usda", "spp.vdb", "lb.usda", "lb.vdb", "png")]


def foliage_env(*args, env: dict, cwd=None) -> subprocess.CompletedProcess:
    full = dict(os.environ, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"), **env)
    return subprocess.run([sys.executable, "-m", "foliage_tools", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=full, timeout=300)


@contextlib.contextmanager
def tmpfs(where: Path, *, size: str = "16m", read_only: bool = False):
    """A tmpfs mounted at ``where`` (created), unmounted afterwards; skips the test where mounting is not allowed."""
    where.mkdir(exist_ok=True)
    opts = f"size={size}" + (",ro" if read_only else "")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root with CAP_SYS_ADMIN): {r.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


# --- one commit per result ---------------------------------------------------------------------------------------

def test_bake_over_a_directory_named_like_an_output_fails_before_any_work_and_writes_nothing(tmp_path):
    # issue 18, case 2: this used to exit 2 only after the whole bake, with five of eight outputs moved in
    out = tmp_path / "O"
    (out / "tree_small.lb.usda").mkdir(parents=True)
    r = foliage("bake", EXAMPLE, "-o", out, "--resolution", "16", "--json")
    assert r.returncode == 2, r.stderr
    assert "tree_small.lb.usda@ is a directory" in r.stderr and "Nothing was written" in r.stderr
    assert [p.name for p in out.iterdir()] == ["tree_small.lb.usda"] and list((out / "tree_small.lb.usda").iterdir()) == []
    assert json.loads(r.stdout)["error"]["code"] == 2


def test_lb_killed_between_its_grid_and_its_layer_is_refused_then_finished_by_the_next_run(tmp_path, simple_tree):
    out = tmp_path / "t.lb.usda"
    assert foliage("lb", simple_tree, "-o", out, "--resolution", "8").returncode == 0
    old = visible(tmp_path)
    # killed after the new t.lb.vdb is in place, before the layer: the old layer with the new grid
    r = foliage_env("lb", simple_tree, "-o", out, "--resolution", "10", env={atomic.KILL_ENV: "1"})
    assert r.returncode == -signal.SIGKILL
    state = visible(tmp_path)
    assert state["t.lb.usda"] == old["t.lb.usda"] and state["t.lb.vdb"] != old["t.lb.vdb"]
    v = foliage("validate", out)
    assert v.returncode == 1 and "bake-files-match" in v.stdout and "t.lb.vdb" in v.stdout and "stale" in v.stdout, v.stdout
    # a stage reading it refuses it too, naming the stale file
    s = foliage("spp", out, "-o", tmp_path / "s.usda", "--resolution", "8")
    assert s.returncode == 2 and "t.lb.usda@, the older, is stale" in s.stderr, s.stderr
    # the next run on the output finishes the interrupted commit first (then writes its own result)
    again = foliage("lb", simple_tree, "-o", out, "--resolution", "10", "--json")
    assert again.returncode == 0, again.stderr
    assert any("finished the write of an interrupted run" in w for w in json.loads(again.stdout)["warnings"])
    assert hidden(tmp_path) == [] and foliage("validate", out).returncode == 0


def test_the_stale_file_is_named_by_when_each_was_written_and_preview_refuses_the_pair(tmp_path, simple_tree):
    d = tmp_path / "d.usda"
    assert foliage("density", simple_tree, "-o", d, "--resolution", "8").returncode == 0
    shutil.copy(tmp_path / "d.vdb", tmp_path / "older.vdb")
    assert foliage("density", simple_tree, "-o", d, "--resolution", "10").returncode == 0
    shutil.copy(tmp_path / "older.vdb", tmp_path / "d.vdb")  # an old grid copied over the new one: its mtime is now
    v = foliage("validate", d)
    assert v.returncode == 1 and "d.vdb@, the older, is stale" in v.stdout, v.stdout
    p = foliage("preview", d, "-o", tmp_path / "p.png", "--method", "direct")
    assert p.returncode == 2 and "d.vdb@, the older, is stale" in p.stderr, p.stderr
    assert not (tmp_path / "p.png").exists()


def _bake_states(tmp_path: Path) -> tuple[dict, dict, list[Path]]:
    """An old bake, then a new one (another sun) with a copy of OUTDIR before each of its renames."""
    out = tmp_path / "out"
    optics = parse_leaf_optics(None)
    legacy = tmp_path / ".out.tmp-k2j4_x9a"  # what a killed bake of an earlier version left beside OUTDIR
    legacy.mkdir()
    report = run_bake(EXAMPLE, out, BakeParams(optics=optics, resolution=8, sun=(30.0, 50.0)))
    assert any(str(legacy) in w and "earlier foliage-tools version" in w for w in report.warnings), report.warnings
    assert legacy.is_dir()  # reported, not removed: its run may be alive (it has no process id)
    old = visible(out)
    snapshots = []

    def snapshot(index, staged, final):
        snap = tmp_path / f"kill{index}"
        shutil.copytree(out, snap)
        snapshots.append(snap)

    atomic.before_rename = snapshot
    try:
        run_bake(EXAMPLE, out, BakeParams(optics=optics, resolution=8, sun=(200.0, 40.0)))
    finally:
        atomic.before_rename = None
    return old, visible(out), snapshots


def test_a_bake_killed_at_any_rename_is_the_old_bake_or_the_new_one(tmp_path):
    from foliage_tools.scene.validate import validate

    old, new, snapshots = _bake_states(tmp_path)
    assert sorted(old) == sorted(new) == sorted(BAKE_FILES) and len(snapshots) == len(BAKE_FILES)
    assert all(old[n] != new[n] for n in BAKE_FILES)  # every file differs, so a mix is visible
    refused = 0
    for snap in snapshots:
        state = visible(snap)
        layers = [snap / n for n in state if n.endswith(".usda")]
        if state != old and state != new:
            # a mix: the final layer's stack refuses it (and so does `foliage validate`)
            assert check_layers(layers), f"{snap.name}: a mix nothing refuses"
            refused += 1
        warnings: list[str] = []
        as_if_dead(snap)
        atomic.recover(snap, ["tree_small.bake", *BAKE_FILES], warnings)
        assert visible(snap) == new and hidden(snap) == [], snap.name
        assert check_layers(layers) == []
    assert refused == len(snapshots) - 1  # all but the kill before the first rename (still the old bake)
    mixed = snapshots[len(snapshots) // 2]
    shutil.rmtree(mixed)
    shutil.copytree(tmp_path / "out", mixed)
    assert not [f for f in validate(mixed / "tree_small.lb.usda") if f.severity == "error"]


def test_a_bake_onto_a_mount_point_works(tmp_path):
    # issue 18, case 4: staging beside OUTDIR made the last step a rename across devices (EXDEV)
    with tmpfs(tmp_path / "mnt") as out:
        report = run_bake(EXAMPLE, out, BakeParams(optics=parse_leaf_optics(None), resolution=8))
        assert sorted(p.name for p in out.iterdir()) == sorted(BAKE_FILES)
        assert Path(report.stats["result"]) == out / "tree_small.lb.usda"
        assert foliage("validate", out / "tree_small.lb.usda").returncode == 0


def test_a_read_only_outdir_is_refused_before_any_work(tmp_path):
    with tmpfs(tmp_path / "ro", read_only=True) as out:
        r = foliage("bake", EXAMPLE, "-o", out, "--resolution", "16", "-v")
        assert r.returncode == 2 and str(out) in r.stderr and "Read-only file system" in r.stderr, r.stderr
        assert "reading" not in r.stderr  # refused before the first stage read the input (-v logs each step)
    assert list(tmp_path.iterdir()) == [tmp_path / "ro"]


# --- signals and what killed runs leave ------------------------------------------------------------------------

@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_interrupt_like_ctrl_c(tmp_path, sig):
    out = tmp_path / "r.usda"
    with subprocess.Popen(
        [sys.executable, "-m", "foliage_tools", "reference", str(EXAMPLE), "-o", str(out), "--paths", "400000000", "-v"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: (signal.signal(signal.SIGTERM, signal.SIG_DFL), signal.signal(signal.SIGHUP, signal.SIG_DFL)),
    ) as proc:
        # -v logs each step: signal once the tracing (and so the staging) has started
        _, err = signal_after_line(proc, "tracing", sig)
    assert proc.returncode == 130, err
    assert f"interrupted ({sig.name})" in err and "no output was written" in err
    assert list(tmp_path.iterdir()) == []


def test_sigterm_during_the_renames_is_held_until_the_result_is_whole(tmp_path, simple_tree):
    out = tmp_path / "d.usda"
    r = foliage_env("density", simple_tree, "-o", out, "--resolution", "8", env={atomic.KILL_ENV: "0:TERM"})
    assert r.returncode == 130, r.stderr
    assert "just after the outputs were written" in r.stderr and "d.vdb" in r.stderr
    assert sorted(visible(tmp_path)) == ["d.usda", "d.vdb", "tree.usda"] and hidden(tmp_path) == []
    assert foliage("validate", out).returncode == 0


def test_the_next_run_removes_what_killed_runs_left_and_says_so(tmp_path, simple_tree):
    out = tmp_path / "d.usda"
    killed = foliage_env("density", simple_tree, "-o", out, env={atomic.KILL_ENV: "0"})  # staged and journaled, not moved
    assert killed.returncode == -signal.SIGKILL and len(hidden(tmp_path)) == 1
    legacy = tmp_path / f".d.tmp-{dead_pid()}.vdb"  # an earlier version's temporary, left by SIGKILL
    legacy.write_bytes(b"partial")
    live = atomic.Commit(tmp_path, "d.usda")  # a run still going (this test process)
    try:
        r = foliage("density", simple_tree, "-o", out, "--json")
        assert r.returncode == 0, r.stderr
        warnings = json.loads(r.stdout)["warnings"]
        assert any("finished the write of an interrupted run" in w for w in warnings), warnings
        assert any(legacy.name in w and "removed" in w for w in warnings), warnings
        assert hidden(tmp_path) == [live.staging.name]
    finally:
        live.discard()


# --- under-sampling is never silent ------------------------------------------------------------------------------

def test_a_reference_without_one_scattered_path_fails_its_accuracy_check_and_writes_nothing(tmp_path):
    # issue 18, case 1: the two-halves noise is 0/0 then and read "noise 0.000", exit 0, all-zero E_scattered.
    # (4 paths of seed 0 happen to scatter onto no leaf of the example; 2 do.)
    r = foliage("reference", EXAMPLE, "-o", tmp_path / "r.usda", "--paths", "4", "--json")
    assert r.returncode == 1, r.stderr
    assert "accuracy check failed" in r.stderr and "cannot be measured" in r.stderr and "Raise --paths" in r.stderr
    report = json.loads(r.stdout)
    assert report["error"]["code"] == 1 and report["outputs"] == [] and "tree_small.usda" in report["error"]["message"]
    assert list(tmp_path.iterdir()) == []


def test_black_leaves_and_wood_scatter_nothing_and_zero_is_then_the_measured_answer(tmp_path):
    r = foliage("reference", EXAMPLE, "-o", tmp_path / "r.usda", "--paths", "4", "--leaf-optics", "0,0",
                "--wood-reflectance", "0", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["stats"]["noise_rel"] == 0.0 and report["stats"]["e_scattered_mean"] == [0.0, 0.0, 0.0]
    assert any("reached by no sun path" in w for w in report["warnings"])  # but E_direct is under-sampled: said


def test_few_paths_warn_that_most_leaves_got_none(tmp_path):
    r = foliage("reference", EXAMPLE, "-o", tmp_path / "r.usda", "--paths", "100", "--json")
    assert r.returncode == 0, r.stderr
    warnings = json.loads(r.stdout)["warnings"]
    assert any("under-sampled" in w for w in warnings)
    assert any("of 1,500 leaves were reached by no sun path" in w for w in warnings), warnings


def test_a_reference_that_ends_above_its_noise_target_is_exit_1_with_its_layer_written(tmp_path):
    out = tmp_path / "r.usda"
    r = foliage("reference", EXAMPLE, "-o", out, "--paths", "20000", "--noise", "0.05", "--json")
    assert r.returncode == 1, r.stderr
    report = json.loads(r.stdout)
    assert report["stats"]["noise_rel"] > 0.05 and report["outputs"] == [str(out)] and out.is_file()
    assert any("above --noise 0.05" in w for w in report["warnings"])
    assert "accuracy check failed" in r.stderr


# --- environment errors --------------------------------------------------------------------------------------------

def test_a_full_disk_is_exit_2_naming_the_file_and_leaves_nothing(tmp_path):
    # issue 18, case 7: disk full was an internal error (exit 3)
    with tmpfs(tmp_path / "small", size="64k") as out:
        r = foliage("density", EXAMPLE, "-o", out / "d.usda", "--resolution", "48", "--json")
        assert r.returncode == 2, r.stderr
        assert "d.usda" in r.stderr and "full" in r.stderr, r.stderr
        assert json.loads(r.stdout)["error"]["code"] == 2
        assert list(out.iterdir()) == []


@pytest.mark.parametrize("args, code", [
    (["density", "{tmp}/missing.usda", "-o", "{tmp}/o.usda"], 2),          # a FoliageError in the command
    (["density", "{tree}", "-o", "{tmp}/o.usda", "--method", "magic"], 2),  # refused by click before it runs
    (["nosuchcommand", "--json"], 2),
])
def test_json_always_prints_one_object_with_error_set(tmp_path, simple_tree, args, code):
    # issue 18, case 8: --json printed nothing on stdout for exit 2 or 3
    import jsonschema

    schema = json.loads((Path(__file__).resolve().parents[2] / "schemas" / "json" / "report.schema.json").read_text())
    r = foliage(*[a.format(tmp=tmp_path, tree=simple_tree) for a in args], *([] if "--json" in args else ["--json"]))
    assert r.returncode == code, r.stderr
    report = json.loads(r.stdout)  # exactly one object
    jsonschema.validate(report, schema)
    assert report["error"]["code"] == code and report["error"]["message"] and r.stderr


def test_a_file_name_too_long_is_exit_2_before_any_work(tmp_path, simple_tree):
    out = tmp_path / ("x" * 300 + ".usda")
    r = foliage("density", simple_tree, "-o", out)
    assert r.returncode == 2 and "file name is 305 bytes long" in r.stderr, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tree.usda"]
    assert digest(simple_tree)  # the input is still there and readable

"""Fault injection (issue 18): kills between renames, signals, full disks, read-only and mounted output directories.

Each test runs the real command or stage on real files. A process killed
outright is simulated by the commit's own test hook (scene.atomic: the
process sends itself SIGKILL just before rename N), so no test waits for
time to pass. Tests that need a tmpfs mount (root with CAP_SYS_ADMIN) skip,
saying so, where the machine does not allow it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
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


# --- the fault sweep: a bake stopped anywhere is the old result or the new one, and the next run is clean -------

MINIMAL = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")
MINIMAL_FILES = sorted(f"tree.{n}" for n in
                       ("density.usda", "density.vdb", "smax.usda", "spp.usda", "spp.vdb", "lb.usda", "lb.vdb", "png"))
OLD_SUN, NEW_SUN = "30,50", "200,40"
#: Words of the bake's progress lines on stderr, one or more per stage (``writing`` is each stage's commit).
STAGE_WORDS = ("direct sunlight", "voxelizing", "writing", "s_max for", "SPP/SPPG", "final gather",
               "lattice-Boltzmann", "rendering")


@dataclasses.dataclass(frozen=True)
class Fault:
    """Where a bake is stopped: a signal just before rename ``rename`` of its commit (the commit's test hook), or
    ``delay`` s after the ``nth`` progress line holding ``after`` (None: ``delay`` s after the process started)."""

    sig: str
    rename: int | None = None
    after: str | None = None
    nth: int = 1
    delay: float = 0.0

    def __str__(self) -> str:
        if self.rename is not None:
            return f"{self.sig}-at-rename-{self.rename}"
        where = "start" if self.after is None else f"{self.after.replace(' ', '_').replace('/', '_')}#{self.nth}"
        return f"{self.sig}-{self.delay:.2f}s-after-{where}"


def sweep(seed: int, signals: int) -> list[Fault]:
    """Every rename of the commit, killed (SIGKILL) and signalled (SIGTERM), and ``signals`` interrupts at times drawn
    from ``seed``: a stage's progress line (the 1st to 4th commit for ``writing``) plus up to 0.3 s, or up to 1.5 s
    after the start (the imports)."""
    rng = random.Random(seed)
    faults = [Fault(sig, rename=i) for i in range(len(MINIMAL_FILES)) for sig in ("KILL", "TERM")]
    for _ in range(signals):
        after = rng.choice([None, *STAGE_WORDS])
        faults.append(Fault(rng.choice(["INT", "TERM", "HUP"]), after=after,
                            nth=rng.randint(1, 4) if after == "writing" else 1,
                            delay=round(rng.uniform(0.0, 1.5 if after is None else 0.3), 2)))
    return faults


#: The default suite's points: the first, a middle and the last rename killed, one held signal, and signals in the
#: imports, in pyopenvdb's first import (0.05 s after the first "writing"), in each kind of stage and in the preview.
REPRESENTATIVE = [
    Fault("KILL", rename=0), Fault("KILL", rename=4), Fault("KILL", rename=len(MINIMAL_FILES) - 1),
    Fault("TERM", rename=3),
    Fault("INT", delay=0.15),
    Fault("TERM", after="writing", delay=0.05),
    Fault("HUP", after="voxelizing", delay=0.1),
    Fault("INT", after="writing", nth=3, delay=0.0),
    Fault("TERM", after="lattice-Boltzmann", delay=0.1),
    Fault("TERM", after="rendering", delay=0.2),
]


@pytest.fixture(scope="module")
def old_bake(tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """The input, a finished bake of it (the old result, to copy before each fault) and its files' digests."""
    base = tmp_path_factory.mktemp("sweep")
    tree = base / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    template = base / "old" / "out"
    template.parent.mkdir()
    r = foliage("bake", tree, "-o", template, *FAST, "--sun", OLD_SUN)
    assert r.returncode == 0, r.stderr
    assert sorted(visible(template)) == MINIMAL_FILES
    return tree, template, visible(template)


def _stop_bake(fault: Fault, tree: Path, out: Path) -> tuple[int, str, bool]:
    """Run the new bake into ``out`` and stop it at ``fault``; its exit code, its stderr and whether it was still running
    when signalled (a run that ended first cannot be interrupted)."""
    env = dict(os.environ, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"))
    if fault.rename is not None:
        env[atomic.KILL_ENV] = f"{fault.rename}:{fault.sig}"
    proc = subprocess.Popen([sys.executable, "-m", "foliage_tools", "bake", str(tree), "-o", str(out), *FAST,
                             "--sun", NEW_SUN], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    lines: list[str] = []
    seen = threading.Event()

    def read() -> None:
        count = 0
        for line in proc.stderr:
            lines.append(line)
            if fault.after is not None and fault.after in line:
                count += 1
                if count == fault.nth:
                    seen.set()
        seen.set()  # stderr ended: the run is over

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    alive = True
    try:
        if fault.rename is None:
            if fault.after is not None:
                assert seen.wait(timeout=240), f"{fault}: no progress line with {fault.after!r}"
            time.sleep(fault.delay)  # the fault's own time: where in the run the signal lands
            alive = proc.poll() is None
            if alive:
                proc.send_signal(getattr(signal, f"SIG{fault.sig}"))
        proc.wait(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=30)
    proc.stderr.close()
    return proc.returncode, "".join(lines), alive


def _is_new(out: Path, old: dict[str, str]) -> bool:
    """The whole new bake: every file there and none of them the old one's, and every layer's record of the files
    below it holds (so no file of another run is among them)."""
    state = visible(out)
    return (sorted(state) == MINIMAL_FILES and all(state[n] != old[n] for n in MINIMAL_FILES)
            and check_layers(out / n for n in MINIMAL_FILES) == [])


def _check_fault(fault: Fault, old_bake, where: Path, *, next_run: bool) -> None:
    tree, template, old = old_bake
    out = where / "out"
    shutil.copytree(template, out)
    code, err, alive = _stop_bake(fault, tree, out)
    state = visible(out)
    if fault.sig == "KILL":  # no process can react to SIGKILL: a mix is possible, and refused
        assert code == -signal.SIGKILL, err
        if state != old and not _is_new(out, old):
            assert check_layers(out / n for n in state), f"{fault}: a mix nothing refuses"
    else:
        assert "Traceback" not in err and "internal error" not in err, f"{fault}:\n{err[-3000:]}"
        assert code == 130 or (code == 0 and not alive), f"{fault}: exit {code}\n{err[-3000:]}"
        assert state == old or _is_new(out, old), f"{fault}: neither the old bake nor the new one: {sorted(state)}"
        assert hidden(out) == [], f"{fault}: left {hidden(out)}"
        if fault.rename is not None:  # held until the renames were done: the new result, whole
            assert code == 130 and _is_new(out, old) and "just after the outputs were written" in err, err
    assert sorted(p.name for p in where.iterdir()) == ["out"], f"{fault}: wrote beside OUTDIR"
    if next_run or fault.sig == "KILL":
        r = foliage("bake", tree, "-o", out, *FAST, "--sun", NEW_SUN)
        assert r.returncode == 0, f"{fault}: the next run failed\n{r.stderr}"
        assert _is_new(out, old) and hidden(out) == [], f"{fault}: the next run left {hidden(out)}"


@pytest.mark.parametrize("fault", REPRESENTATIVE, ids=str)
def test_a_bake_stopped_at_a_representative_point_is_old_or_new_and_the_next_run_is_clean(old_bake, tmp_path, fault):
    _check_fault(fault, old_bake, tmp_path, next_run=False)


@pytest.mark.slow  # ~36 bakes stopped and as many run again: ~8 min on 2 cores
@pytest.mark.parametrize("fault", sweep(seed=40, signals=20), ids=str)
def test_a_bake_stopped_anywhere_is_old_or_new_and_the_next_run_is_clean(old_bake, tmp_path, fault):
    _check_fault(fault, old_bake, tmp_path, next_run=True)

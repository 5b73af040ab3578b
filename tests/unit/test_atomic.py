"""One commit per result (scene.atomic, scene.integrity): killed at any rename, the output is the old result or the new one.

A SIGKILL between two renames leaves the directory exactly as it is at that
moment, so a hook that copies the directory before every rename gives every
state a kill can leave, in one run. Each such state must be the old result,
the new result, or a mix that the layer's record of its files refuses; and
after the next run's recovery it must be the old or the new result, with no
temporaries left. Real USD layers and OpenVDB files, no mocks.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from foliage_tools.errors import OutputError
from foliage_tools.scene import atomic
from foliage_tools.scene.integrity import check_layer, digest
from foliage_tools.scene.vdb import Grid
from foliage_tools.scene.write import LayerEdits, VolumeEdit, stage_metadata, write_layer
from tests.conftest import cards_mesh, write_mesh_stage
from tests.helpers.staging import as_if_dead, dead_pid, hidden, visible


def edits(out: Path, volumes: int, value: float) -> LayerEdits:
    vols = []
    for k in range(volumes):
        grid = Grid("density", np.full((2, 2, 2), value + k, np.float32), (0.0, 0.0, 0.0), 0.5, {})
        vdb = out.with_suffix(".vdb") if volumes == 1 else out.with_name(f"{out.stem}.{k:02d}_t{k}.vdb")
        vols.append(VolumeEdit(path=f"/Tree/T{k}/FoliageLighting", vdb_file=vdb, grids=(grid,),
                               attributes={"foliage:method": "density"}))
    return LayerEdits(volumes=vols)


def write(tree: Path, out: Path, volumes: int, value: float) -> dict[str, str]:
    """Write a result; {name: content hash} of its files."""
    written = write_layer(tree, out, edits(out, volumes, value), input_stage_meta=stage_metadata(tree))
    return {p.name: digest(p) for p in written}


def is_result(state: dict[str, str], result: dict[str, str]) -> bool:
    """Every file of ``result`` is there with its content (files of an older result may lie beside it)."""
    return all(state.get(name) == h for name, h in result.items())


@settings(max_examples=30, deadline=None)
@given(old_volumes=st.integers(0, 3), new_volumes=st.integers(1, 3), value=st.floats(0.5, 100.0))
def test_a_kill_at_any_rename_leaves_the_old_result_or_the_new_one(old_volumes, new_volumes, value):
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        tree = write_mesh_stage(tmp / "tree.usda", {"Leaves": {**cards_mesh([(0, 0, 1)]), "isLeaf": True}})
        out_dir = tmp / "out"
        out_dir.mkdir()
        out = out_dir / "tree.density.usda"
        old = write(tree, out, old_volumes, value) if old_volumes else {}
        snapshots = []

        def snapshot(index, staged, final):
            snap = tmp / f"snap{index}"
            shutil.copytree(out_dir, snap, symlinks=True)
            snapshots.append(snap)

        atomic.before_rename = snapshot
        try:
            new = write(tree, out, new_volumes, value + 1000.0)
        finally:
            atomic.before_rename = None
        assert len(snapshots) == new_volumes + 1  # one rename per grid file, then the layer
        assert is_result(visible(out_dir), new) and hidden(out_dir) == [] and check_layer(out) == []

        for snap in snapshots:
            state = visible(snap)
            layer = snap / out.name
            if layer.exists() and not ((old and is_result(state, old)) or is_result(state, new)):
                assert check_layer(layer), f"a mix that nothing refuses: {sorted(state)}"
            # the next run on this output finishes the interrupted commit
            warnings: list[str] = []
            as_if_dead(snap)
            atomic.recover(snap, [out.name], warnings)
            after = visible(snap)
            assert is_result(after, new), (snap.name, sorted(after))
            assert hidden(snap) == [] and check_layer(layer) == []
            assert any("finished the write of an interrupted run" in w for w in warnings), warnings


def test_a_run_killed_before_its_commit_leaves_the_old_result_and_its_staging_is_removed(tmp_path, simple_tree):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "o.usda"
    old = write(simple_tree, out, 1, 1.0)
    commit = atomic.Commit(out_dir, out.name)  # a run killed while writing: staged files, no journal
    commit.path(out.name).write_text("half a layer")
    commit.staging = None  # (killed: nothing cleans up)
    as_if_dead(out_dir)
    assert hidden(out_dir)
    warnings: list[str] = []
    atomic.recover(out_dir, [out.name], warnings)
    assert visible(out_dir) == old and hidden(out_dir) == []
    assert any("unfinished work of an interrupted run" in w for w in warnings)


def test_recovery_leaves_the_temporaries_of_live_runs_and_of_other_outputs_alone(tmp_path):
    mine = atomic.Commit(tmp_path, "a.usda")  # this process is alive
    (tmp_path / f".b.tmp-{dead_pid()}.vdb").write_text("another output's")
    legacy = tmp_path / f".a.tmp-{dead_pid()}.vdb"
    legacy.write_text("an earlier version's temporary of a.vdb")
    warnings: list[str] = []
    atomic.recover(tmp_path, ["a.usda"], warnings)
    assert mine.staging.is_dir() and not legacy.exists()
    assert sorted(hidden(tmp_path)) == sorted([mine.staging.name, next(p.name for p in tmp_path.iterdir() if p.name.startswith(".b."))])
    assert len(warnings) == 1 and legacy.name in warnings[0]
    mine.discard()


def test_commits_into_one_directory_are_serialised(tmp_path, monkeypatch):
    # another run's commit holds the directory's lock: this one must not interleave its renames with it
    monkeypatch.setattr(atomic, "LOCK_TIMEOUT", 0.0)
    fd = os.open(tmp_path, os.O_RDONLY | os.O_DIRECTORY)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        with pytest.raises(OutputError, match="another run"):
            with atomic.atomic_outputs([tmp_path / "a.bin", tmp_path / "a.txt"]) as temps:
                for t in temps.values():
                    t.write_text("x")
    finally:
        os.close(fd)
    assert list(tmp_path.iterdir()) == []


def test_an_output_name_taken_by_a_directory_is_refused_before_anything_moves(tmp_path):
    (tmp_path / "a.txt").mkdir()
    with pytest.raises(OutputError, match=r"a\.txt@ is a directory"):
        with atomic.atomic_outputs([tmp_path / "a.bin", tmp_path / "a.txt"]) as temps:
            for t in temps.values():
                t.write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]  # no a.vdb, no temporaries


def test_an_interrupt_during_the_renames_waits_until_the_result_is_whole(tmp_path):
    previous = signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt))
    atomic.before_rename = lambda index, staged, final: os.kill(os.getpid(), signal.SIGTERM) if index == 0 else None
    try:
        with pytest.raises(atomic.InterruptedAfterCommit) as info:
            with atomic.atomic_outputs([tmp_path / "a.bin", tmp_path / "a.txt"]) as temps:
                for t in temps.values():
                    t.write_text(t.name)
    finally:
        atomic.before_rename = None
        signal.signal(signal.SIGTERM, previous)
    assert info.value.paths == [tmp_path / "a.bin", tmp_path / "a.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "a.txt"]


def test_a_long_output_name_gets_a_staging_directory_that_fits(tmp_path):
    name = "x" * 240 + ".txt"  # valid (NAME_MAX 255), but .NAME.tmp-PID-TOKEN would not be
    with atomic.atomic_outputs([tmp_path / name]) as temps:
        temps[tmp_path / name].write_text("x")
    assert [p.name for p in tmp_path.iterdir()] == [name]

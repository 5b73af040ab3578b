"""``foliage batch``: many bakes on a real Dask cluster (no mocks), cached by content, failures isolated.

The inputs are copied to tmp_path first (they are edited there, never in
place): examples/tree_small.usda, with a sublayer added so that a test can
edit one, and the Webots oak and the Sapling tree from ../shared/assets. The
bakes are small (--resolution 16, 16 shadow rays per leaf) to keep the suite
fast; what is compared is bitwise.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from tests.conftest import ASSETS, REPO
from tests.helpers.typed_json import assert_typed_stats

SMALL = ("--resolution", "16", "--direct-samples", "16")
SOURCES = {
    "tree_small": REPO / "examples" / "tree_small.usda",
    "oak": ASSETS / "webots_oak" / "oak.usda",
    "blender_tree": ASSETS / "sapling_blendertree" / "blender_tree.usda",
}
NOTE = "tree_small_note.usda"
SCHEMA = json.loads((REPO / "schemas" / "json" / "report.schema.json").read_text())


def _env() -> dict:
    """The environment of every process a test starts: this checkout's foliage_tools first."""
    path = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    return dict(os.environ, PYTHONPATH=path, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"))


def foliage(*args, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "foliage_tools", *map(str, args)], capture_output=True, text=True,
                          env=_env(), timeout=timeout)


def copy_inputs(where: Path) -> dict[str, Path]:
    """The three assets under ``where``; tree_small gets a sublayer (``tree_small_note.usda``) to edit."""
    missing = [str(p) for p in SOURCES.values() if not p.exists()]
    if missing:
        pytest.skip(f"third-party assets not present at {ASSETS}: {missing}")
    where.mkdir(parents=True)
    text = SOURCES["tree_small"].read_text(encoding="utf-8")
    assert '    upAxis = "Z"\n' in text
    tree = where / "tree" / "tree_small.usda"
    tree.parent.mkdir()
    tree.write_text(text.replace('    upAxis = "Z"\n', f'    upAxis = "Z"\n    subLayers = [@./{NOTE}@]\n', 1), encoding="utf-8")
    (tree.parent / NOTE).write_text('#usda 1.0\n\nover "Tree"\n{\n    custom string foliage:note = "first"\n}\n', encoding="utf-8")
    paths = {"tree_small": tree}
    for name in ("oak", "blender_tree"):
        paths[name] = where / name / SOURCES[name].name
        paths[name].parent.mkdir()
        shutil.copy2(SOURCES[name], paths[name])
    return paths


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> dict[str, Path]:
    """One copy of the inputs, never edited, shared by the tests that do not edit them."""
    return copy_inputs(tmp_path_factory.mktemp("batch") / "inputs")


@pytest.fixture(scope="module")
def reference(pristine, tmp_path_factory) -> dict[str, Path]:
    """Three `foliage bake` runs of the pristine inputs, the results to match: {name: OUTDIR}.

    The command runs in this process (click's test runner: the same code as `foliage bake` but one interpreter
    start-up for all three, which the 2-core suite feels).
    """
    from click.testing import CliRunner

    from foliage_tools.cli.main import cli
    from foliage_tools.scene.schemas import register

    register()  # in this process, before any test opens a stage without it (USD would then ignore the schemas)

    root = tmp_path_factory.mktemp("reference")
    for name, path in pristine.items():
        r = CliRunner().invoke(cli, ["bake", str(path), "-o", str(root / name), *SMALL, "-q"])
        assert r.exit_code == 0, (name, r.output, r.exception)
    return {name: root / name for name in pristine}


def _foliage_values(layer: Path) -> dict:
    """Every ``foliage`` attribute of the composed bake (primvars, bake metadata), timings left out."""
    from foliage_tools.scene.schemas import register

    register()
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    values = {}
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            name = attr.GetName()
            if "foliage" in name and not name.endswith("seconds"):
                v = attr.Get()
                values[(str(prim.GetPath()), name)] = np.asarray(v) if hasattr(v, "__len__") and not isinstance(v, str) else v
    return values


def _grids(outdir: Path) -> dict:
    """Every grid of every .vdb in ``outdir``: {(file, grid): (active bounding box, voxel values)}."""
    import pyopenvdb as vdb

    grids = {}
    for f in sorted(outdir.glob("*.vdb")):
        for meta in vdb.readAllGridMetadata(str(f)):
            grid = vdb.read(str(f), meta.name)
            lo, hi = grid.evalActiveVoxelBoundingBox()
            if any(b < a for a, b in zip(lo, hi)):  # no active voxel (a grid of zeros: e.g. a base no leaf reads)
                grids[(f.name, meta.name)] = (None, np.zeros(0, np.float32))
                continue
            shape = tuple(int(b - a + 1) for a, b in zip(lo, hi))
            vec = isinstance(grid, vdb.Vec3SGrid)
            values = np.zeros(shape + ((3,) if vec else ()), dtype=np.float32)
            grid.copyToArray(values, ijk=lo)
            grids[(f.name, meta.name)] = (tuple(lo), values)
    return grids


def assert_same_bake(ours: Path, theirs: Path) -> None:
    """Bitwise the same primvars, bake attributes and grid voxels; the same files."""
    assert sorted(p.name for p in ours.iterdir()) == sorted(p.name for p in theirs.iterdir())
    layer = next(ours.glob("*.lb.usda"))
    a, b = _foliage_values(layer), _foliage_values(theirs / layer.name)
    assert a.keys() == b.keys() and len(a) > 20
    differ = [k for k in a if not np.array_equal(np.asarray(a[k]), np.asarray(b[k]))]
    assert not differ, differ[:5]
    ga, gb = _grids(ours), _grids(theirs)
    assert ga.keys() == gb.keys() and len(ga) >= 6
    differ = [k for k in ga if ga[k][0] != gb[k][0] or not np.array_equal(ga[k][1], gb[k][1])]
    assert not differ, differ


def batch(*args, timeout=600) -> tuple[subprocess.CompletedProcess, dict]:
    r = foliage("batch", *args, *SMALL, "--json", timeout=timeout)
    try:
        report = json.loads(r.stdout)
    except json.JSONDecodeError:
        raise AssertionError(f"no JSON on stdout (exit {r.returncode}): {r.stdout[-2000:]}\n{r.stderr[-4000:]}") from None
    jsonschema.validate(report, SCHEMA)
    if "error" not in report:  # an interrupted or refused batch's report has empty stats
        assert_typed_stats(report)
    return r, report


def statuses(report: dict) -> dict[str, str]:
    return {name: e["status"] for name, e in report["stats"]["assets"].items()}


def hidden_entries(outroot: Path) -> list[Path]:
    """Staging directories and temporaries anywhere under OUTROOT (a half-written result would leave them)."""
    return [p for p in outroot.rglob(".*")]


def test_batch_bakes_as_bake_does_caches_by_content_and_isolates_a_broken_asset(tmp_path, reference):
    inputs = copy_inputs(tmp_path / "inputs")
    broken = tmp_path / "inputs" / "broken.usda"
    broken.write_text("#usda 1.0\nthis is { not a USD layer\n", encoding="utf-8")
    out = tmp_path / "out"

    # 1. a local cluster of 2 workers bakes the three as `foliage bake` does; the broken one fails alone
    r, report = batch(*inputs.values(), broken, "-o", out, "--workers", "2", "-v")
    assert r.returncode == 1, r.stderr
    assert statuses(report) == {"tree_small": "baked", "oak": "baked", "blender_tree": "baked", "broken": "failed"}
    assert report["stats"]["workers"] == 2
    assert report["stats"]["dashboard"].startswith("http://") and f"Dask dashboard: {report['stats']['dashboard']}" in r.stderr
    error = report["stats"]["assets"]["broken"]["error"]
    assert error["code"] == 2 and "broken.usda" in error["message"]
    assert "failed: broken (exit 2)" in r.stderr and "broken.usda" in r.stderr
    for name, outdir in reference.items():
        assert_same_bake(out / name, outdir)
    record = json.loads((out / "batch.json").read_text())
    assert {n: e["status"] for n, e in record["assets"].items()} == statuses(report)
    for name in reference:
        e = record["assets"][name]
        assert e["outputs"] and all((out / o).is_file() for o in e["outputs"]) and e["seconds"] > 0 and e["error"] is None
    assert not hidden_entries(out)

    # 2. the same batch again: every asset is a cache hit, nothing is sent to a cluster
    r, report = batch(*inputs.values(), "-o", out)
    assert r.returncode == 0, r.stderr
    assert statuses(report) == {"tree_small": "cached", "oak": "cached", "blender_tree": "cached"}
    assert report["stats"]["workers"] is None
    keys = {n: e["key"] for n, e in report["stats"]["assets"].items()}
    assert keys == {n: record["assets"][n]["key"] for n in keys}
    again = json.loads((out / "batch.json").read_text())["assets"]
    assert again["broken"]["status"] == "failed"  # kept for its retry
    for name in reference:  # nothing ran for a cache hit: no time, worker or threads of the earlier bake
        assert again[name]["seconds"] == 0.0 and again[name]["worker"] is None and again[name]["threads"] == []
        assert again[name]["outputs"] == record["assets"][name]["outputs"]

    # 3. after an edit of tree_small's sublayer, --dry-run says tree_small alone would bake, and why; it writes nothing
    note = inputs["tree_small"].with_name(NOTE)
    note.write_text(note.read_text().replace('"first"', '"second"'), encoding="utf-8")
    before = (out / "batch.json").read_bytes()
    r, dry = batch(*inputs.values(), "-o", out, "--dry-run")
    assert r.returncode == 0, r.stderr
    assert {n: e["action"] for n, e in dry["stats"]["assets"].items()} == {"tree_small": "bake", "oak": "cached", "blender_tree": "cached"}
    assert NOTE in dry["stats"]["assets"]["tree_small"]["reason"]
    assert (out / "batch.json").read_bytes() == before


@pytest.mark.slow  # ~40 s: the default test above covers the same decision with --dry-run
def test_editing_a_sublayer_rebakes_that_asset_only_and_touching_a_file_rebakes_nothing(tmp_path):
    inputs = copy_inputs(tmp_path / "inputs")
    out = tmp_path / "out"
    r, first = batch(*inputs.values(), "-o", out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    os.utime(inputs["oak"], (time.time() + 10, time.time() + 10))  # its time only
    note = inputs["tree_small"].with_name(NOTE)
    note.write_text(note.read_text().replace('"first"', '"second"'), encoding="utf-8")
    r, report = batch(*inputs.values(), "-o", out, "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert statuses(report) == {"tree_small": "baked", "oak": "cached", "blender_tree": "cached"}
    assert NOTE in report["stats"]["assets"]["tree_small"]["reason"]
    assert report["stats"]["assets"]["tree_small"]["key"] != first["stats"]["assets"]["tree_small"]["key"]
    values = _foliage_values(out / "tree_small" / "tree_small.lb.usda")
    assert values[("/Tree", "foliage:note")] == "second"  # the rebake read the edit
    assert not hidden_entries(out)


def test_inputs_are_found_in_directories_and_manifests_and_bad_ones_are_exit_2(tmp_path):
    src = REPO / "examples" / "tree_small.usda"
    trees = tmp_path / "trees"
    (trees / "a").mkdir(parents=True)
    (trees / "b").mkdir()
    shutil.copy2(src, trees / "a" / "tree.usda")
    (trees / "a" / "tree.usda").write_text(src.read_text().replace('    upAxis = "Z"\n', '    upAxis = "Z"\n    subLayers = [@./look.usda@]\n', 1))
    (trees / "a" / "look.usda").write_text('#usda 1.0\nover "Tree"\n{\n}\n')
    shutil.copy2(src, trees / "b" / "pine.usda")
    out = trees / "baked"
    # a directory: its USD files, but not a sublayer of one of them, nor an earlier batch's outputs
    (out / "tree").mkdir(parents=True)
    shutil.copy2(src, out / "tree" / "stale.usda")
    r, report = batch(trees, "-o", out, "--dry-run")
    assert r.returncode == 0, r.stderr
    assert sorted(report["stats"]["assets"]) == ["pine", "tree"]
    assert all(e["action"] == "bake" and "not baked before" in e["reason"] for e in report["stats"]["assets"].values())
    # two files of one name would share OUTROOT/<name>/: refused, naming both
    shutil.copy2(src, trees / "b" / "tree.usda")
    r, report = batch(trees, "-o", out, "--dry-run")
    assert r.returncode == 2 and "a/tree.usda" in r.stderr and "b/tree.usda" in r.stderr and "manifest" in r.stderr
    # a manifest names them, with options per asset over its top-level keys and the flags
    manifest = tmp_path / "trees.toml"
    manifest.write_text('resolution = 20\n[[asset]]\npath = "trees/a/tree.usda"\nname = "tree_a"\n'
                        '[[asset]]\npath = "trees/b/tree.usda"\nname = "tree_b"\nresolution = 24\nsun = "120,35"\n')
    r, report = batch(manifest, "-o", out, "--dry-run", "--leaf-optics", "bright")
    assert r.returncode == 0, r.stderr
    a, b = report["stats"]["assets"]["tree_a"]["options"], report["stats"]["assets"]["tree_b"]["options"]
    assert (a["resolution"], a["sun"], b["resolution"], b["sun"]) == (20, None, 24, [120.0, 35.0])
    assert a["optics"]["reflectance"] == b["optics"]["reflectance"] == [0.45] * 3  # the flag, under both
    # a key foliage bake does not know, and a value it refuses, name the manifest and the asset
    manifest.write_text('[[asset]]\npath = "trees/a/tree.usda"\nresolutoin = 20\n')
    r = foliage("batch", manifest, "-o", out)
    assert r.returncode == 2 and "trees.toml" in r.stderr and "[[asset]] 1" in r.stderr and "resolutoin" in r.stderr
    manifest.write_text('[[asset]]\npath = "trees/a/tree.usda"\nresolution = 2\n')
    r = foliage("batch", manifest, "-o", out)
    assert r.returncode == 2 and "[[asset]] 1" in r.stderr and "--resolution" in r.stderr
    r = foliage("batch", tmp_path / "nope.usda", "-o", out)
    assert r.returncode == 2 and "nope.usda" in r.stderr
    r, report = batch(tmp_path / "nope.usda", "-o", out)  # --json: the refused batch's report names what it was given
    assert r.returncode == 2 and report["inputs"] == [str(tmp_path / "nope.usda")] and report["error"]["code"] == 2
    assert not (out / "batch.json").exists()  # none of these baked or wrote anything


def _wait_for(what: str, check, timeout: float):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = check()
        if found:
            return found
        time.sleep(0.02)  # polling for an event of another process, with a deadline
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.slow  # ~1 min: a scheduler and two workers started as processes
def test_batch_on_a_scheduler_and_workers_started_as_separate_processes(tmp_path, pristine, reference):
    dask = Path(sys.executable).with_name("dask")
    cmd = [str(dask)] if dask.exists() else [sys.executable, "-m", "dask"]
    info = tmp_path / "scheduler.json"
    procs = []
    try:
        procs.append(subprocess.Popen([*cmd, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address", "127.0.0.1:0",
                                       "--scheduler-file", str(info)], env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        _wait_for("the scheduler's address", lambda: info.is_file() and info.stat().st_size > 0, 60)
        address = json.loads(info.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for _ in range(2):
            procs.append(subprocess.Popen([*cmd, "worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard"],
                                          env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout=30) as client:
            _wait_for("two workers", lambda: len(client.scheduler_info()["workers"]) == 2, 120)
            workers = set(client.scheduler_info()["workers"])
        out = tmp_path / "out"
        r, report = batch(*pristine.values(), "-o", out, "--scheduler", address)
        assert r.returncode == 0, r.stderr
        assert statuses(report) == {"tree_small": "baked", "oak": "baked", "blender_tree": "baked"}
        assert report["stats"]["scheduler"] == address and report["stats"]["workers"] == 2
        assert {e["worker"] for e in report["stats"]["assets"].values()} <= workers
        for name, outdir in reference.items():
            assert_same_bake(out / name, outdir)
        r = foliage("batch", *pristine.values(), "-o", out, "--scheduler", address, "--workers", "2")
        assert r.returncode == 2 and "--workers" in r.stderr and "--scheduler" in r.stderr
    finally:
        for proc in reversed(procs):
            _stop(proc)
    r = foliage("batch", pristine["oak"], "-o", tmp_path / "out2", "--scheduler", address)  # the scheduler is gone now
    assert r.returncode == 2 and address in r.stderr and "dask scheduler" in r.stderr


@pytest.mark.slow  # ~1 min
def test_a_worker_killed_in_the_middle_of_an_asset_is_retried_and_nothing_is_half_written(tmp_path, pristine, reference):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "foliage_tools", "batch", *map(str, pristine.values()), "-o", str(out),
                             "--workers", "2", *SMALL, "--json"], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        staging = re.compile(r"\.oak\.bake\.tmp-(\d+)-[0-9a-f]+")

        def oak_staging():
            d = out / "oak"
            hits = [m for p in (d.iterdir() if d.is_dir() else ()) if (m := staging.fullmatch(p.name))]
            return hits[0] if hits else None

        m = _wait_for("the oak's bake to start", oak_staging, 300)
        pid = int(m.group(1))
        assert pid != proc.pid  # the bake runs in a worker process, not in the batch's own
        os.kill(pid, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=600)
    finally:
        _stop(proc)
    assert proc.returncode == 0, stderr
    report = json.loads(stdout)
    assert statuses(report) == {"tree_small": "baked", "oak": "baked", "blender_tree": "baked"}
    oak = report["stats"]["assets"]["oak"]
    assert oak["attempts"] >= 2
    assert any("earlier attempt died" in w for w in oak["warnings"])
    assert any(m.group(0) in w and "interrupted run" in w for w in oak["warnings"])  # the retry removed the dead one's work
    assert not hidden_entries(out)
    for name, outdir in reference.items():
        assert_same_bake(out / name, outdir)

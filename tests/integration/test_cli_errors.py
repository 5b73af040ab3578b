"""Bad inputs get a clear message and the DESIGN.md exit code; inputs never change.

These run the real command (``python -m foliage_tools``) in a subprocess.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import numpy as np
from tests.conftest import cards_mesh, sha256, write_mesh_stage
from tests.helpers.cli import foliage, signal_after_line


def test_missing_file_exits_2_naming_it(tmp_path):
    r = foliage("inspect", tmp_path / "nope.usda")
    assert r.returncode == 2
    assert "nope.usda" in r.stderr and "no such file" in r.stderr


def test_not_usd_exits_2(tmp_path):
    bogus = tmp_path / "bogus.usda"
    bogus.write_text("this is not usd\n")
    r = foliage("inspect", bogus)
    assert r.returncode == 2, r.stderr
    assert "bogus.usda" in r.stderr and "USD" in r.stderr
    other = tmp_path / "tree.obj"
    other.write_text("v 0 0 0\n")
    r = foliage("inspect", other)
    assert r.returncode == 2 and "not a USD file" in r.stderr


def test_empty_stage_exits_2(tmp_path):
    empty = tmp_path / "empty.usda"
    empty.write_text("#usda 1.0\n")
    r = foliage("inspect", empty)
    assert r.returncode == 2 and "empty" in r.stderr


def test_no_leaves_exits_2_and_says_how_to_mark_them(tmp_path):
    path = write_mesh_stage(tmp_path / "wood.usda", {"Trunk": {**cards_mesh([(0, 0, 0)]), "isLeaf": False}})
    r = foliage("density", path, "-o", tmp_path / "out.usda")
    assert r.returncode == 2
    assert "no leaves" in r.stderr and "FoliageLeafAPI" in r.stderr and "<" in r.stderr
    assert not (tmp_path / "out.usda").exists()


def test_nan_points_exit_2_naming_the_prim(tmp_path):
    m = cards_mesh([(0, 0, 0)])
    m["points"][2, 1] = np.nan
    path = write_mesh_stage(tmp_path / "nan.usda", {"Leaves": {**m, "isLeaf": True}})
    before = sha256(path)
    r = foliage("density", path, "-o", tmp_path / "out.usda")
    assert r.returncode == 2
    assert "</Tree/Leaves>" in r.stderr and "NaN" in r.stderr
    v = foliage("validate", path, "--json")
    assert v.returncode == 1
    rules = {f["rule"] for f in json.loads(v.stdout)["stats"]["findings"]}
    assert "finite-geometry" in rules
    assert sha256(path) == before


def test_degenerate_triangles_warn_and_fail_only_strict(tmp_path):
    m = cards_mesh([(0, 0, 0), (1, 0, 0)])
    m["points"][4:8] = m["points"][4]  # second card collapsed to a point
    path = write_mesh_stage(tmp_path / "degen.usda", {"Leaves": {**m, "isLeaf": True}})
    assert foliage("validate", path).returncode == 0
    strict = foliage("validate", path, "--strict")
    assert strict.returncode == 1 and "degenerate" in strict.stdout
    r = foliage("inspect", path, "--json")
    report = json.loads(r.stdout)
    assert report["stats"]["prototypes"][0]["leaves"] == 1
    assert any("degenerate" in w for w in report["warnings"])


def test_validate_warns_that_the_reserved_leaf_optics_attributes_are_not_read(tmp_path):
    from pxr import Gf, Usd

    path = write_mesh_stage(tmp_path / "t.usda", {"Leaves": {**cards_mesh([(0, 0, 0)]), "api": True}})
    assert "leaf-optics-attributes" not in foliage("validate", path, "--strict").stdout
    stage = Usd.Stage.Open(str(path))
    stage.GetPrimAtPath("/Tree/Leaves").GetAttribute("foliage:leaf:reflectance").Set(Gf.Vec3f(0.1, 0.2, 0.1))
    stage.GetRootLayer().Save()
    r = foliage("validate", path)
    assert r.returncode == 0 and "leaf-optics-attributes" in r.stdout and "--leaf-optics" in r.stdout
    assert foliage("validate", path, "--strict").returncode == 1


def test_usage_errors_exit_2(tmp_path, simple_tree):
    r = foliage("density", simple_tree, "-o", tmp_path / "o.usda", "--voxel-size", "0.1", "--resolution", "8")
    assert r.returncode == 2 and "--voxel-size" in r.stderr and "--resolution" in r.stderr
    r = foliage("density", simple_tree, "-o", tmp_path / "o.usda", "--method", "magic")
    assert r.returncode == 2


def test_output_equal_to_input_is_refused(simple_tree):
    before = sha256(simple_tree)
    r = foliage("density", simple_tree, "-o", simple_tree)
    assert r.returncode == 2 and "is the input file" in r.stderr
    assert sha256(simple_tree) == before


@pytest.mark.slow  # > 15 s; the default suite keeps a faster test of the same path
def test_output_over_a_layer_or_grid_the_input_uses_is_refused(tmp_path, simple_tree):
    # chained stages: b.usda sublayers a.usda, which refers to a.vdb; writing either of them again
    # from b would change b's input (and a.usda over itself would make the layer stack a cycle)
    a, b = tmp_path / "a.usda", tmp_path / "b.usda"
    assert foliage("density", simple_tree, "-o", a).returncode == 0
    assert foliage("density", a, "-o", b).returncode == 0
    before = {f.name: sha256(f) for f in tmp_path.iterdir() if f.is_file()}
    r = foliage("density", b, "-o", a)
    assert r.returncode == 2 and "a file the input" in r.stderr and "a.usda" in r.stderr
    # a.usdc would put its grids in a.vdb, which a.usda (used by b) refers to
    r = foliage("density", b, "-o", tmp_path / "a.usdc")
    assert r.returncode == 2 and "a.vdb" in r.stderr
    assert {f.name: sha256(f) for f in tmp_path.iterdir() if f.is_file()} == before
    # an unrelated name still works
    assert foliage("density", b, "-o", tmp_path / "c.usda").returncode == 0
    # no false alarms: t.usda's grid would be t.vdb, not the t.lb.vdb its input uses; smax writes no grids
    assert foliage("density", simple_tree, "-o", tmp_path / "t.lb.usda").returncode == 0
    assert foliage("density", tmp_path / "t.lb.usda", "-o", tmp_path / "t.usda").returncode == 0
    r = foliage("smax", tmp_path / "t.usda", "-o", tmp_path / "t.lb.usdc")
    assert r.returncode == 0, r.stderr


def test_unwritable_output_dir_exits_2(simple_tree):
    # /proc refuses new files even to root (CI runs as root, so chmod would not do)
    r = foliage("density", simple_tree, "-o", "/proc/o.usda")
    assert r.returncode == 2 and "not writable" in r.stderr


def test_output_in_missing_directory_is_made(tmp_path, simple_tree):
    # every command makes its -o file's folder, as bake makes OUTDIR (test_output_folders.py)
    r = foliage("density", simple_tree, "-o", tmp_path / "no" / "such" / "dir" / "o.usda")
    assert r.returncode == 0 and (tmp_path / "no" / "such" / "dir" / "o.usda").is_file(), r.stderr


def test_output_must_be_a_usd_layer(tmp_path, simple_tree):
    r = foliage("density", simple_tree, "-o", tmp_path / "o.vdb")
    assert r.returncode == 2 and "USD layer" in r.stderr


def test_help_teaches_with_examples():
    r = foliage("--help")
    assert r.returncode == 0 and "Exit codes" in r.stdout
    for cmd in ("inspect", "validate", "density"):
        h = foliage(cmd, "--help")
        assert h.returncode == 0 and "Example" in h.stdout, cmd


def test_absurd_voxel_size_is_a_usage_error_not_a_memory_error(tmp_path, simple_tree):
    r = foliage("density", simple_tree, "-o", tmp_path / "o.usda", "--voxel-size", "1e-5")
    assert r.returncode == 2 and "too large" in r.stderr and "--voxel-size" in r.stderr
    assert not (tmp_path / "o.usda").exists()


def test_interrupt_exits_130_and_leaves_no_output(tmp_path):
    import signal

    example = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"
    out = tmp_path / "r.usda"
    # The context manager closes the pipe whatever happens (an unclosed pipe fails a later test's warnings
    # check). SIGINT is reset to its default in the child: a test run started in the background inherits
    # SIGINT ignored (POSIX), and Python then installs no KeyboardInterrupt handler, so the child would
    # trace 400M paths.
    with subprocess.Popen(
        [sys.executable, "-m", "foliage_tools", "reference", str(example), "-o", str(out), "--paths", "400000000", "-v"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    ) as proc:
        # -v logs each step on stderr (no terminal, no bar): interrupt once the tracing has started
        _, err = signal_after_line(proc, "tracing", signal.SIGINT)
    assert proc.returncode == 130, err
    assert "interrupted" in err
    assert list(tmp_path.iterdir()) == []


def test_an_output_beside_a_result_of_the_same_name_does_not_take_its_grids(simple_tree, tmp_path):
    # x.usd and x.usda both name their grids x.vdb: the second bake would overwrite the first result's grids, which
    # its layer then refuses as stale (a new user's trial). Refused before any work; the first result stays whole.
    first = tmp_path / "x.usda"
    assert foliage("density", simple_tree, "-o", first, "--resolution", "8").returncode == 0
    before = {p.name: sha256(p) for p in tmp_path.iterdir()}
    r = foliage("density", simple_tree, "-o", tmp_path / "x.usd", "--resolution", "8")
    assert r.returncode == 2 and "x.usda" in r.stderr and "x.vdb" in r.stderr, r.stderr
    assert {p.name: sha256(p) for p in tmp_path.iterdir()} == before
    assert foliage("validate", first).returncode == 0
    # rewriting the result itself is fine
    assert foliage("density", simple_tree, "-o", first, "--resolution", "8").returncode == 0


def test_an_empty_usd_file_is_named_empty(tmp_path):
    empty = tmp_path / "tree.usda"
    empty.write_bytes(b"")
    for args in (("inspect", empty), ("validate", empty), ("spp", empty, "-o", tmp_path / "o.usda")):
        r = foliage(*args)
        assert r.returncode == 2 and "is empty (0 bytes)" in r.stderr and "tree.usda" in r.stderr, (args, r.stderr)

"""Issue #18 case 8: inputs that hung or were accepted silently, and errors that did not name their source."""

from __future__ import annotations

import json
import os
from pathlib import Path

from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_a_fifo_input_is_refused_instead_of_hanging(tmp_path):
    fifo = tmp_path / "tree.usda"
    os.mkfifo(fifo)
    r = foliage("inspect", fifo)  # before: USD blocked reading it until killed
    assert r.returncode == 2 and "not a regular file" in r.stderr and str(fifo) in r.stderr, r.stderr


def test_leaf_optics_range_errors_name_the_flag_or_the_config_file(tmp_path):
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "a.usda", "--leaf-optics", "2,0.5")
    assert r.returncode == 2 and "--leaf-optics '2,0.5'" in r.stderr, r.stderr
    cfg = tmp_path / "pipeline.toml"
    cfg.write_text('leaf-optics = "0.6,0.6"\n', encoding="utf-8")
    r = foliage("smax", EXAMPLE, "-o", tmp_path / "b.usda", "--config", cfg)
    assert r.returncode == 2 and str(cfg) in r.stderr and "leaf-optics" in r.stderr and "≤ 1" in r.stderr, r.stderr
    assert not (tmp_path / "a.usda").exists() and not (tmp_path / "b.usda").exists()


def test_a_voxel_size_that_holds_no_leaf_area_is_warned_about(tmp_path):
    r = foliage("density", EXAMPLE, "-o", tmp_path / "d.usda", "--voxel-size", "1e30", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["stats"]["prototypes"][0]["active_voxels"] == 0
    assert any("holds 0.0 % of the leaf area" in w for w in report["warnings"]), report["warnings"]
    # and a normal grid is not warned about (the area method conserves the leaf area to round-off)
    ok = json.loads(foliage("density", EXAMPLE, "-o", tmp_path / "e.usda", "--json").stdout)
    assert not any("of the leaf area" in w for w in ok["warnings"])


def test_spp_refuses_directions_that_cannot_fit_in_memory_before_any_work(tmp_path):
    # issue #18 case 7: 1M directions took 29 s and 358 GiB before a MemoryError (exit 3)
    r = foliage("spp", EXAMPLE, "-o", tmp_path / "s.usda", "--directions", "1000000")
    assert r.returncode == 2 and "--directions 1000000" in r.stderr and "GB is available" in r.stderr, r.stderr
    assert not (tmp_path / "s.usda").exists()

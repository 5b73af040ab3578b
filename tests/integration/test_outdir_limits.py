"""A write that does not complete is never committed: the file-size limit (``ulimit -f``) and cut files.

Python ignores SIGXFSZ, so a write past RLIMIT_FSIZE fails with EFBIG, which
OpenVDB's and OpenImageIO's writers do not all report: the file is then cut
at the limit. Every staged file is checked before the commit; a cut one is
exit 2 naming the limit, and the earlier result stays as it was.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from foliage_tools.errors import OutputError
from foliage_tools.scene import atomic
from foliage_tools.scene.vdb import Grid, write_vdb
from tests.helpers.staging import hidden, visible

MINIMAL = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")


def _capped(cap: int, *args) -> subprocess.CompletedProcess:
    env = dict(os.environ, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"))
    return subprocess.run([sys.executable, "-m", "foliage_tools", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=300,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (cap, resource.RLIM_INFINITY)))


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """A tree and an earlier, complete bake of it (another sun than the capped runs', so every file would change)."""
    where = tmp_path_factory.mktemp("limits")
    tree = where / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    out = where / "out"
    r = _capped(resource.RLIM_INFINITY, "bake", tree, "-o", out, *FAST, "--sun", "30,50")
    assert r.returncode == 0, r.stderr
    return tree, out, visible(out)


@pytest.mark.parametrize("cap, cut", [
    (64 * 1024, "tree.lb.vdb"),        # a later grid file (74 kB) is cut; the density grids (21 kB) are whole
    (16 * 1024, "tree.density.vdb"),   # the first file the bake writes is cut
])
def test_a_bake_past_the_file_size_limit_is_exit_2_naming_it_and_keeps_the_old_result(baked, cap, cut):
    tree, out, before = baked
    assert max(p.stat().st_size for p in out.iterdir()) > cap  # the cap does cut this bake
    r = _capped(cap, "bake", tree, "-o", out, *FAST, "--sun", "200,40")
    assert r.returncode == 2, r.stderr
    assert "file-size limit" in r.stderr and f"{cap:,} bytes" in r.stderr and f"{out / cut}@" in r.stderr, r.stderr
    assert "unreadable" not in r.stderr and "not a readable OpenVDB file" not in r.stderr
    assert visible(out) == before and hidden(out) == []


def test_a_stage_past_the_file_size_limit_writes_nothing(tmp_path):
    tree = tmp_path / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    r = _capped(8 * 1024, "density", tree, "-o", tmp_path / "d.usda", "--resolution", "8")
    assert r.returncode == 2 and "file-size limit" in r.stderr and "d.vdb@" in r.stderr, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tree.usda"]


def _grid() -> Grid:
    values = np.random.default_rng(0).random((24, 24, 24), dtype=np.float32)
    return Grid(name="density", values=values, origin=(0.0, 0.0, 0.0), voxel_size=0.1)


@pytest.mark.parametrize("name, write", [
    ("g.vdb", lambda p: write_vdb(p, [_grid()])),
    ("l.usda", lambda p: p.write_text('#usda 1.0\n(\n    defaultPrim = "A"\n)\n\ndef Xform "A"\n{\n' + "    " * 2000 + "}\n")),
    ("i.png", lambda p: __import__("foliage_tools.scene.image", fromlist=["x"])._write(p, np.full((64, 64, 3), 0.5), "png", p)),
])
def test_a_staged_file_cut_short_is_refused_before_the_commit(tmp_path, name, write):
    with atomic.Commit(tmp_path, name) as commit:
        staged = commit.path(name)
        write(staged)
        atomic.check_written(staged, tmp_path / name)  # whole: accepted
        size = staged.stat().st_size
        with open(staged, "r+b") as f:
            f.truncate(size * 2 // 3)
        with pytest.raises(OutputError, match="does not read back whole"):
            commit.commit([name])
    assert list(tmp_path.iterdir()) == []

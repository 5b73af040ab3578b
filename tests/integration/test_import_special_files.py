"""``foliage import`` of something that is not a regular file says what it is (a FIFO is never opened: reading one
would block), and a missing file says it does not exist."""

from __future__ import annotations

import os

from tests.helpers.cli import foliage


def test_import_names_a_fifo_a_device_and_a_missing_file_for_what_they_are(tmp_path):
    fifo = tmp_path / "pipe.obj"
    os.mkfifo(fifo)
    for source, says in ((fifo, "is a FIFO (named pipe), not a regular file"),
                         ("/dev/zero", "is a device, not a regular file"),
                         (tmp_path / "gone.obj", "does not exist")):
        r = foliage("import", source, "-o", tmp_path / "t.usda", "--json")
        assert r.returncode == 2 and says in r.stderr, (source, r.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.obj"]


def test_import_refuses_symbolic_link_loops_as_model_and_as_output(tmp_path):
    os.symlink(tmp_path / "b", tmp_path / "a")
    os.symlink(tmp_path / "a", tmp_path / "b")
    model = tmp_path / "leaf.obj"
    model.write_text("o leaves\nv 0 0 1\nv 1 0 1\nv 1 1 1\nf 1 2 3\n")
    for args in (("import", tmp_path / "a", "-o", tmp_path / "t.usda"), ("import", model, "-o", tmp_path / "a")):
        r = foliage(*args, "--json")
        assert r.returncode == 2 and "is a symbolic link that loops" in r.stderr, (args, r.stderr)

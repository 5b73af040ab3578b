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

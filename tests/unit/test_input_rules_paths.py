"""``scene.dependencies.file_problem``: what a path is when it is not a regular file, from ``os.stat`` alone (a FIFO
is never opened, so never blocks), and ``name_problem`` / ``shown`` for names USD cannot take. Every input opener
(``open_stage``, the layer walk, the grid readers) says these words; ``foliage import``'s said "no such file" for a
FIFO and for /dev/zero."""

from __future__ import annotations

import os
import threading

import pytest

from foliage_tools.errors import InputError
from foliage_tools.scene.dependencies import file_problem, name_problem, require_file, shown


def test_each_kind_of_path_is_named_for_what_it_is(tmp_path):
    (tmp_path / "file.obj").write_text("v 0 0 0\n")
    os.mkfifo(tmp_path / "pipe.obj")
    (tmp_path / "folder.obj").mkdir()
    os.symlink("loop.obj", tmp_path / "loop.obj")
    os.symlink("gone.obj", tmp_path / "dangling.obj")
    assert file_problem(tmp_path / "file.obj") is None
    assert file_problem(tmp_path / "pipe.obj") == "is a FIFO (named pipe), not a regular file"
    assert file_problem("/dev/zero") == "is a device, not a regular file"
    assert file_problem(tmp_path / "folder.obj") == "is a directory, not a file"
    assert "loops" in file_problem(tmp_path / "loop.obj")
    assert file_problem(tmp_path / "dangling.obj") == "is a symbolic link to a file that does not exist"
    assert file_problem(tmp_path / "missing.obj") == "does not exist"


def test_a_fifo_is_refused_without_being_opened(tmp_path):
    """Opening a FIFO for reading blocks until a writer comes: the check must return while none does."""
    os.mkfifo(tmp_path / "pipe.usda")
    done = []
    worker = threading.Thread(target=lambda: done.append(file_problem(tmp_path / "pipe.usda")), daemon=True)
    worker.start()
    worker.join(timeout=10)
    assert done == ["is a FIFO (named pipe), not a regular file"]


def test_require_file_names_the_file_and_what_it_is(tmp_path):
    with pytest.raises(InputError) as err:
        require_file("/dev/zero", "Give a model file.")
    assert str(err.value) == "@/dev/zero@ is a device, not a regular file. Give a model file."


def test_names_usd_cannot_take_are_shown_escaped():
    assert name_problem("tree.usda") is None
    assert name_problem("tree\nx.usda") == "its name holds the control character \\n"
    assert name_problem(os.fsdecode(b"tree\xff.usda")) == "its name holds byte 0xff (not UTF-8)"
    assert shown("a\x1b[31mb.usda") == "a\\x1b[31mb.usda"  # an escape sequence is printed, not obeyed
    assert shown(os.fsdecode(b"tree\xff.usda")) == "tree\\xff.usda"

"""What ``scene.atomic`` leaves in a directory: the visible results, the hidden staging, and a killed run's."""

from __future__ import annotations

import subprocess
from pathlib import Path

from foliage_tools.scene import atomic
from foliage_tools.scene.integrity import digest


def dead_pid() -> int:
    """The id of a process that has exited (and been reaped)."""
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def visible(directory: Path) -> dict[str, str]:
    return {p.name: digest(p) for p in directory.iterdir() if p.is_file() and not p.name.startswith(".")}


def hidden(directory: Path) -> list[str]:
    return [p.name for p in directory.iterdir() if p.name.startswith(".")]


def as_if_dead(directory: Path) -> None:
    """Give the staging directories in ``directory`` the id of a process that is gone (the killed run)."""
    pid = dead_pid()
    for p in directory.iterdir():
        m = atomic._STAGING.fullmatch(p.name)
        if m:
            p.rename(p.with_name(f".{m['label']}.tmp-{pid}-{m['token']}"))

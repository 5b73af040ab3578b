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


def plant_staging(directory: Path, label: str, journal: list[str] | None, *, files: dict[str, str] | None = None,
                  host: str | None = None, pid: int | None = None) -> Path:
    """A staging folder as a killed run (or an attacker) leaves it: ``.owner``, a journal of ``journal`` (None: no
    journal) and the ``files`` {name: text} (default: one per plain journal name)."""
    import socket

    pid = dead_pid() if pid is None else pid
    staging = directory / f".{atomic.staging_label(label)}.tmp-{pid}-ab12cd34"
    staging.mkdir()
    (staging / atomic.OWNER).write_text(f"{host or socket.gethostname()} {pid}\n", encoding="utf-8")
    if files is None:
        files = {n: f"staged {n}\n" for n in journal or () if "/" not in n and "\0" not in n and n not in (".", "..")
                 and n not in (atomic.JOURNAL, atomic.OWNER) and not n.endswith(".lock") and ".tmp-" not in n}
    for name, text in files.items():
        (staging / name).write_text(text, encoding="utf-8")
    if journal is not None:
        (staging / atomic.JOURNAL).write_text("".join(f"{n}\n" for n in journal), encoding="utf-8")
    return staging

"""Atomic file output: write to a temporary sibling, then rename into place.

An interrupted or failed run leaves no partial output: either every file of a
stage is renamed into place, or none is and the temporaries are removed.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from foliage_tools.errors import OutputError


def temp_sibling(path: Path) -> Path:
    """A temporary name in the same directory (so the rename is atomic), keeping the extension."""
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")


def check_writable(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise OutputError(f"@{path}@: the directory {parent} does not exist; create it first.")
    if path.is_dir():
        raise OutputError(f"@{path}@ is a directory; give a file name.")
    # os.access says yes to root on read-only mounts and special filesystems: try it for real
    try:
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".foliage-probe-"):
            pass
    except OSError as exc:
        raise OutputError(f"@{path}@: the directory {parent} is not writable ({exc.strerror}); choose another output path.") from None


@contextlib.contextmanager
def atomic_outputs(paths: list[Path]) -> Iterator[dict[Path, Path]]:
    """Yield {final path: temporary path}; on success rename all into place, else delete the temporaries.

    Files are renamed in the order given, so list the files a layer refers to
    (``.vdb``) before the layer itself.
    """
    temps = {p: temp_sibling(p) for p in paths}
    try:
        yield temps
        for final, tmp in temps.items():
            if tmp.exists():
                os.replace(tmp, final)
    except OSError as exc:
        raise OutputError(f"@{exc.filename or paths[-1]}@: cannot be written ({exc.strerror}); nothing was written.") from None
    finally:
        for tmp in temps.values():
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()

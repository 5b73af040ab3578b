"""The real command (``python -m foliage_tools``) in a subprocess, the schema of its ``--json`` report, and a
signal sent to a run once it has reached a step."""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
REPORT_SCHEMA = json.loads((REPO / "schemas" / "json" / "report.schema.json").read_text())


def foliage(*args, cwd=None) -> subprocess.CompletedProcess:
    # a cache directory of the tests' own, so a run never reads or fills the user's
    env = dict(os.environ, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"))
    return subprocess.run([sys.executable, "-m", "foliage_tools", *map(str, args)], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def signal_after_line(proc: subprocess.Popen, word: str, sig: int, *, timeout: float = 120.0) -> tuple[list[str], str]:
    """Send ``sig`` to ``proc`` once a line of its stderr contains ``word``, and wait for it to exit.

    Returns the stderr lines up to that one and the rest of stderr. A thread reads stderr, so a run that never
    prints ``word`` (a step renamed, an early exit) fails after ``timeout`` s, or when its stderr ends, instead of
    holding the suite for as long as the run lasts; ``proc`` is killed then. ``proc`` has ``stderr=PIPE`` in text
    mode and nothing else piped (only stderr is drained).
    """
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        for line in proc.stderr:
            lines.put(line)
        lines.put(None)  # end of stderr

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    try:
        while not seen or word not in seen[-1]:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"no line with {word!r} on stderr within {timeout} s:\n{''.join(seen)[-2000:]}") from None
            if line is None:
                raise AssertionError(f"stderr ended (exit {proc.wait()}) without a line with {word!r}:\n{''.join(seen)[-2000:]}")
            seen.append(line)
        proc.send_signal(sig)
        proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:  # never leave the run behind
            proc.kill()
            proc.wait()
    reader.join(timeout=timeout)
    rest = []
    while not lines.empty():
        line = lines.get()
        if line is not None:
            rest.append(line)
    return seen, "".join(rest)

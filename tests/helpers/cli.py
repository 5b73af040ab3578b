"""The real command (``python -m foliage_tools``) in a subprocess, and the schema of its ``--json`` report."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
REPORT_SCHEMA = json.loads((REPO / "schemas" / "json" / "report.schema.json").read_text())


def foliage(*args, cwd=None) -> subprocess.CompletedProcess:
    # a cache directory of the tests' own, so a run never reads or fills the user's
    env = dict(os.environ, XDG_CACHE_HOME=str(Path(tempfile.gettempdir()) / "foliage-test-cache"))
    return subprocess.run([sys.executable, "-m", "foliage_tools", *map(str, args)], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)

"""``foliage_tools.interrupts``: a signal inside an import is held until the import is over, then interrupts.

A KeyboardInterrupt raised inside an extension module's initialisation is not
an interrupt any more: pyopenvdb's prints it, numpy's import fails under it,
and the import then succeeds, so the run went on and committed (a lost
signal), or it became "SystemError: initialization of pyopenvdb raised
unreported exception" (exit 3). Each case runs in a fresh interpreter, where
numpy is first imported by pyopenvdb's initialisation; a meta-path finder
sends the signal exactly there.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {repo!r})
    from foliage_tools import interrupts

    interrupts.install_interrupts()
    interrupts.interrupts_ready()

    class Trip:
        sent = False

        def find_spec(self, name, path=None, target=None):
            if not Trip.sent and name.startswith("numpy"):  # inside pyopenvdb's initialisation
                Trip.sent = True
                os.kill(os.getpid(), signal.{sig})
            return None

    sys.meta_path.insert(0, Trip())
    try:
        import pyopenvdb
        for _ in range(10**8):
            pass
        print("not interrupted")
    except KeyboardInterrupt as exc:
        print("interrupted", exc, "| pyopenvdb works:", pyopenvdb.FloatGrid() is not None)
    print("noted", interrupts.interrupt_noted() == signal.{sig})
""")


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_signal_inside_an_extensions_import_interrupts_once_the_import_is_over(sig):
    r = subprocess.run([sys.executable, "-c", SCRIPT.format(repo=str(REPO), sig=sig)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [f"interrupted {sig} | pyopenvdb works: True", "noted True"], r.stdout
    assert "failed to import" not in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_signal_before_the_command_begins_is_raised_when_it_begins():
    script = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(REPO)!r})
        from foliage_tools import interrupts

        interrupts.install_interrupts()
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(10**6):
            pass
        print("still here", flush=True)
        try:
            interrupts.interrupts_ready()
        except KeyboardInterrupt as exc:
            print("interrupted", exc)
        interrupts.interrupts_done()
        os.kill(os.getpid(), signal.SIGTERM)  # after the exit code is known: ignored, even while Python shuts down
        print("done")
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["still here", "interrupted SIGTERM", "done"], r.stdout

"""How SIGINT, SIGTERM and SIGHUP stop a run: as KeyboardInterrupt (exit 130), never inside an import.

The command line installs :func:`install_interrupts` first of all, before its
own imports (``python -m foliage_tools`` and the ``foliage`` script alike),
and calls :func:`interrupts_ready` when the command begins. Standard library
only, so that installing it imports nothing heavy.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from types import FrameType
from typing import Callable

#: Signals that interrupt a run (the CLI maps them to exit 130); ``scene.atomic`` holds them back during its renames.
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class _Interrupts:
    """The state of :func:`install_interrupts`'s handler (one per process)."""

    def __init__(self) -> None:
        self.started = False
        """The command has begun: an interrupt is raised where it lands (outside an import)."""
        self.noted: int | None = None
        """The first interrupting signal of this run (kept whatever became of its KeyboardInterrupt)."""
        self.pending: int | None = None
        """A signal held back until the import it landed in (or the command's start) is over."""
        self.lock = threading.RLock()  # reentrant: the handler runs in the main thread, which may hold it
        self.on_signal: Callable[[int], None] | None = None


_interrupts = _Interrupts()


def _importing(frame: FrameType | None) -> bool:
    """Whether ``frame`` (a thread's innermost) runs inside an ``import``."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _on_interrupt(signum: int, frame: FrameType | None) -> None:
    """SIGINT, SIGTERM, SIGHUP: KeyboardInterrupt where the main thread is, except inside an import.

    An exception raised inside an import is not an interrupt any more: an
    extension module's initialisation turns it into SystemError ("initialization
    of pyopenvdb raised unreported exception") or swallows it and leaves a
    half-made module behind (USD's then fail with a TypeError, or the run goes
    on and commits). So there, and before the command has begun, the signal is
    held back and delivered again as soon as the main thread is out of the
    import. Every interrupt is also noted (:func:`interrupt_noted`), so a
    commit refuses to start after one, wherever its KeyboardInterrupt went.
    """
    st = _interrupts
    if st.noted is None:
        st.noted = signum
    if st.on_signal is not None:
        st.on_signal(signum)
    if not st.started or _importing(frame):
        with st.lock:
            if st.pending is None:
                st.pending = signum
                threading.Thread(target=_deliver_when_safe, name="foliage-interrupt", daemon=True).start()
        return
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _deliver_when_safe() -> None:
    st = _interrupts
    main = threading.main_thread().ident
    while True:
        time.sleep(0.01)
        if not st.started or _importing(sys._current_frames().get(main)):  # type: ignore[arg-type]
            continue
        with st.lock:
            signum, st.pending = st.pending, None
        if signum is not None:
            os.kill(os.getpid(), signum)
        return


def install_interrupts(on_signal: Callable[[int], None] | None = None) -> None:
    """Make SIGINT, SIGTERM and SIGHUP interrupt a run safely (:func:`_on_interrupt`); call it as early as possible.

    A signal the caller set to be ignored (``nohup`` ignores SIGHUP) or to a
    handler of its own stays so. Until :func:`interrupts_ready`, an interrupt
    is held back. ``on_signal(signum)`` is called for each one.
    """
    for sig in INTERRUPT_SIGNALS:
        handler = signal.getsignal(sig)
        if handler is signal.default_int_handler or handler == signal.SIG_DFL:
            signal.signal(sig, _on_interrupt)
    if on_signal is not None:
        _interrupts.on_signal = on_signal


def interrupts_ready() -> None:
    """The command begins: from now on an interrupt raises KeyboardInterrupt; one that came before is raised now."""
    st = _interrupts
    with st.lock:
        st.started = True
        signum, st.pending = st.pending, None
    if signum is not None:
        raise KeyboardInterrupt(signal.Signals(signum).name)


def interrupts_done() -> None:
    """The command has its exit code: a later interrupt is ignored (nothing is left to stop).

    Ignored, not noted: Python's finalisation puts back the default action of
    every signal it handles, so a SIGTERM while the interpreter shuts down (its
    thread pools joined, its modules freed) would kill the finished run (-15).
    """
    _interrupts.started = False
    if threading.current_thread() is threading.main_thread():
        for sig in INTERRUPT_SIGNALS:
            if signal.getsignal(sig) is _on_interrupt:
                signal.signal(sig, signal.SIG_IGN)


def interrupt_noted() -> int | None:
    """The signal that interrupted this run, if one did (None: none, or :func:`install_interrupts` was not called)."""
    return _interrupts.noted

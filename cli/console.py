"""Terminal output: rich progress on stderr, tables on stdout, JSON for ``--json``."""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import sys
import threading
import time
from typing import Any

from rich.console import Console
from rich.errors import MarkupError
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import BarColumn, Progress, SpinnerColumn, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

#: Characters a terminal acts on instead of showing (C0/C1 controls but newline and tab, DEL, the bidirectional
#: overrides) and lone surrogates (the bytes of a file name that are not UTF-8, as Python's surrogateescape reads
#: them): shown as a repr writes them, ``\\x1b``, ``\\r``, ``\\xff``.
_UNPRINTABLE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\ud800-\udfff]")


def _shown(match: re.Match) -> str:
    c = match.group()
    if 0xDC80 <= ord(c) <= 0xDCFF:  # a byte surrogateescape kept
        return f"\\x{ord(c) - 0xDC00:02x}"
    return c.encode("unicode_escape", "backslashreplace").decode("ascii")


def printable(text: str) -> str:
    """``text`` safe to print on a terminal or a log: an escape sequence, a carriage return or a byte that is not
    UTF-8 in a file name is shown escaped (``\\x1b[31m``), never acted on or a UnicodeEncodeError; so is a newline
    or a tab inside an ``@path@`` (a message's own line breaks stay)."""
    text = _PATH.sub(lambda m: m.group().replace("\n", "\\n").replace("\t", "\\t"), text)
    return _UNPRINTABLE.sub(_shown, text)


#: A path as messages name it (``@path@``, the project's convention).
_PATH = re.compile("@[^@]*@")


def _cell(value: Any) -> Any:
    """A table's text as rich shows it: its markup (the callers escape the paths they put in), or, where that is not
    markup rich can read (a ``[/]`` in a path nobody escaped), the text itself; control characters escaped."""
    if not isinstance(value, str):
        return value
    value = printable(value)
    try:
        return Text.from_markup(value)
    except MarkupError:
        return Text(value)


class OutputLost(Exception):
    """stdout could not be written (closed, a full disk, a closed pipe): the report did not reach the caller."""

    def __init__(self, error: OSError | None) -> None:
        self.error = error
        why = "it is closed" if error is None else (error.strerror or str(error))
        super().__init__(f"the report could not be written to stdout ({why}); give the command a writable stdout.")


#: The streams that could not be written: their descriptors now go to /dev/null, so the exit is clean.
lost: set[str] = set()


def give_up(name: str) -> None:
    """Point the broken stream's descriptor at /dev/null: Python's flush at exit would fail on it again."""
    lost.add(name)
    stream = getattr(sys, name)
    try:
        fd = stream.fileno()
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, fd)
        os.close(null)
    except (AttributeError, OSError, ValueError):  # no descriptor (closed, or a test runner's stream)
        pass


def write(name: str, text: str) -> None:
    """Write ``text`` to ``sys.stdout`` or ``sys.stderr`` as it is at the moment, flushed. stdout that cannot take
    it raises :class:`OutputLost`; stderr that cannot is given up on silently (nothing could say so)."""
    stream = getattr(sys, name)
    try:
        if stream is None:
            raise OSError(errno.EBADF, "it is closed")
        stream.write(text)
        stream.flush()
    except OSError as exc:
        give_up(name)
        if name == "stdout":
            raise OutputLost(exc) from None


class PrintableStream:
    """A text stream that writes what it is given through :func:`printable` (for click's own usage messages)."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        if self.stream is None:
            return len(text)
        return self.stream.write(printable(text))

    def flush(self) -> None:
        if self.stream is not None:
            self.stream.flush()


class SafeConsole(Console):
    """A rich console that prints what it is given as text: markup only where a caller asks for it
    (``markup=True``, having passed every path and user-given part through :func:`rich.markup.escape`), control
    characters escaped (:func:`printable`), and a stream that cannot be written handled as :func:`write` does."""

    def print(self, *objects: Any, markup: bool | None = None, **kwargs: Any) -> None:  # type: ignore[override]
        objects = tuple(printable(o) if isinstance(o, str) else o for o in objects)
        name = "stderr" if self.stderr else "stdout"
        if name == "stdout" and sys.stdout is None and name not in lost:
            raise OutputLost(None)
        try:
            super().print(*objects, markup=bool(markup), **kwargs)
        except OSError as exc:
            give_up(name)
            if name == "stdout":
                raise OutputLost(exc) from None


stderr = SafeConsole(stderr=True)
stdout = SafeConsole()


def error(message: str, label: str = "error", colour: str = "red") -> None:
    """The one way a message reaches the user on stderr: ``label:`` coloured, ``message`` as text (a ``[/]`` in
    a path is not markup, an escape sequence in a file name is shown escaped)."""
    stderr.print(f"[{colour}]{label}:[/{colour}] {escape(printable(message))}", highlight=False, markup=True,
                 soft_wrap=True)


def finish(code: int) -> int:
    """The exit code once stdout and stderr are flushed: a stdout that could not take the report makes a run that
    would exit 0 exit 2, saying so on stderr; a broken stream is pointed at /dev/null so the exit is clean."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is None or name in lost:
            continue
        try:
            stream.flush()
        except OSError:
            give_up(name)
    if "stdout" in lost and code == 0:
        error(str(OutputLost(None)).replace("(it is closed)", "(a write failed)"))
        return 2
    return code


#: Without a terminal (a pipeline step, CI), a line at least this often (s) says which step the run is at and, where
#: the step counts its work, its share done: a log that goes quiet for longer reads as a hung job.
PLAIN_EVERY_S = 10.0


#: The step the run is at (the last :meth:`RichProgress.step`), named by an out-of-memory error.
last_step: str | None = None

#: A result's hidden staging folder inside its output folder (``scene.atomic``: ``.LABEL.tmp-PID-TOKEN/``): progress
#: names the output folder, where the files will be, instead.
_STAGING_PART = re.compile(r"\.[^/\s]+\.tmp-\d+-[0-9a-f]+/")


def shown_path(text: str) -> str:
    """``text`` with every staging folder of a path left out: ``out/.tree.bake.tmp-8229-ab12/tree.lb.usda`` is
    shown as ``out/tree.lb.usda``, the name the file has once the result is committed."""
    return _STAGING_PART.sub("", text)


class RichProgress:
    """Implements :class:`foliage_tools.pipeline.report.Progress`: a rich bar on stderr when it is a terminal, else
    (a pipeline step, a CI log) plain lines: one per step, and one at least every :data:`PLAIN_EVERY_S` seconds of
    a long one (its share done when it counts its work, else how long it has run), from a thread of its own.

    The heartbeat thread runs while the main thread computes in code that lets go of Python's lock (numba's
    ``nogil`` kernels, Embree, numpy); a call that holds it delays the line until it returns."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and stderr.is_terminal
        self.plain = enabled and not stderr.is_terminal
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._start = time.monotonic()
        self._line: list[Any] | None = None  # plain mode: [message, total, done, time of the last line, step start]
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    def __enter__(self) -> "RichProgress":
        if self.enabled:
            self._progress = Progress(
                SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                TimeElapsedColumn(), console=stderr, transient=True,
            )
            self._progress.__enter__()
        if self.plain:
            self._beat = threading.Thread(target=self._heartbeat, name="foliage-progress", daemon=True)
            self._beat.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._beat is not None:
            self._beat.join(timeout=2.0)
        if self._progress is not None:
            self._progress.__exit__(*exc)

    def _print(self, text: str) -> None:
        write("stderr", f"[{time.monotonic() - self._start:7.1f} s] {printable(shown_path(text))}\n")

    def _status(self, line: list[Any], now: float, *, beat: bool = False) -> str:
        """The step's share done (and, from the heartbeat, how long it has run), or how long it has run."""
        message, total, done, _, began = line
        if total:
            running = f", running {now - began:.0f} s" if beat else ""
            return f"{message}: {100.0 * done / total:.0f} % ({done:,}/{total:,}){running}"
        return f"{message}: still running ({now - began:.0f} s)"

    def _heartbeat(self) -> None:
        while not self._stop.wait(min(1.0, PLAIN_EVERY_S) or 0.05):
            with self._lock:
                line, now = self._line, time.monotonic()
                if line is not None and now - line[3] >= PLAIN_EVERY_S:
                    self._print(self._status(line, now, beat=True))
                    line[3] = now

    def step(self, message: str, total: int | None = None) -> None:
        global last_step
        last_step = message
        if self.plain:
            with self._lock:
                self._print(message)
                now = time.monotonic()
                self._line = [message, total, 0, now, now]
            return
        if self._progress is None:
            # no bar (-q or --json): the steps still reach a log (-v) line by line
            logging.getLogger("foliage").info(shown_path(message))
            return
        if self._task is not None:
            self._progress.update(self._task, visible=False)
        self._task = self._progress.add_task(escape(printable(shown_path(message))), total=total)

    def advance(self, n: int = 1) -> None:
        if self.plain and self._line is not None:
            with self._lock:
                line = self._line
                line[2] += n
                now = time.monotonic()
                if line[1] and now - line[3] >= PLAIN_EVERY_S:
                    self._print(self._status(line, now))
                    line[3] = now
            return
        if self._progress is not None and self._task is not None:
            self._progress.advance(self._task, n)


def result_table(title: str, name: str, columns: tuple[str, ...]) -> Table:
    """A table of results: one row per named thing (a method, a prototype's prim path), then right-aligned values.

    The name column never wraps, so a name such as ``sppg-paper-radiance`` or a prim path stays whole and can be
    copied; every other cell and heading folds onto more lines rather than being cut short with an ellipsis
    (rich's default), so nothing printed is lost on a narrow terminal. Print it with :func:`print_table`.
    """
    table = Table(title=title)
    table.add_column(name, justify="left", no_wrap=True)
    for col in columns:
        table.add_column(col, justify="right", overflow="fold")
    return table


def print_table(table: Table, *, console: Console | None = None) -> None:
    """Print a result table on stdout (or ``console``), whole.

    On a terminal it is fitted to the terminal's width (see :func:`result_table`). Without one (stdout a pipe,
    a file, a CI log) rich assumes 80 columns, or ``$COLUMNS``, and would squeeze a wide table into them although
    nothing there has a width: the table is printed at its natural width instead, one line per row.
    """
    target = console or stdout
    for column in table.columns:  # a prim path or part name with an escape sequence in it is shown, not acted on
        column._cells = [_cell(c) for c in column._cells]
        column.header = _cell(column.header)
    table.title = _cell(table.title)
    if target.is_terminal:
        target.print(table)
        return
    natural = Measurement.get(target, target.options.update_width(10_000), table).maximum
    if natural <= target.width:
        target.print(table)
        return
    # Console.print(width=) is capped at the console's own width: a console of the table's width on the same file
    SafeConsole(file=target.file, stderr=target.stderr, width=natural, color_system=target.color_system,  # type: ignore[arg-type]  # rich types the property str, the argument its names
            no_color=target.no_color).print(table)


def print_json(obj: dict) -> None:
    """The ``--json`` report on stdout (:class:`OutputLost` if stdout cannot take it). JSON's own escapes keep
    control characters and non-UTF-8 bytes of file names printable."""
    write("stdout", json.dumps(obj, indent=2, allow_nan=False, default=_default) + "\n")


def _default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def warn(messages: list[str], quiet: bool) -> None:
    if quiet:
        return
    for m in messages:
        error(m, "warning", "yellow")

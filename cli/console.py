"""Terminal output: rich progress on stderr, tables on stdout, JSON for ``--json``."""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import BarColumn, Progress, SpinnerColumn, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table

stderr = Console(stderr=True)
stdout = Console()


#: Without a terminal (a pipeline step, CI), a long step's progress is printed as a line at most this often (s).
PLAIN_EVERY_S = 30.0


class RichProgress:
    """Implements :class:`foliage_tools.pipeline.report.Progress`: a rich bar on stderr when it is a terminal, else
    (a pipeline step, a CI log) plain lines, one per step and one per :data:`PLAIN_EVERY_S` seconds of a long one."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and stderr.is_terminal
        self.plain = enabled and not stderr.is_terminal
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._start = time.monotonic()
        self._line: list[Any] | None = None  # plain mode: [message, total, done, time of the last line]

    def __enter__(self) -> "RichProgress":
        if self.enabled:
            self._progress = Progress(
                SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                TimeElapsedColumn(), console=stderr, transient=True,
            )
            self._progress.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._progress is not None:
            self._progress.__exit__(*exc)

    def _print(self, text: str) -> None:
        sys.stderr.write(f"[{time.monotonic() - self._start:7.1f} s] {text}\n")
        sys.stderr.flush()

    def step(self, message: str, total: int | None = None) -> None:
        if self.plain:
            self._print(message)
            self._line = [message, total, 0, time.monotonic()]
            return
        if self._progress is None:
            # no bar (-q or --json): the steps still reach a log (-v) line by line
            logging.getLogger("foliage").info(message)
            return
        if self._task is not None:
            self._progress.update(self._task, visible=False)
        self._task = self._progress.add_task(message, total=total)

    def advance(self, n: int = 1) -> None:
        if self.plain and self._line is not None:
            line = self._line
            line[2] += n
            now = time.monotonic()
            if line[1] and now - line[3] >= PLAIN_EVERY_S:
                self._print(f"{line[0]}: {100.0 * line[2] / line[1]:.0f} % ({line[2]:,}/{line[1]:,})")
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
    if target.is_terminal:
        target.print(table)
        return
    natural = Measurement.get(target, target.options.update_width(10_000), table).maximum
    if natural <= target.width:
        target.print(table)
        return
    # Console.print(width=) is capped at the console's own width: a console of the table's width on the same file
    Console(file=target.file, width=natural, color_system=target.color_system,  # type: ignore[arg-type]  # rich types the property str, the argument its names
            no_color=target.no_color).print(table)


def print_json(obj: dict) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False, default=_default) + "\n")


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
        stderr.print(f"[yellow]warning:[/yellow] {escape(m)}", highlight=False, markup=True, soft_wrap=True)

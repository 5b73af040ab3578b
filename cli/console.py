"""Terminal output: rich progress on stderr, tables on stdout, JSON for ``--json``."""

from __future__ import annotations

import json
import logging
import sys

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

stderr = Console(stderr=True)
stdout = Console()


class RichProgress:
    """Implements :class:`foliage_tools.pipeline.report.Progress` with a rich bar on stderr."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and stderr.is_terminal
        self._progress: Progress | None = None
        self._task = None

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

    def step(self, message: str, total: int | None = None) -> None:
        if self._progress is None:
            # no bar (stderr is not a terminal, or -q): the steps still reach a log (-v) line by line
            logging.getLogger("foliage").info(message)
            return
        if self._task is not None:
            self._progress.update(self._task, visible=False)
        self._task = self._progress.add_task(message, total=total)

    def advance(self, n: int = 1) -> None:
        if self._progress is not None and self._task is not None:
            self._progress.advance(self._task, n)


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

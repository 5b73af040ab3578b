"""The report every command returns, and the progress interface stages talk to.

``Report.as_json()`` is the ``--json`` object of DESIGN.md section 3:
``command``, ``version``, ``inputs``, ``outputs``, ``seconds``, ``warnings``
and per-command ``stats`` (schema: ``schemas/json/report.schema.json``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from collections.abc import Mapping
from typing import Any, Generic, Protocol, TypeVar

from foliage_tools import __version__


class Progress(Protocol):
    """What a long stage tells the user. The CLI shows it with rich; tests pass :class:`Silent`."""

    def step(self, message: str, total: int | None = None) -> None: ...
    def advance(self, n: int = 1) -> None: ...


class Silent:
    def step(self, message: str, total: int | None = None) -> None:
        pass

    def advance(self, n: int = 1) -> None:
        pass


S = TypeVar("S", bound=Mapping[str, Any])
"""A command's stats: one of the ``TypedDict`` s of ``pipeline.stats``."""


def _no_stats() -> Any:
    return {}


@dataclass
class Report(Generic[S]):
    """What a command did. ``Report[LBStats]`` etc.: the type of ``stats`` says which keys the CLI may read."""

    command: str
    inputs: list[str]
    outputs: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    stats: S = field(default_factory=_no_stats)
    findings: list[str] = field(default_factory=list)
    """Failed accuracy checks of the bake: the outputs were written, the exit code is 1 (listed with the warnings in JSON)."""
    started: float = field(default_factory=time.perf_counter)
    seconds: float = 0.0
    peak_rss_bytes: int | None = None
    """The process's peak resident memory when the command ended, where a caller measured it (``bake``, per stage)."""

    def finish(self) -> "Report[S]":
        self.seconds = time.perf_counter() - self.started
        return self

    def as_json(self) -> dict[str, Any]:
        return {
            "command": self.command,
            "version": __version__,
            "inputs": self.inputs,
            "outputs": self.outputs,
            "seconds": round(self.seconds, 6),
            "warnings": self.warnings + self.findings,
            "stats": self.stats,
        }

"""How every ``foliage`` command lays out its ``--help``: the common options first, the expert ones after.

click has no option groups of its own; ``Command.format_options`` is its documented place to change how the
options are listed. Each command names its common options where it is declared
(``@click.command(cls=FoliageCommand, common=("--output", "--resolution"))``); the options every command shares
(``--config``, ``--json``, ``-q``, ``-v``, ``--help``) are always common. Every other option is listed under
"Expert options", so an option added later shows up there without editing this module.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import click

#: Options of every command, listed with the common ones (after the command's own).
ALWAYS_COMMON = ("--config", "--json", "--quiet", "--verbose", "--help")

#: The heading of the options a first run does not need.
EXPERT_HEADING = "Expert options"


class FoliageCommand(click.Command):
    """A command whose ``--help`` lists its ``common`` options first and the others under "Expert options"."""

    def __init__(self, *args: Any, common: Sequence[str] = (), **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.common = tuple(common) + ALWAYS_COMMON

    def is_common(self, param: click.Parameter) -> bool:
        return any(opt in self.common for opt in (*param.opts, *param.secondary_opts))

    def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        common: list[tuple[str, str]] = []
        expert: list[tuple[str, str]] = []
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is not None and not isinstance(param, click.Argument):  # as click's own format_options
                (common if self.is_common(param) else expert).append(record)
        if common:
            with formatter.section("Options"):
                formatter.write_dl(common)
        if expert:
            with formatter.section(EXPERT_HEADING):
                formatter.write_dl(expert)

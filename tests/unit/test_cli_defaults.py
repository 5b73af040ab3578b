"""One source for defaults (issue #20): every option of a bake command that sets a field of the stage's params
dataclass has that field's default, after the option's own parsing (``auto`` -> None), so `--help` tells the
truth about what a bake does when the flag is left out, and a default changed in one place cannot drift."""

from __future__ import annotations

import dataclasses

import click
import pytest

from foliage_tools.cli.main import cli
from foliage_tools.pipeline.lb import LBBakeParams
from foliage_tools.pipeline.reference import ReferenceParams
from foliage_tools.pipeline.smax import SmaxParams
from foliage_tools.pipeline.spp import SppParams

STAGES = {"lb": LBBakeParams, "spp": SppParams, "smax": SmaxParams, "reference": ReferenceParams}


def _cli_default(ctx: click.Context, p: click.Parameter):
    if isinstance(p, click.Option) and p.is_flag and p.default is not None and not isinstance(p.default, bool):
        return False  # a boolean flag with no default given is off
    value = p.get_default(ctx)
    if value is not None:
        value = p.type_cast_value(ctx, value)
    return p.callback(ctx, p, value) if p.callback is not None else value


@pytest.mark.parametrize("command", sorted(STAGES))
def test_the_cli_defaults_are_the_params_defaults(command):
    group_ctx = click.Context(cli)
    cmd = cli.get_command(group_ctx, command)
    assert cmd is not None
    ctx = click.Context(cmd, parent=group_ctx, info_name=command)
    fields = {f.name: f for f in dataclasses.fields(STAGES[command]) if f.default is not dataclasses.MISSING}
    shared = [p for p in cmd.params if p.name in fields]
    assert len(shared) >= 2, [p.name for p in shared]  # the scan sees the options (a renamed field would hide)
    differ = {p.name: (_cli_default(ctx, p), fields[p.name].default) for p in shared
              if _cli_default(ctx, p) != fields[p.name].default}
    assert not differ, differ

"""Every command's ``--help`` teaches in one screen: its common options first, one line each, the expert ones
under their own heading, and no history (issue or session numbers, dates) in any help text.

Rendered at 100 columns, the width the group caps its help at (``max_content_width``).
"""

from __future__ import annotations

import re

import click
import pytest
from click.testing import CliRunner

from foliage_tools.cli.helpformat import EXPERT_HEADING, FoliageCommand
from foliage_tools.cli.main import cli

COMMANDS = sorted(cli.commands)
#: A screen: the lines before the expert options.
SCREEN = 60
HISTORY = re.compile(r"session\s*[0-9]|issue\s*#|#\d+\b|\b20\d\d-\d\d", re.IGNORECASE)


def _help(*args: str) -> str:
    result = CliRunner().invoke(cli, [*args, "--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    return result.output


def _section(text: str, heading: str) -> list[str]:
    """The lines of one help section (``Options:``), up to the blank line that ends it."""
    lines = text.splitlines()
    start = lines.index(f"{heading}:") + 1
    end = next((i for i in range(start, len(lines)) if not lines[i].strip()), len(lines))
    return lines[start:end]


def _entries(section: list[str]) -> list[list[str]]:
    """The section's lines grouped by option: an entry starts at two spaces and a dash."""
    entries: list[list[str]] = []
    for line in section:
        if re.match(r"  -", line):
            entries.append([line])
        else:
            entries[-1].append(line)
    return entries


def test_every_command_lays_out_its_help_with_the_common_options_first():
    for name in COMMANDS:
        assert isinstance(cli.commands[name], FoliageCommand), name


@pytest.mark.parametrize("name", COMMANDS)
def test_the_common_options_fit_one_screen_one_line_each(name):
    text = _help(name)
    screen = text.split(f"\n{EXPERT_HEADING}:")[0].splitlines()
    assert len(screen) <= SCREEN, f"foliage {name} --help: {len(screen)} lines before the expert options"
    for entry in _entries(_section(text, "Options")):
        name_only = len(entry[0].split()) <= 3 and len(entry) == 2  # an option wider than the column: help below it
        assert len(entry) == 1 or name_only, f"foliage {name} --help: more than one line for\n" + "\n".join(entry)


@pytest.mark.parametrize("name", COMMANDS)
def test_expert_options_are_under_their_heading_and_none_is_lost(name):
    command = cli.commands[name]
    text = _help(name)
    options = [p for p in command.params if isinstance(p, click.Option) and not p.hidden]
    expert = [p for p in options if not command.is_common(p)]
    if expert:
        listed = text.split(f"\n{EXPERT_HEADING}:")[1]
        for p in expert:
            assert p.opts[-1] in listed, (name, p.opts)
    for p in options:
        assert text.count(f"  {p.opts[0]}") >= 1, (name, p.opts)


@pytest.mark.parametrize("name", [None, *COMMANDS])
def test_no_help_carries_history(name):
    text = _help(*([name] if name else []))
    found = HISTORY.findall(text)
    assert not found, f"foliage {name or ''} --help mentions {found}"


def test_resolution_is_described_the_same_way_by_every_command():
    helps = {name: p.help for name, c in cli.commands.items() for p in c.params if p.name == "resolution"}
    assert len(helps) >= 5, helps
    assert len(set(helps.values())) == 1, helps

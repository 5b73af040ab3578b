"""The one error family users see, and the exit codes it maps to.

Every user-facing failure raises a :class:`FoliageError` subclass whose message
names the file, the prim (``<...>``) and what to do. The command line maps the
class to an exit code in one place (``cli/main.py``); anything else is an
internal error (exit 3, with a crash log).
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_FINDINGS = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130


class FoliageError(Exception):
    """Base class for failures caused by the user's input or environment."""

    exit_code = EXIT_BAD_INPUT


class InputError(FoliageError):
    """The input file is missing, unreadable, not USD, or holds unusable data."""


class UsageError(FoliageError):
    """Options that cannot be combined or are out of range."""


class OutputError(FoliageError):
    """An output cannot be written (unwritable directory, output == input, ...)."""


class FindingsError(FoliageError):
    """Validation found problems, or a bake failed its own accuracy check."""

    exit_code = EXIT_FINDINGS

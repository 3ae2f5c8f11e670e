"""How an expected failure ends a command: one line on stderr and an exit status, or the traceback with ``--debug``.

One place for it, so that every command ends the same way (no traceback reaches a user for an expected failure)
and ``--debug`` shows the traceback wherever a command has the option.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import typer

from colonlight import ColonlightError, OptionError

from .display import error_line

#: Exit status of a command that ran and failed.
FAILED = 1
#: Exit status of an argument that cannot be used (typer's own for a bad option).
USAGE = 2


@contextmanager
def ends_command(
    code: int, debug: bool = False, kinds: tuple[type[Exception], ...] = (ColonlightError,)
) -> Iterator[None]:
    """An error of ``kinds`` raised in the block ends the command: its message as one line, exit status ``code``
    (``USAGE`` for an ``OptionError``: a value the user gave, wherever it was found bad, such as an environment
    variable read only when needed); with ``debug``, the error itself, traceback and all."""
    try:
        yield
    except kinds as exc:
        if debug:
            raise
        error_line(str(exc))
        raise typer.Exit(USAGE if isinstance(exc, OptionError) else code) from None

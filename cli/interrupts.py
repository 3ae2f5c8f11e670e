"""Signals that stop a command as Ctrl-C does: one mechanism for every command that writes files.

Python's default for SIGTERM is to die on the spot: no ``finally`` runs, so a write in flight left its temporary,
a render pool its workers' semaphores, and the shell saw no word of why. Raised as a ``KeyboardInterrupt`` instead,
the atomic writers delete their temporaries, pools shut down, and the command ends with one line and exit code 143
(130 for Ctrl-C). ``enhance`` takes SIGINT this way too (its batch's clean-up must not be cut short by a second
Ctrl-C); ``stream`` stops its source gracefully instead; ``serve`` leaves signals to uvicorn. The console
script's entry (``entry.py``) takes SIGTERM this way while the command line loads, so this module imports
nothing heavy at its top.
"""

from __future__ import annotations

import functools
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import ParamSpec, TypeVar

INTERRUPTED = "interrupted; rerun the same command to resume"

P = ParamSpec("P")
R = TypeVar("R")


@contextmanager
def signals_interrupt(
    signals: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM),
) -> Iterator[list[int]]:
    """Within the block, the first of ``signals`` raises ``KeyboardInterrupt``, once: a second signal during the
    clean-up is ignored, so that the clean-up finishes. Yields the list the signal's number lands in.

    Outside the main thread (where signal handlers cannot be set) nothing changes.
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        if received:
            return
        received.append(signum)
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, handler) for s in signals}
    try:
        yield received
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def exit_code(received: list[int]) -> int:
    """The exit code of an interrupted command: 143 for SIGTERM, 130 for Ctrl-C (the shells' 128 + signal)."""
    return 143 if received == [signal.SIGTERM] else 130


def interruptible(command: Callable[P, R]) -> Callable[P, R]:
    """``command`` with SIGTERM raised as ``KeyboardInterrupt`` while it runs (:func:`signals_interrupt`), and
    either signal ending it with :data:`INTERRUPTED` and :func:`exit_code`. The signature is kept, for typer."""
    import typer

    from .display import error_line

    @functools.wraps(command)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        with signals_interrupt((signal.SIGTERM,)) as received:
            try:
                return command(*args, **kwargs)
            except KeyboardInterrupt:
                error_line(INTERRUPTED)
                raise typer.Exit(exit_code(received)) from None

    return run

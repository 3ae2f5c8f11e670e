"""SIGTERM stops a command as Ctrl-C does, for the commands without a signal handler of their own (``enhance`` and
``stream`` have theirs; ``serve`` leaves signals to uvicorn).

Python's default for SIGTERM is to die on the spot: no ``finally`` runs, so a write in flight left its temporary,
a render pool its workers' semaphores, and the shell saw no word of why. As a ``KeyboardInterrupt`` the atomic
writers delete their temporaries, pools shut down, and the command ends with one line and exit code 143
(130 for Ctrl-C).
"""

from __future__ import annotations

import functools
import signal
import threading
from collections.abc import Callable
from typing import ParamSpec, TypeVar

import typer

from .display import error_line

INTERRUPTED = "interrupted; rerun the same command to resume"

P = ParamSpec("P")
R = TypeVar("R")


def interruptible(command: Callable[P, R]) -> Callable[P, R]:
    """``command`` with SIGTERM raised as ``KeyboardInterrupt`` while it runs, and either signal ending it with
    :data:`INTERRUPTED` and exit code 143 (SIGTERM) or 130 (SIGINT). The signature is kept, for typer."""

    @functools.wraps(command)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        terminated: list[int] = []

        def on_sigterm(signum: int, frame: object) -> None:
            terminated.append(signum)
            raise KeyboardInterrupt

        main = threading.current_thread() is threading.main_thread()  # handlers can only be set there
        previous = signal.signal(signal.SIGTERM, on_sigterm) if main else None
        try:
            return command(*args, **kwargs)
        except KeyboardInterrupt:
            error_line(INTERRUPTED)
            raise typer.Exit(143 if terminated else 130) from None
        finally:
            if main:
                signal.signal(signal.SIGTERM, previous)

    return run

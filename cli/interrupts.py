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
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import CodeType, FrameType
from typing import Any, ParamSpec, TypeVar

INTERRUPTED = "interrupted; rerun the same command to resume"
_REDELIVER_S = 0.005

P = ParamSpec("P")
R = TypeVar("R")


@contextmanager
def signals_interrupt(
    signals: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM),
) -> Iterator[list[int]]:
    """Within the block, the first of ``signals`` raises ``KeyboardInterrupt``, once: a second signal during the
    clean-up is ignored, so that the clean-up finishes. Yields the list the signal's number lands in. An interrupt
    raised where Python swallows exceptions (a weakref callback, ``__del__``) is raised again where it can act.

    Outside the main thread (where signal handlers cannot be set) nothing changes.
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    redeliver: list[bool] = []
    own = signals[0]  # the signal an interrupt is delivered again by: its handler is ours

    def handler(signum: int, frame: FrameType | None) -> None:
        if redeliver and _running(frame, unraisable.__code__):
            _deliver_soon(own)  # not inside the hook, where it would be swallowed again
            return
        if received and not redeliver:
            return
        redeliver.clear()
        if not received:
            received.append(signum)
        raise KeyboardInterrupt

    previous_hook = sys.unraisablehook

    def unraisable(args: Any) -> None:
        # The interrupt was raised where Python cannot pass an exception on (a weakref callback, say importlib's
        # module-lock one, or a __del__): it would be lost, the command would run on to the end, and stderr would
        # show "Exception ignored ... KeyboardInterrupt". It is delivered again, at the next point that can take it.
        if args.exc_type is not None and issubclass(args.exc_type, KeyboardInterrupt):
            if not received:  # Python's own Ctrl-C handler raised it
                received.append(signal.SIGINT)
            redeliver.append(True)
            _deliver_soon(own)
            return
        previous_hook(args)

    previous = {s: signal.signal(s, handler) for s in signals}
    sys.unraisablehook = unraisable
    try:
        yield received
    finally:
        sys.unraisablehook = previous_hook
        for s, h in previous.items():
            signal.signal(s, h)


def _deliver_soon(signum: int) -> None:
    """Have ``signum``'s handler run in the main thread a few milliseconds from now, from another thread: by then
    the code that swallowed the interrupt has returned (tripping it from there would run the handler there)."""

    main = threading.main_thread().ident

    def trip() -> None:
        time.sleep(_REDELIVER_S)
        if main is not None:
            signal.pthread_kill(main, signum)

    threading.Thread(target=trip, name="colonlight-interrupt", daemon=True).start()


def _running(frame: FrameType | None, code: CodeType) -> bool:
    """Whether ``code`` is running in ``frame`` or any frame that called it."""
    while frame is not None:
        if frame.f_code is code:
            return True
        frame = frame.f_back
    return False


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

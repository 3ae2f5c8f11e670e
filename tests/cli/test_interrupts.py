"""``signals_interrupt``, in this process with real signals: an interrupt that Python swallows is raised again.

CI caught ``synth`` stopped by SIGTERM running on to the end with exit 0: the handler's ``KeyboardInterrupt`` was
raised inside importlib's module-lock weakref callback, where Python only prints "Exception ignored" and goes on.
"""

from __future__ import annotations

import gc
import signal
import time
import weakref
from collections.abc import Iterator

import pytest
from colonlight_cli.interrupts import signals_interrupt


class _Thing:
    pass


def _signal_inside_a_weakref_callback(signum: int) -> None:
    """Deliver ``signum`` while a weakref callback runs, so that its handler raises there."""

    def callback(_ref: object) -> None:
        signal.raise_signal(signum)  # the handler runs at the next instruction boundary: inside this callback
        sum(range(10))

    thing = _Thing()
    ref = weakref.ref(thing, callback)
    del thing  # the callback runs now (reference counting): an exception it raises is "ignored"
    gc.collect()
    assert ref() is None


@pytest.fixture
def python_handles_ctrl_c() -> Iterator[None]:
    """Ctrl-C's handler as Python installs it (a shell that starts a job in the background leaves SIGINT ignored,
    and Python then keeps it so)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("python_handles_ctrl_c")
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_an_interrupt_swallowed_by_a_weakref_callback_is_raised_again(
    signum: int, capsys: pytest.CaptureFixture[str]
) -> None:
    reached: list[str] = []
    with pytest.raises(KeyboardInterrupt), signals_interrupt((signal.SIGTERM,)) as received:
        _signal_inside_a_weakref_callback(signum)
        deadline = time.monotonic() + 10  # the interrupt is raised again within milliseconds, long before this
        while time.monotonic() < deadline:
            sum(range(10))
        reached.append("the block ran on to its end")
    assert not reached
    assert received == [signum]  # Ctrl-C's, raised by Python's own handler, is told apart: exit 130, not 143
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_second_signal_during_the_clean_up_is_still_ignored() -> None:
    with pytest.raises(KeyboardInterrupt), signals_interrupt((signal.SIGTERM,)) as received:
        try:
            signal.raise_signal(signal.SIGTERM)
            sum(range(10))
        finally:
            signal.raise_signal(signal.SIGTERM)  # ignored: the clean-up finishes
            cleaned = True
    assert cleaned and received == [signal.SIGTERM]

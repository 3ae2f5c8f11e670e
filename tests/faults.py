"""Faults injected where a real signal cannot be aimed: an interrupt at one exact point of colonlight's writes."""

from __future__ import annotations

import os
from typing import Any

import pytest

import colonlight.atomic


class _OsInterruptingOpen:
    """``os`` as ``colonlight.atomic`` sees it, except that its ``nth`` ``open`` that creates a file raises
    ``KeyboardInterrupt`` (what the CLI's SIGTERM handler raises) once the file exists."""

    def __init__(self, nth: int, made: list[str]) -> None:
        self._nth, self._made = nth, made

    def __getattr__(self, name: str) -> Any:
        return getattr(os, name)

    def open(self, path: Any, flags: int, mode: int = 0o777, **kwargs: Any) -> int:
        fd = os.open(path, flags, mode, **kwargs)
        if flags & os.O_CREAT:
            self._made.append(os.fspath(path))
            if len(self._made) == self._nth:
                os.close(fd)
                raise KeyboardInterrupt
        return fd


def interrupt_after_creating(monkeypatch: pytest.MonkeyPatch, nth: int) -> list[str]:
    """From now on in the test, the ``nth`` temporary ``colonlight.atomic`` creates is interrupted just after its
    file exists, before any caller holds its name. Returns the list of the temporaries created, as they are."""
    made: list[str] = []
    monkeypatch.setattr(colonlight.atomic, "os", _OsInterruptingOpen(nth, made))
    return made

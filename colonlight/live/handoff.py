"""A bounded hand-off from the reader thread to the processing loop, which drops frames instead of queueing them.

A live source does not wait: when the processing loop falls behind, a queue would grow without bound and every
frame would come out later than the one before. Here at most ``capacity`` frames wait; a new frame either
replaces the oldest waiting one (``oldest``: the output stays as fresh as possible), is itself discarded
(``newest``: the frames that are processed stay evenly spaced), or, for a file read as fast as possible, makes the
reader wait (``never``). Every discarded frame is counted.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")

DROP_POLICIES = ("oldest", "newest", "never")


class HandoffClosed(Exception):
    """Raised by :meth:`FrameHandoff.get` once the producer has finished and nothing is left."""


class FrameHandoff(Generic[T]):
    """Single producer, single consumer, ``capacity`` items, a drop policy; thread-safe."""

    def __init__(self, capacity: int, policy: str = "oldest") -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if policy not in DROP_POLICIES:
            raise ValueError(f"drop policy must be one of {', '.join(DROP_POLICIES)}, got {policy!r}")
        self.capacity = capacity
        self.policy = policy
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._cancelled = False
        self.accepted = 0  # items put (dropped ones included)
        self.dropped = 0

    def put(self, item: T) -> None:
        """Hand over ``item``; may drop it or the oldest item, or wait (``never``) until there is room."""
        with self._cond:
            self.accepted += 1
            if self._cancelled:
                self.dropped += 1
                return
            if len(self._items) >= self.capacity:
                if self.policy == "newest":
                    self.dropped += 1
                    return
                if self.policy == "oldest":
                    self._items.popleft()
                    self.dropped += 1
                else:
                    while len(self._items) >= self.capacity and not self._cancelled:
                        self._cond.wait(0.1)
                    if self._cancelled:
                        self.dropped += 1
                        return
            self._items.append(item)
            self._cond.notify_all()

    def get(self, timeout: float) -> T | None:
        """The oldest waiting item; None after ``timeout`` seconds without one; HandoffClosed at the end."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if self._items:
                item = self._items.popleft()
                self._cond.notify_all()
                return item
            if self._closed:
                raise HandoffClosed
            return None

    def close(self) -> None:
        """The producer is done: :meth:`get` drains what is left, then raises HandoffClosed."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def cancel(self) -> int:
        """The consumer stops: discard what waits (counted as dropped), release a waiting producer; return how many."""
        with self._cond:
            self._cancelled = True
            n = len(self._items)
            self.dropped += n
            self._items.clear()
            self._closed = True
            self._cond.notify_all()
            return n

    @property
    def cancelled(self) -> bool:
        return self._cancelled

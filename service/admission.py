"""Admission and the queue: uploads being received, jobs admitted, waiting and running, under one lock.

Uploads in flight and jobs are counted apart: at most ``max_uploads`` uploads are received (and checked) at once,
and a job is admitted only once its upload is complete and checked, so a slow or stalled client holds an upload
place, never a place in the queue. Admission counts jobs that are queued or running (and clips of
``POST /v1/enhance``); at most ``workers + queue_size`` at once.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from .errors import ApiError
from .metrics import Metrics
from .model_status import ModelStatus
from .runners import ClipHooks
from .settings import Settings
from .uploads import CLOSE


@dataclass
class Admission:
    """A place among the admitted jobs; released on error, handed to the job on success."""

    board: JobBoard
    held: bool = True

    def release(self) -> None:
        if self.held:
            self.held = False
            self.board.release()

    def transfer(self) -> None:
        self.held = False  # the job now owns the place; it is released when the job finishes


class JobBoard:
    """Who holds a place: the counts behind 503s, the waiting and running clips (by job id, or a sync token) with
    their hooks, and the frames each running job has done. ``lock`` is re-entrant, so that a caller can hold it
    across a change of the job table and the board (a job deleted while it starts)."""

    def __init__(self, settings: Settings, metrics: Metrics, model: ModelStatus) -> None:
        self.settings = settings
        self.metrics = metrics
        self.model = model
        self.lock = threading.RLock()
        self._admitted = 0
        self._uploading = 0
        self._queued: set[str] = set()
        self._running: dict[str, ClipHooks] = {}
        self._progress: dict[str, int] = {}
        self._stopping = False

    # ------------------------------------------------------------------------------------------ admission

    def _refusal(self) -> ApiError | None:
        """Why a job would not be admitted now (model failed, shutting down, queue full); call with the lock."""
        retry = {"Retry-After": str(self.settings.retry_after_seconds), **CLOSE}
        if self.model.state == "failed":
            return ApiError(503, "model_unavailable", f"the model could not be loaded: {self.model.message}", CLOSE)
        if self._stopping:
            return ApiError(503, "shutting_down", "the server is shutting down", retry)
        if self._admitted >= self.settings.capacity:
            self.metrics.inc("rejected", "queue_full")
            return ApiError(
                503,
                "queue_full",
                f"all {self.settings.workers} workers are busy and the queue of {self.settings.queue_size} is full; "
                f"retry in {self.settings.retry_after_seconds} s",
                retry,
            )
        return None

    @contextmanager
    def receiving(self) -> Iterator[None]:
        """An upload place for the time an upload is received and checked, or 503 before its body is read.

        Refused at once, too, when no job would be admitted now (so that nobody sends gigabytes to be told so);
        but this holds no place in the queue: that is taken by :meth:`admit` once the upload is complete.
        """
        with self.lock:
            refusal = self._refusal()
            if refusal is None and self._uploading >= self.settings.max_uploads:
                self.metrics.inc("rejected", "too_many_uploads")
                refusal = ApiError(
                    503,
                    "too_many_uploads",
                    f"{self.settings.max_uploads} uploads are being received already (COLONLIGHT_MAX_UPLOADS); "
                    f"retry in {self.settings.retry_after_seconds} s",
                    {"Retry-After": str(self.settings.retry_after_seconds), **CLOSE},
                )
            if refusal is not None:
                raise refusal
            self._uploading += 1
        try:
            yield
        finally:
            with self.lock:
                self._uploading -= 1

    def admit(self) -> Admission:
        """A place for one more job (its upload complete and checked), or 503 (queue full, model failed, stopping)."""
        with self.lock:
            refusal = self._refusal()
            if refusal is not None:
                raise refusal
            self._admitted += 1
        return Admission(self)

    def readmit(self) -> None:
        """A place for a job resumed after a restart (admitted then; not refused now)."""
        with self.lock:
            self._admitted += 1

    def release(self) -> None:
        with self.lock:
            self._admitted -= 1

    # ------------------------------------------------------------------------------------------ the queue

    def waiting(self, key: str) -> None:
        """``key`` waits for a worker."""
        with self.lock:
            self._queued.add(key)

    def begin(self, key: str, hooks: ClipHooks, claim: Callable[[], bool] = lambda: True) -> bool:
        """``key`` starts running, unless the server is stopping or ``claim()`` (called with the lock) says no."""
        with self.lock:
            if self._stopping or not claim():
                return False
            self._queued.discard(key)
            self._running[key] = hooks
            self._progress[key] = 0
        return True

    def advance(self, key: str, frames: int) -> int:
        """Record that ``key`` has done ``frames`` frames; returns how many more than before."""
        with self.lock:
            before = self._progress.get(key, 0)
            self._progress[key] = frames
        return frames - before

    def end(self, key: str) -> bool:
        """``key`` is finished (or was never started) and gives its place back; returns whether it had run."""
        with self.lock:
            self._queued.discard(key)
            was_running = self._running.pop(key, None) is not None
            self._progress.pop(key, None)
            self._admitted -= 1
        return was_running

    def frames_done(self, key: str, default: int) -> int:
        with self.lock:
            return self._progress.get(key, default)

    def hooks(self, key: str) -> ClipHooks | None:
        """The hooks of ``key`` while it runs."""
        with self.lock:
            return self._running.get(key)

    def running_keys(self) -> set[str]:
        with self.lock:
            return set(self._running)

    @property
    def stopping(self) -> bool:
        return self._stopping

    def stop(self) -> None:
        """Refuse from now on, and stop every running clip at its next frame."""
        with self.lock:
            self._stopping = True
            for hooks in self._running.values():
                hooks.stop_reason = "shutdown"
                hooks.cancel.set()

    # ------------------------------------------------------------------------------------------ state

    def queue_state(self) -> tuple[int, int, int]:
        """(waiting, running, admitted)."""
        with self.lock:
            return len(self._queued), len(self._running), self._admitted

    def uploads_in_flight(self) -> int:
        """Uploads being received or checked now (they hold no place in the queue)."""
        with self.lock:
            return self._uploading

    def readiness(self) -> tuple[bool, str, str]:
        """(ready, status, message): ready when the model is loaded and a job would be admitted."""
        if self.model.state != "ready":
            return False, self.model.state, self.model.message
        admitted = self.queue_state()[2]
        if self._stopping:
            return False, "busy", "shutting down"
        if admitted >= self.settings.capacity:
            return False, "busy", "all workers are busy and the queue is full"
        return True, "ready", "model loaded; accepting jobs"

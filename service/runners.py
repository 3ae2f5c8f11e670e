"""Where clips run: the executor seam between the job manager and the engine.

A runner takes one clip (``ClipJob``, ``MethodSpec``, ``ClipOptions``) and returns a future of the engine's
``ClipOutcome``. Two exist:

* :class:`LocalRunner` (default): a bounded pool of ``workers`` threads in the server process, sharing the
  methods loaded at start-up. The engine releases the GIL in decoding, the network and encoding, so the event
  loop stays responsive; memory stays flat because the pipeline streams frames through bounded queues.
* :class:`ClusterRunner`: ``COLONLIGHT_CLUSTER=tcp://host:8786`` sends clips to a Dask cluster through
  ``colonlight.cluster`` (imported only then). Job folders must be on storage the cluster's workers share.

Both run a clip as ``colonlight enhance`` does (``colonlight.run_clip``).
"""

from __future__ import annotations

import threading
import traceback
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol

from colonlight import ClipJob, ClipOptions, ClipOutcome, ColonlightError, Method, MethodSpec, run_clip
from colonlight.errors import resource_shortage

from .errors import is_disk_full

#: ``ClipOutcome.detail`` of a clip that failed because the data folder is full (a 507, not the clip's fault).
DISK_FULL = "disk_full"
NO_SPACE = "no space left in the server's data folder to write its results"


class Stopped(Exception):
    """Raised inside a running clip (from the frame callback) to stop it: deleted, shut down, or over a limit."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass
class ClipHooks:
    """How a runner reports back. ``started()`` returns False when the clip must be skipped (job deleted);
    ``frames(n)`` may raise :class:`Stopped`; setting ``cancel`` stops a running clip at its next frame."""

    started: Callable[[], bool] = lambda: True
    frames: Callable[[int], None] = lambda n: None
    cancel: threading.Event = field(default_factory=threading.Event)
    stop_reason: str = "cancelled"


class ClipRunner(Protocol):
    def submit(self, job: ClipJob, spec: MethodSpec, opts: ClipOptions, hooks: ClipHooks) -> Future[ClipOutcome]: ...

    def shutdown(self) -> None: ...


class MethodCache:
    """Methods built once and shared by the worker threads: the default one pinned (loaded at start-up), up to
    ``size`` others kept by least-recent use, so that requests with ever new options cannot grow memory."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._pinned: dict[MethodSpec, Method] = {}
        self._lru: OrderedDict[MethodSpec, Method] = OrderedDict()
        self._lock = threading.Lock()
        self._building: dict[MethodSpec, threading.Lock] = {}

    def pin(self, spec: MethodSpec) -> Method:
        method = self.get(spec)
        with self._lock:
            self._pinned[spec] = method
            self._lru.pop(spec, None)
        return method

    def get(self, spec: MethodSpec) -> Method:
        """The method for ``spec``, built on first use (OptionError, a ColonlightError, for bad options)."""
        with self._lock:
            if spec in self._pinned:
                return self._pinned[spec]
            if spec in self._lru:
                self._lru.move_to_end(spec)
                return self._lru[spec]
            build_lock = self._building.setdefault(spec, threading.Lock())
        with build_lock:  # one build per spec, even when two requests ask at once
            try:
                with self._lock:
                    if spec in self._lru:
                        return self._lru[spec]
                method = spec.build()
                with self._lock:
                    self._lru[spec] = method
                    while len(self._lru) > self.size:
                        self._lru.popitem(last=False)
            finally:
                with self._lock:
                    self._building.pop(spec, None)
        return method


def service_wording(job: ClipJob, exc: Exception) -> tuple[str, str | None]:
    """The service's words for a clip that raised (``colonlight.run_clip``'s ``wording``): a stop and a full data
    folder are told apart by ``detail``; no line names a server path beyond what ``JobManager.scrub`` removes."""
    if isinstance(exc, Stopped):
        return f"stopped: {exc.reason}", "stopped"
    if is_disk_full(exc):
        return NO_SPACE, DISK_FULL
    if isinstance(exc, (ColonlightError, ValueError)):  # a ValueError from deep in a clip is the clip's, too
        return str(exc), None
    shortage = resource_shortage(exc)
    if shortage is not None:
        return shortage, traceback.format_exc()
    return f"internal error: {type(exc).__name__}: {exc}", traceback.format_exc()


def run_one(job: ClipJob, method: Method, opts: ClipOptions, hooks: ClipHooks) -> ClipOutcome:
    """One clip through the engine's ``run_clip`` (always overwriting: a job folder is new), with the hooks."""
    if not hooks.started():
        return ClipOutcome(job.name, str(job.source), "failed", error="cancelled before it started")

    def on_frame(n: int) -> None:
        if hooks.cancel.is_set():
            raise Stopped(hooks.stop_reason)
        hooks.frames(n)

    return run_clip(job, method, opts, overwrite=True, on_frame=on_frame, wording=service_wording)


class LocalRunner:
    """``workers`` threads in this process; methods come from ``methods`` (shared, thread-safe streams)."""

    def __init__(self, workers: int, methods: MethodCache) -> None:
        self.methods = methods
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="colonlight-job")

    def submit(self, job: ClipJob, spec: MethodSpec, opts: ClipOptions, hooks: ClipHooks) -> Future[ClipOutcome]:
        def work() -> ClipOutcome:
            try:
                method = self.methods.get(spec)
            except ColonlightError as exc:
                hooks.started()
                return ClipOutcome(job.name, str(job.source), "failed", error=str(exc))
            return run_one(job, method, opts, hooks)

        return self._pool.submit(work)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class ClusterRunner:
    """Clips run on a Dask cluster via ``colonlight.cluster.ClusterRunner``; ``workers`` bounds the clips in
    flight from this server. No per-frame progress or mid-clip cancellation on this path."""

    def __init__(self, address: str, workers: int) -> None:
        from colonlight import ClusterRunner as EngineClusterRunner  # optional: imported only when used

        self._cluster = EngineClusterRunner(address)
        self._waiters = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="colonlight-cluster")

    def submit(self, job: ClipJob, spec: MethodSpec, opts: ClipOptions, hooks: ClipHooks) -> Future[ClipOutcome]:
        def wait() -> ClipOutcome:
            if not hooks.started():
                return ClipOutcome(job.name, str(job.source), "failed", error="cancelled before it started")
            outcome: ClipOutcome = self._cluster.submit(job, spec, opts, True).result()
            return outcome

        return self._waiters.submit(wait)

    def shutdown(self) -> None:
        self._waiters.shutdown(wait=False, cancel_futures=True)
        self._cluster.close()

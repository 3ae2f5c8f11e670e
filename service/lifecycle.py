"""A job's life: created from a checked upload, queued on the runner, running (progress kept in memory and
saved every second), finished ('succeeded' | 'failed'), deleted; and resumed after a restart.

A job that fails loses its upload (and its uploaded content mask) at once; its results (if any) are kept until
the TTL. After a crash, jobs left 'queued' or 'running' are resumed at the next start (the pipeline redoes a clip
from scratch; an uploaded content mask is kept in the job's folder for it), unless one has already been started
``max_attempts`` times, in which case it is marked failed with the reason.
"""

from __future__ import annotations

import asyncio
import logging
import os
import secrets
import sqlite3
import time
from collections.abc import Callable
from concurrent.futures import CancelledError, Future
from pathlib import Path
from typing import Any

import anyio

from colonlight import ClipJob, ClipOptions, ClipOutcome, MethodSpec, estimate_frames

from .admission import Admission, JobBoard
from .errors import ApiError, is_disk_full, storage_full
from .memory import FrameCollector, release_free_memory
from .metrics import Metrics
from .results import label_source, mask_label
from .runners import DISK_FULL, NO_SPACE, ClipHooks, ClipRunner
from .settings import Settings
from .store import JobRecord, JobStore
from .uploads import Upload, safe_suffix
from .workspace import MASK_NAME, Workspace, remove

log = logging.getLogger("colonlight.service")

_PROGRESS_FLUSH_S = 1.0
JOB_ID_PATTERN = r"^[A-Za-z0-9_-]{22}$"


def new_job_id() -> str:
    """128 random bits, URL-safe (22 characters)."""
    return secrets.token_urlsafe(16)


class JobLifecycle:
    """Creates, runs, finishes, deletes and recovers jobs. ``store`` and ``runner`` are set when the server
    starts; ``plan`` turns a job's recorded options (and its folder, which holds an uploaded content mask) into the
    engine's method and clip options (it raises :class:`ApiError` or ``ValueError`` for options that are no
    longer valid)."""

    def __init__(
        self,
        settings: Settings,
        workspace: Workspace,
        board: JobBoard,
        metrics: Metrics,
        collector: FrameCollector,
        limiter: anyio.CapacityLimiter,
        plan: Callable[[dict[str, Any], Path], tuple[MethodSpec, ClipOptions]],
    ) -> None:
        self.settings = settings
        self.workspace = workspace
        self.board = board
        self.metrics = metrics
        self.collector = collector
        self.limiter = limiter
        self.plan = plan
        self.store: JobStore | None = None
        self.runner: ClipRunner | None = None

    async def create(
        self, admission: Admission, upload: Upload, options: dict[str, Any], fps: float | None
    ) -> JobRecord:
        """The job of a checked upload: its folder, its row (``options``: the resolved options it records; ``fps``
        the rate its frames are counted at), then queued."""
        assert self.store is not None
        job_id = new_job_id()
        input_name = "input" + safe_suffix(upload.filename)
        job_dir = self.workspace.job_dir(job_id)

        def place() -> int | None:
            job_dir.mkdir(parents=True)
            os.replace(upload.path, job_dir / input_name)
            if upload.mask is not None:
                os.replace(upload.mask.path, job_dir / MASK_NAME)
            return estimate_frames(job_dir / input_name, fps or None)

        try:
            total = await anyio.to_thread.run_sync(place, limiter=self.limiter)
            rec = JobRecord(
                id=job_id,
                status="queued",
                filename=upload.filename,
                input_name=input_name,
                input_bytes=upload.size,
                options=options,
                created_at=time.time(),
                frames_total=total,
            )
            await asyncio.to_thread(self.store.insert, rec)
        except BaseException as exc:
            await asyncio.to_thread(remove, job_dir)
            if is_disk_full(exc):
                raise storage_full() from None
            raise
        admission.transfer()
        self.metrics.inc("submitted")
        # off the event loop: planning reads the job's content mask (up to a 16 MiB PGM, ~100 ms), and every other
        # request would wait for it; the board, the store and the runners' pools are thread-safe
        await asyncio.to_thread(self.enqueue, rec)
        return rec

    def enqueue(self, rec: JobRecord) -> None:
        assert self.runner is not None and self.store is not None
        job_dir = self.workspace.job_dir(rec.id)
        job = ClipJob(
            source=job_dir / rec.input_name, name=Path(rec.filename).stem or "upload", out_dir=job_dir / "out"
        )
        store, job_id, board = self.store, rec.id, self.board
        hooks = ClipHooks()
        last_flush = [0.0]

        def started() -> bool:
            return board.begin(job_id, hooks, claim=lambda: store.mark_running(job_id) is not None)  # None: deleted

        def frames(n: int) -> None:
            more = board.advance(job_id, n)
            self.metrics.inc("frames", by=more)
            self.collector.count(more)
            now = time.monotonic()
            if now - last_flush[0] >= _PROGRESS_FLUSH_S:
                last_flush[0] = now
                try:
                    store.update(job_id, frames_done=n)
                except sqlite3.Error as exc:  # e.g. a full disk: progress is also kept in memory, the clip goes on
                    log.warning("job %s: progress not saved: %s", job_id, exc)

        hooks.started, hooks.frames = started, frames
        board.waiting(job_id)
        try:
            spec, clip_opts = self.plan(rec.options, job_dir)
        except (ApiError, ValueError) as exc:  # options that were valid once but no longer are (settings changed)
            self.fail(rec, self._scrub(rec, job, getattr(exc, "message", str(exc))))
            board.end(job_id)
            return
        future = self.runner.submit(job, spec, clip_opts, hooks)
        future.add_done_callback(lambda f: self._finished(rec, job, f, hooks))

    def _finished(self, rec: JobRecord, job: ClipJob, future: Future[ClipOutcome], hooks: ClipHooks) -> None:
        assert self.store is not None
        job_id = rec.id
        was_running = self.board.end(job_id)
        try:
            outcome: ClipOutcome | None = future.result()
        except CancelledError:
            outcome = None  # shut down before it started: still 'queued' on disk, resumed at the next start
        except Exception as exc:  # noqa: BLE001 - e.g. the cluster lost the task, or the job table had no room
            full = is_disk_full(exc)
            outcome = ClipOutcome(
                job.name,
                str(job.source),
                "failed",
                detail=DISK_FULL if full else None,
                error=NO_SPACE if full else f"worker failed: {exc}",
            )
        if outcome is None:
            return
        if not was_running and hooks.stop_reason != "deleted" and self.board.stopping:
            return  # not started because of shutdown: stays 'queued'
        if hooks.cancel.is_set() and hooks.stop_reason == "shutdown":
            self.store.requeue(job_id, "interrupted by a server shutdown; resumed at the next start")
            return
        now = time.time()
        if outcome.status == "done":
            outcome = label_source(outcome, job, rec.filename, mask_label(rec.options))
        try:
            if outcome.status == "done":
                ok = self.store.update(
                    job_id,
                    status="succeeded",
                    finished_at=now,
                    frames_done=outcome.frames,
                    frames_total=outcome.frames,
                    seconds=outcome.seconds,
                    error=None,
                )
                self.metrics.observe_job("succeeded", outcome.seconds)
            else:
                message = self._scrub(rec, job, outcome.error or "failed")
                if outcome.detail and outcome.detail not in ("stopped", DISK_FULL):
                    log.error("job %s: %s\n%s", job_id, message, outcome.detail)
                if outcome.detail == DISK_FULL:
                    remove(job.out_dir)  # partial results of no use: their room lets the failure be recorded
                ok = self.fail(rec, message, seconds=outcome.seconds)
                self.metrics.observe_job("failed", outcome.seconds)
        except sqlite3.Error as exc:  # the job table cannot take the outcome (a full disk): the restart recovers it
            log.error("job %s ended %s, but the job table could not record it: %s", job_id, outcome.status, exc)
            return
        if ok:
            self._drop_upload(rec)  # results kept, upload not
        else:
            remove(self.workspace.job_dir(job_id))  # deleted meanwhile
        release_free_memory()  # what the clip's frames used goes back to the system, not to the next peak

    def _scrub(self, rec: JobRecord, job: ClipJob, message: str) -> str:
        """An engine message about the job with the upload names in place of the server's paths."""
        mask = mask_label(rec.options)
        return self.workspace.scrub(
            message, job.source, rec.filename, None if mask is None else (job.source.parent / MASK_NAME, mask)
        )

    def _drop_upload(self, rec: JobRecord) -> None:
        """Remove the job's uploaded files (the clip and its content mask); its results stay."""
        job_dir = self.workspace.job_dir(rec.id)
        (job_dir / rec.input_name).unlink(missing_ok=True)
        (job_dir / MASK_NAME).unlink(missing_ok=True)

    def fail(self, rec: JobRecord, message: str, seconds: float | None = None) -> bool:
        """Mark the job failed and remove its upload now (whatever results it has are kept until the TTL)."""
        assert self.store is not None
        self._drop_upload(rec)
        return self.store.update(rec.id, status="failed", error=message, finished_at=time.time(), seconds=seconds)

    def recover(self) -> None:
        """Resume the jobs a stopped server left 'queued' or 'running' (or fail them, saying why)."""
        assert self.store is not None
        for rec in self.store.with_status("queued", "running"):
            source = self.workspace.job_dir(rec.id) / rec.input_name
            if rec.status == "running" and rec.attempts >= self.settings.max_attempts:
                self.fail(rec, f"interrupted by a server stop after {rec.attempts} attempt(s); not retried")
            elif not source.is_file():
                self.fail(rec, "interrupted by a server stop, and its upload is gone")
            elif mask_label(rec.options) is not None and not (source.parent / MASK_NAME).is_file():
                self.fail(rec, f"interrupted by a server stop, and its content mask {mask_label(rec.options)} is gone")
            else:
                self.store.update(rec.id, status="queued", frames_done=0, note="resumed after a server restart")
                self.board.readmit()
                self.enqueue(rec)
                log.info("job %s resumed after a restart", rec.id)

    def get(self, job_id: str) -> JobRecord | None:
        assert self.store is not None
        rec = self.store.get(job_id)
        if rec is not None and rec.status == "running":
            rec.frames_done = self.board.frames_done(job_id, rec.frames_done)
        return rec

    def delete(self, job_id: str) -> bool:
        """Remove a job and its files; a running one is stopped at its next frame and cleaned up by its worker."""
        assert self.store is not None
        with self.board.lock:
            if not self.store.delete(job_id):
                return False
            hooks = self.board.hooks(job_id)
            if hooks is not None:
                hooks.stop_reason = "deleted"
                hooks.cancel.set()
                return True
        remove(self.workspace.job_dir(job_id))
        return True

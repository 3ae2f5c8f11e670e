"""Jobs: admission (a bounded queue), the job table, running clips through a runner, restart recovery, expiry.

Life of a job::

    POST /v1/jobs -> an upload place (or 503) -> upload streamed (413, 408, 507) -> probed (413, 415)
    -> admitted (or 503) -> row 'queued' -> 202
    a worker takes it -> 'running' (frames_done advances) -> 'succeeded' | 'failed' -> swept after the TTL

Uploads in flight and jobs are counted apart: at most ``max_uploads`` uploads are received (and checked) at once,
and a job is admitted only once its upload is complete and checked, so a slow or stalled client holds an upload
place (until its body has made no progress for ``upload_idle_seconds``), never a place in the queue. Admission
counts jobs that are queued or running; at most ``workers + queue_size`` at once. A job that fails loses its
upload at once; its results (if any) are kept until the TTL. After a crash, jobs left 'queued' or 'running' are
resumed at the next start (the pipeline redoes a clip from scratch), unless one has already been started
``max_attempts`` times, in which case it is marked failed with the reason.
"""

from __future__ import annotations

import asyncio
import base64
import gc
import json
import logging
import math
import os
import secrets
import shutil
import sqlite3
import threading
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError, Future
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio

from colonlight import ClipJob, ClipOptions, ClipOutcome, ColonlightError, MethodSpec, estimate_frames
from colonlight.atomic import write_json_atomic
from colonlight.limits import MAX_FPS, available_cores
from colonlight.pipeline import GAMMAS_FILE, VIDEO_FILE
from colonlight.video import VideoInfo, probe_video

from .errors import ApiError, is_disk_full, storage_full
from .header_probe import declared_frame_size
from .memory import release_free_memory
from .metrics import Metrics
from .request_options import JobOptions, method_spec
from .runners import DISK_FULL, NO_SPACE, ClipHooks, ClipRunner, ClusterRunner, LocalRunner, MethodCache, Stopped
from .settings import Settings
from .store import JobRecord, JobStore
from .uploads import CLOSE, Upload, safe_suffix

log = logging.getLogger("colonlight.service")

_PROGRESS_FLUSH_S = 1.0
#: A full garbage collection every this many frames (server-wide). Decoded PyAV frames whose side data was read
#: sit in reference cycles and are freed only by the cyclic collector, so without this the resident memory grows
#: with clip length; after ``gc.freeze()`` at start-up a collection only scans recent objects and costs ~0.1 ms.
_GC_EVERY_FRAMES = 100
_SYNC_LEFTOVER_S = 3600.0


def new_job_id() -> str:
    """128 random bits, URL-safe (22 characters)."""
    return secrets.token_urlsafe(16)


JOB_ID_PATTERN = r"^[A-Za-z0-9_-]{22}$"


@dataclass
class Admission:
    """A place among the admitted jobs; released on error, handed to the job on success."""

    manager: JobManager
    held: bool = True

    def release(self) -> None:
        if self.held:
            self.held = False
            self.manager._release()

    def transfer(self) -> None:
        self.held = False  # the job now owns the place; it is released when the job finishes


class JobManager:
    """Everything about jobs, shared by the routes (one per app)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.root = Path(settings.data_dir).resolve()
        self.jobs_dir = self.root / "jobs"
        self.uploads_dir = self.root / "uploads"
        self.sync_dir = self.root / "sync"
        self.metrics = Metrics()
        self.methods = MethodCache(settings.method_cache)
        self.store: JobStore | None = None
        self.runner: ClipRunner | None = None
        self._lock = threading.Lock()
        self._zip_lock = threading.Lock()
        self._admitted = 0
        self._uploading = 0
        self._queued: set[str] = set()
        self._running: dict[str, ClipHooks] = {}
        self._progress: dict[str, int] = {}
        self._stopping = False
        self._frames_since_gc = 0
        self.model_state = "loading"  # loading | ready | failed
        self.model_message = "loading the model"
        self.model_info: dict[str, Any] | None = None
        self._sweeper: asyncio.Task[None] | None = None
        # Probing an upload opens a decoder (threads, frame buffers): a few at a time, so memory does not grow
        # with the number of clients uploading at once.
        self._probe_limiter = anyio.CapacityLimiter(max(2, settings.workers))
        self.default_spec = self.method_spec(JobOptions())

    # ------------------------------------------------------------------------------------------ options

    def method_spec(self, o: JobOptions) -> MethodSpec:
        """The engine's method for a request's options, with the server's weights and device."""
        return method_spec(self.settings, o)

    def resolved(self, o: JobOptions) -> JobOptions:
        """``o`` with the server's defaults filled in (what the job records and runs with)."""
        return o.model_copy(
            update={"fps": self.settings.fps if o.fps is None else o.fps, "method": o.method or self.settings.method}
        )

    def clip_options(self, o: JobOptions, frames: bool | None = None) -> ClipOptions:
        fps = self.settings.fps if o.fps is None else o.fps
        return ClipOptions(
            fps=fps or None,
            frames=o.frames if frames is None else frames,
            video=True,
            format=o.format,
            quality=o.quality,
            content=o.content,
        )

    async def check_method(self, spec: MethodSpec) -> None:
        """Build (and cache) the method for ``spec`` now, so that bad options are a 422, not a failed job."""
        if spec == self.default_spec:
            if self.model_state == "failed":
                raise ApiError(503, "model_unavailable", f"the model could not be loaded: {self.model_message}")
            return
        try:
            await asyncio.to_thread(self.methods.get, spec)
        except ColonlightError as exc:
            raise ApiError(422, "validation_error", f"method {spec.name!r} cannot be used: {exc}") from None

    # ------------------------------------------------------------------------------------------ life cycle

    async def start(self) -> None:
        for d in (self.jobs_dir, self.uploads_dir, self.sync_dir):
            d.mkdir(parents=True, exist_ok=True)
        for leftover in list(self.uploads_dir.iterdir()) + list(self.sync_dir.iterdir()):
            _remove(leftover)  # partial uploads and sync work of a process that died
        self.store = JobStore(self.root / "jobs.sqlite3")
        known = self.store.ids()
        for d in self.jobs_dir.iterdir():
            if d.name not in known:
                _remove(d)  # a job folder whose row is gone (deleted while the process died)
        try:
            self.runner = (
                ClusterRunner(self.settings.cluster, self.settings.workers)
                if self.settings.cluster
                else LocalRunner(self.settings.workers, self.methods)
            )
        except ColonlightError as exc:  # e.g. the scheduler is unreachable: reported by /readyz, submissions get 503
            self.model_state, self.model_message = "failed", str(exc)
            log.error("%s", exc)
            self._sweeper = asyncio.create_task(self._sweep_forever())
            return
        threading.Thread(target=self._load_model, name="colonlight-load-model", daemon=True).start()
        self._recover()
        self._sweeper = asyncio.create_task(self._sweep_forever())

    def _load_model(self) -> None:
        try:
            import torch

            cores = available_cores()
            torch.set_num_threads(self.settings.torch_threads or max(1, cores // self.settings.workers))
            method = self.methods.pin(self.default_spec)
            self.model_info = {"method": method.name, "model": method.model_info(), "parameters": method.parameters()}
            gc.collect()
            gc.freeze()  # the model and libraries are permanent: later collections skip them
            self.model_state, self.model_message = "ready", "model loaded"
            log.info("model ready: %s", json.dumps(self.model_info))
        except Exception as exc:  # noqa: BLE001 - reported by /readyz and by every submission
            self.model_state, self.model_message = "failed", str(exc)
            log.error("the model could not be loaded: %s", exc)

    def _recover(self) -> None:
        assert self.store is not None
        for rec in self.store.with_status("queued", "running"):
            source = self.job_dir(rec.id) / rec.input_name
            if rec.status == "running" and rec.attempts >= self.settings.max_attempts:
                self._fail(rec, f"interrupted by a server stop after {rec.attempts} attempt(s); not retried")
            elif not source.is_file():
                self._fail(rec, "interrupted by a server stop, and its upload is gone")
            else:
                self.store.update(rec.id, status="queued", frames_done=0, note="resumed after a server restart")
                with self._lock:
                    self._admitted += 1
                self._enqueue(rec)
                log.info("job %s resumed after a restart", rec.id)

    async def stop(self) -> None:
        with self._lock:
            self._stopping = True
            for hooks in self._running.values():
                hooks.stop_reason = "shutdown"
                hooks.cancel.set()
        if self._sweeper is not None:
            self._sweeper.cancel()
        if self.runner is not None:
            await asyncio.to_thread(self.runner.shutdown)
        if self.store is not None:
            self.store.close()

    # ------------------------------------------------------------------------------------------ admission

    def _refusal(self) -> ApiError | None:
        """Why a job would not be admitted now (model failed, shutting down, queue full); call with the lock."""
        retry = {"Retry-After": str(self.settings.retry_after_seconds), **CLOSE}
        if self.model_state == "failed":
            return ApiError(503, "model_unavailable", f"the model could not be loaded: {self.model_message}", CLOSE)
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
        with self._lock:
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
            with self._lock:
                self._uploading -= 1

    def admit(self) -> Admission:
        """A place for one more job (its upload complete and checked), or 503 (queue full, model failed, stopping)."""
        with self._lock:
            refusal = self._refusal()
            if refusal is not None:
                raise refusal
            self._admitted += 1
        return Admission(self)

    def _count_frames(self, n: int) -> None:
        self.metrics.inc("frames", by=n)
        with self._lock:
            self._frames_since_gc += n
            due = self._frames_since_gc >= _GC_EVERY_FRAMES
            if due:
                self._frames_since_gc = 0
        if due:
            gc.collect()

    def _release(self) -> None:
        with self._lock:
            self._admitted -= 1

    def new_upload_path(self) -> Path:
        return self.uploads_dir / f"{secrets.token_hex(16)}.part"

    async def probe(self, upload: Upload) -> VideoInfo:
        """413 if the frames are over the pixel cap (read from the stream header, before any frame is decoded),
        415 unless the upload decodes as video."""
        cap = self.settings.max_pixels
        declared = await anyio.to_thread.run_sync(declared_frame_size, upload.path, cap, limiter=self._probe_limiter)
        if declared is not None:
            self._check_pixels(upload, *declared)
        try:
            info = await anyio.to_thread.run_sync(probe_video, upload.path, limiter=self._probe_limiter)
        except ColonlightError as exc:
            self.metrics.inc("rejected", "not_video")
            raise ApiError(415, "unsupported_media_type", self.scrub(str(exc), upload.path, upload.filename)) from None
        self._check_pixels(upload, info.width, info.height)  # a header that said nothing, or too little
        return info

    def _check_pixels(self, upload: Upload, width: int, height: int) -> None:
        cap = self.settings.max_pixels
        if width * height > cap:
            self.metrics.inc("rejected", "too_many_pixels")
            raise ApiError(
                413,
                "frame_too_large",
                f"{upload.filename}: its frames are {width}x{height} ({width * height} pixels), over this "
                f"server's limit of {cap} pixels a frame (COLONLIGHT_MAX_PIXELS)",
            )

    # ------------------------------------------------------------------------------------------ jobs

    def job_dir(self, job_id: str) -> Path:
        return self.jobs_dir / job_id

    async def create_job(self, admission: Admission, upload: Upload, options: JobOptions) -> JobRecord:
        assert self.store is not None
        job_id = new_job_id()
        opts = self.resolved(options)
        input_name = "input" + safe_suffix(upload.filename)
        job_dir = self.job_dir(job_id)

        def place() -> int | None:
            job_dir.mkdir(parents=True)
            os.replace(upload.path, job_dir / input_name)
            return estimate_frames(job_dir / input_name, opts.fps or None)

        try:
            total = await anyio.to_thread.run_sync(place, limiter=self._probe_limiter)
            rec = JobRecord(
                id=job_id,
                status="queued",
                filename=upload.filename,
                input_name=input_name,
                input_bytes=upload.size,
                options=opts.model_dump(),
                created_at=time.time(),
                frames_total=total,
            )
            await asyncio.to_thread(self.store.insert, rec)
        except BaseException as exc:
            await asyncio.to_thread(_remove, job_dir)
            if is_disk_full(exc):
                raise storage_full() from None
            raise
        admission.transfer()
        self.metrics.inc("submitted")
        self._enqueue(rec)
        return rec

    def _enqueue(self, rec: JobRecord) -> None:
        assert self.runner is not None and self.store is not None
        options = JobOptions(**rec.options)
        job_dir = self.job_dir(rec.id)
        job = ClipJob(
            source=job_dir / rec.input_name, name=Path(rec.filename).stem or "upload", out_dir=job_dir / "out"
        )
        store, job_id = self.store, rec.id
        hooks = ClipHooks()
        last_flush = [0.0]

        def started() -> bool:
            with self._lock:
                if self._stopping:
                    return False
                if store.mark_running(job_id) is None:
                    return False  # deleted while it waited
                self._queued.discard(job_id)
                self._running[job_id] = hooks
                self._progress[job_id] = 0
            return True

        def frames(n: int) -> None:
            with self._lock:
                before = self._progress.get(job_id, 0)
                self._progress[job_id] = n
            self._count_frames(n - before)
            now = time.monotonic()
            if now - last_flush[0] >= _PROGRESS_FLUSH_S:
                last_flush[0] = now
                try:
                    store.update(job_id, frames_done=n)
                except sqlite3.Error as exc:  # e.g. a full disk: progress is also kept in memory, the clip goes on
                    log.warning("job %s: progress not saved: %s", job_id, exc)

        hooks.started, hooks.frames = started, frames
        with self._lock:
            self._queued.add(job_id)
        try:
            spec, clip_opts = self.method_spec(options), self.clip_options(options)
        except (ApiError, ValueError) as exc:  # options that were valid once but no longer are (settings changed)
            self._fail(rec, getattr(exc, "message", str(exc)))
            with self._lock:
                self._queued.discard(job_id)
                self._admitted -= 1
            return
        future = self.runner.submit(job, spec, clip_opts, hooks)
        future.add_done_callback(lambda f: self._job_finished(rec, job, f, hooks))

    def _job_finished(self, rec: JobRecord, job: ClipJob, future: Future[ClipOutcome], hooks: ClipHooks) -> None:
        assert self.store is not None
        job_id = rec.id
        with self._lock:
            self._queued.discard(job_id)
            was_running = self._running.pop(job_id, None) is not None
            self._progress.pop(job_id, None)
            self._admitted -= 1
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
        if not was_running and hooks.stop_reason != "deleted" and self._stopping:
            return  # not started because of shutdown: stays 'queued'
        if hooks.cancel.is_set() and hooks.stop_reason == "shutdown":
            self.store.requeue(job_id, "interrupted by a server shutdown; resumed at the next start")
            return
        now = time.time()
        if outcome.status == "done":
            outcome = self._label_source(outcome, job, rec.filename)
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
                message = self.scrub(outcome.error or "failed", job.source, rec.filename)
                if outcome.detail and outcome.detail not in ("stopped", DISK_FULL):
                    log.error("job %s: %s\n%s", job_id, message, outcome.detail)
                if outcome.detail == DISK_FULL:
                    _remove(job.out_dir)  # partial results of no use: their room lets the failure be recorded
                ok = self._fail(rec, message, seconds=outcome.seconds)
                self.metrics.observe_job("failed", outcome.seconds)
        except sqlite3.Error as exc:  # the job table cannot take the outcome (a full disk): the restart recovers it
            log.error("job %s ended %s, but the job table could not record it: %s", job_id, outcome.status, exc)
            return
        if ok:
            (self.job_dir(job_id) / rec.input_name).unlink(missing_ok=True)  # results are kept, the upload is not
        else:
            _remove(self.job_dir(job_id))  # deleted meanwhile
        release_free_memory()  # what the clip's frames used goes back to the system, not to the next peak

    @staticmethod
    def _label_source(outcome: ClipOutcome, job: ClipJob, label: str) -> ClipOutcome:
        """The finished clip's gammas.json with ``source`` naming the upload's label, not its server path."""
        gammas = job.out_dir / GAMMAS_FILE
        try:
            record = json.loads(gammas.read_text(encoding="utf-8"))
            record["source"] = label
            write_json_atomic(gammas, record)
        except (OSError, ValueError) as exc:
            gammas.unlink(missing_ok=True)
            full = is_disk_full(exc)
            return ClipOutcome(
                outcome.clip,
                outcome.source,
                "failed",
                seconds=outcome.seconds,
                error=NO_SPACE if full else f"its results could not be completed: {exc}",
                detail=DISK_FULL if full else None,
            )
        return outcome

    def _fail(self, rec: JobRecord, message: str, seconds: float | None = None) -> bool:
        """Mark the job failed and remove its upload now (whatever results it has are kept until the TTL)."""
        assert self.store is not None
        (self.job_dir(rec.id) / rec.input_name).unlink(missing_ok=True)
        return self.store.update(rec.id, status="failed", error=message, finished_at=time.time(), seconds=seconds)

    def get(self, job_id: str) -> JobRecord | None:
        assert self.store is not None
        rec = self.store.get(job_id)
        if rec is not None and rec.status == "running":
            with self._lock:
                rec.frames_done = self._progress.get(job_id, rec.frames_done)
        return rec

    def delete(self, job_id: str) -> bool:
        """Remove a job and its files; a running one is stopped at its next frame and cleaned up by its worker."""
        assert self.store is not None
        with self._lock:
            if not self.store.delete(job_id):
                return False
            hooks = self._running.get(job_id)
            if hooks is not None:
                hooks.stop_reason = "deleted"
                hooks.cancel.set()
                return True
        _remove(self.job_dir(job_id))
        return True

    def result_path(self, rec: JobRecord, what: str) -> Path:
        out = self.job_dir(rec.id) / "out"
        return out / {"video": VIDEO_FILE, "gammas": GAMMAS_FILE}[what]

    def frames_zip(self, rec: JobRecord) -> Path:
        """``frames.zip`` of a finished job, built once (stored, not compressed: the frames are png/jpg)."""
        import zipfile

        from colonlight.atomic import atomic_path

        target = self.job_dir(rec.id) / "frames.zip"
        with self._zip_lock:
            if not target.is_file():
                frames_dir = self.job_dir(rec.id) / "out" / "frames"
                with atomic_path(target) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
                    for p in sorted(frames_dir.iterdir()):
                        if p.is_file() and not p.name.startswith("."):
                            zf.write(p, arcname=f"frames/{p.name}")
        return target

    # ------------------------------------------------------------------------------------------ sync

    async def enhance_now(
        self, admission: Admission, upload: Upload, options: JobOptions, info: VideoInfo
    ) -> dict[str, Any]:
        """Run a short clip through the same runner and return ``{"gammas": ..., "video": ...}``."""
        limit = self.settings.sync_max_seconds
        too_long = ApiError(
            413,
            "clip_too_long",
            f"{upload.filename} is longer than {limit:g} s, the limit of POST /v1/enhance "
            "(COLONLIGHT_SYNC_MAX_SECONDS); submit it to POST /v1/jobs and poll GET /v1/jobs/{id} instead",
        )
        if info.duration_s is not None and info.duration_s > limit + 1e-3:
            self.metrics.inc("sync_requests", "too_long")
            raise too_long
        opts = self.resolved(options)
        spec, clip_opts = self.method_spec(opts), self.clip_options(opts, frames=False)
        rate = (opts.fps or 0) or info.avg_fps or MAX_FPS
        max_frames = math.ceil(limit * rate) + 2
        token = "sync-" + secrets.token_hex(8)
        work = self.sync_dir / token
        job = ClipJob(
            source=work / ("input" + safe_suffix(upload.filename)),
            name=Path(upload.filename).stem or "upload",
            out_dir=work / "out",
        )
        await asyncio.to_thread(lambda: (work.mkdir(parents=True), os.replace(upload.path, job.source)))
        hooks = ClipHooks()
        over = [False]

        def started() -> bool:
            with self._lock:
                if self._stopping:
                    return False
                self._running[token] = hooks
            return True

        def frames(n: int) -> None:
            self._count_frames(1)
            if n > max_frames:
                over[0] = True
                raise Stopped("over the duration limit")

        hooks.started, hooks.frames = started, frames
        assert self.runner is not None
        future = self.runner.submit(job, spec, clip_opts, hooks)
        admission.transfer()  # from here on the place is released when the clip ends, even if the client left
        abandoned = [False]

        def finished(_: Future[ClipOutcome]) -> None:
            with self._lock:
                self._running.pop(token, None)
            self._release()
            if abandoned[0]:
                _remove(work)

        future.add_done_callback(finished)
        try:
            outcome = await asyncio.wrap_future(future)
        except BaseException:  # the request was cancelled (client gone): stop the clip, clean up after it
            abandoned[0] = True
            hooks.stop_reason = "client went away"
            hooks.cancel.set()
            if future.done():
                _remove(work)
            raise
        try:
            if over[0]:
                self.metrics.inc("sync_requests", "too_long")
                raise too_long
            if outcome.status != "done" and outcome.detail == DISK_FULL:
                self.metrics.inc("sync_requests", "failed")
                raise storage_full()
            if outcome.status != "done":
                self.metrics.inc("sync_requests", "failed")
                raise ApiError(
                    422, "unprocessable_clip", self.scrub(outcome.error or "failed", job.source, upload.filename)
                )
            self.metrics.observe_job("succeeded", outcome.seconds)

            def read() -> dict[str, Any]:
                gammas = json.loads((job.out_dir / GAMMAS_FILE).read_text(encoding="utf-8"))
                gammas["source"] = upload.filename  # the upload's label, not the server's path
                video = (job.out_dir / VIDEO_FILE).read_bytes()
                return {
                    "gammas": gammas,
                    "video": {
                        "media_type": "video/mp4",
                        "encoding": "base64",
                        "size_bytes": len(video),
                        "data": base64.b64encode(video).decode(),
                    },
                }

            result = await asyncio.to_thread(read)
            self.metrics.inc("sync_requests", "ok")
            return result
        finally:
            await asyncio.to_thread(_remove, work)
            release_free_memory()

    # ------------------------------------------------------------------------------------------ state

    def scrub(self, message: str, source: Path, filename: str) -> str:
        """An engine message with the server's paths replaced by the client's file name."""
        message = message.replace(str(source), filename)
        return message.replace(str(self.root), "<data>")

    def queue_state(self) -> tuple[int, int, int]:
        """(waiting, running, admitted)."""
        with self._lock:
            return len(self._queued), len(self._running), self._admitted

    def uploads_in_flight(self) -> int:
        """Uploads being received or checked now (they hold no place in the queue)."""
        with self._lock:
            return self._uploading

    def readiness(self) -> tuple[bool, str, str]:
        """(ready, status, message): ready when the model is loaded and a job would be admitted."""
        if self.model_state != "ready":
            return False, self.model_state, self.model_message
        admitted = self.queue_state()[2]
        if self._stopping:
            return False, "busy", "shutting down"
        if admitted >= self.settings.capacity:
            return False, "busy", "all workers are busy and the queue is full"
        return True, "ready", "model loaded; accepting jobs"

    async def _sweep_forever(self) -> None:
        while True:
            await asyncio.sleep(self.settings.sweep_interval_seconds)
            try:
                await asyncio.to_thread(self.sweep)
            except Exception:  # a failed sweep is retried at the next interval
                log.exception("sweep failed")

    def sweep(self) -> int:
        """Delete jobs finished more than the TTL ago (and stale sync work folders); return how many jobs.

        The TTL in force is applied, so a server restarted with a shorter TTL also sweeps older results sooner."""
        assert self.store is not None
        expired = self.store.finished_before(time.time() - self.settings.result_ttl_seconds)
        for job_id in expired:
            self.delete(job_id)
        cutoff = time.time() - _SYNC_LEFTOVER_S
        with self._lock:
            busy = set(self._running)
        for d in self.sync_dir.iterdir():
            if d.name not in busy and d.stat().st_mtime < cutoff:
                _remove(d)
        if expired:
            log.info("swept %d expired job(s)", len(expired))
        return len(expired)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)

"""``POST /v1/enhance``: a short clip through the same runner as the jobs, answered in the response (gammas and
the video, base64), its work folder removed whatever happens (the client may leave mid-clip)."""

from __future__ import annotations

import asyncio
import base64
import dataclasses
import math
import os
import secrets
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from colonlight import GAMMAS_FILE, VIDEO_FILE, ClipJob, ClipOptions, ClipOutcome, MethodSpec, VideoInfo, read_json
from colonlight.limits import MAX_FPS

from .admission import Admission, JobBoard
from .errors import ApiError, storage_full
from .memory import FrameCollector, release_free_memory
from .metrics import Metrics
from .results import relabel
from .runners import DISK_FULL, ClipHooks, ClipRunner, Stopped
from .settings import Settings
from .uploads import Upload, safe_suffix
from .workspace import MASK_NAME, Workspace, remove

#: Sync work folders older than this are swept (a process that died mid-request; see :mod:`.sweeper`).
SYNC_LEFTOVER_S = 3600.0


class SyncEnhancer:
    """Runs one short clip now; ``runner`` is set when the server starts."""

    def __init__(
        self, settings: Settings, workspace: Workspace, board: JobBoard, metrics: Metrics, collector: FrameCollector
    ) -> None:
        self.settings = settings
        self.workspace = workspace
        self.board = board
        self.metrics = metrics
        self.collector = collector
        self.runner: ClipRunner | None = None

    def _too_long(self, upload: Upload) -> ApiError:
        limit = self.settings.sync_max_seconds
        return ApiError(
            413,
            "clip_too_long",
            f"{upload.filename} is longer than {limit:g} s, the limit of POST /v1/enhance "
            "(COLONLIGHT_SYNC_MAX_SECONDS); submit it to POST /v1/jobs and poll GET /v1/jobs/{id} instead",
        )

    def check_duration(self, upload: Upload, info: VideoInfo) -> None:
        """413 when the container says the clip is over the limit (before anything runs)."""
        if info.duration_s is not None and info.duration_s > self.settings.sync_max_seconds + 1e-3:
            self.metrics.inc("sync_requests", "too_long")
            raise self._too_long(upload)

    async def run(
        self,
        admission: Admission,
        upload: Upload,
        spec: MethodSpec,
        clip_opts: ClipOptions,
        fps: float | None,
        info: VideoInfo,
    ) -> dict[str, Any]:
        """Run the clip (checked by :meth:`check_duration`) and return ``{"gammas": ..., "video": ...}``; ``fps``
        is the extraction rate (0 or None: every frame), which bounds the frames the duration limit allows. An
        uploaded content mask is moved into the work folder and used in place of ``clip_opts.content``."""
        rate = (fps or 0) or info.avg_fps or MAX_FPS
        max_frames = math.ceil(self.settings.sync_max_seconds * rate) + 2
        token = "sync-" + secrets.token_hex(8)
        work = self.workspace.sync_dir / token
        job = ClipJob(
            source=work / ("input" + safe_suffix(upload.filename)),
            name=Path(upload.filename).stem or "upload",
            out_dir=work / "out",
        )

        mask = work / MASK_NAME

        def place_upload() -> ClipOptions:
            work.mkdir(parents=True)
            os.replace(upload.path, job.source)
            if upload.mask is None:
                return clip_opts
            os.replace(upload.mask.path, mask)
            return dataclasses.replace(clip_opts, content=str(mask))  # read here, as ``--content MASK`` is

        try:
            clip_opts = await asyncio.to_thread(place_upload)
        except BaseException:
            await asyncio.to_thread(remove, work)
            raise
        hooks = ClipHooks()
        over = [False]

        def frames(n: int) -> None:
            self.metrics.inc("frames", by=1)
            self.collector.count(1)
            if n > max_frames:
                over[0] = True
                raise Stopped("over the duration limit")

        hooks.started, hooks.frames = lambda: self.board.begin(token, hooks), frames
        assert self.runner is not None
        future = self.runner.submit(job, spec, clip_opts, hooks)
        admission.transfer()  # from here on the place is released when the clip ends, even if the client left
        abandoned = [False]

        def finished(_: Future[ClipOutcome]) -> None:
            self.board.end(token)
            if abandoned[0]:
                remove(work)

        future.add_done_callback(finished)
        try:
            outcome = await asyncio.wrap_future(future)
        except BaseException:  # the request was cancelled (client gone): stop the clip, clean up after it
            abandoned[0] = True
            hooks.stop_reason = "client went away"
            hooks.cancel.set()
            if future.done():
                remove(work)
            raise
        try:
            if over[0]:
                self.metrics.inc("sync_requests", "too_long")
                raise self._too_long(upload)
            if outcome.status != "done" and outcome.detail == DISK_FULL:
                self.metrics.inc("sync_requests", "failed")
                raise storage_full()
            if outcome.status != "done":
                self.metrics.inc("sync_requests", "failed")
                named = None if upload.mask is None else (mask, upload.mask.filename)
                message = self.workspace.scrub(outcome.error or "failed", job.source, upload.filename, named)
                raise ApiError(422, "unprocessable_clip", message)
            self.metrics.observe_job("succeeded", outcome.seconds)
            mask_name = None if upload.mask is None else upload.mask.filename

            def read() -> dict[str, Any]:
                # the upload's labels, not the server's paths
                gammas = relabel(read_json(job.out_dir / GAMMAS_FILE), upload.filename, mask_name)
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
            await asyncio.to_thread(remove, work)
            release_free_memory()

"""Jobs: the job manager the routes share, a thin façade over the modules that do the work.

Life of a job::

    POST /v1/jobs -> an upload place (or 503) -> upload streamed (413, 408, 507) -> probed (413, 415)
    -> admitted (or 503) -> row 'queued' -> 202
    a worker takes it -> 'running' (frames_done advances) -> 'succeeded' | 'failed' -> swept after the TTL

Where each part lives: a request's options become the engine's here (:meth:`JobManager.method_spec`);
:mod:`.admission` (upload places, admitted jobs, the queue), :mod:`.probing` (the checks of an upload),
:mod:`.lifecycle` (creating, running, finishing, deleting and recovering jobs), :mod:`.sync_enhance`
(``POST /v1/enhance``), :mod:`.results` (result files, ``frames.zip``), :mod:`.sweeper` (expiry),
:mod:`.model_status` (the default model's loading), :mod:`.workspace` (the data folder's layout).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

from colonlight import DEFAULT_CONTENT, ClipOptions, ColonlightError, MethodSpec, VideoInfo

from .admission import Admission, JobBoard
from .errors import ApiError
from .lifecycle import JOB_ID_PATTERN, JobLifecycle
from .memory import FrameCollector
from .metrics import Metrics
from .model_status import ModelStatus, torch_threads
from .probing import UploadProbe
from .request_options import JobOptions, method_spec
from .results import Results, mask_label, mask_setting
from .runners import ClipRunner, ClusterRunner, LocalRunner, MethodCache
from .settings import Settings
from .store import JobRecord, JobStore
from .sweeper import Sweeper
from .sync_enhance import SyncEnhancer
from .uploads import Upload
from .workspace import MASK_NAME, Workspace

__all__ = ["JOB_ID_PATTERN", "Admission", "JobManager"]

log = logging.getLogger("colonlight.service")


class JobManager:
    """Everything about jobs, shared by the routes (one per app)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.workspace = Workspace(settings.data_dir)
        self.metrics = Metrics()
        self.methods = MethodCache(settings.method_cache)
        self.model = ModelStatus()
        self.board = JobBoard(settings, self.metrics, self.model)
        self.probing = UploadProbe(settings, self.metrics, self.workspace)
        collector = FrameCollector()
        self.lifecycle = JobLifecycle(
            settings, self.workspace, self.board, self.metrics, collector, self.probing.limiter, self._plan
        )
        self.sync = SyncEnhancer(settings, self.workspace, self.board, self.metrics, collector)
        self.results = Results(self.workspace)
        self.sweeper = Sweeper(settings, self.workspace, self.board, self.lifecycle)
        self.store: JobStore | None = None
        self.runner: ClipRunner | None = None
        self.default_spec = self.method_spec(JobOptions())
        #: torch's intra-op threads in this server process (set once, when the model loads)
        self.torch_threads = torch_threads(settings.torch_threads, self.default_spec, settings.workers)

    # ------------------------------------------------------------------------------------------ options

    def method_spec(self, o: JobOptions) -> MethodSpec:
        """The engine's method for a request's options, with the server's weights and device."""
        return method_spec(self.settings, o)

    def resolved(self, o: JobOptions) -> JobOptions:
        """``o`` with the server's defaults filled in (what the job records and runs with)."""
        return o.model_copy(
            update={"fps": self.settings.fps if o.fps is None else o.fps, "method": o.method or self.settings.method}
        )

    def clip_options(self, o: JobOptions, frames: bool | None = None, mask: Path | None = None) -> ClipOptions:
        """The engine's clip options; ``mask``: an uploaded content mask in the job's folder, used as
        ``colonlight enhance --content MASK`` uses one (read here, once)."""
        fps = self.settings.fps if o.fps is None else o.fps
        return ClipOptions(
            fps=fps or None,
            frames=o.frames if frames is None else frames,
            video=True,
            format=o.format,
            quality=o.quality,
            content=o.content if mask is None else str(mask),
            max_gap_frames=self.settings.max_gap_frames,
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

    def _plan(self, recorded: dict[str, Any], job_dir: Path) -> tuple[MethodSpec, ClipOptions]:
        """A job's recorded options as the engine's method and clip options; a recorded content mask (its upload
        name and hash, :func:`.results.mask_setting`) is the one in the job's folder, there after a restart too."""
        if mask_label(recorded) is None:
            options = JobOptions(**recorded)
            return self.method_spec(options), self.clip_options(options)
        options = JobOptions(**{**recorded, "content": DEFAULT_CONTENT})
        return self.method_spec(options), self.clip_options(options, mask=job_dir / MASK_NAME)

    # ------------------------------------------------------------------------------------------ life cycle

    @property
    def model_state(self) -> str:
        return self.model.state

    @property
    def model_message(self) -> str:
        return self.model.message

    @property
    def model_info(self) -> dict[str, Any] | None:
        return self.model.info

    async def start(self) -> None:
        self.workspace.prepare()
        self.store = self.lifecycle.store = JobStore(self.workspace.table)
        self.workspace.remove_orphans(self.store.ids())
        try:
            self.runner = (
                ClusterRunner(self.settings.cluster, self.settings.workers)
                if self.settings.cluster
                else LocalRunner(self.settings.workers, self.methods)
            )
        except ColonlightError as exc:  # e.g. the scheduler is unreachable: reported by /readyz, submissions get 503
            self.model.fail(str(exc))
            log.error("%s", exc)
            self.sweeper.start()
            return
        self.lifecycle.runner = self.sync.runner = self.runner
        threading.Thread(
            target=self.model.load,
            args=(self.methods, self.default_spec, self.torch_threads),
            name="colonlight-load-model",
            daemon=True,
        ).start()
        self.lifecycle.recover()
        self.sweeper.start()

    async def stop(self) -> None:
        self.board.stop()
        self.sweeper.stop()
        if self.runner is not None:
            await asyncio.to_thread(self.runner.shutdown)
        if self.store is not None:
            self.store.close()

    # ------------------------------------------------------------------------------------------ the routes' API

    def receiving(self) -> AbstractContextManager[None]:
        """An upload place while an upload is received and checked (:meth:`JobBoard.receiving`), or 503."""
        return self.board.receiving()

    def admit(self) -> Admission:
        return self.board.admit()

    def new_upload_path(self) -> Path:
        return self.workspace.new_upload_path()

    async def probe(self, upload: Upload) -> VideoInfo:
        return await self.probing.probe(upload)

    async def check_mask(self, upload: Upload) -> None:
        await self.probing.check_mask(upload)

    async def create_job(self, admission: Admission, upload: Upload, options: JobOptions) -> JobRecord:
        opts = self.resolved(options)
        recorded = opts.model_dump()
        if upload.mask is not None:  # recorded by its upload name and hash, never by its path on the server
            recorded["content"] = mask_setting(upload.mask.filename, upload.mask.sha256)
        return await self.lifecycle.create(admission, upload, recorded, opts.fps)

    def get(self, job_id: str) -> JobRecord | None:
        return self.lifecycle.get(job_id)

    def delete(self, job_id: str) -> bool:
        return self.lifecycle.delete(job_id)

    def result_path(self, rec: JobRecord, what: str) -> Path:
        return self.results.path(rec, what)

    def frames_zip(self, rec: JobRecord) -> Path:
        return self.results.frames_zip(rec)

    async def enhance_now(
        self, admission: Admission, upload: Upload, options: JobOptions, info: VideoInfo
    ) -> dict[str, Any]:
        """Run a short clip through the same runner and return ``{"gammas": ..., "video": ...}``."""
        self.sync.check_duration(upload, info)
        opts = self.resolved(options)
        spec, clip_opts = self.method_spec(opts), self.clip_options(opts, frames=False)
        return await self.sync.run(admission, upload, spec, clip_opts, opts.fps, info)

    def scrub(self, message: str, source: Path, filename: str) -> str:
        return self.workspace.scrub(message, source, filename)

    def queue_state(self) -> tuple[int, int, int]:
        """(waiting, running, admitted)."""
        return self.board.queue_state()

    def uploads_in_flight(self) -> int:
        return self.board.uploads_in_flight()

    def readiness(self) -> tuple[bool, str, str]:
        return self.board.readiness()

    def sweep(self) -> int:
        return self.sweeper.sweep()

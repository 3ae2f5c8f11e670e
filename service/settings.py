"""Service settings, read from ``COLONLIGHT_*`` environment variables (pydantic-settings).

Every setting has a default that works on a laptop; ``create_app(Settings(...))`` takes them explicitly in tests.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from pydantic import Field, SecretStr, ValidationInfo, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from colonlight.errors import MethodOptionError
from colonlight.limits import (
    DEFAULT_FPS,
    DEFAULT_MAX_GAP_FRAMES,
    DEFAULT_MAX_PIXELS,
    DEFAULT_METHOD,
    MAX_FPS,
    available_cores,
)
from colonlight.methods.options import option

#: Seconds a connection may take to deliver a request's headers (``COLONLIGHT_HEADER_TIMEOUT_SECONDS``).
DEFAULT_HEADER_TIMEOUT_S = 10.0


def _default_workers() -> int:
    return max(1, available_cores() // 2)


class Settings(BaseSettings):
    """Settings of ``colonlight serve``; each field is read from ``COLONLIGHT_<FIELD NAME IN CAPITALS>``."""

    model_config = SettingsConfigDict(env_prefix="COLONLIGHT_", extra="ignore", validate_default=True)

    host: str = Field("127.0.0.1", description="Address uvicorn binds to (`colonlight serve --host`).")
    port: int = Field(8000, ge=0, le=65535, description="Port uvicorn listens on (`colonlight serve --port`).")
    data_dir: Path = Field(Path("colonlight-service"), description="Jobs, results and the SQLite job table live here.")
    workers: int = Field(
        default_factory=_default_workers,
        ge=1,
        le=64,
        description="Clips processed at once (default: one per two cores).",
    )
    queue_size: int = Field(
        16, ge=0, le=10_000, description="Jobs that may wait beyond the running ones; more get 503."
    )
    max_upload_mb: float = Field(2048.0, gt=0, description="Largest accepted upload in MiB; larger ones get 413.")
    max_uploads: int = Field(
        8,
        ge=1,
        le=10_000,
        description="Uploads received at once; more get 503. Counted apart from the job queue: "
        "a job is admitted only once its upload is complete.",
    )
    header_timeout_seconds: float = Field(
        DEFAULT_HEADER_TIMEOUT_S,
        gt=0,
        description="A request whose headers are not complete this long after the connection opened (or after the "
        "previous response on it) gets 408 and is closed: a client sending its headers slowly (slowloris) "
        "cannot hold a connection. Applies under `colonlight serve`.",
    )
    upload_idle_seconds: float = Field(
        30.0,
        gt=0,
        description="An upload whose body makes no progress this long gets 408 and its partial file is removed.",
    )
    upload_min_bytes_per_s: float = Field(
        1024.0,
        ge=0,
        description="Progress means at least this many bytes a second, averaged "
        "over each upload_idle_seconds (0: any byte); a trickle below "
        "it is a stall.",
    )
    max_pixels: int = Field(
        DEFAULT_MAX_PIXELS,
        ge=1,
        description="Largest frame (width x height) accepted, read from the stream header at upload "
        "time; larger ones get 413 before any frame is decoded (COLONLIGHT_MAX_PIXELS, "
        "the same variable as the CLI's).",
    )
    max_gap_frames: int = Field(
        DEFAULT_MAX_GAP_FRAMES,
        ge=1,
        description="Most copies of one frame a timestamp gap may add (the fps conversion repeats a frame until the "
        "next is due); past it the job fails with the reason (COLONLIGHT_MAX_GAP_FRAMES, the same variable as "
        "the CLI's).",
    )
    sync_max_seconds: float = Field(20.0, gt=0, description="Longest clip POST /v1/enhance accepts (seconds).")
    result_ttl_seconds: float = Field(
        24 * 3600.0, gt=0, description="Finished jobs are deleted this long after they end."
    )
    sweep_interval_seconds: float = Field(60.0, gt=0, description="How often expired jobs are swept.")
    retry_after_seconds: int = Field(10, ge=1, description="Retry-After sent with 503 when the queue is full.")
    max_attempts: int = Field(2, ge=1, description="Starts of a job (restarts included) before it is marked failed.")
    api_key: SecretStr | None = Field(None, description="When set, every route but /healthz and /readyz requires it.")
    method: str = Field(DEFAULT_METHOD, description="Default enhancement method (loaded at start-up).")
    weights: Path | None = Field(None, description="Checkpoint for rnn (default: the shipped model).")
    model_size: str | None = Field(
        None, description="Default of a request's model_size: " + option("model_size").description
    )
    device: str = Field("auto", description=option("device").description)
    runtime: str | None = Field(None, description=option("runtime").description)
    fps: float = Field(DEFAULT_FPS, ge=0, le=MAX_FPS, description="Default extraction rate (0 keeps every frame).")
    cluster: str | None = Field(None, description="Dask scheduler address: run clips there instead of locally.")
    method_cache: int = Field(4, ge=1, le=64, description="Methods with non-default options kept loaded (LRU).")
    torch_threads: int | None = Field(
        None,
        ge=1,
        description="torch intra-op threads (default: 1 for the recurrent net at its small input size, "
        "else cores / workers).",
    )
    log_level: str = Field("info", description="uvicorn log level.")
    malloc_arena_max: int = Field(2, ge=0, description="glibc malloc arenas (0: glibc's default); keeps memory flat.")
    stream_max: int = Field(
        4,
        ge=0,
        le=256,
        description="WebSocket streams (/v1/stream) open at once; more are "
        "refused with close code 1013 (0 turns the route off).",
    )
    stream_max_frame_mb: float = Field(
        16.0,
        gt=0,
        le=1024,
        description="Largest WebSocket message (one frame) in MiB; a larger one closes the stream with code 1009.",
    )
    stream_idle_seconds: float = Field(
        60.0, gt=0, description="A stream with no message for this long is closed (1001)."
    )
    stream_send_timeout_seconds: float = Field(
        30.0,
        gt=0,
        description="A stream whose client reads no answer for "
        "this long is dropped: a slow client holds one answer, no more.",
    )

    @field_validator("api_key", mode="before")
    @classmethod
    def _empty_key_is_none(cls, value: object) -> object:
        return None if value in ("", None) else value

    @field_validator("model_size", "runtime", "cluster", "weights", mode="before")
    @classmethod
    def _empty_is_none(cls, value: object) -> object:
        return None if value == "" else value

    @field_validator("data_dir")
    @classmethod
    def _usable_data_dir(cls, value: Path) -> Path:
        """A data folder that can never be one is refused at start in one line (nothing is created here): a file
        or a path under one was a NotADirectoryError traceback, a name past NAME_MAX an OSError one, a link loop
        pathlib's RuntimeError ("Symlink loop from ..."), each as uvicorn's "Application startup failed"."""
        try:
            path = value.resolve()
        except RuntimeError:  # Python < 3.13 on a link loop
            raise ValueError(f"{value}: a symbolic link loop") from None
        for place in (path, *path.parents):
            try:
                st = os.stat(place)
            except (FileNotFoundError, NotADirectoryError):
                continue  # created at start, or a parent is a file (found next)
            except OSError as exc:  # ENAMETOOLONG, ELOOP, EACCES
                raise ValueError(f"{value}: cannot be the data folder: {exc.strerror or exc}") from None
            if not stat.S_ISDIR(st.st_mode):
                where = "it is" if place == path else f"{place} is"
                raise ValueError(f"{value}: cannot be the data folder: {where} a file, not a folder")
            break
        return value

    @field_validator("model_size", "runtime")
    @classmethod
    def _method_option(cls, value: str | None, info: ValidationInfo) -> str | None:
        """Checked by the methods' declaration: the values and the message the CLI and a request have."""
        if value is None:
            return None
        try:
            return str(option(str(info.field_name)).parse(value))
        except MethodOptionError as exc:
            raise ValueError(str(exc)) from None

    @property
    def max_upload_bytes(self) -> int:
        return int(self.max_upload_mb * 1024 * 1024)

    @property
    def stream_max_frame_bytes(self) -> int:
        return int(self.stream_max_frame_mb * 1024 * 1024)

    @property
    def capacity(self) -> int:
        """Jobs admitted at once: the running ones plus the waiting ones."""
        return self.workers + self.queue_size

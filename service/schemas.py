"""Response bodies of the HTTP API (they make the OpenAPI schema); request options: :mod:`.request_options`."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any, Literal

from pydantic import BaseModel, Field

from colonlight import available_methods
from colonlight.limits import DEFAULT_FPS, DEFAULT_FRAME_FORMAT, DEFAULT_JPEG_QUALITY, DEFAULT_METHOD

METHODS = available_methods()
JobState = Literal["queued", "running", "succeeded", "failed"]


class JobLinks(BaseModel):
    self: str
    video: str = Field(description="The enhanced H.264 mp4 (once succeeded).")
    gammas: str = Field(description="The clip's gammas.json (once succeeded).")
    frames: str = Field(description="The enhanced frames as a zip (once succeeded, if frames were written).")


class JobStatus(BaseModel):
    """A job: its state, progress, and where its results are."""

    id: str = Field(description="Unguessable job id (128 random bits).")
    status: JobState
    filename: str = Field(description="The uploaded file's name (a label only).")
    options: dict[str, Any] = Field(description="The options the clip is processed with.")
    frames_done: int
    frames_total: int | None = Field(description="Frames expected (an estimate until the job succeeds).")
    progress: float | None = Field(description="frames_done / frames_total, 0..1.")
    error: str | None = None
    note: str | None = Field(None, description="E.g. 'resumed after a server restart'.")
    attempts: int
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    expires_at: datetime | None = Field(None, description="When the results are swept away.")
    links: JobLinks

    model_config = {
        "json_schema_extra": {
            "examples": [
                {
                    "id": "q0Xq3b9bYJgP4yL2m9Vb0w",
                    "status": "running",
                    "filename": "p7.mp4",
                    "options": {
                        "fps": DEFAULT_FPS,
                        "method": DEFAULT_METHOD,
                        "format": DEFAULT_FRAME_FORMAT,
                        "quality": DEFAULT_JPEG_QUALITY,
                        "frames": True,
                    },
                    "frames_done": 12,
                    "frames_total": 36,
                    "progress": 0.333,
                    "error": None,
                    "note": None,
                    "attempts": 1,
                    "created_at": "2024-05-01T10:00:00Z",
                    "started_at": "2024-05-01T10:00:01Z",
                    "finished_at": None,
                    "expires_at": None,
                    "links": {
                        "self": "/v1/jobs/q0Xq3b9bYJgP4yL2m9Vb0w",
                        "video": "/v1/jobs/q0Xq3b9bYJgP4yL2m9Vb0w/video",
                        "gammas": "/v1/jobs/q0Xq3b9bYJgP4yL2m9Vb0w/gammas",
                        "frames": "/v1/jobs/q0Xq3b9bYJgP4yL2m9Vb0w/frames.zip",
                    },
                }
            ]
        }
    }


class VideoPayload(BaseModel):
    media_type: Literal["video/mp4"] = "video/mp4"
    encoding: Literal["base64"] = "base64"
    size_bytes: int
    data: str = Field(description="The enhanced H.264 mp4, base64-encoded.")


class EnhanceResult(BaseModel):
    """POST /v1/enhance: the gammas.json the CLI writes, and the enhanced video, in one JSON body."""

    gammas: dict[str, Any] = Field(description="Exactly the gammas.json of `colonlight enhance` for this clip.")
    video: VideoPayload

    model_config = {
        "json_schema_extra": {
            "examples": [
                {
                    "gammas": {
                        "clip": "p7",
                        "fps": DEFAULT_FPS,
                        "method": "rnn",
                        "frame_count": 2,
                        "frames": [
                            {"index": 0, "time_s": 0.0, "source_time_s": 0.0, "gamma": 1.0, "seed": True},
                            {"index": 1, "time_s": 0.055556, "source_time_s": 0.04, "gamma": 1.0, "seed": True},
                        ],
                    },
                    "video": {
                        "media_type": "video/mp4",
                        "encoding": "base64",
                        "size_bytes": 1234,
                        "data": "AAAAIGZ0eXBpc29t...",
                    },
                }
            ]
        }
    }


class Health(BaseModel):
    status: Literal["ok"] = "ok"


class WorkerState(BaseModel):
    total: int
    busy: int


class QueueState(BaseModel):
    depth: int = Field(description="Jobs waiting for a worker.")
    capacity: int = Field(description="Jobs admitted at once (workers + queue size).")
    admitted: int = Field(description="Jobs admitted now (waiting or running); an upload is admitted once complete.")
    uploads: int = Field(0, description="Uploads being received or checked now; they hold no place in the queue.")


class Readiness(BaseModel):
    ready: bool
    status: Literal["loading", "ready", "busy", "failed"]
    message: str
    model: dict[str, Any] | None = None
    workers: WorkerState
    queue: QueueState


class ServiceInfo(BaseModel):
    version: str
    methods: list[str]
    defaults: dict[str, Any]
    limits: dict[str, float]
    auth_required: bool


def iso(ts: float | None) -> datetime | None:
    return datetime.fromtimestamp(ts, tz=timezone.utc) if ts is not None else None

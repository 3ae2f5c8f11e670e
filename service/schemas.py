"""Request options and response bodies of the HTTP API (they make the OpenAPI schema)."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from colonlight.limits import DEFAULT_FPS, MAX_FPS
from colonlight.methods import available_methods

METHODS = available_methods()
JobState = Literal["queued", "running", "succeeded", "failed"]


class JobOptions(BaseModel):
    """The options of ``colonlight enhance`` that a request may set (form fields beside the ``file`` part).

    Server-side choices (weights file, device, workers) are settings, not request options.
    """

    model_config = ConfigDict(extra="forbid")

    fps: float | None = Field(
        None,
        ge=0,
        le=int(MAX_FPS),
        description=f"Extraction rate; 0 keeps every frame (default: the server's, {DEFAULT_FPS:g}).",
    )
    method: str | None = Field(None, description="Enhancement method (default: the server's, rnn).")
    model_size: str | None = Field(
        None,
        description="rnn only: network input side in pixels (8..1024) or 'full'; default: the size the weights were "
        "trained at (48 for the shipped model).",
    )
    gamma: float | None = Field(None, gt=0, le=10, description="method=gamma only: the exponent (out = in ** gamma).")
    format: Literal["png", "jpg"] = Field("png", description="Format of the enhanced frames (the zip).")
    quality: int = Field(95, ge=1, le=100, description="JPEG quality.")
    frames: bool = Field(True, description="Also write the enhanced frames (downloadable as a zip).")
    content: Literal["auto", "full"] = Field(
        "auto",
        description="auto: the method sees only the field of view inside a black border, less fixed on-screen text; "
        "border and text pixels are written unchanged. full: the whole frame.",
    )

    @field_validator("*", mode="before")
    @classmethod
    def _blank_is_unset(cls, value: Any) -> Any:
        return None if isinstance(value, str) and value.strip() == "" else value

    @field_validator("method")
    @classmethod
    def _known_method(cls, value: str | None) -> str | None:
        if value is not None and value not in METHODS:
            raise ValueError(f"unknown method {value!r}; available: {', '.join(METHODS)}")
        return value

    @field_validator("model_size")
    @classmethod
    def _model_size(cls, value: str | None) -> str | None:
        if value is None:
            return None
        v = value.strip().lower()
        if v == "full":
            return v
        if not v.isdigit() or not 8 <= int(v) <= 1024:
            raise ValueError("model_size must be an integer 8..1024 or 'full'")
        return str(int(v))


#: OpenAPI description of the multipart body of POST /v1/jobs and POST /v1/enhance (parsed by hand, streamed).
def upload_request_body(description: str) -> dict[str, Any]:
    props: dict[str, Any] = {
        "file": {
            "type": "string",
            "format": "binary",
            "description": "The clip: any video FFmpeg decodes (mp4, mov, avi, mkv, ...).",
        },
        "fps": {
            "type": "number",
            "minimum": 0,
            "maximum": int(MAX_FPS),
            "description": JobOptions.model_fields["fps"].description,
            "example": int(DEFAULT_FPS),
        },
        "method": {
            "type": "string",
            "enum": METHODS,
            "description": JobOptions.model_fields["method"].description,
            "example": "rnn",
        },
        "model_size": {
            "type": "string",
            "pattern": "^(full|[0-9]{1,4})$",
            "description": JobOptions.model_fields["model_size"].description,
            "example": "64",
        },
        "gamma": {
            "type": "number",
            "exclusiveMinimum": 0,
            "maximum": 10,
            "description": JobOptions.model_fields["gamma"].description,
        },
        "format": {
            "type": "string",
            "enum": ["png", "jpg"],
            "default": "png",
            "description": JobOptions.model_fields["format"].description,
        },
        "quality": {
            "type": "integer",
            "minimum": 1,
            "maximum": 100,
            "default": 95,
            "description": JobOptions.model_fields["quality"].description,
        },
        "frames": {"type": "boolean", "default": True, "description": JobOptions.model_fields["frames"].description},
        "content": {
            "type": "string",
            "enum": ["auto", "full"],
            "default": "auto",
            "description": JobOptions.model_fields["content"].description,
        },
    }
    return {
        "required": True,
        "description": description,
        "content": {
            "multipart/form-data": {
                "schema": {"type": "object", "required": ["file"], "properties": props, "additionalProperties": False},
                "encoding": {"file": {"contentType": "application/octet-stream, video/*"}},
                "example": {"file": "(binary: clip.mp4)", "fps": 18, "method": "rnn", "format": "jpg"},
            }
        },
    }


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
                    "options": {"fps": 18.0, "method": "rnn", "format": "png", "quality": 95, "frames": True},
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
                        "fps": 18.0,
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

"""A request's options: the fields beside an upload (and a stream's start message), their OpenAPI schema, and the
engine's method they ask for.

The method options among them (``model_size``, ``gamma``) are not written here: they come from the methods' one
declaration (:mod:`colonlight.methods.options`), as the CLI's flags do, so that both shells take the same values
and refuse a bad one with the same message. Server-side choices (weights file, device, runtime, workers) are
settings, not request options.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model, field_validator
from pydantic_core import PydanticCustomError

from colonlight import DEFAULT_CONTENT, ContentMode, MethodSpec
from colonlight.errors import MethodOptionError
from colonlight.limits import (
    DEFAULT_FPS,
    DEFAULT_FRAME_FORMAT,
    DEFAULT_JPEG_QUALITY,
    DEFAULT_METHOD,
    MAX_FPS,
    MAX_JPEG_QUALITY,
    MIN_JPEG_QUALITY,
    is_usable_fps,
)
from colonlight.methods.options import method_kwargs, option, request_options

from .errors import ApiError
from .schemas import METHODS
from .settings import Settings
from .uploads import MASK_FIELD, MAX_MASK_BYTES

#: The method options a request may set, in declaration order.
METHOD_FIELDS = tuple(o.name for o in request_options())


def check_method_option(name: str, value: Any) -> Any:
    """``value`` of the declared option ``name`` checked by its declaration (a pydantic error with its message)."""
    if value is None:
        return None
    try:
        return option(name).parse(value)
    except MethodOptionError as exc:
        raise PydanticCustomError("value_error", "{message}", {"message": str(exc)}) from None


def method_option_fields() -> dict[str, Any]:
    """Pydantic fields of the declared request options (unset by default: the server's, then the method's)."""
    return {o.name: (Any, Field(None, description=o.description)) for o in request_options()}


class _ClipOptions(BaseModel):
    """The options of a clip that are not a method's."""

    model_config = ConfigDict(extra="forbid")

    fps: float | None = Field(
        None,
        ge=0,
        le=int(MAX_FPS),
        allow_inf_nan=False,
        description=f"Extraction rate; 0 keeps every frame (default: the server's, {DEFAULT_FPS:g}).",
    )
    method: str | None = Field(None, description=f"Enhancement method (default: the server's, {DEFAULT_METHOD}).")
    format: Literal["png", "jpg"] = Field(DEFAULT_FRAME_FORMAT, description="Format of the enhanced frames (the zip).")
    quality: int = Field(DEFAULT_JPEG_QUALITY, ge=MIN_JPEG_QUALITY, le=MAX_JPEG_QUALITY, description="JPEG quality.")
    frames: bool = Field(True, description="Also write the enhanced frames (downloadable as a zip).")
    content: ContentMode = Field(
        DEFAULT_CONTENT,
        description="auto: the method sees only the field of view inside a black border, less fixed on-screen "
        "text; border and text pixels are written unchanged. full: the whole frame. Leave it unset (or auto) "
        f"when sending a `{MASK_FIELD}` part, which is used instead of the detection.",
    )

    @field_validator("*", mode="before")
    @classmethod
    def _blank_is_unset(cls, value: Any) -> Any:
        return None if isinstance(value, str) and value.strip() == "" else value

    @field_validator("fps")
    @classmethod
    def _usable_fps(cls, value: float | None) -> float | None:
        # NaN and infinities are not rates; a positive rate under 1/1001 rounds to 0 frames per second (the CLI's
        # check_fps refuses both too): refused here, not accepted and then failed as a job
        if value is not None and not is_usable_fps(value):
            raise ValueError(f"must be 0 (every frame) or a rate within 1/1001..{MAX_FPS:g}, got {value!r}")
        return 0.0 if value == 0 else value  # "-0" is every frame too, and is recorded as 0.0, not -0.0

    @field_validator("method")
    @classmethod
    def _known_method(cls, value: str | None) -> str | None:
        if value is not None and value not in METHODS:
            raise ValueError(f"unknown method {value!r}; available: {', '.join(METHODS)}")
        return value

    @field_validator(*METHOD_FIELDS, mode="after", check_fields=False)
    @classmethod
    def _method_option(cls, value: Any, info: Any) -> Any:
        return check_method_option(info.field_name, value)

    def method_values(self) -> dict[str, Any]:
        """The method options this request sets (``None``: not set)."""
        return {name: getattr(self, name) for name in METHOD_FIELDS}


#: The options of ``colonlight enhance`` that a request may set (form fields beside the ``file`` part): the
#: clip's, then the methods' declared request options.
JobOptions = create_model("JobOptions", __base__=_ClipOptions, __module__=__name__, **method_option_fields())
JobOptions.__doc__ = "The options of ``colonlight enhance`` that a request may set (form fields beside the file)."


def method_spec(settings: Settings, o: _ClipOptions) -> MethodSpec:
    """The engine's method for a request's options, with the server's weights, device and runtime; a method option
    the method does not take is a 422 with the declaration's message (the CLI's)."""
    name = o.method or settings.method
    fallback = {
        "device": settings.device,
        "runtime": settings.runtime,
        "model_size": settings.model_size,
        "weights": None if settings.weights is None or name != "rnn" else str(settings.weights),
    }
    try:
        return MethodSpec.of(name, **method_kwargs(name, o.method_values(), fallback))
    except MethodOptionError as exc:
        raise ApiError(422, "validation_error", str(exc)) from None


def upload_request_body(description: str) -> dict[str, Any]:
    """OpenAPI description of the multipart body of POST /v1/jobs and POST /v1/enhance (parsed by hand, streamed)."""
    fields = JobOptions.model_fields
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
            "description": fields["fps"].description,
            "example": int(DEFAULT_FPS),
        },
        "method": {"type": "string", "enum": METHODS, "description": fields["method"].description, "example": "rnn"},
        **{o.name: o.json_schema() for o in request_options()},
        "format": {
            "type": "string",
            "enum": ["png", "jpg"],
            "default": "png",
            "description": fields["format"].description,
        },
        "quality": {
            "type": "integer",
            "minimum": 1,
            "maximum": 100,
            "default": 95,
            "description": fields["quality"].description,
        },
        "frames": {"type": "boolean", "default": True, "description": fields["frames"].description},
        "content": {
            "type": "string",
            "enum": ["auto", "full"],
            "default": "auto",
            "description": fields["content"].description,
        },
        MASK_FIELD: {
            "type": "string",
            "format": "binary",
            "description": "Optional: the scope's content mask, used instead of `content` detection (as "
            "`colonlight enhance --content MASK`): one grey channel of the clip's frame size, 255 scene, 0 border, "
            "a level between for fixed text. Binary PGM, PNG or lossless WebP (JPEG and lossy WebP are refused); "
            f"at most {MAX_MASK_BYTES} bytes and COLONLIGHT_MAX_PIXELS pixels. Not with `content=full`.",
        },
    }
    return {
        "required": True,
        "description": description,
        "content": {
            "multipart/form-data": {
                "schema": {"type": "object", "required": ["file"], "properties": props, "additionalProperties": False},
                "encoding": {
                    "file": {"contentType": "application/octet-stream, video/*"},
                    MASK_FIELD: {
                        "contentType": "application/octet-stream, image/png, image/x-portable-graymap, image/webp"
                    },
                },
                "example": {"file": "(binary: clip.mp4)", "fps": int(DEFAULT_FPS), "method": "rnn", "format": "jpg"},
            }
        },
    }

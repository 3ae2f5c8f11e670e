"""``/v1/stream``: live enhancement over a WebSocket, one recurrent state per connection.

Protocol (version 1; every text message is a JSON object with a ``type``):

* client -> ``{"type": "start", "method": "rnn", "model_size": "48", "gamma": null, "format": "jpeg",
  "quality": 90, "frames": true, "content": "auto", "content_mask": {"name": "scope.png", "data": "<base64>"},
  "api_key": "..."}``: optional, first; every field optional. Without it the server's defaults apply from the
  first frame on. ``content`` ``auto`` (the default) shows the method only the field of view inside a black
  border, less fixed text, found on the first frame and again after a change of frame size
  (``colonlight.content.live_content_stream``); its result carries ``"content"`` where the area changes.
  ``content_mask``: a scope's mask image (a job's ``content_mask`` part: PNG, lossless WebP or binary PGM, 255
  scene, 0 border), its file's bytes in base64 inside the start message, so the protocol stays one JSON message
  per step and a browser sends it as it is; used instead of the detection, exactly as ``colonlight stream
  --content MASK`` uses one (border pixels sent back unchanged; a frame of another size is a ``bad_frame``).
  Read off the event loop from the decoded bytes (``content_mask_from_bytes``: the engine's checks, no file).
  ``api_key`` is for browsers, which cannot set headers on a WebSocket; other clients send ``X-API-Key`` or
  ``Authorization: Bearer`` as on every route.
* server -> ``{"type": "ready", "method", "model", "parameters", "format", "frames", "content", "max_pixels",
  "max_frame_bytes"}``: before the first result. ``content`` is the mode, or a mask's record as a job's
  (``{"mask": its name, "sha256"}``), never a server path.
* client -> a binary message: one frame, JPEG or PNG bytes. To give it a timestamp (or any number to match it
  by), send ``{"type": "frame", "time": 12.34}`` just before it; ``time`` is echoed in its result.
* server -> per frame, in order: ``{"type": "result", "index", "time", "gamma", "a", "seed", "clamped", "width",
  "height", "received", "latency_ms", "format", "bytes"}``, then (unless ``frames`` is false) one binary
  message: the enhanced frame in ``format``. ``received`` is the server's wall clock (Unix seconds) when the
  frame arrived, ``latency_ms`` the time from then to sending this record.
* server -> ``{"type": "error", "code", "message", "index"?}`` for a frame it cannot use (``bad_frame``: not a
  JPEG/PNG, corrupt, over the pixel cap) or a bad message (``bad_message``); the frame is skipped, the stream
  and its state go on.
* client -> ``{"type": "end"}``: the server answers frames still held back, sends ``{"type": "end", "frames",
  "errors"}`` and closes with 1000.

Close codes: 1000 after ``end``; 1001 idle for ``COLONLIGHT_STREAM_IDLE_SECONDS``; 1008 no or wrong API key, bad
start options (a content mask beside ``content`` other than ``auto``, not base64, over ``MAX_MASK_BYTES`` decoded,
over the pixel cap, or one the engine refuses: one line naming it by its ``name``), or streams turned off; 1009 a
message over ``COLONLIGHT_STREAM_MAX_FRAME_MB`` (uvicorn; the start message too); 1011 internal error (logged; no
traceback is sent); 1013 ``COLONLIGHT_STREAM_MAX`` streams are open already. Each close but 1009 is preceded by an
``error`` message saying why.

Memory: the server reads a client's next message only after it has sent the answers to the previous one, and
uvicorn stops reading the socket while a message waits, so a client that does not read its answers is pushed
back through TCP and costs one frame and one answer; one that has read nothing for
``COLONLIGHT_STREAM_SEND_TIMEOUT_SECONDS`` is dropped, freeing its place.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import anyio
from fastapi import APIRouter, WebSocket
from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model
from starlette.websockets import WebSocketDisconnect

from colonlight import (
    DEFAULT_CONTENT,
    ColonlightError,
    ContentMode,
    FrameResult,
    MethodStream,
    content_mask_from_bytes,
    live_content_stream,
    parse_json,
)
from colonlight.errors import FrameTooLargeError
from colonlight.limits import MAX_JPEG_QUALITY, MIN_JPEG_QUALITY

if TYPE_CHECKING:  # the type of content_mask_from_bytes's answer, for the checker only
    from colonlight.content_mask import ContentMask

from ..deps import key_is_valid
from ..errors import ApiError
from ..jobs import JobManager
from ..request_options import METHOD_FIELDS, JobOptions, method_option_fields
from ..results import mask_setting
from ..settings import Settings
from ..stream_frames import FrameError, decode_frame, encode_frame, max_pixels
from ..uploads import MASK_FIELD, MAX_MASK_BYTES, display_name

log = logging.getLogger("colonlight.service")
router = APIRouter()

CLOSE_NORMAL = 1000
CLOSE_IDLE = 1001
CLOSE_POLICY = 1008
CLOSE_INTERNAL = 1011
CLOSE_BUSY = 1013
#: Text messages longer than this (a start message carrying a content mask) are parsed off the event loop.
_LARGE_TEXT = 64 * 1024
T = TypeVar("T")


class StreamMask(BaseModel):
    """A scope's content mask in the start message: its image file's bytes in base64 (JSON carries no bytes, and
    the protocol stays one message per step), and the client's name for it, a label only."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(MASK_FIELD, description="The mask's file name, for the ready record and errors; never a path.")
    data: str = Field(description="The image file's bytes (PNG, lossless WebP or binary PGM) in base64 (RFC 4648).")


class _StreamStartBase(BaseModel):
    """The optional first message: the stream's options (the enhancement options of a job, plus the answer's)."""

    model_config = ConfigDict(extra="forbid")

    type: Literal["start"]
    api_key: str | None = Field(None, description="The server's key, for clients that cannot send headers.")
    method: str | None = None
    format: Literal["jpeg", "png"] = Field("jpeg", description="Format of the enhanced frames sent back.")
    quality: int = Field(
        90, ge=MIN_JPEG_QUALITY, le=MAX_JPEG_QUALITY, description="JPEG quality of the frames sent back."
    )
    frames: bool = Field(True, description="Send the enhanced frames (false: the gamma records only).")
    content: ContentMode = Field(
        DEFAULT_CONTENT,
        description="auto: the method sees the field of view inside a black border, less fixed on-screen text, found "
        "on the first frame (none is held back) and checked on every block of frames after; border and text "
        "pixels are sent back unchanged. full: the whole frame.",
    )
    content_mask: StreamMask | None = Field(
        None,
        description="The scope's content mask (255 scene, 0 border; as a job's `content_mask` part), used instead "
        "of the detection: leave `content` unset with it. Frames must have its size.",
    )

    def job_options(self) -> Any:
        """The enhancement options, validated exactly as a job's are (ValidationError): the method and the
        methods' declared request options (``model_size``, ``gamma``, ...)."""
        values = {name: getattr(self, name) for name in METHOD_FIELDS}
        return JobOptions(method=self.method, **values)


#: The start message: its own fields and the methods' declared request options (checked as a job's are).
StreamStart = create_model("StreamStart", __base__=_StreamStartBase, __module__=__name__, **method_option_fields())


class StreamSlots:
    """Streams open at once, at most ``limit`` (one event loop: no lock needed)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.open = 0

    def take(self) -> bool:
        if self.open >= self.limit:
            return False
        self.open += 1
        return True

    def give_back(self) -> None:
        self.open -= 1


class Closing(Exception):
    """End the stream: send ``{"type": "error", code, message}``, then close with ``close_code``. ``rejected``:
    the reason label of ``colonlight_requests_rejected_total`` to count, for a refusal a job upload counts too."""

    def __init__(self, close_code: int, code: str, message: str, reason: str, rejected: str | None = None) -> None:
        super().__init__(message)
        self.close_code, self.code, self.message, self.reason = close_code, code, message, reason
        self.rejected = rejected


class ClientGone(Exception):
    """The client disconnected, or read nothing for the send timeout: leave without a close handshake."""


@dataclass
class Pending:
    """A frame pushed into the method whose result has not been sent yet (methods may hold frames back)."""

    index: int
    time: float | None
    received: float
    width: int
    height: int


def finite(value: Any) -> Any:
    """JSON has no NaN or infinity: such a float (a network output gone wrong) is sent as null, in lists too."""
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def short_errors(exc: ValidationError) -> str:
    return "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'message'}: {e['msg']}" for e in exc.errors())


def mask_refused(code: str, message: str, rejected: str | None = "bad_content_mask") -> Closing:
    """A start message's content mask refused: one line, naming the mask by the client's name, then 1008; counted
    under the job upload's reason for the same refusal (``rejected``; none for a misused option, as for a job)."""
    return Closing(CLOSE_POLICY, code, message, "bad content mask", rejected)


def read_mask(mask: StreamMask, content: str, pixel_limit: int) -> ContentMask:
    """The start message's content mask, decoded and read as a job's upload is (``content_mask_from_bytes``, the
    engine's checks): its text is the client's name, never a server path. Closing (1008) with one line naming it
    for a mask beside ``content`` other than the default, data that is not base64, more than
    :data:`MAX_MASK_BYTES` bytes, over the pixel cap, or anything the engine refuses. Blocking: run in a thread."""
    name = display_name(mask.name or MASK_FIELD)
    if content != DEFAULT_CONTENT:
        raise mask_refused(
            "validation_error",
            f"content mask {name}: a `{MASK_FIELD}` is used instead of content detection; leave `content` unset "
            f"(or {DEFAULT_CONTENT!r}) with it, not {content!r}",
            rejected=None,
        )
    too_large = mask_refused(
        "payload_too_large",
        f"content mask {name}: larger than {MAX_MASK_BYTES} bytes (a mask is one grey channel of the frames' size: "
        "send it as PNG, lossless WebP or binary PGM)",
        rejected="too_large",
    )
    if len(mask.data) > 4 * -(-MAX_MASK_BYTES // 3):  # decodes to more than MAX_MASK_BYTES: not even decoded
        raise too_large
    try:
        data = base64.b64decode(mask.data, validate=True)
    except ValueError as exc:  # binascii.Error, or a character outside ASCII
        raise mask_refused(
            "invalid_content_mask", f"content mask {name}: its data is not valid base64 ({exc})"
        ) from None
    if len(data) > MAX_MASK_BYTES:
        raise too_large
    try:
        loaded = content_mask_from_bytes(data, name, pixel_limit)
    except FrameTooLargeError as exc:
        raise mask_over_cap(name, exc.width, exc.height, pixel_limit) from None
    except ColonlightError as exc:
        raise mask_refused("invalid_content_mask", f"content mask {exc}") from None
    height, width = loaded.area.fov.shape
    if width * height > pixel_limit:  # a header the size check could not read
        raise mask_over_cap(name, width, height, pixel_limit)
    return loaded


def mask_over_cap(name: str, width: int, height: int, pixel_limit: int) -> Closing:
    return mask_refused(
        "frame_too_large",
        f"content mask {name}: it is {width}x{height} ({width * height} pixels), over this server's limit of "
        f"{pixel_limit} pixels a frame (COLONLIGHT_MAX_PIXELS)",
        rejected="too_many_pixels",
    )


class StreamSession:
    """One connection: its options, its method stream (the recurrent state) and its counters."""

    def __init__(self, ws: WebSocket, settings: Settings, manager: JobManager) -> None:
        self.ws = ws
        self.settings = settings
        self.manager = manager
        self.options: StreamStart | None = None
        self.stream: MethodStream | None = None
        self.pending: deque[Pending] = deque()
        self.pixel_limit = max_pixels()
        self.next_time: float | None = None
        self.messages = self.frames_in = self.frames_out = self.errors = 0

    # ------------------------------------------------------------------------------------------ transport

    async def send(self, message: dict[str, Any] | bytes) -> None:
        payload: dict[str, Any] = (
            {"type": "websocket.send", "bytes": message}
            if isinstance(message, bytes)
            else {"type": "websocket.send", "text": json.dumps(message, allow_nan=False)}
        )
        try:
            await asyncio.wait_for(self.ws.send(payload), self.settings.stream_send_timeout_seconds)
        except asyncio.TimeoutError:
            raise ClientGone(f"read nothing for {self.settings.stream_send_timeout_seconds:g} s") from None
        except (WebSocketDisconnect, OSError, RuntimeError):
            raise ClientGone("disconnected") from None

    async def receive(self) -> dict[str, Any]:
        idle = self.settings.stream_idle_seconds
        try:
            message = dict(await asyncio.wait_for(self.ws.receive(), idle))  # starlette types it a MutableMapping
        except asyncio.TimeoutError:
            raise Closing(
                CLOSE_IDLE,
                "idle",
                f"no message for {idle:g} s (COLONLIGHT_STREAM_IDLE_SECONDS)",
                f"idle for {idle:g} s",
            ) from None
        except (WebSocketDisconnect, OSError, RuntimeError):
            raise ClientGone("disconnected") from None
        if message["type"] == "websocket.disconnect":
            raise ClientGone(f"disconnected ({message.get('code')})")
        self.messages += 1
        return message

    async def close(self, code: int, reason: str) -> None:
        with contextlib.suppress(asyncio.TimeoutError, WebSocketDisconnect, OSError, RuntimeError):
            await asyncio.wait_for(self.ws.close(code, reason[:120]), self.settings.stream_send_timeout_seconds)

    # ------------------------------------------------------------------------------------------ protocol

    @staticmethod
    def parse_text(text: str) -> dict[str, Any]:
        try:
            value = parse_json(text)
        except ValueError:
            raise FrameError(f"a text message must be a JSON object, got {text[:60]!r}") from None
        if not isinstance(value, dict) or not isinstance(value.get("type"), str):
            raise FrameError('a text message must be a JSON object with a "type" ("start", "frame" or "end")')
        return value

    async def start(self, options: StreamStart) -> None:
        """Read the start message's content mask if it has one, build (or fetch) the method for ``options`` and a
        fresh stream of it; send ``ready``."""
        mask: ContentMask | None = None
        if options.content_mask is not None:  # decoded and read off the event loop: other streams go on
            mask = await anyio.to_thread.run_sync(read_mask, options.content_mask, options.content, self.pixel_limit)
            options = options.model_copy(update={"content_mask": None})  # its base64 is not kept for the stream
        try:
            spec = self.manager.method_spec(options.job_options())
            await self.manager.check_method(spec)
            method = await anyio.to_thread.run_sync(self.manager.methods.get, spec)
        except ValidationError as exc:
            raise Closing(
                CLOSE_POLICY, "validation_error", f"bad start options: {short_errors(exc)}", "bad start options"
            ) from None
        except ApiError as exc:
            close = CLOSE_POLICY if exc.status == 422 else CLOSE_INTERNAL
            raise Closing(close, exc.code, exc.message, exc.code) from None
        except ColonlightError as exc:
            raise Closing(
                CLOSE_INTERNAL, "model_unavailable", f"the model could not be loaded: {exc}", "model unavailable"
            ) from None
        self.options = options
        # with a mask, the engine's own stream for it (``colonlight stream --content MASK``'s): its area on every
        # frame, border pixels sent back unchanged, a frame of another size refused naming the mask
        self.stream = live_content_stream(method, options.content if mask is None else mask)
        await self.send(
            {
                "type": "ready",
                "method": method.name,
                "model": method.model_info(),
                "parameters": method.parameters(),
                "format": options.format,
                "frames": options.frames,
                "content": options.content if mask is None else mask_setting(str(mask), mask.sha256),
                "max_pixels": self.pixel_limit,
                "max_frame_bytes": self.settings.stream_max_frame_bytes,
            }
        )

    async def handle_text(self, message: dict[str, Any]) -> bool:
        """Act on a control message; False once the client has ended the stream."""
        kind = message["type"]
        if kind == "start":
            if self.options is not None:
                raise FrameError('"start" must be the first message; this stream has started already')
            try:  # in a thread: a start message may carry a mask's megabytes of base64
                await self.start(await anyio.to_thread.run_sync(StreamStart.model_validate, message))
            except ValidationError as exc:
                raise Closing(
                    CLOSE_POLICY, "validation_error", f"bad start options: {short_errors(exc)}", "bad start options"
                ) from None
        elif kind == "frame":
            t = message.get("time")
            if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t)):
                raise FrameError(f'"time" must be a finite number, got {t!r}')
            self.next_time = None if t is None else float(t)
        elif kind == "end":
            if self.stream is not None:
                results = await anyio.to_thread.run_sync(self.stream.flush)
                await self.send_results(results)
            await self.send({"type": "end", "frames": self.frames_out, "errors": self.errors})
            return False
        else:
            raise FrameError(f'unknown message type {kind!r}; expected "start", "frame" or "end"')
        return True

    async def handle_frame(self, data: bytes, received: float) -> None:
        if self.options is None:
            await self.start(StreamStart(type="start"))
        assert self.stream is not None
        stream, limit, t = self.stream, self.pixel_limit, self.next_time
        self.next_time = None

        def decode_and_push() -> tuple[Pending, list[FrameResult]]:
            frame = decode_frame(data, limit)
            meta = Pending(self.frames_in, t, received, frame.shape[1], frame.shape[0])
            try:
                return meta, stream.push(frame)
            except FrameError:
                raise
            except ColonlightError as exc:  # FrameShapeError: e.g. a method that needs every frame the same size
                raise FrameError(str(exc)) from None

        meta, results = await anyio.to_thread.run_sync(decode_and_push)
        self.frames_in += 1
        self.pending.append(meta)
        await self.send_results(results)

    async def send_results(self, results: list[FrameResult]) -> None:
        assert self.options is not None
        opts = self.options
        for res in results:
            meta = self.pending.popleft()
            payload = (
                await anyio.to_thread.run_sync(encode_frame, res.frame, opts.format, opts.quality)
                if opts.frames
                else None
            )
            record: dict[str, Any] = {
                "type": "result",
                "index": meta.index,
                "time": meta.time,
                "gamma": finite(res.gamma),
                **{k: finite(v) for k, v in res.info.items()},
                "width": meta.width,
                "height": meta.height,
                "received": round(meta.received, 6),
                "latency_ms": round((time.time() - meta.received) * 1000, 3),
                "format": opts.format if opts.frames else None,
                "bytes": len(payload) if payload else 0,
            }
            await self.send(record)
            if payload is not None:
                await self.send(payload)
            self.frames_out += 1
            self.manager.metrics.inc("frames")

    async def run(self, first: dict[str, Any] | None = None) -> None:
        """Messages in, answers out, one at a time (the next message is read only once this one is answered)."""
        while True:
            message, first = (first, None) if first is not None else (await self.receive(), None)
            received = time.time()
            try:
                if message.get("bytes") is not None:
                    await self.handle_frame(message["bytes"], received)
                elif not await self.handle_text(await parse_off_loop(self.parse_text, message.get("text") or "")):
                    return
            except FrameError as exc:
                self.errors += 1
                if message.get("bytes") is not None:
                    error = {"type": "error", "code": "bad_frame", "message": f"message {self.messages}: {exc}"}
                else:
                    error = {"type": "error", "code": "bad_message", "message": f"message {self.messages}: {exc}"}
                await self.send(error)


def header_key_ok(ws: WebSocket, settings: Settings) -> bool:
    """The key rule of every route: ``X-API-Key: <key>`` or ``Authorization: Bearer <key>``."""
    bearer = ws.headers.get("authorization", "")
    offered = [ws.headers.get("x-api-key"), bearer[7:].strip() if bearer[:7].lower() == "bearer " else None]
    return key_is_valid(settings, *offered)


async def parse_off_loop(parse: Callable[[str], T], text: str) -> T:
    """``parse(text)``, in a thread for a long text (a start message with a content mask: megabytes of JSON)."""
    return parse(text) if len(text) <= _LARGE_TEXT else await anyio.to_thread.run_sync(parse, text)


async def start_key(message: dict[str, Any]) -> str | None:
    """The ``api_key`` of a first message that is a JSON start message, else None."""
    try:
        value = await parse_off_loop(parse_json, message.get("text") or "null")
    except ValueError:
        return None
    key = value.get("api_key") if isinstance(value, dict) and value.get("type") == "start" else None
    return key if isinstance(key, str) else None


@router.websocket("/v1/stream")
async def stream(ws: WebSocket) -> None:
    settings: Settings = ws.app.state.settings
    manager: JobManager = ws.app.state.manager
    slots: StreamSlots = ws.app.state.stream_slots
    await ws.accept()
    session = StreamSession(ws, settings, manager)
    holding = False
    close: tuple[int, str] | None = None
    try:
        first: dict[str, Any] | None = None
        if not header_key_ok(ws, settings):  # a browser: the key may come in the start message
            first = await session.receive()
            if not key_is_valid(settings, await start_key(first)):
                raise Closing(
                    CLOSE_POLICY,
                    "unauthorized",
                    "this server requires an API key: send it as an X-API-Key header, as Authorization: "
                    'Bearer <key>, or as "api_key" in the start message',
                    "unauthorized",
                )
        if settings.stream_max == 0:
            raise Closing(
                CLOSE_POLICY,
                "streams_off",
                "streams are turned off on this server (COLONLIGHT_STREAM_MAX=0)",
                "streams are turned off",
            )
        if not slots.take():
            raise Closing(
                CLOSE_BUSY,
                "busy",
                f"the server has {slots.limit} streams open, its limit (COLONLIGHT_STREAM_MAX); try again later",
                f"busy: {slots.limit} streams open, try again later",
                rejected="streams_full",
            )
        holding = True
        await session.run(first)
        close = (CLOSE_NORMAL, "end of stream")
    except Closing as exc:
        if exc.rejected is not None:
            manager.metrics.inc("rejected", exc.rejected)
        try:
            await session.send({"type": "error", "code": exc.code, "message": exc.message})
            close = (exc.close_code, exc.reason)
        except ClientGone:
            pass
    except ClientGone as exc:
        log.info("stream ended after %d frames: client %s", session.frames_out, exc)
    except Exception:  # noqa: BLE001 - a bug ends this stream, never the server; the client gets no traceback
        log.exception("stream failed after %d frames", session.frames_out)
        try:
            await session.send(
                {"type": "error", "code": "internal_error", "message": "internal error; see the server log"}
            )
            close = (CLOSE_INTERNAL, "internal error")
        except ClientGone:
            pass
    finally:
        if holding:
            slots.give_back()  # before the close frame: a client that reconnects on it finds its place free
    if close is not None:
        await session.close(*close)

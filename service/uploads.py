"""Multipart uploads streamed to disk chunk by chunk, with a size cap enforced while the bytes arrive.

FastAPI's ``UploadFile`` would parse the whole body into a temporary file before the route runs; here the route
reads the request stream itself, so that an upload over the cap is answered with 413 as soon as the cap is
crossed, one whose body stops arriving (or only trickles) with 408 once it has made too little progress for the
idle time, one that meets a full disk with 507, and nothing of any of them stays on disk. The client's file name
is kept only as a label, never as a path.
"""

from __future__ import annotations

import contextlib
import re
import unicodedata
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING

import anyio
from python_multipart.exceptions import FormParserError, MultipartParseError
from python_multipart.multipart import MultipartParser, MultipartState, parse_options_header
from starlette.requests import ClientDisconnect, Request

from colonlight import VIDEO_SUFFIXES

if TYPE_CHECKING:  # python-multipart defines its callback table's type for checkers only
    from python_multipart.multipart import MultipartCallbacks

from .errors import ApiError, is_disk_full, storage_full

FILE_FIELD = "file"
MAX_FIELDS = 32
MAX_FIELD_BYTES = 8 * 1024
_MULTIPART_OVERHEAD = 64 * 1024  # boundaries, part headers and small fields on top of the file


@dataclass
class Upload:
    path: Path  # where the bytes are (a name chosen by the server)
    filename: str  # the client's name for it, sanitised, for display only
    size: int
    fields: dict[str, str] = field(default_factory=dict)

    def discard(self) -> None:
        self.path.unlink(missing_ok=True)


def display_name(raw: str | None) -> str:
    """The client's file name reduced to a harmless label: last path component, no control characters."""
    name = (raw or "").replace("\\", "/").rsplit("/", 1)[-1]
    name = "".join(ch for ch in name if unicodedata.category(ch)[0] != "C").strip()
    name = name.lstrip(".") or "upload"
    return name[:200]


def safe_suffix(filename: str) -> str:
    """A known video suffix of ``filename`` (lower case), else ``""``: a hint for the demuxer, nothing more."""
    m = re.search(r"\.[A-Za-z0-9]{1,5}$", filename)
    suffix = m.group(0).lower() if m else ""
    return suffix if suffix in VIDEO_SUFFIXES else ""


class _Collector:
    """python-multipart callbacks: small fields kept in memory, the one file part handed out in pieces."""

    def __init__(self) -> None:
        self.fields: dict[str, str] = {}
        self.filename: str | None = None
        self.file_seen = False
        self.pending: list[bytes] = []  # file bytes of the current chunk, written after each feed
        self._in_file = False
        self._name = ""
        self._data = bytearray()
        self._header_name = b""
        self._header_value = b""
        self._disposition = b""

    def on_part_begin(self) -> None:
        self._in_file = False
        self._name = ""
        self._data = bytearray()
        self._disposition = b""

    def on_header_field(self, data: bytes, start: int, end: int) -> None:
        self._header_name += data[start:end]

    def on_header_value(self, data: bytes, start: int, end: int) -> None:
        self._header_value += data[start:end]

    def on_header_end(self) -> None:
        if self._header_name.strip().lower() == b"content-disposition":
            self._disposition = self._header_value
        self._header_name = self._header_value = b""

    def on_headers_finished(self) -> None:
        _, options = parse_options_header(self._disposition)
        raw_name = options.get(b"name")
        if raw_name is None:
            raise ApiError(400, "bad_request", "a multipart part has no name in its Content-Disposition header")
        self._name = raw_name.decode("utf-8", "replace")
        if self._name == FILE_FIELD:
            if self.file_seen:
                raise ApiError(422, "validation_error", f"send exactly one `{FILE_FIELD}` part")
            self.file_seen = self._in_file = True
            raw_filename = options.get(b"filename")
            self.filename = raw_filename.decode("utf-8", "replace") if raw_filename is not None else None
        elif len(self.fields) >= MAX_FIELDS:
            raise ApiError(422, "validation_error", f"too many form fields (at most {MAX_FIELDS})")

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        if self._in_file:
            self.pending.append(data[start:end])
            return
        self._data += data[start:end]
        if len(self._data) > MAX_FIELD_BYTES:
            raise ApiError(
                422, "validation_error", f"form field `{self._name[:50]}` is longer than {MAX_FIELD_BYTES} bytes"
            )

    def on_part_end(self) -> None:
        if not self._in_file:
            if self._name in self.fields:
                raise ApiError(422, "validation_error", f"form field `{self._name[:50]}` is given twice")
            self.fields[self._name] = self._data.decode("utf-8", "replace")

    def callbacks(self) -> MultipartCallbacks:
        return {
            "on_part_begin": self.on_part_begin,
            "on_header_field": self.on_header_field,
            "on_header_value": self.on_header_value,
            "on_header_end": self.on_header_end,
            "on_headers_finished": self.on_headers_finished,
            "on_part_data": self.on_part_data,
            "on_part_end": self.on_part_end,
        }


def _boundary(request: Request) -> bytes:
    ctype = request.headers.get("content-type", "")
    kind, params = parse_options_header(ctype)
    if kind != b"multipart/form-data":
        raise ApiError(
            415,
            "unsupported_media_type",
            f"send the clip as multipart/form-data in a part named `{FILE_FIELD}` "
            f"(got {ctype[:80] or 'no content type'!r})",
            CLOSE,
        )
    boundary = params.get(b"boundary")
    if not boundary:
        raise ApiError(400, "bad_request", "multipart/form-data without a boundary", CLOSE)
    return boundary


#: Sent with refusals made before the body was read: the server then closes the connection instead of reading
#: (and discarding) the rest of an upload it has already refused.
CLOSE = {"Connection": "close"}


def too_large(max_bytes: int) -> ApiError:
    return ApiError(
        413,
        "payload_too_large",
        f"the upload is larger than this server's limit of {max_bytes / 1048576:g} MiB (COLONLIGHT_MAX_UPLOAD_MB)",
        CLOSE,
    )


def stalled(idle_seconds: float, need: int) -> ApiError:
    return ApiError(
        408,
        "request_timeout",
        f"the upload made no progress: under {need} bytes arrived in {idle_seconds:g} s "
        "(COLONLIGHT_UPLOAD_IDLE_SECONDS, COLONLIGHT_UPLOAD_MIN_BYTES_PER_S); what had arrived was discarded",
        CLOSE,
    )


async def _chunks(request: Request, idle_seconds: float, min_bytes_per_s: float) -> AsyncIterator[bytes]:
    """The body of ``request`` chunk by chunk; 408 when a window of ``idle_seconds`` brings fewer than
    ``min_bytes_per_s * idle_seconds`` bytes (at least one), so that a client trickling a byte now and then
    cannot hold an upload place for ever. Windows follow each other from the start of the body."""
    stream = request.stream().__aiter__()
    need = max(1, int(min_bytes_per_s * idle_seconds))
    window_end = anyio.current_time() + idle_seconds
    got = 0
    while True:
        # A window short of bytes fails at its end; a satisfied one lets the next window run its course too.
        deadline = window_end if got < need else window_end + idle_seconds
        with anyio.move_on_after(deadline - anyio.current_time()) as wait:
            try:
                chunk = await stream.__anext__()
            except StopAsyncIteration:
                return
        if wait.cancelled_caught:
            raise stalled(idle_seconds, need)
        while anyio.current_time() >= window_end:
            if got < need:
                raise stalled(idle_seconds, need)
            window_end += idle_seconds
            got = 0
        got += len(chunk)
        yield chunk


async def receive_upload(
    request: Request, dest: Path, max_bytes: int, idle_seconds: float, min_bytes_per_s: float = 0.0
) -> Upload:
    """Stream the multipart body of ``request``: the ``file`` part to ``dest``, other parts as text fields.

    Raises :class:`ApiError`: 415 (not multipart), 413 (over ``max_bytes``, checked against Content-Length first
    and then while reading), 408 (too few body bytes in a window of ``idle_seconds``, see :func:`_chunks`), 507
    (the disk is full), 400 (malformed body), 422 (no file part, too many or too long fields). ``dest`` is
    removed on every error.
    """
    boundary = _boundary(request)
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > max_bytes + _MULTIPART_OVERHEAD:
        raise too_large(max_bytes)
    collector = _Collector()
    try:
        parser = MultipartParser(boundary, collector.callbacks())
    except FormParserError as exc:  # e.g. a boundary over python-multipart's 256 bytes: the client's fault, not a 500
        raise ApiError(400, "bad_request", f"malformed multipart/form-data header: {str(exc)[:200]}", CLOSE) from None
    size = 0
    fh: IO[bytes] | None = None
    try:
        fh = await anyio.to_thread.run_sync(lambda: open(dest, "xb"))  # noqa: SIM115 - closed below
        async for chunk in _chunks(request, idle_seconds, min_bytes_per_s):
            parser.write(chunk)
            if collector.pending:
                data = b"".join(collector.pending)
                collector.pending.clear()
                size += len(data)
                if size > max_bytes:
                    raise too_large(max_bytes)
                await anyio.to_thread.run_sync(fh.write, data)
        parser.finalize()
        await anyio.to_thread.run_sync(fh.close)
        if parser.state != MultipartState.END:
            raise ApiError(400, "bad_request", "incomplete multipart body: the closing boundary never came")
        if not collector.file_seen:
            raise ApiError(
                422, "validation_error", f"the form has no `{FILE_FIELD}` part: attach the clip as `{FILE_FIELD}`"
            )
    except MultipartParseError as exc:
        _cleanup(fh, dest)
        raise ApiError(400, "bad_request", f"malformed multipart body: {str(exc)[:200]}") from None
    except ClientDisconnect:
        _cleanup(fh, dest)
        raise ApiError(400, "client_disconnected", "the client went away during the upload") from None
    except OSError as exc:
        _cleanup(fh, dest)
        if is_disk_full(exc):
            raise storage_full() from None
        raise
    except BaseException:
        _cleanup(fh, dest)
        raise
    return Upload(path=dest, filename=display_name(collector.filename), size=size, fields=collector.fields)


def _cleanup(fh: IO[bytes] | None, dest: Path) -> None:
    if fh is not None:
        with contextlib.suppress(OSError):
            fh.close()
    dest.unlink(missing_ok=True)

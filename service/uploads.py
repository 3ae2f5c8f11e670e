"""Multipart uploads streamed to disk chunk by chunk, with a size cap enforced while the bytes arrive.

FastAPI's ``UploadFile`` would parse the whole body into a temporary file before the route runs; here the route
reads the request stream itself, so that an upload over the cap is answered with 413 as soon as the cap is
crossed, one whose body stops arriving (or only trickles) with 408 once it has made too little progress for the
idle time, one that meets a full disk with 507, and nothing of any of them stays on disk. The client's file name
is kept only as a label, never as a path. An optional second file part, ``content_mask`` (a scope's content mask
image, used instead of detecting the area), is streamed the same way beside the clip under its own small cap.
"""

from __future__ import annotations

import contextlib
import re
import unicodedata
from collections.abc import AsyncIterator, Iterable
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
MASK_FIELD = "content_mask"
#: A binary PGM mask of a frame at the default pixel cap (4096x4096) is 16 MiB and its header: masks are small
#: beside clips (a 1080p PGM is 2 MiB, a PNG of one a few KiB), and this bounds what a mask part may write.
MAX_MASK_BYTES = 16 * 1024 * 1024 + 4096
MAX_FIELDS = 32
MAX_FIELD_BYTES = 8 * 1024
_MULTIPART_OVERHEAD = 64 * 1024  # boundaries, part headers and small fields on top of the file


@dataclass
class MaskUpload:
    """The ``content_mask`` part: where its bytes are (beside the clip's, a name chosen by the server), the client's
    name for it (a label only), and the SHA-256 of those bytes once they have been checked as a mask."""

    path: Path
    filename: str
    size: int
    sha256: str = ""


@dataclass
class Upload:
    path: Path  # where the bytes are (a name chosen by the server)
    filename: str  # the client's name for it, sanitised, for display only
    size: int
    fields: dict[str, str] = field(default_factory=dict)
    mask: MaskUpload | None = None  # the optional ``content_mask`` part

    def discard(self) -> None:
        self.path.unlink(missing_ok=True)
        if self.mask is not None:
            self.mask.path.unlink(missing_ok=True)

    def on_disk(self) -> bool:
        """Whether a file of this upload is still where it was received (a job moves them away)."""
        return self.path.exists() or (self.mask is not None and self.mask.path.exists())


def mask_path(dest: Path) -> Path:
    """Where the ``content_mask`` part of the upload received at ``dest`` is written (beside it, same token)."""
    return dest.with_suffix(".mask")


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
    """python-multipart callbacks: small fields kept in memory, the file parts (the clip, and at most one mask)
    handed out in pieces."""

    def __init__(self) -> None:
        self.fields: dict[str, str] = {}
        self.filenames: dict[str, str | None] = {}  # file part -> the client's file name, once the part is seen
        self.pending: list[tuple[str, bytes]] = []  # (file part, bytes) of the current chunk, written after each feed
        self._in_file: str | None = None
        self._name = ""
        self._data = bytearray()
        self._header_name = b""
        self._header_value = b""
        self._disposition = b""

    @property
    def file_seen(self) -> bool:
        return FILE_FIELD in self.filenames

    def on_part_begin(self) -> None:
        self._in_file = None
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
        if self._name in (FILE_FIELD, MASK_FIELD):
            if self._name in self.filenames:
                which = "exactly one" if self._name == FILE_FIELD else "at most one"
                raise ApiError(422, "validation_error", f"send {which} `{self._name}` part")
            self._in_file = self._name
            raw_filename = options.get(b"filename")
            self.filenames[self._name] = raw_filename.decode("utf-8", "replace") if raw_filename is not None else None
        elif len(self.fields) >= MAX_FIELDS:
            raise ApiError(422, "validation_error", f"too many form fields (at most {MAX_FIELDS})")

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        if self._in_file is not None:
            self.pending.append((self._in_file, data[start:end]))
            return
        self._data += data[start:end]
        if len(self._data) > MAX_FIELD_BYTES:
            raise ApiError(
                422, "validation_error", f"form field `{self._name[:50]}` is longer than {MAX_FIELD_BYTES} bytes"
            )

    def on_part_end(self) -> None:
        if self._in_file is None:
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


def mask_too_large(filename: str | None) -> ApiError:
    return ApiError(
        413,
        "payload_too_large",
        f"{display_name(filename)}: the `{MASK_FIELD}` part is larger than {MAX_MASK_BYTES} bytes (a mask is one grey "
        "channel of the clip's frame size: send it as PNG, lossless WebP or binary PGM)",
        CLOSE,
    )


class _PartFile:
    """One file part written to ``path`` as it arrives, opened on its first bytes, refused past ``cap`` bytes."""

    def __init__(self, path: Path, cap: int, too_big: ApiError) -> None:
        self.path, self.cap, self.too_big = path, cap, too_big
        self.size = 0
        self._fh: IO[bytes] | None = None

    async def open(self) -> IO[bytes]:
        """The part's file, created on first use (``x``: a name of the server's, never one already there)."""
        if self._fh is None:
            self._fh = await anyio.to_thread.run_sync(lambda: open(self.path, "xb"))  # noqa: SIM115 - closed below
        return self._fh

    async def write(self, data: bytes) -> None:
        self.size += len(data)
        if self.size > self.cap:
            raise self.too_big
        await anyio.to_thread.run_sync((await self.open()).write, data)

    async def close(self) -> None:
        """Close the file; one that never got a byte is created empty (a part of no bytes is still a file)."""
        await anyio.to_thread.run_sync((await self.open()).close)

    def cleanup(self) -> None:
        if self._fh is not None:
            with contextlib.suppress(OSError):
                self._fh.close()
        self.path.unlink(missing_ok=True)


def _mask_part(collector: _Collector, part: _PartFile) -> MaskUpload | None:
    """The ``content_mask`` part received, if any: one with no bytes and no file name (a browser's form with no
    mask chosen) counts as none."""
    if MASK_FIELD not in collector.filenames:
        return None
    raw = collector.filenames[MASK_FIELD]
    if part.size == 0 and not raw:
        part.path.unlink(missing_ok=True)
        return None
    return MaskUpload(path=part.path, filename=display_name(raw or "content_mask"), size=part.size)


async def receive_upload(
    request: Request, dest: Path, max_bytes: int, idle_seconds: float, min_bytes_per_s: float = 0.0
) -> Upload:
    """Stream the multipart body of ``request``: the ``file`` part to ``dest``, a ``content_mask`` part (optional,
    at most :data:`MAX_MASK_BYTES`) to :func:`mask_path`, other parts as text fields.

    Raises :class:`ApiError`: 415 (not multipart), 413 (over ``max_bytes``, checked against Content-Length first
    and then while reading), 408 (too few body bytes in a window of ``idle_seconds``, see :func:`_chunks`), 507
    (the disk is full), 400 (malformed body), 422 (no file part, too many or too long fields). ``dest`` and the
    mask's file are removed on every error.
    """
    boundary = _boundary(request)
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > max_bytes + MAX_MASK_BYTES + _MULTIPART_OVERHEAD:
        raise too_large(max_bytes)
    collector = _Collector()
    try:
        parser = MultipartParser(boundary, collector.callbacks())
    except FormParserError as exc:  # e.g. a boundary over python-multipart's 256 bytes: the client's fault, not a 500
        raise ApiError(400, "bad_request", f"malformed multipart/form-data header: {str(exc)[:200]}", CLOSE) from None
    parts = {
        FILE_FIELD: _PartFile(dest, max_bytes, too_large(max_bytes)),
        MASK_FIELD: _PartFile(mask_path(dest), MAX_MASK_BYTES, mask_too_large(None)),
    }
    try:
        await parts[FILE_FIELD].open()  # the clip's name is taken before any byte comes
        async for chunk in _chunks(request, idle_seconds, min_bytes_per_s):
            parser.write(chunk)
            for name, data in collector.pending:
                if name == MASK_FIELD:
                    parts[name].too_big = mask_too_large(collector.filenames.get(MASK_FIELD))
                await parts[name].write(data)
            collector.pending.clear()
        parser.finalize()
        for name in collector.filenames:
            await parts[name].close()
        if parser.state != MultipartState.END:
            raise ApiError(400, "bad_request", "incomplete multipart body: the closing boundary never came")
        if not collector.file_seen:
            raise ApiError(
                422, "validation_error", f"the form has no `{FILE_FIELD}` part: attach the clip as `{FILE_FIELD}`"
            )
        mask = _mask_part(collector, parts[MASK_FIELD])
    except MultipartParseError as exc:
        _cleanup(parts.values())
        raise ApiError(400, "bad_request", f"malformed multipart body: {str(exc)[:200]}") from None
    except ClientDisconnect:
        _cleanup(parts.values())
        raise ApiError(400, "client_disconnected", "the client went away during the upload") from None
    except OSError as exc:
        _cleanup(parts.values())
        if is_disk_full(exc):
            raise storage_full() from None
        raise
    except BaseException:
        _cleanup(parts.values())
        raise
    filename = display_name(collector.filenames[FILE_FIELD])
    return Upload(path=dest, filename=filename, size=parts[FILE_FIELD].size, fields=collector.fields, mask=mask)


def _cleanup(parts: Iterable[_PartFile]) -> None:
    for part in parts:
        part.cleanup()

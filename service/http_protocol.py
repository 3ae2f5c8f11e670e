"""uvicorn's HTTP/1.1 protocol (h11) with a deadline on request headers, against slowloris clients.

uvicorn times out an idle keep-alive connection, but not one that is sending its request headers: a client that
sends ``POST / HTTP/1.1\\r\\nHost: x\\r\\n`` and then a byte every few seconds (or connects and sends nothing)
holds its connection, and its file descriptor, forever. Many such clients exhaust the server's descriptors while
sending almost nothing. Here every request's headers must be complete within ``header_timeout`` seconds of the
connection opening (or of the previous response on a kept-alive connection): a client that sent part of its
headers is answered 408 with the service's JSON error body and the connection is closed; one that sent nothing
is closed, as an idle keep-alive connection is. The deadline ends when the headers are complete: a slow body is
the upload's own timeouts' business (``COLONLIGHT_UPLOAD_IDLE_SECONDS``).

A request h11 cannot parse (a ``Content-Length`` that is no number or past any size, both ``Content-Length`` and
``Transfer-Encoding``, headers too long) is answered 400 with the same JSON error body, not uvicorn's plain text.

``colonlight serve`` passes the class made by :func:`header_deadline_protocol` to ``uvicorn.run(http=...)``.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from .settings import DEFAULT_HEADER_TIMEOUT_S

#: the JSON error body of a 408 sent for headers that came too slowly (same shape as every service error)
_CODE = "header_timeout"


def _json_response(status: int, reason: str, code: str, message: str) -> bytes:
    """A complete HTTP/1.1 response carrying the service's JSON error body; the connection closes after it."""
    body = json.dumps({"status": status, "code": code, "message": message}).encode()
    head = (
        f"HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\nconnection: close\r\n"
        f"content-length: {len(body)}\r\n\r\n"
    ).encode()
    return head + body


def _response_408(seconds: float) -> bytes:
    return _json_response(
        408,
        "Request Timeout",
        _CODE,
        f"the request headers were not complete within {seconds:g} s (COLONLIGHT_HEADER_TIMEOUT_SECONDS)",
    )


#: the answer to a request h11 cannot parse (uvicorn's own is text/plain "Invalid HTTP request received.")
_RESPONSE_400 = _json_response(
    400,
    "Bad Request",
    "bad_request",
    "malformed HTTP request: its request line, headers or framing (Content-Length, Transfer-Encoding) are invalid",
)


class HeaderDeadlineProtocol(H11Protocol):
    """:class:`H11Protocol` whose request headers must arrive within :attr:`header_timeout` seconds."""

    header_timeout: float = DEFAULT_HEADER_TIMEOUT_S

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._header_deadline: asyncio.TimerHandle | None = None
        self._header_bytes = 0  # bytes received towards the request whose headers are awaited

    def _arm_header_deadline(self) -> None:
        self._cancel_header_deadline()
        self._header_bytes = 0
        self._header_deadline = self.loop.call_later(self.header_timeout, self._header_deadline_passed)

    def _cancel_header_deadline(self) -> None:
        if self._header_deadline is not None:
            self._header_deadline.cancel()
            self._header_deadline = None

    def _awaiting_headers(self) -> bool:
        return self.conn.their_state is h11.IDLE and self.transport is not None and not self.transport.is_closing()

    def _header_deadline_passed(self) -> None:
        self._header_deadline = None
        if not self._awaiting_headers():
            return
        if self._header_bytes:  # part of a request came: say why it is cut off
            self.logger.warning("request headers not complete within %g s: closing with 408", self.header_timeout)
            self.transport.write(_response_408(self.header_timeout))
        self.transport.close()

    def send_400_response(self, msg: str) -> None:
        """A request h11 refused (``msg``: uvicorn's text, already logged): the JSON error, then close."""
        self._cancel_header_deadline()
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(_RESPONSE_400)
            self.transport.close()

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm_header_deadline()

    def data_received(self, data: bytes) -> None:
        if self._header_deadline is not None:
            self._header_bytes += len(data)
        super().data_received(data)
        if self._header_deadline is not None and self.conn.their_state is not h11.IDLE:
            self._cancel_header_deadline()  # the headers are complete (or the connection is being upgraded)

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if self._header_deadline is None and self._awaiting_headers():
            self._arm_header_deadline()  # a kept-alive connection: the next request's headers are due in time

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_header_deadline()
        super().connection_lost(exc)


def header_deadline_protocol(seconds: float) -> type[HeaderDeadlineProtocol]:
    """A :class:`HeaderDeadlineProtocol` class with a deadline of ``seconds``, for ``uvicorn.run(http=...)``."""
    return type("HeaderDeadlineProtocol", (HeaderDeadlineProtocol,), {"header_timeout": float(seconds)})

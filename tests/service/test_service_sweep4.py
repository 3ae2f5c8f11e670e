"""Hostile input against a real ``colonlight serve`` (uvicorn on loopback), fourth sweep: a ``/v1/stream`` text
message nested too deep for Python's JSON decoder, and requests whose HTTP framing h11 refuses (a Content-Length
that is no number or past any size, Content-Length beside Transfer-Encoding). Each is answered with the service's
JSON error, the stream or the server goes on, and no traceback reaches the log."""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator

import httpx
import pytest
from websockets.sync.client import connect

from ..service_server import ServiceServer

pytestmark = pytest.mark.timeout(120)

#: deeper than Python's recursion limit: json.loads raises RecursionError, not ValueError
DEEP = "[" * 5000 + "]" * 5000


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("sweep4") / "data"
    env = {"COLONLIGHT_METHOD": "gamma", "COLONLIGHT_WORKERS": "1"}
    srv = ServiceServer(data, env).start()
    try:
        yield srv
        assert "Traceback" not in srv.log(), srv.log()
    finally:
        srv.stop()


def _messages(ws: object, n: int) -> list[dict]:
    return [json.loads(ws.recv(timeout=30)) for _ in range(n)]  # type: ignore[attr-defined]


def test_a_stream_message_nested_too_deep_is_a_bad_message_and_the_stream_goes_on(server: ServiceServer) -> None:
    """json.loads raised RecursionError, which the stream's parser did not catch (it caught ValueError): the
    stream ended with ``internal_error`` (close 1011) and a traceback in the server log, losing its state."""
    url = server.url.replace("http://", "ws://") + "/v1/stream"
    with connect(url, proxy=None, max_size=None, compression=None) as ws:
        ws.send(json.dumps({"type": "start"}))
        (ready,) = _messages(ws, 1)
        assert ready["type"] == "ready", ready
        ws.send(DEEP)
        (error,) = _messages(ws, 1)
        assert error["type"] == "error" and error["code"] == "bad_message", error
        assert "must be a JSON object" in error["message"], error
        ws.send(json.dumps({"type": "end"}))
        (end,) = _messages(ws, 1)
        assert end == {"type": "end", "frames": 0, "errors": 1}, end
    assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200


def _raw(server: ServiceServer, request: bytes) -> tuple[bytes, bytes]:
    """Send ``request`` on a fresh connection; the response's head and body (read until the server closes)."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as s:
        s.sendall(request)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return head, body


BODY = b'--B\r\nContent-Disposition: form-data; name="file"; filename="a.mp4"\r\n\r\nxyz\r\n--B--\r\n'


@pytest.mark.parametrize(
    "framing",
    [
        b"Content-Length: 99999999999999999999999999\r\n",
        b"Content-Length: -1\r\n",
        b"Content-Length: 12abc\r\n",
        b"Content-Length: 5\r\nTransfer-Encoding: chunked\r\n",
    ],
    ids=["past-any-size", "negative", "not-a-number", "length-and-chunked"],
)
def test_http_framing_h11_refuses_is_a_json_400(server: ServiceServer, framing: bytes) -> None:
    """uvicorn answered these with a text/plain "Invalid HTTP request received.", the one error of the service
    that was not its JSON body."""
    request = b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=B\r\n"
    head, body = _raw(server, request + framing + b"\r\n" + BODY)
    assert head.startswith(b"HTTP/1.1 400 "), head
    assert b"content-type: application/json" in head.lower(), head
    error = json.loads(body)
    assert error["status"] == 400 and error["code"] == "bad_request" and "malformed HTTP request" in error["message"]
    assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200
    assert not list((server.data_dir / "uploads").iterdir())

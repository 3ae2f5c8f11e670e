"""Slow request headers (slowloris) cannot hold a connection: real sockets against a real ``colonlight serve``.

Before, uvicorn gave a client sending its headers a byte at a time, or sending nothing after connecting, as long
as it liked: each held a connection and a file descriptor forever. Now the headers must be complete within
``COLONLIGHT_HEADER_TIMEOUT_SECONDS`` (default 10 s): a partial request gets a JSON 408 and is closed, a silent
connection is closed; beside them an honest client is served throughout, and so is a kept-alive connection's
next request sent in time.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from colonlight_service.settings import Settings

from ..service_server import ServiceServer

pytestmark = pytest.mark.timeout(180)

HEADER_S = 2.0


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("slowloris-server") / "data"
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_HEADER_TIMEOUT_SECONDS": str(HEADER_S),
    }
    with ServiceServer(data, env) as srv:
        yield srv


def test_default_header_timeout_is_ten_seconds() -> None:
    assert Settings().header_timeout_seconds == 10.0


def read_all(sock: socket.socket, timeout: float) -> tuple[bytes, float]:
    """Everything the server sends until it closes ``sock``, and the seconds that took."""
    t0 = time.monotonic()
    sock.settimeout(timeout)
    data = b""
    while chunk := sock.recv(65536):
        data += chunk
    return data, time.monotonic() - t0


def content_length(response: bytes) -> int:
    for line in response.partition(b"\r\n\r\n")[0].split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return int(value)
    return 0


class Dribble(threading.Thread):
    """A slowloris client: a request line and headers, one header line every ``every`` seconds, never the end."""

    def __init__(self, server: ServiceServer, every: float = 0.5) -> None:
        super().__init__(daemon=True)
        self.sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
        self.every = every
        self.closed_after: float | None = None
        self.received = b""

    def run(self) -> None:
        t0 = time.monotonic()
        try:
            self.sock.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            for i in range(200):
                time.sleep(self.every)
                self.sock.sendall(f"X-Slow-{i}: {'a' * 10}\r\n".encode())
        except OSError:  # the server closed the connection: what this client is for
            pass
        self.sock.settimeout(5)
        try:
            while chunk := self.sock.recv(65536):
                self.received += chunk
        except OSError:
            pass
        self.closed_after = time.monotonic() - t0
        self.sock.close()


def test_slow_headers_get_408_and_are_closed_beside_an_honest_client(server: ServiceServer) -> None:
    slow = [Dribble(server) for _ in range(6)]
    for client in slow:
        client.start()
    with httpx.Client(base_url=server.url, timeout=30) as honest:
        t_end = time.monotonic() + HEADER_S * 1.5
        while time.monotonic() < t_end:  # served throughout, while the slow clients hold their connections
            assert honest.get("/healthz").status_code == 200
            assert honest.get("/readyz").status_code == 200
            time.sleep(0.2)
    for client in slow:
        client.join(timeout=60)
        assert not client.is_alive(), "a slow client was never cut off"
        assert client.closed_after is not None and client.closed_after < HEADER_S + 30
        head, _, body = client.received.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 408"), client.received[:200]
        error = json.loads(body)
        assert error["status"] == 408 and error["code"] == "header_timeout"
        assert "COLONLIGHT_HEADER_TIMEOUT_SECONDS" in error["message"]


def test_a_silent_connection_is_closed(server: ServiceServer) -> None:
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
    data, waited = read_all(sock, timeout=HEADER_S + 30)
    sock.close()
    assert data == b"" and waited >= HEADER_S * 0.9  # closed without a word, not before the deadline


def test_headers_sent_slowly_but_in_time_are_served(server: ServiceServer) -> None:
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
    for part in (b"GET /healthz HTTP/1.1\r\n", b"Host: 127.0.0.1\r\n", b"Connection: close\r\n", b"\r\n"):
        sock.sendall(part)
        time.sleep(HEADER_S / 8)
    data, _ = read_all(sock, timeout=30)
    sock.close()
    assert data.startswith(b"HTTP/1.1 200"), data[:200]


def test_a_kept_alive_connection_gets_the_deadline_for_its_next_request(server: ServiceServer) -> None:
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
    sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    sock.settimeout(30)
    first = b""
    while b"\r\n\r\n" not in first or len(first.partition(b"\r\n\r\n")[2]) < content_length(first):
        first += sock.recv(65536)  # the whole first response (its head and body may come apart)
    assert first.startswith(b"HTTP/1.1 200"), first[:200]
    t0 = time.monotonic()
    sock.sendall(b"GET /healthz HTTP/1.1\r\n")  # the second request's headers start, and never end
    while time.monotonic() - t0 < HEADER_S + 30:
        time.sleep(0.4)
        try:
            sock.sendall(b"X-Slow: a\r\n")
        except OSError:
            break
    data, _ = read_all(sock, timeout=10)
    sock.close()
    assert data.startswith(b"HTTP/1.1 408"), data[:200]
    assert time.monotonic() - t0 < HEADER_S + 30

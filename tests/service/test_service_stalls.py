"""Stalled uploads cannot starve the service: real raw sockets that send headers and 150 bytes, then nothing.

They hold upload places (COLONLIGHT_MAX_UPLOADS), never places in the job queue: beside them an honest client's
job is accepted and done and /readyz stays ready; once every upload place is taken the next upload is told 503 at
once; after COLONLIGHT_UPLOAD_IDLE_SECONDS without progress each stalled upload gets 408 and its partial file is
gone; so does one that only trickles (under COLONLIGHT_UPLOAD_MIN_BYTES_PER_S). A slow upload that keeps making
progress is not cut off.
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

from ..media import make_clip, needs_ffmpeg
from ..service_server import ServiceServer
from .test_service import assert_json_error, leftovers, wait_done

pytestmark = [needs_ffmpeg, pytest.mark.timeout(180)]

IDLE_S = 3.0
MIN_RATE = 256  # bytes a second: at least 768 bytes in every 3 s
MAX_UPLOADS = 6
BOUNDARY = "stall-boundary"


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("stalls") / "honest.mp4", n_frames=20, fps=25)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("stalls-server") / "data"
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_QUEUE_SIZE": "1",
        "COLONLIGHT_MAX_UPLOADS": str(MAX_UPLOADS),
        "COLONLIGHT_UPLOAD_IDLE_SECONDS": str(IDLE_S),
        "COLONLIGHT_UPLOAD_MIN_BYTES_PER_S": str(MIN_RATE),
    }
    with ServiceServer(data, env) as srv:
        yield srv


def multipart_head(filename: str) -> bytes:
    return (
        f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="file"; filename="{filename}"\r\n'
        "Content-Type: video/mp4\r\n\r\n"
    ).encode()


def stalled_upload(server: ServiceServer, declared: int = 1_000_000) -> socket.socket:
    """A raw socket that sends the request headers and 150 bytes of a body announced as ``declared`` bytes."""
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
    head = multipart_head("stall.mp4")
    sock.sendall(
        f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\n"
        f"Content-Length: {declared}\r\n\r\n".encode()
        + head
        + b"\0" * (150 - len(head))
    )
    return sock


def read_response(sock: socket.socket, timeout: float) -> tuple[int, dict, float]:
    """(status, JSON body, seconds waited) of the one response on ``sock``, read until the server closes it."""
    t0 = time.monotonic()
    sock.settimeout(timeout)
    data = b""
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except ConnectionResetError:  # closed with bytes of ours unread: what it sent before is what counts
        assert data, "the connection was reset before any answer"
    head, _, body = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    return status, json.loads(body), time.monotonic() - t0


def readiness(c: httpx.Client) -> tuple[int, dict]:
    r = c.get("/readyz")
    return r.status_code, r.json()


def wait_partials(server: ServiceServer, n: int, timeout: float = 10) -> None:
    """Until ``n`` partial upload files are on disk (each stalled upload has begun its file part)."""
    deadline = time.monotonic() + timeout
    while len(leftovers(server)) != n:
        assert time.monotonic() < deadline, f"expected {n} partial uploads, found {leftovers(server)}"
        time.sleep(0.05)


def test_stalled_uploads_do_not_starve_honest_clients(server: ServiceServer, clip: Path) -> None:
    with httpx.Client(base_url=server.url, timeout=60) as c:
        stalled = [stalled_upload(server) for _ in range(4)]
        try:
            wait_partials(server, 4)  # their partial files are on disk while they stall
            code, ready = readiness(c)
            assert code == 200 and ready["status"] == "ready", ready  # before the fix: 503 busy
            assert ready["queue"]["admitted"] == 0 and ready["queue"]["uploads"] == 4, ready

            honest = c.post("/v1/jobs", files={"file": (clip.name, clip.read_bytes(), "video/mp4")})
            assert honest.status_code == 202, honest.text  # before the fix: 503 queue_full for 60+ s

            stalled += [stalled_upload(server) for _ in range(MAX_UPLOADS - 4)]
            wait_partials(server, MAX_UPLOADS)
            t0 = time.monotonic()
            refused = c.post("/v1/jobs", files={"file": (clip.name, clip.read_bytes(), "video/mp4")})
            assert time.monotonic() - t0 < IDLE_S  # told at once, not after the stalled ones time out
            body = assert_json_error(refused, 503)
            assert body["code"] == "too_many_uploads" and refused.headers["retry-after"]
            assert readiness(c)[0] == 200  # the job queue itself is not full

            for sock in stalled:  # each stalled body is answered 408 once it has made no progress for IDLE_S
                status, body, waited = read_response(sock, timeout=IDLE_S + 20)
                assert status == 408 and body["code"] == "request_timeout" and "no progress" in body["message"]
                assert waited < IDLE_S + 15
        finally:
            for sock in stalled:
                sock.close()
        assert leftovers(server) == []  # partial files removed
        assert readiness(c)[1]["queue"]["uploads"] == 0
        assert wait_done(c, honest.headers["location"], timeout=60)["status"] == "succeeded"
        again = c.post("/v1/jobs", files={"file": (clip.name, clip.read_bytes(), "video/mp4")})
        assert again.status_code == 202, again.text
        assert wait_done(c, again.headers["location"], timeout=60)["status"] == "succeeded"
        metrics = c.get("/metrics").text
        assert f'colonlight_requests_rejected_total{{reason="stalled"}} {float(MAX_UPLOADS)}' in metrics
        assert 'colonlight_requests_rejected_total{reason="too_many_uploads"} 1.0' in metrics


def test_slow_upload_that_keeps_progressing_is_not_cut_off(server: ServiceServer, clip: Path) -> None:
    """Sent in pieces IDLE_S / 3 apart, for longer than IDLE_S in all: accepted (the limit is on stalls, not time)."""
    body = multipart_head(clip.name) + clip.read_bytes() + f"\r\n--{BOUNDARY}--\r\n".encode()
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
    try:
        sock.sendall(
            f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode()
        )
        pieces = 6
        step = -(-len(body) // pieces)
        t0 = time.monotonic()
        for i in range(pieces):
            time.sleep(IDLE_S / 3)
            sock.sendall(body[i * step : (i + 1) * step])
        assert time.monotonic() - t0 > IDLE_S
        status, job, _ = read_response(sock, timeout=30)
    finally:
        sock.close()
    assert status == 202, job
    with httpx.Client(base_url=server.url, timeout=60) as c:
        assert wait_done(c, f"/v1/jobs/{job['id']}", timeout=60)["status"] == "succeeded"
    assert leftovers(server) == []


def test_trickling_upload_is_cut_off(server: ServiceServer) -> None:
    """10 bytes every half second (20 B/s, under MIN_RATE): answered 408 while it is still sending, file removed."""
    sock = stalled_upload(server)
    stop = threading.Event()

    def trickle() -> None:
        while not stop.wait(0.5):
            try:
                sock.sendall(b"\0" * 10)
            except OSError:  # answered and closed by the server
                return

    sender = threading.Thread(target=trickle)
    sender.start()
    try:
        status, body, waited = read_response(sock, timeout=4 * IDLE_S + 10)
    finally:
        stop.set()
        sender.join()
        sock.close()
    assert status == 408 and body["code"] == "request_timeout", body
    assert IDLE_S - 0.5 < waited < 2 * IDLE_S + 10
    time.sleep(0.2)
    assert leftovers(server) == []

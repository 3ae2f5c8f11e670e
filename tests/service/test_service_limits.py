"""Admission limits and authentication of the service: a full queue answers 503 + Retry-After, and with
COLONLIGHT_API_KEY set every route but /healthz and /readyz needs the key (X-API-Key or Bearer)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from ..media import make_clip, needs_ffmpeg
from ..service_server import ServiceServer
from .test_service import assert_json_error, leftovers, wait_done

pytestmark = [needs_ffmpeg, pytest.mark.timeout(150)]

KEY = "s3cret-key-for-tests"
AUTH = {"X-API-Key": KEY}


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("limits") / "c.mp4", n_frames=50, fps=25)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("limits-server") / "data"
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_QUEUE_SIZE": "1",
        "COLONLIGHT_API_KEY": KEY,
        "COLONLIGHT_RETRY_AFTER_SECONDS": "7",
    }
    with ServiceServer(data, env) as srv:
        yield srv


def test_queue_full_is_503_with_retry_after(server: ServiceServer, clip: Path) -> None:
    """Six clients at once against 1 worker + a queue of 1: two are admitted, the rest are told to come back."""
    payload = clip.read_bytes()
    results: list[httpx.Response] = []
    barrier = threading.Barrier(6)

    def client() -> None:
        with httpx.Client(base_url=server.url, timeout=60, headers=AUTH) as c:
            barrier.wait()
            results.append(c.post("/v1/jobs", files={"file": ("c.mp4", payload)}))

    threads = [threading.Thread(target=client) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    codes = sorted(r.status_code for r in results)
    assert set(codes) <= {202, 503}, codes
    accepted = [r for r in results if r.status_code == 202]
    refused = [r for r in results if r.status_code == 503]
    assert len(accepted) >= 2 and refused, codes  # a job takes seconds: the burst overflows capacity 2
    for r in refused:
        body = assert_json_error(r, 503)
        assert body["code"] == "queue_full" and r.headers["retry-after"] == "7"
    with httpx.Client(base_url=server.url, timeout=60, headers=AUTH) as c:
        ready = c.get("/readyz")
        if ready.status_code == 503:  # while both places are taken, readiness says so
            assert ready.json()["status"] == "busy"
        for r in accepted:
            assert wait_done(c, r.headers["location"], timeout=90)["status"] == "succeeded"
        assert c.get("/readyz").status_code == 200
        metrics = c.get("/metrics").text
        assert f'colonlight_requests_rejected_total{{reason="queue_full"}} {float(len(refused))}' in metrics
    assert leftovers(server) == []


PROTECTED = [
    ("POST", "/v1/jobs"),
    ("GET", "/v1/jobs/AAAAAAAAAAAAAAAAAAAAAA"),
    ("GET", "/v1/jobs/AAAAAAAAAAAAAAAAAAAAAA/video"),
    ("GET", "/v1/jobs/AAAAAAAAAAAAAAAAAAAAAA/gammas"),
    ("GET", "/v1/jobs/AAAAAAAAAAAAAAAAAAAAAA/frames.zip"),
    ("DELETE", "/v1/jobs/AAAAAAAAAAAAAAAAAAAAAA"),
    ("POST", "/v1/enhance"),
    ("GET", "/metrics"),
    ("GET", "/v1/info"),
    ("GET", "/openapi.json"),
]


@pytest.mark.parametrize(("method", "path"), PROTECTED)
def test_routes_need_the_key(server: ServiceServer, method: str, path: str) -> None:
    for headers in ({}, {"X-API-Key": "wrong"}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Basic {KEY}"}):
        r = httpx.request(method, server.url + path, headers=headers, timeout=30)
        body = assert_json_error(r, 401)
        assert "X-API-Key" in body["message"] and r.headers["www-authenticate"] == "Bearer"


def test_health_needs_no_key_and_both_key_forms_work(server: ServiceServer, clip: Path) -> None:
    assert httpx.get(server.url + "/healthz").status_code == 200
    assert httpx.get(server.url + "/readyz").status_code in (200, 503)
    assert httpx.get(server.url + "/").status_code == 200  # the page shell holds no data; it asks for the key
    assert httpx.get(server.url + "/v1/info", headers=AUTH).json()["auth_required"] is True
    assert httpx.get(server.url + "/metrics", headers={"Authorization": f"Bearer {KEY}"}).status_code == 200
    with httpx.Client(base_url=server.url, timeout=60, headers={"Authorization": f"Bearer {KEY}"}) as c:
        deadline = time.monotonic() + 60
        while (r := c.post("/v1/jobs", files={"file": ("c.mp4", clip.read_bytes())})).status_code == 503:
            assert time.monotonic() < deadline
            time.sleep(0.5)
        assert r.status_code == 202, r.text
        done = wait_done(c, r.headers["location"], timeout=90)
        assert done["status"] == "succeeded"
        assert c.get(done["links"]["video"]).status_code == 200
        assert httpx.get(server.url + done["links"]["video"]).status_code == 401
        assert c.delete(done["links"]["self"]).status_code == 204


def test_unauthenticated_upload_is_refused_before_it_is_read(server: ServiceServer) -> None:
    sent = [0]

    def body() -> Iterator[bytes]:
        yield b'--b\r\nContent-Disposition: form-data; name="file"; filename="x.mp4"\r\n\r\n'
        for _ in range(200):
            sent[0] += 1
            yield b"\0" * 65536
        yield b"\r\n--b--\r\n"

    r = httpx.post(server.url + "/v1/jobs", content=body(), headers={"Content-Type": "multipart/form-data; boundary=b"})
    assert_json_error(r, 401)
    assert sent[0] < 200, "the server read the whole body of a request it refused"
    assert leftovers(server) == []

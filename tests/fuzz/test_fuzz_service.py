"""Fuzz the upload routes of a real ``colonlight serve`` (uvicorn on loopback) with damaged real clips.

Each case uploads one damaged clip (see :mod:`corrupt`) to ``POST /v1/jobs`` (then polls the job) or to
``POST /v1/enhance``. Properties: an answer within the time bound, never a 5xx; a 4xx is the JSON error body with
a one-line message; a job ends ``succeeded`` (its gammas.json, video and frames whole and consistent) or
``failed`` with a one-line reason that names no server path; afterwards no upload, sync work or temporary is left
in the data folder, the server's log holds no traceback, and its peak RSS stays within the written bound.
``COLONLIGHT_FUZZ_EXAMPLES=500`` runs the long version.
"""

from __future__ import annotations

import base64
import io
import json
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import av
import httpx
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from colonlight.pipeline import peak_rss_bound

from ..service_server import ServiceServer
from .checks import BUG_MARKS, Hang, no_bug_marks, temporaries
from .corrupt import FAMILIES, Case, fuzz_settings

pytestmark = pytest.mark.timeout(900)

MAX_PIXELS = 256 * 256  # the seeds are 32x32; as in the CLI fuzz, the cap makes the memory bound hold for any damage
CASE_SECONDS = 60.0
ROUTES = ("/v1/jobs", "/v1/enhance")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("fuzz-service") / "data"
    env = {
        "COLONLIGHT_METHOD": "gamma",
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_QUEUE_SIZE": "2",
        "COLONLIGHT_MAX_UPLOAD_MB": "1",
        "COLONLIGHT_SYNC_MAX_SECONDS": "5",
        "COLONLIGHT_MAX_PIXELS": str(MAX_PIXELS),
    }
    with ServiceServer(data, env) as srv:
        yield srv
        log = srv.log()
    for mark in BUG_MARKS:
        assert mark not in log, log


@pytest.fixture(scope="module")
def client(server: ServiceServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server.url, timeout=CASE_SECONDS) as c:
        yield c


def one_line(text: str, server: ServiceServer, where: str) -> None:
    assert text and "\n" not in text, f"{where}: not one line: {text!r}"
    no_bug_marks(text, where)
    assert str(server.data_dir) not in text, f"{where} reveals a server path: {text!r}"


def decoded_frames(data: bytes) -> int:
    with av.open(io.BytesIO(data)) as c:
        return sum(1 for _ in c.decode(video=0))


def check_error(resp: httpx.Response, server: ServiceServer) -> None:
    assert resp.status_code < 500, f"{resp.status_code}: {resp.text[:2000]}"
    assert resp.headers["content-type"].startswith("application/json"), resp.text[:500]
    body = resp.json()
    assert body["status"] == resp.status_code and body["code"], body
    one_line(body["message"], server, f"the {resp.status_code} message")


def wait_finished(client: httpx.Client, location: str) -> dict:
    deadline = time.monotonic() + CASE_SECONDS
    while time.monotonic() < deadline:
        r = client.get(location)
        assert r.status_code == 200, r.text
        job = r.json()
        if job["status"] in ("succeeded", "failed"):
            return job
        time.sleep(0.05)
    raise Hang(f"job {location} did not finish within {CASE_SECONDS:g} s: {job}")


def check_job(client: httpx.Client, server: ServiceServer, location: str, frames: bool) -> None:
    job = wait_finished(client, location)
    event(f"job {job['status']}")
    links = job["links"]
    if job["status"] == "failed":
        one_line(job["error"], server, "the job's error")
        assert client.get(links["gammas"]).status_code == 409
    else:
        r = client.get(links["gammas"])
        assert r.status_code == 200, r.text
        gammas = r.json()
        n = gammas["frame_count"]
        assert n >= 2 and len(gammas["frames"]) == n and job["frames_done"] == n, (job, n)
        assert str(server.data_dir) not in json.dumps(gammas), gammas["source"]
        r = client.get(links["video"])
        assert r.status_code == 200 and decoded_frames(r.content) == n
        r = client.get(links["frames"])
        if frames:
            assert r.status_code == 200, r.text
            with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
                assert zf.testzip() is None and len(zf.namelist()) == n
        else:
            assert r.status_code == 404
    assert client.delete(links["self"]).status_code == 204


def check_left_behind(server: ServiceServer) -> None:
    data = server.data_dir
    assert not list((data / "uploads").iterdir()), list((data / "uploads").iterdir())
    assert not list((data / "sync").iterdir()), list((data / "sync").iterdir())
    assert not temporaries(data), temporaries(data)
    assert not list((data / "jobs").iterdir()), list((data / "jobs").iterdir())  # every job was deleted


def check_case(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    log_before = len(server.log_path.read_bytes())
    with case_dir() as d:
        clip = case.write(seeds, d)
        try:
            resp = client.post(
                route,
                files={"file": (clip.name, clip.read_bytes(), "video/mp4")},
                data={"method": "gamma", "frames": str(frames).lower()},
            )
        except httpx.TimeoutException:
            raise Hang(f"POST {route} of {case} had no answer within {CASE_SECONDS:g} s") from None
        event(f"{route}: {resp.status_code}")
        if resp.status_code >= 400:
            event(f"{route}: {resp.status_code} {resp.json().get('code')}")
            check_error(resp, server)
        elif route == "/v1/jobs":
            assert resp.status_code == 202, resp.text
            check_job(client, server, resp.headers["location"], frames)
        else:
            assert resp.status_code == 200, resp.text
            body = resp.json()
            n = body["gammas"]["frame_count"]
            assert n >= 2 and decoded_frames(base64.b64decode(body["video"]["data"])) == n
    assert server.proc is not None and server.proc.poll() is None, "the server died"
    log = server.log_path.read_bytes()[log_before:].decode(errors="replace")
    no_bug_marks(log, "the server's log")
    check_left_behind(server)
    peak, bound = server.peak_rss_bytes(), peak_rss_bound(256, 256, workers=1, video=True)
    assert peak is not None and peak <= bound, f"server peak RSS {peak / 2**20:.0f} MiB > {bound / 2**20:.0f} MiB"


routes = st.sampled_from(ROUTES)


@fuzz_settings(8)
@given(case=FAMILIES["flips"], route=routes, frames=st.booleans())
def test_flipped_bytes(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    check_case(case, route, frames, seeds, server, client, case_dir)


@fuzz_settings(8)
@given(case=FAMILIES["cuts"], route=routes, frames=st.booleans())
def test_truncated_at_any_offset(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    check_case(case, route, frames, seeds, server, client, case_dir)


@fuzz_settings(8)
@given(case=FAMILIES["chunks"], route=routes, frames=st.booleans())
def test_duplicated_and_dropped_chunks(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    check_case(case, route, frames, seeds, server, client, case_dir)


@fuzz_settings(8)
@given(case=FAMILIES["packets"], route=routes, frames=st.booleans())
def test_duplicated_and_dropped_packets(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    check_case(case, route, frames, seeds, server, client, case_dir)


@fuzz_settings(8)
@given(case=FAMILIES["foreign"], route=routes, frames=st.booleans())
def test_foreign_headers_and_wrong_suffixes(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    check_case(case, route, frames, seeds, server, client, case_dir)


@fuzz_settings(8)
@given(case=FAMILIES["mixed"], route=routes, frames=st.booleans())
def test_mixed_damage(
    case: Case,
    route: str,
    frames: bool,
    seeds: dict[str, Path],
    server: ServiceServer,
    client: httpx.Client,
    case_dir: Callable[[], Iterator[Path]],
) -> None:
    check_case(case, route, frames, seeds, server, client, case_dir)

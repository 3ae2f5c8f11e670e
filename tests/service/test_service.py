"""The HTTP service against a real ``colonlight serve`` (uvicorn subprocess on a loopback port), driven by httpx.

One server for this module (rnn with test weights, 2 workers); the limits, restart, browser and fuzz tests start
their own servers with other settings.
"""

from __future__ import annotations

import base64
import io
import json
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import av
import httpx
import pytest
from colonlight_cli.main import app as cli_app
from colonlight_service.uploads import MAX_MASK_BYTES
from typer.testing import CliRunner

from colonlight.limits import max_pixels_setting

from ..media import make_clip, needs_ffmpeg, read_index, text_file, truncated_copy, zero_byte_file
from ..service_server import ServiceServer

pytestmark = [needs_ffmpeg, pytest.mark.timeout(120)]

MAX_UPLOAD_MB = 2


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("service-clips")
    return {
        "mp4": make_clip(d / "p7.mp4", n_frames=50, fps=25),  # 2 s: 36 frames at 18 fps
        "avi": make_clip(d / "scope ü.avi", n_frames=30, fps=30, codec_args=("-c:v", "mpeg4", "-q:v", "3")),
        "long": make_clip(d / "long.mp4", n_frames=125, fps=25),  # 5 s
        "text": text_file(d / "letter.mp4"),
        "empty": zero_byte_file(d / "empty.mp4"),
    }


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("service") / "data"
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "2",
        "COLONLIGHT_QUEUE_SIZE": "8",
        "COLONLIGHT_MAX_UPLOAD_MB": str(MAX_UPLOAD_MB),
        "COLONLIGHT_SYNC_MAX_SECONDS": "3",
    }
    with ServiceServer(data, env) as srv:
        yield srv


def submit(client: httpx.Client, path: Path, **fields: str) -> httpx.Response:
    return client.post("/v1/jobs", files={"file": (path.name, path.read_bytes(), "video/mp4")}, data=fields)


def wait_done(client: httpx.Client, location: str, timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(location).json()
        if job["status"] in ("succeeded", "failed"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {location} did not finish in {timeout} s: {job}")


def decoded_frames(data: bytes) -> tuple[int, str, str]:
    with av.open(io.BytesIO(data)) as c:
        s = c.streams.video[0]
        n = sum(1 for _ in c.decode(video=0))
        return n, s.codec_context.name, s.codec_context.pix_fmt


def assert_json_error(resp: httpx.Response, status: int) -> dict:
    assert resp.status_code == status, resp.text
    assert resp.headers["content-type"].startswith("application/json")
    body = resp.json()
    assert body["status"] == status and body["code"] and body["message"]
    return body


def leftovers(server: ServiceServer) -> list[str]:
    return sorted(p.name for p in (server.data_dir / "uploads").iterdir())


# ----------------------------------------------------------------------------------------------------------


def test_health_and_readiness(client: httpx.Client) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200
    body = ready.json()
    assert body["ready"] and body["status"] == "ready"
    assert body["model"]["method"] == "rnn" and body["model"]["model"]["name"] == "random-test"  # loaded at start-up
    assert body["workers"]["total"] == 2 and body["queue"]["capacity"] == 10


def test_job_round_trip(client: httpx.Client, clips: dict[str, Path], server: ServiceServer) -> None:
    r = submit(client, clips["mp4"])
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}" == job["links"]["self"]
    assert job["status"] in ("queued", "running") and len(job["id"]) == 22
    assert job["options"]["method"] == "rnn" and job["options"]["fps"] == 18.0
    done = wait_done(client, r.headers["location"])
    assert done["status"] == "succeeded", done
    assert done["frames_done"] == done["frames_total"] == 36 and done["progress"] == 1.0
    assert done["started_at"] and done["finished_at"] and done["expires_at"] and done["attempts"] == 1

    video = client.get(done["links"]["video"])
    assert video.status_code == 200 and video.headers["content-type"] == "video/mp4"
    assert decoded_frames(video.content) == (36, "h264", "yuv420p")
    part = client.get(done["links"]["video"], headers={"Range": "bytes=100-199"})  # a browser seeking
    assert part.status_code == 206 and part.content == video.content[100:200]
    assert part.headers["content-range"] == f"bytes 100-199/{len(video.content)}"
    bad_range = client.get(done["links"]["video"], headers={"Range": f"bytes={len(video.content) + 10}-"})
    assert_json_error(bad_range, 416)

    gammas = client.get(done["links"]["gammas"]).json()
    assert gammas["frame_count"] == 36 and gammas["clip"] == "p7" and gammas["model"]["name"] == "random-test"
    assert [f["index"] for f in gammas["frames"]] == list(range(36))
    assert gammas["frames"][0]["gamma"] == 1.0 and all(0.125 <= f["gamma"] <= 4 for f in gammas["frames"])

    zipped = client.get(done["links"]["frames"])
    assert zipped.status_code == 200
    with zipfile.ZipFile(io.BytesIO(zipped.content)) as zf:
        assert zf.namelist() == [f"frames/{i:06d}.png" for i in range(36)]

    job_dir = server.data_dir / "jobs" / job["id"]
    assert job_dir.is_dir() and not list(job_dir.glob("input*"))  # the upload is dropped once the job ends
    assert client.delete(done["links"]["self"]).status_code == 204
    assert_json_error(client.get(done["links"]["self"]), 404)
    assert_json_error(client.get(done["links"]["video"]), 404)
    assert_json_error(client.delete(done["links"]["self"]), 404)
    assert not job_dir.exists()


def test_same_gammas_as_the_cli(
    client: httpx.Client, clips: dict[str, Path], tmp_path: Path, random_weights: Path
) -> None:
    """The service runs the CLI's pipeline: identical gammas.json frames and settings for the same clip."""
    r = submit(client, clips["mp4"], fps="18")
    done = wait_done(client, r.headers["location"])
    served = client.get(done["links"]["gammas"]).json()
    result = CliRunner().invoke(
        cli_app,
        [
            "enhance",
            str(clips["mp4"]),
            "-o",
            str(tmp_path),
            "--weights",
            str(random_weights),
            "--device",
            "cpu",
            "--video",
            "-q",
        ],
    )
    assert result.exit_code == 0, result.output
    local = json.loads((tmp_path / "p7" / "gammas.json").read_text())
    assert served["frames"] == local["frames"]
    assert served["settings"] == local["settings"]
    assert set(served) == set(local)


def test_every_frame_jpeg_from_avi_with_method_none(client: httpx.Client, clips: dict[str, Path]) -> None:
    r = submit(client, clips["avi"], fps="0", method="none", format="jpg", quality="90")
    assert r.status_code == 202, r.text
    done = wait_done(client, r.headers["location"])
    assert done["status"] == "succeeded" and done["frames_done"] == 30
    assert done["filename"] == "scope ü.avi"
    video = client.get(done["links"]["video"]).content
    assert decoded_frames(video)[0] == 30
    with av.open(io.BytesIO(video)) as c:  # identity method: the source frames, in order
        indices = [read_index(f.to_ndarray(format="rgb24")) for f in c.decode(video=0)]
    assert indices == list(range(30))
    with zipfile.ZipFile(io.BytesIO(client.get(done["links"]["frames"]).content)) as zf:
        assert len(zf.namelist()) == 30 and zf.namelist()[0].endswith(".jpg")
    gammas = client.get(done["links"]["gammas"]).json()
    assert gammas["method"] == "none" and gammas["model"] is None


def test_video_only_job_has_no_frames_zip(client: httpx.Client, clips: dict[str, Path]) -> None:
    done = wait_done(
        client, submit(client, clips["mp4"], frames="false", method="gamma", gamma="0.5").headers["location"]
    )
    assert done["status"] == "succeeded"
    assert client.get(done["links"]["gammas"]).json()["frames"][3]["gamma"] == 0.5
    assert_json_error(client.get(done["links"]["frames"]), 404)


def test_results_of_an_unfinished_job_are_409_and_delete_stops_it(
    client: httpx.Client, clips: dict[str, Path], server: ServiceServer
) -> None:
    r = submit(client, clips["long"], fps="0", model_size="full")
    loc = r.headers["location"]
    body = client.get(loc + "/video")
    if body.status_code == 409:  # normally still queued or running
        assert "poll" in assert_json_error(body, 409)["message"]
    deadline = time.monotonic() + 30
    while client.get(loc).json()["frames_done"] == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    latencies = []
    for _ in range(10):  # processing runs in worker threads: the event loop keeps answering at once
        t0 = time.perf_counter()
        assert client.get("/healthz").status_code == 200
        latencies.append(time.perf_counter() - t0)
        time.sleep(0.02)
    assert client.get(loc).json()["status"] == "running" and max(latencies) < 0.5, latencies
    assert client.delete(loc).status_code == 204  # deleting a running job stops it at its next frame
    assert_json_error(client.get(loc), 404)
    job_dir = server.data_dir / "jobs" / r.json()["id"]
    while job_dir.exists():  # the worker removes the folder once the clip has stopped
        assert time.monotonic() < deadline, "a deleted running job left its folder"
        time.sleep(0.05)


@pytest.mark.parametrize("kind", ["text", "empty", "random", "truncated"])
def test_non_video_upload_is_415(
    client: httpx.Client, clips: dict[str, Path], server: ServiceServer, kind: str, tmp_path: Path
) -> None:
    if kind == "random":
        path = tmp_path / "noise.mp4"
        path.write_bytes(bytes(range(256)) * 200)
    elif kind == "truncated":
        path = truncated_copy(clips["mp4"], tmp_path / "cut.mp4", keep=0.3)
    else:
        path = clips[kind]
    before = set((server.data_dir / "jobs").iterdir())
    body = assert_json_error(submit(client, path), 415)
    assert path.name in body["message"] and str(server.data_dir) not in body["message"]  # no server paths leak
    assert leftovers(server) == [] and set((server.data_dir / "jobs").iterdir()) == before


def test_oversized_upload_is_413_and_leaves_nothing(client: httpx.Client, server: ServiceServer) -> None:
    big = b"\0" * (MAX_UPLOAD_MB * 1048576 + 4096)
    body = assert_json_error(client.post("/v1/jobs", files={"file": ("big.mp4", big)}), 413)  # Content-Length
    assert "MiB" in body["message"]
    assert leftovers(server) == []

    sent = [0]

    def stream() -> Iterator[bytes]:  # chunked, no Content-Length: the cap is enforced while reading
        boundary = b"--xyz"
        yield boundary + b'\r\nContent-Disposition: form-data; name="file"; filename="big.mp4"\r\n\r\n'
        for _ in range(400):  # 25 MiB if the server read it all
            sent[0] += 1
            yield b"\1" * 65536
        yield b"\r\n" + boundary + b"--\r\n"

    r = client.post("/v1/jobs", content=stream(), headers={"Content-Type": "multipart/form-data; boundary=xyz"})
    assert_json_error(r, 413)
    assert r.headers["connection"] == "close"  # the server stops reading instead of swallowing the rest
    assert sent[0] < 400, "the server read the whole oversized body before refusing it"
    time.sleep(0.2)
    assert leftovers(server) == []


@pytest.mark.parametrize(
    ("fields", "status", "needle"),
    [
        ({"fps": "-1"}, 422, "fps"),
        ({"fps": "fast"}, 422, "fps"),
        ({"method": "magic"}, 422, "unknown method"),
        ({"method": "none", "model_size": "64"}, 422, "model_size"),
        ({"model_size": "4"}, 422, "model_size"),
        ({"format": "gif"}, 422, "format"),
        ({"quality": "0"}, 422, "quality"),
        ({"content": "border"}, 422, "content"),
        ({"colour": "blue"}, 422, "colour"),
    ],
)
def test_bad_options_are_422(
    client: httpx.Client, clips: dict[str, Path], server: ServiceServer, fields: dict, status: int, needle: str
) -> None:
    body = assert_json_error(submit(client, clips["mp4"], **fields), status)
    assert needle in json.dumps(body)
    assert leftovers(server) == []


def test_malformed_requests_are_json_errors(client: httpx.Client) -> None:
    assert_json_error(client.post("/v1/jobs", content=b"raw bytes", headers={"Content-Type": "video/mp4"}), 415)
    assert_json_error(client.post("/v1/jobs", data={"fps": "18"}, files={"other": ("x", b"y")}), 422)
    assert_json_error(
        client.post(
            "/v1/jobs",
            content=b'--b\r\nContent-Disposition: form-data; name="file"\r\n\r\nab',
            headers={"Content-Type": "multipart/form-data; boundary=b"},
        ),
        400,
    )
    assert_json_error(client.post("/v1/jobs", content=b"x", headers={"Content-Type": "multipart/form-data"}), 400)
    assert_json_error(client.get("/v1/jobs/not-an-id"), 422)
    assert_json_error(client.get("/v1/jobs/AAAAAAAAAAAAAAAAAAAAAA"), 404)
    assert_json_error(client.get("/v1/nothing"), 404)
    assert_json_error(client.put("/v1/jobs"), 405)
    assert_json_error(client.get("/static/../jobs.sqlite3"), 404)


def test_sync_enhance(client: httpx.Client, clips: dict[str, Path], server: ServiceServer) -> None:
    r = client.post("/v1/enhance", files={"file": ("p7.mp4", clips["mp4"].read_bytes())}, data={"fps": "18"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["gammas"]["frame_count"] == 36 and body["gammas"]["model"]["name"] == "random-test"
    video = base64.b64decode(body["video"]["data"])
    assert len(video) == body["video"]["size_bytes"] and decoded_frames(video)[0] == 36
    too_long = assert_json_error(
        client.post("/v1/enhance", files={"file": ("long.mp4", clips["long"].read_bytes())}), 413
    )
    assert "/v1/jobs" in too_long["message"]
    assert_json_error(client.post("/v1/enhance", files={"file": ("x.mp4", clips["text"].read_bytes())}), 415)
    time.sleep(0.3)
    assert list((server.data_dir / "sync").iterdir()) == [] and leftovers(server) == []


def test_metrics(client: httpx.Client, clips: dict[str, Path]) -> None:
    wait_done(client, submit(client, clips["mp4"], method="none").headers["location"])
    text = client.get("/metrics").text
    assert client.get("/metrics").headers["content-type"].startswith("text/plain")
    values = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            values[name] = float(value)
    assert values['colonlight_jobs{status="succeeded"}'] >= 1
    assert values["colonlight_frames_processed_total"] >= 36
    assert values["colonlight_processing_seconds_count"] >= 1 and values["colonlight_processing_seconds_sum"] > 0
    assert "colonlight_queue_depth" in values and values["colonlight_workers"] == 2
    assert values['colonlight_requests_rejected_total{reason="not_video"}'] >= 1
    assert values["process_peak_resident_memory_bytes"] > 0


def test_openapi_schema_is_complete(client: httpx.Client) -> None:
    schema = client.get("/openapi.json").json()
    paths = schema["paths"]
    assert set(paths) >= {
        "/v1/jobs",
        "/v1/jobs/{job_id}",
        "/v1/jobs/{job_id}/video",
        "/v1/jobs/{job_id}/gammas",
        "/v1/jobs/{job_id}/frames.zip",
        "/v1/enhance",
        "/healthz",
        "/readyz",
        "/metrics",
    }
    for path, ops in paths.items():
        for method, op in ops.items():
            assert op.get("summary"), (method, path)
    post = paths["/v1/jobs"]["post"]
    form = post["requestBody"]["content"]["multipart/form-data"]
    assert form["schema"]["required"] == ["file"] and form["example"]
    assert {"fps", "method", "format", "model_size", "quality", "frames"} <= set(form["schema"]["properties"])
    assert {"202", "413", "415", "503"} <= set(post["responses"])
    assert "Location" in post["responses"]["202"]["headers"]
    comps = schema["components"]["schemas"]
    assert (
        comps["JobStatus"].get("examples")
        and comps["ErrorBody"].get("examples")
        and comps["EnhanceResult"].get("examples")
    )
    assert paths["/v1/jobs/{job_id}/video"]["get"]["responses"]["200"]["content"]["video/mp4"]


def test_web_page_is_served(client: httpx.Client) -> None:
    page = client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"] and 'id="drop"' in page.text
    assert client.get("/static/app.js").status_code == 200
    info = client.get("/v1/info").json()
    assert (
        "rnn" in info["methods"] and info["auth_required"] is False and info["limits"]["max_upload_mb"] == MAX_UPLOAD_MB
    )
    # the default method's worker setting (colonlight.network_threads): one thread for the small recurrent net
    assert info["limits"]["torch_threads"] == 1
    # what an upload may be, so a client can check before it sends: the mask part's cap and the frame pixel cap
    assert info["limits"]["max_content_mask_bytes"] == MAX_MASK_BYTES
    assert info["limits"]["max_pixels"] == max_pixels_setting()


def test_frames_total_at_submission_is_the_final_count(client: httpx.Client, tmp_path: Path) -> None:
    """A 3 s clip at 30 fps gives 54 frames at 18 fps: the estimate a job starts with (from the container's
    duration) is the count it ends with, not 55 turning into 54."""
    clip = make_clip(tmp_path / "three seconds.mp4", n_frames=90, fps=30)
    r = submit(client, clip)
    assert r.status_code == 202, r.text
    assert r.json()["frames_total"] == 54
    done = wait_done(client, r.headers["location"])
    assert done["status"] == "succeeded", done
    assert done["frames_done"] == done["frames_total"] == 54


def test_favicon_is_served(client: httpx.Client) -> None:
    r = client.get("/favicon.ico")
    assert r.status_code == 200 and r.headers["content-type"] == "image/x-icon"
    assert r.content[:4] == b"\x00\x00\x01\x00" and len(r.content) > 100  # an ICO header, not an error page
    assert '<link rel="icon" href="/favicon.ico">' in client.get("/").text

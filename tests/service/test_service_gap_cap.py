"""The gap cap in the service, against a real ``colonlight serve``: ``COLONLIGHT_MAX_GAP_FRAMES`` (the CLI's
variable, a service setting) bounds how many copies of one frame a timestamp gap may add. Past it a job ends
``failed`` with the cause in one line, its upload is removed at once and its results hold nothing half-written;
under the default cap the same clip succeeds with every repeat in ``enhanced.mp4``, as ``ffmpeg -vf fps=18``
repeats it (tests/engine/video/test_decode_gaps.py covers the engine and the CLI)."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import av
import httpx
import pytest
from colonlight_service.settings import Settings

from colonlight.limits import DEFAULT_MAX_GAP_FRAMES, MAX_GAP_FRAMES_ENV

from ..media import ffmpeg_fps_indices, make_vfr_clip, needs_ffmpeg, read_index
from ..service_server import ServiceServer
from .test_service import leftovers, wait_done

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

CAP = 60  # the 4 s gap below repeats frame 2 69 times at 18 fps


@pytest.fixture(scope="module")
def gap_clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_vfr_clip(tmp_path_factory.mktemp("gap-cap") / "gap4.mp4", [0.0, 0.05, 0.1, 4.0, 4.05])


def served(data: Path, weights: Path, **env: str) -> ServiceServer:
    return ServiceServer(data, {"COLONLIGHT_WEIGHTS": str(weights), "COLONLIGHT_WORKERS": "1", **env})


@pytest.fixture(scope="module")
def capped(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    with served(tmp_path_factory.mktemp("gap-capped") / "data", random_weights, **{MAX_GAP_FRAMES_ENV: str(CAP)}) as s:
        yield s


@pytest.fixture(scope="module")
def uncapped(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    with served(tmp_path_factory.mktemp("gap-default") / "data", random_weights) as s:
        yield s


def run_job(client: httpx.Client, clip: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Upload ``clip`` as a job with method ``none``: (the 202 answer, the job once it has ended)."""
    r = client.post("/v1/jobs", files={"file": (clip.name, clip.read_bytes(), "video/mp4")}, data={"method": "none"})
    assert r.status_code == 202, r.text
    job = wait_done(client, r.headers["location"], timeout=180)
    return r.json(), job


def test_the_cap_is_a_service_setting_read_from_the_cli_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(MAX_GAP_FRAMES_ENV, raising=False)
    assert Settings().max_gap_frames == DEFAULT_MAX_GAP_FRAMES
    monkeypatch.setenv(MAX_GAP_FRAMES_ENV, "60")
    assert Settings().max_gap_frames == 60
    monkeypatch.setenv(MAX_GAP_FRAMES_ENV, "0")
    with pytest.raises(ValueError, match="max_gap_frames"):
        Settings()


def test_a_gap_past_the_cap_fails_the_job_cleanly(capped: ServiceServer, gap_clip: Path) -> None:
    with httpx.Client(base_url=capped.url, timeout=120) as client:
        created, job = run_job(client, gap_clip)
        assert job["status"] == "failed", job
        error = job["error"]
        assert "\n" not in error and "Traceback" not in error, error
        assert "gap4.mp4" in error and "timestamp gap" in error and "69 times" in error, error
        assert f"cap of {CAP}" in error and MAX_GAP_FRAMES_ENV in error, error
        assert str(capped.data_dir) not in error
        job_dir = capped.data_dir / "jobs" / job["id"]
        assert not list(job_dir.glob("input*"))  # the upload went with the failure, not at the TTL
        assert leftovers(capped) == []
        written = [str(p.relative_to(job_dir)) for p in job_dir.rglob("*") if p.is_file() and "out" in p.parts]
        assert written == [], written  # the frames before the gap were removed with the job
        for link in created["links"].values():
            answer = client.get(link)
            assert answer.status_code < 500, (link, answer.status_code, answer.text)
        assert client.get(created["links"]["gammas"]).status_code in (404, 409, 410)
        assert client.get("/readyz").status_code == 200  # the server goes on


def test_the_same_gap_under_the_default_cap_streams_every_repeat(uncapped: ServiceServer, gap_clip: Path) -> None:
    expected = ffmpeg_fps_indices(gap_clip, 18)
    assert expected.count(2) == 70  # frame 2 shown from 0.1 s to 4.0 s
    with httpx.Client(base_url=uncapped.url, timeout=120) as client:
        created, job = run_job(client, gap_clip)
        assert job["status"] == "succeeded", job
        gammas = client.get(created["links"]["gammas"])
        assert gammas.status_code == 200, gammas.text
        assert json.loads(gammas.content)["frame_count"] == len(expected)
        video = client.get(created["links"]["video"])
        assert video.status_code == 200
    with av.open(io.BytesIO(video.content), mode="r") as c:
        shown = [read_index(f.to_ndarray(format="rgb24")) for f in c.decode(video=0)]
    assert shown == expected  # method none: the output frames are the source frames ffmpeg's fps=18 picks


@pytest.mark.parametrize("value", ["0", "many"])
def test_a_bad_cap_stops_the_server_at_start_in_one_line(tmp_path: Path, random_weights: Path, value: str) -> None:
    """Before, the server started, every job failed and POST /v1/enhance answered 500 (a ValueError traceback)."""
    srv = served(tmp_path / "data", random_weights, **{MAX_GAP_FRAMES_ENV: value})
    with pytest.raises(RuntimeError, match="server exited with 2"):
        srv.start(timeout=120)
    lines = [line for line in srv.log().splitlines() if line.strip()]
    assert any(MAX_GAP_FRAMES_ENV in line for line in lines), lines
    assert not any("Traceback" in line for line in lines), lines
